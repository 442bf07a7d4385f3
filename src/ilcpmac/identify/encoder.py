"""The identification's torque from the encoder's time stamps: benches without a torque sensor (issue 12).

Each trial's torque table is the encoder-derived torque of
`ilcpmac.signals.encoder_torque` (eq. 1 there: tau_h = j h (J / 2) (omega^2)_h
+ b omega_h), harmonics 1..H of the joint fit's band, in true torque units: no
sensor gain delta, high-pass, delay, DC level or drift. Its weights are the
larger of the revolution-to-revolution scatter and the timer's quantisation
floor, per harmonic (`EncoderTorqueSpectrum.weight_variance_nm2`). J is
bench.toml's [motor] inertia: given, not estimated (eps and J enter only as
eps / J, since tau scales with J).

The brake
---------
The brake absorbs the mean torque: over a revolution, eq. 3.1 in the
position domain, J omega domega/dtheta = tau - b omega - C, averages to b_k
omega_0,k + C = tau_0,k in trial k, omega_0 the speed's mean over the angle
and C the Coulomb friction. The speed ripple shows tau_h - b omega_h at h >= 1
only; b matters (at the cogging order it is of the order of h J Omega). So
the joint fit (`ilcpmac.identify.joint`, its encoder source) takes the brake's
torque out of the data and puts it into its model: each linear column's mean,
times the trial's relative speed ripple omega_h / omega_0, joins the column,
so that b_k = tau_0,k / omega_0,k follows from the fitted gains, offsets and
saturation (`MeanTorqueModel`) with no iteration. C is not seen by the
encoder (only b omega_0 + C is): it is taken as 0, and a friction C makes
every b_k too large by C / omega_0,k. The tables themselves (for ch. 2 and 4
and the weights) hold the brake of the model of the fit before.

The encoder's graduation error
------------------------------
Line c truly at (c + e_c) Delta adds m_h,k e_h to trial k's torque (eq. 4
there). After a joint fit, what the model's trial-dependent columns leave,
r_k,h = tau_k,h - model_k,h (`fitted_columns_nm`; the stamps' whole band above
the fit), is the shared position table T_h plus m_h,k e_h plus noise:
`separate_encoder_error` over trials at two or more speeds gives e_h at every
harmonic 1..N/2 - 1. Of that estimate only the octaves of harmonics that
stand out of their noise (the misfit of the separation included) are kept,
shrunk by their Wiener factor (`significant_encoder_error`: a perfect encoder
gets 0, not its estimate's noise, which applied to every trial's stamps would
leave m_h times it in the torque); the stamps are corrected for that
(`at_nominal_angles`), the fit repeated and the estimate refined once more
(`ENCODER_PASSES`), each pass judging the sum of what was applied and its
increment. Where
inertia dominates (h J Omega >> b) m_h grows as Omega^2 while the torque's
speed ripple falls, and the two separate well; where the brake dominates,
m_h ~ -j h Delta tau_0 grows with the mean torque instead, like a torque
ripple proportional to the load, and the separation is only as good as the
model of such ripple (docs/identification.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from ilcpmac.bench.format import Bench
from ilcpmac.core.errors import IdentificationError
from ilcpmac.core.records import TrialData
from ilcpmac.core.torque_source import TorqueSource
from ilcpmac.identify.joint import JointEstimate, fitted_columns_nm
from ilcpmac.identify.reduction import BenchTables, TrialTables, reduce_bench, revolution_averages
from ilcpmac.model.encoder import line_errors_problem
from ilcpmac.signals.encoder_torque import (
    FALSE_ALARM,
    EncoderSeparation,
    EncoderTorqueSpectrum,
    at_nominal_angles,
    brake_viscous_nm_s,
    encoder_error_blocks,
    encoder_error_table,
    revolution_torques_nm,
    separate_encoder_error,
    significant_encoder_error,
    with_viscous,
)
from ilcpmac.signals.harmonics import table_from_amplitudes

__all__ = ["EncoderIdentification", "MeanTorqueModel", "identify_on_encoder", "timer_resolution_s"]

#: estimates of the encoder error (each on stamps corrected for the ones before)
ENCODER_PASSES = 2
#: finest timer resolution read off the stamps: the trial files' 0.1 us
MIN_TIMER_RESOLUTION_S = 1e-7


def timer_resolution_s(bench: Bench) -> float:
    """bench.toml's [motor] timer_resolution_s, else the finest step of the stamps, s: the quantum q of eq. 3 of
    `ilcpmac.signals.encoder_torque`.

    Stamps quantised to q make every count's duration, and every change of duration from one count to
    the next, a multiple of q; the smallest non-zero change over the trials is q (or a multiple, when
    the speed never changes by less), and at least the trial files' 0.1 us. A record of count means over b
    lines (`MotorInfo.lines_per_count`) averages b stamps per count, whose steps tell nothing of q: it states
    q, and eq. 3 takes q / sqrt(b), the quantum independent stamps at the counts would need for the noise of
    every line's.
    """
    motor = bench.motor
    if motor.timer_resolution_s is not None:
        return motor.timer_resolution_s / math.sqrt(motor.lines_per_count)
    steps = [np.abs(np.diff(np.diff(t.time_s))) for t in bench.trials if t.time_s.size > 2]
    changes = np.concatenate(steps) if steps else np.zeros(0)
    changes = changes[changes > 0.5 * MIN_TIMER_RESOLUTION_S]
    return float(max(changes.min(initial=np.inf), MIN_TIMER_RESOLUTION_S)) if changes.size else MIN_TIMER_RESOLUTION_S


@dataclass(frozen=True)
class MeanTorqueModel:
    """The identified model's mean torque: theta_p (true torque per reference ampere over K_p), beta_p (A),
    s (per A^2), as `JointEstimate` holds them on the encoder-derived torque."""

    theta: np.ndarray
    beta_a: np.ndarray
    saturation_per_a2: float

    @classmethod
    def nominal(cls) -> MeanTorqueModel:
        """Ideal sensors: the mean torque is the set point's."""
        return cls(np.ones(3), np.zeros(3), 0.0)

    @classmethod
    def of(cls, joint: JointEstimate) -> MeanTorqueModel:
        return cls(joint.theta, joint.beta_star_a, joint.saturation_per_a2)

    def mean_torque_nm(self, backemf_nm_per_a: np.ndarray, i_ref_table_a: np.ndarray) -> float:
        """tau_0 = mean_c sum_p K_p (i_p - s i_p^3), i_p = theta_p I*_p + beta_p, N m."""
        current = self.theta * i_ref_table_a + self.beta_a
        return float(np.mean(np.sum(backemf_nm_per_a * (current - self.saturation_per_a2 * current**3), axis=1)))


@dataclass(frozen=True)
class EncoderIdentification:
    """The encoder path's tables and joint fit, and the encoder error found.

    Attributes
    ----------
    tables : BenchTables
        The final tables (stamps corrected for ``line_errors_counts``, the brakes of the fit before).
    joint : JointEstimate or None
        The joint fit on them (None: it failed, the reason in ``messages``).
    viscous_nm_s : ndarray, shape (n_trials,)
        b_k each trial of ``tables`` holds, N m s / rad.
    timer_resolution_s : float
    line_errors_counts : ndarray, shape (counts_per_rev,), or None
        e_c taken out of the stamps (None: not identified; zeros: identified, nothing stands out of the noise).
    encoder_error_counts, encoder_error_variance_counts2 : ndarray, shape (counts_per_rev // 2,), or None
        Its harmonics e_h, h = 0..N/2 - 1 (`significant_encoder_error` of the estimate), and the estimate's
        variances E|d e_h|^2, misfit included (the last pass's).
    estimated_error_counts : ndarray, shape (counts_per_rev // 2,), or None
        The estimate before the significance rule: applied plus the last pass's increment.
    messages : tuple of str
    """

    tables: BenchTables
    joint: JointEstimate | None
    viscous_nm_s: np.ndarray
    timer_resolution_s: float
    line_errors_counts: np.ndarray | None
    encoder_error_counts: np.ndarray | None
    encoder_error_variance_counts2: np.ndarray | None
    estimated_error_counts: np.ndarray | None
    messages: tuple


def _spectrum(trial: TrialData, motor, timer_s: float, backemf: np.ndarray, model: MeanTorqueModel,
              line_errors_counts: np.ndarray | None) -> EncoderTorqueSpectrum:
    """The encoder-derived torque of ``trial`` over its whole band, harmonics 0..N/2 - 1, with its brake
    b = tau_0 / omega_0 (C taken as 0): omega_0 the speed's mean over the angle, as the mean of eq. 3.1 over
    a revolution in the position domain, mean(tau - b omega) = J mean(omega domega/dtheta) = 0, asks."""
    cpr = motor.counts_per_rev
    try:
        spectrum = EncoderTorqueSpectrum.of(trial.count, trial.time_s, cpr, cpr // 2 - 1, motor.inertia_kgm2,
                                            timer_s, 0.0, line_errors_counts)
    except ValueError as e:
        raise IdentificationError(f"encoder-derived torque: {e}") from None
    _, i_ref_table, _ = revolution_averages(trial.count, trial.time_s, trial.i_ref_a, cpr)
    return with_viscous(spectrum, brake_viscous_nm_s(model.mean_torque_nm(backemf, i_ref_table),
                                                     spectrum.speed_harmonics_rad_s[0].real))


def encoder_trial_tables(trial: TrialData, motor, backemf: np.ndarray, timer_s: float, band: int,
                         model: MeanTorqueModel, line_errors_counts: np.ndarray | None) -> TrialTables:
    """One trial reduced on its encoder-derived torque, harmonics 1..``band``, its brake from ``model``."""
    cpr = motor.counts_per_rev
    spectrum = _spectrum(trial, motor, timer_s, backemf, model, line_errors_counts)
    time_s = trial.time_s if line_errors_counts is None else at_nominal_angles(trial.count, trial.time_s, cpr,
                                                                               line_errors_counts)
    first, inertial, speed = revolution_torques_nm(trial.count, time_s, cpr, band, motor.inertia_kgm2)
    rows = inertial + spectrum.viscous_nm_s * speed
    revolution = trial.count // cpr - first
    mask = (revolution >= 0) & (revolution < rows.shape[0])
    count = trial.count[mask]
    speed_hz, i_ref_table, count_period = revolution_averages(count, time_s[mask], trial.i_ref_a[mask], cpr)
    harmonics = spectrum.harmonics_nm[: band + 1].copy()
    harmonics[0] = 0.0
    variances = spectrum.weight_variance_nm2[: band + 1] / 2.0
    scatter = rows - rows.mean(axis=0)
    return TrialTables(
        torque_setpoint_nm=trial.torque_setpoint_nm, speed_setpoint_hz=trial.speed_setpoint_hz, speed_hz=speed_hz,
        revolutions=rows.shape[0], count=count, time_s=time_s[mask], torque_nm=rows[revolution[mask], count % cpr],
        torque_table_nm=table_from_amplitudes(harmonics, cpr), i_ref_table_a=i_ref_table,
        count_period_s=count_period,
        noise_variance_nm2=float(np.sum(scatter**2) / (scatter.size - cpr)),
        harmonic_variance_nm2=float(variances[1:].mean()), harmonic_variances_nm2=variances,
        speed_table_rad_s=table_from_amplitudes(spectrum.speed_harmonics_rad_s[: band + 1], cpr),
        viscous_nm_s=spectrum.viscous_nm_s)


def encoder_tables(bench: Bench, timer_s: float, band: int, model: MeanTorqueModel,
                   line_errors_counts: np.ndarray | None) -> BenchTables:
    """Every usable trial of ``bench`` reduced on its encoder-derived torque (`reduce_bench`)."""
    backemf = np.asarray(bench.backemf_nm_per_a, float)
    return reduce_bench(bench, lambda trial, _: encoder_trial_tables(trial, bench.motor, backemf, timer_s, band,
                                                                     model, line_errors_counts),
                        TorqueSource.ENCODER)


def identify_on_encoder(bench: Bench, fit: Callable[[BenchTables], JointEstimate | None]) -> EncoderIdentification:
    """The joint fit ``fit`` on the encoder-derived torque, with the brakes and the encoder error out.

    ``fit(tables)`` returns the joint estimate, or None when it fails (having said why). The first fit
    runs on the whole band with the brakes of ideal sensors (its weights and the tables of ch. 2-4 are
    then off, never its brake: `ilcpmac.identify.joint` models it); the next ones on the fit's band with
    the fitted brakes, the encoder error taken out of the stamps.

    Raises
    ------
    IdentificationError
        When no trial can be used.
    """
    cpr = bench.motor.counts_per_rev
    timer_s = timer_resolution_s(bench)
    messages: list[str] = []
    speeds = [t.mean_speed_hz(cpr) for t in bench.trials]
    separable = max(speeds) - min(speeds) >= 0.05 * max(speeds)
    if not separable:
        set_points = ", ".join(f"{f:g}" for f in sorted({t.speed_setpoint_hz for t in bench.trials}))
        messages.append(f"encoder error: not identified - every trial runs at {set_points} Hz; trials at two or "
                        "more speeds tell it from the torque ripple (it stays in the encoder-derived torque and "
                        "biases every estimate by its apparent torque, which grows as (h speed)^2)")
    model, line_errors, applied, estimate, separation = MeanTorqueModel.nominal(), None, None, None, None
    tables = encoder_tables(bench, timer_s, cpr // 2 - 1, model, None)
    joint = fit(tables)
    for _ in range(ENCODER_PASSES if separable else 1):
        if joint is None:
            break
        model = MeanTorqueModel.of(joint)
        if separable:
            try:
                separation = _separation(bench, tables, joint, timer_s, model, line_errors)
                estimate = separation.encoder_error_counts + (0.0 if applied is None else applied)
                applied = significant_encoder_error(estimate, separation.encoder_error_variance_counts2)
                table = encoder_error_table(applied, cpr)
                problem = line_errors_problem(table, cpr)
                if problem:
                    raise ValueError(f"the estimate is no encoder's: {problem}")
                line_errors = table if np.any(applied) else None
            except ValueError as e:
                messages.append(f"encoder error: not identified - {e}")
                applied = estimate = separation = line_errors = None
                separable = False
        tables = encoder_tables(bench, timer_s, int(joint.sets.fit.max()), model, line_errors)
        joint = fit(tables)
    if applied is not None:
        messages += _left_out(applied)
    viscous = np.array([t.viscous_nm_s for t in tables.trials])
    return EncoderIdentification(
        tables, joint, viscous, timer_s, None if applied is None else encoder_error_table(applied, cpr), applied,
        None if separation is None else separation.encoder_error_variance_counts2, estimate, tuple(messages))


def _left_out(applied: np.ndarray) -> list[str]:
    """The message naming the octaves of the encoder error that did not stand out of their noise."""
    blocks = [b for b in encoder_error_blocks(applied.size) if not np.any(applied[b])]
    if not blocks:
        return []
    test = f"median |e_h|^2 / var below its {100 * (1 - FALSE_ALARM):g} % quantile"
    if not np.any(applied):
        return [f"encoder error: 0 - no harmonic stands out of the estimate's noise and misfit ({test} in every "
                "octave): a perfect encoder as far as these trials tell"]
    names = ", ".join(f"{b[0]}" if b.size == 1 else f"{b[0]}-{b[-1]}" for b in blocks)
    return [f"encoder error: harmonics {names} taken as 0 - they do not stand out of the estimate's noise and "
            f"misfit ({test} per octave); applied, their noise would leave m_h times it in every trial's torque"]


def _separation(bench: Bench, tables: BenchTables, joint: JointEstimate, timer_s: float, model: MeanTorqueModel,
                line_errors: np.ndarray | None) -> EncoderSeparation:
    """The encoder error (its increment on stamps already corrected for ``line_errors``) from what the joint
    model's trial-dependent columns (the brake's included) leave of each trial's whole-band torque."""
    columns = fitted_columns_nm(tables, joint)
    fit = joint.sets.fit
    spectra = []
    for k, name in enumerate(tables.trial_files):
        spectrum = _spectrum(bench.trials[bench.trial_files.index(name)], bench.motor, timer_s,
                             tables.backemf_nm_per_a, model, line_errors)
        residual = spectrum.harmonics_nm.copy()
        residual[fit] -= spectrum.viscous_nm_s * spectrum.speed_harmonics_rad_s[fit] + columns[k]
        spectra.append(replace(spectrum, harmonics_nm=residual))
    return separate_encoder_error(spectra)
