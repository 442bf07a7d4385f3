"""Drive logs into a bench folder: ``ilcpmac import LOG... --map MAPPING.toml --out BENCH_DIR``.

A drive logs rows at a fixed rate (time, position, currents, torque); a bench
folder holds one row per encoder count (docs/bench-format.md). A mapping file
names the log's columns, units and scales, the motor as a campaign config's
[bench] describes it, and optionally each log's operating point. Each log is
resampled onto the encoder counts it crosses, by linear interpolation between
rows, with an estimate of the interpolation error (`InterpolationError`).
Logs without a torque column make a bench without a torque sensor ([motor]
torque_sensor = false), identified on the torque of the encoder's time stamps:
the interpolated crossing times, whose resolution bench.toml states
(`stamp_resolution_s`). A log is cut into laps where its position turns;
reverse laps are mirrored (phi = -theta, torque negated, time kept) into a
bench of the motor's mirror image beside the forward one (`reverse_folder`,
[motor] mirrored = true; docs/bench-format.md, "Reverse laps").
A mapping with ``[log] kind = "scan"`` marks its logs as a standstill
position scan (`ilcpmac.bench.standstill`): their rows are kept as they are,
in standard units, with the direction of motion, and written as a scan folder;
with ``[log] kind = "moteus-cogging"``, moteus cogging files
(`ilcpmac.bench.moteus`) make a scan folder. A mapping with ``[log] kind =
"rolling"`` keeps its logs' rows as they are, their steady part, as a rolling
folder (`ilcpmac.bench.rolling`, `write_rolling_folder`); a run log the per-count
path refuses as one it cannot resample (`NotPerCount`: a lap shorter than a
revolution, rows too coarse for the counts or the harmonics, a gap) is kept so
too by ``ilcpmac import``, which says so.
A mapping's optional [limits] (`ImportLimits`) are what the logged values are judged
against, never converted: a log whose currents, torque or the torque its currents ask for pass
`LOG_LIMIT_FACTOR` times them, or a scan whose holding torque passes the motor's torque range, is in a wrong
unit or holds an outlier, and is refused.
Every problem raises `ConfigError` (the mapping, naming its key) or
`BenchFormatError` (a log, naming its line and column), one line each.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ilcpmac.bench.format import (
    BENCH_FILE,
    MAX_COUNT,
    MAX_REVOLUTIONS,
    MAX_TIMER_RESOLUTION_S,
    MAX_TRIAL_ROWS,
    Bench,
    as_written,
    check_backemf,
    check_torque_setpoint,
    check_trial,
    mean_torque_reference_nm,
    read_backemf_csv,
    write_bench,
)
from ilcpmac.bench.holding_map import HOLDING_MAP, HoldingMapMapping, holding_map_mapping
from ilcpmac.bench.logs import (
    LOG_LIMIT_FACTOR,
    ImportLimits,
    LogLayout,
    beyond_limit,
    current_columns,
    named_columns,
    read_log,
)
from ilcpmac.bench.moteus import MOTEUS_COGGING, MoteusLog, MoteusMapping, cogging_scan
from ilcpmac.bench.rolling import Coverage, RollingData, RollingSettings, coverage, steady_rows, write_rolling
from ilcpmac.bench.standstill import (
    ScanData,
    SensorErrors,
    check_scan,
    holding_problem,
    logged_holding_nm,
    write_scan,
)
from ilcpmac.config import BenchSettings, model_key
from ilcpmac.core.errors import BenchFormatError, ConfigError
from ilcpmac.core.records import (
    CURRENTS_FROM_I_Q,
    CURRENTS_FROM_PHASES,
    MAX_CURRENT_A,
    MAX_SPEED_HZ,
    MAX_TORQUE_NM,
    MotorInfo,
    SensorCalibration,
    TrialData,
    mirrored_table,
)
from ilcpmac.core.schema import in_range, parse_section, read_toml, setting, shown
from ilcpmac.model.motor import backemf_problem
from ilcpmac.model.tables import backemf_table, q_axis

__all__ = ["ImportMapping", "ImportedBench", "ImportedLog", "InterpolationError", "LogPoint", "MAX_TIME_S",
           "NotPerCount", "RollingLog", "bench_motor", "import_laps", "import_log", "import_logs", "import_rolling",
           "import_scan", "read_mapping", "resample_to_counts", "reverse_folder", "stamp_resolution_s",
           "write_rolling_folder", "write_scan_folder"]

#: finest resolution of the time stamps written (the trial files' 0.1 us)
MIN_STAMP_RESOLUTION_S = 1e-7
#: largest |time| of a log once scaled, s: the trial files' 0.1 us stamps are exact in a double up to 2^53 of
#: them (about 28.5 years)
MAX_TIME_S = 2.0**53 * MIN_STAMP_RESOLUTION_S
#: a change of the row interval or of the position step below this fraction of it is rounding, not a quantum
_ROUNDING = 1e-6
#: row rates a drive log may have, Hz: from a coarse logger's (40 Hz still gives the low harmonics) to 10x the
#: 20 kHz drives log at (a time column in s read as ms moves the rate 1000x up)
LOG_RATE_HZ = (10.0, 200e3)
#: the slowest mean speed a log may show, Hz: a time column in ms read as s moves a drive's speed (0.1 Hz and up)
#: 1000x down, below it
MIN_LOG_SPEED_HZ = 0.01
#: most median row intervals between two rows: a longer gap means rows are missing
MAX_GAP_INTERVALS = 10.0


class NotPerCount(BenchFormatError):
    """A run log the per-count path cannot resample, but a rolling folder can keep as it is (`import_rolling`): a
    lap shorter than a revolution between turns, rows too coarse for the counts or for [log] highest_harmonic,
    crossing times too coarse for a log without torque, a gap in its rows, fewer than two counts crossed."""


@dataclass(frozen=True)
class LogPoint:
    """[[points]] of a mapping file: the operating point of one log, when the data do not give it."""

    file: str = setting(None, "the log's file name, as given on the command line (its last part)",
                       dataclasses.MISSING)
    torque_setpoint_nm: float = setting(in_range(0.0, 1e5, low_open=True), "N m, within (0, 1e5]",
                                       dataclasses.MISSING)
    speed_setpoint_hz: float = setting(in_range(0.0, 1e3, low_open=True), "Hz, within (0, 1e3]",
                                      dataclasses.MISSING)


@dataclass(frozen=True)
class ImportMapping:
    """A parsed mapping file.

    Attributes
    ----------
    path : the mapping file.
    motor : MotorInfo
        From [bench] (as a campaign config's; inertia_kgm2 required); a run without [log] torque has no
        torque sensor.
    backemf_nm_per_a : ndarray, shape (counts_per_rev, 3)
        From [bench] backemf_file or [bench.backemf].
    sensors : SensorCalibration or None
        From [bench.calibration].
    layout : LogLayout
    points : dict of str to (float, float)
        Log file name -> (torque set point N m, speed set point Hz).
    scan_errors : SensorErrors
        From [scan] (a scan's sensor errors; the defaults without it).
    limits : ImportLimits
        From [limits] (the defaults without it).
    """

    path: Path
    motor: MotorInfo
    backemf_nm_per_a: np.ndarray
    sensors: SensorCalibration | None
    layout: LogLayout
    points: dict[str, tuple[float, float]]
    scan_errors: SensorErrors = SensorErrors()
    limits: ImportLimits = ImportLimits()


@dataclass(frozen=True)
class InterpolationError:
    """Estimated largest error of a log resampled onto encoder counts, per quantity.

    Linear interpolation over a row interval errs by at most half the larger
    |second difference| of the two rows bounding it (a bound for a function
    smooth, or linear between kinks, over three rows); a value's error adds
    its slope times the crossing time's error. The largest over the trial.

    For a smooth motion p(t) (counts) logged at f_s rows per second the
    interpolated position errs by p'' (t - t_n)(t_n+1 - t) / 2, at most
    |p''| / (8 f_s^2), so a crossing time errs by at most
    |domega/dt| / (8 f_s^2 omega) = |tau - b omega| / (8 J omega f_s^2) (the
    speed ripple, eq. 3.1); `time_s` states 4x that (p'' / f_s^2 is the second
    difference). The error is systematic: linear interpolation passes a
    motion at frequency f with the gain sinc^2(f / f_s) (`torque_loss`).

    Attributes
    ----------
    time_s : float
        Crossing times, s.
    current_a : float
        Current references, A.
    torque_nm : float or None
        Torque, N m; None for a log without torque.
    """

    time_s: float
    current_a: float
    torque_nm: float | None


@dataclass(frozen=True)
class ImportedLog:
    """One log resampled.

    Attributes
    ----------
    log : Path
    trial : TrialData
    error : InterpolationError
    resolved_harmonic : int
        The highest harmonic the rows resolve (two rows per period, and within the counts' Nyquist limit
        counts_per_rev / 2).
    stamp_resolution_s : float
        The crossing times' resolution (`stamp_resolution_s`), s.
    torque_loss : float
        1 - sinc^2(H f / f_s): how much the crossing times' linear interpolation lowers the encoder-derived
        torque at harmonic H = [log] highest_harmonic of a revolution, at the log's mean speed f (Hz) and
        row rate f_s; (pi H f / f_s)^2 / 3 for H f << f_s.
    row_rate_hz : float
        The log's rows per second over the lap.
    reverse : bool
        A reverse lap: ``trial`` is its mirror image (counts -c, torque and set point negated, time kept),
        a forward lap of the mirrored motor.
    lines : (int, int) or None
        The file lines of the lap's first and last rows, in a log that turns; None for a whole log.
    """

    log: Path
    trial: TrialData
    error: InterpolationError
    resolved_harmonic: int
    stamp_resolution_s: float
    torque_loss: float
    row_rate_hz: float
    reverse: bool
    lines: tuple[int, int] | None


@dataclass(frozen=True)
class ImportedBench:
    """A bench folder an import wrote.

    Attributes
    ----------
    folder : Path
    bench : Bench
        Its motor says ``mirrored`` for the reverse laps' bench.
    laps : tuple of ImportedLog
        The lap behind each trial of ``bench``, in order.
    """

    folder: Path
    bench: Bench
    laps: tuple[ImportedLog, ...]


def read_mapping(path: str | Path) -> ImportMapping | MoteusMapping | HoldingMapMapping:
    """Read and check a mapping file, of logs, (``[log] kind = "moteus-cogging"``) of moteus cogging files or
    (``kind = "holding-map"``) of a drive's holding maps (`ilcpmac.bench.holding_map`); each problem raises
    `ConfigError` naming the file and key."""
    path = Path(path)
    data = read_toml(path)
    known = ("bench", "log", "points", "scan", "limits")
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise ConfigError(f"{path}: unknown table [{shown(unknown[0])}] (known: {', '.join(known)})")
    for name in known[:2]:
        if name not in data:
            raise ConfigError(f"{path}: missing table [{name}]")
    bench = parse_section(data["bench"], BenchSettings, str(path), "bench")
    if isinstance(data["log"], dict) and data["log"].get("kind") == HOLDING_MAP:  # a map needs no inertia
        limits = parse_section(data.get("limits", {}), ImportLimits, str(path), "limits")
        motor = MotorInfo(bench.pole_pairs, bench.slots, bench.counts_per_rev, bench.inertia_kgm2 or 1.0)
        backemf = None if bench.backemf_file is None and bench.backemf is None else _backemf(bench, motor, path)
        return holding_map_mapping(data, bench, limits, path, backemf)
    if bench.inertia_kgm2 is None:
        raise ConfigError(f"{path}: [bench] inertia_kgm2: missing (a bench folder needs it)")
    limits = parse_section(data.get("limits", {}), ImportLimits, str(path), "limits")
    if isinstance(data["log"], dict) and data["log"].get("kind") == MOTEUS_COGGING:
        return _moteus_mapping(data, bench, MotorInfo(bench.pole_pairs, bench.slots, bench.counts_per_rev,
                                                      bench.inertia_kgm2, torque_sensor=True), limits, path)
    layout = parse_section(data["log"], LogLayout, str(path), "log")
    motor = MotorInfo(bench.pole_pairs, bench.slots, bench.counts_per_rev, bench.inertia_kgm2,
                      torque_sensor=layout.kind == "scan" or layout.torque is not None,
                      currents=CURRENTS_FROM_PHASES if layout.i_q is None else CURRENTS_FROM_I_Q,
                      inertia_uncertainty=bench.inertia_uncertainty)
    _check_layout(layout, motor, path)
    points = data.get("points", [])
    if not isinstance(points, list):
        raise ConfigError(f"{path}: [points] must be a list of [[points]] tables")
    parsed = [parse_section(p, LogPoint, str(path), f"points #{i}") for i, p in enumerate(points, start=1)]
    by_file = {p.file: (p.torque_setpoint_nm, p.speed_setpoint_hz) for p in parsed}
    if len(by_file) < len(parsed):
        raise ConfigError(f"{path}: [[points]] lists a file twice")
    if parsed and layout.kind != "run":
        what = "standstill scan" if layout.kind == "scan" else "rolling log"
        raise ConfigError(f"{path}: [[points]]: only for run logs (a {what} has no operating point)")
    if "scan" in data and layout.kind != "scan":
        raise ConfigError(f'{path}: [scan]: only for a standstill scan ([log] kind = "scan")')
    errors = SensorErrors.parse(data.get("scan", {}), str(path), "scan")
    return ImportMapping(path, motor, _backemf(bench, motor, path), None if bench.calibration is None
                         else bench.calibration.calibration(), layout, by_file, errors, limits)


def _moteus_mapping(data: dict, bench: BenchSettings, motor: MotorInfo, limits: ImportLimits,
                    path: Path) -> MoteusMapping:
    """A mapping for moteus cogging files: [log] holds the kind alone, no [[points]]; ``motor`` has a torque
    sensor (the scan holds a torque)."""
    parse_section(data["log"], MoteusLog, str(path), "log")
    if "points" in data:
        raise ConfigError(f"{path}: [[points]]: only for run logs (a moteus cogging file has no operating point)")
    return MoteusMapping(path, motor, _backemf(bench, motor, path), None if bench.calibration is None
                         else bench.calibration.calibration(), SensorErrors.parse(data.get("scan", {}), str(path),
                                                                                  "scan"), limits)


def _check_layout(layout: LogLayout, motor: MotorInfo, path: Path) -> None:
    """The [log] keys that go together: one kind of current, counts per revolution for counts, harmonics the
    counts resolve."""
    if layout.highest_harmonic > motor.counts_per_rev // 2:
        raise ConfigError(f"{path}: [log] highest_harmonic: {layout.highest_harmonic} is beyond the Nyquist limit "
                          f"of [bench] counts_per_rev {motor.counts_per_rev}")
    currents = (layout.phase_currents is not None) + (layout.i_q is not None)
    if layout.kind == "scan":
        if currents > 1 or (currents == 1) == (layout.torque is not None):
            raise ConfigError(f"{path}: [log] phase_currents, i_q, torque: a scan gives exactly one of them (the "
                              "holding currents or the holding torque)")
    elif currents != 1:
        raise ConfigError(f"{path}: [log] phase_currents, i_q: give exactly one")
    if layout.direction is not None and layout.kind != "scan":
        raise ConfigError(f'{path}: [log] direction: only for a standstill scan ([log] kind = "scan")')
    rolling_keys = [k for k in ("current_filter_s", "cut_transients")
                    if getattr(layout, k) != getattr(LogLayout, k)]
    if layout.kind == "scan" and rolling_keys:
        raise ConfigError(f"{path}: [log] {rolling_keys[0]}: only for a rolling log ([log] kind = \"rolling\", or a "
                          "run log kept as one)")
    if (layout.position_unit == "counts") != (layout.position_counts_per_rev is not None):
        raise ConfigError(f"{path}: [log] position_counts_per_rev: give it when, and only when, "
                          'position_unit = "counts"')
    keys: dict[str, str] = {}
    for key, column in named_columns(layout):
        if column in keys:
            raise ConfigError(f"{path}: [log] {key}: column {shown(column)} is [log] {keys[column]} already (each "
                              "quantity needs a column of its own)")
        keys[column] = key


def _backemf(bench: BenchSettings, motor: MotorInfo, path: Path) -> np.ndarray:
    """The back-EMF table of [bench]: backemf_file (relative to the mapping) or [bench.backemf]."""
    if bench.backemf_file is not None and bench.backemf is None:
        try:
            return read_backemf_csv(path.parent / bench.backemf_file, motor)
        except BenchFormatError as e:
            raise ConfigError(f"{path}: [bench] backemf_file: {e}") from None
    if bench.backemf_file is not None or bench.backemf is None:
        raise ConfigError(f"{path}: [bench] backemf_file, [bench.backemf]: give exactly one")
    problem = backemf_problem(bench.backemf, motor.pole_pairs, motor.counts_per_rev, model_key)
    if problem is not None:
        raise ConfigError(f"{path}: {problem}")
    table = backemf_table(motor, bench.backemf, motor.counts_per_rev)
    check_backemf(table, motor, f"{path}: [bench.backemf]")
    return table


def _inverse_park(i_q: np.ndarray, position_counts: np.ndarray, motor: MotorInfo, offset_rad: float) -> np.ndarray:
    """Phase currents i_p = i_q sin(theta_e - 2 pi p / 3), theta_e = pole_pairs 2 pi position / counts_per_rev
    + offset_rad, shape (n, 3)."""
    theta_e = motor.pole_pairs * 2.0 * np.pi * position_counts / motor.counts_per_rev + offset_rad
    return i_q[:, None] * q_axis(theta_e)


def _interval_error(values: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Half the larger |second difference| at rows k-1 and k of ``values`` (n, m), per interval (k-1, k),
    2 <= k <= n-2."""
    second = np.abs(values[2:] - 2.0 * values[1:-1] + values[:-2])  # at rows 1..n-2
    return 0.5 * np.maximum(second[k - 2], second[k - 1])


def resample_to_counts(time_s: np.ndarray, position_counts: np.ndarray, values: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Time-sampled rows at the encoder counts the position crosses.

    Parameters
    ----------
    time_s : ndarray, shape (n,)
        Strictly increasing.
    position_counts : ndarray, shape (n,)
        Unwrapped, non-decreasing, in counts; it rises above its first value.
    values : ndarray, shape (n, m)

    Returns
    -------
    count : ndarray of int64, shape (c,)
        Every integer position the rows cross, but in the first and the last row interval (no second
        difference there states their error).
    time_s, values : ndarray, shapes (c,) and (c, m)
        Linearly interpolated where the position reaches each count.
    time_error_s, value_error : ndarray, shapes (c,) and (c, m)
        Their estimated errors (`InterpolationError`).
    """
    p = position_counts
    count = np.arange(math.floor(p[0]) + 1, math.floor(p[-1]) + 1, dtype=np.int64)
    k = np.searchsorted(p, count, side="left")  # p[k-1] < count <= p[k]
    inner = (k >= 2) & (k <= p.size - 2)
    count, k = count[inner], k[inner]
    dp, dt = p[k] - p[k - 1], time_s[k] - time_s[k - 1]
    frac = (count - p[k - 1]) / dp
    at = time_s[k - 1] + frac * dt
    values_at = values[k - 1] + frac[:, None] * (values[k] - values[k - 1])
    time_error = _interval_error(p[:, None], k)[:, 0] * dt / dp
    slope = np.abs(values[k] - values[k - 1]) / dt[:, None]
    value_error = _interval_error(values, k) + slope * time_error[:, None]
    return count, at, values_at, time_error, value_error


def _laps(log: Path, position_counts: np.ndarray, mapping: ImportMapping) -> list[tuple[int, int, bool]]:
    """The laps of a log: (first row, last row, reverse) of each run of rows in one direction, a turning row
    ending one lap and starting the next; rows holding still belong to the lap they follow (or, first in
    the log, to the first).

    Raises
    ------
    BenchFormatError
        A position that never changes; in a log that turns, a lap shorter than a revolution (a position
        that dithers, or a partial lap at a turn).
    """
    layout, cpr = mapping.layout, mapping.motor.counts_per_rev
    step = np.diff(position_counts)
    moving = np.flatnonzero(step)
    if not moving.size:
        raise BenchFormatError(f"{log}: {layout.position} never changes (the motor did not turn)")
    direction = step[moving] < 0
    turns = moving[1:][direction[1:] != direction[:-1]]
    first = np.concatenate([[0], turns])
    last = np.concatenate([turns, [position_counts.size - 1]])
    reverse = np.concatenate([direction[:1], direction[1:][direction[1:] != direction[:-1]]])
    laps = [(int(a), int(b), bool(r)) for a, b, r in zip(first, last, reverse)]
    if len(laps) > 1:
        for a, b, r in laps:
            span = abs(position_counts[b] - position_counts[a])
            if span < cpr:
                raise NotPerCount(
                    f"{log}: lines {_line(layout, a)}-{_line(layout, b)}: a {'reverse' if r else 'forward'} lap of "
                    f"{span / cpr:.3g} revolutions between turns of {layout.position}; in a log that turns each "
                    "lap must cover a whole revolution (a position that dithers, or a partial lap: cut the log)")
    return laps


def _line(layout: LogLayout, row: int) -> int:
    """The file line of data row ``row`` (0-based)."""
    return layout.header_lines + 1 + row


def import_laps(log: Path, mapping: ImportMapping) -> list[ImportedLog]:
    """A drive log cut into laps where its position turns (`_laps`), each resampled onto encoder counts as a
    bench trial (`import_log`'s checks, per lap); a reverse lap as its mirror image (`ImportedLog.reverse`)."""
    columns, time_s, position = _time_and_position(log, mapping)
    laps = _laps(log, position, mapping)
    return [_import_lap(log, mapping, columns, time_s, position, lap, len(laps) > 1) for lap in laps]


def import_log(log: Path, mapping: ImportMapping) -> ImportedLog:
    """A drive log that does not turn, resampled onto encoder counts as a bench trial, checked as `read_bench`
    checks one; a log running backwards gives its mirror image (`ImportedLog.reverse`).

    Raises
    ------
    BenchFormatError
        Naming the log: time not increasing, a row's time, position, current
        or torque beyond what a trial file holds (`MAX_TIME_S`, 2^53 counts,
        1e4 A, 1e5 N m) or its current, torque or K . i_ref beyond
        `LOG_LIMIT_FACTOR` times [limits], rows off a drive's rate or with a gap (`_check_clock`),
        a [[points]] torque set point at odds with the currents, a position that never
        changes or that turns (`import_laps` cuts such a log into laps), a
        mean speed beyond a bench's 1000 Hz, rows too coarse for [log]
        highest_harmonic (with the highest harmonic they resolve), crossing
        times too coarse for a log without torque, a trial at odds with
        [bench] as its file will hold it (`as_written`).
    """
    columns, time_s, position = _time_and_position(log, mapping)
    laps = _laps(log, position, mapping)
    if len(laps) > 1:
        raise BenchFormatError(f"{log}: line {_line(mapping.layout, laps[1][0])}: {mapping.layout.position} turns "
                               f"({len(laps)} laps; import_laps gives each)")
    return _import_lap(log, mapping, columns, time_s, position, laps[0], False)


def _import_lap(log: Path, mapping: ImportMapping, columns: dict[str, np.ndarray], time_s: np.ndarray,
                position: np.ndarray, lap: tuple[int, int, bool], part: bool) -> ImportedLog:
    """Rows ``lap`` = (first, last, reverse) of a log as a trial; ``part``: the log has other laps (messages
    name the lap's lines). A reverse lap is mirrored: position -theta, torque negated, currents and time as
    they are; phase references from i_q by the inverse Park transform at the motor's own angle."""
    layout, motor = mapping.layout, mapping.motor
    cpr = motor.counts_per_rev
    first, last, reverse = lap
    lines = (_line(layout, first), _line(layout, last)) if part else None
    where = str(log) if lines is None else f"{log}: lines {lines[0]}-{lines[1]}"
    rows = slice(first, last + 1)
    sign = -1.0 if reverse else 1.0
    time_s, position = time_s[rows], sign * position[rows]
    step = np.diff(position)
    speed_hz = (position[-1] - position[0]) / cpr / (time_s[-1] - time_s[0])
    if speed_hz > MAX_SPEED_HZ:
        raise BenchFormatError(f"{where}: {layout.time} and {layout.position} give a mean speed of {speed_hz:.3g} "
                               f"Hz, beyond a bench's {MAX_SPEED_HZ:g} Hz (wrong time_s_per_unit or position unit in "
                               f"{mapping.path}?)")
    largest = float(step.max())
    resolved = min(math.floor(cpr / (2.0 * largest)), cpr // 2)
    if resolved < layout.highest_harmonic:
        raise NotPerCount(
            f"{where}: too coarse: up to {largest:.4g} counts between rows, {cpr / largest:.4g} rows per revolution "
            f"at the fastest, fewer than two per period of harmonic {layout.highest_harmonic} ([log] "
            f"highest_harmonic); the data resolve harmonics up to {resolved}")
    _check_clock(log, where, time_s, first, speed_hz, mapping)
    resolution_s = stamp_resolution_s(time_s, position, layout.timer_resolution_s)
    if layout.torque is None and resolution_s > MAX_TIMER_RESOLUTION_S:
        raise NotPerCount(f"{where}: the crossing times resolve {resolution_s:.3g} s only, coarser than "
                               f"{MAX_TIMER_RESOLUTION_S:g} s: too coarse for the torque of the encoder's time stamps "
                               f"(a log without torque; a finer position or time column is needed)")
    current_names = current_columns(layout)
    torque_names = [] if layout.torque is None else [layout.torque]
    values = np.column_stack([columns[n][rows] for n in current_names + torque_names])
    values *= np.array([layout.current_a_per_unit] * len(current_names) + [sign * layout.torque_nm_per_unit] * len(
        torque_names))
    count, at, values_at, time_error, value_error = resample_to_counts(time_s, position, values)
    max_rows = min(MAX_REVOLUTIONS * cpr, MAX_TRIAL_ROWS)
    if count.size > max_rows:
        raise BenchFormatError(f"{where}: crosses {count.size} encoder counts; a trial holds 2 to {max_rows}")
    if count.size < 2:
        raise NotPerCount(f"{where}: crosses {count.size} encoder counts; a trial holds 2 to {max_rows}")
    if layout.i_q is not None:
        currents = _inverse_park(values_at[:, 0], sign * count, motor, layout.angle_offset_rad)
        current_error = value_error[:, 0]
    else:
        currents = values_at[:, :3]
        current_error = value_error[:, :3].max(axis=1)
    point = mapping.points.get(log.name)
    backemf = mirrored_table(mapping.backemf_nm_per_a) if reverse else mapping.backemf_nm_per_a
    problem = _limit_problem(np.sum(backemf[count % cpr] * currents, axis=1), "max_torque_nm", "N m", mapping)
    if problem is not None:
        raise BenchFormatError(f"{where}: count {sign * count[problem[0]]:g}: the current references ask for "
                               f"(K . i_ref) {problem[1]}")
    torque, speed = point if point is not None else _operating_point(where, count, at, currents, backemf, mapping)
    trial = TrialData(torque, speed, count, at, np.ascontiguousarray(currents),
                      values_at[:, -1].copy() if torque_names else None,
                      i_meas_a=currents.copy() if layout.current == "measured" else None)
    _check_as_written(trial, motor, where)
    if point is not None:
        check_torque_setpoint(trial, backemf, f"{mapping.path}: [[points]] file {shown(log.name)} torque_setpoint_nm",
                              where)
    error = InterpolationError(float(time_error.max()), float(current_error.max()),
                               float(value_error[:, -1].max()) if torque_names else None)
    highest_hz = layout.highest_harmonic * trial.mean_speed_hz(cpr)
    row_rate_hz = (time_s.size - 1) / (time_s[-1] - time_s[0])
    return ImportedLog(log, trial, error, resolved, resolution_s, float(1.0 - np.sinc(highest_hz / row_rate_hz) ** 2),
                       float(row_rate_hz), reverse, lines)


def _time_unit(s_per_unit: float) -> str:
    """The name of a time unit of ``s_per_unit`` seconds: s, ms, us or ns, else "units of ... s"."""
    for name, size in (("s", 1.0), ("ms", 1e-3), ("us", 1e-6), ("ns", 1e-9)):
        if math.isclose(s_per_unit, size, rel_tol=1e-9):
            return name
    return f"units of {s_per_unit:g} s"


def _check_clock(log: Path, where: str, time_s: np.ndarray, first: int, speed_hz: float,
                 mapping: ImportMapping) -> None:
    """A lap's rows (the first at row ``first`` of the log) at a drive's row rate, without gaps.

    The rate is the inverse of the median row interval: within
    `LOG_RATE_HZ`, at a mean speed of `MIN_LOG_SPEED_HZ` or more (a time column in the wrong unit, ms read as
    s, say, moves both 1000x; the message names the unit it looks like), and no interval longer
    than `MAX_GAP_INTERVALS` median ones (rows missing, which the
    interpolation would bridge, and the speed set point would average over).
    """
    layout = mapping.layout
    interval_s = np.diff(time_s)
    median_s = float(np.median(interval_s))
    rate_hz = 1.0 / median_s
    low_hz, high_hz = LOG_RATE_HZ
    if not (low_hz <= rate_hz <= high_hz and abs(speed_hz) >= MIN_LOG_SPEED_HZ):
        given = layout.time_s_per_unit
        likely = given * (1e3 if rate_hz > high_hz else 1e-3)
        raise BenchFormatError(
            f"{where}: {layout.time} gives {rate_hz:.3g} rows per second and a mean speed of {speed_hz:.3g} Hz; a "
            f"drive logs {low_hz:g} to {high_hz:g} rows per second at {MIN_LOG_SPEED_HZ:g} Hz or faster: "
            f"{layout.time} looks like {_time_unit(likely)}, not {_time_unit(given)} ([log] time_s_per_unit = "
            f"{given:g} in {mapping.path})")
    gap = int(np.argmax(interval_s))
    if interval_s[gap] > MAX_GAP_INTERVALS * median_s:
        raise NotPerCount(
            f"{log}: line {_line(layout, first + gap + 1)}: {layout.time} jumps by {interval_s[gap]:.3g} s, "
            f"{interval_s[gap] / median_s:.3g} times the median row interval {median_s:.3g} s (more than "
            f"{MAX_GAP_INTERVALS:g}: rows are missing; cut the log at the gap)")


def _check_as_written(trial: TrialData, motor: MotorInfo, where: str) -> None:
    """``trial`` as its file will hold it (`as_written`: stamps to 0.1 us, currents and torque to 1e-6) must pass
    `check_trial` and keep its stamps increasing, as `read_bench` requires; its electrical period is checked on
    logged phase currents only, not on those the inverse Park transform made from i_q (``motor.currents``)."""
    written = as_written(trial)
    check_trial(written, motor, f"{where} (as a trial file holds it)")
    same = np.flatnonzero(np.diff(written.time_s) <= 0)
    if same.size:
        raise BenchFormatError(f"{where}: counts {trial.count[same[0]]} and {trial.count[same[0] + 1]} are crossed "
                               f"within the trial files' {MIN_STAMP_RESOLUTION_S:g} s stamps (too fast for "
                               "[bench] counts_per_rev)")


def stamp_resolution_s(time_s: np.ndarray, position_counts: np.ndarray, time_quantum_s: float | None = None) -> float:
    """The resolution of the crossing times interpolated between a log's rows, s.

    A crossing time t_n-1 + (c - p_n-1) / (p_n - p_n-1) (t_n - t_n-1) carries
    the error of the rows' time stamps (quantum q_t) and of their positions
    (quantum q_p, counts) over the speed v (counts/s): uniform errors of
    widths up to q_t and q_p / v, which add as stamps quantised to
    sqrt(q_t^2 + (q_p / v)^2), v the log's mean speed; at least the bench
    files' 0.1 us. q_t is ``time_quantum_s`` when given, else read off the
    rows as q_p is: a quantised clock or position makes every change of the
    row interval, or of the position step, a multiple of its quantum, and the
    smallest change above rounding (1e-6 of the interval or step) is taken
    for it; none (rows at exact intervals, a position of real numbers that
    changes smoothly) gives 0, or nearly.
    """
    speed = (position_counts[-1] - position_counts[0]) / (time_s[-1] - time_s[0])
    q_t = _finest_change(np.diff(time_s)) if time_quantum_s is None else time_quantum_s
    q_p = _finest_change(np.diff(position_counts))
    return float(max(math.hypot(q_t, q_p / speed), MIN_STAMP_RESOLUTION_S))


def _finest_change(steps: np.ndarray) -> float:
    """The smallest |change| between successive ``steps`` above `_ROUNDING` of the largest step, or 0."""
    changes = np.abs(np.diff(steps))
    changes = changes[changes > _ROUNDING * np.abs(steps).max()]
    return float(changes.min()) if changes.size else 0.0


def _time_and_position(log: Path, mapping: ImportMapping, shared_stamps: bool = False
                       ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
    """A log's columns, its time stamps in s (strictly increasing; non-decreasing with ``shared_stamps``) and its
    unwrapped position in counts of [bench] counts_per_rev ([log] position_wraps_at, else once per revolution);
    every row's time, position, currents and torque, once scaled, within what a trial file holds (`MAX_TIME_S`,
    2^53 counts, 1e4 A, 1e5 N m), and its currents and torque within `LOG_LIMIT_FACTOR` times [limits]
    (`_limit_problem`), or the first row beyond is named."""
    layout, cpr = mapping.layout, mapping.motor.counts_per_rev
    columns = read_log(log, layout)
    time_s = columns[layout.time] * layout.time_s_per_unit
    back = np.flatnonzero(np.diff(time_s) < 0 if shared_stamps else np.diff(time_s) <= 0)
    if back.size:
        raise BenchFormatError(f"{log}: line {layout.header_lines + 2 + back[0]}: {layout.time} does not increase")
    per_rev = 2.0 * np.pi if layout.position_unit == "rad" else layout.position_counts_per_rev
    if per_rev is None:
        raise ConfigError(f'{log}: [log] position_counts_per_rev: missing (position_unit = "counts" needs it)')
    position = columns[layout.position] * (cpr / per_rev)
    wrap = cpr if layout.position_wraps_at is None else layout.position_wraps_at * cpr / per_rev
    judged = [(name, columns[name] * layout.current_a_per_unit, MAX_CURRENT_A, "max_current_a", "A")
              for name in current_columns(layout)] + (
        [] if layout.torque is None else [(layout.torque, columns[layout.torque] * layout.torque_nm_per_unit,
                                           MAX_TORQUE_NM, "max_torque_nm", "N m")])
    bounds = [(layout.time, time_s, MAX_TIME_S, "s"), (layout.position, position, MAX_COUNT, "counts")] + [
        (name, values, bound, unit) for name, values, bound, _, unit in judged]
    for name, values, bound, unit in bounds:
        beyond = np.flatnonzero(~(np.abs(values) <= bound))
        if beyond.size:
            raise BenchFormatError(f"{log}: line {layout.header_lines + 1 + beyond[0]}: {name} beyond {bound:.4g} "
                                   f"{unit} once scaled, more than a trial file holds (wrong scale or unit in "
                                   f"{mapping.path}?)")
    for name, values, _, key, unit in judged:
        problem = _limit_problem(values, key, unit, mapping)
        if problem is not None:
            raise BenchFormatError(f"{log}: line {_line(layout, problem[0])}: {name} {problem[1]}")
    return columns, time_s, np.unwrap(position, period=wrap)


def _limit_problem(values: np.ndarray, key: str, unit: str, mapping: ImportMapping) -> tuple[int, str] | None:
    """The first row where |values| (a log's currents or torque, or the torque its currents ask for) passes
    `LOG_LIMIT_FACTOR` times [limits] ``key``, and the message's rest naming the limit and the likely cause
    (`beyond_limit`); None within."""
    limit = getattr(mapping.limits, key)
    found = beyond_limit(values, LOG_LIMIT_FACTOR * limit)
    if found is None:
        return None
    row, cause = found
    return row, (f"{values[row]:.4g} {unit} once scaled, beyond {LOG_LIMIT_FACTOR:g}x [limits] {key} = {limit:g} "
                 f"{unit} (of {mapping.path}, its default if not given): {cause}")


def import_scan(log: Path, mapping: ImportMapping) -> ScanData:
    """One standstill-scan log in standard units, row by row (docs/standstill.md).

    The direction of each row is the sign of [log] direction, or else of the
    position's last change at or before it (rows before the first change take
    its sign). q-axis currents become phase currents by the inverse Park
    transform at each row's position, as for a run.
    """
    layout, motor = mapping.layout, mapping.motor
    columns, time_s, position = _time_and_position(log, mapping)
    if layout.direction is not None:
        direction = np.sign(columns[layout.direction])
        still = np.flatnonzero(direction == 0)
        if still.size:
            raise BenchFormatError(f"{log}: line {layout.header_lines + 1 + still[0]}: {layout.direction} is 0 "
                                   "(> 0 forward, < 0 reverse)")
    else:
        step = np.sign(np.diff(position))
        moved = np.flatnonzero(step)
        if not moved.size:
            raise BenchFormatError(f"{log}: the position never changes: not a scan")
        last = np.maximum.accumulate(np.where(step != 0, np.arange(step.size), moved[0]))
        direction = np.concatenate([step[moved[:1]], step[last]])
    scale = layout.current_a_per_unit
    if layout.phase_currents is not None:
        currents = np.column_stack([columns[c] for c in layout.phase_currents]) * scale
    elif layout.i_q is not None:
        currents = _inverse_park(columns[layout.i_q] * scale, position, motor, layout.angle_offset_rad)
    else:
        currents = None
    torque = None if layout.torque is None else columns[layout.torque] * layout.torque_nm_per_unit
    scan = ScanData(time_s, position, direction.astype(float), currents, torque)
    check_scan(scan, str(log))
    problem = holding_problem(logged_holding_nm(scan, mapping.backemf_nm_per_a), mapping.limits, mapping.path)
    if problem is not None:
        raise BenchFormatError(f"{log}: line {_line(layout, problem[0])}: {problem[1]}")
    return scan


def write_scan_folder(logs: list[Path], mapping: ImportMapping | MoteusMapping, out: Path) -> ScanData:
    """Import every scan log (`import_scan`) or moteus cogging file (`cogging_scan`) and write them, one after
    the other, as the scan folder ``out``.

    Nothing is written unless every log imports; a folder that holds a bench.toml already is refused.
    """
    _check_new(out)
    _check_distinct(logs)
    if isinstance(mapping, MoteusMapping):
        scans = [cogging_scan(log, mapping) for log in logs]
    else:
        _check_points(logs, mapping)
        scans = [import_scan(log, mapping) for log in logs]
    currents = [s.currents_a for s in scans if s.currents_a is not None]
    torques = [s.torque_nm for s in scans if s.torque_nm is not None]
    joined = ScanData(np.concatenate([s.time_s for s in scans]), np.concatenate([s.position_counts for s in scans]),
                      np.concatenate([s.direction for s in scans]), np.concatenate(currents) if currents else None,
                      np.concatenate(torques) if torques else None)
    check_scan(joined, str(out))
    write_scan(out, mapping.motor, mapping.backemf_nm_per_a, mapping.sensors, mapping.scan_errors, joined)
    return joined


@dataclass(frozen=True)
class RollingLog:
    """One log kept as a rolling log's segment (`import_rolling`).

    Attributes
    ----------
    log : Path
    data : RollingData
        Its steady rows in standard units (segment 1).
    lines : (int, int)
        The file lines of the first and last row kept.
    cut_start_s, cut_end_s : float
        The seconds left out before and after them (`steady_rows`; 0 with [log] cut_transients = false).
    rows : int
        The log's rows.
    row_rate_hz : float
        The inverse of the kept rows' median interval.
    gaps : int
        Row intervals longer than `MAX_GAP_INTERVALS` median ones (rows missing; the identification does not
        bridge them).
    coverage : Coverage
        What the kept rows cover of a revolution.
    shared_stamps : int
        Rows that shared a time stamp with the one before, spread up to the next stamp (`_spread_stamps`).
    """

    log: Path
    data: RollingData
    lines: tuple[int, int]
    cut_start_s: float
    cut_end_s: float
    rows: int
    row_rate_hz: float
    gaps: int
    coverage: Coverage
    shared_stamps: int = 0

    def text(self) -> str:
        """What the import kept, one line: rows, lines, seconds left out, rate, gaps and coverage."""
        cut = ("" if not (self.cut_start_s or self.cut_end_s) else
               f", {self.cut_start_s:.3g} s at the start and {self.cut_end_s:.3g} s at the end left out (speed not "
               "settled)")
        gaps = f", {self.gaps} gap{'s' if self.gaps > 1 else ''} in the rows" if self.gaps else ""
        shared = (f", {self.shared_stamps} rows sharing a stamp spread up to the next" if self.shared_stamps else "")
        return (f"{self.data.time_s.size} of {self.rows} rows kept (lines {self.lines[0]}-{self.lines[1]}{cut}), "
                f"{self.row_rate_hz:.4g} rows/s{gaps}{shared}; {self.coverage.text()}")


def import_rolling(log: Path, mapping: ImportMapping) -> RollingLog:
    """One log as a rolling log's segment: its rows as they are, in standard units (time s, position in counts of
    [bench] counts_per_rev, unwrapped, the q-axis or phase currents in A, the torque in N m), their steady part
    (`steady_rows`, unless [log] cut_transients = false).

    Rows that share a time stamp (a host polling faster than its clock's quantum) are spread evenly up to the
    next stamp (`_spread_stamps`).

    Raises
    ------
    BenchFormatError
        Naming the log: what `_time_and_position` refuses (time going back, a value beyond a bench's bounds or
        `LOG_LIMIT_FACTOR` times [limits]), rows at a rate off a drive's (`LOG_RATE_HZ`: a time column in the
        wrong unit), a position or a time that never changes, fewer than 16 rows kept.
    """
    layout, cpr = mapping.layout, mapping.motor.counts_per_rev
    columns, time_s, position = _time_and_position(log, mapping, shared_stamps=True)
    if np.all(position == position[0]):
        raise BenchFormatError(f"{log}: {layout.position} never changes (the motor did not turn)")
    if time_s[-1] == time_s[0]:
        raise BenchFormatError(f"{log}: {layout.time} never changes")
    time_s, shared = _spread_stamps(time_s)
    first, last = steady_rows(time_s, position) if layout.cut_transients else (0, time_s.size - 1)
    rows = slice(first, last + 1)
    interval_s = np.diff(time_s[rows])
    if interval_s.size < 2:
        raise BenchFormatError(f"{log}: {interval_s.size + 1} rows kept of its steady part; a rolling log needs 16 "
                               "or more")
    median_s = float(np.median(interval_s))
    low_hz, high_hz = LOG_RATE_HZ
    if not low_hz <= 1.0 / median_s <= high_hz:
        raise BenchFormatError(f"{log}: {layout.time} gives {1.0 / median_s:.3g} rows per second; a drive logs "
                               f"{low_hz:g} to {high_hz:g} (wrong [log] time_s_per_unit = {layout.time_s_per_unit:g} "
                               f"in {mapping.path}?)")
    scale = layout.current_a_per_unit
    problem = _motion_problem(time_s[rows], position[rows], mapping) or _commutation_problem(
        position[rows], None if layout.phase_currents is None else
        np.column_stack([columns[c][rows] for c in layout.phase_currents]), mapping)
    if problem is not None:
        (row, last_row), why = problem
        where = (f"line {_line(layout, first + row)}" if row == last_row else
                 f"lines {_line(layout, first + row)}-{_line(layout, first + last_row)}")
        raise BenchFormatError(f"{log}: {where}: {why}")
    data = RollingData(
        time_s[rows], position[rows], np.ones(last - first + 1, np.int64),
        None if layout.i_q is None else columns[layout.i_q][rows] * scale,
        None if layout.phase_currents is None else np.column_stack([columns[c][rows] for c in layout.phase_currents])
        * scale, None if layout.torque is None else columns[layout.torque][rows] * layout.torque_nm_per_unit)
    return RollingLog(log, data, (_line(layout, first), _line(layout, last)), float(time_s[first] - time_s[0]),
                      float(time_s[-1] - time_s[last]), int(time_s.size), 1.0 / median_s,
                      int(np.count_nonzero(interval_s > MAX_GAP_INTERVALS * median_s)),
                      coverage(position[rows], cpr), shared)


#: the least span of a rolling log's position, revolutions: over a shorter arc the harmonics of the revolution are
#: not told apart (a scan is refused below half a revolution too)
MIN_ROLLING_SPAN_REV = 0.5
#: how many times the acceleration [limits] max_torque_nm gives [bench] inertia_kgm2 a rolling log's position may
#: show between rows (beside its quantum's share): a drive's peak torque is a few times its rated one, and an inertia
#: may be off by a few times; beyond it a row is a glitch, or the position's unit or scale is wrong
ACCELERATION_FACTOR = 10.0
#: the least coherence |mean exp(j (arg s^2 - 2 p theta))| of the phase currents' space vector s with the position's
#: electrical angle p theta: a few per cent of ripple or noise leave it near 1, a wrong pole_pairs or position unit
#: spreads it around the circle (near 0)
MIN_COMMUTATION_COHERENCE = 0.5


def _motion_problem(time_s: np.ndarray, position: np.ndarray,
                    mapping: ImportMapping) -> tuple[tuple[int, int], str] | None:
    """The first rows (first, last) of a rolling log's steady part at odds with a motor's motion, and why, or None.

    Its span under `MIN_ROLLING_SPAN_REV`; two rows more than half a revolution apart (a position that wraps
    without [log] position_wraps_at, a wrong unit or scale, rows too sparse for the speed); an acceleration beyond
    `ACCELERATION_FACTOR` times [limits] max_torque_nm over [bench] inertia_kgm2, beside what its quantum (the
    least step between rows) makes of two intervals (a glitch, a wrong unit).
    """
    cpr = mapping.motor.counts_per_rev
    span = float(np.ptp(position)) / cpr
    if span < MIN_ROLLING_SPAN_REV:
        return (0, position.size - 1), (
            f"the position spans {span:.3g} revolutions of {cpr} counts, fewer than {MIN_ROLLING_SPAN_REV:g}: no "
            "harmonic of the revolution is told from the others (a wrong position unit or scale?)")
    step = np.diff(position)
    apart = np.flatnonzero(np.abs(step) > cpr / 2)
    if apart.size:
        return (int(apart[0]), int(apart[0]) + 1), (
            f"the position moves {step[apart[0]] / cpr:+.3g} revolutions from the row before: a position that wraps "
            "([log] position_wraps_at), a wrong unit or scale, or rows too sparse for the speed")
    moved = np.abs(step[step != 0])
    quantum_rad = 2.0 * np.pi / cpr * float(moved.min()) if moved.size else 0.0
    dt = np.diff(time_s)
    theta = 2.0 * np.pi / cpr * position
    accel = 2.0 * np.diff(np.diff(theta) / dt) / (dt[1:] + dt[:-1])
    bound = ACCELERATION_FACTOR * mapping.limits.max_torque_nm / mapping.motor.inertia_kgm2
    beyond = np.flatnonzero(np.abs(accel) > bound + 4.0 * quantum_rad / (dt[1:] * dt[:-1]))
    if beyond.size:
        run = beyond[: np.argmax(np.diff(np.append(beyond, -1)) != 1) + 1]  # the first run of rows beyond it
        k = int(run[np.argmax(np.abs(accel[run]))])
        return (int(run[0]) + 1, int(run[-1]) + 1), (
            f"the position jumps: {accel[k]:.3g} rad/s^2 where {ACCELERATION_FACTOR:g} x [limits] max_torque_nm / "
            f"[bench] inertia_kgm2 allows {bound:.3g} (a glitch, a counter that wraps without [log] "
            "position_wraps_at, or a wrong position unit or scale?)")
    return None


def _commutation_problem(position: np.ndarray, currents: np.ndarray | None,
                         mapping: ImportMapping) -> tuple[tuple[int, int], str] | None:
    """Why a rolling log's phase currents do not turn [bench] pole_pairs electrical periods per revolution of its
    position (`MIN_COMMUTATION_COHERENCE`), or None; nothing to check without phase currents (an i_q log) or over
    less than one electrical period."""
    motor = mapping.motor
    theta = 2.0 * np.pi / motor.counts_per_rev * position
    if currents is None or motor.pole_pairs * float(np.ptp(theta)) < 2.0 * np.pi:
        return None
    space = currents @ (2.0 / 3.0 * np.exp(2j * np.pi * np.arange(3) / 3.0))
    square = space**2
    turning = square[np.abs(square) > 0] * np.exp(-2j * motor.pole_pairs * theta[np.abs(square) > 0])
    coherence = float(np.abs(np.mean(turning / np.abs(turning)))) if turning.size else 0.0
    if coherence >= MIN_COMMUTATION_COHERENCE:
        return None
    return (0, position.size - 1), (
        f"the phase currents do not turn [bench] pole_pairs = {motor.pole_pairs} electrical periods per revolution "
        f"of the position (coherence {coherence:.2g}, below {MIN_COMMUTATION_COHERENCE:g}): a wrong pole_pairs, "
        "position unit or scale?")


def _spread_stamps(time_s: np.ndarray) -> tuple[np.ndarray, int]:
    """Non-decreasing stamps made increasing: the k rows that share a stamp (a host polling faster than its
    clock's quantum) spread evenly from it to the next stamp (the last ones' by the median interval between
    stamps); and how many rows shared one."""
    starts = np.flatnonzero(np.concatenate([[True], np.diff(time_s) > 0]))
    if starts.size == time_s.size:
        return time_s, 0
    stamps = time_s[starts]
    step = np.diff(stamps)
    ends = np.concatenate([stamps[1:], [stamps[-1] + float(np.median(step))]])
    sizes = np.diff(np.concatenate([starts, [time_s.size]]))
    within = np.arange(time_s.size) - np.repeat(starts, sizes)
    spread = np.repeat(stamps, sizes) + within * np.repeat((ends - stamps) / sizes, sizes)
    return spread, int(time_s.size - starts.size)


def write_rolling_folder(logs: list[Path], mapping: ImportMapping, out: Path) -> list[RollingLog]:
    """Import every log as a rolling log (`import_rolling`) and write them, one segment each, as the rolling folder
    ``out`` (`ilcpmac.bench.rolling`).

    Nothing is written unless every log imports; a folder that holds a bench.toml already is refused.
    """
    _check_new(out)
    _check_distinct(logs)
    if mapping.layout.kind == "scan":
        raise BenchFormatError(f'{mapping.path}: [log] kind = "scan": a scan makes a scan folder (write_scan_folder)')
    kept = [import_rolling(log, mapping) for log in logs]
    def joined(parts: list[np.ndarray | None]) -> np.ndarray | None:
        present = [part for part in parts if part is not None]
        return np.concatenate(present) if present else None

    data = RollingData(np.concatenate([r.data.time_s for r in kept]),
                       np.concatenate([r.data.position_counts for r in kept]),
                       np.concatenate([r.data.segment + k for k, r in enumerate(kept)]),
                       joined([r.data.i_q_a for r in kept]), joined([r.data.currents_a for r in kept]),
                       joined([r.data.torque_nm for r in kept]))
    settings = RollingSettings(current=mapping.layout.current, current_filter_s=mapping.layout.current_filter_s,
                               angle_offset_rad=mapping.layout.angle_offset_rad,
                               logs=tuple(r.log.name for r in kept), first_lines=tuple(r.lines[0] for r in kept),
                               last_lines=tuple(r.lines[1] for r in kept),
                               cut_start_s=tuple(float(f"{r.cut_start_s:.6g}") for r in kept),
                               cut_end_s=tuple(float(f"{r.cut_end_s:.6g}") for r in kept))
    motor = dataclasses.replace(mapping.motor, torque_sensor=mapping.layout.torque is not None,
                                log_rate_hz=float(f"{min(r.row_rate_hz for r in kept):.6g}"))
    write_rolling(out, motor, mapping.backemf_nm_per_a, mapping.sensors, settings, data)
    return kept


def _check_new(folder: Path) -> None:
    """``folder`` must not hold a bench.toml yet."""
    if (folder / BENCH_FILE).exists():
        raise BenchFormatError(f"{folder}: holds a {BENCH_FILE} already (refused: choose a new folder)")


def _check_distinct(logs: list[Path]) -> None:
    """Each log given once (a bench folder holds each trial once)."""
    seen: dict[object, Path] = {}
    for log in logs:
        identity = _file_identity(log)
        if identity in seen:
            raise BenchFormatError(f"{log}: given twice (as {seen[identity]} before): each log is imported once")
        seen[identity] = log


def _check_points(logs: list[Path], mapping: ImportMapping) -> None:
    """Every [[points]] file among the logs, once."""
    names = [log.name for log in logs]
    for name in mapping.points:
        if names.count(name) != 1:
            raise ConfigError(f"{mapping.path}: [[points]] file {shown(name)}: " + (
                f"not among the logs given ({shown(names)})" if name not in names else
                f"names {names.count(name)} of the logs given (rename them apart)"))


def _file_identity(path: Path) -> object:
    """What tells two paths of one file from two files: its device and inode, else its absolute path."""
    try:
        status = os.stat(path)
    except (OSError, ValueError):
        return os.path.abspath(path)
    return status.st_dev, status.st_ino


def _operating_point(where: str, count: np.ndarray, time_s: np.ndarray, currents: np.ndarray,
                     backemf_nm_per_a: np.ndarray, mapping: ImportMapping) -> tuple[float, float]:
    """(torque N m, speed Hz) of a lap [[points]] does not list, to 3 significant digits: the mean of
    K(count) . i_ref (the current law's torque reference; for a mirrored lap, the mirror's table and counts
    give the motor's reference negated) and the mean speed."""
    cpr = mapping.motor.counts_per_rev
    torque = mean_torque_reference_nm(count, currents, backemf_nm_per_a)
    speed = (count[-1] - count[0]) / cpr / (time_s[-1] - time_s[0])
    if torque <= 0:
        raise BenchFormatError(f"{where}: the mean torque reference is {torque:.3g} N m in the direction of motion: "
                               f"give the log's operating point in [[points]] of {mapping.path}")
    return float(f"{torque:.3g}"), float(f"{speed:.3g}")


def reverse_folder(out: Path) -> Path:
    """The folder of the reverse laps of an import into ``out``: its path with "-reverse" appended."""
    path = os.path.normpath(out)
    if os.path.basename(path) in (".", ".."):
        path = os.path.abspath(path)
    return Path(path + "-reverse")


def import_logs(logs: list[Path], mapping: ImportMapping, out: Path, suffix: str = ".csv") -> list[ImportedBench]:
    """Import every log's laps (`import_laps`), then write the forward laps as the bench folder ``out`` and the
    reverse ones, mirrored, as ``reverse_folder(out)`` (trial_01 ... in the format of ``suffix``, in the order
    of the logs and their laps), each only if it gets a lap.

    Nothing is written unless every log imports; a folder that holds a bench.toml already is refused.
    """
    _check_distinct(logs)
    _check_points(logs, mapping)
    if mapping.layout.kind == "scan":
        raise BenchFormatError(f'{mapping.path}: [log] kind = "scan": a scan makes a scan folder (write_scan_folder)')
    imported = [lap for log in logs for lap in import_laps(log, mapping)]
    parts = [(folder, laps) for folder, reverse in ((out, False), (reverse_folder(out), True))
             if (laps := tuple(lap for lap in imported if lap.reverse == reverse))]
    for folder, _ in parts:
        _check_new(folder)
    written = []
    for folder, laps in parts:
        motor = bench_motor(mapping, laps)
        backemf = mirrored_table(mapping.backemf_nm_per_a) if motor.mirrored else mapping.backemf_nm_per_a
        bench = Bench(motor, backemf, mapping.sensors, tuple(lap.trial for lap in laps),
                      tuple(f"trial_{i:02d}{suffix}" for i in range(1, len(laps) + 1)))
        write_bench(folder, bench)
        written.append(ImportedBench(folder, bench, laps))
    return written


def bench_motor(mapping: ImportMapping, imported: Sequence[ImportedLog]) -> MotorInfo:
    """[motor] of the bench that laps of one direction make: mirrored for reverse laps; log_rate_hz the slowest
    lap's row rate (it bounds the harmonics the acceleration method resolves); without torque,
    torque_sensor = false and timer_resolution_s the finest of the laps' `stamp_resolution_s` (one value per
    bench: the floor of the encoder-derived torque's weights, which an understated value leaves to the
    measured scatter and an overstated one would raise)."""
    motor = dataclasses.replace(mapping.motor, mirrored=imported[0].reverse,
                                log_rate_hz=float(f"{min(r.row_rate_hz for r in imported):.6g}"))
    if motor.torque_sensor:
        return motor
    return dataclasses.replace(motor, timer_resolution_s=min(r.stamp_resolution_s for r in imported))
