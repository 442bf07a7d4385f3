"""Limits every request obeys, whatever the stages ask: the one check that decides what may reach a backend.

`request_violation` is that check (docs/safety.md): on a copy of the request in
values the host owns (`owned_request`), the form, then the limits
(`limit_violation`). The campaign's `LimitGuard` checks every request of every
phase so and sends exactly the copy it checked, the plan check covers every
planned request before the first trial, and the bench protocol's target every
REQUEST. `enforce_limits` and `clip_to_trust_region` are the two
corrections the pipeline applies instead of refusing: the feed-forward and a
stage's calibration are clipped, everything else out of bounds is an error.
"""

from __future__ import annotations

import math
import numbers
import operator
from dataclasses import dataclass
from typing import Iterable

import numpy as np

from ilcpmac.config import LimitSettings
from ilcpmac.core.errors import ConfigError, IdentificationError, SafetyError
from ilcpmac.core.records import (
    BenchDescription,
    BenchLimits,
    DriveTrialRequest,
    SensorCalibration,
    TrialRequest,
    immutable,
)
from ilcpmac.model.tables import current_references, dead_counts
from ilcpmac.stages.base import Identified

#: relative slack of every comparison with a limit: what clipping to a bound may leave after rounding
ROUNDING = 1e-9


#: the limits a bench states too (`BenchLimits`): a campaign's are the smaller of the two
BENCH_BOUNDED = ("max_current_a", "max_torque_nm", "max_speed_hz")
#: the limits of the config's [limits] alone (`LimitSettings`), besides the feed-forward's bound
CONFIG_ONLY = ("max_scale_deviation", "max_offset_deviation_a", "max_torque_gain_deviation", "max_samples_per_trial",
               "max_trial_duration_s")


@dataclass(frozen=True, kw_only=True)
class SafetyLimits:
    """Bounds on a request (docs/safety.md); the optional ones are unbounded unless given.

    Attributes
    ----------
    max_correction_nm : float
        |feed-forward| per count, N m.
    max_current_a : float
        |I*_p| per count and phase, and the flowing |i_p| where the sensors are known, A.
    max_torque_nm : float
        |torque reference| per count, N m.
    max_speed_hz : float
        Speed set point, Hz.
    max_scale_deviation, max_offset_deviation_a, max_torque_gain_deviation : float
        The calibration trust region: relative deviation of each current scale, deviation of each
        current offset in amperes (counts / scale), relative deviation of the torque gain.
    max_samples_per_trial : float
        revolutions x counts_per_rev.
    max_trial_duration_s : float
        (warm-up + recorded revolutions) / speed, s.
    warmup_revolutions : int
        Revolutions a trial runs before recording, counted in its duration.
    from_config : bool
        Messages name the [limits] keys (True) or "the bench limit" (False).
    """

    max_correction_nm: float
    max_current_a: float
    max_torque_nm: float
    max_speed_hz: float = math.inf
    max_scale_deviation: float = math.inf
    max_offset_deviation_a: float = math.inf
    max_torque_gain_deviation: float = math.inf
    max_samples_per_trial: float = math.inf
    max_trial_duration_s: float = math.inf
    warmup_revolutions: int = 0
    from_config: bool = False

    @classmethod
    def of_bench(cls, bench: BenchLimits) -> "SafetyLimits":
        """What a bench announces: current, torque and speed."""
        return cls(max_correction_nm=math.inf, **{key: getattr(bench, key) for key in BENCH_BOUNDED})

    @classmethod
    def of_campaign(cls, settings: LimitSettings, bench: BenchLimits, warmup_revolutions: int) -> "SafetyLimits":
        """The config's [limits], never beyond what the bench accepts (`BENCH_BOUNDED`)."""
        return cls(max_correction_nm=settings.correction_nm(),
                   **{key: min(getattr(settings, key), getattr(bench, key)) for key in BENCH_BOUNDED},
                   **{key: getattr(settings, key) for key in CONFIG_ONLY},
                   warmup_revolutions=warmup_revolutions, from_config=True)

    def text(self, key: str, unit: str) -> str:
        """Limit ``key`` as a message names it: its value and where it comes from."""
        value = getattr(self, key)
        if not self.from_config:
            return f"the bench limit of {value:g} {unit}"
        bench = " or the bench's" if key in BENCH_BOUNDED else ""
        return f"{value:g} {unit} ([limits] {key}{bench})"


@dataclass(frozen=True)
class FlowingCurrent:
    """The phase currents that flow for references I*: i_p = gain_p I*_p + offset_p (eq. 1.2).

    Attributes
    ----------
    gain : ndarray, shape (3,)
        epsilon alpha_p = s*_p / s_p.
    offset_a : ndarray, shape (3,)
        beta_p = (o_p - o*_p) / s_p, A.
    """

    gain: np.ndarray
    offset_a: np.ndarray

    @classmethod
    def at(cls, calibration: SensorCalibration, truth: SensorCalibration) -> "FlowingCurrent":
        """The currents under controller ``calibration`` (s*, o*) with true sensors ``truth`` (s, o)."""
        return cls(calibration.current_scale / truth.current_scale,
                   (truth.current_offset - calibration.current_offset) / truth.current_scale)


def identified_truth(identified: Identified) -> SensorCalibration:
    """The true sensors the identification found: scale 1 / G_s, offset o*_s + beta / G_s, torque gain g_t
    (the calibration the current-sensor stage starts from)."""
    gain = identified.sensor_gain
    if not (np.all(np.isfinite(gain)) and np.all(gain > 0) and np.all(np.isfinite(identified.beta_a))
            and 0 < identified.torque_gain_v_per_nm < math.inf):
        raise IdentificationError(
            "the identified sensors bound the flowing current and need finite positive gains and finite offsets, "
            f"got epsilon alpha {identified.epsilon * identified.alpha}, beta {identified.beta_a} A, "
            f"delta {identified.delta}")
    return SensorCalibration(1.0 / gain, identified.calibration.current_offset + identified.beta_a / gain,
                             identified.torque_gain_v_per_nm)


def unconfirmed_scale_violation(identified: Identified, limits: SafetyLimits) -> str | None:
    """Why identified sensors that rest on an unconfirmed back-EMF table may not bound the flowing current, or
    None when they keep every current scale within max_scale_deviation of the bench's calibration.

    epsilon is the true torque over the one the bench's table predicts: a table k times too large gives
    epsilon / k, a current scale k times too large and k times the current the bound believes. Only a table
    the config confirms ([bench.backemf] or backemf_file) makes a larger change something the data show.
    """
    change = identified_truth(identified).current_scale / identified.calibration.current_scale
    if np.all(np.abs(change - 1.0) <= limits.max_scale_deviation * (1.0 + ROUNDING)):
        return None
    return (f"the identified epsilon {identified.epsilon:.3g} puts the current scales at {change.min():.3g}x to "
            f"{change.max():.3g}x the bench's calibration's, beyond {100 * limits.max_scale_deviation:g} % "
            f"([limits] max_scale_deviation): the bench's back-EMF table is wrong, {1.0 / identified.epsilon:.3g}x "
            "its true one if its calibration is right (phase vs line-to-line is 1.73x, peak vs RMS 1.41x); "
            "confirm the table with [bench.backemf] or backemf_file (docs/safety.md)")


def trust_edges(limits: SafetyLimits) -> list[FlowingCurrent]:
    """The currents at the edge of the trust region around the true sensors that bound every other:
    epsilon alpha = 1 + max_scale_deviation with beta = +-max_offset_deviation_a (none if unbounded)."""
    if not math.isfinite(limits.max_scale_deviation + limits.max_offset_deviation_a):
        return []
    gain = np.full(3, 1.0 + limits.max_scale_deviation)
    return [FlowingCurrent(gain, np.full(3, sign * limits.max_offset_deviation_a)) for sign in (1.0, -1.0)]


# ---------------------------------------------------------------- calibration trust region


def _trust_deviation(calibration: SensorCalibration, centre: SensorCalibration, centre_name: str,
                     limits: SafetyLimits) -> str | None:
    """Why ``calibration`` lies outside the trust region around ``centre``, or None."""
    deviations = (("current scale", calibration.current_scale / centre.current_scale - 1.0,
                   "max_scale_deviation", "%", 100.0),
                  ("current offset", (calibration.current_offset - centre.current_offset) / centre.current_scale,
                   "max_offset_deviation_a", "A", 1.0),
                  ("torque gain", np.array([calibration.torque_gain / centre.torque_gain - 1.0]),
                   "max_torque_gain_deviation", "%", 100.0))
    for what, values, key, unit, factor in deviations:
        p = int(np.argmax(np.abs(values)))
        if abs(values[p]) > getattr(limits, key) * (1.0 + ROUNDING):
            phase = f" of phase {'abc'[p]}" if values.size == 3 else ""
            return (f"{what}{phase} deviates {factor * values[p]:+.4g} {unit} from the {centre_name}, "
                    f"beyond {factor * getattr(limits, key):g} {unit} ([limits] {key})")
    return None


def calibration_violation(calibration: SensorCalibration, nominal: SensorCalibration,
                          truth: SensorCalibration | None, limits: SafetyLimits) -> str | None:
    """Why ``calibration`` is outside the trust regions, or None.

    A calibration is trusted within the region around the bench's ``nominal`` one (what it runs
    today) or, once identified, around the true sensors ``truth`` (where the stages aim).
    """
    near_nominal = _trust_deviation(calibration, nominal, "bench's calibration", limits)
    if near_nominal is None or truth is None:
        return near_nominal
    return _trust_deviation(calibration, truth, "identified sensors", limits)


def clip_to_trust_region(calibration: SensorCalibration, nominal: SensorCalibration,
                         truth: SensorCalibration, limits: SafetyLimits) -> SensorCalibration:
    """``calibration`` itself when trusted (`calibration_violation`), else clipped into the region around ``truth``."""
    if calibration_violation(calibration, nominal, truth, limits) is None:
        return calibration
    d_scale, d_gain = limits.max_scale_deviation, limits.max_torque_gain_deviation
    room_a = limits.max_offset_deviation_a * truth.current_scale
    return SensorCalibration(
        np.clip(calibration.current_scale, truth.current_scale * (1 - d_scale), truth.current_scale * (1 + d_scale)),
        np.clip(calibration.current_offset, truth.current_offset - room_a, truth.current_offset + room_a),
        float(np.clip(calibration.torque_gain, truth.torque_gain * (1 - d_gain), truth.torque_gain * (1 + d_gain))))


# ---------------------------------------------------------------- torque and currents


def _amperes_per_nm(backemf_nm_per_a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """I*_p per N m of torque reference per count and phase (`current_references`), and the `dead_counts`
    (they get 0 A / N m and admit only zero torque)."""
    return (current_references(np.ones(len(backemf_nm_per_a)), backemf_nm_per_a),
            dead_counts(backemf_nm_per_a))


def _phase_interval(gain: np.ndarray, offset: np.ndarray, bound: float) -> tuple[np.ndarray, np.ndarray]:
    """Per count, the tau with |gain_p tau + offset_p| <= bound in every phase (low > high: none)."""
    zero = gain == 0
    safe = np.where(zero, 1.0, gain)
    with np.errstate(over="ignore"):  # a tiny gain: no bound there
        ends = np.stack([(-bound - offset) / safe, (bound - offset) / safe])
    room = np.abs(offset) <= bound
    low = np.where(zero, np.where(room, -np.inf, np.inf), ends.min(axis=0))
    high = np.where(zero, np.where(room, np.inf, -np.inf), ends.max(axis=0))
    return low.max(axis=1), high.min(axis=1)


def torque_interval_nm(backemf_nm_per_a: np.ndarray, limits: SafetyLimits,
                       flowing: FlowingCurrent | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per count, the torque references [low, high] within max_torque_nm whose current references
    I*_p = tau K_p / sum K^2, and flowing currents (when ``flowing`` is known), stay within max_current_a."""
    per_nm, dead = _amperes_per_nm(backemf_nm_per_a)
    low, high = _phase_interval(per_nm, np.zeros(3), limits.max_current_a)
    if flowing is not None:
        flow_low, flow_high = _phase_interval(per_nm * flowing.gain, flowing.offset_a, limits.max_current_a)
        low, high = np.maximum(low, flow_low), np.minimum(high, flow_high)
    low = np.maximum(low, -limits.max_torque_nm)
    high = np.minimum(high, limits.max_torque_nm)
    return np.where(dead, np.maximum(low, 0.0), low), np.where(dead, np.minimum(high, 0.0), high)


def _peak(values: np.ndarray) -> tuple[int, ...]:
    """The index of the largest magnitude in ``values``."""
    return tuple(int(i) for i in np.unravel_index(int(np.argmax(np.abs(values))), values.shape))


def torque_violation(torque_reference_nm: np.ndarray, backemf_nm_per_a: np.ndarray, limits: SafetyLimits,
                     flowing: FlowingCurrent | None = None) -> str | None:
    """Why a torque reference per count breaks the torque or current limits, or None."""
    tau = torque_reference_nm
    (k,) = _peak(tau)
    if abs(tau[k]) > limits.max_torque_nm * (1.0 + ROUNDING):
        return (f"torque reference {tau[k]:.4g} N m at count {k} (set point + feed-forward + excitation) "
                f"exceeds {limits.text('max_torque_nm', 'N m')}")
    per_nm, dead = _amperes_per_nm(backemf_nm_per_a)
    if np.any(dead & (tau != 0)):
        k = int(np.argmax(dead & (tau != 0)))
        return (f"torque reference {tau[k]:.4g} N m at count {k}, where the back-EMF table is zero in every "
                "phase (no current makes torque there)")
    currents = [("current reference", tau[:, None] * per_nm, "")]
    if flowing is not None:
        currents.append(("flowing current", flowing.gain * currents[0][1] + flowing.offset_a,
                         " (epsilon alpha and beta of the identified sensors at this calibration)"))
    for what, amperes, why in currents:
        k, p = _peak(amperes)
        if abs(amperes[k, p]) > limits.max_current_a * (1.0 + ROUNDING):
            return (f"{what} {amperes[k, p]:.4g} A in phase {'abc'[p]} at count {k}{why} exceeds "
                    f"{limits.text('max_current_a', 'A')}")
    return None


def enforce_limits(request: TrialRequest, backemf_nm_per_a: np.ndarray, limits: SafetyLimits,
                   flowing: FlowingCurrent | None = None) -> TrialRequest:
    """Clip the feed-forward to max_correction_nm and so that the torque reference stays within
    `torque_interval_nm`; nothing else changes.

    Raises `SafetyError` when the set point plus excitation alone break the limits.
    """
    base = request.torque_setpoint_nm + request.excitation_nm
    why = torque_violation(base, backemf_nm_per_a, limits, flowing)
    if why is not None:
        raise SafetyError(f"set point {request.torque_setpoint_nm:g} N m with its excitation: {why}")
    low, high = torque_interval_nm(backemf_nm_per_a, limits, flowing)
    correction = np.clip(request.feedforward_nm, -limits.max_correction_nm, limits.max_correction_nm)
    correction = np.clip(base + correction, low, high) - base
    return request.with_changes(feedforward_nm=correction)


# ---------------------------------------------------------------- the check


class MalformedRequest(SafetyError):
    """No valid request at all: a wrong type or shape, NaN or infinity (`owned_request`)."""


def _what(value: object) -> str:
    """``value`` for a message: a builtin scalar shown, anything else by its type alone (whose repr may lie, raise
    or never end)."""
    return repr(value) if type(value) in (bool, int, float, str, type(None)) else type(value).__name__


def _owned_float(value: object, name: str) -> float:
    """``value`` as a builtin float, converted once; `MalformedRequest` naming ``name`` for anything but a real
    number (a bool included)."""
    if not isinstance(value, numbers.Real) or isinstance(value, bool | np.bool_):
        raise MalformedRequest(f"{name} must be a real number, got {_what(value)}")
    try:
        return float(value)
    except (TypeError, ValueError, OverflowError) as e:
        raise MalformedRequest(f"{name}: {type(value).__name__} does not convert to a float ({e})") from None


def _owned_int(value: object, name: str) -> int:
    """``value`` as a builtin int, converted once; `MalformedRequest` naming ``name`` for anything but an integer
    (a bool or a whole float included)."""
    if not isinstance(value, numbers.Integral) or isinstance(value, bool | np.bool_):
        raise MalformedRequest(f"{name} must be an integer, got {_what(value)}")
    try:
        return int(operator.index(value))  # index() may return an int subclass; int() of one is a builtin int
    except (TypeError, ValueError, OverflowError) as e:
        raise MalformedRequest(f"{name}: {type(value).__name__} does not convert to an int ({e})") from None


def _owned_table(table: object, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """``table`` as an `immutable` float64 copy of ``shape``, finite; `MalformedRequest` naming ``name`` otherwise.

    Read through `numpy.ndarray`'s own view, so that a subclass's methods and attributes are never consulted."""
    if not isinstance(table, np.ndarray):
        raise MalformedRequest(f"{name} must be an array of real numbers, got {_what(table)}")
    plain = np.ndarray.view(table, np.ndarray)
    if plain.dtype.kind not in "fiu":
        raise MalformedRequest(f"{name} must be an array of real numbers, got {plain.dtype}")
    if plain.shape != shape:
        raise MalformedRequest(f"{name} has shape {plain.shape}, the bench needs {shape}")
    owned = immutable(np.asarray(plain, np.float64))
    if not np.isfinite(owned).all():
        raise MalformedRequest(f"{name} holds NaN or infinite values")
    return owned


def owned_request(request: object, counts_per_rev: int) -> TrialRequest:
    """``request`` copied once into values the host owns: builtin ``float`` and ``int``, `immutable` float64 tables
    of ``counts_per_rev`` values (docs/safety.md, "Check what is sent, send what was checked").

    Every check of a request is made on this copy and exactly this copy goes on, so that a value whose class lies
    to comparisons, or an array its maker changes from another thread, cannot pass as one thing and run as another.

    Raises
    ------
    MalformedRequest
        For no valid request at all: not a `TrialRequest`, a wrong type or shape, NaN or infinity anywhere,
        revolutions or seed out of range, a speed or calibration that is not positive.
    """
    if not isinstance(request, TrialRequest):
        raise MalformedRequest(f"a request must be a TrialRequest, got {_what(request)}")
    cal = request.calibration
    if not isinstance(cal, SensorCalibration):
        raise MalformedRequest(f"calibration must be a SensorCalibration, got {_what(cal)}")
    calibration = SensorCalibration(_owned_table(cal.current_scale, "calibration current_scale", (3,)),
                                    _owned_table(cal.current_offset, "calibration current_offset", (3,)),
                                    _owned_float(cal.torque_gain, "calibration torque_gain"))
    if not (np.all(calibration.current_scale > 0) and 0 < calibration.torque_gain < math.inf):
        raise MalformedRequest("calibration needs finite positive current scales and torque gain, and finite offsets")
    owned = TrialRequest(
        torque_setpoint_nm=_owned_float(request.torque_setpoint_nm, "torque set point"),
        speed_setpoint_hz=_owned_float(request.speed_setpoint_hz, "speed set point"),
        revolutions=_owned_int(request.revolutions, "revolutions"),
        feedforward_nm=_owned_table(request.feedforward_nm, "feedforward_nm", (counts_per_rev,)),
        excitation_nm=_owned_table(request.excitation_nm, "excitation_nm", (counts_per_rev,)),
        calibration=calibration, seed=_owned_int(request.seed, "seed"))
    if not 1 <= owned.revolutions < 2**32:
        raise MalformedRequest(f"revolutions must be 1 to 2^32-1, got {owned.revolutions}")
    if not 0 <= owned.seed < 2**32:
        raise MalformedRequest(f"seed must be a 32-bit unsigned integer, got {owned.seed}")
    if not math.isfinite(owned.torque_setpoint_nm):
        raise MalformedRequest(f"torque set point must be finite, got {owned.torque_setpoint_nm}")
    if not 0 < owned.speed_setpoint_hz < math.inf:
        raise MalformedRequest(f"speed set point must be positive, got {owned.speed_setpoint_hz} Hz")
    return owned


def extent_violation(request: TrialRequest, counts_per_rev: int, limits: SafetyLimits) -> str | None:
    """Why ``request`` (well formed) breaks the speed, sample or duration limit, or None."""
    speed, revolutions = request.speed_setpoint_hz, request.revolutions
    if speed > limits.max_speed_hz * (1.0 + ROUNDING):
        return f"speed set point {speed:g} Hz exceeds {limits.text('max_speed_hz', 'Hz')}"
    if revolutions * counts_per_rev > limits.max_samples_per_trial:
        return (f"{revolutions} revolutions of {counts_per_rev} counts ({revolutions * counts_per_rev} samples) "
                f"exceed {limits.text('max_samples_per_trial', 'samples')}")
    duration = (limits.warmup_revolutions + revolutions) / speed
    if duration > limits.max_trial_duration_s * (1.0 + ROUNDING):
        return (f"the trial lasts {duration:.4g} s ({limits.warmup_revolutions} warm-up and {revolutions} "
                f"revolutions at {speed:g} Hz), beyond {limits.text('max_trial_duration_s', 's')}")
    return None


#: entries of a drive's position table, at most (moteus: 1024)
MAX_DRIVE_TABLE = 2**16
#: the longest a drive trial settles before recording, s
MAX_DRIVE_SETTLE_S = 60.0


def owned_drive_request(request: object) -> DriveTrialRequest:
    """``request`` copied once into values the host owns, as `owned_request` does for a bench trial: builtin
    ``float`` and ``int``, an `immutable` int64 table of whole entries within int8.

    Raises
    ------
    MalformedRequest
        For no valid drive request: not a `DriveTrialRequest`, a speed that is 0 or not finite, a settle time
        outside [0, `MAX_DRIVE_SETTLE_S`], recorded seconds not positive, a table that is not 1 to `MAX_DRIVE_TABLE`
        whole entries within [-127, 127], a scale negative or not finite, a seed out of range.
    """
    if not isinstance(request, DriveTrialRequest):
        raise MalformedRequest(f"a drive request must be a DriveTrialRequest, got {_what(request)}")
    if not isinstance(request.table_values, np.ndarray) or request.table_values.ndim != 1 \
            or not 1 <= request.table_values.size <= MAX_DRIVE_TABLE:
        raise MalformedRequest(f"table_values must be an array of 1 to {MAX_DRIVE_TABLE} entries")
    table = _owned_table(request.table_values, "table_values", request.table_values.shape)
    if not np.all((table == np.rint(table)) & (np.abs(table) <= 127)):
        raise MalformedRequest("table_values must be whole numbers within [-127, 127] (int8)")
    owned = DriveTrialRequest(
        speed_hz=_owned_float(request.speed_hz, "speed"), settle_s=_owned_float(request.settle_s, "settle_s"),
        seconds=_owned_float(request.seconds, "seconds"), table_values=immutable(table.astype(np.int64)),
        table_scale_a=_owned_float(request.table_scale_a, "table_scale_a"), seed=_owned_int(request.seed, "seed"))
    if not (math.isfinite(owned.speed_hz) and owned.speed_hz != 0):
        raise MalformedRequest(f"speed must be finite and not 0, got {owned.speed_hz} Hz")
    if not 0 <= owned.settle_s <= MAX_DRIVE_SETTLE_S:
        raise MalformedRequest(f"settle_s must be 0 to {MAX_DRIVE_SETTLE_S:g} s, got {owned.settle_s}")
    if not 0 < owned.seconds < math.inf:
        raise MalformedRequest(f"seconds must be positive and finite, got {owned.seconds}")
    if not 0 <= owned.table_scale_a < math.inf:
        raise MalformedRequest(f"table_scale_a must be finite and not negative, got {owned.table_scale_a}")
    if not 0 <= owned.seed < 2**32:
        raise MalformedRequest(f"seed must be a 32-bit unsigned integer, got {owned.seed}")
    return owned


def drive_violation(owned: DriveTrialRequest, description: BenchDescription, limits: SafetyLimits) -> str | None:
    """Why ``owned``, a drive request as `owned_drive_request` copied it, breaks a limit, or None: its speed
    (max_speed_hz), its running time (max_trial_duration_s), its table's peak current (max_current_a) and that
    current's torque at most, whatever the commutation, the back-EMF table's largest sum over the phases of
    |K_p| per ampere (max_correction_nm)."""
    speed = abs(owned.speed_hz)
    if speed > limits.max_speed_hz * (1.0 + ROUNDING):
        return f"speed {owned.speed_hz:g} Hz exceeds {limits.text('max_speed_hz', 'Hz')} in magnitude"
    if owned.duration_s > limits.max_trial_duration_s * (1.0 + ROUNDING):
        return (f"the trial runs {owned.duration_s:.4g} s ({owned.settle_s:g} s settling, {owned.seconds:g} s "
                f"recorded), beyond {limits.text('max_trial_duration_s', 's')}")
    peak_a = float(np.max(np.abs(owned.table_current_a())))
    if peak_a > limits.max_current_a * (1.0 + ROUNDING):
        return f"the table asks {peak_a:.4g} A of q current, beyond {limits.text('max_current_a', 'A')}"
    peak_nm = peak_a * float(np.max(np.sum(np.abs(description.backemf_nm_per_a), axis=1)))
    if peak_nm > limits.max_correction_nm * (1.0 + ROUNDING):
        return (f"the table's {peak_a:.4g} A make up to {peak_nm:.4g} N m, beyond "
                f"{limits.text('max_correction_nm', 'N m')}")
    return None


@dataclass(frozen=True)
class Violation:
    """Why a request must not reach a backend.

    Attributes
    ----------
    malformed : bool
        True: no valid request at all (shape, type, NaN); False: a valid one beyond a limit.
    message : str
    """

    malformed: bool
    message: str


def limit_violation(owned: TrialRequest, description: BenchDescription, limits: SafetyLimits,
                    truth: SensorCalibration | None = None) -> str | None:
    """Why ``owned``, a request as `owned_request` copied it, breaks a limit of the bench ``description``, or None.

    Speed, samples and duration (`extent_violation`), the calibration trust region (`calibration_violation`), the
    torque reference, the current references and, with the identified true sensors ``truth``, the flowing currents
    (`torque_violation`).
    """
    flowing = None if truth is None else FlowingCurrent.at(owned.calibration, truth)
    return (extent_violation(owned, description.motor.counts_per_rev, limits)
            or calibration_violation(owned.calibration, description.calibration, truth, limits)
            or torque_violation(owned.torque_reference_nm(), description.backemf_nm_per_a, limits, flowing))


def request_violation(request: object, description: BenchDescription, limits: SafetyLimits,
                      truth: SensorCalibration | None = None) -> Violation | None:
    """Why ``request`` must not reach the bench ``description``, or None: its form (`owned_request`), then its
    limits (`limit_violation`) on the owned copy. What sends a request checks and sends that copy (`LimitGuard`)."""
    try:
        owned = owned_request(request, description.motor.counts_per_rev)
    except MalformedRequest as e:
        return Violation(True, str(e))
    why = limit_violation(owned, description, limits, truth)
    return None if why is None else Violation(False, why)


def check_plan(plan: Iterable[tuple[str, TrialRequest]], description: BenchDescription,
               limits: SafetyLimits) -> None:
    """Check planned requests before any runs: one `ConfigError` for the first beyond the limits.

    ``plan`` pairs each request with what in the config asks for it (the file and keys).
    """
    for place, request in plan:
        violation = request_violation(request, description, limits)
        if violation is not None:
            raise ConfigError(f"{place}: {violation.message}")
