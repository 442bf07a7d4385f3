"""Torque-sensor gain delta from the mechanical dynamics (report ch. 3).

The rotor obeys tau*_m = delta (J d omega/dt + b omega) (eq. 3.1), so the
frequency response from angular velocity to measured torque is
J* s + b* with J* = delta J and b* = delta b (eqs. 3.2-3.4). The data are
sampled per encoder count, so they are first re-sampled at constant time
intervals through cubic splines (sec. 3.1), with a whole number of samples
per mean revolution; the response is then estimated for a periodic
excitation as scipy.signal's csd and welch would (boxcar windows of one
revolution, no overlap), with its coherence, and J* s + b* is fitted per set
point by weighted least squares (the report used frsfit): an unweighted
linear fit first, then weights 1 / var(H) from the coherence and the fitted
model, iterated. J* is averaged over the set points (fig. 3.3) and
delta = J* / J with J from bench.toml.

Beyond the report (`SensorGainEstimate.corrected_*`, `fit_pooled`): eq. 3.1
in the position domain, harmonic by harmonic and exact for a periodic motion
(`ilcpmac.signals.encoder_torque`, eq. 1),

    tau*_h exp(j w_h D) / H_hp(w_h) = J* j h (omega^2)_h / 2 + b*_k omega_h exp(-j w_h D_b),

with the speed from the encoder's time stamps (no splines), the sensor's
high-pass H_hp identified by the joint fit divided out, the torque's delay D
against the stamps and the brake's delay D_b behind the speed fitted, one J*
shared by all set points and a b*_k per set point, weighted by each
harmonic's revolution-to-revolution scatter. The brake's torque lags the
speed (an eddy-current brake by its electrical time constant; the
simulator's explicit brake by half a control period against the stamps'
speed): unmodelled, b*_k omega_h exp(-j w_h D_b) ~ b*_k omega_h - j w_h
b*_k D_b omega_h reads as J* - b*_k D_b. D_b and J* separate over set points
of different b*_k.

Uncertainty. Where the residual holds more than noise, the standard error
grows with it (docs/identification.md, "Uncertainty on mismatched data"):
each set point's share of the information by its chi-square per degree of
freedom (max(chi2_k, 1)), plus the variance of a structure J* shows across
blocks of harmonics (two halves, or blocks of ceil(sqrt(n))) and across set
points (`ilcpmac.identify.system_gain.structure_variance`), which no average
removes. The torque sampled once per encoder count while the current loop
settles after each step of its per-count reference, and a time offset
between torque and speed, make J* from the upper harmonics differ from J*
from the lower ones: such structure, not scatter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ilcpmac.core.errors import IdentificationError
from ilcpmac.identify.reduction import BenchTables
from ilcpmac.identify.system_gain import structure_variance
from ilcpmac.signals.encoder_torque import EncoderTorqueSpectrum
from ilcpmac.signals.harmonics import revolution_harmonics, uniform_time_resample

__all__ = ["InertiaMisfit", "MIN_COHERENCE", "PooledInertia", "PositionResponse", "SensorGainEstimate",
           "TrialResponse", "estimate_sensor_gain", "fit_inertia", "fit_pooled", "harmonic_structure",
           "inertia_misfit", "position_response", "trial_response"]

#: coherence a harmonic needs to enter the transfer-function fit
MIN_COHERENCE = 0.8
#: reweighting passes of the weighted least-squares fit; Gauss-Newton steps of the pooled fit's delay
PASSES = 3
#: smallest variance of a torque harmonic in the pooled fit, relative to the mean power (noise-free data)
NOISE_FLOOR = 1e-12


@dataclass(frozen=True)
class TrialResponse:
    """Torque over angular velocity of one trial at the harmonics of its mean revolution.

    Attributes
    ----------
    frequency_hz, response, coherence : ndarray, shape (H,)
        Harmonics 1..H of the mean revolution; H1 response tau*_m / omega, N m s / rad.
    revolutions : int
        Windows averaged.
    """

    frequency_hz: np.ndarray
    response: np.ndarray
    coherence: np.ndarray
    revolutions: int


@dataclass(frozen=True)
class PositionResponse:
    """One trial's torque and speed harmonics 1..H in the position domain (eq. 3.1 harmonic by harmonic).

    Attributes
    ----------
    torque_nm, torque_variance_nm2 : ndarray, shape (H,)
        tau*_h of the synchronous average (the sensor's response divided out), and E|d tau*_h|^2 from
        the revolution-to-revolution scatter, N m and N^2 m^2.
    inertial_rad2_s2 : ndarray of complex, shape (H,)
        j h (omega^2)_h / 2: the torque per kg m^2 of inertia, rad^2 / s^2.
    speed_rad_s : ndarray of complex, shape (H,)
        omega_h, rad/s.
    frequency_rad_s : ndarray, shape (H,)
        2 pi h f at the trial's mean speed f.
    """

    torque_nm: np.ndarray
    torque_variance_nm2: np.ndarray
    inertial_rad2_s2: np.ndarray
    speed_rad_s: np.ndarray
    frequency_rad_s: np.ndarray


@dataclass(frozen=True)
class InertiaMisfit:
    """How far a J* fit's residual is from its noise, and the standard error that follows.

    Attributes
    ----------
    chi2_reduced : float
        Weighted residual sum of squares per degree of freedom (about 1 for noise alone).
    structure_variance_kgm4 : float
        Variance of the structure J* shows across blocks of harmonics (`harmonic_structure`; 0 without).
    structure_chi2 : float
        Chi-square per degree of freedom of the block estimates about J*.
    """

    chi2_reduced: float
    structure_variance_kgm4: float
    structure_chi2: float

    def variance(self, noise_std: float) -> float:
        """The variance of J*: the noise's, scaled by max(chi2, 1), plus the structure's, kg^2 m^4."""
        return noise_std**2 * max(self.chi2_reduced, 1.0) + self.structure_variance_kgm4


@dataclass(frozen=True)
class PooledInertia:
    """One J* shared by all set points, a b*_k, the torque's delay D and the brake's D_b (`fit_pooled`).

    Attributes
    ----------
    inertia, inertia_std : float
        J* and its standard error (noise, misfit and structure), kg m^2.
    noise_std : float
        The standard error the noise alone gives, kg m^2.
    damping : ndarray, shape (n_trials,)
        b*_k, N m s / rad.
    delay_s : float
        D, the torque's delay against the encoder's stamps beyond the sensor response divided out, s.
    brake_delay_s : float
        D_b, the brake's torque b*_k omega's delay behind the stamps' speed, s.
    chi2_per_trial : ndarray, shape (n_trials,)
        Each set point's reduced chi-square.
    structure_chi2 : tuple of float
        Chi-square per degree of freedom of J* over blocks of harmonics and over set points.
    delay_structure_chi2 : float
        Chi-square per degree of freedom of D over blocks of harmonics (`fit_pooled`).
    delay_structure_s : float
        The standard deviation of D's structure over blocks of harmonics (0 without), s.
    """

    inertia: float
    inertia_std: float
    noise_std: float
    damping: np.ndarray
    delay_s: float
    brake_delay_s: float
    chi2_per_trial: np.ndarray
    structure_chi2: tuple
    delay_structure_chi2: float = 0.0
    delay_structure_s: float = 0.0

    @property
    def inflation(self) -> float:
        """inertia_std / noise_std."""
        return self.inertia_std / self.noise_std


@dataclass(frozen=True)
class SensorGainEstimate:
    """The report's torque-sensor gain (ch. 3) and the corrected pooled fit.

    Attributes
    ----------
    responses : tuple of TrialResponse
    inertia_per_trial, inertia_std_per_trial, damping_per_trial : ndarray
        J* (kg m^2) with its standard error (misfit and structure included), and b* (N m s / rad), per
        set point.
    misfit_per_trial : tuple of InertiaMisfit
    inertia, inertia_std : float
        J* for the bench: the mean over set points and the standard error of that mean.
    inflation : float
        How much the misfit widened inertia_std over the set points' scatter and noise (1 without).
    delta, delta_std : float
        J* / J.
    corrected : PooledInertia or None
        The position-domain pooled fit with the sensor's response divided out (None when not given).
    corrected_inertia, corrected_inertia_std, corrected_delta, corrected_delta_std : float
        Its J* and delta (NaN when not given).
    corrected_failure : str or None
        Why the corrected fit is missing though asked (e.g. trials of one whole revolution), or None.
    """

    responses: tuple
    inertia_per_trial: np.ndarray
    inertia_std_per_trial: np.ndarray
    damping_per_trial: np.ndarray
    misfit_per_trial: tuple
    inertia: float
    inertia_std: float
    inflation: float
    delta: float
    delta_std: float
    corrected: PooledInertia | None
    corrected_inertia: float
    corrected_inertia_std: float
    corrected_delta: float
    corrected_delta_std: float
    corrected_failure: str | None = None

    @property
    def warnings(self) -> tuple[str, ...]:
        """One line per fit whose J* varies over harmonics or set points beyond its noise, and why the corrected
        fit is missing when it failed."""
        out = [] if self.corrected_failure is None else [self.corrected_failure]
        worst = max(self.misfit_per_trial, key=lambda m: m.structure_chi2)
        if self.inflation > 1.2:
            out.append(f"torque-sensor gain (ch. 3, the report's method, shown beside the joint fit's): "
                       f"J* over blocks of harmonics is not constant (chi2/dof up to "
                       f"{worst.structure_chi2:.3g}, residual chi2/dof up to "
                       f"{max(m.chi2_reduced for m in self.misfit_per_trial):.3g}) - the J* s + b* model misses "
                       f"structure there; standard error inflated x{self.inflation:.2g}")
        c = self.corrected
        if c is not None and c.inflation > 1.2:
            out.append(f"torque-sensor gain (corrected ch. 3, shown beside the joint fit's): "
                       f"J* not constant (chi2/dof {c.structure_chi2[0]:.3g} "
                       f"over blocks of harmonics, {c.structure_chi2[1]:.3g} over set points, the delay's "
                       f"{c.delay_structure_chi2:.3g} over blocks of harmonics, residual chi2/dof up to "
                       f"{c.chi2_per_trial.max():.3g}) - the model misses structure there; standard error "
                       f"inflated x{c.inflation:.2g}")
        return tuple(out)


def trial_response(tables: BenchTables, index: int, max_harmonic: int) -> TrialResponse:
    """tau*_m / omega of one trial at harmonics 1..max_harmonic of its mean revolution (sec. 3.2).

    The H1 estimate S_xy / S_xx and the coherence |S_xy|^2 / (S_xx S_yy) from the cross and auto spectra
    averaged over windows of one revolution (boxcar, no overlap, no detrending): scipy.signal.csd and welch
    with those options, whose common scaling cancels in both ratios.
    """
    trial = tables.trials[index]
    samples_per_rev = int(2 ** np.ceil(np.log2(4 * max_harmonic + 4)))
    t, _, omega, torque = uniform_time_resample(trial.time_s, trial.count, trial.torque_nm,
                                                tables.motor.counts_per_rev, samples_per_rev)
    revolutions = t.size // samples_per_rev
    h = slice(1, max_harmonic + 1)
    windows = np.fft.rfft(np.stack([omega, torque])[:, : revolutions * samples_per_rev].reshape(
        2, revolutions, samples_per_rev), axis=2)[:, :, h]
    x, y = windows
    p_xy = np.mean(np.conj(x) * y, axis=0)
    p_xx, p_yy = np.mean(np.abs(windows) ** 2, axis=1)
    frequency = np.fft.rfftfreq(samples_per_rev, t[1] - t[0])
    with np.errstate(invalid="ignore", divide="ignore"):
        return TrialResponse(frequency_hz=frequency[h], response=p_xy / p_xx,
                             coherence=np.abs(p_xy) ** 2 / (p_xx * p_yy), revolutions=revolutions)


def _weights(response: TrialResponse, use: np.ndarray, model: np.ndarray) -> np.ndarray:
    """1 / var(H), var(H) = |H|^2 (1 - gamma^2) / (2 n gamma^2) with |H| from ``model``."""
    gamma2 = np.clip(response.coherence[use], None, 1.0 - 1e-12)
    return 2.0 * response.revolutions * gamma2 / ((1.0 - gamma2) * np.abs(model) ** 2)


def fit_inertia(response: TrialResponse, sensor: np.ndarray | None = None) -> tuple[float, float, float]:
    """Weighted least-squares fit of J* s + b* (eq. 3.2) to one response: J*, its standard error, b*.

    The weights are 1 / var(H), var(H) = |H|^2 (1 - gamma^2) / (2 n gamma^2)
    with |H| from the model of the previous pass (the first pass is
    unweighted). ``sensor``: the torque sensor's response per harmonic, divided
    out of H first (beyond the report).
    """
    use = response.coherence >= MIN_COHERENCE
    h = response.response[use] / (1.0 if sensor is None else sensor[use])
    w_rad = 2.0 * np.pi * response.frequency_hz[use]
    weights = np.ones(h.size)
    for _ in range(PASSES):
        inertia = np.sum(weights * w_rad * h.imag) / np.sum(weights * w_rad**2)
        damping = np.sum(weights * h.real) / np.sum(weights)
        weights = _weights(response, use, damping + 1j * w_rad * inertia)
    inertia_std = np.sqrt(0.5 / np.sum(weights * w_rad**2))  # each of Re and Im carries var(H) / 2
    return float(inertia), float(inertia_std), float(damping)


def inertia_misfit(response: TrialResponse, inertia: float, damping: float) -> InertiaMisfit:
    """The misfit of `fit_inertia`'s J* (from the imaginary part of H alone): chi-square and structure.

    chi2 = sum 2 w (Im H - w J*)^2 / (n - 1) over the n fitted harmonics,
    w = 1 / var(H) as the fit weighted them (each of Re and Im carries var(H) / 2).
    """
    use = response.coherence >= MIN_COHERENCE
    w_rad = 2.0 * np.pi * response.frequency_hz[use]
    information = 2.0 * _weights(response, use, damping + 1j * w_rad * inertia) * w_rad**2
    contribution = information * response.response[use].imag / w_rad
    chi2 = float(np.sum(information * (response.response[use].imag / w_rad - inertia) ** 2) / max(use.sum() - 1, 1))
    variance, q = harmonic_structure(contribution, information, inertia)
    return InertiaMisfit(chi2, variance, q)


def harmonic_structure(contribution: np.ndarray, information: np.ndarray, value: float) -> tuple[float, float]:
    """`structure_variance` of an estimate over consecutive blocks of harmonics: (variance, chi2 per dof).

    The estimate is sum(contribution) / sum(information) with variance 1 / sum(information) from the
    noise; each block of harmonics in order gives its own, with its own variance. Two halves (a trend)
    and blocks of ceil(sqrt(n)) (a bump): the one that finds more structure counts.
    """
    n = information.size
    best = (0.0, 0.0)
    for size in {n // 2, int(np.ceil(np.sqrt(n)))}:
        if size < 1 or n // size < 2:
            continue
        count = n // size
        info = information[: count * size].reshape(count, size).sum(axis=1)
        part = contribution[: count * size].reshape(count, size).sum(axis=1)
        seen = info > 0.0
        if seen.sum() < 2:
            continue
        best = max(best, structure_variance(part[seen] / info[seen] - value, 1.0 / info[seen], info[seen]))
    return best


def position_response(tables: BenchTables, index: int, max_harmonic: int, sensor: np.ndarray) -> PositionResponse:
    """One trial's harmonics 1..max_harmonic for the pooled fit; ``sensor``: the torque sensor's response there.

    The variances are floored at NOISE_FLOOR times the mean power (a noise-free trial repeats exactly).
    """
    trial = tables.trials[index]
    cpr = tables.motor.counts_per_rev
    torque, variance = revolution_harmonics(trial.count, trial.torque_nm, cpr, max_harmonic)
    try:
        speed = EncoderTorqueSpectrum.of(trial.count, trial.time_s, cpr, max_harmonic, 1.0, 0.0)
    except ValueError as e:
        raise IdentificationError(f"torque-sensor gain (corrected ch. 3): {e}") from None
    h = np.arange(1, max_harmonic + 1)
    torque, variance = torque[1:] / sensor, variance[1:] / np.abs(sensor) ** 2
    floor = NOISE_FLOOR * max(float(np.mean(np.abs(torque) ** 2)), np.finfo(float).tiny)
    return PositionResponse(torque, np.maximum(variance, floor), speed.harmonics_nm[1:],
                            speed.speed_harmonics_rad_s[1:], 2.0 * np.pi * h * trial.speed_hz)


def fit_pooled(responses: list[PositionResponse]) -> PooledInertia:
    """J* shared by all set points, b*_k per set point and the delays D and D_b, by weighted least squares.

    tau*_h exp(j w_h D) = J* inertial_h + b*_k omega_h exp(-j w_h D_b), each real and imaginary part
    weighted by 2 / E|d tau*_h|^2; D and D_b by Gauss-Newton steps from 0 (the columns
    -j w_h tau*_h exp(j w_h D) and -j w_h b*_k omega_h exp(-j w_h D_b) with the previous step's b*_k,
    kept in the final fit so that J*'s error holds theirs). With B the inverse of the normal matrix and X_k the
    rows of set point k, the covariance is B (sum_k max(chi2_k, 1) X_k^T X_k) B (a set point's misfit
    widens its share), and J*'s variance adds the structure of J* over blocks of harmonics and over set
    points (`harmonic_structure`, `structure_variance`), and that of D over blocks of harmonics times
    J*'s dependence on D, (B_JD / B_DD)^2 var(D): one delay for every harmonic is a model, and the torque
    sampled once per count as the current settles within it makes the delay seen at the excitation
    harmonics differ from the one at the position-locked harmonics (cogging, 1x-2x electrical) that hold
    most of J*'s information; through the brake's b*_k omega_h, rotated by the delay, J* moves with it.
    """
    n = len(responses)
    delays, damping = np.zeros(2), np.zeros(n)
    for _ in range(PASSES):
        step = _least_squares(*_pooled_rows(responses, delays, damping)[:2])[0]
        delays, damping = delays + step[1:3], step[3:]
    delay, brake_delay = delays
    design, y, group = _pooled_rows(responses, delays, damping)
    x, bound = _least_squares(design, y)
    rest = y - design @ x
    information = np.zeros_like(bound)
    chi2 = np.empty(n)
    for k in range(n):
        part = design[group == k]
        dof = part.shape[0] - np.trace(bound @ part.T @ part)
        chi2[k] = np.sum(rest[group == k] ** 2) / dof
        information += max(chi2[k], 1.0) * (part.T @ part)
    covariance = bound @ information @ bound
    inertia, damping = float(x[0]), x[3:]
    # J* over blocks of harmonics (pooled over set points) and per set point, D, D_b and b*_k held
    size = responses[0].torque_nm.size
    contribution, info = np.zeros(size), np.zeros(size)
    delay_contribution, delay_info = np.zeros(size), np.zeros(size)
    per_trial, per_trial_variance = np.empty(n), np.empty(n)
    for k, r in enumerate(responses):
        weight = 2.0 / r.torque_variance_nm2
        shifted = r.torque_nm * np.exp(1j * r.frequency_rad_s * delay)
        rest_k = shifted - damping[k] * r.speed_rad_s * np.exp(-1j * r.frequency_rad_s * brake_delay)
        contribution_k = weight * np.real(np.conj(r.inertial_rad2_s2) * rest_k)
        info_k = weight * np.abs(r.inertial_rad2_s2) ** 2
        contribution += contribution_k
        info += info_k
        # D's step with J* and b*_k held: column -j w_h tau*_h exp(j w_h D) against the residual
        step = -1j * r.frequency_rad_s * shifted
        delay_contribution += weight * np.real(np.conj(step) * (rest_k - inertia * r.inertial_rad2_s2))
        delay_info += weight * np.abs(step) ** 2
        per_trial[k] = contribution_k.sum() / info_k.sum()
        per_trial_variance[k] = max(chi2[k], 1.0) / info_k.sum()
    over_harmonics, q_harmonics = harmonic_structure(contribution, info, inertia)
    over_set_points, q_set_points = structure_variance(per_trial - inertia, per_trial_variance) if n > 1 else (0.0, 0.0)
    delay_variance, q_delay = harmonic_structure(delay_contribution, delay_info, 0.0)
    over_delay = (bound[0, 1] / bound[1, 1]) ** 2 * delay_variance if bound[1, 1] > 0.0 else 0.0
    return PooledInertia(
        inertia=inertia,
        inertia_std=float(np.sqrt(covariance[0, 0] + over_harmonics + over_set_points + over_delay)),
        noise_std=float(np.sqrt(bound[0, 0])), damping=damping, delay_s=float(delay),
        brake_delay_s=float(brake_delay), chi2_per_trial=chi2,
        structure_chi2=(q_harmonics, q_set_points), delay_structure_chi2=q_delay,
        delay_structure_s=float(np.sqrt(delay_variance)))


def _least_squares(design: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares solution and (X^T X)^-1, by the normal equations with the columns scaled to unit norm."""
    scale = np.sqrt(np.sum(design**2, axis=0))
    scale[scale == 0.0] = 1.0
    inverse = np.linalg.pinv((design.T @ design) / np.outer(scale, scale)) / np.outer(scale, scale)
    return inverse @ (design.T @ y), inverse


def _pooled_rows(responses: list[PositionResponse], delays_s: np.ndarray,
                 damping: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`fit_pooled`'s weighted design (J*, the steps of D and D_b, b*_k), data and set point per row, real
    parts then imaginary parts of each set point's harmonics, at the delays ``delays_s`` (D, D_b) with D_b's
    column from ``damping`` (b*_k, N m s / rad)."""
    n = len(responses)
    rows, data, group = [], [], []
    for k, r in enumerate(responses):
        shifted = r.torque_nm * np.exp(1j * r.frequency_rad_s * delays_s[0])
        brake = r.speed_rad_s * np.exp(-1j * r.frequency_rad_s * delays_s[1])
        columns = np.zeros((r.torque_nm.size, n + 3), complex)
        columns[:, 0] = r.inertial_rad2_s2
        columns[:, 1] = -1j * r.frequency_rad_s * shifted
        columns[:, 2] = -1j * r.frequency_rad_s * damping[k] * brake
        columns[:, 3 + k] = brake
        root = np.sqrt(2.0 / r.torque_variance_nm2)
        rows.append(np.concatenate([(root[:, None] * columns).real, (root[:, None] * columns).imag]))
        data.append(np.concatenate([(root * shifted).real, (root * shifted).imag]))
        group.append(np.full(2 * r.torque_nm.size, k))
    return np.vstack(rows), np.concatenate(data), np.concatenate(group)


def estimate_sensor_gain(tables: BenchTables, max_harmonic: int,
                         sensor_response=None) -> SensorGainEstimate:
    """The report's ch. 3 over all trials: J* per set point, their mean, delta = J* / J.

    Parameters
    ----------
    tables : BenchTables
    max_harmonic : int
        Highest harmonic of the response.
    sensor_response : callable, optional
        ``sensor_response(harmonics, speed_hz)`` -> the torque sensor's complex
        response (high-pass and delay) for the corrected fit (`fit_pooled`, which fits the delay on).

    Raises
    ------
    IdentificationError
        With trials at fewer than two set points (J* is averaged over the
        operating range, fig. 3.3), or when too few harmonics are coherent.
    """
    set_points = {(t.torque_setpoint_nm, t.speed_setpoint_hz) for t in tables.trials}
    if len(set_points) < 2:
        raise IdentificationError(
            "torque-sensor gain (ch. 3): a single set point - J* is averaged over the operating range "
            "(fig. 3.3) and needs trials at two set points or more")
    responses = tuple(trial_response(tables, k, max_harmonic) for k in range(len(tables.trials)))
    coherent = [int(np.sum(r.coherence >= MIN_COHERENCE)) for r in responses]
    if min(coherent) < 3:
        raise IdentificationError(
            f"torque-sensor gain (ch. 3): coherence too low - a trial has {min(coherent)} harmonics with "
            f"coherence >= {MIN_COHERENCE}, the J* s + b* fit needs 3")
    fits = np.array([fit_inertia(r) for r in responses])
    inertia_per_trial, noise_std, damping = fits.T
    misfits = tuple(inertia_misfit(r, j, b) for r, j, b in zip(responses, inertia_per_trial, damping))
    variance = np.array([m.variance(s) for m, s in zip(misfits, noise_std)])
    n = inertia_per_trial.size
    inertia = float(inertia_per_trial.mean())
    scatter = float(inertia_per_trial.var(ddof=1) / n)
    noise = float(np.mean(noise_std**2) / n)
    inertia_variance = max(scatter, float(variance.mean()) / n) + float(np.mean([m.structure_variance_kgm4
                                                                                 for m in misfits]))
    corrected, failure = None, None
    if sensor_response is not None:
        h = np.arange(1, max_harmonic + 1)
        try:
            corrected = fit_pooled([position_response(tables, k, max_harmonic, sensor_response(h, t.speed_hz))
                                    for k, t in enumerate(tables.trials)])
        except IdentificationError as e:  # the report's fit still stands
            failure = f"{e} - the report's ch. 3 fit is used"
    j = tables.motor.inertia_kgm2
    inertia_std = float(np.sqrt(inertia_variance))
    corrected_inertia = np.nan if corrected is None else corrected.inertia
    corrected_std = np.nan if corrected is None else corrected.inertia_std
    return SensorGainEstimate(
        responses=responses, inertia_per_trial=inertia_per_trial, inertia_std_per_trial=np.sqrt(variance),
        damping_per_trial=damping, misfit_per_trial=misfits, inertia=inertia, inertia_std=inertia_std,
        inflation=float(np.sqrt(inertia_variance / max(scatter, noise))), delta=inertia / j,
        delta_std=inertia_std / j, corrected=corrected, corrected_inertia=corrected_inertia,
        corrected_inertia_std=corrected_std, corrected_delta=corrected_inertia / j,
        corrected_delta_std=corrected_std / j, corrected_failure=failure)
