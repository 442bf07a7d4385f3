"""moteus cogging files as a standstill scan: ``ilcpmac import cogging.json`` with ``[log] kind = "moteus-cogging"``.

moteus's ``utils/compensate_cogging.py`` (github.com/mjbots/moteus) turns the rotor at a constant speed in
position control, reverse then forward, and writes the JSON object ``{"reverse": [...], "forward": [...]}``:
per direction the mean measured q-axis current (A, the firmware's ``q_A``) in each of 128 x split_count
equal position bins of one revolution of encoder 0, bin j covering [j, j + 1) / N of a revolution. A
bin's value is the average of the current over the bin; `cogging_scan` undoes that average (exactly for
harmonics below N / 2), takes each bin's centre for its position and the holding torque as k_q i_q with
k_q the q-axis torque constant of the mapping's back-EMF table (`q_torque_constant`), and gives the scan
samples of `ilcpmac.bench.standstill` (docs/bench-format.md, "moteus cogging files").
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ilcpmac.bench.logs import ImportLimits, utf8_text
from ilcpmac.bench.standstill import ScanData, SensorErrors, check_scan, holding_problem
from ilcpmac.core.errors import BenchFormatError
from ilcpmac.core.files import read_bounded
from ilcpmac.core.records import MAX_CURRENT_A, MotorInfo, SensorCalibration
from ilcpmac.core.schema import setting, shown, unique_keys
from ilcpmac.signals.harmonics import harmonic_amplitudes

__all__ = ["HISTOGRAM_BINS", "MAX_BINS", "MOTEUS_COGGING", "MoteusLog", "MoteusMapping", "cogging_scan",
           "q_torque_constant", "read_cogging_file"]

#: [log] kind of a mapping for moteus cogging files
MOTEUS_COGGING = "moteus-cogging"
#: bins of the firmware's histogram per split (kHistogramBinCount in fw/board_debug.cc): a direction holds a
#: multiple of it
HISTOGRAM_BINS = 128
#: most bins of one direction (split_count 512), and the file's bytes they may take
MAX_BINS = 2**16
_MAX_FILE_BYTES = 2 * MAX_BINS * 32 + 1024
#: the file's keys, in the order its rows are written (forward, then back)
_DIRECTIONS = (("forward", 1.0), ("reverse", -1.0))


@dataclass(frozen=True)
class MoteusLog:
    """[log] of a mapping for moteus cogging files: the file's layout is moteus's, so the kind alone."""

    kind: str = setting(lambda x: x == MOTEUS_COGGING, f'"{MOTEUS_COGGING}"', MOTEUS_COGGING)


@dataclass(frozen=True)
class MoteusMapping:
    """A parsed mapping for moteus cogging files: [bench] as for logs (``motor`` with a torque sensor: the scan
    holds a torque), [bench.calibration], the scan's sensor errors ([scan]; torque_sensor_gain is k_q's) and
    [limits]."""

    path: Path
    motor: MotorInfo
    backemf_nm_per_a: np.ndarray
    sensors: SensorCalibration | None
    scan_errors: SensorErrors
    limits: ImportLimits = ImportLimits()


def q_torque_constant(backemf_nm_per_a: np.ndarray, pole_pairs: int) -> float:
    """k_q = 3/2 k_1, N m / A: the torque per ampere of amplitude-invariant i_q (i_d = 0, the currents in phase
    with the back-EMF's fundamental, k_1 its amplitude averaged over the phases)."""
    return float(1.5 * np.abs(harmonic_amplitudes(backemf_nm_per_a)[pole_pairs]).mean())


def read_cogging_file(path: Path) -> dict[str, np.ndarray]:
    """The ``forward`` and ``reverse`` q-axis currents (A) of a moteus cogging file, by key.

    Raises
    ------
    BenchFormatError
        One line naming the file and the key (and the index of a bad value): not UTF-8 text (`utf8_text`), not
        a JSON object, a key missing, unknown or given twice, lists of unequal length or not a multiple of
        `HISTOGRAM_BINS`, a value not a finite number within a bench's currents, every bin the same.
    """
    raw = utf8_text(path, read_bounded(path, _MAX_FILE_BYTES, BenchFormatError))
    try:
        data = json.loads(raw.decode("utf-8"), object_pairs_hook=unique_keys)
    except json.JSONDecodeError as e:
        raise BenchFormatError(f"{path}: line {e.lineno}: not JSON ({e.msg})") from None
    except UnicodeDecodeError:
        raise BenchFormatError(f"{path}: not UTF-8 text") from None
    except ValueError as e:
        raise BenchFormatError(f"{path}: {e}") from None
    except RecursionError:
        raise BenchFormatError(f"{path}: nested too deeply (a moteus cogging file is one object of two "
                               "lists)") from None
    keys = [key for key, _ in _DIRECTIONS]
    if not isinstance(data, dict):
        raise BenchFormatError(f"{path}: not a JSON object with the keys {', '.join(keys)} (a moteus cogging file)")
    for key in data:
        if key not in keys:
            raise BenchFormatError(f"{path}: unknown key {shown(key)} (a moteus cogging file holds "
                                   f"{', '.join(keys)})")
    currents = {}
    for key in keys:
        if key not in data:
            raise BenchFormatError(f"{path}: missing key {shown(key)}")
        values = data[key]
        if not isinstance(values, list) or not 0 < len(values) <= MAX_BINS or len(values) % HISTOGRAM_BINS:
            raise BenchFormatError(f"{path}: {key}: must be a list of {HISTOGRAM_BINS} x split_count numbers, at "
                                   f"most {MAX_BINS}, got {_length(values)}")
        bad = [i for i, v in enumerate(values) if isinstance(v, bool) or not isinstance(v, (int, float))
               or not abs(v) <= MAX_CURRENT_A]
        if bad:
            raise BenchFormatError(f"{path}: {key}[{bad[0]}]: {shown(values[bad[0]])} is not a finite current "
                                   f"within +-{MAX_CURRENT_A:g} A")
        currents[key] = np.asarray(values, dtype=float)
    if currents["forward"].size != currents["reverse"].size:
        raise BenchFormatError(f"{path}: forward has {currents['forward'].size} values, reverse "
                               f"{currents['reverse'].size}: one per bin of the same revolution in each direction")
    first = currents["forward"][0]
    if all(np.all(values == first) for values in currents.values()):
        raise BenchFormatError(f"{path}: every bin holds {first:g} A: no cogging, nothing to identify (an empty or "
                               "constant file?)")
    return currents


def _length(values: object) -> str:
    return f"{len(values)} values" if isinstance(values, list) else f"a {type(values).__name__}"


def _point_values(bin_means: np.ndarray) -> np.ndarray:
    """Values at the bins' centres from their means over N equal bins of a revolution: harmonic h of a bin mean
    is the point value's times sinc(h / N)."""
    n = bin_means.size
    return np.fft.irfft(np.fft.rfft(bin_means) / np.sinc(np.arange(n // 2 + 1) / n), n=n)


def cogging_scan(path: Path, mapping: MoteusMapping) -> ScanData:
    """A moteus cogging file as scan samples: forward bins in ascending position, then reverse bins in
    descending position, each at its centre (j + 1/2) counts_per_rev / N, holding torque k_q i_q of the
    current at that point; time is the row's number (the file holds none). A bin whose holding torque k_q i_q
    passes [limits] max_torque_nm (`holding_problem`: a file in mA, or an outlier) is refused, naming it."""
    currents = read_cogging_file(path)
    cpr = mapping.motor.counts_per_rev
    n = currents["forward"].size
    if n < 2 * cpr:
        raise BenchFormatError(f"{path}: {n} bins a revolution, fewer than two per count of [bench] counts_per_rev "
                               f"= {cpr} in {mapping.path} (the scan's scatter needs two or more: counts_per_rev "
                               f"{n // 2} or fewer)")
    k_q = q_torque_constant(mapping.backemf_nm_per_a, mapping.motor.pole_pairs)
    for key, _ in _DIRECTIONS:
        problem = holding_problem(k_q * currents[key], mapping.limits, mapping.path)
        if problem is not None:
            raise BenchFormatError(f"{path}: {key}[{problem[0]}]: {currents[key][problem[0]]:.4g} A, {problem[1]}")
    centre = (np.arange(n) + 0.5) * cpr / n
    order = {"forward": slice(None), "reverse": slice(None, None, -1)}
    position = np.concatenate([centre[order[key]] for key, _ in _DIRECTIONS])
    torque = np.concatenate([k_q * _point_values(currents[key])[order[key]] for key, _ in _DIRECTIONS])
    direction = np.repeat([sign for _, sign in _DIRECTIONS], n)
    scan = ScanData(np.arange(2.0 * n), position, direction, torque_nm=torque)
    check_scan(scan, str(path))
    return scan
