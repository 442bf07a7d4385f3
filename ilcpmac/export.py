"""Writers of a `Compensation` for a drive's firmware: JSON, CSV, or C99 (docs/export.md).

- json: ``compensation.json``, the record with its units, indented.
- csv: ``calibration.csv`` (a row per phase), ``torque_gain.csv`` (one row), ``feedforward.csv`` (a row per
  count, a column per (torque, speed) point, torque-major) and ``map.csv`` (the grid, counts_per_rev and the
  fade-out, one value per row); every number as the shortest decimal that reads back to the same double.
- c: ``ilcpmac_compensation.h`` and ``ilcpmac_compensation.c``: const tables (int16 at a stated N m per LSB,
  or float), the calibration, and ``ilcpmac_feedforward_nm`` implementing the rule of
  `ilcpmac.compensation` in float arithmetic; C99, no allocation, only <stdint.h>.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from string import Template

import numpy as np

from ilcpmac.compensation import COMPENSATION_FILE, Compensation

__all__ = ["C_TYPES", "FORMATS", "INT16_FULL_SCALE", "Exported", "Int16Tables", "export", "feedforward_column",
           "write_c", "write_csv", "write_json"]

#: what ``ilcpmac export --format`` writes
FORMATS = ("json", "csv", "c")
#: the C tables' element type
C_TYPES = ("int16", "float")
#: the int16 value of the tables' largest magnitude: 8 % headroom below 32767
INT16_FULL_SCALE = 30000
#: the C files
C_HEADER, C_SOURCE = "ilcpmac_compensation.h", "ilcpmac_compensation.c"
_PHASES = ("a", "b", "c")
#: table values per line of the C source
_C_PER_LINE = 12
#: a CSV row: text as it is, numbers as their shortest exact decimals
_Row = list[str | float]


@dataclass(frozen=True)
class Exported:
    """What an export wrote.

    Attributes
    ----------
    files : tuple of Path
        The files, in the order written.
    quantisation_error_nm : float or None
        int16 C tables: max |table - int16 x N m per LSB| over every value, N m; None otherwise.
    """

    files: tuple[Path, ...]
    quantisation_error_nm: float | None = None


@dataclass(frozen=True)
class Int16Tables:
    """The tables as int16 at a float32 scale.

    Attributes
    ----------
    values : ndarray of int16, shape (n_T, n_S, counts_per_rev)
    nm_per_lsb : float
        The scale, a float32 value: the tables' largest magnitude maps to `INT16_FULL_SCALE`.
    error_nm : float
        max |table - values x nm_per_lsb|, N m.
    """

    values: np.ndarray
    nm_per_lsb: float
    error_nm: float

    @classmethod
    def of(cls, tables_nm: np.ndarray) -> Int16Tables:
        """``tables_nm`` quantised."""
        peak = float(np.max(np.abs(tables_nm)))
        scale = float(np.float32((peak or 1.0) / INT16_FULL_SCALE))
        values = np.rint(tables_nm / scale).astype(np.int16)
        return cls(values, scale, float(np.max(np.abs(tables_nm - values * scale))))


def feedforward_column(torque_nm: float, speed_hz: float) -> str:
    """The header of feedforward.csv's column of the point (torque_nm, speed_hz)."""
    return f"feedforward_nm_at_{float(torque_nm)!r}_nm_{float(speed_hz)!r}_hz"


def _text(rows: list[_Row]) -> str:
    """CSV lines, floats as their shortest exact decimals."""
    return "".join(",".join(v if isinstance(v, str) else repr(v) for v in row) + "\n" for row in rows)


def write_json(compensation: Compensation, out_dir: Path) -> Exported:
    """compensation.json: the record (`Compensation.to_json`), indented."""
    path = out_dir / COMPENSATION_FILE
    path.write_text(json.dumps(compensation.to_json(), indent=1, allow_nan=False) + "\n")
    return Exported((path,))


def write_csv(compensation: Compensation, out_dir: Path) -> Exported:
    """calibration.csv, torque_gain.csv, feedforward.csv and map.csv (module docstring)."""
    c = compensation
    cal = c.calibration
    calibration: list[_Row] = [["phase", "current_scale_counts_per_a", "current_offset_counts"]]
    calibration += [[phase, float(cal.current_scale[p]), float(cal.current_offset[p])]
                    for p, phase in enumerate(_PHASES)]
    points = [(float(t), float(s)) for t in c.torques_nm for s in c.speeds_hz]
    columns = c.tables_nm.reshape(len(points), c.counts_per_rev).T
    feedforward: list[_Row] = [["count", *(feedforward_column(t, s) for t, s in points)]]
    feedforward += [[str(count), *row] for count, row in enumerate(columns.tolist())]
    grid: list[_Row] = [["name", "index", "value"], ["counts_per_rev", "0", str(c.counts_per_rev)]]
    grid += [["torques_nm", str(i), float(t)] for i, t in enumerate(c.torques_nm)]
    grid += [["speeds_hz", str(i), float(s)] for i, s in enumerate(c.speeds_hz)]
    grid += [["fade_full_hz", "0", c.fade.full_hz], ["fade_zero_hz", "0", c.fade.zero_hz]]
    files: dict[str, list[_Row]] = {
        "calibration.csv": calibration, "torque_gain.csv": [["torque_gain_v_per_nm"], [cal.torque_gain]],
        "feedforward.csv": feedforward, "map.csv": grid}
    for name, rows in files.items():
        (out_dir / name).write_text(_text(rows))
    return Exported(tuple(out_dir / name for name in files))


def _c_float(x: float) -> str:
    """``x`` as a C float literal: the shortest decimal of its float32."""
    return str(np.float32(x)) + "f"


def _c_list(values: Iterable[float], indent: str = "", literal: Callable[[float], str] = _c_float) -> str:
    """Values of a C initialiser; with an ``indent``, `_C_PER_LINE` to a line, else on one line."""
    items = [literal(v) for v in values]
    if not indent:
        return ", ".join(items)
    return ",\n".join(indent + ", ".join(items[i:i + _C_PER_LINE]) for i in range(0, len(items), _C_PER_LINE))


_HEADER = Template("""\
/* $header: the torque-ripple compensation of $source, written by ilcpmac export.
 *
 * C99, no allocation, only <stdint.h>; docs/export.md of ilcpmac gives every field and the rule.
 * Current of phase p (0, 1, 2 = a, b, c) from a raw reading r, A:
 *     i_p = (r + ilcpmac_current_offset_counts[p]) / ilcpmac_current_scale_counts_per_a[p]
 * Torque sensor, N m: volts / ILCPMAC_TORQUE_GAIN_V_PER_NM.
 * Torque reference at encoder count n, torque set point T (N m), mechanical speed S (Hz):
 *     tau_ref = T + ilcpmac_feedforward_nm(n, T, S)
 * the tables learned at the grid's (T, S) points, bilinear between them, T and S clamped into the
 * grid (NaN: its lowest point), times the fade-out at the unclamped S (NaN: 0).
$table_doc
$fade_doc
 */
#ifndef ILCPMAC_COMPENSATION_H
#define ILCPMAC_COMPENSATION_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define ILCPMAC_COUNTS_PER_REV ${counts_per_rev}u
#define ILCPMAC_N_TORQUES ${n_torques}u
#define ILCPMAC_N_SPEEDS ${n_speeds}u
/* N m per table unit */
#define ILCPMAC_TABLE_NM_PER_LSB $nm_per_lsb
$fade_defines#define ILCPMAC_TORQUE_GAIN_V_PER_NM $torque_gain

/* per phase a, b, c */
extern const float ilcpmac_current_scale_counts_per_a[3];
extern const float ilcpmac_current_offset_counts[3];
/* the grid, strictly ascending */
extern const float ilcpmac_torques_nm[ILCPMAC_N_TORQUES];
extern const float ilcpmac_speeds_hz[ILCPMAC_N_SPEEDS];
/* the feed-forward per count at each grid point, in ILCPMAC_TABLE_NM_PER_LSB */
extern const $element ilcpmac_feedforward_table[ILCPMAC_N_TORQUES][ILCPMAC_N_SPEEDS][ILCPMAC_COUNTS_PER_REV];

/* The torque feed-forward at encoder count `count` (taken modulo ILCPMAC_COUNTS_PER_REV), N m. */
float ilcpmac_feedforward_nm(uint32_t count, float torque_nm, float speed_hz);

#ifdef __cplusplus
}
#endif

#endif
""")

_SOURCE = Template("""\
/* $source_name: written by ilcpmac export; see $header. */
#include "$header"

const float ilcpmac_current_scale_counts_per_a[3] = {$current_scale};
const float ilcpmac_current_offset_counts[3] = {$current_offset};
const float ilcpmac_torques_nm[ILCPMAC_N_TORQUES] = {$torques};
const float ilcpmac_speeds_hz[ILCPMAC_N_SPEEDS] = {$speeds};
const $element ilcpmac_feedforward_table[ILCPMAC_N_TORQUES][ILCPMAC_N_SPEEDS][ILCPMAC_COUNTS_PER_REV] = {
$tables
};

/* The grid point at or below x clamped into the grid (the first of the last two at its top), and the
 * weight of the next one; an axis of one point has weight 0. */
static float ilcpmac_bracket(const float *grid, uint32_t n, float x, uint32_t *lower)
{
    uint32_t k = 0u;
    if (n < 2u || !(x > grid[0])) {
        *lower = 0u;
        return 0.0f;
    }
    if (x >= grid[n - 1u]) {
        *lower = n - 2u;
        return 1.0f;
    }
    while (x >= grid[k + 1u]) {
        k++;
    }
    *lower = k;
    return (x - grid[k]) / (grid[k + 1u] - grid[k]);
}

static float ilcpmac_fade(float speed_hz)
{
$fade_body}

float ilcpmac_feedforward_nm(uint32_t count, float torque_nm, float speed_hz)
{
    uint32_t n = count % ILCPMAC_COUNTS_PER_REV;
    uint32_t t0, t1, s0, s1;
    float u = ilcpmac_bracket(ilcpmac_torques_nm, ILCPMAC_N_TORQUES, torque_nm, &t0);
    float v = ilcpmac_bracket(ilcpmac_speeds_hz, ILCPMAC_N_SPEEDS, speed_hz, &s0);
    float lower, upper;
    t1 = ILCPMAC_N_TORQUES > 1u ? t0 + 1u : t0;
    s1 = ILCPMAC_N_SPEEDS > 1u ? s0 + 1u : s0;
    lower = (1.0f - v) * (float)ilcpmac_feedforward_table[t0][s0][n]
            + v * (float)ilcpmac_feedforward_table[t0][s1][n];
    upper = (1.0f - v) * (float)ilcpmac_feedforward_table[t1][s0][n]
            + v * (float)ilcpmac_feedforward_table[t1][s1][n];
    return ((1.0f - u) * lower + u * upper) * ILCPMAC_TABLE_NM_PER_LSB * ilcpmac_fade(speed_hz);
}
""")

_FADE_BODY = """\
    if (speed_hz <= ILCPMAC_FADE_FULL_HZ) {
        return 1.0f;
    }
    if (speed_hz < ILCPMAC_FADE_ZERO_HZ) {
        return (ILCPMAC_FADE_ZERO_HZ - speed_hz) / (ILCPMAC_FADE_ZERO_HZ - ILCPMAC_FADE_FULL_HZ);
    }
    return 0.0f;
"""


def _c_tables(compensation: Compensation, values: np.ndarray, literal: Callable[[float], str]) -> str:
    """The initialiser of the tables, a block per grid point."""
    blocks = []
    for i, t in enumerate(compensation.torques_nm):
        rows = [f"        {{ /* {t:g} N m, {s:g} Hz */\n{_c_list(values[i, k].tolist(), ' ' * 12, literal)}\n"
                "        }" for k, s in enumerate(compensation.speeds_hz)]
        blocks.append("    {\n" + ",\n".join(rows) + "\n    }")
    return ",\n".join(blocks)


def write_c(compensation: Compensation, out_dir: Path, c_type: str = "int16", source: str = "") -> Exported:
    """ilcpmac_compensation.h and .c (module docstring); ``source`` names the record in their comments."""
    c = compensation
    cal = c.calibration
    fade = c.fade
    fades = not math.isinf(fade.full_hz)
    literal: Callable[[float], str]
    if c_type == "int16":
        quantised = Int16Tables.of(c.tables_nm)
        element, values, literal, nm_per_lsb = "int16_t", quantised.values, str, _c_float(quantised.nm_per_lsb)
        table_doc = (f" * Tables: int16, {quantised.nm_per_lsb:.9g} N m per LSB; quantisation error\n"
                     f" * max |float - int16| = {quantised.error_nm:.3g} N m (the lookup's float arithmetic adds less\n"
                     " * than 1e-6 of the tables' peak).")
    else:
        quantised = None
        element, values, literal, nm_per_lsb = "float", c.tables_nm, _c_float, "1.0f"
        table_doc = " * Tables: float, N m."
    header = _HEADER.substitute(
        header=C_HEADER, source=source or "a campaign", table_doc=table_doc,
        fade_doc=f" * Fade-out: 1 up to {fade.full_hz:g} Hz, linear down to 0 at {fade.zero_hz:g} Hz, 0 beyond."
        if fades else " * Fade-out: none (the feed-forward never fades).",
        counts_per_rev=c.counts_per_rev, n_torques=c.torques_nm.size, n_speeds=c.speeds_hz.size,
        nm_per_lsb=nm_per_lsb, element=element, torque_gain=_c_float(cal.torque_gain),
        fade_defines=f"#define ILCPMAC_FADE_FULL_HZ {_c_float(fade.full_hz)}\n"
                     f"#define ILCPMAC_FADE_ZERO_HZ {_c_float(fade.zero_hz)}\n" if fades else "")
    body = _SOURCE.substitute(
        source_name=C_SOURCE, header=C_HEADER, element=element, current_scale=_c_list(cal.current_scale),
        current_offset=_c_list(cal.current_offset), torques=_c_list(c.torques_nm), speeds=_c_list(c.speeds_hz),
        tables=_c_tables(c, values, literal),
        fade_body=_FADE_BODY if fades else "    (void)speed_hz;\n    return 1.0f;\n")
    paths = (out_dir / C_HEADER, out_dir / C_SOURCE)
    paths[0].write_text(header)
    paths[1].write_text(body)
    return Exported(paths, None if quantised is None else quantised.error_nm)


def export(compensation: Compensation, out_dir: Path, fmt: str, c_type: str = "int16", source: str = "") -> Exported:
    """Write ``compensation`` into ``out_dir`` (made if missing) in format ``fmt`` (`FORMATS`; another raises
    `ValueError` before anything is made)."""
    if fmt not in FORMATS:
        raise ValueError(f"export format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    out_dir.mkdir(parents=True, exist_ok=True)
    if fmt == "json":
        return write_json(compensation, out_dir)
    if fmt == "csv":
        return write_csv(compensation, out_dir)
    return write_c(compensation, out_dir, c_type, source)
