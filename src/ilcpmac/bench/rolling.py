"""Rolling-log folders: drive logs kept row by row, as they were recorded (docs/rolling-logs.md).

A log that cannot be resampled once per encoder count (a position that stick-slips or dithers within a lap, less
than whole revolutions, rows too sparse for the counts: 100 Hz telemetry, a host polling a drive with coarse
stamps) is kept as a *rolling folder*, on the model of a scan folder (`ilcpmac.bench.standstill`): bench.toml
([motor] and optional [sensors], no [[trials]]), backemf.csv, and

- ``rolling.toml``: one table [rolling] (`RollingSettings`): the samples' file, what the currents are, the
  logged current's filter if the mapping stated it, and per log what the import kept of it;
- ``rolling.csv``: one row per logged row, in acquisition order: ``time`` (s), ``position`` (mechanical, in counts
  of [motor] counts_per_rev, real-valued and unwrapped, count 0 at the back-EMF table's), ``segment`` (the log it
  came from, 1, 2, ...: time runs on within a segment only), then the q-axis current ``i_q`` or the phase
  currents ``i_a``, ``i_b``, ``i_c`` (A), and the torque ``torque`` (N m) if the log had one.

`read_rolling` reads a folder, `write_rolling` writes one, `steady_rows` is the rule that leaves a start and an
end transient out, `coverage` what a log covers of a revolution. Every problem of a file raises
`BenchFormatError` naming the file and the key, line or sample.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ilcpmac.bench.fastcsv import format_rows
from ilcpmac.bench.format import BENCH_FILE, bench_toml_text, read_bench_head, write_backemf_csv
from ilcpmac.bench.logs import MAX_LOG_ROWS, LogLayout, column_names, read_log
from ilcpmac.core.errors import BenchFormatError, ConfigError
from ilcpmac.core.files import atomic_write
from ilcpmac.core.records import MAX_CURRENT_A, MAX_TORQUE_NM, MotorInfo, SensorCalibration
from ilcpmac.core.schema import in_range, param, parse_section, read_toml, section_toml, setting, shown

__all__ = ["CURRENT_KINDS", "Coverage", "MAX_SEGMENTS", "POSITION_DECIMALS", "ROLLING_DATA_FILE", "ROLLING_FILE",
           "Rolling", "RollingData", "RollingSettings", "SETTLE_WINDOWS", "TIME_DECIMALS", "check_rolling", "coverage",
           "read_rolling", "rolling_seconds", "steady_rows", "write_rolling"]

#: the file that makes a folder a rolling folder, and the samples' file it names by default
ROLLING_FILE = "rolling.toml"
ROLLING_DATA_FILE = "rolling.csv"
#: columns of rolling.csv: always these, then the currents (`I_Q_COLUMN` or `PHASE_COLUMNS`), then the torque
BASE_COLUMNS = ("time", "position", "segment")
I_Q_COLUMN = "i_q"
PHASE_COLUMNS = ("i_a", "i_b", "i_c")
TORQUE_COLUMN = "torque"
#: what the logged currents are ([log] current of the mapping)
CURRENT_KINDS = ("commanded", "measured")
#: the decimals rolling.csv keeps of its times (s) and positions (counts): what a quantum read off them must pass
TIME_DECIMALS, POSITION_DECIMALS = 7, 6
#: most logs one rolling folder holds
MAX_SEGMENTS = 256
#: the fewest rows a segment keeps
MIN_SEGMENT_ROWS = 16
#: windows a log is cut into to find where its speed has settled (`steady_rows`), the fewest rows per window, how
#: many robust standard deviations of the windows' speeds a transient's speed lies off their median, and the
#: smallest such offset relative to the median speed
SETTLE_WINDOWS = 40
SETTLE_MIN_ROWS = 8
SETTLE_SPREADS = 4.0
SETTLE_RELATIVE = 0.1


def _names(x) -> bool:
    return all(isinstance(v, str) and v for v in x)


@dataclass(frozen=True)
class RollingSettings:
    """[rolling] of rolling.toml: the samples' file, the currents, and per log (the parallel lists, one entry per
    segment) what the import kept: the log's name, the file lines of the first and last row kept, the seconds
    left out at its start and its end (`steady_rows`)."""

    file: str = setting(lambda x: bool(x) and "/" not in x and "\\" not in x and x not in (".", ".."),
                        "the samples' file, in the folder", ROLLING_DATA_FILE)
    current: str = setting(lambda x: x in CURRENT_KINDS, '"commanded" (references) or "measured" (by the '
                           'controller)', "measured")
    current_filter_s: float | None = setting(in_range(0.0, 10.0), "time constant of a first-order filter the drive "
                                             "applied to the logged current, s; without it, fitted from the data",
                                             None)
    angle_offset_rad: float = setting(in_range(-2 * math.pi, 2 * math.pi), "theta_e = pole_pairs * theta + "
                                      "angle_offset_rad in the inverse Park transform of i_q", 0.0)
    logs: tuple[str, ...] = param(_names, "each segment's log, by file name", parallel=True, default=())
    first_lines: tuple[int, ...] = param(in_range(1, 2**40), "each segment's first row kept, as a line of its log",
                                         parallel=True, default=())
    last_lines: tuple[int, ...] = param(in_range(1, 2**40), "each segment's last row kept, as a line of its log",
                                        parallel=True, default=())
    cut_start_s: tuple[float, ...] = param(in_range(0.0, 1e9), "seconds left out at each log's start (its speed "
                                           "not yet settled)", parallel=True, default=())
    cut_end_s: tuple[float, ...] = param(in_range(0.0, 1e9), "seconds left out at each log's end", parallel=True,
                                         default=())


@dataclass(frozen=True)
class RollingData:
    """A rolling log's samples in acquisition order.

    Attributes
    ----------
    time_s : ndarray, shape (n,)
        Strictly increasing within each segment.
    position_counts : ndarray, shape (n,)
        Mechanical position in counts of [motor] counts_per_rev, unwrapped, count 0 at the back-EMF table's 0.
    segment : ndarray of int, shape (n,)
        The log each sample came from, 1, 2, ..., non-decreasing.
    i_q_a : ndarray, shape (n,), or None
        The q-axis current (amplitude-invariant, i_d = 0), A; or ``currents_a``.
    currents_a : ndarray, shape (n, 3), or None
        The phase currents, A.
    torque_nm : ndarray, shape (n,), or None
        A torque column, N m, if the log had one.
    """

    time_s: np.ndarray
    position_counts: np.ndarray
    segment: np.ndarray
    i_q_a: np.ndarray | None = None
    currents_a: np.ndarray | None = None
    torque_nm: np.ndarray | None = None

    def rows(self, keep: np.ndarray) -> RollingData:
        """The samples where boolean ``keep`` holds."""
        def pick(v: np.ndarray | None) -> np.ndarray | None:
            return None if v is None else v[keep]

        return RollingData(self.time_s[keep], self.position_counts[keep], self.segment[keep], pick(self.i_q_a),
                           pick(self.currents_a), pick(self.torque_nm))

    @property
    def segments(self) -> list[slice]:
        """Each segment's rows."""
        edges = np.flatnonzero(np.diff(self.segment)) + 1
        bounds = np.concatenate([[0], edges, [self.segment.size]])
        return [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]


@dataclass(frozen=True)
class Rolling:
    """A rolling folder in memory: the motor, its back-EMF table (N m / A, shape (counts_per_rev, 3)), the
    calibration the log ran with, [rolling] and the samples, read from ``settings.file`` in the folder."""

    path: Path
    motor: MotorInfo
    backemf_nm_per_a: np.ndarray
    sensors: SensorCalibration | None
    settings: RollingSettings
    data: RollingData


@dataclass(frozen=True)
class Coverage:
    """What a log covers of one revolution, per count.

    Attributes
    ----------
    revolutions : float
        The position's span (largest minus smallest), revolutions.
    counts_visited : int
        Counts of a revolution a sample lies within half a count of, or that the position passes between two
        samples.
    largest_gap_counts : int
        The longest run of counts no sample lies at or passes over (periodic).
    counts_per_rev : int
    """

    revolutions: float
    counts_visited: int
    largest_gap_counts: int
    counts_per_rev: int

    def text(self) -> str:
        """``"0.996 revolutions, 8160 of 8192 counts (largest gap 32 counts)"``."""
        gap = "" if not self.largest_gap_counts else f" (largest gap {self.largest_gap_counts} counts)"
        return (f"{self.revolutions:.3g} revolutions, {self.counts_visited} of {self.counts_per_rev} counts "
                f"covered{gap}")


def coverage(position_counts: np.ndarray, counts_per_rev: int, segment: np.ndarray | None = None) -> Coverage:
    """The `Coverage` of unwrapped positions (in counts): a count is covered by a sample within half a count of
    it, or by the motion between two successive samples of one segment passing over it."""
    cpr = counts_per_rev
    same = np.ones(position_counts.size - 1, bool) if segment is None else segment[1:] == segment[:-1]
    low = np.minimum(position_counts[:-1], position_counts[1:])[same]
    high = np.maximum(position_counts[:-1], position_counts[1:])[same]
    first = np.ceil(np.concatenate([low, position_counts]) - 0.5).astype(np.int64)
    length = np.floor(np.concatenate([high, position_counts]) + 0.5).astype(np.int64) - first + 1
    edges = np.zeros(2 * cpr + 1, np.int64)
    np.add.at(edges, first % cpr, 1)
    np.add.at(edges, first % cpr + np.clip(length, 0, cpr), -1)
    passes = np.cumsum(edges)[:2 * cpr]
    hit = (passes[:cpr] + passes[cpr:]) > 0
    gap = 0
    if not hit.all():
        rolled = np.roll(hit, -int(np.argmax(hit)))
        change = np.flatnonzero(np.diff(np.concatenate([rolled, [True]]).astype(np.int8)))
        gap = int(np.max(change[1::2] - change[::2]))
    span = float(position_counts.max() - position_counts.min()) / cpr
    return Coverage(span, int(hit.sum()), gap, cpr)


def steady_rows(time_s: np.ndarray, position_counts: np.ndarray) -> tuple[int, int]:
    """The first and last row of a log's steady part: the rows before its speed has settled, and after it leaves
    its steady value, left out.

    The log is cut into `SETTLE_WINDOWS` windows of equal duration (at least `SETTLE_MIN_ROWS` rows each); each
    window's speed is its position change over its duration. A window is off the steady speed when its speed lies
    more than `SETTLE_SPREADS` robust standard deviations (1.4826 times the median absolute deviation) of the
    windows' speeds, and more than `SETTLE_RELATIVE` of their median, from their median; the leading and the
    trailing windows off it are left out, as far as the first (last) window on it. A log whose windows' median
    speed is zero (a position that dithers) and a log too short for the windows keep every row.
    """
    n = time_s.size
    windows = min(SETTLE_WINDOWS, n // SETTLE_MIN_ROWS)
    if windows < 4:
        return 0, n - 1
    edges = np.linspace(time_s[0], time_s[-1], windows + 1)
    speed = np.diff(np.interp(edges, time_s, position_counts)) / np.diff(edges)
    median = float(np.median(speed))
    if median == 0.0:
        return 0, n - 1
    spread = 1.4826 * float(np.median(np.abs(speed - median)))
    steady = np.abs(speed - median) <= max(SETTLE_SPREADS * spread, SETTLE_RELATIVE * abs(median))
    on = np.flatnonzero(steady)
    if not on.size:
        return 0, n - 1
    first = int(np.searchsorted(time_s, edges[on[0]], side="left"))
    last = int(np.searchsorted(time_s, edges[on[-1] + 1], side="right")) - 1
    return first, max(last, first)


# ---------------------------------------------------------------- checks, reading and writing


def check_rolling(data: RollingData, where: str) -> None:
    """Segments numbered 1, 2, ... in order, each of `MIN_SEGMENT_ROWS` rows or more with its time increasing;
    positions within 2^53 counts; one kind of current; currents within 1e4 A and a torque within 1e5 N m, not the
    same at every sample (a constant or empty file: nothing to identify)."""
    n = data.time_s.size
    if n > MAX_LOG_ROWS * MAX_SEGMENTS:
        raise BenchFormatError(f"{where}: {n} samples; a rolling folder holds at most {MAX_LOG_ROWS * MAX_SEGMENTS}")
    if (data.i_q_a is None) == (data.currents_a is None):
        raise BenchFormatError(f"{where}: needs the q-axis current or the phase currents, exactly one")
    if n == 0 or data.segment[0] != 1 or np.any(~np.isin(np.diff(data.segment), (0, 1))):
        raise BenchFormatError(f"{where}: segment must start at 1 and go up by 1 from one log to the next")
    if data.segment[-1] > MAX_SEGMENTS:
        raise BenchFormatError(f"{where}: {int(data.segment[-1])} segments; a rolling folder holds at most "
                               f"{MAX_SEGMENTS}")
    for rows in data.segments:
        if rows.stop - rows.start < MIN_SEGMENT_ROWS:
            raise BenchFormatError(f"{where}: segment {int(data.segment[rows.start])} holds {rows.stop - rows.start} "
                                   f"samples; a segment needs {MIN_SEGMENT_ROWS} or more")
        back = np.flatnonzero(np.diff(data.time_s[rows]) <= 0)
        if back.size:
            raise BenchFormatError(f"{where}: line {rows.start + back[0] + 3}: time does not increase")
    currents = data.i_q_a if data.i_q_a is not None else data.currents_a
    assert currents is not None
    checks = [("position", data.position_counts, 2.0**53), ("current", np.abs(currents).reshape(n, -1).max(axis=1),
                                                             MAX_CURRENT_A)]
    if data.torque_nm is not None:
        checks.append(("torque", data.torque_nm, MAX_TORQUE_NM))
    for name, values, bound in checks:
        bad = np.flatnonzero(~(np.abs(values) <= bound))
        if bad.size:
            raise BenchFormatError(f"{where}: line {bad[0] + 2}: {name} beyond +-{bound:g} (wrong unit or scale?)")
    if np.all(currents == currents[0]):
        raise BenchFormatError(f"{where}: the currents are the same at every sample: nothing to identify (an empty or "
                               "constant file?)")


def read_rolling(folder: str | Path) -> Rolling:
    """Read a rolling folder: bench.toml (no [[trials]]) and backemf.csv as `read_bench_head` checks them,
    rolling.toml and its samples (`check_rolling`)."""
    folder = Path(folder)
    head = read_bench_head(folder)
    path = folder / ROLLING_FILE
    if head.entries is not None:
        raise BenchFormatError(f"{folder / BENCH_FILE}: a rolling folder lists no [[trials]] ({ROLLING_FILE} names "
                               "its samples)")
    data = read_toml(path, BenchFormatError)
    if set(data) != {"rolling"}:
        raise BenchFormatError(f"{path}: needs exactly the table [rolling], got {shown(sorted(data))}")
    try:
        settings = parse_section(data["rolling"], RollingSettings, str(path), "rolling", error=BenchFormatError)
    except ConfigError as e:
        raise BenchFormatError(str(e)) from None
    samples = folder / settings.file
    if not samples.resolve().is_relative_to(folder.resolve()):
        raise BenchFormatError(f"{path}: [rolling] file: {settings.file!r} leads outside the folder (refused)")
    header = column_names(samples, f"{ROLLING_FILE} [rolling] file")
    phases = set(PHASE_COLUMNS) <= set(header)
    if phases == (I_Q_COLUMN in header):
        raise BenchFormatError(f"{samples}: line 1: needs the column {I_Q_COLUMN} or the columns "
                               f"{', '.join(PHASE_COLUMNS)}, exactly one of them (the header has {shown(header)})")
    extra = ("segment",) + ((TORQUE_COLUMN,) if TORQUE_COLUMN in header else ())
    layout = LogLayout(time="time", position="position", position_unit="counts",
                       position_counts_per_rev=head.motor.counts_per_rev,
                       phase_currents=PHASE_COLUMNS if phases else None, i_q=None if phases else I_Q_COLUMN,
                       torque=TORQUE_COLUMN if TORQUE_COLUMN in header else None, direction=extra[0])
    columns = read_log(samples, layout)
    segment = columns["segment"]
    if np.any(segment != np.round(segment)):
        raise BenchFormatError(f"{samples}: line {int(np.flatnonzero(segment != np.round(segment))[0]) + 2}: segment "
                               "is not a whole number")
    rolling = RollingData(columns["time"], columns["position"], segment.astype(np.int64),
                          None if phases else columns[I_Q_COLUMN],
                          np.column_stack([columns[c] for c in PHASE_COLUMNS]) if phases else None,
                          columns.get(TORQUE_COLUMN))
    check_rolling(rolling, str(samples))
    segments = int(rolling.segment[-1])
    if settings.logs and len(settings.logs) != segments:
        raise BenchFormatError(f"{path}: [rolling] logs: {len(settings.logs)} logs for the {segments} segments of "
                               f"{samples.name}")
    return Rolling(folder, head.motor, head.backemf_nm_per_a, head.sensors, settings, rolling)


def write_rolling(folder: str | Path, motor: MotorInfo, backemf_nm_per_a: np.ndarray,
                  sensors: SensorCalibration | None, settings: RollingSettings, data: RollingData) -> None:
    """Write a rolling folder: backemf.csv, rolling.csv, rolling.toml, then bench.toml last (times to 0.1 us,
    positions to 1e-6 counts, currents and torque to 1e-6 of their unit)."""
    folder = Path(folder)
    check_rolling(data, str(folder / settings.file))
    names = list(BASE_COLUMNS) + ([I_Q_COLUMN] if data.i_q_a is not None else list(PHASE_COLUMNS))
    columns = [data.time_s, data.position_counts, data.segment.astype(float)]
    columns += [data.i_q_a] if data.i_q_a is not None else list(np.asarray(data.currents_a).T)
    if data.torque_nm is not None:
        names.append(TORQUE_COLUMN)
        columns.append(data.torque_nm)
    decimals = [TIME_DECIMALS, POSITION_DECIMALS, 0] + [6] * (len(names) - 3)
    folder.mkdir(parents=True, exist_ok=True)
    write_backemf_csv(folder / "backemf.csv", backemf_nm_per_a)
    body = format_rows(np.column_stack(columns), np.array(decimals))
    atomic_write(folder / settings.file, ",".join(names).encode() + b"\n" + body)
    atomic_write(folder / ROLLING_FILE, "[rolling]\n" + section_toml(settings))
    atomic_write(folder / BENCH_FILE, bench_toml_text(motor, sensors, []))


def rolling_seconds(data: RollingData) -> float:
    """The samples' duration, summed over the segments, s."""
    return float(sum(data.time_s[r.stop - 1] - data.time_s[r.start] for r in data.segments))

