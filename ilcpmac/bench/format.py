"""Reader and writer of bench folders, exactly as BENCH_FORMAT.md specifies.

A bench folder holds ``bench.toml`` ([motor], optional [sensors], [[trials]]),
``backemf.csv`` and one CSV per trial sampled once per encoder count. Every
violation raises `BenchFormatError` naming the file and the line or key.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ilcpmac.bench.fastcsv import format_rows
from ilcpmac.config import read_toml
from ilcpmac.errors import BenchFormatError
from ilcpmac.records import SensorCalibration, TrialData

BENCH_FILE = "bench.toml"
TRIAL_COLUMNS = ("count", "time", "i_ref_a", "i_ref_b", "i_ref_c", "torque")
#: simulator-only columns (allowed and ignored by other readers)
EXTRA_COLUMNS = {
    "i_meas_a": ("i_meas_a", 3),
    "torque_true": ("torque_true_nm", 1),
    "i_true_a": ("i_true_a", 3),
    "speed_true": ("speed_true_rad_s", 1),
}
_PHASES = ("a", "b", "c")
_MOTOR_KEYS = {"pole_pairs": int, "slots": int, "counts_per_rev": int, "inertia": float, "backemf_file": str}
_SENSOR_KEYS = {"current_scale": list, "current_offset": list, "torque_gain": float}
_TRIAL_KEYS = {"file": str, "torque_setpoint": float, "speed_setpoint": float}


@dataclass(frozen=True)
class MotorInfo:
    """The [motor] table of bench.toml."""

    pole_pairs: int
    slots: int
    counts_per_rev: int
    inertia_kgm2: float

    @property
    def cogging_order(self) -> int:
        """lcm(slots, 2 pole_pairs): cogging periods per mechanical revolution."""
        return math.lcm(self.slots, 2 * self.pole_pairs)


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
    """

    motor: MotorInfo
    backemf_nm_per_a: np.ndarray
    sensors: SensorCalibration | None
    trials: tuple[TrialData, ...]
    trial_files: tuple[str, ...]


# ---------------------------------------------------------------- reading


def _table_value(table: dict, key: str, kind: type, where: str):
    if key not in table:
        raise BenchFormatError(f"{where}: missing key {key!r}")
    value = table[key]
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise BenchFormatError(f"{where}: key {key!r} must be a finite number, got {value!r}")
        return float(value)
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise BenchFormatError(f"{where}: key {key!r} must be a positive integer, got {value!r}")
        return value
    if not isinstance(value, kind):
        raise BenchFormatError(f"{where}: key {key!r} must be a {kind.__name__}, got {value!r}")
    return value


def _check_keys(table, allowed: dict, where: str) -> None:
    if not isinstance(table, dict):
        raise BenchFormatError(f"{where}: must be a table")
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise BenchFormatError(f"{where}: unknown key {unknown[0]!r} (allowed: {', '.join(allowed)})")


def _three_numbers(table: dict, key: str, where: str) -> np.ndarray:
    value = _table_value(table, key, list, where)
    if len(value) != 3 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        raise BenchFormatError(f"{where}: key {key!r} must be a list of 3 numbers, got {value!r}")
    return np.array(value, float)


def _read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    """Header and float rows of a CSV; bad rows raise naming file and line."""
    try:
        with open(path, newline="") as f:
            header_line = f.readline()
            header = [h.strip() for h in header_line.strip().split(",")]
            try:
                data = np.loadtxt(f, delimiter=",", ndmin=2, dtype=float)
            except ValueError as e:
                raise BenchFormatError(f"{path}: {_loadtxt_message(e, len(header))}") from None
    except FileNotFoundError:
        raise BenchFormatError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise BenchFormatError(f"{path}: cannot read ({e})") from None
    if data.size and data.shape[1] != len(header):
        raise BenchFormatError(f"{path}: line 2 has {data.shape[1]} fields, the header has {len(header)}")
    if data.size == 0:
        data = np.zeros((0, len(header)))
    bad = np.argwhere(~np.isfinite(data))
    if bad.size:
        row, col = bad[0]
        raise BenchFormatError(f"{path}: line {row + 2}: {header[col]} is not a finite number")
    return header, data


def _loadtxt_message(e: ValueError, n_header: int) -> str:
    """Name the file line of a numpy loadtxt error (the header is line 1, the first data row line 2).

    numpy counts data rows from 0 when a value does not convert, but from 1
    when a row's number of fields differs from the first data row's (which
    may itself be the row at fault).
    """
    text = str(e)
    m = re.search(r"number of columns changed from (\d+) to (\d+) at row (\d+)", text)
    if m:
        first, fields, row = (int(g) for g in m.groups())
        if first != n_header:
            return f"line 2 has {first} fields, the header has {n_header}"
        return f"line {row + 1} has {fields} fields, the header has {n_header}"
    m = re.search(r"(?:at|in) row (\d+)", text)
    if m:
        return f"line {int(m.group(1)) + 2}: {text}"
    return text


def _read_backemf(path: Path, counts_per_rev: int) -> np.ndarray:
    header, data = _read_csv(path)
    if header != ["count", "k_a", "k_b", "k_c"]:
        raise BenchFormatError(f"{path}: line 1: header must be count,k_a,k_b,k_c, got {','.join(header)}")
    if data.shape[0] != counts_per_rev:
        raise BenchFormatError(f"{path}: has {data.shape[0]} rows, expected counts_per_rev = {counts_per_rev}")
    wrong = np.flatnonzero(data[:, 0] != np.arange(counts_per_rev))
    if wrong.size:
        raise BenchFormatError(f"{path}: line {wrong[0] + 2}: count must be {wrong[0]}, got {data[wrong[0], 0]:g}")
    return np.ascontiguousarray(data[:, 1:])


def read_trial_csv(path: Path, torque_setpoint_nm: float, speed_setpoint_hz: float) -> TrialData:
    """Read one trial CSV (required columns in any order; others ignored unless known extras)."""
    header, data = _read_csv(path)
    required = ["count", "time", "i_ref_a", "i_ref_b", "i_ref_c", "torque"]
    missing = [c for c in required if c not in header]
    if missing:
        raise BenchFormatError(f"{path}: line 1: missing column {missing[0]!r}")
    dup = sorted({c for c in header if header.count(c) > 1})
    if dup:
        raise BenchFormatError(f"{path}: line 1: column {dup[0]!r} appears twice")
    col = {name: data[:, header.index(name)] for name in header}
    if data.shape[0] < 2:
        raise BenchFormatError(f"{path}: needs at least 2 rows, has {data.shape[0]}")
    count = col["count"]
    if np.any(count != np.round(count)):
        line = int(np.flatnonzero(count != np.round(count))[0]) + 2
        raise BenchFormatError(f"{path}: line {line}: count must be an integer")
    steps = np.diff(count)
    if np.any(steps <= 0):
        line = int(np.flatnonzero(steps <= 0)[0]) + 3
        raise BenchFormatError(f"{path}: line {line}: count does not increase")
    extras = {}
    for prefix, (attr, width) in EXTRA_COLUMNS.items():
        names = [prefix[:-1] + ph for ph in _PHASES] if width == 3 else [prefix]
        if all(n in col for n in names):
            extras[attr] = np.column_stack([col[n] for n in names]) if width == 3 else col[names[0]]
    return TrialData(
        torque_setpoint_nm=torque_setpoint_nm, speed_setpoint_hz=speed_setpoint_hz,
        count=count.astype(np.int64), time_s=col["time"],
        i_ref_a=np.column_stack([col[f"i_ref_{ph}"] for ph in _PHASES]), torque_nm=col["torque"], **extras)


def read_bench(folder: str | Path) -> Bench:
    """Read and validate a bench folder."""
    folder = Path(folder)
    if not folder.is_dir():
        raise BenchFormatError(f"{folder}: not a folder")
    toml_path = folder / BENCH_FILE
    if not toml_path.is_file():
        raise BenchFormatError(f"{toml_path}: no such file (a bench folder needs {BENCH_FILE})")
    data = read_toml(toml_path, BenchFormatError)
    _check_keys(data, {"motor": 0, "sensors": 0, "trials": 0}, str(toml_path))
    if "motor" not in data:
        raise BenchFormatError(f"{toml_path}: missing table [motor]")
    where = f"{toml_path}: [motor]"
    _check_keys(data["motor"], _MOTOR_KEYS, where)
    values = {k: _table_value(data["motor"], k, kind, where) for k, kind in _MOTOR_KEYS.items()}
    if values["inertia"] <= 0:
        raise BenchFormatError(f"{where}: key 'inertia' must be positive, got {values['inertia']}")
    motor = MotorInfo(values["pole_pairs"], values["slots"], values["counts_per_rev"], values["inertia"])
    backemf = _read_backemf(folder / values["backemf_file"], motor.counts_per_rev)
    sensors = None
    if "sensors" in data:
        where = f"{toml_path}: [sensors]"
        _check_keys(data["sensors"], _SENSOR_KEYS, where)
        scale = _three_numbers(data["sensors"], "current_scale", where)
        if np.any(scale <= 0):
            raise BenchFormatError(f"{where}: key 'current_scale' must be positive, got {scale.tolist()}")
        gain = _table_value(data["sensors"], "torque_gain", float, where)
        if gain <= 0:
            raise BenchFormatError(f"{where}: key 'torque_gain' must be positive, got {gain}")
        sensors = SensorCalibration(scale, _three_numbers(data["sensors"], "current_offset", where), gain)
    entries = data.get("trials")
    if not isinstance(entries, list) or not entries:
        raise BenchFormatError(f"{toml_path}: needs at least one [[trials]] entry")
    trials, files = [], []
    for i, entry in enumerate(entries, start=1):
        where = f"{toml_path}: [[trials]] #{i}"
        _check_keys(entry, _TRIAL_KEYS, where)
        name = _table_value(entry, "file", str, where)
        torque = _table_value(entry, "torque_setpoint", float, where)
        speed = _table_value(entry, "speed_setpoint", float, where)
        if name in files:
            raise BenchFormatError(f"{where}: file {name!r} is listed twice")
        trials.append(read_trial_csv(folder / name, torque, speed))
        files.append(name)
    return Bench(motor, backemf, sensors, tuple(trials), tuple(files))


# ---------------------------------------------------------------- writing


def atomic_write(path: Path, data: bytes | str, durable: bool = True) -> None:
    """Write via a temporary file and rename, so a reader never sees half a file.

    ``durable`` also fsyncs before the rename, so the file survives a power cut.
    """
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(data.encode() if isinstance(data, str) else data)
        if durable:
            f.flush()
            os.fsync(f.fileno())
    os.replace(tmp, path)


def _toml_value(value) -> str:
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return str(int(value))
    return repr(float(value))


def bench_toml_text(motor: MotorInfo, sensors: SensorCalibration | None,
                    trials: list[tuple[str, float, float]], backemf_file: str = "backemf.csv") -> str:
    """bench.toml text; ``trials`` lists (file, torque set point N m, speed set point Hz)."""
    m = motor
    lines = ["[motor]",
             f"pole_pairs = {m.pole_pairs}", f"slots = {m.slots}", f"counts_per_rev = {m.counts_per_rev}",
             f"inertia = {_toml_value(m.inertia_kgm2)}", f"backemf_file = {_toml_value(backemf_file)}", ""]
    if sensors is not None:
        lines += ["[sensors]", f"current_scale = {_toml_value(sensors.current_scale)}",
                  f"current_offset = {_toml_value(sensors.current_offset)}",
                  f"torque_gain = {_toml_value(sensors.torque_gain)}", ""]
    for name, torque, speed in trials:
        lines += ["[[trials]]", f"file = {_toml_value(name)}",
                  f"torque_setpoint = {_toml_value(torque)}", f"speed_setpoint = {_toml_value(speed)}", ""]
    return "\n".join(lines)


def _write_csv(path: Path, header: list[str], columns: list[np.ndarray], decimals: list[int]) -> None:
    """Write a numeric CSV atomically, column c rounded to ``decimals[c]`` decimals."""
    body = format_rows(np.column_stack(columns), np.array(decimals))
    atomic_write(path, (",".join(header) + "\n").encode() + body)


def _trial_columns(trial: TrialData) -> list[tuple[list[str], str, int]]:
    """(CSV column names, TrialData attribute, decimals) of every column ``trial`` has.

    Times are written to 0.1 us, currents, torques and speeds to 1e-6 of
    their unit (far below any sensor's noise: the rounding adds 3e-7 RMS).
    """
    columns = [(["count"], "count", 0), (["time"], "time_s", 7),
               ([f"i_ref_{ph}" for ph in _PHASES], "i_ref_a", 6), (["torque"], "torque_nm", 6)]
    for prefix, (attr, width) in EXTRA_COLUMNS.items():
        if getattr(trial, attr) is not None:
            columns.append(([prefix[:-1] + ph for ph in _PHASES] if width == 3 else [prefix], attr, 6))
    return columns


def write_trial_csv(path: Path, trial: TrialData) -> None:
    """Write one trial CSV atomically, with the simulator's extra columns when present."""
    spec = _trial_columns(trial)
    header = [name for names, _, _ in spec for name in names]
    decimals = [d for names, _, d in spec for _ in names]
    _write_csv(path, header, [getattr(trial, attr) for _, attr, _ in spec], decimals)


def as_written(trial: TrialData) -> TrialData:
    """``trial`` exactly as `write_trial_csv` then `read_trial_csv` would give it back.

    Each value v becomes round(v 10^d) / 10^d, the double nearest to its
    d-decimal text, so a campaign that learns from this and one resumed from
    the files learn from identical numbers.
    """
    changes = {attr: np.round(getattr(trial, attr) * 10.0**d) / 10.0**d
               for _, attr, d in _trial_columns(trial) if attr != "count"}
    return replace(trial, **changes)


def write_backemf_csv(path: Path, backemf_nm_per_a: np.ndarray) -> None:
    """Write backemf.csv: count,k_a,k_b,k_c, one row per encoder count."""
    n = backemf_nm_per_a.shape[0]
    _write_csv(path, ["count", "k_a", "k_b", "k_c"], [np.arange(n), backemf_nm_per_a], [0, 12, 12, 12])


def write_bench_toml(folder: Path, bench: Bench) -> None:
    """(Re)write bench.toml atomically: the trials listed are exactly ``bench.trials``."""
    entries = [(name, t.torque_setpoint_nm, t.speed_setpoint_hz) for name, t in zip(bench.trial_files, bench.trials)]
    atomic_write(folder / BENCH_FILE, bench_toml_text(bench.motor, bench.sensors, entries))


def write_bench(folder: str | Path, bench: Bench) -> None:
    """Write a whole bench folder: backemf.csv, every trial CSV, then bench.toml last."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    write_backemf_csv(folder / "backemf.csv", bench.backemf_nm_per_a)
    for name, trial in zip(bench.trial_files, bench.trials):
        write_trial_csv(folder / name, trial)
    write_bench_toml(folder, bench)
