"""The drive campaign: a drive without a torque sensor or a load learns its own position table in closed loop
(docs/moteus.md).

The drive turns the rotor on its own velocity loop (`DriveBackend.run_drive_trial`) with its own table of q
current by commutation position uploaded (moteus: int8 x motor.cogging_dq_scale, 1024 entries, linear between
them, `MoteusTable`). The plan (`drive_plan`):

    round 0, uncompensated:   one trial per speed and direction, table 0
    rounds 1..N, learning:    one trial per speed and direction, all with the table of the round before
    round N + 1, verification (``verify``): the same with the final table

Its motor time, sum over the trials of settle_s + seconds, is stated before the first trial and refused beyond
max_motor_time_s; every planned request is checked against the drive's own limits and the guard's before any
motion.

Estimate, per trial k at speed s and direction d: the torque balance of the rows (identify/rolling.py, eqs. 1-7)
gives the position-locked torque per count, tau^_pos(theta), with the drive's whole q current (the table's
current flows in it). The residual the table left is

    rho^_k,s,d(theta) = tau^_pos(theta) + k_q(theta) i_k(theta)                                           (1)

i_k(theta) the uploaded table as the firmware interpolates it (`MoteusTable.sample_a`) and as it flows through
the drive's current loop where the drive states its bandwidth f_c (moteus: servo.pid_dq_hz), a first-order lag
at the trial's signed speed f:

    i_k,h -> i_k,h / (1 + j h f / f_c)      per harmonic h of the revolution                               (3)

k_q the q-axis torque per ampere of the back-EMF table (`k_q_table`). Learning law, gain L in (0, 1]:

    i_k+1(theta) = i_k(theta) - L mean_{s,d} rho^_k,s,d(theta) / k_q(theta)                                (2)

brought back to the table's 1024 entries by its Fourier series up to order 511, each order divided by
sinc^2(n / 1024), the linear interpolation's response (the route of the moteus export), and quantised
(`MoteusTable.of`). The mean over both directions cancels what reverses with the direction (the friction's
part); the lag's, which turns the table's harmonics one way forward and the other in reverse, no one table
cancels: it leaves about sin(atan(h f / f_c)) of harmonic h at +-f (`floor_table`), which is why the derived
speeds keep C f / f_c small.

Why this converges where moteus's one shot (the q current averaged by position, eq. 2 of identify/rolling.py)
does not: with the true k_q, J domega/dt = k_q i_q + tau_pos - f, and the estimator's k^_q,
rho^ = rho + (k_q - k^_q)(i_q - i_k) + (J's and the encoder's errors of J domega/dt): the error in k^_q cancels
on the table's own current, and what is left scales with the current the drive's loop adds and with the speed's
ripple, both driven by the residual rho itself. As the table improves they shrink with it (a contraction of
factor about 1 - L (1 - epsilon), epsilon their relative size); the noise is left, averaged over the rounds by
(2) (the table a running mean of weight L).

Result: `DriveCampaignResult` (drive_result.json, moteus_cogging.txt, drive_residual.png), per speed and
direction the measured residual RMS (the per-count rho^ with its mean removed) uncompensated and with the final
table, with an emulated drive the true ones, and the floor: the best table of the drive's format (least squares
of 1024 linearly interpolated entries against the true position torque over k_q, quantised as `MoteusTable.of`
does), the residual it would leave.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ilcpmac.backends.base import Backend
from ilcpmac.backends.drive import DriveBackend, DriveLimits, DriveTrial
from ilcpmac.backends.guard import LimitGuard
from ilcpmac.bench.rolling import Rolling, RollingSettings
from ilcpmac.config import CampaignConfig
from ilcpmac.core.errors import BackendError, ConfigError
from ilcpmac.core.files import atomic_write
from ilcpmac.core.records import BenchDescription, DriveTrialRequest
from ilcpmac.core.schema import finite_json, in_range, parse_section, setting
from ilcpmac.core.seeds import trial_seed
from ilcpmac.export import MOTEUS_FILE, MOTEUS_TABLE_SIZE, MoteusTable, moteus_entries
from ilcpmac.identify.rolling import RollingEstimate, estimate_rolling, k_q_table
from ilcpmac.pipeline.safety import MalformedRequest, SafetyLimits, drive_violation, owned_drive_request

__all__ = ["DRIVE_PLOT_FILE", "DRIVE_RESULT_FILE", "DriveCampaignResult", "DrivePlan", "DrivePoint", "DriveSettings",
           "LAG_SHARE", "MeasuredTrial", "Unapplied", "drive_plan", "drive_settings", "floor_table", "lagged_a",
           "learned_table", "measured_trial", "residual_nm", "ripple_rms", "run_drive_campaign", "unapplied",
           "zero_table"]

DRIVE_RESULT_FILE = "drive_result.json"
DRIVE_PLOT_FILE = "drive_residual"
#: rows of the host's per period of the highest order estimated (twice the cogging order) at the fastest derived
#: speed: issue 35's 14-bit actuator at 1 kHz rows, order 168, had 1.9 % error at 6 rows a period (1 Hz), 7 %
#: at 3 (2 Hz), the floor rising with C f / R
ROWS_PER_PERIOD = 6.0
#: the highest order the estimate resolves, in cogging orders (identify/rolling.py's default H)
ORDERS_IN_COGGING = 2
#: tan of the current's lag at the cogging order at the fastest derived speed, C f / f_c: one table for both
#: directions leaves about sin(atan(C f / f_c)) of the cogging (`floor_table`), 5 % here
LAG_SHARE = 0.05
#: the slowest derived speed over the fastest
SLOWEST_SHARE = 0.5
#: a trial's rows are at least this many revolutions (a derived seconds shorter than that is refused)
MIN_REVOLUTIONS = 2.0
#: the uncompensated residual must stand this many of its standard errors clear of 0 for a result to be usable
USABLE_SIGNIFICANCE = 3.0


def _positive_speeds(x: tuple[float, ...]) -> bool:
    return 0 < len(x) <= 16 and all(0 < v <= 1e3 for v in x) and len(set(x)) == len(x)


@dataclass(frozen=True)
class DriveSettings:
    """[drive]: a drive campaign without a torque sensor or a load (docs/moteus.md; optional keys, defaults
    shown)."""

    speeds_hz: tuple[float, ...] | None = setting(
        _positive_speeds, "the speeds learned, each in both directions, Hz (distinct, positive, at most 16); left "
        "out: the fastest with 6 host rows per period of twice the cogging order C and C f / f_c <= 0.05 (f_c the "
        "drive's current loop's bandwidth, where it states it), and half of it", None)
    seconds: float | None = setting(in_range(0.0, 3600.0, low_open=True), "seconds recorded per trial; left out: "
                                    "the trials fill max_motor_time_s", None)
    settle_s: float = setting(in_range(0.0, 60.0), "seconds each trial runs before recording (the loop settles)",
                              1.0)
    iterations: int = setting(in_range(0, 50), "learning rounds after the uncompensated one (one trial per speed "
                              "and direction each)", 4)
    gain: float = setting(in_range(0.0, 1.0, low_open=True), "learning gain L of i_k+1 = i_k - L rho / k_q, in "
                          "(0, 1]", 0.8)
    max_motor_time_s: float = setting(in_range(0.0, 86400.0, low_open=True), "the plan's motor time at most "
                                      "(settling and recording of every trial), s", 600.0)
    verify: bool = setting(None, "a verification round with the final table", True)


def drive_settings(config: CampaignConfig) -> DriveSettings:
    """The config's [drive] table (`CampaignConfig.drive_options`; none: the defaults), each error one line
    naming the file and ``[drive] KEY``."""
    settings: DriveSettings = parse_section(config.drive_options or {}, DriveSettings, str(config.path), "drive")
    return settings


# ---------------------------------------------------------------- the plan


@dataclass(frozen=True)
class DrivePlan:
    """Every trial of a drive campaign, known before the first.

    Attributes
    ----------
    speeds_hz : tuple of float
        The speeds learned (positive; each runs forward then in reverse), Hz.
    settle_s, seconds : float
        Per trial, s.
    rounds : tuple of str
        "uncompensated", "learning 1", ..., and "verification" if verified.
    seed : int
        The campaign's seed ([trials] seed); trial n's is `trial_seed` (seed, n).
    """

    speeds_hz: tuple[float, ...]
    settle_s: float
    seconds: float
    rounds: tuple[str, ...]
    seed: int

    @property
    def signed_speeds_hz(self) -> tuple[float, ...]:
        """One round's speeds in trial order: each speed forward, then in reverse."""
        return tuple(v for s in self.speeds_hz for v in (s, -s))

    @property
    def trials(self) -> int:
        return len(self.rounds) * len(self.signed_speeds_hz)

    @property
    def motor_time_s(self) -> float:
        """The motor's running time of every trial, s."""
        return self.trials * (self.settle_s + self.seconds)

    def requests(self, round_index: int, table: MoteusTable) -> list[DriveTrialRequest]:
        """The trials of round ``round_index``, all with ``table``."""
        first = round_index * len(self.signed_speeds_hz)
        return [DriveTrialRequest(speed, self.settle_s, self.seconds, table.values.astype(np.int64), table.scale_a,
                                  trial_seed(self.seed, first + k)) for k, speed in enumerate(self.signed_speeds_hz)]

    def text(self) -> str:
        """What the plan runs, one line."""
        speeds = ", ".join(f"{s:g}" for s in self.speeds_hz)
        return (f"drive campaign: {len(self.rounds)} rounds ({', '.join(self.rounds)}) x speeds +-{speeds} Hz, "
                f"{self.trials} trials of {self.settle_s:g} s settling + {self.seconds:.4g} s recorded: "
                f"{self.motor_time_s:.4g} s of motor time")


def _derived_speeds(description: BenchDescription, top_hz: float, bandwidth_hz: float | None) -> tuple[float, ...]:
    rate_hz = description.motor.log_rate_hz
    if rate_hz is None:
        raise ConfigError("[drive] speeds_hz: left out, but the backend states no host row rate (its "
                          "description's log_rate_hz) to derive them from; give speeds_hz")
    order = description.motor.cogging_order
    fastest = min(top_hz, rate_hz / (ROWS_PER_PERIOD * ORDERS_IN_COGGING * order),
                  math.inf if bandwidth_hz is None else LAG_SHARE * bandwidth_hz / order)
    fastest = _two_digits_down(fastest)
    return (_two_digits_down(SLOWEST_SHARE * fastest), fastest)


def _two_digits_down(value: float) -> float:
    """``value`` rounded down to two significant digits (0.992 -> 0.99)."""
    unit = 10.0 ** (math.floor(math.log10(value)) - 1)
    return math.floor(value / unit + 1e-9) * unit


def zero_table() -> MoteusTable:
    """The uncompensated table: every entry 0."""
    return MoteusTable(np.zeros(MOTEUS_TABLE_SIZE, np.int8), 0.0)


def drive_plan(settings: DriveSettings, config: CampaignConfig, description: BenchDescription,
               drive: DriveLimits, limits: SafetyLimits) -> DrivePlan:
    """The plan of ``settings`` on a drive, checked before any motion.

    Derived speeds (``speeds_hz`` left out): the fastest keeps `ROWS_PER_PERIOD` host rows (rate R, the
    description's log_rate_hz) per period of the highest order estimated, 2 C (C = lcm(slots, 2 pole_pairs)):
    f = R / (6 x 2 C), within the drive's and [limits]' max speed, since the estimate's floor rises with C f / R
    (the position's quantiser over fewer rows a period, then orders folding above the rows' Nyquist order), and
    where the drive states its current loop's bandwidth f_c, C f / f_c at most `LAG_SHARE`: the table's current
    lags by atan(C f / f_c), one way in one direction and the other way in the other, which no one table
    cancels (`floor_table`); the
    slowest is half of it: the cogging's speed ripple relative to the speed grows as 1 / f^2, towards the
    stick-slip where the rotor stops within a cogging period, while the floor falls only as f^2. Derived seconds:
    the trials fill max_motor_time_s.

    Raises
    ------
    ConfigError
        No inertia uncertainty in the description ([bench] inertia_uncertainty), [limits] max_current_a beyond
        the drive's own, a speed beyond the drive's max speed, a motor time beyond
        max_motor_time_s, trials too short for `MIN_REVOLUTIONS`, or a request the guard would refuse (named).
    """
    if description.motor.inertia_uncertainty is None:
        raise ConfigError(f"{config.path}: [bench] inertia_uncertainty: a drive campaign needs the inertia with its "
                          "uncertainty: without it the estimate is the q current by position, which a drive's loop "
                          "shifts in phase, and learning on it diverges")
    if config.limits.max_current_a > drive.max_current_a:
        raise ConfigError(f"{config.path}: [limits] max_current_a = {config.limits.max_current_a:g} A is beyond the "
                          f"drive's own max current ({drive.max_current_a:g} A, servo.max_current_A): lower it")
    top_hz = min(drive.max_speed_hz, limits.max_speed_hz)
    speeds = settings.speeds_hz or _derived_speeds(description, top_hz, drive.current_bandwidth_hz)
    fast = max(speeds)
    if fast > drive.max_speed_hz:
        raise ConfigError(f"{config.path}: [drive] speeds_hz: {fast:g} Hz is beyond the drive's own max speed "
                          f"({drive.max_speed_hz:g} Hz, servo.max_velocity)")
    rounds = ("uncompensated", *(f"learning {k + 1}" for k in range(settings.iterations)),
              *(("verification",) if settings.verify else ()))
    trials = len(rounds) * 2 * len(speeds)
    seconds = settings.seconds or settings.max_motor_time_s / trials - settings.settle_s
    plan = DrivePlan(tuple(sorted(speeds)), settings.settle_s, seconds, rounds, config.grid.seed)
    if plan.motor_time_s > settings.max_motor_time_s * (1.0 + 1e-9):
        raise ConfigError(f"{config.path}: [drive] max_motor_time_s: the plan runs {plan.motor_time_s:.4g} s of motor "
                          f"time ({trials} trials of {plan.settle_s:g} + {plan.seconds:.4g} s), beyond "
                          f"{settings.max_motor_time_s:g} s: fewer iterations, speeds or seconds")
    slowest = min(speeds)
    if seconds * slowest < MIN_REVOLUTIONS:
        raise ConfigError(f"{config.path}: [drive] seconds: {seconds:.4g} s at {slowest:g} Hz records "
                          f"{seconds * slowest:.3g} revolutions; a trial needs {MIN_REVOLUTIONS:g} or more")
    for request in plan.requests(0, zero_table()):
        try:
            why = drive_violation(owned_drive_request(request), description, limits)
        except MalformedRequest as e:
            why = str(e)
        if why is not None:
            raise ConfigError(f"{config.path}: [drive]: the trial at {request.speed_hz:g} Hz would be refused: {why}")
    return plan


# ---------------------------------------------------------------- estimate and learning law


def _rolling(trial: DriveTrial, description: BenchDescription, where: str) -> Rolling:
    return Rolling(Path(where), description.motor, description.backemf_nm_per_a, description.calibration,
                   RollingSettings(), trial.data)


def _table_at_counts_a(table: MoteusTable, counts_per_rev: int) -> np.ndarray:
    return table.sample_a(np.arange(counts_per_rev) / counts_per_rev)


def lagged_a(current_a: np.ndarray, speed_hz: float, bandwidth_hz: float | None) -> np.ndarray:
    """Eq. (3): a per-count current commanded at a signed speed as it flows through a current loop of
    ``bandwidth_hz`` (a first-order lag; None: none), per count: harmonic h times 1 / (1 + j h f / f_c)."""
    if bandwidth_hz is None:
        return current_a
    spectrum = np.fft.rfft(current_a)
    spectrum /= 1.0 + 1j * np.arange(spectrum.size) * speed_hz / bandwidth_hz
    return np.fft.irfft(spectrum, current_a.size)


def residual_nm(estimate: RollingEstimate, k_q: np.ndarray, table: MoteusTable, speed_hz: float,
                bandwidth_hz: float | None) -> np.ndarray:
    """Eq. (1): rho^ per count, the position torque the trial's rows tell plus the torque of the table's current
    as it flows (eq. 3), N m."""
    flowing = lagged_a(_table_at_counts_a(table, k_q.size), speed_hz, bandwidth_hz)
    delivered: np.ndarray = estimate.table_nm() + k_q * flowing
    return delivered


def learned_table(table: MoteusTable, mean_residual_nm: np.ndarray, k_q: np.ndarray, gain: float) -> MoteusTable:
    """Eq. (2): the table after one round, its per-count current i_k - L rho^ / k_q brought back to the table's
    entries and quantised (the table of 0 where that current is 0)."""
    current_a = _table_at_counts_a(table, k_q.size) - gain * mean_residual_nm / k_q
    entries_a = moteus_entries(current_a)
    if not np.any(entries_a):
        return zero_table()
    return MoteusTable.of(entries_a, "drive campaign: the learned table")


def floor_table(position_torques_nm: list[np.ndarray], k_q: np.ndarray, speeds_hz: tuple[float, ...],
                bandwidth_hz: float | None) -> MoteusTable:
    """The best one table of the drive's format for per-count position torques, one per signed speed of
    ``speeds_hz``: the current whose torque, flowing through the current loop at each speed (eq. 3; ``bandwidth_hz``
    None: as commanded), cancels them together in least squares, harmonic by harmonic of c_p = -tau_p / k_q:

        x_h = sum_p conj(G_p,h) c_p,h / sum_p |G_p,h|^2,   G_p,h = 1 / (1 + j h f_p / f_c),

    brought to the format's 1024 entries as eq. (2) is and quantised (`MoteusTable.of`); counts where a tau_p is
    not known (NaN: not visited) count as 0. A table cannot turn its phase with the direction: at +-f it leaves
    about sin(atan(h f / f_c)) of harmonic h."""
    currents = np.array([np.nan_to_num(-tau / k_q) for tau in position_torques_nm])
    spectra = np.fft.rfft(currents, axis=1)
    orders = np.arange(spectra.shape[1])
    gains = (np.ones_like(spectra) if bandwidth_hz is None else
             1.0 / (1.0 + 1j * np.outer(speeds_hz, orders) / bandwidth_hz))
    best = np.sum(np.conj(gains) * spectra, axis=0) / np.sum(np.abs(gains) ** 2, axis=0)
    return MoteusTable.of(moteus_entries(np.fft.irfft(best, k_q.size)), "drive campaign: the floor's table")


def ripple_rms(values_nm: np.ndarray) -> float:
    """The RMS over a revolution with the mean removed (NaN counts, a truth's unvisited ones, left out)."""
    return float(np.sqrt(np.nanmean(np.square(values_nm - np.nanmean(values_nm)))))


# ---------------------------------------------------------------- the result


@dataclass(frozen=True)
class DrivePoint:
    """One speed and direction of a drive campaign: the residual ripple (RMS over a revolution, the mean removed)
    uncompensated and with the final table, N m.

    Attributes
    ----------
    speed_hz : float
        Signed, Hz.
    uncompensated_nm, final_nm : float
        As measured (eq. 1 of the uncompensated and of the last trial: the verification's, or the last learning
        round's table without one).
    final_std_nm : float
        The standard error of the last trial's rho^ per count (the rolling estimate's).
    true_uncompensated_nm, true_final_nm : float or None
        The true ones (emulated drives).
    true_floor_nm : float or None
        What the best one table of the drive's format for every speed and direction learned leaves here
        (`floor_table` with the current loop's lag, run on the drive; emulated drives, whose truth tells it).
    """

    speed_hz: float
    uncompensated_nm: float
    final_nm: float
    final_std_nm: float
    true_uncompensated_nm: float | None
    true_final_nm: float | None
    true_floor_nm: float | None = None

    def text(self) -> str:
        """``"+1 Hz: 12.3 -> 0.41 mN m measured (true 12.1 -> 0.38, 32x below, 1.6x the floor)"``."""
        floor_nm = self.true_floor_nm
        line = (f"{self.speed_hz:+g} Hz: residual {1e3 * self.uncompensated_nm:.4g} -> {1e3 * self.final_nm:.3g} "
                f"+- {1e3 * self.final_std_nm:.2g} mN m measured")
        if self.true_uncompensated_nm is not None and self.true_final_nm is not None:
            line += (f" (true {1e3 * self.true_uncompensated_nm:.4g} -> {1e3 * self.true_final_nm:.3g}, "
                     f"{self.true_uncompensated_nm / self.true_final_nm:.3g}x below")
            line += ")" if floor_nm is None else f", {self.true_final_nm / floor_nm:.3g}x the floor)"
        return line


@dataclass(frozen=True)
class Unapplied:
    """What the drive's one position table cannot apply, and what it would gain (moteus: one table for every speed,
    direction and load, applied in position mode only; no per-phase current-sensor correction).

    Attributes
    ----------
    one_table_nm, own_table_nm : tuple of float, or None
        Per point of the plan, what the best one table for every point leaves of the uncompensated estimate
        through the current's lag (eq. 3, `floor_table`), and what a table of the point's own would leave (a
        per-operating-point feed-forward), N m; None where the drive states no current loop bandwidth.
    electrical_nm : float
        The final table's torque at orders pole_pairs and 2 pole_pairs (RMS over a revolution, N m), where the
        current sensors' offset and scale errors make their ripple.
    """

    one_table_nm: tuple[float, ...] | None
    own_table_nm: tuple[float, ...] | None
    electrical_nm: float

    def lines(self, speeds_hz: tuple[float, ...]) -> list[str]:
        """What it says to a reader."""
        if self.one_table_nm is None or self.own_table_nm is None:
            out = ["the drive states no current loop bandwidth: what one table for both directions costs is not known"]
        else:
            pairs = ", ".join(f"{v:+g} Hz {1e3 * own:.2g} instead of {1e3 * one:.2g}"
                              for v, one, own in zip(speeds_hz, self.one_table_nm, self.own_table_nm))
            out = ["the drive holds one table for every speed and direction (in position mode only): a table of each "
                   f"point's own, which it cannot apply, would leave about (mN m, the estimate through the current's "
                   f"lag) {pairs}"]
        out.append(f"the table holds {1e3 * self.electrical_nm:.2g} mN m at orders p and 2p, where the current "
                   "sensors' offset and scale errors ripple, as learned at the no-load current: the drive has no "
                   "per-phase current-sensor correction, and a scale error's ripple grows with the load, which no "
                   "position table follows")
        return out

    def to_json(self) -> dict[str, Any]:
        return {"one_table_nm": None if self.one_table_nm is None else list(self.one_table_nm),
                "own_table_nm": None if self.own_table_nm is None else list(self.own_table_nm),
                "electrical_nm": self.electrical_nm}


def unapplied(taus: list[np.ndarray], k_q: np.ndarray, table: MoteusTable, speeds_hz: tuple[float, ...],
              pole_pairs: int, bandwidth_hz: float | None) -> Unapplied:
    """`Unapplied` from the uncompensated trials' position torques per count (their rho^ is tau^_pos), one per
    signed speed, and the final table."""
    own = one = None
    if bandwidth_hz is not None:
        joint = _table_at_counts_a(floor_table(taus, k_q, speeds_hz, bandwidth_hz), k_q.size)
        one = tuple(ripple_rms(t + k_q * lagged_a(joint, v, bandwidth_hz)) for t, v in zip(taus, speeds_hz))
        own = tuple(ripple_rms(t + k_q * lagged_a(_table_at_counts_a(floor_table([t], k_q, (v,), bandwidth_hz),
                                                                     k_q.size), v, bandwidth_hz))
                    for t, v in zip(taus, speeds_hz))
    amplitudes = np.abs(np.fft.rfft(k_q * _table_at_counts_a(table, k_q.size)) / k_q.size * 2)
    return Unapplied(one, own, float(np.sqrt(np.sum(amplitudes[[pole_pairs, 2 * pole_pairs]] ** 2) / 2)))


@dataclass(frozen=True)
class DriveCampaignResult:
    """What a drive campaign learned and measured.

    Attributes
    ----------
    path : Path
        The directory its files are in.
    plan : DrivePlan
    points : tuple of DrivePoint
        Per speed and direction, in the plan's order.
    table : MoteusTable
        The final table (moteus_cogging.txt).
    format_floor_nm : float or None
        The residual RMS the best table of the drive's format leaves of the true position torque where its current
        flowed as commanded (`floor_table` without the lag; emulated drives), N m: the format's own floor, below
        each point's (`DrivePoint.true_floor_nm`).
    motor_time_planned_s, motor_time_used_s : float
    unapplied : Unapplied
        What the drive's table cannot apply, and what it would gain.
    usable : bool
        False where the result is too uncertain to use (``messages`` says why).
    stored : bool
        Whether the table was written to the drive's flash (``--write-config``).
    messages : tuple of str
    """

    path: Path
    plan: DrivePlan
    points: tuple[DrivePoint, ...]
    table: MoteusTable
    format_floor_nm: float | None
    motor_time_planned_s: float
    motor_time_used_s: float
    unapplied: Unapplied
    usable: bool
    stored: bool
    messages: tuple[str, ...]

    def lines(self) -> list[str]:
        """The result as a reader reads it."""
        out = [point.text() for point in self.points]
        if self.format_floor_nm is not None:
            out.append(f"the floor at each point: the best one {MOTEUS_TABLE_SIZE}-entry int8 table for every speed "
                       "and direction, its current through the drive's current loop; without the loop's lag "
                       f"{1e3 * self.format_floor_nm:.3g} mN m")
        out += self.unapplied.lines(self.plan.signed_speeds_hz)
        out.append(f"motor time: {self.motor_time_used_s:.4g} s of {self.motor_time_planned_s:.4g} s planned")
        return out + list(self.messages)

    def to_json(self) -> dict[str, Any]:
        """drive_result.json."""
        result: dict[str, Any] = finite_json({
            "speeds_hz": list(self.plan.speeds_hz), "rounds": list(self.plan.rounds),
            "settle_s": self.plan.settle_s, "seconds": self.plan.seconds,
            "motor_time_planned_s": self.motor_time_planned_s, "motor_time_used_s": self.motor_time_used_s,
            "format_floor_nm": self.format_floor_nm, "unapplied": self.unapplied.to_json(), "usable": self.usable,
            "stored": self.stored,
            "points": [{"speed_hz": p.speed_hz, "uncompensated_nm": p.uncompensated_nm, "final_nm": p.final_nm,
                        "final_std_nm": p.final_std_nm, "true_uncompensated_nm": p.true_uncompensated_nm,
                        "true_final_nm": p.true_final_nm, "true_floor_nm": p.true_floor_nm} for p in self.points],
            "table": {"scale_a": float(np.float32(self.table.scale_a)), "values": self.table.values.tolist()},
            "messages": list(self.messages)})
        return result


@dataclass(frozen=True)
class MeasuredTrial:
    """One trial as the campaign keeps it: rho^ per count and its standard error (N m), k_q per count (the
    back-EMF table's, the same for every trial, N m / A)."""

    trial: DriveTrial
    residual_nm: np.ndarray
    std_nm: float
    k_q: np.ndarray


def measured_trial(trial: DriveTrial, description: BenchDescription, table: MoteusTable,
                   bandwidth_hz: float | None = None) -> MeasuredTrial:
    """A trial's rows run with ``table`` through the rolling estimate: rho^ per count (eq. 1), the table's current
    through a current loop of ``bandwidth_hz`` (None: as commanded)."""
    rolling = _rolling(trial, description, f"trial at {trial.request.speed_hz:g} Hz")
    k_q = k_q_table(rolling)
    estimate = estimate_rolling(rolling)
    return MeasuredTrial(trial, residual_nm(estimate, k_q, table, trial.request.speed_hz, bandwidth_hz),
                         float(estimate.table_std_nm()[0]), k_q)


def _true_rms(measured: MeasuredTrial, true_position: bool = False) -> float | None:
    values = measured.trial.true_position_torque_nm if true_position else measured.trial.true_residual_nm
    return None if values is None else ripple_rms(values)


def _plot(first: list[MeasuredTrial], last: list[MeasuredTrial], plan: DrivePlan, path: Path) -> None:
    """Per direction, the residual by position uncompensated and, on its own scale, with the final table."""
    from ilcpmac import plotting

    fig, axes = plotting.figure(4, 2.2)
    for k_axis, (sign, name) in enumerate(((1.0, "forward"), (-1.0, "reverse"))):
        before, after = axes[2 * k_axis], axes[2 * k_axis + 1]
        for speed, colour in plotting.group_colours(plan.speeds_hz).items():
            k = plan.signed_speeds_hz.index(sign * speed)
            degrees = plotting.mechanical_degrees(np.arange(first[k].residual_nm.size), first[k].residual_nm.size)
            before.plot(degrees, 1e3 * first[k].residual_nm, color=colour, lw=0.6, label=f"{speed:g} Hz")
            after.plot(degrees, 1e3 * last[k].residual_nm, color=colour, lw=0.8, label=f"{speed:g} Hz measured")
            true = last[k].trial.true_residual_nm
            if true is not None:
                after.plot(degrees, 1e3 * (true - np.nanmean(true)), color=colour, lw=0.8, ls=":",
                           label=f"{speed:g} Hz true")
        before.set_ylabel(f"{name}, none (mN m)")
        after.set_ylabel(f"{name}, final (mN m)")
        plotting.legend(before, ncol=3)
        plotting.legend(after, ncol=4)
    plotting.angle_axis(axes[-1])
    plotting.save(fig, path)


def run_drive_campaign(config: CampaignConfig, backend: Backend, out_dir: Path,
                       on_event: Callable[[str], None] | None = None,
                       write_config: bool = False) -> DriveCampaignResult:
    """Learn the drive's own table (the module's docstring), writing drive_result.json, moteus_cogging.txt and
    drive_residual.png to ``out_dir``; the table goes to the drive's flash only with ``write_config``, at the
    end. The campaign wraps ``backend`` in a `LimitGuard` of the config's [limits] itself.

    Raises
    ------
    ConfigError
        [drive] or a plan beyond the drive's limits or the motor time (before any motion).
    BackendError
        ``backend`` is no `DriveBackend`.
    SafetyError, BackendError, IdentificationError
        From a trial (the backend stops the drive on every path).
    """
    tell = on_event or (lambda _text: None)
    settings = drive_settings(config)
    if not isinstance(backend, DriveBackend):
        raise BackendError(f"the {type(backend).__name__} backend drives no drive without a load (it has no "
                           "run_drive_trial, store_table or drive_limits): a [drive] campaign needs one")
    description = backend.describe()
    limits = SafetyLimits.of_campaign(config.limits, description.limits, 0)
    guard = LimitGuard(backend, description, limits)
    drive = backend.drive_limits()
    bandwidth_hz = drive.current_bandwidth_hz
    plan = drive_plan(settings, config, description, drive, limits)
    tell(plan.text())
    table = zero_table()
    rounds: list[list[MeasuredTrial]] = []
    used_s = 0.0
    for index, name in enumerate(plan.rounds):
        measured = []
        for request in plan.requests(index, table):
            m = measured_trial(guard.run_drive_trial(request), description, table, bandwidth_hz)
            used_s += request.duration_s
            measured.append(m)
            true = _true_rms(m)
            tell(f"{name}: {request.speed_hz:+g} Hz: residual {1e3 * ripple_rms(m.residual_nm):.4g} +- "
                 f"{1e3 * m.std_nm:.2g} mN m measured" + ("" if true is None else f", {1e3 * true:.4g} true")
                 + f"; {m.trial.lost} of {m.trial.polls} polls lost")
        rounds.append(measured)
        if name != "verification":
            table = learned_table(table, np.mean([m.residual_nm for m in measured], axis=0), measured[0].k_q,
                                  settings.gain)
    first, last = rounds[0], rounds[-1]
    k_q = first[0].k_q
    format_floor: float | None = None
    floors: list[float | None] = [None] * len(last)
    true_tau = [m.trial.true_position_torque_nm for m in last]
    if all(t is not None for t in true_tau):
        taus = [np.asarray(t, float) for t in true_tau]
        speeds = plan.signed_speeds_hz
        true_k_q = _true_scale(last, k_q, bandwidth_hz) * k_q
        plain = _table_at_counts_a(floor_table(taus, true_k_q, speeds, None), k_q.size)
        format_floor = float(np.sqrt(np.mean([ripple_rms(t + true_k_q * plain) ** 2 for t in taus])))
        best = floor_table(taus, true_k_q, speeds, bandwidth_hz)
        tell("the floor: the least-squares table of the drive's format for every speed and direction, run once at "
             "each (an emulated drive's truth tells what it leaves; not part of the campaign's motor time)")
        floors = [ripple_rms(np.asarray(guard.run_drive_trial(request).true_residual_nm, float))
                  for request in plan.requests(len(plan.rounds) - 1, best)]
    points = tuple(DrivePoint(a.trial.request.speed_hz, ripple_rms(a.residual_nm), ripple_rms(b.residual_nm),
                              b.std_nm, _true_rms(a, true_position=True), _true_rms(b), floor)
                   for a, b, floor in zip(first, last, floors))
    messages = _usability(points, settings.verify)
    result = DriveCampaignResult(out_dir, plan, points, table, format_floor, plan.motor_time_s, used_s,
                                 unapplied([m.residual_nm for m in first], k_q, table, plan.signed_speeds_hz,
                                           description.motor.pole_pairs, bandwidth_hz),
                                 not messages, False, tuple(messages))
    out_dir.mkdir(parents=True, exist_ok=True)
    if write_config:
        guard.store_table(plan.requests(len(plan.rounds) - 1, table)[0])
        result = replace(result, stored=True)
    atomic_write(out_dir / MOTEUS_FILE, "\n".join(table.lines()) + "\n")
    atomic_write(out_dir / DRIVE_RESULT_FILE, json.dumps(result.to_json(), indent=1, allow_nan=False))
    _plot(first, last, plan, out_dir / DRIVE_PLOT_FILE)
    for line in result.lines():
        tell(line)
    return result


def _true_scale(trials: list[MeasuredTrial], k_q: np.ndarray, bandwidth_hz: float | None) -> float:
    """The true torque per ampere over the described k_q, from an emulated drive's truth: the least squares of the
    table's true torque (true residual less true position torque) on k_q times its flowing current (eq. 3); 1
    where the tables were 0. The floor is the true drive's, whatever the campaign was told of its k_q."""
    made, modelled = [], []
    for m in trials:
        request = m.trial.request
        table = MoteusTable(np.asarray(request.table_values, np.int8), request.table_scale_a)
        x = k_q * lagged_a(_table_at_counts_a(table, k_q.size), request.speed_hz, bandwidth_hz)
        y = np.asarray(m.trial.true_residual_nm, float) - np.asarray(m.trial.true_position_torque_nm, float)
        known = np.isfinite(y)
        made.append(y[known])
        modelled.append(x[known])
    x, y = np.concatenate(modelled), np.concatenate(made)
    return float(x @ y / (x @ x)) if np.any(x) else 1.0


def _usability(points: tuple[DrivePoint, ...], verified: bool) -> list[str]:
    """Why a result is too uncertain to use, if it is."""
    out = []
    if not verified:
        out.append("not verified ([drive] verify = false): the final table's residual is the last learning round's "
                   "table's, not its own")
    for p in points:
        if p.uncompensated_nm < USABLE_SIGNIFICANCE * p.final_std_nm:
            out.append(f"{p.speed_hz:+g} Hz: the uncompensated residual ({1e3 * p.uncompensated_nm:.3g} mN m) is "
                       f"within {USABLE_SIGNIFICANCE:g} standard errors ({1e3 * p.final_std_nm:.2g} mN m): too "
                       "uncertain to tell what the table does; longer trials or a slower speed")
        elif p.final_nm >= p.uncompensated_nm:
            out.append(f"{p.speed_hz:+g} Hz: the final table leaves {1e3 * p.final_nm:.3g} mN m, no less than the "
                       f"uncompensated {1e3 * p.uncompensated_nm:.3g}: do not use it")
    return out

