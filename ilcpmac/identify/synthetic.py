"""Bench folders for any motor, generated directly from the report's eqs. (1.3) and (3.1).

Unlike the full simulator (`ilcpmac.sim`), nothing here but the model the
identification assumes: the currents are eps alpha_p G(I*_p) + beta_p with G
an optional first-order current-loop lag applied in time to the per-count
staircase of the references, the torque is sum_p K_p i_p + tau_c (eq. 1.3),
the rotor obeys J d omega/dt = tau - b omega (eq. 3.1), and the torque sensor
reports delta times the torque (optionally high-passed) plus an unknown DC
level, a linear drift and white noise. Samples are taken once per encoder
count; counts may be skipped. Used by the tests and the benchmark to score
the identification against a known truth for motors other than the seed bench.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from ilcpmac.bench.format import Bench, MotorInfo
from ilcpmac.model.motor import BackEmf, Cogging, Winding
from ilcpmac.model.tables import backemf_table, cogging_table, current_references
from ilcpmac.records import SensorCalibration, TrialData
from ilcpmac.signals.multisine import multisine, multisine_phases_rad


@dataclass(frozen=True)
class SyntheticMotor:
    """Geometry, back-EMF, cogging and inertia of a synthetic motor.

    Attributes
    ----------
    pole_pairs, slots, counts_per_rev : int
    inertia_kgm2 : float
        J, kg m^2.
    backemf_harmonics, backemf_amplitudes_nm_per_a, backemf_phases_rad : tuple
        K_p = sum_n k_n sin(n (theta_e - 2 pi p / 3) + phi_n), N m / A.
    backemf_asymmetry : tuple of 3 floats
        Relative amplitude deviation per phase.
    cogging_multiples, cogging_amplitudes_nm, cogging_phases_rad : tuple
        tau_c = sum_m a_m sin(m N_c theta + phi_m), N_c = lcm(slots, 2 pole_pairs).
    """

    pole_pairs: int = 4
    slots: int = 36
    counts_per_rev: int = 2048
    inertia_kgm2: float = 0.004
    backemf_harmonics: tuple = (1, 3, 5)
    backemf_amplitudes_nm_per_a: tuple = (0.3, 0.02, 0.006)
    backemf_phases_rad: tuple = (0.0, 0.4, -0.3)
    backemf_asymmetry: tuple = (0.0, 0.01, -0.02)
    cogging_multiples: tuple = (1, 2)
    cogging_amplitudes_nm: tuple = (0.15, 0.03)
    cogging_phases_rad: tuple = (0.3, -1.0)

    @property
    def cogging_order(self) -> int:
        """lcm(slots, 2 pole_pairs)."""
        return math.lcm(self.slots, 2 * self.pole_pairs)


@dataclass(frozen=True)
class SyntheticSensors:
    """The true sensor errors relative to the controller's calibration (eqs. 1.4-1.7).

    Attributes
    ----------
    delta, epsilon : float
    alpha : tuple of 3 floats
        Normalised to mean 1 here.
    beta_a : tuple of 3 floats
        A.
    """

    delta: float = 0.9
    epsilon: float = 0.8
    alpha: tuple = (0.9, 1.05, 1.05)
    beta_a: tuple = (0.3, -0.2, 0.1)

    def alpha_normalised(self) -> np.ndarray:
        alpha = np.asarray(self.alpha, float)
        return alpha / alpha.mean()


@dataclass(frozen=True)
class SyntheticCampaign:
    """Set points, excitation and measurement of a synthetic campaign.

    Attributes
    ----------
    torque_setpoints_nm, speed_setpoints_hz : tuple
        The grid; one trial per pair.
    revolutions, warmup_revolutions : int
    excitation_harmonics : int
        Multisine over harmonics 1..H of the revolution, random phases per trial.
    excitation_fraction : float
        Multisine RMS over the set point.
    current_loop_hz : float or None
        Corner of a first-order current-loop lag (None: the currents follow the references).
    torque_noise_nm, torque_dc_nm, torque_drift_nm_per_s : float
        White noise per sample, bounds of the unknown DC level and drift.
    torque_highpass_hz : float
        First-order high-pass of the torque sensor (0: none).
    skip_fraction : float
        Fraction of the counts not recorded (skipped at random).
    timer_resolution_s : float
        Time-stamp quantum.
    seed : int
    """

    torque_setpoints_nm: tuple = (1.0, 2.0, 3.0)
    speed_setpoints_hz: tuple = (0.6, 1.0)
    revolutions: int = 4
    warmup_revolutions: int = 1
    excitation_harmonics: int = 100
    excitation_fraction: float = 0.05
    current_loop_hz: float | None = None
    torque_noise_nm: float = 0.01
    torque_dc_nm: float = 0.3
    torque_drift_nm_per_s: float = 0.005
    torque_highpass_hz: float = 0.0
    skip_fraction: float = 0.0
    timer_resolution_s: float = 1e-6
    seed: int = 0


#: integration steps per encoder count
STEPS_PER_COUNT = 8


@njit(cache=True)
def _eq13(table, i_ref, scale, offset, j):
    """Eq. (1.3) at count j (without delta): sum_p K_p (eps alpha_p I*_p + beta_p) + tau_c."""
    torque = table[j, 3]
    for p in range(3):
        torque += table[j, p] * (scale[p] * i_ref[j, p] + offset[p])
    return torque


@njit(cache=True)
def _integrate(table, i_ref, scale, offset, inertia, brake, omega0, loop_tau, counts, dt, highpass_gain,
               settled_nm, out_count, out_time, out_torque):
    """Integrate eq. (3.1) with the torque of eq. (1.3) and sample once per count.

    ``table`` holds K_a, K_b, K_c and tau_c per count (linearly interpolated
    in angle between counts). The currents follow the per-count staircase of
    the references through a first-order lag with time constant ``loop_tau``.
    Without a lag (0) the torque is eq. (1.3) at each count and linear in
    angle in between, so that the samples are eq. (1.3) exactly.
    The sampled torque is high-passed by subtracting a first-order low-pass
    with gain ``highpass_gain`` per step (0: none), settled at ``settled_nm``.
    Returns the number of samples (fewer than ``counts`` if the rotor stalled).
    """
    cpr = i_ref.shape[0]
    rad_per_count = 2.0 * np.pi / cpr
    decay = np.exp(-dt / loop_tau) if loop_tau > 0.0 else 0.0
    theta, omega, t = 0.0, omega0, 0.0
    current = scale * i_ref[0] + offset
    low = settled_nm if highpass_gain > 0.0 else 0.0
    last_count = 0
    n = 0
    for _ in range(50 * counts * STEPS_PER_COUNT):
        position = theta / rad_per_count
        c = int(np.floor(position))
        f = position - c
        j, j1 = c % cpr, (c + 1) % cpr
        k = table[j] + f * (table[j1] - table[j])
        target = scale * i_ref[j] + offset
        previous = current
        if loop_tau > 0.0:
            current = target + (current - target) * decay
            tau = k[0] * previous[0] + k[1] * previous[1] + k[2] * previous[2] + k[3]
        else:
            tau = (1.0 - f) * _eq13(table, i_ref, scale, offset, j) + f * _eq13(table, i_ref, scale, offset, j1)
        low += highpass_gain * (tau - low)
        theta_old, t_old = theta, t
        theta += omega * dt
        omega += dt / inertia * (tau - brake * omega)
        t += dt
        new_count = int(np.floor(theta / rad_per_count))
        if new_count > last_count:
            last_count = new_count
            if new_count >= counts:
                break
            fraction = (new_count * rad_per_count - theta_old) / (theta - theta_old)
            m = new_count % cpr
            if loop_tau > 0.0:
                drive = previous + fraction * (current - previous)
                sample = table[m, 0] * drive[0] + table[m, 1] * drive[1] + table[m, 2] * drive[2] + table[m, 3]
            else:
                sample = _eq13(table, i_ref, scale, offset, m)
            out_count[n] = new_count
            out_time[n] = t_old + fraction * dt
            out_torque[n] = sample - low
            n += 1
    return n


def _trial(motor: SyntheticMotor, sensors: SyntheticSensors, campaign: SyntheticCampaign, backemf: np.ndarray,
           cogging: np.ndarray, torque_nm: float, speed_hz: float, index: int) -> TrialData:
    cpr = motor.counts_per_rev
    rng = np.random.default_rng([campaign.seed, index])
    phases = multisine_phases_rad(campaign.excitation_harmonics, "random", rng)
    reference = torque_nm + multisine(cpr, campaign.excitation_harmonics, campaign.excitation_fraction * torque_nm,
                                      phases)
    i_ref = current_references(reference, backemf)
    scale = sensors.epsilon * sensors.alpha_normalised()
    offset = np.asarray(sensors.beta_a, float)
    mean_torque = float(np.mean(np.sum(backemf * (scale * i_ref + offset), axis=1) + cogging))
    omega0 = 2.0 * np.pi * speed_hz
    warmup = campaign.warmup_revolutions * cpr
    counts = warmup + campaign.revolutions * cpr
    dt = 1.0 / (STEPS_PER_COUNT * cpr * speed_hz)
    loop_tau = 0.0 if campaign.current_loop_hz is None else 1.0 / (2.0 * np.pi * campaign.current_loop_hz)
    highpass_gain = 1.0 - np.exp(-2.0 * np.pi * campaign.torque_highpass_hz * dt)
    out = (np.zeros(counts, np.int64), np.zeros(counts), np.zeros(counts))
    n = _integrate(np.column_stack([backemf, cogging]), i_ref, scale, offset, motor.inertia_kgm2,
                   mean_torque / omega0, omega0, loop_tau, counts, dt, highpass_gain, mean_torque, *out)
    count, time, torque = (a[:n] for a in out)
    keep = count >= warmup
    if campaign.skip_fraction > 0.0:
        keep &= rng.random(n) >= campaign.skip_fraction
    count, time, torque = count[keep] - warmup, time[keep], torque[keep]
    time = np.round(time / campaign.timer_resolution_s) * campaign.timer_resolution_s
    dc = rng.uniform(-1.0, 1.0) * campaign.torque_dc_nm
    drift = rng.uniform(-1.0, 1.0) * campaign.torque_drift_nm_per_s
    measured = sensors.delta * torque + dc + drift * time + campaign.torque_noise_nm * rng.standard_normal(time.size)
    return TrialData(torque_nm, speed_hz, count, time, i_ref[count % cpr], measured)


def synthetic_bench(motor: SyntheticMotor = SyntheticMotor(), sensors: SyntheticSensors = SyntheticSensors(),
                    campaign: SyntheticCampaign = SyntheticCampaign()) -> tuple[Bench, dict]:
    """A bench folder in memory and its truth (the result keys of docs/bench-format.md).

    The controller's calibration ([sensors]) is 10 counts per ampere, no
    offset and a torque gain of 1 V / N m, so that the truth's calibration
    block follows from eqs. (1.4)-(1.7).
    """
    cpr = motor.counts_per_rev
    winding = Winding(motor.pole_pairs, motor.slots, 1.0, 1.0)
    backemf = backemf_table(winding, BackEmf(motor.backemf_harmonics, motor.backemf_amplitudes_nm_per_a,
                                             motor.backemf_phases_rad, motor.backemf_asymmetry), cpr)
    cogging = cogging_table(winding, Cogging(motor.cogging_multiples, motor.cogging_amplitudes_nm,
                                             motor.cogging_phases_rad), cpr)
    grid = [(t, f) for t in campaign.torque_setpoints_nm for f in campaign.speed_setpoints_hz]
    trials = tuple(_trial(motor, sensors, campaign, backemf, cogging, t, f, i) for i, (t, f) in enumerate(grid))
    calibration = SensorCalibration([10.0, 10.0, 10.0], [0.0, 0.0, 0.0], 1.0)
    bench = Bench(MotorInfo(motor.pole_pairs, motor.slots, cpr, motor.inertia_kgm2), backemf, calibration, trials,
                  tuple(f"trial_{i + 1:02d}.csv" for i in range(len(trials))))
    alpha = sensors.alpha_normalised()
    scale = calibration.current_scale / (sensors.epsilon * alpha)
    truth = {
        "total_system_gain": sensors.delta * sensors.epsilon, "torque_sensor_gain": sensors.delta,
        "epsilon": sensors.epsilon, "alpha": alpha.tolist(), "beta": list(sensors.beta_a),
        "inertia_estimate": sensors.delta * motor.inertia_kgm2,
        "cogging": {"count": list(range(cpr)), "torque": cogging.tolist()},
        "calibration": {"current_scale": scale.tolist(),
                        "current_offset": (np.asarray(sensors.beta_a) * scale).tolist(),
                        "torque_gain": sensors.delta * calibration.torque_gain},
        "current_loop_bandwidth_hz": campaign.current_loop_hz,
    }
    return bench, truth
