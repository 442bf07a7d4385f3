"""Python side of the simulator: validate, build the kernel's inputs, run trials in parallel."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ilcpmac.errors import SimulationError
from ilcpmac.model.motor import MotorModel
from ilcpmac.model.tables import backemf_table, cogging_table, current_references, disturbance_table
from ilcpmac.records import SensorCalibration, TrialData, TrialRequest
from ilcpmac.sim.kernel import GAUSS_BITS, simulate_trial

#: Physics tables hold this many points per encoder count (linear interpolation in between).
OVERSAMPLE = 16


def trial_seed(seed: int, index: int) -> int:
    """The 32-bit seed of trial ``index`` of a campaign seeded with ``seed``."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


@dataclass(frozen=True)
class SensorTruth:
    """The report's parameters of a trial, eqs. (1.4)-(1.7), for a given calibration."""

    delta: float
    epsilon: float
    alpha: np.ndarray
    beta_a: np.ndarray


class Simulator:
    """Simulates trials of one drive.

    Parameters
    ----------
    model : MotorModel
        The drive.
    warmup_revolutions : int
        Revolutions simulated and dropped before recording starts.
    """

    def __init__(self, model: MotorModel, warmup_revolutions: int = 1) -> None:
        self.model = model
        self.warmup_revolutions = warmup_revolutions
        cpr = model.encoder.counts_per_rev
        n_fine = cpr * OVERSAMPLE
        backemf = backemf_table(model.winding, model.backemf, n_fine)
        self.cogging_fine = cogging_table(model.winding, model.cogging, n_fine)
        self.torque_pos_fine = self.cogging_fine + disturbance_table(model.unexplained, n_fine)
        fine = np.column_stack([backemf, self.torque_pos_fine])
        self.fine = np.ascontiguousarray(np.vstack([fine, fine[:1]]))  # periodic: first row repeated
        #: the back-EMF table per encoder count (backemf.csv, the controller's K*)
        self.backemf_counts = np.ascontiguousarray(backemf[::OVERSAMPLE])
        self.gauss_table = np.random.default_rng(0).standard_normal(2**GAUSS_BITS)
        start = model.controller.calibration()
        self.scale_true = model.current_sensors.true_scale_counts_per_a(start)
        self.offset_true = model.current_sensors.true_offset_counts(start)
        self.torque_gain_true = model.torque_sensor.true_gain_v_per_nm(start)

    def truth(self, calibration: SensorCalibration) -> SensorTruth:
        """delta, epsilon, alpha and beta that hold while the controller uses ``calibration``."""
        eps_alpha = calibration.current_scale / self.scale_true
        return SensorTruth(
            delta=self.torque_gain_true / calibration.torque_gain,
            epsilon=float(eps_alpha.mean()),
            alpha=eps_alpha / eps_alpha.mean(),
            beta_a=(self.offset_true - calibration.current_offset) / self.scale_true,
        )

    def cogging_counts(self) -> np.ndarray:
        """The true cogging torque per encoder count, N m."""
        return self.cogging_fine[::OVERSAMPLE].copy()

    def _check(self, request: TrialRequest) -> None:
        cpr = self.model.encoder.counts_per_rev
        for name in ("feedforward_nm", "excitation_nm"):
            table = getattr(request, name)
            if table.shape != (cpr,):
                raise SimulationError(f"request {name} has shape {table.shape}, expected ({cpr},)")
            if not np.all(np.isfinite(table)):
                raise SimulationError(f"request {name} holds NaN or infinite values")
        if not 0 <= request.seed < 2**32:
            raise SimulationError(f"request seed must be a 32-bit unsigned integer, got {request.seed}")
        if not request.speed_setpoint_hz > 0:
            raise SimulationError(f"speed set point must be positive, got {request.speed_setpoint_hz}")
        if request.revolutions < 1:
            raise SimulationError(f"revolutions must be at least 1, got {request.revolutions}")
        cal = request.calibration
        if not (np.all(cal.current_scale > 0) and cal.torque_gain > 0 and np.all(np.isfinite(cal.current_offset))):
            raise SimulationError("request calibration needs positive current scales and torque gain")

    def _steady_state(self, request: TrialRequest, i_ref: np.ndarray) -> np.ndarray:
        """Torque per count with ideal current tracking, N m (eq. 1.3 plus the unexplained terms)."""
        truth = self.truth(request.calibration)
        i_true = truth.epsilon * truth.alpha * i_ref + truth.beta_a
        c = self.model.unexplained.saturation_per_a2
        tau = np.sum(self.backemf_counts * i_true * (1.0 - c * i_true**2), axis=1)
        return tau + self.torque_pos_fine[::OVERSAMPLE]

    def run_trial(self, request: TrialRequest) -> TrialData:
        """Simulate one trial; ``request.seed`` fixes every random draw."""
        self._check(request)
        m = self.model
        cpr = m.encoder.counts_per_rev
        i_ref = current_references(request.torque_reference_nm(), self.backemf_counts)
        omega0 = 2.0 * np.pi * request.speed_setpoint_hz
        mean_torque = float(self._steady_state(request, i_ref).mean())
        if mean_torque <= m.mechanics.coulomb_friction_nm:
            raise SimulationError(
                f"set point {request.torque_setpoint_nm} N m gives {mean_torque:.3g} N m mean torque: "
                "not enough to turn the rotor against friction")
        brake = (mean_torque - m.mechanics.coulomb_friction_nm) / omega0
        rng = np.random.default_rng(request.seed)
        dc = rng.uniform(-1.0, 1.0) * m.torque_sensor.dc_level_nm
        drift = rng.uniform(-1.0, 1.0) * m.torque_sensor.drift_nm_per_s
        dt = 1.0 / m.controller.control_rate_hz
        w_bw = 2.0 * np.pi * m.controller.bandwidth_hz
        r = np.full(3, m.winding.phase_resistance_ohm)
        ell = np.full(3, m.winding.phase_inductance_h)
        delta = self.torque_gain_true / request.calibration.torque_gain
        warmup = self.warmup_revolutions * cpr
        record = request.revolutions * cpr
        duration = (self.warmup_revolutions + request.revolutions) / request.speed_setpoint_hz
        max_steps = int(3.0 * duration / dt) + 1000
        out = _allocate(record)
        n = simulate_trial(
            self.fine, np.ascontiguousarray(i_ref), self.gauss_table,
            r, ell, w_bw * ell, w_bw * r, m.controller.voltage_limit_v, dt,
            self.scale_true, self.offset_true, request.calibration.current_scale,
            request.calibration.current_offset, m.current_sensors.noise_counts,
            m.unexplained.saturation_per_a2,
            m.mechanics.inertia_kgm2, brake, m.mechanics.coulomb_friction_nm, omega0,
            delta, 1.0 / (1.0 + 2.0 * np.pi * m.torque_sensor.highpass_hz * dt), dc, drift,
            m.torque_sensor.noise_nm,
            warmup, record, m.encoder.timer_resolution_s, max_steps, request.seed, *out,
        )
        if n < 2 or out[0][n - 1] < record - 1 - cpr // 2:
            raise SimulationError(
                f"trial at {request.torque_setpoint_nm} N m, {request.speed_setpoint_hz} Hz stalled "
                f"after {n} of {record} counts")
        count, time, i_ref_s, i_meas, torque, torque_true, i_true, speed = (a[:n] for a in out)
        return TrialData(
            torque_setpoint_nm=request.torque_setpoint_nm, speed_setpoint_hz=request.speed_setpoint_hz,
            count=count, time_s=time, i_ref_a=i_ref_s, torque_nm=torque, i_meas_a=i_meas,
            torque_true_nm=torque_true, i_true_a=i_true, speed_true_rad_s=speed, request=request)

    def run_trials(self, requests: Sequence[TrialRequest], workers: int | None = None,
                   on_done: Callable[[int, TrialData], None] | None = None) -> list[TrialData]:
        """Simulate several trials in parallel threads (the kernel releases the GIL).

        ``on_done(index, trial)`` is called as each finishes (for progress).
        Results are in request order and do not depend on ``workers``.
        """
        workers = workers or os.cpu_count() or 1
        results: list[TrialData | None] = [None] * len(requests)
        with ThreadPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(self.run_trial, req): i for i, req in enumerate(requests)}
            for future in as_completed(futures):
                i = futures[future]
                results[i] = future.result()
                if on_done is not None:
                    on_done(i, results[i])
        return results  # type: ignore[return-value]


def _allocate(n: int) -> tuple[np.ndarray, ...]:
    return (np.zeros(n, np.int64), np.zeros(n), np.zeros((n, 3)), np.zeros((n, 3)),
            np.zeros(n), np.zeros(n), np.zeros((n, 3)), np.zeros(n))
