"""A rolling drive log of the simulated motor: a speed, position or current loop, logged at a fixed rate.

The drive commutates sine currents at the rotor's angle (field-oriented, i_d = 0): phase p carries
i_q sin(theta_e - 2 pi p / 3), theta_e = pole_pairs theta, the inverse Park transform the importer applies
to an i_q log (amplitude-invariant). Their torque is k_q(theta) i_q with

    k_q(theta) = sum_p K_p(theta) sin(theta_e - 2 pi p / 3),

K the true back-EMF ([bench.backemf] times [simulator.winding] backemf_scale); its mean over a revolution
is K_t = 3/2 times the fundamental (times the mean of 1 + asymmetry), and its ripple comes from the
back-EMF's harmonics and asymmetry, as the identification's sum_p K_p i_p sees it. The rotor follows

    J domega/dt = k_q(theta) i_q + tau_pos(theta) - (F + L) sign(omega)

at the control rate ([simulator.controller] control_rate_hz), semi-implicit Euler as the trial kernel
(`ilcpmac.sim.kernel`): tau_pos the cogging plus the position disturbance of [simulator.unexplained], J
the true inertia, F [simulator.mechanics] coulomb_friction_nm, L the plan's load. The model has no viscous
friction (b = 0), no saturation term here (c i^2 is below 1e-3 at the log's currents), and ideal current
sensors: the i_q flowing is the one logged, plus white noise. The current follows the loop's command as a
first-order lag of corner [simulator.controller] bandwidth_hz (a tuned PI current loop's closed loop).

The drive has an encoder of its own, of 2^encoder_bits lines per revolution (the plan's, independent of the
bench's counts_per_rev that the import resamples onto): the loop reads it at the control rate, and the log
holds it in rad, each reading the true angle rounded to the nearest line. The loop estimates the speed as the
line difference over one period low-passed by two first-order stages of corner 4 f_c. "speed": a PI on the
speed error, i_q = K_p e + K_p w_i int e, K_p = J* 2 pi f_c / K*_t
(J*, K*_t what the controller knows), w_i = 2 pi f_c / 4; "position": the same PI on the speed reference
omega* + 2 pi f_c / 5 (theta* - theta), theta* = omega* t; "current": i_q held at (F + L) / K*_t, the rotor
coasting at its start speed omega*. The loops start settled (the integrator at that current).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from ilcpmac.bench.fastcsv import format_rows
from ilcpmac.bench.logs import MAX_LOG_ROWS
from ilcpmac.core.errors import SimulationError
from ilcpmac.core.files import atomic_write
from ilcpmac.core.schema import in_range, shown
from ilcpmac.model.tables import q_axis
from ilcpmac.sim.simulator import OVERSAMPLE, Simulator

__all__ = ["LOOPS", "LogPlan", "drive_log", "torque_per_ampere", "write_drive_log"]

#: the loops a log's drive closes
LOOPS = ("speed", "position", "current")
#: corner of the speed estimate's two low-pass stages, and the integral and position loops' corners,
#: over the speed loop's bandwidth
_FILTER_RATIO, _INTEGRAL_RATIO, _POSITION_RATIO = 4.0, 0.25, 0.2


@dataclass(frozen=True)
class LogPlan:
    """A simulated rolling log.

    Attributes
    ----------
    rate_hz : float
        Rows per second, at most half the control rate.
    speed_hz : float
        Mechanical speed reference, Hz, within (0, 1e3].
    duration_s : float
        Within (0, 3600].
    loop : str
        "speed", "position" or "current".
    current_column : str
        "q" (i_q) or "phases" (i_a, i_b, i_c).
    jitter_s : float
        Each row's instant is (n + 1/2) / rate_hz plus a uniform draw within +-jitter_s, rounded to a control
        period; below half a row interval less one control period.
    load_nm : float
        L, a constant load against the motion (a brake), N m, >= 0.
    speed_bandwidth_hz : float
        f_c, the speed loop's crossover, Hz, at most control rate / 100.
    encoder_bits : int
        The drive's encoder, which its loop reads and its log holds: 2^encoder_bits lines per revolution,
        within [8, 24].
    seed : int
    """

    rate_hz: float = 1000.0
    speed_hz: float = 0.5
    duration_s: float = 10.0
    loop: str = "speed"
    current_column: str = "q"
    jitter_s: float = 0.0
    load_nm: float = 0.2
    speed_bandwidth_hz: float = 30.0
    encoder_bits: int = 20
    seed: int = 0

    def problem(self, simulator: Simulator) -> str | None:
        """The first value out of its range, as "name: why", or None."""
        control_hz = simulator.model.controller.control_rate_hz
        cpr = simulator.model.encoder.counts_per_rev
        checks = [("rate_hz", in_range(0.0, control_hz / 2, low_open=True)),
                  ("speed_hz", in_range(0.0, 1e3, low_open=True)),
                  ("duration_s", in_range(0.0, 3600.0, low_open=True)), ("load_nm", in_range(0.0, 1e4)),
                  ("speed_bandwidth_hz", in_range(0.0, control_hz / 100, low_open=True)),
                  ("encoder_bits", in_range(8, 24)),
                  ("seed", in_range(0, 2**63 - 1)),
                  ("jitter_s", lambda x: in_range(0.0, 0.5 / self.rate_hz - 1.0 / control_hz)(x))]
        for name, check in checks:  # in order: jitter_s's bound needs a valid rate_hz
            if not check(getattr(self, name)):
                return f"{name}: invalid value {shown(getattr(self, name))}"
        if self.loop not in LOOPS:
            return f"loop: one of {', '.join(LOOPS)}, got {shown(self.loop)}"
        if self.current_column not in ("q", "phases"):
            return f'current_column: "q" or "phases", got {shown(self.current_column)}'
        if self.speed_hz * cpr > control_hz / 2:
            return (f"speed_hz: {self.speed_hz:g} Hz x {cpr} counts per revolution is more than half the control "
                    f"rate {control_hz:g} Hz")
        if self.load_nm == 0 and simulator.model.mechanics.coulomb_friction_nm == 0:
            return ("load_nm: 0 without Coulomb friction: the drive then makes no mean torque, and a log needs one "
                    "in the direction of motion (its operating point)")
        if self.duration_s * self.rate_hz > MAX_LOG_ROWS:
            return f"duration_s: {self.duration_s:g} s x {self.rate_hz:g} Hz is more than a log's {MAX_LOG_ROWS} rows"
        return None


def torque_per_ampere(pole_pairs: int, backemf_nm_per_a: np.ndarray, rows_per_rev: int) -> np.ndarray:
    """k_q = sum_p K_p sin(theta_e - 2 pi p / 3), N m / A, of a back-EMF table whose row j is at the angle
    2 pi j / rows_per_rev."""
    theta_e = pole_pairs * 2.0 * np.pi * np.arange(backemf_nm_per_a.shape[0]) / rows_per_rev
    return np.sum(backemf_nm_per_a * q_axis(theta_e), axis=1)


@njit(cache=True)
def _roll(k_q_fine, torque_pos_fine, lines, steps, dt, inertia, friction_nm, omega_ref, loop,
          k_p, w_i, k_theta, a_filter, a_current, i_hold, row_steps, out_count, out_i_q):
    """Run ``steps`` control periods, the encoder of ``lines`` per revolution read as the nearest line; at step
    ``row_steps[n]`` write its reading (lines) and the flowing i_q to row n. ``loop``: 0 speed, 1 position,
    2 current. Returns the rows written."""
    n_fine = k_q_fine.size - 1
    two_pi = 2.0 * np.pi
    theta, omega, i_q, integral = 0.0, omega_ref, i_hold, i_hold
    speed_1, speed_2 = omega_ref, omega_ref
    count_before = 0
    row = 0
    for k in range(steps):
        count = math.floor(theta / two_pi * lines + 0.5)
        theta_m = count * two_pi / lines
        raw = omega_ref if k == 0 else (count - count_before) * two_pi / lines / dt
        count_before = count
        speed_1 += a_filter * (raw - speed_1)
        speed_2 += a_filter * (speed_1 - speed_2)
        if loop == 2:
            command = i_hold
        else:
            target = omega_ref
            if loop == 1:
                target += k_theta * (omega_ref * k * dt - theta_m)
            error = target - speed_2
            integral += k_p * w_i * dt * error
            command = k_p * error + integral
        i_q += a_current * (command - i_q)
        if row < row_steps.size and row_steps[row] == k:
            out_count[row] = count
            out_i_q[row] = i_q
            row += 1
        u = (theta / two_pi % 1.0) * n_fine
        base = min(int(u), n_fine - 1)
        frac = u - base
        k_q = (1.0 - frac) * k_q_fine[base] + frac * k_q_fine[base + 1]
        torque_pos = (1.0 - frac) * torque_pos_fine[base] + frac * torque_pos_fine[base + 1]
        torque = k_q * i_q + torque_pos - friction_nm * (1.0 if omega > 0 else -1.0 if omega < 0 else 0.0)
        omega += dt * torque / inertia
        theta += dt * omega
    return row


def drive_log(simulator: Simulator, plan: LogPlan) -> tuple[dict[str, np.ndarray], dict]:
    """The log's columns (time s, position rad, unwrapped, in whole lines of the plan's encoder; i_q or i_a..i_c,
    A) and its truth (`write_drive_log` lists the keys)."""
    problem = plan.problem(simulator)
    if problem is not None:
        raise SimulationError(f"log plan {problem}")
    m = simulator.model
    cpr = m.encoder.counts_per_rev
    control_hz = m.controller.control_rate_hz
    dt = 1.0 / control_hz
    rng = np.random.default_rng(plan.seed)
    rows = int(plan.duration_s * plan.rate_hz)
    instants = (np.arange(rows) + 0.5) / plan.rate_hz + rng.uniform(-plan.jitter_s, plan.jitter_s, rows)
    row_steps = np.round(instants * control_hz).astype(np.int64)
    pole_pairs = m.winding.pole_pairs
    k_q_fine = np.ascontiguousarray(torque_per_ampere(pole_pairs, simulator.fine[:, :3], cpr * OVERSAMPLE))
    k_t_true = float(k_q_fine[:-1].mean())
    k_t_known = float(torque_per_ampere(pole_pairs, simulator.backemf_counts, cpr).mean())
    hold_nm = m.mechanics.coulomb_friction_nm + plan.load_nm
    w_c = 2.0 * np.pi * plan.speed_bandwidth_hz
    k_p = m.mechanics.inertia_kgm2 * w_c / k_t_known
    count, i_q = np.zeros(rows, np.int64), np.zeros(rows)
    lines = 2**plan.encoder_bits
    written = _roll(k_q_fine, np.ascontiguousarray(simulator.fine[:, 3]), lines, int(row_steps[-1]) + 1, dt,
                    m.mechanics.true_inertia_kgm2, hold_nm, 2.0 * np.pi * plan.speed_hz, LOOPS.index(plan.loop),
                    k_p, _INTEGRAL_RATIO * w_c, _POSITION_RATIO * w_c, 1.0 - math.exp(-_FILTER_RATIO * w_c * dt),
                    1.0 - math.exp(-2.0 * np.pi * m.controller.bandwidth_hz * dt), hold_nm / k_t_known, row_steps,
                    count, i_q)
    if written != rows:
        raise SimulationError(f"the log wrote {written} of its {rows} rows")
    sigma_a = m.current_sensors.noise_counts / float(np.mean(m.controller.calibration().current_scale))
    columns = {"time": row_steps * dt, "position": count * (2.0 * np.pi / lines)}
    if plan.current_column == "q":
        columns["i_q"] = i_q + sigma_a * math.sqrt(2.0 / 3.0) * rng.standard_normal(rows)
    else:
        theta_e = m.winding.pole_pairs * columns["position"]
        phases = i_q[:, None] * q_axis(theta_e) + sigma_a * rng.standard_normal((rows, 3))
        columns.update({"i_a": phases[:, 0], "i_b": phases[:, 1], "i_c": phases[:, 2]})
    counts = list(range(cpr))
    truth = {"torque_constant_nm_per_a": k_t_true,
             "torque_per_ampere": {"count": counts, "nm_per_a": k_q_fine[:-1:OVERSAMPLE].tolist()},
             "cogging": {"count": counts, "torque": simulator.cogging_counts().tolist()},
             "position_torque": {"count": counts, "torque": simulator.torque_pos_fine[::OVERSAMPLE].tolist()},
             "coulomb_friction_nm": m.mechanics.coulomb_friction_nm, "load_nm": plan.load_nm,
             "viscous_friction_nm_s_per_rad": 0.0, "inertia_kgm2": m.mechanics.true_inertia_kgm2,
             "current_noise_a": sigma_a, "current_loop_bandwidth_hz": m.controller.bandwidth_hz,
             "control_rate_hz": control_hz,
             "speed_loop": {"loop": plan.loop, "bandwidth_hz": plan.speed_bandwidth_hz, "k_p_a_s_per_rad": k_p,
                            "integral_corner_rad_per_s": _INTEGRAL_RATIO * w_c,
                            "position_gain_per_s": _POSITION_RATIO * w_c,
                            "filter_corner_rad_per_s": _FILTER_RATIO * w_c}}
    return columns, truth


def write_drive_log(path: str | Path, simulator: Simulator, plan: LogPlan) -> dict:
    """Write `drive_log`'s columns as a CSV log (header ``time,position,i_q`` or ``time,position,i_a,i_b,i_c``),
    atomically (`atomic_write`: a full disk leaves no part of it, and its error names it); returns the truth.

    Truth keys: ``torque_constant_nm_per_a`` K_t (mean of k_q), ``torque_per_ampere`` k_q per count,
    ``cogging`` and ``position_torque`` (cogging plus the position disturbance) per count under the result keys
    ({"count", "torque"}), ``coulomb_friction_nm`` F, ``load_nm`` L, ``viscous_friction_nm_s_per_rad`` (0),
    ``inertia_kgm2`` the true J, ``current_noise_a`` (per phase, RMS), ``current_loop_bandwidth_hz``,
    ``control_rate_hz`` and ``speed_loop`` (the loop and its gains).
    """
    columns, truth = drive_log(simulator, plan)
    decimals = {"time": 7, "position": 9}
    values = np.column_stack(list(columns.values()))
    body = format_rows(values, np.array([decimals.get(name, 6) for name in columns]))
    atomic_write(Path(path), ",".join(columns).encode() + b"\n" + body)
    return truth
