"""Python side of the simulator: validate, build the kernel's inputs, run trials in parallel.

Every input of the kernel is checked here first (`SimulationError`, one line
naming the value): the model's ranges, the request's values, shapes and
dtypes, the encoder's line errors, and the trial's size against
`MAX_SAMPLES` and `MAX_STEPS`.
"""

from __future__ import annotations

import copy
import math
import os
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np

from ilcpmac.core.binning import count_means, sample_means
from ilcpmac.core.errors import SimulationError
from ilcpmac.core.records import MotorInfo, SensorCalibration, TrialData, TrialRequest, mirrored_table
from ilcpmac.core.schema import finite_number, shown
from ilcpmac.model.encoder import line_errors_problem
from ilcpmac.model.motor import MotorModel, model_problem
from ilcpmac.model.tables import backemf_table, cogging_table, current_references, disturbance_table
from ilcpmac.sim.kernel import GAUSS_BITS, simulate_trial

#: Physics tables hold this many points per encoder count (linear interpolation in between).
OVERSAMPLE = 16
#: Most encoder counts per revolution simulated: the tables then hold 4.2 M rows (134 MB).
MAX_COUNTS_PER_REV = 2**18
#: Most samples one trial records: its eight output arrays take 112 bytes per sample (0.94 GB at the cap).
MAX_SAMPLES = 2**23
#: Most control steps of one trial's budget (three times its nominal duration over the control period):
#: about a minute of one core at the cap.
MAX_STEPS = 2**31
#: Most warm-up revolutions.
MAX_WARMUP_REVOLUTIONS = 2**24


def airgap_torque_nm(k_nm_per_a: np.ndarray, i_true_a: np.ndarray, saturation_per_a2: float) -> np.ndarray:
    """sum_p K_p i_p (1 - c i_p^2) over the last axis (eq. 1.1 with the saturation term), N m: the kernel's
    `_torque` without the position torque, for arrays."""
    return np.sum(k_nm_per_a * i_true_a * (1.0 - saturation_per_a2 * i_true_a**2), axis=-1)


@dataclass(frozen=True)
class SensorTruth:
    """The report's parameters of a trial, eqs. (1.4)-(1.7), for a given calibration.

    ``loop_bandwidth_hz``, shape (3,): each phase's closed current loop's corner, Hz.
    """

    delta: float
    epsilon: float
    alpha: np.ndarray
    beta_a: np.ndarray
    loop_bandwidth_hz: np.ndarray


class Simulator:
    """Simulates trials of one drive.

    The kernel samples every line of the model's encoder; a trial records
    ``record_counts_per_rev`` counts per revolution, each the centred mean
    over its b = counts_per_rev / record_counts_per_rev lines
    (`ilcpmac.core.binning`), and takes its feed-forward and excitation
    tables at those counts: the controller holds a count's torque reference
    over its b lines and commutes at every line.

    Parameters
    ----------
    model : MotorModel
        The drive.
    warmup_revolutions : int
        Revolutions simulated and dropped before recording starts.
    record_counts_per_rev : int or None
        A divisor of the encoder's counts per revolution (None: all of them).
    """

    def __init__(self, model: MotorModel, warmup_revolutions: int = 1,
                 record_counts_per_rev: int | None = None) -> None:
        problem = model_problem(model)
        if problem is not None:
            raise SimulationError(f"model {problem}")
        if model.encoder.counts_per_rev > MAX_COUNTS_PER_REV:
            raise SimulationError(f"model [encoder] counts_per_rev: {model.encoder.counts_per_rev} is more than "
                                  f"the simulator's {MAX_COUNTS_PER_REV}")
        if not (_integer(warmup_revolutions) and 0 <= warmup_revolutions <= MAX_WARMUP_REVOLUTIONS):
            raise SimulationError(f"warmup_revolutions must be an integer within 0..{MAX_WARMUP_REVOLUTIONS}, "
                                  f"got {shown(warmup_revolutions)}")
        cpr = model.encoder.counts_per_rev
        recorded = cpr if record_counts_per_rev is None else record_counts_per_rev
        if not (_integer(recorded) and 1 <= recorded <= cpr and cpr % recorded == 0):
            raise SimulationError(f"record_counts_per_rev {shown(recorded)} does not divide the encoder's {cpr} "
                                  "counts per revolution")
        self.model = model
        self.warmup_revolutions = warmup_revolutions
        self.record_counts_per_rev = recorded
        #: lines of the encoder per recorded count
        self.lines_per_count = cpr // recorded
        n_fine = cpr * OVERSAMPLE
        backemf = backemf_table(model.winding, model.backemf, n_fine)
        self.cogging_fine = cogging_table(model.winding, model.cogging, n_fine)
        self.torque_pos_fine = self.cogging_fine + disturbance_table(model.unexplained, n_fine)
        fine = np.column_stack([model.winding.backemf_scale * backemf, self.torque_pos_fine])
        self.fine = np.ascontiguousarray(np.vstack([fine, fine[:1]]))  # periodic: first row repeated
        #: the back-EMF table per encoder line (the controller's K*), and at each recorded count (backemf.csv)
        self.backemf_lines = np.ascontiguousarray(backemf[::OVERSAMPLE])
        self.backemf_counts = np.ascontiguousarray(self.backemf_lines[::self.lines_per_count])
        errors = model.encoder.line_errors_counts()
        problem = line_errors_problem(errors, cpr)
        if problem is not None:
            raise SimulationError(f"model [encoder] eccentricity_counts, line_std_counts, line_seed: {problem}")
        #: true positions of lines -1 .. counts_per_rev + 1 from angle 0, counts (the kernel's ``lines_counts``)
        self.lines_counts = np.arange(-1, cpr + 2) + np.concatenate([errors[-1:], errors, errors[:2]])
        self.gauss_table = np.random.default_rng(0).standard_normal(2**GAUSS_BITS)
        start = model.controller.calibration()
        self.scale_true = model.current_sensors.true_scale_counts_per_a(start)
        self.offset_true = model.current_sensors.true_offset_counts(start)
        self.torque_gain_true = model.torque_sensor.true_gain_v_per_nm(start)

    def mirrored(self) -> Simulator:
        """The simulator of the mirror image M' of this motor M, whose forward laps are M's reverse laps
        (docs/bench-format.md, "Reverse laps"): its back-EMF (the controller's table and the true one), position
        torque (cogging and disturbance) and encoder lines mirrored; sensors, current loop, load and mechanics as
        they are."""
        mirror = copy.copy(self)
        fine = mirrored_table(self.fine[:-1])
        mirror.fine = np.ascontiguousarray(np.vstack([fine, fine[:1]]))
        mirror.backemf_lines = np.ascontiguousarray(mirrored_table(self.backemf_lines))
        mirror.backemf_counts = np.ascontiguousarray(mirror.backemf_lines[::self.lines_per_count])
        mirror.cogging_fine = mirrored_table(self.cogging_fine)
        mirror.torque_pos_fine = mirrored_table(self.torque_pos_fine)
        cpr = self.backemf_lines.shape[0]
        errors = mirrored_table(self.lines_counts[1:-2] - np.arange(cpr))
        mirror.lines_counts = np.arange(-1, cpr + 2) + np.concatenate([errors[-1:], errors, errors[:2]])
        return mirror

    def truth(self, calibration: SensorCalibration) -> SensorTruth:
        """delta, epsilon, alpha, beta and the current loop's corners that hold while the controller uses
        ``calibration``."""
        eps_alpha = calibration.current_scale / self.scale_true
        ctrl = self.model.controller
        return SensorTruth(
            delta=self.torque_gain_true / calibration.torque_gain,
            epsilon=float(eps_alpha.mean()),
            alpha=eps_alpha / eps_alpha.mean(),
            beta_a=(self.offset_true - calibration.current_offset) / self.scale_true,
            # a PI loop closes on the measured current, 1 / (epsilon alpha_p) times the true one
            loop_bandwidth_hz=np.full(3, ctrl.bandwidth_hz) / (eps_alpha if ctrl.loop == "pi" else 1.0),
        )

    def cogging_counts(self) -> np.ndarray:
        """The true cogging torque per recorded count (its lines' mean, as a trial records it), N m."""
        return count_means(self.cogging_fine[::OVERSAMPLE], self.lines_per_count)

    def line_errors_counts(self) -> np.ndarray:
        """The true error of each recorded count's position (its lines' mean), recorded counts."""
        b = self.lines_per_count
        return count_means(self.model.encoder.line_errors_counts(), b) / b

    def motor_info(self) -> MotorInfo:
        """The motor as the bench describes it: `MotorModel.motor_info` at the recorded counts, each the mean over
        `lines_per_count` lines; such a record states its stamps' resolution (`timer_resolution_s` of
        `ilcpmac.identify.encoder`)."""
        if self.lines_per_count == 1:
            return self.model.motor_info()
        return replace(self.model.motor_info(), counts_per_rev=self.record_counts_per_rev,
                       lines_per_count=self.lines_per_count, timer_resolution_s=self.model.encoder.timer_resolution_s)

    def _check(self, request: TrialRequest) -> int:
        """Refuse what the kernel cannot run; returns the trial's step budget."""
        cpr, lines = self.record_counts_per_rev, self.model.encoder.counts_per_rev
        for name in ("feedforward_nm", "excitation_nm"):
            table = getattr(request, name)
            if not isinstance(table, np.ndarray) or table.dtype.kind not in "fiu":
                raise SimulationError(f"request {name} must be a real NumPy array, got {shown(table)}")
            if table.shape != (cpr,):
                raise SimulationError(f"request {name} has shape {table.shape}, expected ({cpr},)")
            if not np.all(np.isfinite(table)):
                raise SimulationError(f"request {name} holds NaN or infinite values")
        if not (_integer(request.seed) and 0 <= request.seed < 2**32):
            raise SimulationError(f"request seed must be a 32-bit unsigned integer, got {shown(request.seed)}")
        if not (_integer(request.revolutions) and request.revolutions >= 1):
            raise SimulationError(f"revolutions must be at least 1, got {shown(request.revolutions)}")
        if request.revolutions * lines > MAX_SAMPLES:
            raise SimulationError(f"{request.revolutions} revolutions x {lines} counts are more samples than the "
                                  f"simulator's {MAX_SAMPLES} per trial")
        if not finite_number(request.torque_setpoint_nm):
            raise SimulationError(f"torque set point must be a finite number, got {shown(request.torque_setpoint_nm)}")
        speed = request.speed_setpoint_hz
        if not (finite_number(speed) and speed > 0):
            raise SimulationError(f"speed set point must be positive, got {shown(speed)}")
        rate = self.model.controller.control_rate_hz
        if speed * lines > rate / 2:
            raise SimulationError(f"speed set point {speed:g} Hz x {lines} counts per revolution is more than half "
                                  f"the control rate {rate:g} Hz (each count needs two control periods)")
        budget = 3.0 * (self.warmup_revolutions + request.revolutions) / speed * rate + 1000
        if not budget <= MAX_STEPS:
            raise SimulationError(f"a trial of {self.warmup_revolutions} + {request.revolutions} revolutions at "
                                  f"{speed:g} Hz needs a budget of {budget:.3g} control steps, more than the "
                                  f"simulator's {MAX_STEPS}")
        cal = request.calibration
        scale, offset, gain = cal.current_scale, cal.current_offset, cal.torque_gain
        if not (np.all(np.isfinite(scale) & (scale > 0)) and np.all(np.isfinite(offset))
                and math.isfinite(gain) and gain > 0):
            raise SimulationError("request calibration needs finite positive current scales and torque gain "
                                  "and finite offsets")
        return int(budget)

    def _steady_state(self, request: TrialRequest, i_ref: np.ndarray) -> np.ndarray:
        """Torque per count with ideal current tracking, N m (eq. 1.3 plus the unexplained terms)."""
        truth = self.truth(request.calibration)
        i_true = truth.epsilon * truth.alpha * i_ref + truth.beta_a
        backemf = self.model.winding.backemf_scale * self.backemf_lines
        tau = airgap_torque_nm(backemf, i_true, self.model.unexplained.saturation_per_a2)
        return tau + self.torque_pos_fine[::OVERSAMPLE]

    def _load(self, request: TrialRequest, mean_torque_nm: float, omega0_rad_s: float) -> tuple[float, float]:
        """The load that holds the set speed against the mean torque: b (omega - omega_load), N m s and rad/s.

        Where the motor turns the rotor against the friction (motoring), the brake or the load machine, omega_load
        0, b what balances the rest at the set speed; where it holds the rotor back (generating: less torque than
        the friction takes, or negative), only a load machine (``[simulator.mechanics] load = "machine"``) driving
        it, omega_load 2 omega, b of the same size: the rotor equally stiff either way.
        """
        rest = mean_torque_nm - self.model.mechanics.coulomb_friction_nm
        if rest > 0.0:
            return rest / omega0_rad_s, 0.0
        if self.model.mechanics.load == "brake" or rest == 0.0:
            raise SimulationError(
                f"set point {request.torque_setpoint_nm} N m gives {mean_torque_nm:.3g} N m mean torque: "
                "not enough to turn the rotor against friction, and " + (
                    "a brake cannot drive it (generating needs [simulator.mechanics] load = \"machine\")"
                    if rest < 0.0 else "no load holds the speed at the friction's torque exactly"))
        return -rest / omega0_rad_s, 2.0 * omega0_rad_s

    def run_trial(self, request: TrialRequest) -> TrialData:
        """Simulate one trial; ``request.seed`` fixes every random draw."""
        max_steps = self._check(request)
        m = self.model
        cpr, b = m.encoder.counts_per_rev, self.lines_per_count
        # the controller holds each recorded count's torque reference over its b lines and commutes at every line
        i_ref = np.ascontiguousarray(current_references(np.repeat(request.torque_reference_nm(), b),
                                                        self.backemf_lines), dtype=np.float64)
        if not np.all(np.isfinite(i_ref)):
            raise SimulationError("the torque reference needs infinite currents where the back-EMF table vanishes")
        omega0 = 2.0 * np.pi * request.speed_setpoint_hz
        brake, load_speed = self._load(request, float(self._steady_state(request, i_ref).mean()), omega0)
        dt = 1.0 / m.controller.control_rate_hz
        if not brake * dt / m.mechanics.true_inertia_kgm2 < 1.0:
            raise SimulationError(
                f"set point {request.torque_setpoint_nm} N m at {request.speed_setpoint_hz:g} Hz needs a brake of "
                f"{brake:.3g} N m s, too strong for the explicit speed update (brake x control period / inertia "
                "must stay below 1): raise the speed")
        rng = np.random.default_rng(request.seed)
        dc = rng.uniform(-1.0, 1.0) * m.torque_sensor.dc_level_nm
        drift = rng.uniform(-1.0, 1.0) * m.torque_sensor.drift_nm_per_s
        w_bw = 2.0 * np.pi * m.controller.bandwidth_hz
        r = np.full(3, m.winding.phase_resistance_ohm)
        ell = np.full(3, m.winding.phase_inductance_h)
        delta = self.torque_gain_true / request.calibration.torque_gain
        # the lines from the first recorded count's mean to the last's: b // 2 either side of lines 0 .. (R - 1) b
        warmup = max(self.warmup_revolutions * cpr - b // 2, 0)
        before = self.warmup_revolutions * cpr - warmup
        record = before + (request.revolutions * self.record_counts_per_rev - 1) * b + b // 2 + 1
        out = _allocate(record)
        n = simulate_trial(
            self.fine, i_ref, self.lines_counts, self.gauss_table,
            r, ell, w_bw * ell, w_bw * r, m.controller.voltage_limit_v, dt,
            m.controller.loop == "lag", math.exp(-w_bw * dt),
            self.scale_true, self.offset_true, np.array(request.calibration.current_scale, np.float64),
            np.array(request.calibration.current_offset, np.float64), m.current_sensors.noise_counts,
            m.unexplained.saturation_per_a2,
            m.mechanics.true_inertia_kgm2, brake, load_speed, m.mechanics.coulomb_friction_nm, omega0,
            delta, 1.0 / (1.0 + 2.0 * np.pi * m.torque_sensor.highpass_hz * dt), dc, drift,
            m.torque_sensor.noise_nm,
            warmup, record, m.encoder.timer_resolution_s, max_steps, request.seed, *out,
        )
        if n < 2 or out[0][n - 1] < record - 1 - cpr // 2:
            raise SimulationError(
                f"trial at {request.torque_setpoint_nm} N m, {request.speed_setpoint_hz} Hz stalled or diverged "
                f"after {n} of {record} counts")
        count, time, i_ref_s, i_meas, torque, torque_true, i_true, speed = (a[:n] for a in out)
        if b > 1:  # the measurements as count means; the references those at the count's line
            count, (time, i_meas, torque, torque_true, i_true, speed) = sample_means(
                count - before, [time, i_meas, torque, torque_true, i_true, speed], b,
                request.revolutions * self.record_counts_per_rev)
            i_ref_s = i_ref[count * b % cpr]
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
        results: dict[int, TrialData] = {}
        with ThreadPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(self.run_trial, req): i for i, req in enumerate(requests)}
            for future in as_completed(futures):
                i = futures[future]
                results[i] = future.result()
                if on_done is not None:
                    on_done(i, results[i])
        return [results[i] for i in range(len(requests))]


def _integer(x) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, bool)


def _allocate(n: int) -> tuple[np.ndarray, ...]:
    return (np.zeros(n, np.int64), np.zeros(n), np.zeros((n, 3)), np.zeros((n, 3)),
            np.zeros(n), np.zeros(n), np.zeros((n, 3)), np.zeros(n))
