"""Identification of the torque ripple's sources from a bench folder (report chapters 1-4, and beyond).

`identify_bench` runs, on a `ilcpmac.bench.format.Bench`:

1. the reduction of each trial to one revolution (`reduction`);
2. the report's total system gain delta*eps from the harmonic frequency
   response (`system_gain`, ch. 2);
3. the joint least-squares fit over all set points with the identified
   current loop (`joint`, beyond the report);
4. the torque-sensor gain delta from the mechanical dynamics (`sensor_gain`, ch. 3);
5. the report's decoupling by the pseudo-inverse (`decoupling`, sec. 1.4, ch. 4);

and returns an `IdentificationResult` holding both methods' estimates and,
in its main fields, the better one of each; a bench of reverse laps
([motor] mirrored = true) in the motor's own coordinates (`mirror`).

Without a torque sensor, trials at one operating point (one speed and one
torque set point: a rolling drive log), which neither the joint fit nor the
encoder error can use, are identified by the acceleration method instead
(`acceleration`): the position-locked torque from J domega/dt - K.i, the
inertia given. So are rolling logs ([motor] log_rate_hz: an import) at
several speeds (`several_speeds`) and one torque set point (the joint fit
needs several), and other trials at several speeds where the encoder path
fails: the inertia (and b) then identified.

Otherwise without a torque sensor (or asked to), the torque is the encoder-derived one
(`ilcpmac.identify.encoder`): the trials are reduced on it with the encoder's
graduation error taken out (the part of its estimate that stands out of the
estimate's noise), over three joint fits that model the brake
(step 1); ch. 3 is skipped, and what only a torque sensor shows (its gain
delta, delta*eps, J* = delta J, its high-pass and delay) is None with the
reason in ``messages``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Protocol

import numpy as np

from ilcpmac.bench.format import Bench, StaticTrial
from ilcpmac.bench.standstill import MAX_RELATIVE_STD, unresolved_cogging
from ilcpmac.core.current_loop import CurrentLoop
from ilcpmac.core.errors import IdentificationError
from ilcpmac.core.records import IdentificationResult, MethodEstimates, SensorCalibration
from ilcpmac.core.torque_source import TorqueSource
from ilcpmac.identify.acceleration import estimate_by_acceleration, one_operating_point, one_setpoint, several_speeds
from ilcpmac.identify.decoupling import DecouplingEstimate, decouple
from ilcpmac.identify.encoder import EncoderIdentification, identify_on_encoder
from ilcpmac.identify.joint import JointEstimate, fit_joint
from ilcpmac.identify.mirror import in_motor_coordinates
from ilcpmac.identify.reduction import NUMERICAL_FAILURES, BenchTables, degenerate, reduce_bench
from ilcpmac.identify.sensor_gain import SensorGainEstimate, estimate_sensor_gain
from ilcpmac.identify.static import static_epsilon
from ilcpmac.identify.system_gain import SystemGainEstimate, TorqueNotFollowing, estimate_system_gain
from ilcpmac.signals.encoder_torque import encoder_error_summary

__all__ = ["SIGNIFICANT_EMF", "TOO_UNCERTAIN", "IdentificationDetails", "IdentificationResult", "Identifier",
           "MethodEstimates", "corrected_calibration", "encoder_error_fields", "identify_bench"]

#: the steps reported to ``progress``
STEPS = ("reducing trials", "total system gain (ch. 2)", "joint fit", "torque-sensor gain (ch. 3)",
         "decoupling (ch. 4)")
#: the loop the joint fit starts from when ch. 2 gives none: a 200 Hz lag
DEFAULT_LOOP = CurrentLoop(np.full(3, 1.0 / (2.0 * np.pi * 200.0)), 0.0)
#: what the encoder-derived torque cannot show, and why
NOT_IDENTIFIED_WITHOUT_SENSOR = (
    "torque-sensor gain (ch. 3): not identified - the torque comes from the encoder (no sensor reading): delta, "
    "delta*eps and J* = delta J need a torque sensor; eps is the gain to the true torque",
    "torque-sensor high-pass and delay: not identified - no sensor reading (the encoder-derived torque passes "
    "neither)",
    "Coulomb friction: not identified - the encoder sees b Omega + C only (the mean torque): taken as 0 in each "
    "trial's brake b = mean torque / Omega",
)
#: standard errors the joint fit's back-EMF coefficient c_e must stand from 0 for the winding's conductance 1 / R
#: to be taken (the speed's feedback, `ilcpmac.core.current_loop.speed_feedback`, rests on it)
SIGNIFICANT_EMF = 3.0
#: the diagnostics' key of the one line naming the estimates too uncertain to take (`_certain`), when any is
TOO_UNCERTAIN = "too_uncertain"
#: the estimates judged by `MAX_RELATIVE_STD` (of a gain's value, of an offset's reference currents' RMS): every one
#: with a standard error; the gains and offsets correct the calibration, delta*eps scales the learning
JUDGED = ("delta_epsilon", "delta", "epsilon", "alpha", "beta", "inertia_estimate")
#: what the acceleration method does not give beyond what needs a sensor
ACCELERATION_NOT_IDENTIFIED = ("current sensors (eps, alpha, beta), current loop, encoder error: not identified - "
                               "the acceleration method at one speed gives the position-locked torque and the friction")


@dataclass(frozen=True)
class IdentificationDetails:
    """The intermediate estimates behind a result (any but ``tables`` may be None), for plots and diagnostics."""

    tables: BenchTables
    system: SystemGainEstimate | None
    joint: JointEstimate | None
    sensor: SensorGainEstimate | None
    decoupling: DecouplingEstimate | None
    encoder: EncoderIdentification | None = None


def _attempt(messages: list, step: str, compute: Callable):
    """``compute()``, or None with the reason in ``messages``: its IdentificationError, or ``step``'s
    numerical failure on degenerate data (`NUMERICAL_FAILURES`)."""
    try:
        return compute()
    except IdentificationError as e:
        messages.append(str(e))
    except NUMERICAL_FAILURES as e:
        messages.append(f"{step}: {degenerate(e)}")
    return None


#: a (value, standard error) pair of a scalar, of a vector
_Pair = tuple[float | None, float | None]
_ArrayPair = tuple[np.ndarray | None, np.ndarray | None]


def _ratio(numerator: _Pair, denominator: _Pair) -> _Pair:
    """A ratio and its standard error (relative errors added in quadrature)."""
    (value_n, std_n), (value_d, std_d) = numerator, denominator
    if value_n is None or std_n is None or value_d is None or std_d is None:
        return None, None
    value = value_n / value_d
    return value, abs(value) * float(np.hypot(std_n / value_n, std_d / value_d))


@dataclass(frozen=True)
class _Measured:
    """One method's (value, std) pairs of delta*eps, delta, alpha, delta beta and J*, and its cogging, in the
    measured torque's units (eq. 1.11); (None, None) where the method gave none."""

    gain: _Pair
    sensor_gain: _Pair
    alpha: _ArrayPair
    beta_star: _ArrayPair
    inertia: _Pair
    cogging_measured: np.ndarray | None

    def over(self, sensor_gain: _Pair) -> tuple[_Pair, _ArrayPair, np.ndarray | None]:
        """eps, beta and the cogging in true units over the torque-sensor gain ``sensor_gain``: delta*eps, delta
        beta and the measured cogging divided by that delta."""
        delta, delta_std = sensor_gain
        beta_star_value, beta_star_std = self.beta_star
        beta = beta_std = cogging = None
        if delta is not None and delta_std is not None and beta_star_value is not None and beta_star_std is not None:
            beta = beta_star_value / delta
            beta_std = np.hypot(beta_star_std / delta, beta * delta_std / delta)
        if delta is not None and self.cogging_measured is not None:
            cogging = self.cogging_measured / delta
        return _ratio(self.gain, sensor_gain), (beta, beta_std), cogging

    def estimates(self) -> MethodEstimates:
        """The method's estimates, each over its own delta (`over`)."""
        epsilon, beta, cogging = self.over(self.sensor_gain)
        return MethodEstimates(*self.gain, *self.sensor_gain, *epsilon, *self.alpha, *beta, *self.inertia, cogging)


#: a (value, standard error) pair a method did not give
MISSING = (None, None)


def _report_method(system: SystemGainEstimate | None, sensor: SensorGainEstimate | _UnitSensor | None,
                   decoupling: DecouplingEstimate | None) -> _Measured:
    """The report's estimates: ch. 2 gain, ch. 3 mean J*, ch. 4 decoupling averaged over set points."""
    return _Measured(
        (system.delta_epsilon, system.delta_epsilon_std) if system else MISSING,
        (sensor.delta, sensor.delta_std) if sensor else MISSING,
        (decoupling.alpha(), decoupling.alpha_std()) if decoupling else MISSING,
        (decoupling.beta_star_mean(), decoupling.beta_star_std()) if decoupling else MISSING,
        (sensor.inertia, sensor.inertia_std) if sensor else MISSING,
        decoupling.mean_cogging_nm() if decoupling else None)


def _joint_method(joint: JointEstimate | None, sensor: SensorGainEstimate | _UnitSensor | None,
                  counts_per_rev: int) -> _Measured:
    """The joint fit's estimates, with the pooled, sensor-corrected J* of ch. 3."""
    corrected = sensor if sensor is not None and np.isfinite(sensor.corrected_delta) else None
    return _Measured(
        (joint.delta_epsilon, joint.delta_epsilon_std) if joint else MISSING,
        (corrected.corrected_delta, corrected.corrected_delta_std) if corrected is not None else MISSING,
        (joint.alpha, joint.alpha_std) if joint else MISSING,
        (joint.beta_star_a, joint.beta_star_std) if joint else MISSING,
        (corrected.corrected_inertia, corrected.corrected_inertia_std) if corrected is not None else MISSING,
        joint.cogging_table_nm(counts_per_rev) if joint else None)


class Identifier(Protocol):
    """What identifies a bench folder as `identify_bench` does (the campaign takes one, so that tests can inject
    an answer)."""

    def __call__(self, bench: Bench, *, torque_source: TorqueSource | None = None) -> IdentificationResult:
        """The identification of ``bench`` on ``torque_source`` (None: its default, `identify_bench`)."""
        ...


def identify_bench(bench: Bench, progress: Callable[[str, int, int], None] | None = None,
                   torque_source: TorqueSource | None = None) -> IdentificationResult:
    """Identify delta*eps, delta, eps, alpha, beta, J* and the cogging torque of a bench folder.

    Parameters
    ----------
    bench : Bench
        A bench folder in memory (`ilcpmac.bench.format.read_bench`).
    progress : callable, optional
        ``progress(step, index, total)`` before each step of STEPS.
    torque_source : TorqueSource, optional
        Where the torque comes from: SENSOR, the torque sensor's column, or ENCODER, the encoder's time stamps
        (also on a bench with a sensor, to compare), not BOTH; None: `TorqueSource.default` of the bench. ENCODER
        on a bench without a sensor at one operating point (`one_operating_point`), or of rolling logs at several
        speeds (`several_speeds`) and one set point, runs the acceleration method:
        ``details`` is then its `AccelerationEstimate`, and ``progress`` is not called.

    Raises
    ------
    IdentificationError
        When no trial can be used or nothing at all can be estimated, for BOTH, or for a source that reads
        a torque sensor on a bench without one, and when the torque follows the current references neither as
        ch. 2's gain and loop (`TorqueNotFollowing`) nor with a joint fit's gain to take. An estimate that is
        impossible on its own is reported in ``messages``.
    """
    def step(index: int) -> None:
        if progress is not None:
            progress(STEPS[index], index, len(STEPS))

    source = torque_source or TorqueSource.default(bench.motor.torque_sensor)
    if source.fuses:
        raise IdentificationError(f"torque source must be one of {TorqueSource.SENSOR.value}, "
                                  f"{TorqueSource.ENCODER.value}, got {source.value!r}")
    if source.reads_sensor and not bench.motor.torque_sensor:
        raise IdentificationError(f"torque source {source.value!r}: the bench has no torque sensor ([motor] "
                                  "torque_sensor = false); use the encoder")
    sensorless = source.reads_encoder and not bench.motor.torque_sensor and bool(bench.trials)
    rolling = bench.motor.log_rate_hz is not None and bool(bench.trials) and one_setpoint(bench)
    if sensorless and (one_operating_point(bench) or (several_speeds(bench) and rolling)):
        result = _by_acceleration(bench, source)
        return in_motor_coordinates(result) if bench.motor.mirrored else result
    return _identify(bench, source, step)


def _identify(bench: Bench, source: TorqueSource, step: Callable[[int], None]) -> IdentificationResult:
    """`identify_bench` by the report's, the joint and (on the encoder) the encoder path's steps."""
    step(0)
    encoder = None
    if source.reads_encoder:
        encoder = _encoder_tables(bench)
        tables = encoder.tables
        messages = [*tables.messages, *encoder.messages]
    else:
        tables = reduce_bench(bench)
        messages = list(tables.messages)
    step(1)
    not_following: list[TorqueNotFollowing] = []

    def system_gain() -> SystemGainEstimate:
        try:
            return estimate_system_gain(tables)
        except TorqueNotFollowing as e:
            not_following.append(e)
            raise

    system = _attempt(messages, STEPS[1], system_gain)
    step(2)
    if encoder is not None:
        joint = encoder.joint
    else:
        joint = _attempt(messages, STEPS[2],
                         lambda: fit_joint(tables, system.loop if system is not None else DEFAULT_LOOP))
    step(3)
    band = joint.sets.fit.max() if joint else (system.harmonics.max() if system else 2 * bench.motor.cogging_order)
    if encoder is not None:
        sensor = None
        messages += NOT_IDENTIFIED_WITHOUT_SENSOR
    else:
        sensor = _attempt(messages, STEPS[3], lambda: estimate_sensor_gain(
            tables, int(band), None if joint is None else joint.sensor_response))
    step(4)
    decoupling = None if system is None else _attempt(messages, STEPS[4],
                                                      lambda: decouple(tables, system.delta_epsilon))
    if system is None and joint is None and sensor is None:
        raise IdentificationError("nothing can be estimated: " + "; ".join(messages))
    messages += [w for estimate in (joint, system, sensor, decoupling) if estimate is not None
                 for w in estimate.warnings]

    measured = {"report": _report_method(system, sensor if encoder is None else _UNIT_SENSOR, decoupling),
                "joint": _joint_method(joint, sensor if encoder is None else _UNIT_SENSOR, bench.motor.counts_per_rev)}
    report, joint_estimates = (measured[m].estimates() if encoder is None else _without_sensor(measured[m].estimates())
                               for m in ("report", "joint"))
    unresolved = unresolved_cogging(bench.motor.cogging_order, bench.motor.counts_per_rev)
    if unresolved is not None:
        messages.append(unresolved)
        report, joint_estimates = (replace(m, cogging_nm=None) for m in (report, joint_estimates))
    report = _finite_estimates(report, "report method", messages)
    joint_estimates = _finite_estimates(joint_estimates, "joint method", messages)
    current_rms_a = float(np.sqrt(np.mean([np.mean(t.i_ref_table_a**2) for t in tables.trials])))
    (joint_taken, joint_left), (report_taken, report_left) = (_certain(m, current_rms_a)
                                                              for m in (joint_estimates, report))
    fitted = joint if joint is not None and "delta_epsilon" not in dict(joint_left) else None  # its gain taken
    if not_following and fitted is None:
        raise IdentificationError(f"{not_following[0]}; the joint fit's gain is "
                                  f"{'too uncertain to take' if joint is not None else 'none'}: nothing can be "
                                  "identified from this torque")
    best = {name: getattr(joint_taken, name) if getattr(joint_taken, name) is not None
            else getattr(report_taken, name) for name in MethodEstimates.__dataclass_fields__}
    methods = {"report": report, "joint": joint_estimates}
    pinned = None
    if bench.static is not None:
        pinned = _pinned_by_static(bench, bench.static, best, encoder is not None, fitted)
        best |= {key: value for key, value in vars(pinned).items() if value is not None}
        methods["static"] = pinned
    if encoder is None:
        best |= _over_taken_delta(best, *(measured["joint" if getattr(joint_taken, name) is not None else "report"]
                                          for name in ("beta", "cogging_nm")))
    if pinned is not None:
        best |= {"epsilon": pinned.epsilon, "epsilon_std": pinned.epsilon_std}
        messages.append(_static_message(bench, pinned, best["inertia_estimate"]))
    untaken = [f"{method} method's {text}" for method, left in (("joint", joint_left), ("report", report_left))
               for name, text in left if best[name] is None]
    too_uncertain = None
    if untaken:
        too_uncertain = (f"too uncertain to take (a standard error beyond {MAX_RELATIVE_STD:g} of the size): "
                         f"{'; '.join(untaken)} - the trials' torque noise hides the currents' part of the torque"
                         f"{'' if joint is not None else ' and the joint fit failed (see the warnings)'}: more "
                         "revolutions per trial, or more excitation, narrow it")
        messages.append(too_uncertain)
    calibration = None
    delta = 1.0 if encoder is not None else best["delta"]
    if bench.sensors is not None and delta is not None and all(best[k] is not None
                                                                 for k in ("epsilon", "alpha", "beta")):
        calibration = corrected_calibration(bench.sensors, best["epsilon"], best["alpha"], best["beta"], delta)
        if not all(np.all(np.isfinite(v)) for v in vars(calibration).values()):
            messages.append("calibration: not finite (a gain estimate is zero) - not reported")
            calibration = None
        elif encoder is not None:
            messages.append("calibration: torque_gain left as bench.toml's (no torque sensor reading)")
    loop = None
    if fitted is not None and not fitted.loop.is_ideal and np.all(np.isfinite(fitted.loop.bandwidth_hz)):
        loop = fitted.loop
    conductance = None if fitted is None or delta is None else _winding_conductance(fitted, delta)
    covariance = None if fitted is None or delta is None or conductance is None else \
        fitted.loop_winding_covariance(delta, best["delta_std"] or 0.0)
    saturation = None if fitted is None or delta is None else fitted.saturation_per_a2 * delta**2
    diagnostics = _diagnostics(tables, system, joint, sensor, conductance, saturation, covariance)
    if encoder is not None:
        diagnostics = _encoder_diagnostics(diagnostics, bench, encoder)
    if too_uncertain is not None:
        diagnostics[TOO_UNCERTAIN] = too_uncertain
    result = IdentificationResult(
        **best, current_loop=loop, methods=methods, calibration=calibration,
        messages=tuple(messages), diagnostics=diagnostics,
        details=IdentificationDetails(tables, system, joint, sensor, decoupling, encoder),
        torque_source=source, torque_sensor_highpass_hz=None if fitted is None else fitted.highpass_hz,
        torque_sensor_delay_s=None if fitted is None else fitted.torque_delay_s,
        winding_conductance_s=conductance, loop_winding_covariance=covariance,
        winding_time_constant_s=None if fitted is None else fitted.winding_time_constant_s,
        saturation_per_a2=saturation, **_encoder_error_fields(encoder))
    return in_motor_coordinates(result) if bench.motor.mirrored else result


def _winding_conductance(joint: JointEstimate, delta: float) -> float | None:
    """1 / R = -c_e / delta from the joint fit's back-EMF coefficient, S; None unless c_e < 0 stands
    `SIGNIFICANT_EMF` standard errors from 0."""
    if joint.loop.is_ideal or not -joint.emf_gain > SIGNIFICANT_EMF * joint.emf_gain_std:
        return None
    return -joint.emf_gain / delta


def _pinned_by_static(bench: Bench, static: StaticTrial, best: dict, on_encoder: bool,
                      fitted: JointEstimate | None) -> MethodEstimates:
    """The static trial's estimates (`ilcpmac.identify.static`): eps, and delta = delta eps / eps where the bench
    has a torque sensor; `IdentificationError` where there is no alpha to read it with, or on the encoder-derived
    torque (whose every torque, the cogging's and the offsets', the given inertia scales: not pinned yet)."""
    if on_encoder:
        raise IdentificationError(f"{bench.static_file}: a static trial pins eps on the torque sensor's data; on the "
                                  "encoder-derived torque the given inertia scales every torque, which it does not "
                                  "rescale yet: identify with the sensor, or without [static]")
    if best["alpha"] is None:
        raise IdentificationError(f"{bench.static_file}: the static trial needs alpha, which the identification "
                                  "could not estimate")
    # the saturation's c, true units, and its standard error: at the largest currents of a static trial it takes
    # about 1 % of the torque, and its error is one of eps there (0.04 % on the seed bench, noiseless)
    saturation = saturation_std = 0.0
    if fitted is not None and best["delta"] is not None:
        saturation, saturation_std = (value * best["delta"] ** 2
                                      for value in (fitted.saturation_per_a2, fitted.saturation_std))
    beta = np.zeros(3) if best["beta"] is None else np.asarray(best["beta"])
    alpha = np.asarray(best["alpha"])
    try:
        pinned = static_epsilon(static, bench.backemf_nm_per_a, alpha, beta, saturation)
    except IdentificationError as e:
        raise IdentificationError(f"{bench.static_file}: {e}") from None
    moved = static_epsilon(static, bench.backemf_nm_per_a, alpha, beta, saturation + saturation_std).epsilon
    epsilon_std = float(np.hypot(pinned.epsilon_std, moved - pinned.epsilon))
    if best["delta_epsilon"] is None:
        return MethodEstimates(epsilon=pinned.epsilon, epsilon_std=epsilon_std)
    delta = best["delta_epsilon"] / pinned.epsilon
    relative = np.hypot(best["delta_epsilon_std"] / best["delta_epsilon"], epsilon_std / pinned.epsilon)
    return MethodEstimates(epsilon=pinned.epsilon, epsilon_std=epsilon_std, delta=delta,
                           delta_std=float(abs(delta) * relative))


def _static_message(bench: Bench, pinned: MethodEstimates, inertia_estimate: float | None) -> str:
    """What the static trial gave: eps, and delta with the inertia the torque sensor's J* = delta J then implies."""
    eps = f"eps {pinned.epsilon:.5g} +- {pinned.epsilon_std:.2g} from the static trial ({bench.static_file})"
    if pinned.delta is None or inertia_estimate is None:
        return eps
    implied, given = inertia_estimate / pinned.delta, bench.motor.inertia_kgm2
    return (f"{eps}, delta {pinned.delta:.5g} from it: the torque sensor saw an inertia of {implied:.4g} kg m^2, "
            f"{implied / given - 1:+.1%} from [motor] inertia {given:g}, which eps rests on without the static trial")


def _over_taken_delta(best: dict, beta_from: _Measured, cogging_from: _Measured) -> dict:
    """eps, beta and the cogging of ``best`` over the delta it takes: its delta*eps, the delta beta of ``beta_from``
    and the measured cogging of ``cogging_from`` (the methods whose beta and cogging it takes), each over that delta.

    A method's own eps, beta and cogging are over its own delta, which ``best`` may not take: on a motor of issue 37
    the joint fit's delta 0.62 +- 0.36 (true 1.05) was left for ch. 3's 0.97 +- 0.11, and eps from the report's
    delta*eps (-18 %) with beta and the cogging over the joint's delta (1.7 times the truth) made the learning's
    gain 1.2 times the identified one and the compensation trial's offsets and cogging wrong by 0.7 of their size.
    Where ``best`` takes no eps, beta or cogging, none is made.
    """
    delta = (best["delta"], best["delta_std"])
    epsilon, beta, _ = replace(beta_from, gain=(best["delta_epsilon"], best["delta_epsilon_std"])).over(delta)
    cogging = cogging_from.over(delta)[2]
    out: dict = {}
    if best["epsilon"] is not None and epsilon[0] is not None:
        out["epsilon"], out["epsilon_std"] = epsilon
    if best["beta"] is not None and beta[0] is not None:
        out["beta"], out["beta_std"] = beta
    if best["cogging_nm"] is not None and cogging is not None:
        out["cogging_nm"] = cogging
    return out


def _by_acceleration(bench: Bench, source: TorqueSource) -> IdentificationResult:
    """The result of the acceleration method (`estimate_by_acceleration`): the cogging (its resolved band; None
    where none is) and the whole position-locked torque with its standard error, the rest None with the reasons."""
    estimate = estimate_by_acceleration(bench)
    cogging = estimate.table_nm(cogging_only=True) if np.any(estimate.resolved & estimate.cogging_band) else None
    position = estimate.table_nm() if estimate.resolved.any() else None
    return IdentificationResult(
        cogging_nm=cogging, methods={"acceleration": MethodEstimates(cogging_nm=cogging)},
        messages=(*estimate.messages, *NOT_IDENTIFIED_WITHOUT_SENSOR[:2],
                  ACCELERATION_NOT_IDENTIFIED.replace("at one speed", "at several speeds").replace(
                      "and the friction", "J and the friction") if estimate.inertia_identified
                  else ACCELERATION_NOT_IDENTIFIED),
        diagnostics={"trials_used": estimate.trials, "method": "acceleration", "acceleration": estimate.to_json()},
        details=estimate, torque_source=source, position_torque_nm=position,
        position_torque_std_nm=None if position is None else estimate.table_std_nm())


class _UnitSensor:
    """The encoder-derived torque's "sensor": gain 1 by construction, not an estimate (`_without_sensor`)."""

    delta = corrected_delta = 1.0
    delta_std = corrected_delta_std = 0.0
    inertia = inertia_std = corrected_inertia = corrected_inertia_std = None


_UNIT_SENSOR = _UnitSensor()


def _without_sensor(estimates: MethodEstimates) -> MethodEstimates:
    """A method's estimates on the encoder-derived torque: what needs a torque sensor made None."""
    return replace(estimates, delta_epsilon=None, delta_epsilon_std=None, delta=None, delta_std=None,
                   inertia_estimate=None, inertia_estimate_std=None)


def _encoder_tables(bench: Bench) -> EncoderIdentification:
    """`identify_on_encoder` with the joint fit from the default loop; the last fit's failure in its messages."""
    failures: list[str] = []

    def fit(tables: BenchTables) -> JointEstimate | None:
        failures.clear()
        return _attempt(failures, STEPS[2], lambda: fit_joint(tables, DEFAULT_LOOP))

    encoder = identify_on_encoder(bench, fit)
    return replace(encoder, messages=(*encoder.messages, *failures))


def _encoder_error_fields(encoder: EncoderIdentification | None) -> dict:
    """The `IdentificationResult` fields of the encoder error (none without one) (`encoder_error_fields`)."""
    if encoder is None:
        return {}
    applied, error, variance = (encoder.line_errors_counts, encoder.encoder_error_counts,
                                encoder.encoder_error_variance_counts2)
    if applied is None or error is None or variance is None:
        return {}
    return encoder_error_fields(applied, error, variance)


def encoder_error_fields(applied: np.ndarray, error: np.ndarray, variance: np.ndarray) -> dict:
    """The `IdentificationResult` fields of an encoder error: ``applied``, the line errors per count, counts;
    ``error`` and ``variance``, the harmonics applied (`significant_encoder_error`) and their estimate's
    variance; the phase None where the once-per-revolution part is 0 (no phase to tell)."""
    amplitude, amplitude_std, phase, line_rms = encoder_error_summary(error, variance)
    std = float(np.sqrt(np.sum(variance[1:]) / 2.0))
    return {"encoder_error_counts": applied,
            "encoder_error_std_counts": np.full(applied.size, std),
            "encoder_eccentricity_counts": amplitude, "encoder_eccentricity_std_counts": amplitude_std,
            "encoder_eccentricity_phase_rad": phase if amplitude > 0.0 else None, "encoder_line_rms_counts": line_rms}


def _encoder_diagnostics(diagnostics: dict, bench: Bench, encoder: EncoderIdentification) -> dict:
    """``diagnostics`` with the encoder path's details."""
    return {**diagnostics, "encoder": {
        "inertia_given": bench.motor.inertia_kgm2, "timer_resolution_s": encoder.timer_resolution_s,
        "harmonics": int(encoder.tables.trials[0].encoder_parts()[0].size - 1),
        "brake_per_trial": [{"torque_setpoint": t.torque_setpoint_nm, "speed_setpoint": t.speed_setpoint_hz,
                             "viscous_nm_s": float(b)} for t, b in zip(encoder.tables.trials, encoder.viscous_nm_s)]}}


def corrected_calibration(sensors: SensorCalibration, epsilon: float, alpha: np.ndarray, beta_a: np.ndarray,
                          delta: float) -> SensorCalibration:
    """The calibration that removes the identified errors (eqs. 1.4-1.7).

    (G*_s)^-1 G_s = eps alpha per phase, so the true scale G_s^-1 is
    current_scale / (eps alpha); beta = G_s (o_s - o*_s) gives the true offset
    o_s = o*_s + beta G_s^-1; and g_t = delta g*_t.
    """
    scale = sensors.current_scale / (epsilon * np.asarray(alpha))
    return SensorCalibration(scale, sensors.current_offset + np.asarray(beta_a) * scale, delta * sensors.torque_gain)


def _finite_estimates(estimates: MethodEstimates, method: str, messages: list) -> MethodEstimates:
    """``estimates`` with every value that is not finite made None (null in JSON), the reason in ``messages``."""
    bad = [name for name, value in vars(estimates).items()
           if value is not None and not np.all(np.isfinite(value))]
    if not bad:
        return estimates
    messages.append(f"{method}: {', '.join(bad)} not finite (degenerate data or a single set point) - "
                    "reported as null")
    return replace(estimates, **dict.fromkeys(bad))


def _certain(estimates: MethodEstimates, current_rms_a: float) -> tuple[MethodEstimates, list[tuple[str, str]]]:
    """``estimates`` without those of `JUDGED` whose standard error is beyond `MAX_RELATIVE_STD` of their size
    (a gain's value; beta's ``current_rms_a``, the reference currents' RMS), and (name, what it is) of each."""
    left: list[tuple[str, str]] = []
    out: dict[str, None] = {}
    for name in JUDGED:
        value, std = getattr(estimates, name), getattr(estimates, name + "_std")
        if value is None or std is None:
            continue
        size = np.full(np.shape(value), current_rms_a) if name == "beta" else np.abs(value)
        worst = int(np.argmax(np.atleast_1d(std / np.maximum(size, np.finfo(float).tiny))))
        value, std, size = (float(np.atleast_1d(v)[worst]) for v in (value, std, size))
        if std > MAX_RELATIVE_STD * size:
            out |= {name: None, name + "_std": None}
            left.append((name, f"{name} {value:.3g} ± {std:.2g} A against reference currents of {size:.2g} A RMS"
                         if name == "beta" else f"{name} {value:.3g} ± {std:.2g}"))
    return replace(estimates, **out), left


def _diagnostics(tables: BenchTables, system: SystemGainEstimate | None, joint: JointEstimate | None,
                 sensor: SensorGainEstimate | None, winding_conductance_s: float | None,
                 saturation_per_a2: float | None, loop_winding_covariance: np.ndarray | None = None) -> dict:
    """JSON-able details of each step (the winding's conductance the result takes, `_winding_conductance`, the
    covariance of the loop and the winding with it, `JointEstimate.loop_winding_covariance`, and its saturation in
    true units)."""
    out: dict = {"trials_used": len(tables.trials)}
    if system is not None:
        out["system_gain"] = {
            "residue": system.residue, "harmonics": [int(system.harmonics.min()), int(system.harmonics.max())],
            "harmonics_used": int(system.used.sum()),
            "median_coherence": float(np.median(system.coherence[system.used])),
            "loop_corrected_total_system_gain": system.loop_gain,
            "loop_corner_hz": float(system.loop.bandwidth_hz[0]),
            "structure_chi2": [float(c) for c in system.structure_chi2], "std_inflation": system.inflation}
    if joint is not None:
        out["joint"] = {
            "chi2_reduced": joint.chi2_reduced, "harmonics": [int(joint.sets.fit.min()), int(joint.sets.fit.max())],
            "current_loop_time_constant_s": joint.loop.time_constant_s.tolist(),
            "current_loop_time_constant_std_s": joint.loop_std[:3].tolist(),
            "current_loop_delay_s": joint.loop.delay_s,
            "torque_sensor_highpass_hz": joint.highpass_hz, "torque_sensor_highpass_std_hz": joint.highpass_std,
            "torque_sensor_delay_s": joint.torque_delay_s, "winding_time_constant_s": joint.winding_time_constant_s,
            "emf_gain": joint.emf_gain, "emf_gain_std": joint.emf_gain_std,
            "winding_conductance_s": winding_conductance_s,
            "loop_winding_covariance": None if loop_winding_covariance is None else loop_winding_covariance.tolist(),
            "saturation_per_a2_over_delta2": joint.saturation_per_a2, "saturation_per_a2": saturation_per_a2,
            "misfit": [{"family": g.label, "harmonics": [int(g.harmonics.min()), int(g.harmonics.max())],
                        "chi2_reduced": g.chi2_reduced, "dof": g.dof, "std_inflation": g.inflation}
                       for g in joint.misfit]}
    if sensor is not None:
        out["sensor_gain"] = {
            "inertia_per_set_point": [
                {"torque_setpoint": t.torque_setpoint_nm, "speed_setpoint": t.speed_setpoint_hz, "inertia": float(j),
                 "inertia_std": float(s)}
                for t, j, s in zip(tables.trials, sensor.inertia_per_trial, sensor.inertia_std_per_trial)],
            "std_inflation": sensor.inflation,
            "chi2_per_set_point": [float(m.chi2_reduced) for m in sensor.misfit_per_trial]}
        if sensor.corrected is not None:
            c = sensor.corrected
            out["sensor_gain"]["corrected"] = {
                "torque_to_speed_delay_s": c.delay_s, "brake_delay_s": c.brake_delay_s,
                "chi2_per_set_point": c.chi2_per_trial.tolist(),
                "structure_chi2": [float(x) for x in c.structure_chi2], "std_inflation": c.inflation}
    return out
