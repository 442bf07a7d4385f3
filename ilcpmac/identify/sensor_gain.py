"""Torque-sensor gain delta from the mechanical dynamics (report ch. 3).

The rotor obeys tau*_m = delta (J d omega/dt + b omega) (eq. 3.1), so the
frequency response from angular velocity to measured torque is
J* s + b* with J* = delta J and b* = delta b (eqs. 3.2-3.4). The data are
sampled per encoder count, so they are first re-sampled at constant time
intervals through cubic splines (sec. 3.1), with a whole number of samples
per mean revolution; the response is then estimated with scipy.signal for a
periodic excitation (boxcar windows of one revolution, no overlap), with its
coherence, and J* s + b* is fitted per set point by weighted least squares
(the report used frsfit): an unweighted linear fit first, then weights
1 / var(H) from the coherence and the fitted model, iterated. J* is averaged
over the set points (fig. 3.3) and delta = J* / J with J from bench.toml.

Beyond the report (`SensorGainEstimate.corrected_*`): the measured torque
passes the sensor's own high-pass and delay (identified by the joint fit),
which bend the response at its low and high ends; dividing them out before
the fit, and fitting one J* shared by all set points with a b* per set point,
removes that bias.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ilcpmac.errors import IdentificationError
from ilcpmac.identify.reduction import BenchTables
from ilcpmac.signals.harmonics import uniform_time_resample

#: coherence a harmonic needs to enter the transfer-function fit
MIN_COHERENCE = 0.8
#: reweighting passes of the weighted least-squares fit
PASSES = 3


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
class SensorGainEstimate:
    """The report's torque-sensor gain (ch. 3) and the corrected pooled fit.

    Attributes
    ----------
    responses : tuple of TrialResponse
    inertia_per_trial, inertia_std_per_trial, damping_per_trial : ndarray
        J* (kg m^2) with its standard error, and b* (N m s / rad), per set point.
    inertia, inertia_std : float
        J* for the bench: the mean over set points and the standard error of that mean.
    delta, delta_std : float
        J* / J.
    corrected_inertia, corrected_inertia_std, corrected_delta, corrected_delta_std : float
        The pooled fit with the sensor's high-pass and delay divided out (NaN when not given).
    """

    responses: tuple
    inertia_per_trial: np.ndarray
    inertia_std_per_trial: np.ndarray
    damping_per_trial: np.ndarray
    inertia: float
    inertia_std: float
    delta: float
    delta_std: float
    corrected_inertia: float
    corrected_inertia_std: float
    corrected_delta: float
    corrected_delta_std: float


def trial_response(tables: BenchTables, index: int, max_harmonic: int) -> TrialResponse:
    """tau*_m / omega of one trial at harmonics 1..max_harmonic of its mean revolution (sec. 3.2)."""
    from scipy import signal  # 0.5 s to import (scipy 1.17 parses docstrings): only when estimating

    trial = tables.trials[index]
    samples_per_rev = int(2 ** np.ceil(np.log2(4 * max_harmonic + 4)))
    t, _, omega, torque = uniform_time_resample(trial.time_s, trial.count, trial.torque_nm,
                                                tables.motor.counts_per_rev, samples_per_rev)
    fs = 1.0 / (t[1] - t[0])
    options = dict(fs=fs, window="boxcar", nperseg=samples_per_rev, noverlap=0, detrend=False)
    frequency, p_xy = signal.csd(omega, torque, **options)
    _, p_xx = signal.welch(omega, **options)
    _, p_yy = signal.welch(torque, **options)
    h = slice(1, max_harmonic + 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return TrialResponse(frequency_hz=frequency[h], response=p_xy[h] / p_xx[h],
                             coherence=np.abs(p_xy[h]) ** 2 / (p_xx[h] * p_yy[h]),
                             revolutions=t.size // samples_per_rev)


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
    gamma2 = np.clip(response.coherence[use], None, 1.0 - 1e-12)
    weights = np.ones(h.size)
    for _ in range(PASSES):
        inertia = np.sum(weights * w_rad * h.imag) / np.sum(weights * w_rad**2)
        damping = np.sum(weights * h.real) / np.sum(weights)
        model = np.abs(damping + 1j * w_rad * inertia)
        weights = 2.0 * response.revolutions * gamma2 / ((1.0 - gamma2) * model**2)
    inertia_std = np.sqrt(0.5 / np.sum(weights * w_rad**2))  # each of Re and Im carries var(H) / 2
    return float(inertia), float(inertia_std), float(damping)


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
        response (high-pass and delay) for the corrected fit.

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
    inertia_per_trial, inertia_std_per_trial, damping = fits.T
    inertia = float(inertia_per_trial.mean())
    inertia_std = float(inertia_per_trial.std(ddof=1) / np.sqrt(inertia_per_trial.size))
    corrected, corrected_std = np.nan, np.nan
    if sensor_response is not None:
        h = np.arange(1, max_harmonic + 1)
        corrected_fits = np.array([fit_inertia(r, sensor_response(h, t.speed_hz))
                                   for r, t in zip(responses, tables.trials)])
        variance = corrected_fits[:, 1] ** 2
        corrected = float(np.sum(corrected_fits[:, 0] / variance) / np.sum(1.0 / variance))
        scatter = np.sum((corrected_fits[:, 0] - corrected) ** 2 / variance) / max(len(variance) - 1, 1)
        corrected_std = float(np.sqrt(max(scatter, 1.0) / np.sum(1.0 / variance)))
    j = tables.motor.inertia_kgm2
    return SensorGainEstimate(
        responses=responses, inertia_per_trial=inertia_per_trial, inertia_std_per_trial=inertia_std_per_trial,
        damping_per_trial=damping, inertia=inertia, inertia_std=inertia_std, delta=inertia / j,
        delta_std=inertia_std / j, corrected_inertia=corrected, corrected_inertia_std=corrected_std,
        corrected_delta=corrected / j, corrected_delta_std=corrected_std / j)
