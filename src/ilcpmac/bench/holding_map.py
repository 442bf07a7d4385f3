"""Drives' own holding maps as a map folder: ``ilcpmac import MAP... --map MAPPING.toml --out MAP_FOLDER`` with
``[log] kind = "holding-map"``.

A drive's anticogging calibration holds the rotor still at position after position and records the q-axis current
that holds it there: ODrive's ``cogging_map`` (a float per encoder count, zeros where it did not measure) is one,
and so is any per-count array of holding currents or torques a script records. Such a map is one direction's: the
static friction at each position is in it, not separable (a standstill scan forward and back separates it,
`ilcpmac.bench.standstill`). `import_holding_maps` reads one map or several of one motor (npy, CSV or a JSON
list, bounded, UTF-8 for text; `read_map_file`), keeps the measured entries (`measured_entries`: the non-zero
ones, or every k-th), judges them against the mapping's [limits] as a scan's holding torques are
(`holding_problem`), and writes them as a map folder (`MAP_FILE`, `MAP_DATA_FILE`) that `read_holding_maps`
reads back and `ilcpmac.identify.map_decomposition` decomposes (docs/drive-maps.md). Every problem raises
`ConfigError` (the mapping, naming its key) or `BenchFormatError` (a file, naming its entry, line or key), one
line each.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ilcpmac.bench.fastcsv import format_rows, parse_rows
from ilcpmac.bench.format import BENCH_FILE, MAX_HEADER_BYTES, loadtxt_problem
from ilcpmac.bench.logs import ImportLimits, beyond_limit, utf8_text
from ilcpmac.bench.moteus import q_torque_constant
from ilcpmac.bench.standstill import SCAN_FILE, holding_problem
from ilcpmac.config import BenchSettings
from ilcpmac.core.errors import BenchFormatError, ConfigError
from ilcpmac.core.files import atomic_write, read_bounded
from ilcpmac.core.records import MAX_CURRENT_A, MAX_TORQUE_NM, MOTOR_RANGES
from ilcpmac.core.schema import (
    field_like,
    in_range,
    length_in,
    parse_section,
    read_toml,
    section_toml,
    setting,
    shown,
    unique_keys,
)

__all__ = ["HOLDING_MAP", "MAP_DATA_FILE", "MAP_FILE", "MAX_MAPS", "MIN_POINTS", "QUANTITY_UNITS", "HoldingMapLog",
           "HoldingMapMapping", "HoldingMaps", "MapSettings", "holding_map_mapping", "import_holding_maps",
           "import_lines", "measured_entries", "read_holding_maps", "read_map_file", "write_holding_maps"]

#: [log] kind of a mapping for holding maps
HOLDING_MAP = "holding-map"
#: the file that makes a folder a map folder, and the measured values' file beside it
MAP_FILE = "holding_map.toml"
MAP_DATA_FILE = "holding_map.csv"
#: what a map holds -> its unit
QUANTITY_UNITS = {"current": "A", "torque": "N m"}
#: most entries of a map (a per-count map of the finest encoder a bench has), and most maps of one import
MAX_ENTRIES = int(MOTOR_RANGES["counts_per_rev"][1])
MAX_MAPS = 64
#: fewest measured entries of a map: 8 points resolve orders 1-3 and leave the noise a few orders
MIN_POINTS = 8
#: largest input files: an npy of doubles and its header; a text file of numbers of up to 40 characters per entry
_MAX_NPY_BYTES = 8 * MAX_ENTRIES + 4096
_MAX_TEXT_BYTES = 40 * MAX_ENTRIES + MAX_HEADER_BYTES
#: the map folder's columns: the position (counts of counts_per_rev) and one value column per map
_POSITION = "position"
_DECIMALS = (6, 9)
#: a measured position off the even grid by more than this many counts is a folder edited by hand
_GRID_TOLERANCE = 1e-3
_SUFFIXES = (".npy", ".csv", ".json")


def _quantity(x: str) -> bool:
    return x in QUANTITY_UNITS


@dataclass(frozen=True)
class HoldingMapLog:
    """[log] of a mapping for holding maps: the maps' layout and units (docs/drive-maps.md)."""

    kind: str = setting(lambda x: x == HOLDING_MAP, f"\"{HOLDING_MAP}\": a drive's holding map (docs/drive-maps.md)",
                        HOLDING_MAP)
    counts_per_rev: int | None = setting(in_range(*MOTOR_RANGES["counts_per_rev"]), "entries of a map per "
                                         "revolution, entry 0 at count 0 (without it, [bench] counts_per_rev)", None)
    measured_every: int | None = setting(in_range(1, MAX_ENTRIES), "the measured entries are every k-th, from "
                                         "measured_first (1: all); without it, the non-zero entries", None)
    measured_first: int = setting(in_range(0, MAX_ENTRIES - 1), "the first measured entry, with measured_every", 0)
    quantity: str = setting(_quantity, '"current" (the holding q-axis current, amplitude-invariant) or "torque" '
                            "(the holding torque)", "current")
    value_per_unit: float = setting(in_range(1e-12, 1e12), "A (or N m) per unit of the file's values, within "
                                    "[1e-12, 1e12] (1e-3 for mA)", 1.0)
    torque_constant_nm_per_a: float | None = setting(
        in_range(0.0, 1e3, low_open=True), "k_q, N m per A of q-axis current (ODrive's motor.config.torque_constant); "
        'for a current map, instead of a [bench] back-EMF table', None)
    column: str | None = setting(length_in(1, 200), "a CSV map's column, named on its first line; without it, one "
                                 "value per line and no header", None)


@dataclass(frozen=True)
class HoldingMapMapping:
    """A parsed mapping for holding maps: the motor of [bench], the maps' [log], the torque constant k_q (None
    for a torque map) and [limits]."""

    path: Path
    pole_pairs: int
    slots: int
    counts_per_rev: int
    layout: HoldingMapLog
    torque_constant_nm_per_a: float | None
    limits: ImportLimits = ImportLimits()

    @property
    def entries_per_rev(self) -> int:
        """Entries of one map: [log] counts_per_rev, or [bench]'s."""
        return self.layout.counts_per_rev or self.counts_per_rev


def holding_map_mapping(data: dict, bench: BenchSettings, limits: ImportLimits, path: Path,
                        backemf_nm_per_a: np.ndarray | None = None) -> HoldingMapMapping:
    """The mapping for holding maps in the TOML ``data`` of ``path``, [bench] and [limits] parsed already;
    ``backemf_nm_per_a`` the [bench] back-EMF table when it gives one (k_q = 3/2 k_1, `q_torque_constant`).

    [log] is `HoldingMapLog`; [[points]] and [scan] are refused (a map has no operating point, and its sensor
    errors are what the decomposition finds); a current map needs a torque constant, from [log]
    torque_constant_nm_per_a or the back-EMF table, not both; a torque map neither. Each problem raises
    `ConfigError` naming ``path`` and the key.
    """
    layout = parse_section(data["log"], HoldingMapLog, str(path), "log")
    for table in ("points", "scan"):
        if table in data:
            raise ConfigError(f"{path}: [{table}]: not for holding maps (a map has no operating point, and its sensor "
                              "errors are what its decomposition finds)")
    if layout.measured_every is None and layout.measured_first:
        raise ConfigError(f"{path}: [log] measured_first: only with measured_every")
    if layout.column is not None and "," in layout.column:
        raise ConfigError(f"{path}: [log] column: {shown(layout.column)} holds a comma, the CSV's delimiter")
    given = layout.torque_constant_nm_per_a
    if layout.quantity == "torque":
        if given is not None or backemf_nm_per_a is not None:
            raise ConfigError(f'{path}: [log] torque_constant_nm_per_a, [bench] back-EMF: not for a map of holding '
                              'torques (quantity = "torque")')
        k_q = None
    elif (given is None) == (backemf_nm_per_a is None):
        raise ConfigError(f"{path}: [log] torque_constant_nm_per_a: a map of holding currents needs the torque "
                          "constant k_q: give it, or a [bench] back-EMF table (k_q = 3/2 k_1), not both")
    else:
        k_q = given if backemf_nm_per_a is None else q_torque_constant(backemf_nm_per_a, bench.pole_pairs)
    return HoldingMapMapping(path, bench.pole_pairs, bench.slots, bench.counts_per_rev, layout, k_q, limits)


@dataclass(frozen=True)
class MapSettings:
    """[map] of a map folder's holding_map.toml: the motor, what the maps hold and where they came from."""

    pole_pairs: int = field_like(BenchSettings, "pole_pairs")
    slots: int = field_like(BenchSettings, "slots")
    counts_per_rev: int = field_like(BenchSettings, "counts_per_rev")
    files: tuple[str, ...] = setting(length_in(1, MAX_MAPS), f"the imported files, one per map, 1..{MAX_MAPS}",
                                     dataclasses.MISSING)
    quantity: str = field_like(HoldingMapLog, "quantity", default="current")
    torque_constant_nm_per_a: float | None = field_like(HoldingMapLog, "torque_constant_nm_per_a", default=None)


@dataclass(frozen=True)
class HoldingMaps:
    """One motor's holding maps on their measured positions (a map folder in memory).

    Attributes
    ----------
    settings : MapSettings
    position_counts : ndarray, shape (m,)
        The measured positions, counts of ``settings.counts_per_rev``: an even grid of m points a revolution,
        p_0 + j counts_per_rev / m, p_0 in [0, counts_per_rev / m).
    values : ndarray, shape (n, m)
        Each map's holding current (A) or torque (N m) at those positions: what the drive applies as its
        feed-forward, the position torque negated (plus the static friction).
    """

    settings: MapSettings
    position_counts: np.ndarray
    values: np.ndarray

    @property
    def unit(self) -> str:
        """The values' unit: "A" or "N m"."""
        return QUANTITY_UNITS[self.settings.quantity]

    @property
    def nm_per_unit(self) -> float:
        """N m per unit of the values: k_q for currents, 1 for torques."""
        return self.settings.torque_constant_nm_per_a or 1.0

    @property
    def cogging_order(self) -> int:
        """lcm(slots, 2 pole_pairs)."""
        return math.lcm(self.settings.slots, 2 * self.settings.pole_pairs)


# ---------------------------------------------------------------- reading a drive's map


def read_map_file(path: Path, entries: int, column: str | None = None) -> np.ndarray:
    """The ``entries`` values of a map file, as the file holds them (floats, unscaled).

    ``.npy``: a one-dimensional array of real numbers (no pickles); ``.csv``: one number per line, or with
    ``column`` the column of that name under a header line; ``.json``: a list of numbers. Read bounded,
    text in UTF-8 (`utf8_text`). Raises `BenchFormatError` naming the file and the entry or line: another
    suffix, size or shape, a value that is not a finite number.
    """
    suffix = path.suffix.lower()
    if suffix not in _SUFFIXES:
        raise BenchFormatError(f"{path}: a holding map is {', '.join(_SUFFIXES)}, not {shown(path.suffix)}")
    if suffix == ".npy":
        values = _npy_values(path)
    else:
        text = utf8_text(path, read_bounded(path, _MAX_TEXT_BYTES, BenchFormatError))
        values = _json_values(path, text) if suffix == ".json" else _csv_values(path, text, column)
    if values.shape != (entries,):
        raise BenchFormatError(f"{path}: holds {values.size} values ({'x'.join(map(str, values.shape))}), one map "
                               f"needs {entries}: one per entry of a revolution ([log] counts_per_rev, or [bench]'s)")
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise BenchFormatError(f"{path}: entry {bad[0]}: {values[bad[0]]} is not a finite number")
    return values


def _npy_values(path: Path) -> np.ndarray:
    raw = read_bounded(path, _MAX_NPY_BYTES, BenchFormatError)
    try:
        values = np.load(io.BytesIO(raw), allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        raise BenchFormatError(f"{path}: not a NumPy array file ({str(e).splitlines()[0][:120]})") from None
    if not isinstance(values, np.ndarray) or values.dtype.kind not in "iuf":
        raise BenchFormatError(f"{path}: holds {getattr(values, 'dtype', type(values).__name__)} values, not real "
                               "numbers")
    return values.astype(float)


def _json_values(path: Path, text: bytes) -> np.ndarray:
    try:
        data = json.loads(text.decode("utf-8"), object_pairs_hook=unique_keys)
    except UnicodeDecodeError:
        raise BenchFormatError(f"{path}: not UTF-8 text") from None
    except json.JSONDecodeError as e:
        raise BenchFormatError(f"{path}: line {e.lineno}: not JSON ({e.msg})") from None
    except (ValueError, RecursionError):
        raise BenchFormatError(f"{path}: not a JSON list of numbers") from None
    if not isinstance(data, list):
        raise BenchFormatError(f"{path}: holds a JSON {type(data).__name__}, not a list of numbers")
    bad = next((i for i, v in enumerate(data) if isinstance(v, bool) or not isinstance(v, (int, float))), None)
    if bad is not None:
        raise BenchFormatError(f"{path}: entry {bad}: {shown(data[bad])} is not a number")
    try:
        return np.asarray(data, dtype=float)
    except OverflowError:
        raise BenchFormatError(f"{path}: a value beyond a double's range") from None


def _csv_values(path: Path, text: bytes, column: str | None) -> np.ndarray:
    """One column of a CSV: the only one (no header), or ``column`` under the header line."""
    header_lines, names, index, body = 0, ["value"], 0, text
    if column is not None:
        end = text.find(b"\n", 0, MAX_HEADER_BYTES)
        if end < 0:
            raise BenchFormatError(f"{path}: line 1: no end of the header line in {MAX_HEADER_BYTES} bytes")
        try:
            names = [n.strip().strip('"') for n in text[:end].decode("utf-8").strip().split(",")]
        except UnicodeDecodeError:
            raise BenchFormatError(f"{path}: line 1: the column names are not UTF-8 text") from None
        if column not in names:
            raise BenchFormatError(f"{path}: line 1: no column {shown(column)} (the header has {shown(names)})")
        header_lines, index, body = 1, names.index(column), text[end + 1:]
    if not body.strip():
        raise BenchFormatError(f"{path}: no values{' under its header line' if column else ''}")
    rows = parse_rows(body, len(names), MAX_ENTRIES)
    if rows is None:
        try:
            rows = np.loadtxt(io.BytesIO(body), delimiter=",", ndmin=2, dtype=float, max_rows=MAX_ENTRIES + 1,
                              comments=None)
        except ValueError as e:
            raise BenchFormatError(f"{path}: {loadtxt_problem(e, names, ',', header_lines)}") from None
    if rows.shape[1] != len(names):
        raise BenchFormatError(f"{path}: line {header_lines + 1} has {rows.shape[1]} fields, "
                               f"{'the header has' if column else 'a map without [log] column has'} {len(names)}")
    return rows[:, index]


def measured_entries(values: np.ndarray, layout: HoldingMapLog, path: Path) -> np.ndarray:
    """The indices of a map's measured entries: every [log] measured_every-th from measured_first, or the
    non-zero entries, which must then be every k-th for one k dividing the map (ODrive's). Raises
    `BenchFormatError` naming the file and the first entry off the grid (a zero on it may be a measured 0: give
    measured_every)."""
    n = values.size
    if layout.measured_every is not None:
        every, first = layout.measured_every, layout.measured_first
        if n % every or first >= every:
            raise BenchFormatError(f"{path}: every {every}th entry from entry {first} is no even grid of the map's {n} "
                                   f"entries ([log] measured_every must divide {n}, measured_first be below it)")
        return np.arange(first, n, every)
    measured = np.flatnonzero(values)
    if measured.size < 2:
        raise BenchFormatError(f"{path}: {measured.size} non-zero entries: no map (give [log] measured_every when "
                               "zeros are measured values)")
    every = math.gcd(n, *np.diff(measured).tolist())
    grid = np.arange(measured[0] % every, n, every)
    missing = np.setdiff1d(grid, measured)
    if missing.size:
        raise BenchFormatError(f"{path}: entry {missing[0]} is 0 on the grid of every {every}th entry from "
                               f"{grid[0]} ({missing.size} such): a measured 0 or a gap? Give [log] measured_every = "
                               f"{every} to take the zeros as measured")
    return grid


def _map_values(path: Path, mapping: HoldingMapMapping) -> tuple[np.ndarray, np.ndarray]:
    """One map file's measured entries and their values in A or N m, judged against the bounds and [limits]."""
    layout = mapping.layout
    raw = read_map_file(path, mapping.entries_per_rev, layout.column)
    entries = measured_entries(raw, layout, path)
    if entries.size < MIN_POINTS:
        raise BenchFormatError(f"{path}: {entries.size} measured entries; a map needs {MIN_POINTS} or more")
    values = raw[entries] * layout.value_per_unit
    current = layout.quantity == "current"
    bound = MAX_CURRENT_A if current else MAX_TORQUE_NM
    beyond = np.flatnonzero(np.abs(values) > bound)
    if beyond.size:
        raise BenchFormatError(f"{path}: entry {entries[beyond[0]]}: {values[beyond[0]]:.4g} "
                               f"{QUANTITY_UNITS[layout.quantity]} beyond +-{bound:g} once scaled (wrong [log] "
                               f"value_per_unit in {mapping.path}?)")
    found = beyond_limit(values, mapping.limits.max_current_a) if current else None
    if found is not None:
        raise BenchFormatError(f"{path}: entry {entries[found[0]]}: a holding current of {values[found[0]]:.4g} A, "
                               f"beyond [limits] max_current_a = {mapping.limits.max_current_a:g} A (of "
                               f"{mapping.path}, its default if not given): {found[1]}")
    problem = holding_problem(values * (mapping.torque_constant_nm_per_a or 1.0), mapping.limits, mapping.path)
    if problem is not None:
        raise BenchFormatError(f"{path}: entry {entries[problem[0]]}: {problem[1]}")
    if np.all(values == values[0]):
        raise BenchFormatError(f"{path}: every measured entry holds {values[0]:g}: no position torque, nothing to "
                               "decompose")
    return entries, values


def import_holding_maps(files: list[Path], mapping: HoldingMapMapping, out: Path) -> HoldingMaps:
    """Import one motor's holding maps and write them as the map folder ``out`` (`write_holding_maps`).

    Each file is one map (`read_map_file`, `measured_entries`), its values times [log] value_per_unit in A
    (or N m), every one within [limits] max_current_a and its holding torque k_q i within max_torque_nm
    (`holding_problem`), not all the same. All maps must have the same measured entries; entry e sits at count
    e [bench] counts_per_rev / entries. Nothing is written unless every map imports; a folder that holds a
    map, scan or bench already is refused.
    """
    for name in (MAP_FILE, SCAN_FILE, BENCH_FILE):
        if (out / name).exists():
            raise BenchFormatError(f"{out}: holds a {name} already (refused: choose a new folder)")
    if not 1 <= len(files) <= MAX_MAPS:
        raise BenchFormatError(f"{len(files)} maps given: an import takes 1 to {MAX_MAPS} maps of one motor")
    read = [(path, *_map_values(path, mapping)) for path in files]
    first_path, entries, _ = read[0]
    for k, (path, other, values) in enumerate(read[1:], start=1):
        if not np.array_equal(other, entries):
            raise BenchFormatError(f"{path}: measures {other.size} entries from entry {other[0]}, {first_path} "
                                   f"{entries.size} from entry {entries[0]}: the maps of one import measure the same "
                                   "entries (import them apart)")
        same = next((earlier for earlier, _, before in read[:k] if np.array_equal(before, values)), None)
        if same is not None:
            raise BenchFormatError(f"{path}: the same values as {same}: a repeat measures the motor again (one file "
                                   "given twice?), or the maps' scatter measures no noise")
    settings = MapSettings(mapping.pole_pairs, mapping.slots, mapping.counts_per_rev,
                           tuple(path.name for path, _, _ in read), mapping.layout.quantity,
                           mapping.torque_constant_nm_per_a)
    maps = HoldingMaps(settings, entries * (mapping.counts_per_rev / mapping.entries_per_rev),
                       np.stack([values for _, _, values in read]))
    write_holding_maps(out, maps)
    return maps


def import_lines(maps: HoldingMaps, out: Path) -> list[str]:
    """What ``ilcpmac import`` prints after `import_holding_maps`."""
    s, m = maps.settings, maps.values.shape[1]
    constant = "" if s.torque_constant_nm_per_a is None else f", k_q = {s.torque_constant_nm_per_a:.4g} N m / A"
    return [f"{len(s.files)} holding map{'s' if len(s.files) > 1 else ''} -> {MAP_DATA_FILE}: {m} measured positions "
            f"a revolution of {s.counts_per_rev} counts, from count {maps.position_counts[0]:g}, holding "
            f"{s.quantity} in {maps.unit}{constant}",
            "one direction: the static friction is in the map, not separable (docs/drive-maps.md)",
            f"wrote {MAP_DATA_FILE} and {MAP_FILE} to {out}"]


# ---------------------------------------------------------------- the map folder


def write_holding_maps(folder: Path, maps: HoldingMaps) -> None:
    """Write the map folder: holding_map.csv (``position`` and ``map_1`` ... in A or N m), then holding_map.toml."""
    folder.mkdir(parents=True, exist_ok=True)
    header = ",".join([_POSITION] + [f"map_{k}" for k in range(1, maps.values.shape[0] + 1)])
    body = format_rows(np.column_stack([maps.position_counts, maps.values.T]),
                       np.array([_DECIMALS[0]] + [_DECIMALS[1]] * maps.values.shape[0]))
    atomic_write(folder / MAP_DATA_FILE, header.encode() + b"\n" + body)
    atomic_write(folder / MAP_FILE, "[map]\n" + section_toml(maps.settings))


def read_holding_maps(folder: str | Path) -> HoldingMaps:
    """A map folder (`write_holding_maps`), checked: [map] (`MapSettings`), one value column per file it names,
    positions on an even grid of one revolution, values finite, within a bench's bounds and not all the same;
    each problem raises `BenchFormatError` naming the file and the key or line."""
    folder = Path(folder)
    path = folder / MAP_FILE
    data = read_toml(path, BenchFormatError)
    if set(data) != {"map"}:
        raise BenchFormatError(f"{path}: holds the table [map] alone, got {shown(sorted(data))}")
    settings = parse_section(data["map"], MapSettings, str(path), "map", error=BenchFormatError)
    if (settings.quantity == "current") != (settings.torque_constant_nm_per_a is not None):
        raise BenchFormatError(f"{path}: [map] torque_constant_nm_per_a: given when, and only when, quantity = "
                               '"current"')
    samples = folder / MAP_DATA_FILE
    text = utf8_text(samples, read_bounded(samples, _MAX_TEXT_BYTES * (1 + len(settings.files)), BenchFormatError))
    columns = [_POSITION] + [f"map_{k}" for k in range(1, len(settings.files) + 1)]
    end = text.find(b"\n", 0, MAX_HEADER_BYTES)
    if end < 0 or text[:end].decode("utf-8", "replace").strip().split(",") != columns:
        raise BenchFormatError(f"{samples}: line 1 must be {','.join(columns)} (one map per file of {path.name})")
    rows = parse_rows(text[end + 1:], len(columns), MAX_ENTRIES)
    if rows is None:
        raise BenchFormatError(f"{samples}: not {len(columns)} plain decimal numbers on every line after the first")
    if rows.shape[0] > MAX_ENTRIES or rows.shape[0] < MIN_POINTS:
        raise BenchFormatError(f"{samples}: {rows.shape[0]} rows; a map holds {MIN_POINTS} to {MAX_ENTRIES}")
    cpr, m = settings.counts_per_rev, rows.shape[0]
    position = rows[:, 0]
    grid = position[0] + np.arange(m) * (cpr / m)
    off = np.flatnonzero(~(np.abs(position - grid) <= _GRID_TOLERANCE))
    if off.size or not 0 <= position[0] < cpr / m:
        line = 2 + (off[0] if off.size else 0)
        raise BenchFormatError(f"{samples}: line {line}: position {position[line - 2]:g} is off the even grid of {m} "
                               f"points in {cpr} counts from {position[0]:g} (from [0, {cpr / m:g}))")
    values = rows[:, 1:].T
    bound = MAX_CURRENT_A if settings.quantity == "current" else MAX_TORQUE_NM
    beyond = np.argwhere(np.abs(values) > bound)
    if beyond.size:
        k, j = beyond[0]
        raise BenchFormatError(f"{samples}: line {j + 2}: map_{k + 1} beyond +-{bound:g}")
    constant = np.flatnonzero(np.all(values == values[:, :1], axis=1))
    if constant.size:
        raise BenchFormatError(f"{samples}: map_{constant[0] + 1} holds the same value at every position: nothing to "
                               "decompose")
    return HoldingMaps(settings, grid, values)
