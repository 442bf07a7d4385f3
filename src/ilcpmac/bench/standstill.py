"""Standstill position scans: the position torque and the cogging map from holding torques, forward and back.

A scan moves the rotor slowly over whole revolutions, forward then back, and
logs at each position what holds it there: the motor's own currents (the
drive holds the rotor in position control) or a DC torque sensor's reading
(an external drive turns the unpowered motor). Quasi-statically the holding
torque is h_s(theta) = -tau_pos(theta) + s f(theta) with s = +-1 the direction
of motion and f the friction and hysteresis, so (docs/standstill.md)

    tau_pos = -(h_+ + h_-) / 2,    f = (h_+ - h_-) / 2.

A *scan folder* is a bench folder without trials (bench.toml's [motor] and
[sensors], backemf.csv) plus ``scan.toml`` and the samples (``scan.csv``);
`read_scan` reads it, `reduce_scan` gives a `ScanResult`, `identify_scan`
is ``ilcpmac identify SCAN_FOLDER``. Every problem of a file raises
`BenchFormatError` naming the file and the key, line or count. A few counts
without a sample in one direction are filled from their neighbours, their
error bound in the standard errors and their list in the result
(`ScanResult.filled_counts`); a gap that could move a cogging harmonic by
more than its standard error is refused.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ilcpmac.bench.fastcsv import format_rows
from ilcpmac.bench.format import BENCH_FILE, bench_toml_text, read_bench_head, write_backemf_csv
from ilcpmac.bench.logs import ImportLimits, LogLayout, beyond_limit, column_names, read_log
from ilcpmac.core.errors import BenchFormatError, ConfigError
from ilcpmac.core.files import atomic_write, read_bounded
from ilcpmac.core.records import MAX_CURRENT_A, MAX_TORQUE_NM, MotorInfo, SensorCalibration
from ilcpmac.core.schema import all_of, finite_json, in_range, length_in, parse_section, read_toml, setting, shown
from ilcpmac.signals.harmonics import filtered, harmonic_amplitudes, harmonic_band

__all__ = ["CURRENT_COLUMNS", "MAX_RELATIVE_STD", "SCAN_DATA_FILE", "SCAN_FILE", "ScanData", "ScanResult",
           "SensorErrors", "holding_problem", "identify_scan", "logged_holding_nm", "read_scan", "reduce_scan",
           "truth_tables", "unresolved_cogging", "write_scan"]

#: the file that makes a folder a scan folder, and the samples' file it names by default
SCAN_FILE = "scan.toml"
SCAN_DATA_FILE = "scan.csv"
#: a simulated scan's truth beside scan.toml (`ilcpmac.sim.standstill`)
TRUTH_FILE = "truth.json"
#: columns of scan.csv: always time (s), position (counts of [motor] counts_per_rev) and direction (+1 forward,
#: -1 reverse), then the phase currents (A) or the torque (N m)
BASE_COLUMNS = ("time", "position", "direction")
CURRENT_COLUMNS = ("i_a", "i_b", "i_c")
TORQUE_COLUMN = "torque"
#: most samples of one scan
MAX_SCAN_ROWS = 2**22
#: the largest standard error of an estimate a result takes, relative to its size (a scan's cogging, an
#: identification's gains; `ilcpmac.identify` judges by it too): beyond it, 2 standard errors reach past zero and
#: the estimate tells nothing
MAX_RELATIVE_STD = 0.5
_THREE = length_in(3, 3)


@dataclass(frozen=True)
class SensorErrors:
    """The sensors' errors while the scan was recorded, at its calibration ([scan] of scan.toml or of a mapping).

    The result keys of an identification at that calibration (eqs. 1.4-1.7);
    the defaults say the calibration is exact. The true phase current is
    epsilon alpha_p i_p + beta_p for a logged i_p; the true torque is the
    logged one over torque_sensor_gain. The standard errors enter the map's.
    """

    epsilon: float = setting(in_range(0.0, 10.0, low_open=True), "mean current-sensor gain error, (0, 10]", 1.0)
    epsilon_std: float = setting(in_range(0.0, 10.0), "its standard error, [0, 10]", 0.0)
    alpha: tuple[float, ...] = setting(all_of(_THREE, in_range(0.0, 10.0, low_open=True)),
                                       "scale imbalance per phase, three values in (0, 10]", (1.0, 1.0, 1.0))
    alpha_std: tuple[float, ...] = setting(all_of(_THREE, in_range(0.0, 10.0)), "their standard errors, three "
                                           "values in [0, 10]", (0.0, 0.0, 0.0))
    beta_a: tuple[float, ...] = setting(all_of(_THREE, in_range(-1e3, 1e3)), "offset error per phase, A, three "
                                        "values within +-1e3", (0.0, 0.0, 0.0))
    beta_std_a: tuple[float, ...] = setting(all_of(_THREE, in_range(0.0, 1e3)), "their standard errors, A, three "
                                            "values in [0, 1e3]", (0.0, 0.0, 0.0))
    torque_sensor_gain: float = setting(in_range(0.0, 10.0, low_open=True), "delta = g_t / g*_t, (0, 10]", 1.0)
    torque_sensor_gain_std: float = setting(in_range(0.0, 10.0), "its standard error, [0, 10]", 0.0)

    @staticmethod
    def parse(table, source: str, section: str) -> SensorErrors:
        """From a TOML table; each problem raises `ConfigError` naming ``source`` and the key."""
        return parse_section(table, SensorErrors, source, section)

    def toml_lines(self) -> list[str]:
        """The keys that differ from the defaults, as TOML lines."""
        default = SensorErrors()
        return [f"{f.name} = {json.dumps(list(v) if isinstance(v, tuple) else v)}"
                for f in dataclasses.fields(self) if (v := getattr(self, f.name)) != getattr(default, f.name)]


@dataclass(frozen=True)
class ScanData:
    """A scan's samples in acquisition order.

    Attributes
    ----------
    time_s : ndarray, shape (n,)
    position_counts : ndarray, shape (n,)
        Mechanical position in counts of [motor] counts_per_rev, real-valued, count 0 at the back-EMF table's 0.
    direction : ndarray, shape (n,)
        +1 while moving forward, -1 in reverse.
    currents_a : ndarray, shape (n, 3), or None
        Phase currents as the controller had them (commanded or measured), A.
    torque_nm : ndarray, shape (n,), or None
        The torque sensor's reading with today's g*_t, N m (a sensor that holds DC).
    """

    time_s: np.ndarray
    position_counts: np.ndarray
    direction: np.ndarray
    currents_a: np.ndarray | None = None
    torque_nm: np.ndarray | None = None


@dataclass(frozen=True)
class Scan:
    """A scan folder in memory: the motor, its back-EMF table (N m / A, shape (counts_per_rev, 3)), the
    calibration it ran with, the sensors' errors and the samples, read from ``data_file`` in the folder."""

    path: Path
    motor: MotorInfo
    backemf_nm_per_a: np.ndarray
    sensors: SensorCalibration | None
    errors: SensorErrors
    data: ScanData
    data_file: str = SCAN_DATA_FILE


@dataclass(frozen=True)
class ScanResult:
    """The reduction of a scan (`reduce_scan`), per count of one revolution (shape (counts_per_rev,)) in N m.

    Attributes
    ----------
    source : "currents" or "torque"
    position_torque_nm, position_torque_std_nm
        tau_pos = -(h_+ + h_-) / 2 minus its mean, and its standard error.
    cogging_nm, cogging_std_nm
        tau_pos on the multiples of the cogging order (the cogging torque), and its standard error; None when
        the cogging order is beyond the counts' Nyquist limit counts_per_rev / 2 (no cogging harmonic resolved).
    friction_nm, friction_std_nm
        f = (h_+ - h_-) / 2: Coulomb friction plus hysteresis, per count.
    orders : ndarray of int, shape (k,)
        The cogging order's multiples up to counts_per_rev / 2.
    coefficients_nm, coefficients_std_nm : ndarray, shape (k, 2)
        tau_c = sum a_h cos(h theta) + b_h sin(h theta): (a_h, b_h) and their standard errors.
    noise_std_nm : float
        Scatter of one sample about its count's mean (pooled).
    samples : (int, int)
        Forward and reverse samples.
    filled_counts : (tuple of int, tuple of int)
        The counts without a forward (reverse) sample, filled from their neighbours; empty for a complete scan.
    """

    counts_per_rev: int
    cogging_order: int
    source: str
    position_torque_nm: np.ndarray
    position_torque_std_nm: np.ndarray
    cogging_nm: np.ndarray | None
    cogging_std_nm: np.ndarray | None
    friction_nm: np.ndarray
    friction_std_nm: np.ndarray
    orders: np.ndarray
    coefficients_nm: np.ndarray
    coefficients_std_nm: np.ndarray
    noise_std_nm: float
    samples: tuple[int, int]
    filled_counts: tuple[tuple[int, ...], tuple[int, ...]] = ((), ())

    @property
    def messages(self) -> tuple[str, ...]:
        """Warnings about the result, one line each: a cogging not identified, the counts filled from their
        neighbours."""
        unresolved = () if self.cogging_nm is not None else (
            f"{unresolved_cogging(self.cogging_order, self.counts_per_rev)}; the position torque and friction are",)
        if not any(self.filled_counts):
            return unresolved
        return (*unresolved, f"{_gaps_text(self.filled_counts)} without a sample: filled from their neighbours, the "
                "interpolation's error bound in their standard errors (docs/standstill.md)")

    @property
    def too_uncertain(self) -> str | None:
        """Why the cogging is too uncertain to take: its standard error (RMS over the counts) beyond
        `MAX_RELATIVE_STD` of its RMS; None for a cogging to take, or none identified."""
        if self.cogging_nm is None or self.cogging_std_nm is None:
            return None
        size, std = _rms(self.cogging_nm), _rms(self.cogging_std_nm)
        if std <= MAX_RELATIVE_STD * size:
            return None
        return (f"cogging too uncertain to take: {1e3 * size:.3g} mN m RMS ± {1e3 * std:.2g} mN m per count, a "
                f"standard error beyond {MAX_RELATIVE_STD:g} of its size - the scan's scatter hides it (an "
                "outlier, or too few samples)")

    def to_json(self) -> dict:
        """The scan result JSON (docs/standstill.md); its ``cogging`` reads as an identification's."""
        count = list(range(self.counts_per_rev))
        filled = ({"filled_counts": {"forward": list(self.filled_counts[0]), "reverse": list(self.filled_counts[1])}}
                  if any(self.filled_counts) else {})
        return finite_json({
            "kind": "standstill_scan", "counts_per_rev": self.counts_per_rev, "cogging_order": self.cogging_order,
            "source": self.source,
            "cogging": None if self.cogging_nm is None or self.cogging_std_nm is None else {
                "count": count, "torque": self.cogging_nm.tolist(), "std": self.cogging_std_nm.tolist()},
            "position_torque": {"count": count, "torque": self.position_torque_nm.tolist(),
                                "std": self.position_torque_std_nm.tolist()},
            "friction": {"count": count, "torque": self.friction_nm.tolist(), "std": self.friction_std_nm.tolist()},
            "friction_mean_nm": float(self.friction_nm.mean()),
            "cogging_harmonics": {"orders": self.orders.tolist(), "cos_nm": self.coefficients_nm[:, 0].tolist(),
                                  "sin_nm": self.coefficients_nm[:, 1].tolist(),
                                  "cos_std_nm": self.coefficients_std_nm[:, 0].tolist(),
                                  "sin_std_nm": self.coefficients_std_nm[:, 1].tolist()},
            "noise_std_nm": self.noise_std_nm,
            "samples": {"forward": self.samples[0], "reverse": self.samples[1]},
            **filled, **({} if self.too_uncertain is None else {"too_uncertain": self.too_uncertain}),
        })


def unresolved_cogging(cogging_order: int, counts_per_rev: int) -> str | None:
    """Why no cogging can be identified at ``counts_per_rev``: its order beyond the counts' Nyquist limit
    counts_per_rev / 2; None when its first harmonic is resolved."""
    if cogging_order <= counts_per_rev // 2:
        return None
    return (f"cogging: not identified - its order {cogging_order} (lcm(slots, 2 pole_pairs)) is beyond the Nyquist "
            f"limit of {counts_per_rev} counts per revolution ({counts_per_rev // 2}): no cogging harmonic is resolved")


def _gaps_text(filled: tuple[tuple[int, ...], tuple[int, ...]]) -> str:
    """``"2 forward counts (137, 900-902) and 1 reverse count (55)"``: the counts of each direction, runs
    joined, the first ten runs shown."""
    parts = []
    for direction, counts in zip(("forward", "reverse"), filled):
        if not counts:
            continue
        starts = [c for i, c in enumerate(counts) if i == 0 or counts[i - 1] != c - 1]
        ends = [c for i, c in enumerate(counts) if i == len(counts) - 1 or counts[i + 1] != c + 1]
        runs = [str(a) if a == b else f"{a}-{b}" for a, b in zip(starts, ends)]
        shown_runs = ", ".join(runs[:10]) + (f", ... ({len(runs)} runs)" if len(runs) > 10 else "")
        parts.append(f"{len(counts)} {direction} count{'s' if len(counts) > 1 else ''} ({shown_runs})")
    return " and ".join(parts)


# ---------------------------------------------------------------- reading


def read_scan(folder: str | Path) -> Scan:
    """Read a scan folder: bench.toml (no [[trials]]) and backemf.csv as `read_bench_head` checks them,
    scan.toml and its samples."""

    folder = Path(folder)
    head = read_bench_head(folder)
    path = folder / SCAN_FILE
    if head.entries is not None:
        raise BenchFormatError(f"{folder / BENCH_FILE}: a scan folder lists no [[trials]] ({SCAN_FILE} names "
                               "its samples)")
    data = read_toml(path, BenchFormatError)
    if set(data) != {"scan"}:
        raise BenchFormatError(f"{path}: needs exactly the table [scan], got {shown(sorted(data))}")
    table = dict(data["scan"]) if isinstance(data["scan"], dict) else data["scan"]
    name = table.pop("file", SCAN_DATA_FILE) if isinstance(table, dict) else None
    if not (isinstance(name, str) and name and "/" not in name and "\\" not in name and name not in (".", "..")):
        raise BenchFormatError(f"{path}: [scan] file: a file name in the folder, got {shown(name)}")
    try:
        errors = SensorErrors.parse(table, str(path), "scan")
    except ConfigError as e:
        raise BenchFormatError(str(e)) from None
    samples = folder / name
    if not samples.resolve().is_relative_to(folder.resolve()):
        raise BenchFormatError(f"{path}: [scan] file: {name!r} leads outside the folder (refused)")
    header = column_names(samples, f"{SCAN_FILE} [scan] file")
    kind = CURRENT_COLUMNS if set(CURRENT_COLUMNS) <= set(header) else (TORQUE_COLUMN,)
    if (TORQUE_COLUMN in header) == (kind == CURRENT_COLUMNS):
        raise BenchFormatError(f"{samples}: line 1: needs the columns {', '.join(CURRENT_COLUMNS)} or "
                               f"{TORQUE_COLUMN}, not both (the header has {shown(header)})")
    columns = read_log(samples, LogLayout(time="time", position="position", position_unit="counts",
                                          position_counts_per_rev=head.motor.counts_per_rev,
                                          phase_currents=CURRENT_COLUMNS if kind == CURRENT_COLUMNS else None,
                                          torque=TORQUE_COLUMN if kind != CURRENT_COLUMNS else None,
                                          direction="direction", kind="scan"))
    scan = ScanData(columns["time"], columns["position"], columns["direction"],
                    np.column_stack([columns[c] for c in CURRENT_COLUMNS]) if kind == CURRENT_COLUMNS else None,
                    columns.get(TORQUE_COLUMN))
    check_scan(scan, str(samples))
    return Scan(folder, head.motor, head.backemf_nm_per_a, head.sensors, errors, scan, name)


def check_scan(scan: ScanData, where: str) -> None:
    """Directions of +-1, positions within 2^40 counts, currents and torque within a bench's bounds and not the
    same at every sample (a constant or empty file holds no position torque: nothing to identify)."""
    n = scan.position_counts.size
    if n > MAX_SCAN_ROWS:
        raise BenchFormatError(f"{where}: {n} samples; a scan holds at most {MAX_SCAN_ROWS}")
    bad = np.flatnonzero(np.abs(scan.direction) != 1)
    if bad.size:
        raise BenchFormatError(f"{where}: line {bad[0] + 2}: direction must be 1 (forward) or -1 (reverse), got "
                               f"{scan.direction[bad[0]]:g}")
    checks = [("position", scan.position_counts, 2.0**40)]
    if scan.currents_a is not None:
        checks.append(("current", np.abs(scan.currents_a).max(axis=1), MAX_CURRENT_A))
    if scan.torque_nm is not None:
        checks.append(("torque", scan.torque_nm, MAX_TORQUE_NM))
    for name, values, bound in checks:
        bad = np.flatnonzero(np.abs(values) > bound)
        if bad.size:
            raise BenchFormatError(f"{where}: line {bad[0] + 2}: {name} beyond +-{bound:g} (wrong unit or scale?)")
    holding = scan.torque_nm if scan.torque_nm is not None else scan.currents_a
    if holding is not None and n and np.all(holding == holding[0]):
        raise BenchFormatError(f"{where}: the holding {'torque is' if scan.torque_nm is not None else 'currents are'}"
                               " the same at every sample: no position torque, nothing to identify (an empty or "
                               "constant file?)")


def logged_holding_nm(data: ScanData, backemf_nm_per_a: np.ndarray) -> np.ndarray:
    """Each sample's holding torque as logged (exact sensors), N m: its torque, or sum_p K_p i_p."""
    if data.torque_nm is not None:
        return data.torque_nm
    if data.currents_a is None:
        raise BenchFormatError("a scan needs its phase currents or its torque")
    return np.sum(_backemf_at(backemf_nm_per_a, data.position_counts) * data.currents_a, axis=1)


def holding_problem(holding_nm: np.ndarray, limits: ImportLimits, mapping: Path) -> tuple[int, str] | None:
    """The first sample whose holding torque passes [limits] max_torque_nm of the ``mapping`` file, and what to
    say of it: a motor holds its cogging and friction within its torque range, so a holding torque beyond it
    is a wrong unit or an outlier (`beyond_limit`); None within."""
    found = beyond_limit(holding_nm, limits.max_torque_nm)
    if found is None:
        return None
    index, cause = found
    return index, (f"a holding torque of {holding_nm[index]:.4g} N m, beyond [limits] max_torque_nm = "
                   f"{limits.max_torque_nm:g} N m (of {mapping}, its default if not given): a motor holds its cogging "
                   f"and friction within its torque range; {cause}")


# ---------------------------------------------------------------- reduction


def _backemf_at(backemf_nm_per_a: np.ndarray, position_counts: np.ndarray) -> np.ndarray:
    """K_p at real positions: the per-count table linearly interpolated, periodic, shape (n, 3)."""
    cpr = backemf_nm_per_a.shape[0]
    base = np.floor(position_counts)
    frac = (position_counts - base)[:, None]
    k = base.astype(np.int64) % cpr
    return (1.0 - frac) * backemf_nm_per_a[k] + frac * backemf_nm_per_a[(k + 1) % cpr]


def _holding(scan: Scan) -> tuple[np.ndarray, np.ndarray]:
    """Per sample the true holding torque h, N m, and its sensitivity to each sensor error times the error's
    standard error (shape (n, j)): h = sum_p K_p (eps alpha_p i_p + beta_p), or torque / delta."""
    d, e = scan.data, scan.errors
    if d.torque_nm is not None:
        h = d.torque_nm / e.torque_sensor_gain
        return h, (-h * e.torque_sensor_gain_std / e.torque_sensor_gain)[:, None]
    k = _backemf_at(scan.backemf_nm_per_a, d.position_counts)
    alpha, beta = np.asarray(e.alpha), np.asarray(e.beta_a)
    ki = k * d.currents_a
    h = ki @ (e.epsilon * alpha) + k @ beta
    sensitivity = np.column_stack([(ki @ alpha) * e.epsilon_std, e.epsilon * ki * np.asarray(e.alpha_std),
                                   k * np.asarray(e.beta_std_a)])
    return h, sensitivity


def _binned(bins: np.ndarray, values: np.ndarray, cpr: int, hits: np.ndarray) -> np.ndarray:
    """Per-count means of ``values`` (shape (n, m)), shape (cpr, m)."""
    return np.column_stack([np.bincount(bins, weights=v, minlength=cpr) for v in values.T]) / hits[:, None]


@dataclass(frozen=True)
class _Direction:
    """One direction's holding torque per count (`_direction_means`), shapes (counts_per_rev, ...).

    ``inverse_hits`` is 1 / n for a count of n samples and sum_j w_j^2 / n_j for a count filled with weights
    w_j of its neighbours j; ``fill_bound_nm`` holds one column per gap, the interpolation's error bound on
    the gap's counts and zero elsewhere.
    """

    holding_nm: np.ndarray
    sensitivity: np.ndarray
    inverse_hits: np.ndarray
    squared_residuals: np.ndarray
    filled: tuple[int, ...]
    fill_bound_nm: np.ndarray


def _neighbours(present: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per count, the nearest counts with samples at or before it and after it (periodic, unwrapped: left <=
    count < right) and the gap's index (the same for every count of one gap)."""
    cpr = present.size
    counts = np.flatnonzero(present)
    before = np.searchsorted(counts, np.arange(cpr), side="right") - 1
    left = counts[before] - np.where(before < 0, cpr, 0)
    right = np.where(before + 1 < counts.size, counts[(before + 1) % counts.size], counts[0] + cpr)
    return left, right, before % counts.size


def _direction_means(scan: Scan, h: np.ndarray, sensitivity: np.ndarray, forward: bool, where: str
                     ) -> _Direction:
    """One direction's holding torque per count at the count itself, its sensitivities, sample numbers and
    squared residuals; counts without a sample filled from their neighbours.

    The samples of count c lie at c + d, |d| <= 1/2: their mean is h(c) + h'(c) mean(d) + h''(c) mean(d^2) / 2,
    so the derivatives (central differences of the means) remove that bias, and the residuals the slope
    within the count. A count c without a sample, t counts after the last count with one and g - t before
    the next, is their linear interpolation; its error is at most M t (g - t) / 2 with M = max |h''|, taken
    as the largest second difference of three neighbouring counts with samples (noise makes it larger).
    """
    cpr = scan.motor.counts_per_rev
    keep = (scan.data.direction > 0) if forward else (scan.data.direction < 0)
    position = scan.data.position_counts[keep]
    nearest = np.round(position)
    bins = nearest.astype(np.int64) % cpr
    offset = position - nearest
    hits = np.bincount(bins, minlength=cpr).astype(float)
    present = hits > 0
    means = _binned(bins, np.column_stack([h[keep], offset, offset**2, sensitivity[keep]]), cpr,
                    np.maximum(hits, 1.0))
    empty = np.flatnonzero(~present)
    left, right, gap = _neighbours(present)
    weight = ((np.arange(cpr) - left) / (right - left))[empty]
    if empty.size:
        means[empty] = (1.0 - weight)[:, None] * means[left[empty] % cpr] + weight[:, None] * means[right[empty] % cpr]
    m, d1, d2 = means[:, 0], means[:, 1], means[:, 2]
    slope = (np.roll(m, -1) - np.roll(m, 1)) / 2.0
    curvature = np.roll(m, -1) - 2.0 * m + np.roll(m, 1)
    at_count = m - slope * d1 - curvature * d2 / 2.0
    residual = h[keep] - m[bins] - slope[bins] * (offset - d1[bins])
    inverse_hits = 1.0 / np.maximum(hits, 1.0)
    bound = np.zeros((cpr, np.unique(gap[empty]).size))
    if empty.size:
        at_count[empty] = (1.0 - weight) * at_count[left[empty] % cpr] + weight * at_count[right[empty] % cpr]
        inverse_hits[empty] = (1.0 - weight) ** 2 / hits[left[empty] % cpr] + weight**2 / hits[right[empty] % cpr]
        triples = present & np.roll(present, 1) & np.roll(present, -1)
        if not triples.any():
            raise BenchFormatError(f"{where}: {empty.size} of {cpr} counts lack a "
                                   f"{'forward' if forward else 'reverse'} sample, too many to fill from their "
                                   "neighbours: a scan covers every count of a revolution in both directions")
        steepest = np.abs(np.roll(at_count, -1) - 2.0 * at_count + np.roll(at_count, 1))[triples].max()
        t = (np.arange(cpr) - left)[empty]
        bound[empty, np.unique(gap[empty], return_inverse=True)[1]] = steepest * t * ((right - left)[empty] - t) / 2.0
    return _Direction(at_count, means[:, 3:], inverse_hits, residual**2, tuple(int(c) for c in empty), bound)


def reduce_scan(scan: Scan) -> ScanResult:
    """The position torque, cogging, friction and the cogging harmonics of a scan, with standard errors.

    tau_pos = -(h_+ + h_-) / 2 minus its mean, f = (h_+ - h_-) / 2 per count. Standard errors: the
    pooled scatter sigma^2 of one sample about its count's mean gives var = sigma^2 (1/n_+ + 1/n_-) / 4
    per count; each sensor error's standard error adds its sensitivity (linear, correlated over counts)
    in quadrature; the cogging band and its harmonics propagate both exactly (linear maps). A gap filled
    from its neighbours (`_direction_means`) adds its error bound b / 2 on tau_pos, correlated over the gap,
    as a standard error b / (2 sqrt 3) (h'' uniform within +-M); the scan is refused when the gaps could
    move a cogging harmonic by more than its standard error: sqrt(sum over gaps of (sum |W_h| b / 2)^2)
    against the harmonic's standard error without the gaps' own. With the cogging order beyond counts_per_rev /
    2 the cogging is None (`ScanResult.messages` says why).
    """
    where = str(scan.path / scan.data_file)
    cpr, order = scan.motor.counts_per_rev, scan.motor.cogging_order
    h, sensitivity = _holding(scan)
    n_forward = int(np.count_nonzero(scan.data.direction > 0))
    if n_forward == 0 or n_forward == h.size:
        raise BenchFormatError(f"{where}: only {'forward' if n_forward else 'reverse'} samples: friction and "
                               "hysteresis cannot be cancelled (scan forward and back)")
    up = _direction_means(scan, h, sensitivity, True, where)
    down = _direction_means(scan, h, sensitivity, False, where)
    means = 2 * cpr - len(up.filled) - len(down.filled)
    dof = h.size - means
    if dof < 1:
        raise BenchFormatError(f"{where}: {h.size} samples for {means} counts in two directions: the scatter needs "
                               f"more than {means} (two samples per count and direction or more)")
    noise_var = float((up.squared_residuals.sum() + down.squared_residuals.sum()) / dof)
    position = -(up.holding_nm + down.holding_nm) / 2.0
    position -= position.mean()
    friction = (up.holding_nm - down.holding_nm) / 2.0
    var = noise_var * (up.inverse_hits + down.inverse_hits) / 4.0
    orders = np.arange(order, cpr // 2 + 1, order)
    theta = 2.0 * np.pi * np.arange(cpr) / cpr
    weights = np.stack([np.cos(np.outer(orders, theta)), np.sin(np.outer(orders, theta))], axis=1)
    weights *= np.where(2 * orders == cpr, 1.0, 2.0)[:, None, None] / cpr  # (k, 2, cpr): a_h, b_h = W tau
    gaps_up, gaps_down = up.fill_bound_nm.shape[1], down.fill_bound_nm.shape[1]
    s_up = np.hstack([up.sensitivity, up.fill_bound_nm / math.sqrt(3.0), np.zeros((cpr, gaps_down))])
    s_down = np.hstack([down.sensitivity, np.zeros((cpr, gaps_up)), down.fill_bound_nm / math.sqrt(3.0)])
    systematic = -(s_up + s_down) / 2.0
    systematic -= systematic.mean(axis=0)
    filled = (up.filled, down.filled)
    if (gaps_up + gaps_down) and orders.size:
        sensors = systematic[:, :up.sensitivity.shape[1]]
        std = np.sqrt(weights**2 @ var + np.sum((weights @ sensors) ** 2, axis=-1))
        fill_bound = np.hstack([up.fill_bound_nm, down.fill_bound_nm]) / 2.0  # on tau_pos
        change = np.sqrt(np.sum((np.abs(weights) @ fill_bound) ** 2, axis=-1))
        worst = np.unravel_index(np.argmax(change / np.maximum(std, 1e-300)), change.shape)
        if change[worst] > std[worst]:
            raise BenchFormatError(
                f"{where}: {_gaps_text(filled)} without a sample: filled from their neighbours they could move "
                f"cogging harmonic {orders[worst[0]]} ({'cos' if worst[1] == 0 else 'sin'}) by {change[worst]:.2g} "
                f"N m, beyond its standard error {std[worst]:.2g} N m (scan those counts again)")
    cogging = cogging_std = None
    if orders.size:
        band = harmonic_band(cpr, order, cpr // 2, order)
        impulse = np.fft.irfft(band, n=cpr)  # the cogging band's circular impulse response
        cogging = filtered(position, band)
        cogging_noise = np.real(np.fft.ifft(np.fft.fft(var) * np.fft.fft(impulse**2)))
        cogging_std = np.sqrt(np.maximum(cogging_noise, 0.0) + np.sum(filtered(systematic, band[:, None])**2, axis=1))
    c = harmonic_amplitudes(position)[orders]
    coefficient_var = weights**2 @ var + np.sum((weights @ systematic) ** 2, axis=-1)
    return ScanResult(
        cpr, order, "torque" if scan.data.torque_nm is not None else "currents",
        position, np.sqrt(var + np.sum(systematic**2, axis=1)),
        cogging, cogging_std,
        friction, np.sqrt(var + np.sum(((s_up - s_down) / 2.0) ** 2, axis=1)),
        orders, np.column_stack([c.real, -c.imag]), np.sqrt(coefficient_var),
        math.sqrt(noise_var), (n_forward, int(h.size - n_forward)), filled)


# ---------------------------------------------------------------- writing and identify


def write_scan(folder: str | Path, motor: MotorInfo, backemf_nm_per_a: np.ndarray,
               sensors: SensorCalibration | None, errors: SensorErrors, scan: ScanData) -> None:
    """Write a scan folder: backemf.csv, scan.csv, scan.toml, then bench.toml last."""
    folder = Path(folder)
    names: tuple[str, ...]
    if scan.currents_a is not None:
        values, names = scan.currents_a, CURRENT_COLUMNS
    elif scan.torque_nm is not None:
        values, names = scan.torque_nm[:, None], (TORQUE_COLUMN,)
    else:
        raise BenchFormatError(f"{folder}: a scan needs its phase currents or its torque")
    folder.mkdir(parents=True, exist_ok=True)
    write_backemf_csv(folder / "backemf.csv", backemf_nm_per_a)
    body = format_rows(np.column_stack([scan.time_s, scan.position_counts, scan.direction, values]),
                       np.array([7, 6, 0] + [6] * len(names)))
    atomic_write(folder / SCAN_DATA_FILE, ",".join(BASE_COLUMNS + names).encode() + b"\n" + body)
    atomic_write(folder / SCAN_FILE, "\n".join(["[scan]", f'file = "{SCAN_DATA_FILE}"', *errors.toml_lines(), ""]))
    atomic_write(folder / BENCH_FILE, bench_toml_text(motor, sensors, []))


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def truth_tables(folder: Path) -> dict[str, np.ndarray]:
    """The "cogging" and "position_torque" tables of the folder's truth.json (a simulated scan's or log's), if
    any."""
    path = folder / TRUTH_FILE
    if not path.is_file():
        return {}
    try:
        data = json.loads(read_bounded(path, 2**26, BenchFormatError))
        return {key: np.asarray(data[key]["torque"], float) for key in ("cogging", "position_torque") if key in data}
    except (ValueError, KeyError, TypeError) as e:
        raise BenchFormatError(f"{path}: unreadable ({e})") from None


def identify_scan(folder: str | Path, output: str | Path) -> tuple[ScanResult, list[str]]:
    """``ilcpmac identify SCAN_FOLDER``: reduce the scan, write the result JSON to ``output`` and return the
    result (its ``messages`` the warnings, its ``too_uncertain`` the error the command ends with) and the lines
    to print; with a truth.json (a simulated scan's), the RMS errors against it."""
    folder = Path(folder)
    result = reduce_scan(read_scan(folder))
    truth_nm = truth_tables(folder)
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(output, json.dumps(result.to_json(), indent=1, allow_nan=False))
    r = result
    lines = [f"standstill scan ({r.source}): {r.samples[0]} forward, {r.samples[1]} reverse samples",
             f"scatter of one sample: {r.noise_std_nm:.3g} N m",
             f"position torque: {1e3 * _rms(r.position_torque_nm):.4g} mN m RMS, "
             f"± {1e3 * _rms(r.position_torque_std_nm):.2g} mN m per count",
             f"cogging (orders {r.cogging_order}, {2 * r.cogging_order}, ...): " + (
                 "not identified (see the warning)" if r.cogging_nm is None or r.cogging_std_nm is None else
                 f"{1e3 * _rms(r.cogging_nm):.4g} mN m RMS, ± {1e3 * _rms(r.cogging_std_nm):.2g} mN m per count"),
             f"friction and hysteresis: {r.friction_nm.mean():.4g} N m mean, {r.friction_nm.min():.4g} to "
             f"{r.friction_nm.max():.4g}"]
    for h, (a, b), (sa, sb) in zip(r.orders[:4], r.coefficients_nm, r.coefficients_std_nm):
        lines.append(f"  harmonic {h}: cos {a:+.5f} ± {sa:.2g}, sin {b:+.5f} ± {sb:.2g} N m")
    for key, estimate in (("cogging", r.cogging_nm), ("position_torque", r.position_torque_nm)):
        true = truth_nm.get(key)
        if (true is not None and estimate is not None and true.shape == estimate.shape and np.all(np.isfinite(true))
                and np.any(true != true[0])):
            true = np.asarray(true, float) - np.mean(true)
            lines.append(f"vs truth: {key.replace('_', ' ')} RMS error {100 * _rms(estimate - true) / _rms(true):.3g} "
                         f"% of its RMS")
    lines.append(f"wrote {output}")
    return result, lines
