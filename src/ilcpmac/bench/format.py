"""Reader and writer of bench folders, exactly as docs/bench-format.md specifies.

A bench folder holds ``bench.toml`` ([motor], optional [sensors], [[trials]]),
``backemf.csv`` and one file per trial sampled once per encoder count: CSV, or
Parquet when its name ends in .parquet (`ilcpmac.bench.parquet`). Every
violation raises `BenchFormatError` naming the file and the line (row) or key.
"""

from __future__ import annotations

import math
import os
import re
import stat
from concurrent.futures import ThreadPoolExecutor
from dataclasses import astuple, dataclass, replace
from pathlib import Path, PurePosixPath

import numpy as np

from ilcpmac.bench import parquet
from ilcpmac.bench.fastcsv import format_rows, parse_rows
from ilcpmac.config import BACKEMF_TOLERANCE, BenchSettings, CampaignConfig
from ilcpmac.core.errors import BenchFormatError, ConfigError
from ilcpmac.core.files import atomic_write
from ilcpmac.core.records import (
    CURRENTS_FROM_I_Q,
    CURRENTS_FROM_PHASES,
    MAX_CALIBRATION,
    MAX_CURRENT_A,
    MAX_SPEED_HZ,
    MAX_TORQUE_NM,
    MotorInfo,
    SensorCalibration,
    TrialData,
    mirrored_table,
)
from ilcpmac.core.schema import (
    field_like,
    in_range,
    param,
    parse_section,
    read_toml,
    section_toml,
    setting,
    shown,
    unknown_key,
)
from ilcpmac.model.motor import Controller, Encoder, Mechanics, Winding
from ilcpmac.model.tables import backemf_table

BENCH_FILE = "bench.toml"
TRIAL_COLUMNS = ("count", "time", "i_ref_a", "i_ref_b", "i_ref_c", "torque")
#: the column a bench without a torque sensor ([motor] torque_sensor = false) leaves out, and must
TORQUE_COLUMN = "torque"
#: the decimals of the torque columns, measured and true, the finest a record keeps (`torque_decimals`)
_TORQUE_DECIMALS = 6
#: simulator-only columns (allowed and ignored by other readers)
EXTRA_COLUMNS = {
    "i_meas_a": ("i_meas_a", 3),
    "torque_true": ("torque_true_nm", 1),
    "i_true_a": ("i_true_a", 3),
    "speed_true": ("speed_true_rad_s", 1),
}
_PHASES = ("a", "b", "c")


def _column_names(prefix: str, width: int) -> list[str]:
    """The file columns of an EXTRA_COLUMNS entry: "i_meas_a" of width 3 is i_meas_a, i_meas_b, i_meas_c."""
    return [prefix[:-1] + ph for ph in _PHASES] if width == 3 else [prefix]


#: every column a reader takes from a trial file
_KNOWN_COLUMNS = frozenset(TRIAL_COLUMNS + tuple(
    n for prefix, (_, width) in EXTRA_COLUMNS.items() for n in _column_names(prefix, width)))
#: the unit of every column a trial file may have (docs/bench-format.md), by the unit of its TrialData attribute
COLUMN_UNITS = {name: {"count": "encoder count (unwrapped)", "time": "s", "torque": "N m", "speed_true": "rad/s"}.get(
    name, "N m" if name.startswith("torque") else "A") for name in sorted(_KNOWN_COLUMNS)}
#: the TrialData attribute of each quantity of three phases and its file columns
_PHASE_COLUMNS = {"i_ref_a": [f"i_ref_{ph}" for ph in _PHASES]} | {
    attr: _column_names(prefix, width) for prefix, (attr, width) in EXTRA_COLUMNS.items() if width == 3}
#: most revolutions of one trial: its rows are at most this many times counts_per_rev ...
MAX_REVOLUTIONS = 1024
#: ... and never more than this many
MAX_TRIAL_ROWS = 2**22
#: bytes a CSV file may take per row (on average), and in its header line
MAX_ROW_BYTES = 256
MAX_HEADER_BYTES = 4096
#: trial files `read_bench` reads at once (pyarrow, the CSV kernel and NumPy release the GIL as they read)
READERS = 2
#: counts a trial may span per row (a logger skips counts at high speed, never most of them)
MAX_SPAN_PER_ROW = 4
#: largest count magnitude (integers beyond are not exact in a double)
MAX_COUNT = 2**53
#: how far (a factor) the speed given by counts and time stamps may lie from the speed set point
SPEED_TOLERANCE = 1.5
#: how far (a factor) a trial's torque set point may lie from the mean torque its current references ask for
SETPOINT_TOLERANCE = 2.0
#: largest timer resolution of the time stamps, s
MAX_TIMER_RESOLUTION_S = 1e-3
#: the tables of bench.toml
_TABLES = ("motor", "sensors", "static", "trials")
#: the columns of a static trial's file (`read_static_csv`), and its most rows
STATIC_COLUMNS = ["count", "i_ref_a", "i_ref_b", "i_ref_c", "torque"]
MAX_STATIC_ROWS = 10_000


def _inside_folder(name: str) -> bool:
    """A relative path without "..", so that nothing outside the bench folder is ever opened."""
    path = PurePosixPath(name)
    return bool(name) and "\\" not in name and "\0" not in name and not path.is_absolute() and ".." not in path.parts


def _file(what: str):
    return param(_inside_folder, f"{what}, a relative path inside the bench folder (no leading '/', no '..')")


@dataclass(frozen=True)
class MotorTable:
    """bench.toml's [motor] table: `MotorInfo` and the back-EMF table's file (docs/bench-format.md)."""

    pole_pairs: int = field_like(Winding, "pole_pairs")
    slots: int = field_like(Winding, "slots")
    counts_per_rev: int = field_like(Encoder, "counts_per_rev")
    inertia: float = field_like(Mechanics, "inertia_kgm2")
    backemf_file: str = _file("the back-EMF table (backemf.csv)")
    torque_sensor: bool = setting(None, "whether the trials carry the torque sensor's column", True)
    timer_resolution_s: float | None = field_like(Encoder, "timer_resolution_s", default=None)
    mirrored: bool = setting(None, "reverse laps, stored as forward laps of the motor's mirror image", False,
                             commented=True)
    currents: str = setting(lambda x: x in (CURRENTS_FROM_PHASES, CURRENTS_FROM_I_Q),
                            f'"{CURRENTS_FROM_PHASES}" (logged per phase) or "{CURRENTS_FROM_I_Q}" (made from a q-axis '
                            "current: no electrical-period check)", CURRENTS_FROM_PHASES, commented=True)
    inertia_uncertainty: float | None = field_like(BenchSettings, "inertia_uncertainty", default=None)
    log_rate_hz: float | None = setting(in_range(0.0, 1e9, low_open=True), "row rate of the drive logs the trials "
                                        "were resampled from, Hz (written by ilcpmac import)", None, commented=True)
    lines_per_count: int = setting(in_range(1, 2**20), "encoder lines each count is the mean over, centred on it "
                                   "(1: each count the value at its edge)", 1, commented=True)

    @classmethod
    def of(cls, motor: MotorInfo, backemf_file: str) -> MotorTable:
        """The table of ``motor`` and its back-EMF table's file."""
        return cls(motor.pole_pairs, motor.slots, motor.counts_per_rev, motor.inertia_kgm2, backemf_file,
                   motor.torque_sensor, motor.timer_resolution_s, motor.mirrored, motor.currents,
                   motor.inertia_uncertainty, motor.log_rate_hz, motor.lines_per_count)

    def info(self) -> MotorInfo:
        """The motor this table describes."""
        return MotorInfo(self.pole_pairs, self.slots, self.counts_per_rev, self.inertia, self.torque_sensor,
                         self.timer_resolution_s, self.mirrored, self.currents, self.inertia_uncertainty,
                         self.log_rate_hz, self.lines_per_count)


@dataclass(frozen=True)
class SensorTable:
    """bench.toml's [sensors] table, and compensation.json's "calibration": a `SensorCalibration`."""

    current_scale: tuple[float, ...] = field_like(Controller, "current_scale_counts_per_a")
    current_offset: tuple[float, ...] = field_like(Controller, "current_offset_counts")
    torque_gain: float = param(in_range(0.0, MAX_CALIBRATION, low_open=True),
                               f"g*_t, V / N m, within (0, {MAX_CALIBRATION:g}]")

    def calibration(self) -> SensorCalibration:
        """The calibration this table holds."""
        return SensorCalibration(*astuple(self))


@dataclass(frozen=True)
class StaticTable:
    """bench.toml's optional [static] table: the static trial's file (docs/bench-format.md, "Static trial")."""

    file: str = _file("the static trial's file (static.csv)")


@dataclass(frozen=True)
class StaticTrial:
    """A static trial: the rotor held at rest, the drive commanding currents, a DC-capable reference (a lever on a
    scale, a reaction torque sensor) measuring the torque it makes (`ilcpmac.identify.static`).

    Attributes
    ----------
    count : ndarray of int, shape (n,)
        The encoder count the rotor is held at, 0 .. counts_per_rev - 1.
    i_ref_a : ndarray, shape (n, 3)
        The phase current references, A, at the bench's calibration ([sensors]).
    torque_nm : ndarray, shape (n,)
        The torque the reference measured, N m, positive in the direction of increasing counts.
    """

    count: np.ndarray
    i_ref_a: np.ndarray
    torque_nm: np.ndarray


@dataclass(frozen=True)
class TrialEntry:
    """One [[trials]] entry of bench.toml."""

    file: str = _file("the trial's file")
    torque_setpoint: float = param(lambda x: in_range(-MAX_TORQUE_NM, MAX_TORQUE_NM)(x) and x != 0,
                                   f"the torque set point, N m, within [-{MAX_TORQUE_NM:g}, {MAX_TORQUE_NM:g}], not 0 "
                                   "(negative: generating, at a positive speed)")
    speed_setpoint: float = param(in_range(0.0, MAX_SPEED_HZ, low_open=True),
                                  f"the speed set point, Hz, within (0, {MAX_SPEED_HZ:g}]")


@dataclass(frozen=True)
class Bench:
    """A bench folder in memory.

    Attributes
    ----------
    motor : MotorInfo
    backemf_nm_per_a : ndarray, shape (counts_per_rev, 3)
        K per phase and encoder count, N m / A.
    sensors : SensorCalibration or None
        The calibration the controller used while recording.
    trials : tuple of TrialData
    trial_files : tuple of str
        File name of each trial, relative to the folder.
    static : StaticTrial or None
        The static trial ([static] of bench.toml), which pins eps (`ilcpmac.identify.static`); None: none.
    static_file : str
        Its file, relative to the folder.
    """

    motor: MotorInfo
    backemf_nm_per_a: np.ndarray
    sensors: SensorCalibration | None
    trials: tuple[TrialData, ...]
    trial_files: tuple[str, ...]
    static: StaticTrial | None = None
    static_file: str = "static.csv"


# ---------------------------------------------------------------- reading


def _inside(path: Path, root: Path) -> Path:
    """``path`` with its symbolic links resolved, which must lie in the folder ``root`` (itself resolved)."""
    try:
        real = path.resolve()
    except (OSError, RuntimeError) as e:
        raise BenchFormatError(f"{path}: cannot resolve ({getattr(e, 'strerror', None) or e})") from None
    if not real.is_relative_to(root):
        raise BenchFormatError(f"{path}: is a symbolic link to outside the bench folder (refused)")
    return real


def _regular_file(path: Path, max_bytes: int | None) -> None:
    """``path`` must be a regular file of at most ``max_bytes``: FIFOs, devices and folders are refused unopened."""
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise BenchFormatError(f"{path}: no such file") from None
    except (OSError, ValueError) as e:
        raise BenchFormatError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    if not stat.S_ISREG(info.st_mode):
        raise BenchFormatError(f"{path}: not a regular file (a folder, FIFO or device is refused)")
    if max_bytes is not None and info.st_size > max_bytes:
        raise BenchFormatError(f"{path}: {info.st_size} bytes, more than the {max_bytes} its rows may take "
                               f"(at most {MAX_ROW_BYTES} bytes per row, see docs/bench-format.md)")


def _shortened(text: str, limit: int = 120) -> str:
    """``text`` cut to ``limit`` characters, so that a message stays one short line."""
    return text if len(text) <= limit else text[:limit] + "..."


def _rest(f) -> np.ndarray:
    """The rest of the open binary file ``f``, read-only, read straight into an array of the size the file has left
    (and to its end should it have grown)."""
    rest = np.empty(max(os.fstat(f.fileno()).st_size - f.tell(), 0) + 1, np.uint8)
    used = f.readinto(rest)
    text = rest[:used] if used < rest.size else np.concatenate([rest, np.frombuffer(f.read(), np.uint8)])
    text.flags.writeable = False
    return text


def _read_csv(path: Path, max_rows: int, expected: list[str] | None = None) -> tuple[list[str], np.ndarray]:
    """Header and float rows of a CSV of at most ``max_rows`` rows; bad rows raise naming file and line.

    The file's size is checked against ``max_rows`` before it is opened, the
    header line is read with a bounded readline and must be ``expected`` when
    given (before any row is parsed), and no more than ``max_rows`` + 1 rows
    are ever parsed. Plain decimal numbers are parsed by `parse_rows` (always
    finite); anything else by numpy (a ``#`` is no comment: a value that is
    not a number), whose errors name the line and column (`loadtxt_problem`),
    and then checked to be finite. No message quotes the file's text.
    """
    _regular_file(path, MAX_HEADER_BYTES + max_rows * MAX_ROW_BYTES)
    try:
        with open(path, "rb") as f:
            header_line = f.readline(MAX_HEADER_BYTES)
            if len(header_line) == MAX_HEADER_BYTES and not header_line.endswith(b"\n"):
                raise BenchFormatError(f"{path}: line 1: no end of the header line in {MAX_HEADER_BYTES} bytes")
            try:
                header = [h.strip() for h in header_line.decode().strip().split(",")]
            except UnicodeDecodeError:
                raise BenchFormatError(f"{path}: line 1: the header is not UTF-8 text") from None
            if expected is not None and header != expected:
                raise BenchFormatError(f"{path}: line 1: header must be {','.join(expected)}")
            body = f.tell()
            data = parse_rows(_rest(f), len(header), max_rows)
            parsed = data is not None
            if data is None:
                f.seek(body)
                try:
                    data = np.loadtxt(f, delimiter=",", ndmin=2, dtype=float, max_rows=max_rows + 1,
                                      comments=None)
                except ValueError as e:
                    raise BenchFormatError(f"{path}: {loadtxt_problem(e, header, ',', 1)}") from None
    except OSError as e:
        raise BenchFormatError(f"{path}: cannot read ({e.strerror or e})") from None
    if data.shape[0] > max_rows:
        raise BenchFormatError(f"{path}: more than {max_rows} rows (docs/bench-format.md)")
    if data.size and data.shape[1] != len(header):
        raise BenchFormatError(f"{path}: line 2 has {data.shape[1]} fields, the header has {len(header)}")
    if data.size == 0:
        data = np.zeros((0, len(header)))
    if not parsed:
        _check_finite(path, header, data, _csv_line)
    return header, data


def loadtxt_problem(e: ValueError, header: list[str], delimiter: str, header_lines: int) -> str:
    """A numpy loadtxt error of rows under ``header_lines`` lines, the last naming the columns ``header``: the
    file line and column at fault, without the file's text (a file named by mistake, a password file say,
    must not show in a message).

    numpy counts data rows from 0 when a value does not convert, but from 1
    when a row's number of fields differs from the first data row's (which
    may itself be the row at fault).
    """
    text = str(e)
    m = re.search(r"number of columns changed from (\d+) to (\d+) at row (\d+)", text)
    if m:
        first, fields, row = (int(g) for g in m.groups())
        if first != len(header):
            return f"line {header_lines + 1} has {first} fields, the header has {len(header)}"
        return f"line {row + header_lines} has {fields} fields, the header has {len(header)}"
    m = re.search(r"(?:at|in) row (\d+), column (\d+)", text)
    if m:
        row, column = (int(g) for g in m.groups())
        name = f" ({_shortened(header[column - 1], 40)})" if column <= len(header) else ""
        return f"line {row + header_lines + 1}, column {column}{name}: not a number"
    return f"not rows of {len(header)} numbers separated by {delimiter!r}"


def _dominant_harmonic(table: np.ndarray) -> int:
    """The harmonic (of one revolution) with the largest amplitude, summed over the table's columns."""
    spectrum = np.abs(np.fft.rfft(table, axis=0)).sum(axis=1)
    spectrum[0] = 0.0
    return int(np.argmax(spectrum))


def _electrical_periods(currents_a: np.ndarray) -> float:
    """Electrical periods per revolution of three phase currents, shape (n, 3), one row per count of a revolution.

    The space vector i_s = 2/3 (i_a + a i_b + a^2 i_c), a = e^{j 2 pi / 3}, of currents i_q(theta) along an axis
    turning p times per revolution is i_q(theta) e^{j (p theta + phi)}; its square's largest harmonic is 2p
    whatever the ripple of i_q (its mean square m^2 + r^2 / 2 outweighs every sideband: m r, r^2 / 4 for
    i_q = m + r cos(k theta)), where the currents' own largest harmonic is a sideband p +- k once the ripple
    r exceeds the mean m (a speed loop against cogging).
    """
    space = currents_a @ (2.0 / 3.0 * np.exp(2j * np.pi * np.arange(3) / 3.0))
    spectrum = np.abs(np.fft.fft(space**2))
    spectrum[0] = 0.0
    order = int(np.argmax(spectrum))
    return min(order, spectrum.size - order) / 2


def read_backemf_csv(path: Path, motor: MotorInfo) -> np.ndarray:
    """A back-EMF table (count,k_a,k_b,k_c, one row per count), N m / A, checked against ``motor``."""
    _, data = _read_csv(path, motor.counts_per_rev, ["count", "k_a", "k_b", "k_c"])
    if data.shape[0] != motor.counts_per_rev:
        raise BenchFormatError(f"{path}: has {data.shape[0]} rows, expected counts_per_rev = {motor.counts_per_rev}")
    wrong = np.flatnonzero(data[:, 0] != np.arange(motor.counts_per_rev))
    if wrong.size:
        raise BenchFormatError(f"{path}: line {wrong[0] + 2}: count must be {wrong[0]}, got {data[wrong[0], 0]:g}")
    backemf = np.ascontiguousarray(data[:, 1:])
    check_backemf(backemf, motor, str(path))
    return backemf


def read_static_csv(path: Path, motor: MotorInfo) -> StaticTrial:
    """A static trial's file (`STATIC_COLUMNS`, at most `MAX_STATIC_ROWS` rows): each count a whole count of the
    revolution, each current and the torque finite and within `MAX_CURRENT_A` and `MAX_TORQUE_NM`; a
    `BenchFormatError` naming the file and the line otherwise."""
    _, data = _read_csv(path, MAX_STATIC_ROWS, STATIC_COLUMNS)
    if data.shape[0] == 0:
        raise BenchFormatError(f"{path}: no rows")
    count = data[:, 0]
    bad = np.flatnonzero((count != np.round(count)) | (count < 0) | (count >= motor.counts_per_rev))
    if bad.size:
        raise BenchFormatError(f"{path}: line {bad[0] + 2}: count must be a whole count within 0 .. "
                               f"{motor.counts_per_rev - 1} (counts_per_rev {motor.counts_per_rev}), got "
                               f"{count[bad[0]]:g}")
    for columns, bound in ((slice(1, 4), MAX_CURRENT_A), (slice(4, 5), MAX_TORQUE_NM)):
        row, col = np.unravel_index(np.argmax(np.abs(data[:, columns])), data[:, columns].shape)
        if abs(data[row, columns][col]) > bound:
            raise BenchFormatError(f"{path}: line {row + 2}: |{STATIC_COLUMNS[columns.start + col]}| must be at "
                                   f"most {bound:g}, got {data[row, columns][col]:g}")
    return StaticTrial(count.astype(np.int64), np.ascontiguousarray(data[:, 1:4]), np.ascontiguousarray(data[:, 4]))


def write_static_csv(path: Path, trial: StaticTrial) -> None:
    """Write a static trial's file: count,i_ref_a,i_ref_b,i_ref_c,torque, one row per sample."""
    _write_csv(path, STATIC_COLUMNS, [trial.count, trial.i_ref_a, trial.torque_nm], [0, 9, 9, 9, 9])


def check_backemf(backemf_nm_per_a: np.ndarray, motor: MotorInfo, where: str) -> None:
    """Each phase's K must be non-zero and its fundamental at ``pole_pairs`` per revolution.

    Raises
    ------
    BenchFormatError
        Naming ``where`` (the file) and the column or key.
    """
    for p, phase in enumerate(_PHASES):
        if not np.any(backemf_nm_per_a[:, p]):
            raise BenchFormatError(f"{where}: k_{phase} is zero at every count")
    dominant = _dominant_harmonic(backemf_nm_per_a)
    if dominant != motor.pole_pairs:
        raise BenchFormatError(f"{where}: the back-EMF repeats {dominant} times per revolution of "
                               f"{motor.counts_per_rev} counts, but [motor] pole_pairs = {motor.pole_pairs}")


def mean_torque_reference_nm(count: np.ndarray, currents_a: np.ndarray, backemf_nm_per_a: np.ndarray) -> float:
    """The mean of K(count) . i_ref over a trial's rows: the torque the current references ask for, N m."""
    return float(np.mean(np.sum(backemf_nm_per_a[count % backemf_nm_per_a.shape[0]] * currents_a, axis=1)))


def check_torque_setpoint(trial: TrialData, backemf_nm_per_a: np.ndarray, key: str, where: str) -> None:
    """The trial's torque set point (named by ``key``) within a factor `SETPOINT_TOLERANCE` of the mean torque
    its current references ask for (`mean_torque_reference_nm`; the torque sensor's mean is no measure: a piezo
    holds no DC).

    Raises
    ------
    BenchFormatError
        Naming ``key``, with ``where`` naming the trial's data.
    """
    asked = mean_torque_reference_nm(trial.count, trial.i_ref_a, backemf_nm_per_a)
    if not 1.0 / SETPOINT_TOLERANCE <= asked / trial.torque_setpoint_nm <= SETPOINT_TOLERANCE:
        raise BenchFormatError(
            f"{key}: {trial.torque_setpoint_nm:g} N m, but the current references of {where} ask for "
            f"{asked:.3g} N m on average (K . i_ref), more than {SETPOINT_TOLERANCE:g}x apart (wrong set point, "
            "current unit or back-EMF table?)")


def _csv_line(row: int) -> str:
    """Row ``row`` (0-based, -1 the header) of a CSV: its file line."""
    return f"line {row + 2}"


def _parquet_row(row: int) -> str:
    """Row ``row`` (0-based, -1 the schema) of a Parquet file, counted from 1."""
    return "schema" if row < 0 else f"row {row + 1}"


def _check_finite(path: Path, header: list[str], data: np.ndarray, line) -> None:
    """Every value must be finite; ``line`` names row i of the file."""
    bad = np.argwhere(~np.isfinite(data))
    if bad.size:
        row, col = bad[0]
        raise BenchFormatError(f"{path}: {line(row)}: {_shortened(header[col])} is not a finite number")


def read_trial(path: Path, torque_setpoint_nm: float, speed_setpoint_hz: float,
               max_rows: int = MAX_TRIAL_ROWS, torque_sensor: bool = True, extras: bool = True) -> TrialData:
    """Read one trial file: Parquet when its name ends in .parquet, else CSV (docs/bench-format.md).

    A file larger than ``max_rows`` rows may take is refused before it is read. Without a
    ``torque_sensor`` the file must have no torque column, with one it must. Without ``extras``
    the simulator's columns (EXTRA_COLUMNS) are left out: a Parquet file's are never read.
    """
    if path.suffix != parquet.SUFFIX:
        return read_trial_csv(path, torque_setpoint_nm, speed_setpoint_hz, max_rows, torque_sensor, extras)
    _regular_file(path, MAX_HEADER_BYTES + max_rows * MAX_ROW_BYTES)
    blocks = {}

    def allocate(header: list[str], rows: int) -> list[np.ndarray]:
        blocks.update({attr: np.empty((rows, 3)) for attr, names in _PHASE_COLUMNS.items()
                       if all(n in header for n in names)})
        where = {n: blocks[attr][:, k] for attr in blocks for k, n in enumerate(_PHASE_COLUMNS[attr])}
        return [where[n] if n in where else np.empty(rows) for n in header]

    header, columns = parquet.read_columns(path, max_rows, _KNOWN_COLUMNS if extras else TRIAL_COLUMNS, allocate)
    return _trial(path, header, columns, blocks, torque_setpoint_nm, speed_setpoint_hz, _parquet_row,
                  torque_sensor, extras)


def read_trial_csv(path: Path, torque_setpoint_nm: float, speed_setpoint_hz: float,
                   max_rows: int = MAX_TRIAL_ROWS, torque_sensor: bool = True, extras: bool = True) -> TrialData:
    """Read one trial CSV (required columns in any order; others ignored unless known extras, and those too
    without ``extras``).

    A file larger than ``max_rows`` rows may take is refused before it is read.
    """
    header, data = _read_csv(path, max_rows)
    blocks = {attr: np.take(data, [header.index(n) for n in names], axis=1)
              for attr, names in _PHASE_COLUMNS.items() if all(n in header for n in names) and (
                  extras or attr == "i_ref_a")}
    return _trial(path, header, list(data.T), blocks, torque_setpoint_nm, speed_setpoint_hz, _csv_line,
                  torque_sensor, extras)


def _torque_column_problem(has_column: bool, torque_sensor: bool) -> str | None:
    """Why a trial with (or without) a torque column does not fit a bench with (or without) a torque sensor."""
    if torque_sensor and not has_column:
        return f"missing column {TORQUE_COLUMN!r} (a bench without a torque sensor says [motor] torque_sensor = false)"
    if has_column and not torque_sensor:
        return f"has a {TORQUE_COLUMN!r} column, but bench.toml says [motor] torque_sensor = false"
    return None


def _trial(path: Path, header: list[str], columns: list[np.ndarray], blocks: dict[str, np.ndarray],
           torque_setpoint_nm: float, speed_setpoint_hz: float, line, torque_sensor: bool,
           extras: bool) -> TrialData:
    """The trial in ``columns`` (one 1-D array per ``header`` name), with the simulator's columns if ``extras``;
    ``blocks`` holds the (rows, 3) array of each quantity of three phases, by TrialData attribute; ``line`` names
    row i of the file."""
    missing = [c for c in TRIAL_COLUMNS if c not in header and c != TORQUE_COLUMN]
    if missing:
        raise BenchFormatError(f"{path}: {line(-1)}: missing column {missing[0]!r}")
    problem = _torque_column_problem(TORQUE_COLUMN in header, torque_sensor)
    if problem:
        raise BenchFormatError(f"{path}: {line(-1)}: {problem}")
    dup = sorted({c for c in header if header.count(c) > 1})
    if dup:
        raise BenchFormatError(f"{path}: {line(-1)}: column {_shortened(dup[0])!r} appears twice")
    col = dict(zip(header, columns))
    count = col["count"]
    if count.size < 2:
        raise BenchFormatError(f"{path}: needs at least 2 rows, has {count.size}")
    counts = count.astype(np.int64) if -MAX_COUNT <= count.min() and count.max() <= MAX_COUNT else None
    if counts is None or not np.array_equal(counts, count):
        bad = (count != np.round(count)) | (np.abs(count) > MAX_COUNT)
        raise BenchFormatError(f"{path}: {line(int(np.flatnonzero(bad)[0]))}: count must be an integer of "
                               "magnitude at most 2^53")
    for name in ("count", "time"):
        if not np.all(col[name][1:] > col[name][:-1]):
            raise BenchFormatError(f"{path}: {line(int(np.flatnonzero(np.diff(col[name]) <= 0)[0]) + 1)}: {name} "
                                   "does not increase")
    span = count[-1] - count[0]
    if span > MAX_SPAN_PER_ROW * (count.size - 1):
        raise BenchFormatError(f"{path}: {line(int(np.argmax(np.diff(count))) + 1)}: count jumps by "
                               f"{np.diff(count).max():.0f}; a trial's counts may span at most {MAX_SPAN_PER_ROW} "
                               f"per row ({count.size} rows span {span:.0f})")
    kept = {attr: blocks[attr] if width == 3 else col[prefix] for prefix, (attr, width) in EXTRA_COLUMNS.items()
            if extras and (attr in blocks if width == 3 else prefix in col)}
    return TrialData(torque_setpoint_nm=torque_setpoint_nm, speed_setpoint_hz=speed_setpoint_hz, count=counts,
                     time_s=col["time"], i_ref_a=blocks["i_ref_a"], torque_nm=col.get(TORQUE_COLUMN),
                     i_meas_a=kept.get("i_meas_a"), torque_true_nm=kept.get("torque_true_nm"),
                     i_true_a=kept.get("i_true_a"), speed_true_rad_s=kept.get("speed_true_rad_s"))


def _range(values: np.ndarray) -> tuple[float, float]:
    """The smallest and largest of ``values`` (NaN if one is NaN, or if there are none)."""
    return (values.min(), values.max()) if values.size else (np.nan, np.nan)


def check_trial(trial: TrialData, motor: MotorInfo, where: str) -> None:
    """A trial must carry data and fit the declared motor: its speed and its electrical period.

    Every value must be finite; no current reference may be zero throughout,
    nor the torque (which it has exactly when ``motor.torque_sensor``). The
    counts and time stamps give the mean speed at ``counts_per_rev``; it must lie within a factor SPEED_TOLERANCE of the
    speed set point (a wrong counts_per_rev or time unit does not). Over a
    revolution or more, the current references must turn ``pole_pairs`` electrical periods per revolution,
    whatever their ripple (`_electrical_periods`); not checked for references made from i_q (``motor.currents``
    = `CURRENTS_FROM_I_Q`: the period is the one the inverse Park transform put in).

    Raises
    ------
    BenchFormatError
        Naming ``where`` (the file) and the column or key at odds with the data.
    """
    problem = _torque_column_problem(trial.torque_nm is not None, motor.torque_sensor)
    if problem:
        raise BenchFormatError(f"{where}: {problem}")
    columns = [("time", trial.time_s), ("i_ref", trial.i_ref_a), ("torque", trial.torque_nm)]
    ranges = {name: _range(values) for name, values in columns if values is not None}
    for name, values in columns:
        if values is None or np.isfinite(ranges[name]).all():
            continue
        bad = np.flatnonzero(~np.isfinite(values.reshape(values.shape[0], -1)).all(axis=1))
        if len(bad):
            raise BenchFormatError(f"{where}: sample {bad[0]}: {name} is not a finite number")
    for name, values, bound, unit in (("i_ref", trial.i_ref_a, MAX_CURRENT_A, "A"),
                                      ("torque", trial.torque_nm, MAX_TORQUE_NM, "N m")):
        if values is None or -bound <= ranges[name][0] and ranges[name][1] <= bound:
            continue
        big = np.flatnonzero(np.abs(values.reshape(values.shape[0], -1)).max(axis=1) > bound)
        if big.size:
            raise BenchFormatError(f"{where}: sample {big[0]}: {name} beyond {bound:g} {unit}, more than any "
                                   "motor a bench drives (wrong unit or scale?)")
    for p, phase in enumerate(_PHASES):
        if not np.any(trial.i_ref_a[:, p]):
            raise BenchFormatError(f"{where}: i_ref_{phase} is zero on every line")
    if trial.torque_nm is not None and ranges["torque"][0] == ranges["torque"][1]:
        raise BenchFormatError(f"{where}: torque is {trial.torque_nm[0]:g} on every line (the sensor recorded "
                               "nothing)")
    cpr = motor.counts_per_rev
    span = int(trial.count[-1] - trial.count[0])
    speed_hz = span / cpr / (trial.time_s[-1] - trial.time_s[0])
    ratio = speed_hz / trial.speed_setpoint_hz
    if not 1.0 / SPEED_TOLERANCE <= ratio <= SPEED_TOLERANCE:
        raise BenchFormatError(
            f"{where}: counts and time stamps give {speed_hz:.4g} revolutions per second at [motor] counts_per_rev "
            f"= {cpr}, but speed_setpoint = {trial.speed_setpoint_hz:g} Hz (wrong counts_per_rev or time unit?)")
    if span + 1 < cpr or motor.currents == CURRENTS_FROM_I_Q:
        return
    position = trial.count % cpr
    hits = np.maximum(np.bincount(position, minlength=cpr), 1)
    table = np.stack([np.bincount(position, weights=trial.i_ref_a[:, p], minlength=cpr) / hits
                      for p in range(3)], axis=1)
    dominant = _electrical_periods(table)
    if dominant != motor.pole_pairs:
        raise BenchFormatError(
            f"{where}: the current references repeat {dominant:g} times per revolution of {cpr} counts, but "
            f"[motor] pole_pairs = {motor.pole_pairs} (wrong pole_pairs or counts_per_rev?)")


def _motor(table, source: str) -> tuple[MotorInfo, str]:
    """The [motor] table, with at least 4 counts per electrical period; and the back-EMF file's name."""
    motor = parse_section(table, MotorTable, source, "motor", error=BenchFormatError)
    if motor.counts_per_rev < 4 * motor.pole_pairs:
        raise BenchFormatError(f"{source}: [motor] counts_per_rev: must be at least 4 per electrical period "
                               f"(4 x pole_pairs = {4 * motor.pole_pairs}), got {motor.counts_per_rev}")
    return motor.info(), str(PurePosixPath(motor.backemf_file))


@dataclass(frozen=True)
class BenchHead:
    """A bench folder without its trials: bench.toml read and checked, and backemf.csv.

    Attributes
    ----------
    motor : MotorInfo
    backemf_nm_per_a : ndarray, shape (counts_per_rev, 3)
    sensors : SensorCalibration or None
    entries : the raw [[trials]] entries of bench.toml (checked by `read_bench`).
    """

    motor: MotorInfo
    backemf_nm_per_a: np.ndarray
    sensors: SensorCalibration | None
    entries: object


def read_bench_head(folder: str | Path) -> BenchHead:
    """bench.toml and backemf.csv of ``folder``, with every check `read_bench` makes of them."""
    motor, backemf_path, sensors, entries, _ = _bench_toml(folder)
    return BenchHead(motor, read_backemf_csv(backemf_path, motor), sensors, entries)


def _bench_toml(folder: str | Path) -> tuple[MotorInfo, Path, SensorCalibration | None, object, str | None]:
    """`read_bench_head`'s motor, back-EMF file, sensors and [[trials]] entries (not yet checked), and the static
    trial's file ([static]; None: none), from bench.toml alone."""
    folder = Path(folder)
    if not folder.is_dir():
        raise BenchFormatError(f"{folder}: not a folder")
    root = folder.resolve()
    toml_path = folder / BENCH_FILE
    if not toml_path.exists():
        raise BenchFormatError(f"{toml_path}: no such file (a bench folder needs {BENCH_FILE})")
    _regular_file(_inside(toml_path, root), None)
    data = read_toml(toml_path, BenchFormatError)
    problem = unknown_key(data, _TABLES)
    if problem is not None:
        raise BenchFormatError(f"{toml_path}: {problem}")
    if "motor" not in data:
        raise BenchFormatError(f"{toml_path}: missing table [motor]")
    motor, backemf_file = _motor(data["motor"], str(toml_path))
    backemf_path = folder / backemf_file
    _inside(backemf_path, root)
    sensors = parse_section(data["sensors"], SensorTable, str(toml_path), "sensors",
                            error=BenchFormatError).calibration() if "sensors" in data else None
    static = None
    if "static" in data:
        static = str(PurePosixPath(parse_section(data["static"], StaticTable, str(toml_path), "static",
                                                 error=BenchFormatError).file))
        _inside(folder / static, root)
    return motor, backemf_path, sensors, data.get("trials"), static


def read_bench(folder: str | Path, extras: bool = True) -> Bench:
    """Read and validate a bench folder (docs/bench-format.md).

    Every file is a regular file inside the folder (symbolic links resolved),
    no larger than its rows may take; each trial is checked against the motor
    (`check_trial`), its torque set point against its current references
    (`check_torque_setpoint`) and the back-EMF against the pole pairs (`check_backemf`).
    The trials are read `READERS` at a time, while backemf.csv is read (its
    parser is the first use of numba in a process, GIL-bound: 0.3 s); the
    error raised is the one a reading in order, backemf.csv first, meets
    first. Without ``extras`` the trials leave out the simulator's columns
    (`read_trial`), which nothing but a simulation's own analysis uses: a
    Parquet bench reads in about half the time.
    """
    folder = Path(folder)
    motor, backemf_path, sensors, entries, static_file = _bench_toml(folder)
    root = folder.resolve()
    toml_path = folder / BENCH_FILE
    jobs: list[tuple[Path, float, float]] = []
    files: list[str] = []
    seen: dict[Path, int] = {}
    refusal: BenchFormatError | None = None
    if not isinstance(entries, list) or not entries:
        entries, refusal = [], BenchFormatError(f"{toml_path}: needs at least one [[trials]] entry")
    max_rows = min(MAX_REVOLUTIONS * motor.counts_per_rev, MAX_TRIAL_ROWS)
    for i, entry in enumerate(entries, start=1):
        label = f"[[trials]] #{i}"
        try:
            trial = parse_section(entry, TrialEntry, str(toml_path), "trials", error=BenchFormatError, label=label)
            name = str(PurePosixPath(trial.file))
            path = folder / name
            real = _inside(path, root)
            if real in seen:
                raise BenchFormatError(f"{toml_path}: {label}: file {name!r} is listed twice "
                                       f"(also [[trials]] #{seen[real]})")
        except BenchFormatError as e:
            refusal = e
            break
        seen[real] = i
        jobs.append((path, trial.torque_setpoint, trial.speed_setpoint))
        files.append(name)

    def read(job: tuple[Path, float, float]) -> TrialData:
        path, torque, speed = job
        trial = read_trial(path, torque, speed, max_rows, motor.torque_sensor, extras)
        check_trial(trial, motor, str(path))
        return trial

    pool = ThreadPoolExecutor(READERS)
    try:
        read_trials = pool.map(read, jobs)
        backemf = read_backemf_csv(backemf_path, motor)
        trials = []
        for i, (trial, (path, _, _)) in enumerate(zip(read_trials, jobs), start=1):
            check_torque_setpoint(trial, backemf, f"{toml_path}: [[trials]] #{i} torque_setpoint", str(path))
            trials.append(trial)
    finally:
        pool.shutdown(cancel_futures=True)
    if refusal is not None:
        raise refusal
    if static_file is None:
        return Bench(motor, backemf, sensors, tuple(trials), tuple(files))
    static = read_static_csv(folder / static_file, motor)
    return Bench(motor, backemf, sensors, tuple(trials), tuple(files), static, static_file)


# ---------------------------------------------------------------- writing


def bench_toml_text(motor: MotorInfo, sensors: SensorCalibration | None,
                    trials: list[tuple[str, float, float]], backemf_file: str = "backemf.csv",
                    static_file: str | None = None) -> str:
    """bench.toml text; ``trials`` lists (file, torque set point N m, speed set point Hz); ``static_file``: the
    static trial's ([static]; None: none)."""
    tables: list[tuple[str, object]] = [("[motor]", MotorTable.of(motor, backemf_file))]
    if sensors is not None:
        tables.append(("[sensors]", SensorTable(**sensors.to_json())))
    if static_file is not None:
        tables.append(("[static]", StaticTable(static_file)))
    tables += [("[[trials]]", TrialEntry(*trial)) for trial in trials]
    return "\n".join(f"{header}\n{section_toml(table)}" for header, table in tables)


def _write_csv(path: Path, header: list[str], columns: list[np.ndarray], decimals: list[int]) -> None:
    """Write a numeric CSV atomically, column c rounded to ``decimals[c]`` decimals."""
    body = format_rows(np.column_stack(columns), np.array(decimals))
    atomic_write(path, (",".join(header) + "\n").encode() + body)


def _trial_columns(trial: TrialData) -> list[tuple[list[str], str, int]]:
    """(CSV column names, TrialData attribute, decimals) of every column ``trial`` has.

    Times are written to 0.1 us, currents, torques and speeds to 1e-6 of
    their unit (far below any sensor's noise: the rounding adds 3e-7 RMS).
    """
    columns = [(["count"], "count", 0), (["time"], "time_s", 7), ([f"i_ref_{ph}" for ph in _PHASES], "i_ref_a", 6)]
    if trial.torque_nm is not None:
        columns.append(([TORQUE_COLUMN], "torque_nm", _TORQUE_DECIMALS))
    for prefix, (attr, width) in EXTRA_COLUMNS.items():
        if getattr(trial, attr) is not None:
            columns.append((_column_names(prefix, width), attr, 6))
    return columns


def _trial_table(trial: TrialData) -> tuple[list[str], list[np.ndarray], list[int]]:
    """The file columns of ``trial``: names, 1-D values and decimals."""
    header, columns, decimals = [], [], []
    for names, attr, d in _trial_columns(trial):
        values = getattr(trial, attr).reshape(-1, len(names))
        header += names
        columns += [values[:, k] for k in range(len(names))]
        decimals += [d] * len(names)
    return header, columns, decimals


def file_columns(trial: TrialData) -> dict[str, np.ndarray]:
    """The columns of ``trial`` as its file names them (units: `COLUMN_UNITS`), each 1-D."""
    header, columns, _ = _trial_table(trial)
    return dict(zip(header, columns))


def write_trial(path: Path, trial: TrialData) -> None:
    """Write one trial file atomically: Parquet when its name ends in .parquet, else CSV; both hold the
    same numbers (`as_written`), with the simulator's extra columns when present."""
    if path.suffix != parquet.SUFFIX:
        write_trial_csv(path, trial)
        return
    atomic_write(path, parquet.table_bytes(*_trial_table(trial)))


def write_trial_csv(path: Path, trial: TrialData) -> None:
    """Write one trial CSV atomically, with the simulator's extra columns when present."""
    _write_csv(path, *_trial_table(trial))


def as_written(trial: TrialData) -> TrialData:
    """``trial`` exactly as `write_trial` then `read_trial` would give it back, in either format.

    Each value v becomes round(v 10^d) / 10^d (`parquet.rounded`), the double
    nearest to its d-decimal text, which the CSV holds and the Parquet file
    stores, so a campaign that learns from this and one resumed from the files
    learn from identical numbers.
    """
    changes: dict = {attr: parquet.rounded(getattr(trial, attr), d) for _, attr, d in _trial_columns(trial)
                     if attr != "count"}
    return replace(trial, **changes)


#: the share of its noise the simulator's true torque is recorded to at most (`torque_decimals`): rounding to q adds
#: q^2/12 to the noise's variance sigma^2, at most 0.08 % of it
TORQUE_QUANTUM_PER_NOISE = 0.1


def torque_decimals(count: np.ndarray, torque_nm: np.ndarray, counts_per_rev: int) -> int:
    """The decimals d a torque record resolves: 10^-d the largest power of ten at most `TORQUE_QUANTUM_PER_NOISE`
    sigma, at most the file's 6 (a record of no measurable noise).

    sigma is the noise per sample: what does not repeat from one revolution to
    the next (the torque less its mean at each count), from the median absolute
    difference of neighbouring samples over 0.6745 sqrt 2, blind to the ripple
    and to a slow drift. Over R revolutions that reads sigma sqrt(1 - 1/R): never
    more than the noise.
    """
    if torque_nm.size < 3:
        return _TORQUE_DECIMALS
    at = count % counts_per_rev
    mean_nm = np.bincount(at, torque_nm, counts_per_rev) / np.maximum(np.bincount(at, None, counts_per_rev), 1)
    rest_nm = torque_nm - mean_nm[at]
    sigma_nm = float(np.median(np.abs(np.diff(rest_nm)))) / (0.6745 * math.sqrt(2.0))
    if not (math.isfinite(sigma_nm) and sigma_nm > 0.0):
        return _TORQUE_DECIMALS
    return min(_TORQUE_DECIMALS, -math.floor(math.log10(TORQUE_QUANTUM_PER_NOISE * sigma_nm)))


def as_recorded(trial: TrialData, counts_per_rev: int) -> TrialData:
    """``trial`` (sampled at ``counts_per_rev``) as a campaign records it in its run directory: the simulator's
    true torque rounded to the decimals its noise resolves (`torque_decimals`: the current sensors' noise through
    the loop), then `as_written`.

    The file stores a torque of fewer decimals as repeated values (a Parquet
    dictionary): 40 % of the column's bytes. The campaign learns from the
    measured torque, which keeps its 1e-6 N m; the true one gives only the true
    figures, each as the record holds it, so a resumed run's are the same.
    """
    if trial.torque_true_nm is not None:
        decimals = torque_decimals(trial.count, trial.torque_true_nm, counts_per_rev)
        trial = replace(trial, torque_true_nm=parquet.rounded(trial.torque_true_nm, decimals))
    return as_written(trial)


def write_backemf_csv(path: Path, backemf_nm_per_a: np.ndarray) -> None:
    """Write backemf.csv: count,k_a,k_b,k_c, one row per encoder count."""
    n = backemf_nm_per_a.shape[0]
    _write_csv(path, ["count", "k_a", "k_b", "k_c"], [np.arange(n), backemf_nm_per_a], [0, 12, 12, 12])


def write_bench_toml(folder: Path, bench: Bench) -> None:
    """(Re)write bench.toml atomically: the trials listed are exactly ``bench.trials``."""
    entries = [(name, t.torque_setpoint_nm, t.speed_setpoint_hz) for name, t in zip(bench.trial_files, bench.trials)]
    atomic_write(folder / BENCH_FILE, bench_toml_text(bench.motor, bench.sensors, entries,
                                                      static_file=None if bench.static is None else bench.static_file))


def write_bench(folder: str | Path, bench: Bench) -> None:
    """Write a whole bench folder: backemf.csv, the static trial where it has one, every trial (`write_trial`: its
    name sets its format), then bench.toml last."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    write_backemf_csv(folder / "backemf.csv", bench.backemf_nm_per_a)
    if bench.static is not None:
        (folder / bench.static_file).parent.mkdir(parents=True, exist_ok=True)
        write_static_csv(folder / bench.static_file, bench.static)
    for name, trial in zip(bench.trial_files, bench.trials):
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        write_trial(folder / name, trial)
    write_bench_toml(folder, bench)


def convert_bench(folder: str | Path, out: str | Path, suffix: str = ".csv") -> Bench:
    """Copy the bench folder ``folder`` to ``out`` with every trial in the format of ``suffix`` (".csv" or
    ".parquet"), e.g. a run directory's trials as CSV for a tool that reads only CSV; return the bench."""
    if suffix not in (".csv", parquet.SUFFIX):
        raise BenchFormatError(f"{out}: trial format must be .csv or {parquet.SUFFIX}, got {suffix!r}")
    bench = read_bench(folder)
    names = tuple(str(PurePosixPath(name).with_suffix(suffix)) for name in bench.trial_files)
    if len(set(names)) < len(names):
        raise BenchFormatError(f"{folder}: two trials differ only in their suffix; cannot convert them to {suffix}")
    bench = replace(bench, trial_files=names)
    write_bench(out, bench)
    return bench


def config_static_trial(config: CampaignConfig, motor: MotorInfo) -> StaticTrial | None:
    """The static trial [bench] static_trial_file names (relative to the config's folder), read and checked
    (`read_static_csv`) against ``motor``; None where it names none. `ConfigError` naming the key for a file that
    cannot be read or fails a check."""
    name = config.bench.static_trial_file
    if name is None:
        return None
    try:
        return read_static_csv(config.path.parent / name, motor)
    except BenchFormatError as e:
        raise ConfigError(f"{config.path}: [bench] static_trial_file: {e}") from None


def check_bench(config: CampaignConfig, description) -> None:
    """Raise `ConfigError` naming the key if the bench a backend describes (`BenchDescription`) is not the one
    [bench] describes: pole pairs, slots and counts per revolution, and the inertia, back-EMF and
    calibration where [bench] gives them; a mirrored bench's back-EMF against [bench]'s mirrored (`mirrored_table`,
    docs/bench-format.md, "Reverse laps")."""
    bench, motor = config.bench, description.motor
    theirs = mirrored_table(description.backemf_nm_per_a) if motor.mirrored else description.backemf_nm_per_a
    for key in ("pole_pairs", "slots"):
        if getattr(bench, key) != getattr(motor, key):
            raise ConfigError(f"{config.path}: [bench] {key} {getattr(bench, key)} differs from the bench's "
                              f"{getattr(motor, key)}")
    recorded = config.recorded_counts_per_rev()
    if recorded != motor.counts_per_rev:
        how = "" if recorded == bench.counts_per_rev else f" recorded at {recorded} ([bench] record_counts_per_rev)"
        hint = f" (it records them: record_counts_per_rev = {motor.counts_per_rev})" \
            if recorded != bench.counts_per_rev and bench.counts_per_rev % motor.counts_per_rev == 0 else ""
        raise ConfigError(f"{config.path}: [bench] counts_per_rev {bench.counts_per_rev}{how} differs from the "
                          f"bench's {motor.counts_per_rev}{hint}")
    lines = config.sampled_counts_per_rev() // recorded if config.model is not None else 1
    if motor.lines_per_count != lines:
        raise ConfigError(f"{config.path}: [bench] counts_per_rev {bench.counts_per_rev}, recorded at {recorded} "
                          f"counts as means over {lines} lines each, differs from the bench's {motor.counts_per_rev} "
                          f"counts as means over {motor.lines_per_count} lines each")
    if bench.inertia_kgm2 is not None and not math.isclose(bench.inertia_kgm2, motor.inertia_kgm2, rel_tol=1e-9):
        raise ConfigError(f"{config.path}: [bench] inertia_kgm2 {bench.inertia_kgm2:g} differs from the bench's "
                          f"{motor.inertia_kgm2:g}")
    if bench.backemf is not None:
        ours = backemf_table(motor, bench.backemf, motor.counts_per_rev)
        error = np.abs(ours - theirs)
        count, phase = np.unravel_index(np.argmax(error), error.shape)
        if error[count, phase] > BACKEMF_TOLERANCE * np.abs(ours).max():
            raise ConfigError(f"{config.path}: [bench.backemf] differs from the bench's back-EMF table by "
                              f"{error[count, phase]:.3g} N m / A at count {count}, phase {'abc'[phase]}")
    if bench.backemf_file is not None:
        ours = read_backemf_csv(config.path.parent / bench.backemf_file, motor)
        error = np.abs(ours - theirs)
        count, phase = np.unravel_index(np.argmax(error), error.shape)
        if error[count, phase] > BACKEMF_TOLERANCE * np.abs(ours).max():
            raise ConfigError(f"{config.path}: [bench] backemf_file {bench.backemf_file} differs from the bench's "
                              f"back-EMF table by {error[count, phase]:.3g} N m / A at count {count}, "
                              f"phase {'abc'[phase]}")
    if bench.calibration is not None:
        mine, theirs = bench.calibration.calibration(), description.calibration
        for key, a, b in (("current_scale_counts_per_a", mine.current_scale, theirs.current_scale),
                          ("current_offset_counts", mine.current_offset, theirs.current_offset),
                          ("torque_gain_v_per_nm", mine.torque_gain, theirs.torque_gain)):
            if not np.allclose(a, b, rtol=1e-9, atol=1e-12):
                raise ConfigError(f"{config.path}: [bench.calibration] {key} {shown(np.atleast_1d(a).tolist())} "
                                  f"differs from the bench's {shown(np.atleast_1d(b).tolist())}")
