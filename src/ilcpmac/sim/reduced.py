"""The reduced model: bench folders generated directly from the report's eqs. (1.3) and (3.1).

Unlike the full simulator (`ilcpmac.sim.simulator`), nothing here but the
model the identification assumes, on the model's own dataclasses
(`ilcpmac.model.motor`): the currents are eps alpha_p G(I*_p) + beta_p
(`CurrentSensors`) with G an optional first-order current-loop lag applied in
time to the per-count staircase of the references, the torque is
sum_p K_p i_p + tau_c (eq. 1.3; `Winding`, `BackEmf`, `Cogging`), the rotor
obeys J d omega/dt = tau - b omega (eq. 3.1), and the torque sensor reports
delta times the torque, optionally high-passed, plus an unknown DC level, a
linear drift and white noise (`TorqueSensor`). Samples are taken once per
encoder count (`Encoder`); counts may be skipped. Used by the tests and the
benchmark to score the identification against a known truth for motors
other than the seed bench.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ilcpmac.bench.format import Bench
from ilcpmac.core.records import MotorInfo, SensorCalibration, TrialData
from ilcpmac.model.motor import BackEmf, Cogging, CurrentSensors, Encoder, Excitation, TorqueSensor, TrialGrid, Winding
from ilcpmac.model.tables import backemf_table, cogging_table, current_references
from ilcpmac.signals.multisine import multisine, multisine_phases_rad


@dataclass(frozen=True)
class ReducedMotor:
    """What the reduced model knows of a motor (default: 4 pole pairs, 36 slots, 2048 counts).

    ``winding``'s resistance and inductance are not used (the current loop is a lag).
    """

    winding: Winding = Winding(pole_pairs=4, slots=36, phase_resistance_ohm=1.0, phase_inductance_h=1.0)
    backemf: BackEmf = BackEmf(harmonics=(1, 3, 5), amplitudes_nm_per_a=(0.3, 0.02, 0.006),
                               phases_rad=(0.0, 0.4, -0.3), asymmetry=(0.0, 0.01, -0.02))
    cogging: Cogging = Cogging(multiples=(1, 2), amplitudes_nm=(0.15, 0.03), phases_rad=(0.3, -1.0))
    encoder: Encoder = Encoder(counts_per_rev=2048, timer_resolution_s=1e-6)
    inertia_kgm2: float = 0.004


@dataclass(frozen=True)
class ReducedSensors:
    """The true sensors relative to the controller's calibration (eqs. 1.4-1.7); ``current.noise_counts``
    is not used (the bench records the references)."""

    current: CurrentSensors = CurrentSensors(epsilon=0.8, alpha=(0.9, 1.05, 1.05), beta_a=(0.3, -0.2, 0.1),
                                             noise_counts=0.0)
    torque: TorqueSensor = TorqueSensor(delta=0.9, noise_nm=0.01, highpass_hz=0.0, dc_level_nm=0.3,
                                        drift_nm_per_s=0.005)


@dataclass(frozen=True)
class ReducedCampaign:
    """The grid (one trial per torque and speed set point), its excitation and what the bench adds.

    Attributes
    ----------
    grid : TrialGrid
    excitation : Excitation
        Multisine over harmonics 1..H of the revolution (its RMS a fraction of the set point).
    current_loop_hz : float or None
        Corner of a first-order current-loop lag (None: the currents follow the references).
    skip_fraction : float
        Fraction of the counts not recorded (skipped at random).
    """

    grid: TrialGrid = TrialGrid(torque_setpoints_nm=(1.0, 2.0, 3.0), speed_setpoints_hz=(0.6, 1.0), revolutions=4,
                                warmup_revolutions=1, seed=0)
    excitation: Excitation = Excitation(harmonics=100, fraction=0.05, phases="random")
    current_loop_hz: float | None = None
    skip_fraction: float = 0.0


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


def _trial(motor: ReducedMotor, sensors: ReducedSensors, campaign: ReducedCampaign, backemf: np.ndarray,
           cogging: np.ndarray, torque_nm: float, speed_hz: float, index: int) -> TrialData:
    cpr = motor.encoder.counts_per_rev
    grid, excitation, torque_sensor = campaign.grid, campaign.excitation, sensors.torque
    rng = np.random.default_rng([grid.seed, index])
    phases = multisine_phases_rad(excitation.harmonics, excitation.phases, rng)
    reference = torque_nm + multisine(cpr, excitation.harmonics, excitation.fraction * torque_nm, phases)
    i_ref = current_references(reference, backemf)
    scale = sensors.current.epsilon * np.asarray(sensors.current.alpha)
    offset = np.asarray(sensors.current.beta_a, float)
    mean_torque = float(np.mean(np.sum(backemf * (scale * i_ref + offset), axis=1) + cogging))
    omega0 = 2.0 * np.pi * speed_hz
    warmup = grid.warmup_revolutions * cpr
    counts = warmup + grid.revolutions * cpr
    dt = 1.0 / (STEPS_PER_COUNT * cpr * speed_hz)
    loop_tau = 0.0 if campaign.current_loop_hz is None else 1.0 / (2.0 * np.pi * campaign.current_loop_hz)
    highpass_gain = 1.0 - np.exp(-2.0 * np.pi * torque_sensor.highpass_hz * dt)
    out = (np.zeros(counts, np.int64), np.zeros(counts), np.zeros(counts))
    n = _integrate(np.column_stack([backemf, cogging]), i_ref, scale, offset, motor.inertia_kgm2,
                   mean_torque / omega0, omega0, loop_tau, counts, dt, highpass_gain, mean_torque, *out)
    count, time, torque = (a[:n] for a in out)
    keep = count >= warmup
    if campaign.skip_fraction > 0.0:
        keep &= rng.random(n) >= campaign.skip_fraction
    count, time, torque = count[keep] - warmup, time[keep], torque[keep]
    resolution = motor.encoder.timer_resolution_s
    time = np.round(time / resolution) * resolution
    dc = rng.uniform(-1.0, 1.0) * torque_sensor.dc_level_nm
    drift = rng.uniform(-1.0, 1.0) * torque_sensor.drift_nm_per_s
    measured = (torque_sensor.delta * torque + dc + drift * time
                + torque_sensor.noise_nm * rng.standard_normal(time.size))
    return TrialData(torque_nm, speed_hz, count, time, i_ref[count % cpr], measured)


def reduced_bench(motor: ReducedMotor = ReducedMotor(), sensors: ReducedSensors = ReducedSensors(),
                  campaign: ReducedCampaign = ReducedCampaign()) -> tuple[Bench, dict]:
    """A bench folder in memory and its truth (the result keys of docs/bench-format.md).

    The controller's calibration ([sensors]) is 10 counts per ampere, no
    offset and a torque gain of 1 V / N m, so that the truth's calibration
    block follows from eqs. (1.4)-(1.7).
    """
    cpr = motor.encoder.counts_per_rev
    backemf = backemf_table(motor.winding, motor.backemf, cpr)
    cogging = cogging_table(motor.winding, motor.cogging, cpr)
    grid = [(t, f) for t in campaign.grid.torque_setpoints_nm for f in campaign.grid.speed_setpoints_hz]
    trials = tuple(_trial(motor, sensors, campaign, backemf, cogging, t, f, i) for i, (t, f) in enumerate(grid))
    calibration = SensorCalibration([10.0, 10.0, 10.0], [0.0, 0.0, 0.0], 1.0)
    bench = Bench(MotorInfo(motor.winding.pole_pairs, motor.winding.slots, cpr, motor.inertia_kgm2), backemf,
                  calibration, trials, tuple(f"trial_{i + 1:02d}.csv" for i in range(len(trials))))
    current, delta = sensors.current, sensors.torque.delta
    corrected = SensorCalibration(current.true_scale_counts_per_a(calibration),
                                  current.true_offset_counts(calibration), delta * calibration.torque_gain)
    truth = {
        "total_system_gain": delta * current.epsilon, "torque_sensor_gain": delta,
        "epsilon": current.epsilon, "alpha": list(current.alpha), "beta": list(current.beta_a),
        "inertia_estimate": delta * motor.inertia_kgm2,
        "cogging": {"count": list(range(cpr)), "torque": cogging.tolist()},
        "calibration": corrected.to_json(),
        "current_loop_bandwidth_hz": campaign.current_loop_hz,
    }
    return bench, truth
