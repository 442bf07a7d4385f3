"""Speed of the numba drive simulator, against the issue's targets.

Run ``python benchmarks/simulator.py`` (under a minute) or add ``--quick``.
Every time is wall time from ``time.perf_counter``; repeated measurements
report the best (min) and the median. Three things are measured:

1. One core. ``Simulator.run_trial`` on the seed bench's 3 N m set point at
   0.75 Hz, multisine excitation as in ``grid_requests``, 8 recorded
   revolutions after the warm-up, once JIT compiled. Simulated time is
   (warm-up + recorded revolutions) / speed; steps are that time times the
   control rate (20 kHz). Real-time factor = simulated time / wall time.
   The share of the wall time spent inside the kernel is measured by
   wrapping the kernel with a timer.

2. Against ``scipy.integrate.solve_ivp``, the approach of existing Python
   drive simulators (motulator): a continuous-time ODE for the three phase
   currents, the speed and the angle, integrated with RK45 at motulator's
   default tolerances between the 20 kHz updates of a discrete PI current
   controller whose voltages are held (zero-order hold). It has the same
   physics as the kernel (back-EMF, cogging and disturbance as sine sums of
   the model's harmonics, current-sensor scale, offset and noise, PI with
   voltage limit and conditional integration, saturating torque sum,
   J domega/dt = tau - b omega - coulomb, position-triggered sampling), and
   leaves out only the torque sensor, whose output does not feed back.
   Faithfulness is checked first: both simulate the same trial without
   current noise, from the same state; the kernel's samples of current and
   speed are compared with the reference's state at the same control
   instant, and the time stamps count by count. Then the reference is timed
   on a short span of the benchmark trial (with noise).

3. Two cores. The seed bench's 30-trial grid through
   ``Simulator.run_trials`` with one worker thread and with two; the
   scaling is the ratio of the two wall times (best over best, and the
   median of the ratios of runs made back to back). The kernel releases the
   GIL, so the Python-side work of ``run_trial`` (validation, tables,
   allocation) is what could serialise the threads: its share of the wall
   time is reported, and the minor page faults per trial (``run_trials``
   keeps every result, so each trial's output arrays are fresh memory that
   the kernel faults in). The same batch on two worker processes, which
   share no GIL and return only a sample count, shows what the two cores
   give without either. The three ways are interleaved, repeat by repeat,
   as the machine's speed drifts over time.

Every measurement also reports how many cores other processes kept busy
meanwhile (from /proc/stat: Linux only), and is flagged when they competed.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import resource
import statistics
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from functools import partial
from multiprocessing import get_context
from operator import truediv
from pathlib import Path

import numba
import numpy as np
import scipy
from scipy.integrate import solve_ivp

import ilcpmac.sim.simulator as simulator_module
from ilcpmac.campaign.grid import grid_requests
from ilcpmac.config import CampaignConfig, load_config
from ilcpmac.core.records import TrialRequest
from ilcpmac.model.motor import MotorModel
from ilcpmac.model.tables import backemf_table, current_references
from ilcpmac.sim.simulator import Simulator

CONFIG_PATH = Path(__file__).resolve().parents[1] / "configs" / "seed-bench.toml"
TORQUE_NM = 3.0
SPEED_HZ = 0.75
TWO_PI = 2.0 * math.pi

#: The issue's targets.
TARGET_REAL_TIME = 2000.0
TARGET_SPEEDUP = 300.0
TARGET_SCALING = 1.8

#: Other processes' mean CPU use above which a measurement is flagged as contended, cores.
MAX_FOREIGN_CORES = 0.1

#: motulator's default solve_ivp settings.
IVP_METHOD = "RK45"
IVP_RTOL = 1e-3
IVP_ATOL = 1e-6


@dataclass(frozen=True)
class Settings:
    """How much to measure."""

    trial_repeats: int
    grid_trials: int
    grid_repeats: int
    reference_span_s: float
    reference_repeats: int
    check_span_s: float


FULL = Settings(trial_repeats=50, grid_trials=30, grid_repeats=20, reference_span_s=0.1,
                reference_repeats=3, check_span_s=0.2)
QUICK = Settings(trial_repeats=10, grid_trials=10, grid_repeats=3, reference_span_s=0.05,
                 reference_repeats=1, check_span_s=0.1)


@dataclass(frozen=True)
class Timing:
    """Wall times of repeated runs of one workload."""

    seconds: list[float]

    @property
    def best(self) -> float:
        return min(self.seconds)

    @property
    def median(self) -> float:
        return statistics.median(self.seconds)


def wall_time(run: Callable[[], object]) -> float:
    """Wall time of one call of ``run``, s."""
    start = time.perf_counter()
    run()
    return time.perf_counter() - start


def time_runs(run: Callable[[], object], repeats: int) -> Timing:
    """Wall times of ``repeats`` calls of ``run``."""
    return Timing([wall_time(run) for _ in range(repeats)])


@contextmanager
def kernel_clock() -> Iterator[list[float]]:
    """Time every kernel call made by ``Simulator`` inside the block; yields the list of durations."""
    kernel = simulator_module.simulate_trial
    durations: list[float] = []

    def timed(*args):
        start = time.perf_counter()
        n = kernel(*args)
        durations.append(time.perf_counter() - start)
        return n

    simulator_module.simulate_trial = timed
    try:
        yield durations
    finally:
        simulator_module.simulate_trial = kernel


def _busy_cpu_seconds() -> float:
    """CPU time all processes have used since boot (Linux /proc/stat), s."""
    with open("/proc/stat") as f:
        user, nice, system, _idle, _iowait, irq, softirq = map(int, f.readline().split()[1:8])
    return (user + nice + system + irq + softirq) / os.sysconf("SC_CLK_TCK")


def minor_page_faults() -> int:
    """Minor page faults of this process so far (first touches of freshly mapped memory)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt


def _own_cpu_seconds() -> float:
    """CPU time of this process and its finished children, s."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


@contextmanager
def foreign_load() -> Iterator[list[float]]:
    """Yields a list that gets, on exit, the mean number of cores other processes kept busy in the block."""
    cores: list[float] = []
    start, busy, own = time.perf_counter(), _busy_cpu_seconds(), _own_cpu_seconds()
    yield cores
    foreign = (_busy_cpu_seconds() - busy) - (_own_cpu_seconds() - own)
    cores.append(max(foreign, 0.0) / (time.perf_counter() - start))


def simulated_seconds(request: TrialRequest, warmup_revolutions: int) -> float:
    """Simulated time of a trial: (warm-up + recorded revolutions) / speed."""
    return (warmup_revolutions + request.revolutions) / request.speed_setpoint_hz


def bench_request(config: CampaignConfig) -> TrialRequest:
    """The benchmark trial: the grid's multisine request at TORQUE_NM, run at SPEED_HZ."""
    requests = grid_requests(config, config.model.controller.calibration(), config.grid.seed, config.grid.revolutions)
    request = next(r for r in requests if r.torque_setpoint_nm == TORQUE_NM)
    return request.with_changes(speed_setpoint_hz=SPEED_HZ)


def without_current_noise(model: MotorModel) -> MotorModel:
    """``model`` with noiseless current sensors."""
    return dataclasses.replace(model, current_sensors=dataclasses.replace(model.current_sensors,
                                                                          noise_counts=0.0))


# --- the solve_ivp reference ------------------------------------------------------------------


@dataclass(frozen=True)
class ReferenceRun:
    """A trial of the reference: the state at every control instant and the position-triggered samples."""

    states: np.ndarray  # shape (steps + 1, 5): x at t_k = k dt
    count: np.ndarray  # one sample per newly reached encoder count
    time_s: np.ndarray


class SolveIvpDrive:
    """The drive as a continuous-time ODE integrated with solve_ivp between PI updates (ZOH).

    State x = (i_a, i_b, i_c, omega, theta), theta the unwrapped mechanical angle.
    """

    def __init__(self, model: MotorModel, request: TrialRequest) -> None:
        w, emf, cog, unx = model.winding, model.backemf, model.cogging, model.unexplained
        ctrl, sensors = model.controller, model.current_sensors
        start = ctrl.calibration()
        cal = request.calibration
        self.model = model
        self.cpr = model.encoder.counts_per_rev
        self.dt = 1.0 / ctrl.control_rate_hz
        self.r, self.ell = w.phase_resistance_ohm, w.phase_inductance_h
        self.kp = TWO_PI * ctrl.bandwidth_hz * self.ell
        self.ki = TWO_PI * ctrl.bandwidth_hz * self.r
        self.v_max = ctrl.voltage_limit_v
        # back-EMF: K_p = (1 + asym_p) sum_n k_n sin(n (P theta - 2 pi p / 3) + phi_n)
        self.emf_orders = np.asarray(emf.harmonics, float)
        self.emf_amps = np.asarray(emf.amplitudes_nm_per_a)
        self.emf_phases = np.asarray(emf.phases_rad)
        self.emf_scale = 1.0 + np.asarray(emf.asymmetry)
        self.phase_shift = TWO_PI * np.arange(3) / 3.0
        self.pole_pairs = w.pole_pairs
        # position torque: cogging plus the unexplained disturbance, sum_k a_k sin(o_k theta + phi_k)
        self.pos_orders = np.array([m * w.cogging_order for m in cog.multiples] + list(unx.orders), float)
        self.pos_amps = np.array(cog.amplitudes_nm + unx.amplitudes_nm)
        self.pos_phases = np.array(cog.phases_rad + unx.phases_rad)
        self.c_sat = unx.saturation_per_a2
        # sensors: reading r = i G_s^-1 - o_s + noise; the controller's current (r + o*_s) / G*_s^-1
        self.scale_true = sensors.true_scale_counts_per_a(start)
        self.offset_true = sensors.true_offset_counts(start)
        self.scale_cal, self.offset_cal = cal.current_scale, cal.current_offset
        self.noise_counts = sensors.noise_counts
        self.rng = np.random.default_rng(request.seed)
        # minimum-copper-loss references from the controller's back-EMF table, per count
        self.i_ref = current_references(request.torque_reference_nm(),
                                        backemf_table(w, emf, self.cpr))
        self.omega0 = TWO_PI * request.speed_setpoint_hz
        self.coulomb = model.mechanics.coulomb_friction_nm
        self.inertia = model.mechanics.inertia_kgm2
        self.brake = (self._mean_tracked_torque() - self.coulomb) / self.omega0

    def backemf(self, theta: float) -> np.ndarray:
        """K_p(theta) per phase, N m / A."""
        theta_e = self.pole_pairs * theta - self.phase_shift
        return self.emf_scale * (np.sin(np.outer(theta_e, self.emf_orders) + self.emf_phases) @ self.emf_amps)

    def position_torque(self, theta: float) -> float:
        """Cogging plus disturbance torque, N m."""
        return float(self.pos_amps @ np.sin(self.pos_orders * theta + self.pos_phases))

    def torque(self, theta: float, i: np.ndarray) -> float:
        """sum_p K_p i_p (1 - c i_p^2) + position torque, N m."""
        return float(self.backemf(theta) @ (i * (1.0 - self.c_sat * i * i))) + self.position_torque(theta)

    def tracked_currents(self, i_ref: np.ndarray) -> np.ndarray:
        """True currents at which the controller measures ``i_ref`` (noiseless)."""
        return (i_ref * self.scale_cal - self.offset_cal + self.offset_true) / self.scale_true

    def _mean_tracked_torque(self) -> float:
        """Mean torque over a revolution with ideal tracking: sets the brake for the set-point speed."""
        angles = TWO_PI * np.arange(self.cpr) / self.cpr
        tracked = self.tracked_currents(self.i_ref)
        return float(np.mean([self.torque(a, i) for a, i in zip(angles, tracked)]))

    def rhs(self, t: float, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """dx/dt: L di/dt = v - R i - K omega, J domega/dt = tau - b omega - coulomb sign(omega)."""
        i, omega, theta = x[:3], x[3], x[4]
        di = (v - self.r * i - self.backemf(theta) * omega) / self.ell
        friction = self.coulomb * np.sign(omega)
        domega = (self.torque(theta, i) - self.brake * omega - friction) / self.inertia
        return np.array([di[0], di[1], di[2], domega, omega])

    def control(self, i: np.ndarray, integ: np.ndarray, i_ref: np.ndarray) -> np.ndarray:
        """One PI update per phase from a sensor reading; returns the held voltage. Updates ``integ``."""
        reading = i * self.scale_true - self.offset_true + self.noise_counts * self.rng.standard_normal(3)
        err = i_ref - (reading + self.offset_cal) / self.scale_cal
        v = self.kp * err + integ + self.ki * self.dt * err
        free = np.abs(v) <= self.v_max
        integ[free] += self.ki * self.dt * err[free]  # conditional integration (anti-windup)
        return np.clip(v, -self.v_max, self.v_max)

    def run(self, span_s: float) -> ReferenceRun:
        """Simulate ``span_s`` seconds from steady speed on the tracked currents."""
        i0 = self.tracked_currents(self.i_ref[0])
        x = np.array([*i0, self.omega0, 0.0])
        integ = self.r * i0 + self.backemf(0.0) * self.omega0
        states = [x]
        samples = []
        last_count = 0
        for k in range(round(span_s / self.dt)):
            t = k * self.dt
            count = math.floor(x[4] * self.cpr / TWO_PI)
            v = self.control(x[:3], integ, self.i_ref[count % self.cpr])
            sol = solve_ivp(self.rhs, (t, t + self.dt), x, method=IVP_METHOD, rtol=IVP_RTOL,
                            atol=IVP_ATOL, args=(v,))
            theta_old, x = x[4], sol.y[:, -1]
            states.append(x)
            count = math.floor(x[4] * self.cpr / TWO_PI)
            if count > last_count:  # position-triggered sample, time interpolated within the step
                last_count = count
                samples.append((count, t + self.dt * (count * TWO_PI / self.cpr - theta_old)
                                / (x[4] - theta_old)))
        res = self.model.encoder.timer_resolution_s
        count, time_s = np.array(samples).T
        return ReferenceRun(np.array(states), count.astype(np.int64), np.round(time_s / res) * res)


# --- measurements -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Comparison:
    """Largest differences between the kernel's and the reference's run of the same noiseless trial."""

    span_s: float
    samples: int
    current_a: float
    current_peak_a: float
    speed_rad_s: float
    speed_ripple_rad_s: float
    time_s: float


def compare_with_kernel(model: MotorModel, request: TrialRequest, span_s: float) -> Comparison:
    """Run kernel and reference on ``request`` without current noise, from the same initial state.

    The kernel records the state at the end of the control step in which a
    count is reached: the reference's state at that control instant is
    compared. Time stamps on the step grid are left out (the step is
    ambiguous by the timer's rounding). Time stamps are compared count by
    count.
    """
    model = without_current_noise(model)
    trial = Simulator(model, warmup_revolutions=0).run_trial(request.with_changes(revolutions=1))
    reference = SolveIvpDrive(model, request)
    ref = reference.run(span_s)
    steps = trial.time_s / reference.dt
    step = np.ceil(steps).astype(int)
    keep = (step < len(ref.states)) & ~np.isclose(steps, np.round(steps), rtol=0.0, atol=1e-6)
    state = ref.states[step[keep]]
    _, k, r = np.intersect1d(trial.count, ref.count, return_indices=True)
    return Comparison(
        span_s=span_s,
        samples=int(keep.sum()),
        current_a=float(np.abs(trial.i_true_a[keep] - state[:, :3]).max()),
        current_peak_a=float(np.abs(ref.states[:, :3]).max()),
        speed_rad_s=float(np.abs(trial.speed_true_rad_s[keep] - state[:, 3]).max()),
        speed_ripple_rad_s=float(np.ptp(ref.states[:, 3])),
        time_s=float(np.abs(trial.time_s[k] - ref.time_s[r]).max()),
    )


@dataclass(frozen=True)
class BatchRun:
    """Repeated runs of the grid batch one way."""

    label: str
    wall: Timing
    # medians over repeats, threads only: kernel time summed over trials, minor page faults
    kernel_s: float | None = None
    page_faults: float | None = None


_worker_simulator: Simulator | None = None


def _start_worker(warmup_revolutions: int) -> None:
    """Process-pool initializer: each worker process builds its own simulator and warms it up."""
    global _worker_simulator
    config = load_config(CONFIG_PATH)
    _worker_simulator = Simulator(config.model, warmup_revolutions)
    _worker_simulator.run_trial(bench_request(config))  # compile or load the JIT cache


def _worker_pid(_: int) -> int:
    """The worker's process id, after a pause that lets the other worker take the next task."""
    time.sleep(0.1)
    return os.getpid()


def _samples_in_worker(request: TrialRequest) -> int:
    """Run one trial in a worker process; return only its sample count (no large pickles)."""
    return _worker_simulator.run_trial(request).n_samples


def time_batches(simulator: Simulator, requests: list[TrialRequest], repeats: int) -> list[BatchRun]:
    """Wall times of the batch on 1 and 2 threads (``run_trials``) and on 2 processes, interleaved."""
    walls: dict[str, list[float]] = {"1 thread": [], "2 threads": [], "2 processes": []}
    kernel: dict[str, list[float]] = {"1 thread": [], "2 threads": []}
    faults: dict[str, list[int]] = {"1 thread": [], "2 threads": []}
    with ProcessPoolExecutor(2, mp_context=get_context("spawn"), initializer=_start_worker,
                             initargs=(simulator.warmup_revolutions,)) as pool:
        while len(set(pool.map(_worker_pid, range(2)))) < 2:  # until both workers are up and warm
            pass
        for _ in range(repeats):
            for label, workers in (("1 thread", 1), ("2 threads", 2)):
                with kernel_clock() as durations:
                    start = minor_page_faults()
                    walls[label].append(wall_time(partial(simulator.run_trials, requests, workers=workers)))
                    faults[label].append(minor_page_faults() - start)
                kernel[label].append(sum(durations))
            walls["2 processes"].append(wall_time(lambda: list(pool.map(_samples_in_worker, requests))))
    return [BatchRun(label, Timing(seconds), statistics.median(kernel[label]), statistics.median(faults[label]))
            if label in kernel else BatchRun(label, Timing(seconds)) for label, seconds in walls.items()]


# --- report -------------------------------------------------------------------------------------


def verdict(value: float, target: float) -> str:
    """PASS when ``value`` reaches ``target``."""
    return "PASS" if value >= target else "MISS"


def contended(cores: float) -> str:
    """A warning when other processes competed for the CPUs during a measurement."""
    return " (CONTENDED: not a clean measurement)" if cores > MAX_FOREIGN_CORES else ""


def print_table(title: str, header: tuple[str, ...], rows: list[tuple[str, ...]]) -> None:
    """A plain-text table, first column left-aligned."""
    widths = [max(len(row[j]) for row in [header, *rows]) for j in range(len(header))]
    line = "  ".join("-" * w for w in widths)
    print(f"\n{title}\n{line}")
    for row in [header, None, *rows]:
        if row is None:
            print(line)
            continue
        cells = [row[0].ljust(widths[0])] + [c.rjust(w) for c, w in zip(row[1:], widths[1:])]
        print("  ".join(cells))
    print(line)


def one_core_rows(trial: Timing, ref: Timing, settings: Settings, trial_sim_s: float,
                  rate_hz: float) -> list[tuple[str, ...]]:
    """Rows of the one-core table: numba, the solve_ivp reference, their ratio of steps/s."""
    trial_steps = trial_sim_s * rate_hz
    ref_steps = settings.reference_span_s * rate_hz
    rows = []
    for name, t in (("best", trial.best), ("median", trial.median)):
        rows.append((f"numba run_trial ({name} of {len(trial.seconds)})", f"{t * 1e3:.2f} ms",
                     f"{trial_steps / t / 1e6:.1f} M", f"{trial_sim_s / t:.0f}x",
                     f">= {TARGET_REAL_TIME:.0f}x real time", verdict(trial_sim_s / t, TARGET_REAL_TIME)))
    for name, t in (("best", ref.best), ("median", ref.median)):
        rows.append((f"solve_ivp, {settings.reference_span_s:g} s span ({name} of {len(ref.seconds)})",
                     f"{t:.2f} s", f"{ref_steps / t / 1e3:.2f} k", f"{settings.reference_span_s / t:.3f}x",
                     "", ""))
    for name, t, t_ref in (("best", trial.best, ref.best), ("median", trial.median, ref.median)):
        speedup = (trial_steps / t) / (ref_steps / t_ref)
        rows.append((f"numba / solve_ivp steps/s ({name})", "", f"{speedup:.0f}x", "",
                     f">= {TARGET_SPEEDUP:.0f}x", verdict(speedup, TARGET_SPEEDUP)))
    return rows


def batch_rows(batches: list[BatchRun], n_trials: int, sim_s: float) -> list[tuple[str, ...]]:
    """Rows of the batch table: each way of running it, then the 2-core scalings."""
    rows = []
    for b in batches:
        for name, t in (("best", b.wall.best), ("median", b.wall.median)):
            rows.append((f"{b.label} ({name} of {len(b.wall.seconds)})", f"{t:.3f} s",
                         f"{n_trials / t:.1f}", f"{sim_s / t:.0f}", "", ""))
    one = batches[0].wall
    for b in batches[1:]:
        paired = statistics.median(map(truediv, one.seconds, b.wall.seconds))
        for name, scaling in (("best / best", one.best / b.wall.best), ("median of paired repeats", paired)):
            if b.label == "2 threads":
                target, mark = f">= {TARGET_SCALING:g}x", verdict(scaling, TARGET_SCALING)
            else:
                target, mark = "(no GIL)", ""
            rows.append((f"scaling {b.label} / 1 thread ({name})", "", "", f"{scaling:.2f}x", target, mark))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats, shorter spans")
    settings = QUICK if parser.parse_args().quick else FULL

    config = load_config(CONFIG_PATH)
    warmup = config.grid.warmup_revolutions
    rate_hz = config.model.controller.control_rate_hz
    simulator = Simulator(config.model, warmup)
    request = bench_request(config)
    print(f"numba {numba.__version__}, numpy {np.__version__}, scipy {scipy.__version__}; "
          f"{os.cpu_count()} CPUs")

    # 1. one core
    start = time.perf_counter()
    simulator.run_trial(request)  # JIT compile (or load from cache)
    jit_s = time.perf_counter() - start
    trial_sim_s = simulated_seconds(request, warmup)
    with foreign_load() as load_1, kernel_clock() as kernel_s:
        faults = minor_page_faults()
        trial = time_runs(lambda: simulator.run_trial(request), settings.trial_repeats)
        faults = minor_page_faults() - faults
    outside_share = 1.0 - sum(kernel_s) / sum(trial.seconds)

    # 2. against solve_ivp
    check = compare_with_kernel(config.model, request, settings.check_span_s)
    reference = SolveIvpDrive(config.model, request)
    with foreign_load() as load_2:
        ref = time_runs(lambda: reference.run(settings.reference_span_s), settings.reference_repeats)

    # 3. two cores
    grid = grid_requests(config, config.model.controller.calibration(), config.grid.seed,
                         config.grid.revolutions)[:settings.grid_trials]
    grid_sim_s = sum(simulated_seconds(r, warmup) for r in grid)
    with foreign_load() as load_3:
        batches = time_batches(simulator, grid, settings.grid_repeats)

    print(f"\ntrial: {TORQUE_NM:g} N m at {SPEED_HZ:g} Hz, multisine, {warmup}+{request.revolutions} "
          f"revolutions = {trial_sim_s:.2f} s simulated = {trial_sim_s * rate_hz:.0f} steps at "
          f"{rate_hz / 1e3:g} kHz; first call (JIT compile or cache load) {jit_s:.2f} s")
    print_table("1-2. one trial, one core",
                ("", "wall", "steps/s", "real time", "target", ""),
                one_core_rows(trial, ref, settings, trial_sim_s, rate_hz))
    print(f"other processes kept {load_1[0]:.2f} cores busy while timing numba{contended(load_1[0])}, "
          f"{load_2[0]:.2f} while timing solve_ivp{contended(load_2[0])}")
    print(f"run_trial outside the kernel (Python side, holds the GIL): {outside_share:.1%} of the wall "
          f"time, {outside_share * trial.median * 1e3:.2f} ms per trial; "
          f"{faults / settings.trial_repeats:.0f} minor page faults per trial (results dropped)")
    print(f"solve_ivp vs kernel, noiseless trial, {check.samples} samples over {check.span_s:g} s: "
          f"max |di| {check.current_a:.1e} A ({check.current_a / check.current_peak_a:.2%} of the peak), "
          f"max |domega| {check.speed_rad_s:.1e} rad/s "
          f"({check.speed_rad_s / check.speed_ripple_rad_s:.2%} of the peak-to-peak), "
          f"max |d time stamp| {check.time_s * 1e6:.0f} us")

    print_table(f"3. batch: {len(grid)} grid trials, {grid_sim_s:.1f} s simulated",
                ("", "wall", "trials/s", "sim s / s", "target", ""),
                batch_rows(batches, len(grid), grid_sim_s))
    for b in batches[:2]:
        print(f"{b.label}: kernel {b.kernel_s / len(grid) * 1e3:.2f} ms per trial (median; includes any "
              f"wait for the GIL on return); {b.page_faults / len(grid):.0f} minor page faults per trial "
              f"(results kept)")
    threads, processes = batches[1].wall.seconds, batches[2].wall.seconds
    print(f"2 threads / 2 processes wall time: {statistics.median(map(truediv, threads, processes)):.2f} "
          f"(median of paired repeats; the processes share no GIL and drop their results)")
    print(f"other processes kept {load_3[0]:.2f} cores busy during the batch measurements{contended(load_3[0])}")


if __name__ == "__main__":
    main()
