"""Writers of a `Compensation` or a `PositionTable` for a drive's firmware (docs/export.md).

- json: ``compensation.json``, the record with its units, indented (a position table: ``position_table.json``).
- csv: ``calibration.csv`` (a row per phase), ``torque_gain.csv`` (one row), ``feedforward.csv`` (a row per
  count, a column per (torque, speed) point, torque-major) and ``map.csv`` (the grid, counts_per_rev and the
  fade-out, one value per row); every number as the shortest decimal that reads back to the same double. A
  position table: ``feedforward.csv`` with one column, and the calibration's two files where it has one.
- c: ``ilcpmac_compensation.h`` and ``ilcpmac_compensation.c``: const tables (int16 at a stated N m per LSB,
  or float), the calibration, and ``ilcpmac_feedforward_nm`` implementing the rule of
  `ilcpmac.compensation` in float arithmetic; C99, no allocation, only <stdint.h>. A position table:
  ``ilcpmac_position_table.h`` and ``.c`` with ``ilcpmac_position_feedforward_nm(count)``.
- harmonics (a position table): ``harmonics.csv``, a row per order: cos and sin, amplitude and phase, in N m
  and in q-axis amperes at a stated torque constant.
- moteus (a position table): ``moteus_cogging.txt``, the ``conf set`` lines of moteus's
  ``motor.cogging_dq_scale`` and 1024 int8 ``motor.cogging_dq_comp`` entries, q-axis amperes.

Every export states its `Residual`: the table as the target reproduces it per count, against the table; and its
`Bound` s: the feed-forward within the limits the record was made under (a run directory's [limits], `RunLimits`,
else the record's own range) and, for the drive formats, the q-axis current within the run's or the bench
format's largest current. A record beyond them, or one a format cannot hold (a C float that would be 0, a
moteus scale that would be 0 or infinite), is refused before anything is written. The files of one export are
written all or none (`_write_all`). `export_source` exports what a path holds (`read_source`: a run directory,
a compensation.json or a result JSON), as ``ilcpmac export`` and ``ilcpmac.api.export`` do.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Callable, Iterable
from contextlib import suppress
from dataclasses import dataclass, field
from pathlib import Path
from string import Template

import numpy as np

from ilcpmac.bench.format import BENCH_FILE, read_bench_head
from ilcpmac.compensation import COMPENSATION_FILE, Compensation, PositionTable, read_position_table
from ilcpmac.config import DIRECTIONS, LimitSettings
from ilcpmac.core.errors import BenchFormatError, IlcpmacError
from ilcpmac.core.files import atomic_write, check_writable
from ilcpmac.core.records import MAX_CURRENT_A, MAX_TORQUE_NM, SensorCalibration
from ilcpmac.core.schema import parse_section, read_toml
from ilcpmac.model.tables import mechanical_angles_rad
from ilcpmac.signals.harmonics import harmonic_amplitudes

__all__ = ["C_TYPES", "FLOAT32_TINY", "FORMATS", "INT16_FULL_SCALE", "MOTEUS_INT8_MAX", "MOTEUS_TABLE_SIZE",
           "POSITION_FORMATS", "RUN_CONFIG", "Bound", "Exported", "Int16Tables", "MoteusTable", "Residual", "RunLimits",
           "export", "export_source", "feedforward_column", "read_source", "write_c", "write_csv", "write_harmonics",
           "moteus_entries", "write_json", "write_moteus"]

#: what ``ilcpmac export --format`` writes
FORMATS = ("json", "csv", "c", "harmonics", "moteus")
#: the formats of a position table alone: they need a table of position only
POSITION_FORMATS = ("harmonics", "moteus")
#: moteus's cogging table: entries per revolution of its commutation encoder, and the int8 magnitude used
MOTEUS_TABLE_SIZE = 1024
MOTEUS_INT8_MAX = 127
#: the files of a position table and of the drive formats
POSITION_JSON, HARMONICS_FILE, MOTEUS_FILE = "position_table.json", "harmonics.csv", "moteus_cogging.txt"
#: the C tables' element type
C_TYPES = ("int16", "float")
#: the int16 value of the tables' largest magnitude: 8 % headroom below 32767
INT16_FULL_SCALE = 30000
#: the C files
C_HEADER, C_SOURCE = "ilcpmac_compensation.h", "ilcpmac_compensation.c"
POSITION_C_HEADER, POSITION_C_SOURCE = "ilcpmac_position_table.h", "ilcpmac_position_table.c"
_PHASES = ("a", "b", "c")
#: table values per line of the C source
_C_PER_LINE = 12
#: the smallest positive normal float32: a C float or a drive's float below it is subnormal or 0
FLOAT32_TINY = float(np.finfo(np.float32).tiny)
_FLOAT32_MAX = float(np.finfo(np.float32).max)
#: the file that makes a folder a run directory (ilcpmac.campaign.rundir.CONFIG_FILE): the config it ran, [limits]
RUN_CONFIG = "campaign.toml"
#: a CSV row: text as it is, numbers as their shortest exact decimals
_Row = list[str | float]


@dataclass(frozen=True)
class Residual:
    """The ripple a format leaves: the exported tables as the target samples them per count, minus the tables; and,
    beside it, how well the tables themselves are known, which the format's residual says nothing of.

    Attributes
    ----------
    rms_nm, peak_nm : float
        RMS and largest magnitude over every count (and grid point), N m.
    reference_nm : float
        The torque the percentages are of, N m: a stated rated torque, else the tables' largest peak-to-peak.
    reference : str
        What it is: "rated torque" or "the table's peak-to-peak".
    table_std_rms_nm : float or None
        The RMS over the counts of the table's own standard error, as its source states it (an identification's or a
        scan's), N m; None where the source states none.
    """

    rms_nm: float
    peak_nm: float
    reference_nm: float
    reference: str
    table_std_rms_nm: float | None = None

    @classmethod
    def of(cls, tables_nm: np.ndarray, rendered_nm: np.ndarray, rated_torque_nm: float | None = None,
           table_std_nm: np.ndarray | None = None) -> Residual:
        """``rendered_nm`` (same shape as ``tables_nm``, counts on the last axis) against ``tables_nm``;
        ``table_std_nm``: the tables' standard error per count, where their source states it."""
        error = np.asarray(rendered_nm, float) - tables_nm
        if rated_torque_nm is None:
            flat = tables_nm.reshape(-1, tables_nm.shape[-1])
            reference_nm, reference = float(np.max(np.ptp(flat, axis=-1))), "the table's peak-to-peak"
        else:
            reference_nm, reference = float(rated_torque_nm), "rated torque"
        std = None if table_std_nm is None else float(np.sqrt(np.mean(np.square(table_std_nm))))
        return cls(float(np.sqrt(np.mean(error**2))), float(np.max(np.abs(error))), reference_nm, reference, std)

    def line(self, fmt: str) -> str:
        """The line ``ilcpmac export`` prints: the format's residual, then what is known of the table's own error,
        so that the first is never read as the second."""
        def percent(x: float) -> str:
            return f"{100.0 * x / self.reference_nm:.3g} %" if self.reference_nm > 0 else "- %"
        known = ("its source states no standard error of the table" if self.table_std_rms_nm is None else
                 f"the table itself is known to {self.table_std_rms_nm:.3g} N m RMS, {percent(self.table_std_rms_nm)}"
                 " (its source's standard error)")
        return (f"residual ripple of the {fmt} export: {self.rms_nm:.3g} N m RMS, {self.peak_nm:.3g} N m peak "
                f"({percent(self.rms_nm)}, {percent(self.peak_nm)} of {self.reference} {self.reference_nm:.4g} N m): "
                f"the format's, not the table's accuracy; {known}")


@dataclass(frozen=True)
class Bound:
    """A bound an export keeps: the largest magnitude of a quantity in it, and the bound.

    Attributes
    ----------
    quantity : str
        What is bounded, e.g. "|feed-forward|".
    peak : float
        Its largest magnitude in the export, in ``unit``.
    limit : float
        The bound, in ``unit``.
    unit : str
    origin : str
        Where the bound comes from, e.g. "[limits] max_correction_nm of runs/today/campaign.toml".
    """

    quantity: str
    peak: float
    limit: float
    unit: str
    origin: str

    def checked(self, where: str) -> Bound:
        """This bound, kept; else `BenchFormatError` naming ``where`` (the file, the key or the option)."""
        if not self.peak <= self.limit:
            raise BenchFormatError(f"{where}: {self.quantity} {self.peak:.4g} {self.unit} is beyond {self.limit:g} "
                                   f"{self.unit} ({self.origin})")
        return self

    def line(self) -> str:
        """The line ``ilcpmac export`` prints."""
        return (f"bound: {self.quantity} at most {self.peak:.4g} {self.unit}, within {self.limit:g} {self.unit} "
                f"({self.origin})")


@dataclass(frozen=True)
class RunLimits:
    """What a run directory says the records in it were made under: its [limits] and its encoder.

    Attributes
    ----------
    limits : LimitSettings
        The run's [limits] (its campaign.toml).
    counts_per_rev : int
        Its bench's encoder counts per revolution (its bench.toml).
    config : Path
        Its campaign.toml, which messages name.
    """

    limits: LimitSettings
    counts_per_rev: int
    config: Path

    @classmethod
    def of(cls, source: Path) -> RunLimits | None:
        """The limits of the run directory that holds the file ``source`` (a folder with `RUN_CONFIG`), None
        outside one; a campaign.toml or bench.toml that cannot be read is one error naming it."""
        config = source.parent / RUN_CONFIG
        if not config.exists():
            return None
        limits = parse_section(read_toml(config).get("limits", {}), LimitSettings, str(config), "limits")
        # a campaign in both directions keeps its bench in each direction's run directory
        bench = next((folder for folder in (source.parent, *(source.parent / d for d in DIRECTIONS))
                      if (folder / BENCH_FILE).exists()), source.parent)
        return cls(limits, read_bench_head(bench).motor.counts_per_rev, config)

    def bound(self, quantity: str, peak: float, key: str, unit: str) -> Bound:
        """The `Bound` of ``quantity`` at [limits] ``key``."""
        return Bound(quantity, peak, getattr(self.limits, key), unit, f"[limits] {key} of {self.config}")

    def correction_bound(self, peak: float) -> Bound:
        """The `Bound` of the |feed-forward| (`LimitSettings.correction_nm`)."""
        key = "max_correction_nm" if self.limits.max_correction_nm is not None else \
            "max_correction_fraction x max_torque_nm"
        return Bound("|feed-forward|", peak, self.limits.correction_nm(), "N m", f"[limits] {key} of {self.config}")


@dataclass(frozen=True)
class Exported:
    """What an export wrote.

    Attributes
    ----------
    files : tuple of Path
        The files, in the order written.
    quantisation_error_nm : float or None
        int16 C tables: max |table - int16 x N m per LSB| over every value, N m; None otherwise.
    rendered_nm : ndarray or None
        The tables as the target reproduces them per count from the files, N m.
    residual : Residual or None
        `rendered_nm` against the tables (`export` sets it).
    bounds : tuple of Bound
        The bounds the export keeps (`export` adds the record's to the format's).
    """

    files: tuple[Path, ...]
    quantisation_error_nm: float | None = None
    rendered_nm: np.ndarray | None = field(default=None, repr=False)
    residual: Residual | None = None
    bounds: tuple[Bound, ...] = ()


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


Record = Compensation | PositionTable


def tables_of(record: Record) -> np.ndarray:
    """The record's feed-forward tables, N m: counts on the last axis."""
    return record.tables_nm if isinstance(record, Compensation) else record.feedforward_nm


def _staged(path: Path) -> Path:
    """Where `_write_all` writes ``path`` before renaming it: PATH.new, beside it."""
    return path.with_name(path.name + ".new")


def _write_all(out_dir: Path, texts: dict[str, str]) -> tuple[Path, ...]:
    """Write the files ``texts`` (name: text) into ``out_dir`` (made if missing), all or none.

    Each is checked writable first (`check_writable`), then written through `atomic_write` to PATH.new, and
    only once every one is written is each renamed to PATH: on a failure (a full disk, a quota) the PATH.new
    files are removed and the files of those names stay as they were, and the `OSError` names the file.
    """
    paths = tuple(out_dir / name for name in texts)
    for path in paths:
        check_writable(path, IlcpmacError)
    try:
        for path, text in zip(paths, texts.values()):
            try:
                atomic_write(_staged(path), text)
            except OSError as e:
                raise OSError(e.errno, e.strerror, str(path)) from None
        for path in paths:
            os.replace(_staged(path), path)
    except BaseException:
        for path in paths:
            with suppress(OSError):
                _staged(path).unlink(missing_ok=True)
        raise
    return paths


def write_json(record: Record, out_dir: Path) -> Exported:
    """compensation.json (`Compensation.to_json`) or position_table.json (`PositionTable.to_json`), indented."""
    name = COMPENSATION_FILE if isinstance(record, Compensation) else POSITION_JSON
    text = json.dumps(record.to_json(), indent=1, allow_nan=False) + "\n"
    return Exported(_write_all(out_dir, {name: text}), rendered_nm=tables_of(record))


def _calibration_files(cal: SensorCalibration | None) -> dict[str, list[_Row]]:
    """calibration.csv and torque_gain.csv of ``cal`` (none without one)."""
    if cal is None:
        return {}
    calibration: list[_Row] = [["phase", "current_scale_counts_per_a", "current_offset_counts"]]
    calibration += [[phase, float(cal.current_scale[p]), float(cal.current_offset[p])]
                    for p, phase in enumerate(_PHASES)]
    return {"calibration.csv": calibration, "torque_gain.csv": [["torque_gain_v_per_nm"], [cal.torque_gain]]}


def _write_rows(files: dict[str, list[_Row]], out_dir: Path, rendered_nm: np.ndarray) -> Exported:
    return Exported(_write_all(out_dir, {name: _text(rows) for name, rows in files.items()}), rendered_nm=rendered_nm)


def write_csv(record: Record, out_dir: Path) -> Exported:
    """calibration.csv, torque_gain.csv, feedforward.csv and map.csv (module docstring)."""
    if isinstance(record, PositionTable):
        feedforward: list[_Row] = [["count", "feedforward_nm"]]
        feedforward += [[str(count), value] for count, value in enumerate(record.feedforward_nm.tolist())]
        return _write_rows({**_calibration_files(record.calibration), "feedforward.csv": feedforward}, out_dir,
                           record.feedforward_nm)
    c = record
    points = [(float(t), float(s)) for t in c.torques_nm for s in c.speeds_hz]
    columns = c.tables_nm.reshape(len(points), c.counts_per_rev).T
    feedforward = [["count", *(feedforward_column(t, s) for t, s in points)]]
    feedforward += [[str(count), *row] for count, row in enumerate(columns.tolist())]
    grid: list[_Row] = [["name", "index", "value"], ["counts_per_rev", "0", str(c.counts_per_rev)]]
    grid += [["torques_nm", str(i), float(t)] for i, t in enumerate(c.torques_nm)]
    grid += [["speeds_hz", str(i), float(s)] for i, s in enumerate(c.speeds_hz)]
    grid += [["fade_full_hz", "0", c.fade.full_hz], ["fade_zero_hz", "0", c.fade.zero_hz]]
    return _write_rows({**_calibration_files(c.calibration), "feedforward.csv": feedforward, "map.csv": grid},
                       out_dir, c.tables_nm)


def _c_float(x: float) -> str:
    """``x`` as a C float literal: the shortest decimal of its float32."""
    return str(np.float32(x)) + "f"


def _float_scale(x: float, where: str) -> float:
    """A scale a drive divides or multiplies by, ``x`` > 0, as the float32 it holds; one a float32 cannot hold
    (0 or subnormal there, or infinite) raises `BenchFormatError` naming ``where``."""
    if not FLOAT32_TINY <= x <= _FLOAT32_MAX:
        raise BenchFormatError(f"{where}: {x:.4g} is no normal float32, which the drive's float needs (it holds "
                               f"{FLOAT32_TINY:.4g} to {_FLOAT32_MAX:.4g}; below, 0 or lost digits)")
    return float(np.float32(x))


def _c_scale(x: float, where: str) -> str:
    """`_float_scale` as a C float literal (`_c_float`)."""
    return _c_float(_float_scale(x, where))


def _c_grid(values: np.ndarray, where: str) -> str:
    """A grid axis as a C initialiser: it must stay strictly ascending as floats (the lookup divides by the
    steps), else `BenchFormatError` naming ``where``."""
    steps = np.diff(values.astype(np.float32))
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0))
        raise BenchFormatError(f"{where}: values {k} and {k + 1} ({float(values[k])!r}, {float(values[k + 1])!r}) "
                               "are one float in the C export: its lookup would divide by zero")
    return _c_list(values)


def _comment(text: str) -> str:
    """``text`` (a path) inert in a C comment: printable ASCII only, anything else as its escape (a byte of a name
    that is no UTF-8 as \\udcXX), and neither ``*/`` nor ``/*``."""
    text = "".join(c if " " <= c <= "~" else c.encode("unicode_escape").decode("ascii") for c in text)
    return text.replace("*/", "*\\/").replace("/*", "/\\*")


def _c_list(values: Iterable[float], indent: str = "", literal: Callable[[float], str] = _c_float) -> str:
    """Values of a C initialiser; with an ``indent``, `_C_PER_LINE` to a line, else on one line."""
    items = [literal(v) for v in values]
    if not indent:
        return ", ".join(items)
    return ",\n".join(indent + ", ".join(items[i:i + _C_PER_LINE]) for i in range(0, len(items), _C_PER_LINE))


#: what the C header says of the directions its record holds, by whether it holds a negative speed
_DIRECTION_DOC = {
    False: " * Learned turning forward (positive S): a negative S is clamped to the slowest speed, its tables\n"
           " * applied turning the other way, where their lag's correction has the wrong sign.",
    True: " * Learned in both directions: a negative S turns in reverse (n and T as turning forward); between\n"
          " * the slowest reverse and forward speeds the tables are interpolated through 0 Hz."}

_HEADER = Template("""\
/* $header: the torque-ripple compensation of $source, written by ilcpmac export.
 *
 * C99, no allocation, only <stdint.h>; docs/export.md of ilcpmac gives every field and the rule.
$calibration_doc
 * Torque reference at encoder count n, torque set point T (N m), mechanical speed S (Hz):
 *     tau_ref = T + ilcpmac_feedforward_nm(n, T, S)
 * the tables learned at the grid's (T, S) points, bilinear between them, T and S clamped into the
 * grid (NaN: its lowest point), times the fade-out at the unclamped |S| (NaN: 0).
$direction_doc
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
$fade_defines$calibration/* the grid, strictly ascending */
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

${calibration}const float ilcpmac_torques_nm[ILCPMAC_N_TORQUES] = {$torques};
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
    if (speed_hz < 0.0f) {
        speed_hz = -speed_hz;
    }
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


@dataclass(frozen=True)
class _CTables:
    """Tables as the C source holds them: element type, values, literal, the scale's literal, its comment,
    the int16 quantisation (None: float), and what the lookup gives back, N m."""

    element: str
    values: np.ndarray
    literal: Callable[[float], str]
    nm_per_lsb: str
    doc: str
    quantised: Int16Tables | None
    rendered_nm: np.ndarray

    @classmethod
    def of(cls, tables_nm: np.ndarray, c_type: str, where: str) -> _CTables:
        """``where`` names the tables in an error."""
        if c_type == "int16":
            q = Int16Tables.of(tables_nm)
            doc = (f" * Tables: int16, {q.nm_per_lsb:.9g} N m per LSB; quantisation error\n"
                   f" * max |float - int16| = {q.error_nm:.3g} N m (the lookup's float arithmetic adds less\n"
                   " * than 1e-6 of the tables' peak).")
            rendered = (q.values.astype(np.float32) * np.float32(q.nm_per_lsb)).astype(float)
            scale = _c_scale(q.nm_per_lsb, f"{where}: the int16 tables' N m per LSB (their largest magnitude / "
                                           f"{INT16_FULL_SCALE}; --c-type float holds smaller tables)")
            return cls("int16_t", q.values, str, scale, doc, q, rendered)
        return cls("float", tables_nm, _c_float, "1.0f", " * Tables: float, N m.", None,
                   tables_nm.astype(np.float32).astype(float))


def _calibration_c(cal: SensorCalibration, source: str) -> tuple[str, str]:
    """The calibration's declarations (header) and definitions (source); ``source`` names its file in an error."""
    scales = ", ".join(_c_scale(float(x), f"{source}: key 'calibration.current_scale': value [{p}]")
                       for p, x in enumerate(cal.current_scale))
    return ("#define ILCPMAC_TORQUE_GAIN_V_PER_NM "
            + _c_scale(cal.torque_gain, f"{source}: key 'calibration.torque_gain'") + "\n"
            "/* per phase a, b, c */\n"
            "extern const float ilcpmac_current_scale_counts_per_a[3];\n"
            "extern const float ilcpmac_current_offset_counts[3];\n",
            f"const float ilcpmac_current_scale_counts_per_a[3] = {{{scales}}};\n"
            f"const float ilcpmac_current_offset_counts[3] = {{{_c_list(cal.current_offset)}}};\n")


_POSITION_HEADER = Template("""\
/* $header: the position torque feed-forward ($content) of $source, written by ilcpmac export.
 *
 * C99, no allocation, only <stdint.h>; docs/export.md of ilcpmac gives every field.
 * A function of position alone: at every torque set point T and every speed, at encoder count n,
 *     tau_ref = T + ilcpmac_position_feedforward_nm(n)
$calibration_doc
$table_doc
 */
#ifndef ILCPMAC_POSITION_TABLE_H
#define ILCPMAC_POSITION_TABLE_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define ILCPMAC_COUNTS_PER_REV ${counts_per_rev}u
/* N m per table unit */
#define ILCPMAC_TABLE_NM_PER_LSB $nm_per_lsb
$calibration/* the feed-forward per count, in ILCPMAC_TABLE_NM_PER_LSB */
extern const $element ilcpmac_position_feedforward_table[ILCPMAC_COUNTS_PER_REV];

/* The torque feed-forward at encoder count `count` (taken modulo ILCPMAC_COUNTS_PER_REV), N m. */
float ilcpmac_position_feedforward_nm(uint32_t count);

#ifdef __cplusplus
}
#endif

#endif
""")

_POSITION_SOURCE = Template("""\
/* $source_name: written by ilcpmac export; see $header. */
#include "$header"

${calibration}const $element ilcpmac_position_feedforward_table[ILCPMAC_COUNTS_PER_REV] = {
$table
};

float ilcpmac_position_feedforward_nm(uint32_t count)
{
    return (float)ilcpmac_position_feedforward_table[count % ILCPMAC_COUNTS_PER_REV] * ILCPMAC_TABLE_NM_PER_LSB;
}
""")

_CALIBRATION_DOC = """\
 * Current of phase p (0, 1, 2 = a, b, c) from a raw reading r, A:
 *     i_p = (r + ilcpmac_current_offset_counts[p]) / ilcpmac_current_scale_counts_per_a[p]
 * Torque sensor, N m: volts / ILCPMAC_TORQUE_GAIN_V_PER_NM."""


def _write_position_c(table: PositionTable, out_dir: Path, c_type: str) -> Exported:
    """ilcpmac_position_table.h and .c (module docstring)."""
    form = _CTables.of(table.feedforward_nm, c_type, f"{table.source}: key '{table.key}'")
    cal = table.calibration
    declarations, definitions = ("", "") if cal is None else _calibration_c(cal, table.source)
    header = _POSITION_HEADER.substitute(
        header=POSITION_C_HEADER, content=table.content, source=_comment(table.source), table_doc=form.doc,
        calibration_doc=_CALIBRATION_DOC if cal is not None else " * No current-sensor calibration was identified.",
        counts_per_rev=table.counts_per_rev, nm_per_lsb=form.nm_per_lsb, calibration=declarations,
        element=form.element)
    body = _POSITION_SOURCE.substitute(
        source_name=POSITION_C_SOURCE, header=POSITION_C_HEADER, calibration=definitions, element=form.element,
        table=_c_list(form.values.tolist(), " " * 4, form.literal))
    paths = _write_all(out_dir, {POSITION_C_HEADER: header, POSITION_C_SOURCE: body})
    return Exported(paths, None if form.quantised is None else form.quantised.error_nm, form.rendered_nm)


def write_c(record: Record, out_dir: Path, c_type: str = "int16", source: str = "") -> Exported:
    """ilcpmac_compensation.h and .c, or a position table's ilcpmac_position_table.h and .c (module docstring);
    ``source`` names a compensation in their comments (made inert there) and in errors. A scale a C float
    cannot hold, or a grid that is not strictly ascending as floats, raises `BenchFormatError` before anything
    is written."""
    if isinstance(record, PositionTable):
        return _write_position_c(record, out_dir, c_type)
    c = record
    where = source or COMPENSATION_FILE
    fade = c.fade
    fades = not math.isinf(fade.full_hz)
    form = _CTables.of(c.tables_nm, c_type, f"{where}: key 'tables_nm'")
    declarations, definitions = _calibration_c(c.calibration, where)
    torques = _c_grid(c.torques_nm, f"{where}: key 'torques_nm'")
    speeds = _c_grid(c.speeds_hz, f"{where}: key 'speeds_hz'")
    header = _HEADER.substitute(
        header=C_HEADER, source=_comment(source or "a campaign"), table_doc=form.doc,
        calibration_doc=_CALIBRATION_DOC, direction_doc=_DIRECTION_DOC[bool(c.speeds_hz[0] < 0)],
        fade_doc=f" * Fade-out: 1 up to {fade.full_hz:g} Hz, linear down to 0 at {fade.zero_hz:g} Hz, 0 beyond."
        if fades else " * Fade-out: none (the feed-forward never fades).",
        counts_per_rev=c.counts_per_rev, n_torques=c.torques_nm.size, n_speeds=c.speeds_hz.size,
        nm_per_lsb=form.nm_per_lsb, element=form.element, calibration=declarations,
        fade_defines=f"#define ILCPMAC_FADE_FULL_HZ {_c_float(fade.full_hz)}\n"
                     f"#define ILCPMAC_FADE_ZERO_HZ {_c_float(fade.zero_hz)}\n" if fades else "")
    body = _SOURCE.substitute(
        source_name=C_SOURCE, header=C_HEADER, element=form.element, calibration=definitions,
        torques=torques, speeds=speeds, tables=_c_tables(c, form.values, form.literal),
        fade_body=_FADE_BODY if fades else "    (void)speed_hz;\n    return 1.0f;\n")
    paths = _write_all(out_dir, {C_HEADER: header, C_SOURCE: body})
    return Exported(paths, None if form.quantised is None else form.quantised.error_nm, form.rendered_nm)


def _harmonic_sum(orders: np.ndarray, coefficients: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """sum a_n cos(n theta) + b_n sin(n theta) at the angles ``theta``."""
    angle = np.outer(theta, orders)
    return np.cos(angle) @ coefficients[:, 0] + np.sin(angle) @ coefficients[:, 1]


def _q_current_bound(peak_a: float, kt: float, source: str, run: RunLimits | None) -> Bound:
    """The `Bound` of a drive format's q-axis current, ``peak_a`` its largest magnitude at torque constant ``kt``
    (N m per A): within the run's max_current_a, else the bench format's largest current, and no smaller than a
    drive's float holds; `IlcpmacError` naming ``source`` and the option otherwise."""
    where = f"{source}: at --torque-constant {kt!r} N m per A"
    if not peak_a >= FLOAT32_TINY:
        raise IlcpmacError(f"{where}: the q-axis current peaks at {peak_a:.3g} A, below {FLOAT32_TINY:.3g} A, the "
                           "smallest normal float32 a drive holds (a torque constant in N m per A?)")
    bound = (Bound("|q-axis current|", peak_a, MAX_CURRENT_A, "A", "the bench format's largest current")
             if run is None else run.bound("|q-axis current|", peak_a, "max_current_a", "A"))
    return bound.checked(where)


def write_harmonics(table: PositionTable, out_dir: Path, torque_constant_nm_per_a: float,
                    run: RunLimits | None = None) -> Exported:
    """harmonics.csv: per order n of ``table.orders``, a_n, b_n, the amplitude sqrt(a_n^2 + b_n^2) and the
    phase atan2(b_n, a_n) (a_n cos + b_n sin = amplitude cos(n theta - phase)), in N m and in q-axis A; the
    series' q-axis current within `_q_current_bound` (``run``: the run directory's limits)."""
    coefficients = table.coefficients_nm()
    kt = float(torque_constant_nm_per_a)
    rendered = _harmonic_sum(table.orders, coefficients, mechanical_angles_rad(table.counts_per_rev))
    bound = _q_current_bound(float(np.max(np.abs(rendered))) / kt, kt, table.source, run)
    amplitude = np.hypot(coefficients[:, 0], coefficients[:, 1])
    phase = np.arctan2(coefficients[:, 1], coefficients[:, 0])
    at = f"_at_{kt!r}_nm_per_a"
    rows: list[_Row] = [["order", "cos_nm", "sin_nm", "amplitude_nm", "phase_rad",
                         "cos_a" + at, "sin_a" + at, "amplitude_a" + at]]
    rows += [[str(n), float(a), float(b), float(m), float(ph), float(a) / kt, float(b) / kt, float(m) / kt]
             for n, (a, b), m, ph in zip(table.orders.tolist(), coefficients, amplitude, phase)]
    return Exported(_write_all(out_dir, {HARMONICS_FILE: _text(rows)}), rendered_nm=rendered, bounds=(bound,))


def moteus_entries(per_count: np.ndarray) -> np.ndarray:
    """A table per count of a revolution as moteus's 1024 entries at positions k / 1024 that the firmware's linear
    interpolation turns back into it: its Fourier series (orders up to 511, what 1024 entries hold), each order n
    divided by sinc^2(n / 1024), the linear interpolation's response to it."""
    orders = np.arange(min(per_count.size // 2, MOTEUS_TABLE_SIZE // 2 - 1) + 1)
    c = harmonic_amplitudes(per_count)[orders] / np.sinc(orders / MOTEUS_TABLE_SIZE) ** 2
    theta = mechanical_angles_rad(MOTEUS_TABLE_SIZE)
    return np.real(np.exp(1j * np.outer(theta, orders)) @ c)


def _moteus_current_a(table: PositionTable, torque_constant_nm_per_a: float) -> np.ndarray:
    """The feed-forward in q-axis amperes at moteus's 1024 entries (`moteus_entries`)."""
    return moteus_entries(table.feedforward_nm) / torque_constant_nm_per_a


@dataclass(frozen=True)
class MoteusTable:
    """moteus's cogging compensation: q-axis current = ``values[k] x scale_a``, A, at commutation position
    k / `MOTEUS_TABLE_SIZE` of a revolution, linear between entries.

    The firmware (fw/bldc_servo_control.h, fw/bldc_servo_structs.h of mjbots/moteus) takes the commutation
    encoder's position p in [0, 1) of a revolution, the entry k = min(1023, floor(1024 p)) and the next one
    (k + 1) mod 1024, and interpolates linearly with the fraction 1024 p - k; it adds that current after its own
    current limit, so the export bounds it (`_q_current_bound`).

    Attributes
    ----------
    values : ndarray of int8, shape (1024,)
        Within +-`MOTEUS_INT8_MAX`.
    scale_a : float
        A normal float32 number, A per unit: the largest magnitude maps to `MOTEUS_INT8_MAX`.
    """

    values: np.ndarray
    scale_a: float

    @classmethod
    def of(cls, current_a: np.ndarray, where: str) -> MoteusTable:
        """``current_a`` (`_moteus_current_a`, finite, not all 0) quantised; a scale a float32 cannot hold raises
        `BenchFormatError` naming ``where``."""
        peak = float(np.max(np.abs(current_a)))
        scale = _float_scale(peak / MOTEUS_INT8_MAX, f"{where}: motor.cogging_dq_scale")
        values = np.clip(np.rint(current_a / scale), -MOTEUS_INT8_MAX, MOTEUS_INT8_MAX).astype(np.int8)
        return cls(values, scale)

    def sample_a(self, position: np.ndarray) -> np.ndarray:
        """The firmware's q-axis current at positions ``position`` in [0, 1) of a revolution, A."""
        size = self.values.size
        left = np.minimum(size - 1, np.floor(size * position).astype(np.int64))
        fraction = (position - left / size) * size
        low, high = self.values[left] * self.scale_a, self.values[(left + 1) % size] * self.scale_a
        return (high - low) * fraction + low

    def lines(self) -> list[str]:
        """The moteus console commands that store it (``conf write`` then keeps them)."""
        return [f"conf set motor.cogging_dq_scale {np.float32(self.scale_a)}",
                *(f"conf set motor.cogging_dq_comp.{k} {v}" for k, v in enumerate(self.values.tolist()))]


def write_moteus(table: PositionTable, out_dir: Path, torque_constant_nm_per_a: float,
                 run: RunLimits | None = None) -> Exported:
    """moteus_cogging.txt: the `MoteusTable` lines, count c at commutation position c / counts_per_rev; its
    q-axis current within `_q_current_bound` (``run``: the run directory's limits)."""
    kt = float(torque_constant_nm_per_a)
    current_a = _moteus_current_a(table, kt)
    bound = _q_current_bound(float(np.max(np.abs(current_a))), kt, table.source, run)
    moteus = MoteusTable.of(current_a, f"{table.source}: at --torque-constant {kt!r} N m per A")
    rendered = moteus.sample_a(np.arange(table.counts_per_rev) / table.counts_per_rev) * kt
    return Exported(_write_all(out_dir, {MOTEUS_FILE: "\n".join(moteus.lines()) + "\n"}), rendered_nm=rendered,
                    bounds=(bound,))


def _record_bounds(record: Record, where: str, run: RunLimits | None) -> tuple[Bound, ...]:
    """The record within the limits it was made under: its run directory's [limits] and encoder (``run``), else
    its own range; `BenchFormatError` naming ``where`` and the key otherwise."""
    tables = tables_of(record)
    index = [int(i) for i in np.unravel_index(int(np.argmax(np.abs(tables))), tables.shape)]
    peak = float(np.abs(tables).max())
    at = f"{where}: key '{'tables_nm' if isinstance(record, Compensation) else record.key}': value {index}"
    if run is None:
        return (Bound("|feed-forward|", peak, MAX_TORQUE_NM, "N m",
                      "the record's range: no run directory, so no [limits]").checked(at),)
    if record.counts_per_rev != run.counts_per_rev:
        raise BenchFormatError(f"{where}: {record.counts_per_rev} counts per revolution, but the run's encoder has "
                               f"{run.counts_per_rev} ({run.config.parent / BENCH_FILE})")
    bounds = [run.correction_bound(peak).checked(at)]
    if isinstance(record, Compensation):
        bounds += [run.bound("|torque set point|", float(np.abs(record.torques_nm).max()), "max_torque_nm",
                             "N m").checked(f"{where}: key 'torques_nm'"),
                   run.bound("|speed set point|", float(np.abs(record.speeds_hz).max()), "max_speed_hz",
                             "Hz").checked(f"{where}: key 'speeds_hz'")]
    return tuple(bounds)


def export(record: Record, out_dir: Path, fmt: str, c_type: str = "int16", source: str = "",
           torque_constant_nm_per_a: float | None = None, rated_torque_nm: float | None = None,
           run: RunLimits | None = None) -> Exported:
    """Write ``record`` into ``out_dir`` (made if missing) in format ``fmt``, with its `Residual` against
    ``rated_torque_nm`` (None: the tables' peak-to-peak) and its `Bound` s: within ``run``, the limits of the run
    directory it came from (None: its own range; `_record_bounds`), and within the format's.

    A ``fmt`` not in `FORMATS`, or a ``c_type`` not in `C_TYPES`, raises `ValueError` before anything is made.
    `POSITION_FORMATS` take a `PositionTable` and a finite torque constant, N m per q-axis A. Every refusal
    (`IlcpmacError`) comes before anything is made; the files are written all or none (`_write_all`)."""
    if fmt not in FORMATS:
        raise ValueError(f"export format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    if c_type not in C_TYPES:
        raise ValueError(f"C table type must be one of {', '.join(C_TYPES)}, got {c_type!r}")
    if fmt in POSITION_FORMATS:
        if not isinstance(record, PositionTable):
            raise IlcpmacError(f"--format {fmt} takes an identification's or a scan's result.json: "
                               f"{source or 'a campaign'}'s compensation varies with torque and speed (use json, "
                               "csv or c)")
        if torque_constant_nm_per_a is None or not 0 < torque_constant_nm_per_a < math.inf:
            got = "" if torque_constant_nm_per_a is None else f", got {torque_constant_nm_per_a!r}"
            raise IlcpmacError(f"--format {fmt} needs --torque-constant NM_PER_A > 0 and finite, the q-axis torque "
                               "constant that turns N m into q-axis amperes "
                               f"({record.source} does not hold the back-EMF){got}")
    if rated_torque_nm is not None and not 0 < rated_torque_nm < math.inf:
        raise IlcpmacError(f"--rated-torque must be a finite number > 0 N m, got {rated_torque_nm!r}")
    bounds = _record_bounds(record, record.source if isinstance(record, PositionTable) else source or COMPENSATION_FILE,
                            run)
    exported: Exported
    if fmt == "json":
        exported = write_json(record, out_dir)
    elif fmt == "csv":
        exported = write_csv(record, out_dir)
    elif fmt == "c":
        exported = write_c(record, out_dir, c_type, source)
    else:
        assert isinstance(record, PositionTable) and torque_constant_nm_per_a is not None
        writer = write_harmonics if fmt == "harmonics" else write_moteus
        exported = writer(record, out_dir, torque_constant_nm_per_a, run)
    assert exported.rendered_nm is not None
    residual = Residual.of(tables_of(record), exported.rendered_nm, rated_torque_nm,
                           record.std_nm if isinstance(record, PositionTable) else None)
    return dataclasses.replace(exported, residual=residual, bounds=bounds + exported.bounds)


def read_source(source: str | Path, content: str | None = None) -> tuple[Record, Path]:
    """What ``ilcpmac export SOURCE`` exports, and the file it was read from.

    Parameters
    ----------
    source : str or Path
        A folder holding compensation.json (a run directory of ``ilcpmac run``), a file named compensation.json,
        or a result JSON of ``ilcpmac identify`` (a bench's or a standstill scan's).
    content : str or None
        Of a result: "cogging" (None: the default) or "position-torque" (`ilcpmac.compensation.CONTENTS`).

    Returns
    -------
    record : Compensation or PositionTable
        The campaign's compensation, or the result's position table (`read_position_table`).
    path : Path
        The file it was read from.

    Raises
    ------
    BenchFormatError
        A folder without compensation.json, or a file that cannot be read as what it is taken for (one line
        naming the file and key).
    IlcpmacError
        ``content`` given for a compensation.
    """
    path = Path(source)
    if path.is_dir():
        path = path / COMPENSATION_FILE
        if not path.exists():
            raise BenchFormatError(f"{source} has no {path.name} (a campaign writes it when its learning phase ends)")
    elif path.name != COMPENSATION_FILE:
        return read_position_table(path, content or "cogging"), path
    if content is not None:
        raise IlcpmacError(f"--content selects what of a result to export; {path} is a campaign's compensation")
    return Compensation.read(path), path


def export_source(source: str | Path, out_dir: str | Path, fmt: str, c_type: str = "int16",
                  content: str | None = None, torque_constant_nm_per_a: float | None = None,
                  rated_torque_nm: float | None = None) -> Exported:
    """``ilcpmac export SOURCE``: `export` of what ``source`` holds (`read_source`: a run directory, a
    compensation.json or a result JSON) into ``out_dir``; the arguments and errors are `read_source`'s and
    `export`'s."""
    record, path = read_source(source, content)
    return export(record, Path(out_dir), fmt, c_type, str(path), torque_constant_nm_per_a, rated_torque_nm,
                  RunLimits.of(path))
