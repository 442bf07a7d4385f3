"""A rolling drive log of the simulated motor: a speed, position or current loop, polled by a host.

The drive commutates sine currents at its encoder's reading of the rotor's angle (field-oriented, i_d = 0):
phase p carries i_q sin(theta_e^ - 2 pi p / 3), theta_e^ = pole_pairs theta^, the inverse Park transform the
importer applies to an i_q log (amplitude-invariant). Their torque is i_q times

    k(theta, delta) = sum_p K_p(theta) sin(theta_e + delta - 2 pi p / 3) = k_q(theta) cos delta + k_d(theta) sin delta,

delta = pole_pairs (theta^ - theta) the commutation's error, k_q and k_d the q- and d-axis torque per ampere of
K, the true back-EMF ([bench.backemf] times [simulator.winding] backemf_scale); k_q's mean over a revolution
is K_t = 3/2 times the fundamental (times the mean of 1 + asymmetry), and its ripple comes from the back-EMF's
harmonics and asymmetry, as the identification's sum_p K_p i_p sees it. The rotor follows

    J domega/dt = k(theta, delta) i_q + tau_pos(theta) - D sign(omega),   D = F + L,

at the control rate ([simulator.controller] control_rate_hz), semi-implicit Euler as the trial kernel
(`ilcpmac.sim.kernel`): tau_pos the cogging plus the position disturbance of [simulator.unexplained], J the
true inertia, F [simulator.mechanics] coulomb_friction_nm, L the plan's load. D is dry friction, static as
kinetic: a rotor at rest stays at rest while |k i_q + tau_pos| <= D, and a step that would carry omega through
zero ends at rest instead, the next step deciding whether it sticks or starts the other way: a soft loop on a
cogging motor stops, runs back and breaks away (stick-slip) as a real one does. The model has no viscous
friction (b = 0), no saturation term here (c i^2 is below 1e-3 at the log's currents), and ideal current
sensors: the i_q flowing is the one logged, plus white noise. The current follows the loop's command as a
first-order lag of corner [simulator.controller] bandwidth_hz (a tuned PI current loop's closed loop).

The drive has an encoder of its own, of 2^encoder_bits lines per revolution (the plan's, independent of the
bench's counts_per_rev that the import resamples onto), read once per control period, as a magnetic encoder
is (no capture of the instant a line is crossed): its reading is theta^ = 2 pi c / 2^bits, c the line whose
span holds x = theta 2^bits / (2 pi) + e(theta), the true angle plus the position-locked error

    e(theta) = E sin(theta + phi_1) + sum_k A_k sin(k theta + phi_k)   (lines of the drive's encoder),

E the eccentricity (once per revolution), A_k the nonlinearity's harmonics k >= 2 of a magnetic encoder; line c
spans [c - 1/2 + s_c, c + 1/2 + s_(c+1)), s_c a uniform draw within +-encoder_line_error_counts per line
(`_line_shift`; 0: each line's span is nominal, x rounded to the nearest line). The loop estimates the speed
as the reading's difference over one period low-passed by two first-order stages of corner 4 f_c.
"speed": a PI on the speed error, i_q = K_p e + K_p w_i int e, K_p = J* 2 pi f_c / K*_t
(J*, K*_t what the controller knows), w_i = 2 pi f_c / 4; "position": the same PI on the speed reference
omega* + 2 pi f_c / 5 (theta* - theta^), theta* = omega* t; "current": i_q held at (F + L) / K*_t, the rotor
coasting at its start speed omega*. The loops start settled (the integrator at that current).

A host polls the drive: request n at (n + 1/2) / rate_hz plus a uniform draw within +-jitter_s, the requests
in time order, each on a control period; the drive answers with the reading and i_q of the control period a
transit later (a uniform draw within [0, latency_s], never before the answer to the request before); the host
stamps its request with its clock, in whole ticks of stamp_s (floor; 0: exact), and a row whose stamp does
not pass the one before is left out (a clock coarser than the polling). What the model needs of the control
rate: STEPS_PER_PERIOD control periods per period of the fastest term the tables hold at the log's speed
(`highest_order`): semi-implicit Euler moves the response to a term of Omega by (Omega dt)^2 / 12, 0.8 % at
most there; the tables themselves hold 16 points per [bench] count, 32 per period of an order within its
Nyquist limit (interpolated linearly: within 0.5 %). Nothing ties the speed to either encoder's lines.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Callable

import numpy as np
from numba import njit, uint64

from ilcpmac.bench.fastcsv import format_rows
from ilcpmac.bench.format import MAX_TIMER_RESOLUTION_S
from ilcpmac.bench.logs import MAX_LOG_ROWS
from ilcpmac.core.errors import SimulationError
from ilcpmac.core.files import atomic_write
from ilcpmac.core.schema import in_range, setting, value_problem
from ilcpmac.model.motor import MotorModel
from ilcpmac.model.tables import q_axis
from ilcpmac.sim.simulator import OVERSAMPLE, Simulator

__all__ = ["LOOPS", "POSITION_UNITS", "STEPS_PER_PERIOD", "DriveLog", "LogPlan", "current_noise_a",
           "current_torque_per_ampere", "drive_log", "drive_tables", "encoder_terms", "fine_point", "highest_order",
           "known_torque_constant", "position_torque", "read_encoder", "rotor_speed", "torque_per_ampere",
           "write_drive_log"]

#: the loops a log's drive closes
LOOPS = ("speed", "position", "current")
#: the units a log's position may come in
POSITION_UNITS = ("rad", "counts")
#: control periods per period of the fastest position-locked term, at least (the module's docstring says why)
STEPS_PER_PERIOD = 20
#: most terms, and the highest order, of the drive encoder's error harmonics
MAX_ENCODER_TERMS, MAX_ENCODER_ORDER = 16, 256
#: the largest host jitter and transit, s
MAX_HOST_DELAY_S = 0.01
#: corner of the speed estimate's two low-pass stages, and the integral and position loops' corners,
#: over the speed loop's bandwidth
_FILTER_RATIO, _INTEGRAL_RATIO, _POSITION_RATIO = 4.0, 0.25, 0.2
#: a stamp this close below a whole tick (of the tick) is that tick: a control period's instant k dt rounds
_TICK_ROUNDING = 1e-6
#: splitmix64's constants (Steele, Lea, Flood 2014)
_GOLDEN, _MIX_1, _MIX_2 = uint64(0x9E3779B97F4A7C15), uint64(0xBF58476D1CE4E5B9), uint64(0x94D049BB133111EB)


def encoder_terms(spec: object) -> tuple[tuple[int, float, float], ...] | None:
    """The error harmonics ``"ORDER:LINES[:PHASE_RAD],..."`` (e.g. ``"2:0.3,3:0.1:1.2"``) as (order, amplitude in
    lines, phase in rad) terms, or None when ``spec`` is not that: orders distinct within 2..`MAX_ENCODER_ORDER`,
    amplitudes within [0, 2^22], phases within [-2 pi, 2 pi] (0 if left out), at most `MAX_ENCODER_TERMS`;
    "" is none."""
    if not isinstance(spec, str):
        return None
    if not spec.strip():
        return ()
    terms = []
    for part in spec.split(","):
        values = part.split(":")
        if len(values) not in (2, 3):
            return None
        try:
            term = (int(values[0]), float(values[1]), float(values[2]) if len(values) == 3 else 0.0)
        except ValueError:
            return None
        if not (in_range(2, MAX_ENCODER_ORDER)(term[0]) and in_range(0.0, 2.0**22)(term[1])
                and in_range(-2 * math.pi, 2 * math.pi)(term[2])):
            return None
        terms.append(term)
    orders = [term[0] for term in terms]
    return tuple(terms) if len(terms) <= MAX_ENCODER_TERMS and len(set(orders)) == len(orders) else None


@dataclass(frozen=True)
class LogPlan:
    """A simulated rolling log: the drive, its loop, its encoder, and the host that polls it (the module's
    docstring states the model). Each field's doc states its range; `problem` checks them and those that
    depend on the simulated motor."""

    rate_hz: float = setting(in_range(0.0, 1e6, low_open=True), "rows per second, Hz, at most half the control "
                             "rate", 1000.0)
    speed_hz: float = setting(in_range(0.0, 1e3, low_open=True), "mechanical speed reference, Hz, within (0, 1e3]",
                              0.5)
    duration_s: float = setting(in_range(0.0, 3600.0, low_open=True), "s, within (0, 3600]", 10.0)
    loop: str = setting(lambda x: x in LOOPS, f"the loop the drive closes: {', '.join(LOOPS)}", "speed")
    current_column: str = setting(lambda x: x in ("q", "phases"), '"q" (i_q) or "phases" (i_a, i_b, i_c)', "q")
    jitter_s: float = setting(in_range(0.0, MAX_HOST_DELAY_S), "each request drawn uniformly within +-jitter_s of "
                              f"its slot (n + 1/2) / rate_hz, s, within [0, {MAX_HOST_DELAY_S:g}]", 0.0)
    latency_s: float = setting(in_range(0.0, MAX_HOST_DELAY_S), "the drive's reading a uniform draw within "
                               f"[0, latency_s] after the stamped request, s, within [0, {MAX_HOST_DELAY_S:g}]", 0.0)
    stamp_s: float = setting(in_range(0.0, MAX_TIMER_RESOLUTION_S), "the host clock's tick, s, within "
                             f"[0, {MAX_TIMER_RESOLUTION_S:g}] (0: stamps exact to a control period)", 0.0)
    position_unit: str = setting(lambda x: x in POSITION_UNITS, 'the position logged in "rad" or in "counts" '
                                 "(lines of the drive's encoder)", "rad")
    position_wrap: bool = setting(lambda x: isinstance(x, bool), "the position wrapped into one revolution, "
                                  "[0, 2 pi) or [0, 2^encoder_bits), as a count_in_cpr column; else multi-turn",
                                  False)
    load_nm: float = setting(in_range(0.0, 1e4), "L, a constant load against the motion (a brake), N m, within "
                             "[0, 1e4]", 0.2)
    speed_bandwidth_hz: float = setting(in_range(0.0, 1e4, low_open=True), "f_c, the speed loop's crossover, Hz, "
                                        "at most the control rate / 100", 30.0)
    encoder_bits: int = setting(in_range(8, 24), "the drive's encoder, which its loop reads and its log holds: "
                                "2^encoder_bits lines per revolution, within [8, 24]", 20)
    encoder_eccentricity_counts: float = setting(in_range(0.0, 2.0**22), "E, the drive encoder's once-per-"
                                                 "revolution error, lines, within [0, 2^22]", 0.0)
    encoder_eccentricity_phase_rad: float = setting(in_range(-2 * math.pi, 2 * math.pi), "phi_1, its phase at "
                                                    "angle 0, rad, within [-2 pi, 2 pi]", 0.0)
    encoder_harmonics: str = setting(lambda x: encoder_terms(x) is not None, "the drive encoder's error harmonics "
                                     f'"ORDER:LINES[:PHASE_RAD],...", orders 2..{MAX_ENCODER_ORDER} distinct, '
                                     "amplitudes within [0, 2^22], phases within [-2 pi, 2 pi], at most "
                                     f"{MAX_ENCODER_TERMS} terms", "")
    encoder_line_error_counts: float = setting(in_range(0.0, 0.5, high_open=True), "each line's span shifted by a "
                                               "uniform draw within +-this, lines, within [0, 0.5)", 0.0)
    encoder_seed: int = setting(in_range(0, 2**63 - 1), "seed of the lines' errors: the same encoder in every log "
                                "of that seed", 0)
    seed: int = setting(in_range(0, 2**63 - 1), "seed of the host's polling and the currents' noise", 0)

    def encoder_error_counts(self, angle_rad: np.ndarray) -> np.ndarray:
        """e(theta), the drive encoder's reading less the true angle before its lines' errors and rounding,
        lines, at ``angle_rad``."""
        error = self.encoder_eccentricity_counts * np.sin(angle_rad + self.encoder_eccentricity_phase_rad)
        for order, amplitude, phase in encoder_terms(self.encoder_harmonics) or ():
            error = error + amplitude * np.sin(order * angle_rad + phase)
        return error

    def problem(self, simulator: Simulator) -> str | None:
        """The first value out of its range, as "name: why", or None."""
        for f in fields(self):
            problem = value_problem(f, getattr(self, f.name))
            if problem is not None:
                return problem
        m = simulator.model
        control_hz = m.controller.control_rate_hz
        if self.rate_hz > control_hz / 2:
            return f"rate_hz: {self.rate_hz:g} Hz is more than half the control rate {control_hz:g} Hz"
        if self.speed_bandwidth_hz > control_hz / 100:
            return (f"speed_bandwidth_hz: {self.speed_bandwidth_hz:g} Hz is more than the control rate / 100 = "
                    f"{control_hz / 100:g} Hz")
        terms = encoder_terms(self.encoder_harmonics) or ()
        cpr = m.encoder.counts_per_rev
        beyond = [order for order, _, _ in terms if order >= cpr // 2]
        if beyond:
            return (f"encoder_harmonics: order {beyond[0]} is beyond the Nyquist limit of [bench] counts_per_rev "
                    f"{cpr}, on which the simulator tabulates e(theta)")
        slope = self.encoder_eccentricity_counts + sum(order * amplitude for order, amplitude, _ in terms)
        if slope > 2**self.encoder_bits / (4 * math.pi):
            name = "encoder_harmonics" if terms else "encoder_eccentricity_counts"
            return (f"{name}: the error's slope E + sum k A_k = {slope:.4g} lines per rad is more than "
                    f"2^encoder_bits / (4 pi) = {2**self.encoder_bits / (4 * math.pi):.4g}: the reading would not "
                    "keep rising with the angle")
        order = highest_order(m, self)
        if self.speed_hz * order * STEPS_PER_PERIOD > control_hz:
            return (f"speed_hz: {self.speed_hz:g} Hz x the tables' highest order {order} is more than the control "
                    f"rate / {STEPS_PER_PERIOD} = {control_hz / STEPS_PER_PERIOD:g} Hz (each period of the fastest "
                    f"position-locked term needs {STEPS_PER_PERIOD} control periods)")
        if self.load_nm == 0 and m.mechanics.coulomb_friction_nm == 0:
            return ("load_nm: 0 without Coulomb friction: the drive then makes no mean torque, and a log needs one "
                    "in the direction of motion (its operating point)")
        rows = int(self.duration_s * self.rate_hz)
        if not 2 <= rows <= MAX_LOG_ROWS:
            return (f"duration_s: {self.duration_s:g} s x {self.rate_hz:g} Hz is {rows} rows, not within a log's "
                    f"2..{MAX_LOG_ROWS}")
        return None


def highest_order(model: MotorModel, plan: LogPlan) -> int:
    """The highest mechanical order of the log's position-locked terms: the torque per ampere's ((largest
    back-EMF harmonic + 1) x pole pairs), the cogging's, the disturbance's and the drive encoder's error's."""
    w = model.winding
    return max((max(model.backemf.harmonics) + 1) * w.pole_pairs,
               *(multiple * w.cogging_order for multiple in model.cogging.multiples), *model.unexplained.orders,
               *(order for order, _, _ in encoder_terms(plan.encoder_harmonics) or ()))


def torque_per_ampere(pole_pairs: int, backemf_nm_per_a: np.ndarray, rows_per_rev: int,
                      lead_rad: float = 0.0) -> np.ndarray:
    """sum_p K_p sin(theta_e + lead_rad - 2 pi p / 3), N m / A, of a back-EMF table whose row j is at the angle
    2 pi j / rows_per_rev: k_q (lead 0), or k_d (lead pi / 2)."""
    theta_e = pole_pairs * 2.0 * np.pi * np.arange(backemf_nm_per_a.shape[0]) / rows_per_rev + lead_rad
    return np.sum(backemf_nm_per_a * q_axis(theta_e), axis=1)


@dataclass(frozen=True)
class DriveLog:
    """A simulated rolling log: its ``columns`` as the CSV holds them, by name; its ``truth`` (`write_drive_log`
    lists the keys); and what no log holds, the rotor's true angle at each row, ``angle_rad``."""

    columns: dict[str, np.ndarray]
    truth: dict
    angle_rad: np.ndarray


@njit(cache=True, inline="always")
def _line_shift(line, lines, seed, amplitude):
    """s_c of line ``line``: a uniform draw within +-``amplitude`` from splitmix64 of the seed and the line
    within its revolution (the same line, the same draw, in every revolution and log)."""
    z = uint64(line % lines) + uint64(seed) * _GOLDEN
    z = (z ^ (z >> uint64(30))) * _MIX_1
    z = (z ^ (z >> uint64(27))) * _MIX_2
    z ^= z >> uint64(31)
    return amplitude * ((z >> uint64(11)) * 2.0**-52 - 1.0)


@njit(cache=True, inline="always")
def _at(tables, base, frac, column):
    return (1.0 - frac) * tables[base, column] + frac * tables[base + 1, column]


@njit(cache=True, inline="always")
def fine_point(theta, n_fine):
    """The row of a revolution's table of ``n_fine`` rows below the angle ``theta`` (rad, any turn) and the
    fraction of a row beyond it."""
    u = (theta / (2.0 * np.pi) % 1.0) * n_fine
    base = min(int(u), n_fine - 1)
    return base, u - base


@njit(cache=True, inline="always")
def read_encoder(theta, tables, base, frac, lines, line_error, encoder_seed):
    """The drive encoder's line (multi-turn) at the true angle ``theta``: the line whose span holds the angle plus
    e(theta) (``tables`` column 3, at `fine_point` ``base``, ``frac``)."""
    x = theta / (2.0 * np.pi) * lines + _at(tables, base, frac, 3)
    count = math.floor(x + 0.5)
    if line_error > 0.0:
        if x < count - 0.5 + _line_shift(count, lines, encoder_seed, line_error):
            count -= 1
        elif x >= count + 0.5 + _line_shift(count + 1, lines, encoder_seed, line_error):
            count += 1
    return count


@njit(cache=True, inline="always")
def current_torque_per_ampere(tables, base, frac, delta):
    """k(theta, delta) = k_q cos delta + k_d sin delta, N m / A, at `fine_point` ``base``, ``frac``."""
    return math.cos(delta) * _at(tables, base, frac, 0) + math.sin(delta) * _at(tables, base, frac, 1)


@njit(cache=True, inline="always")
def position_torque(tables, base, frac):
    """tau_pos, N m, at `fine_point` ``base``, ``frac``."""
    return _at(tables, base, frac, 2)


@njit(cache=True, inline="always")
def rotor_speed(omega, applied_nm, dry_nm, dt, inertia):
    """The rotor's speed a period ``dt`` after ``omega`` under ``applied_nm`` and dry friction ``dry_nm``, static
    as kinetic (the module's docstring)."""
    if omega == 0.0:
        if abs(applied_nm) > dry_nm:
            return dt * (applied_nm - math.copysign(dry_nm, applied_nm)) / inertia
        return 0.0
    direction = 1.0 if omega > 0.0 else -1.0
    after = omega + dt * (applied_nm - dry_nm * direction) / inertia
    return after if after * direction > 0.0 else 0.0


@njit(cache=True)
def _roll(tables, lines, line_error, encoder_seed, pole_pairs, steps, dt, inertia, dry_nm, omega_ref, loop,
          k_p, w_i, k_theta, a_filter, a_current, i_hold, read_steps, out_count, out_i_q, out_angle):
    """Run ``steps`` control periods; at each step of ``read_steps`` (non-decreasing) write the encoder's
    reading (lines), the flowing i_q and the true angle to the next row. ``tables`` (`drive_tables`). ``loop``:
    0 speed, 1 position, 2 current. Returns the rows written."""
    n_fine = tables.shape[0] - 1
    two_pi = 2.0 * np.pi
    theta, omega, i_q, integral = 0.0, omega_ref, i_hold, i_hold
    speed_1, speed_2 = omega_ref, omega_ref
    count_before = 0
    row = 0
    for k in range(steps):
        base, frac = fine_point(theta, n_fine)
        count = read_encoder(theta, tables, base, frac, lines, line_error, encoder_seed)
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
        while row < read_steps.size and read_steps[row] == k:
            out_count[row] = count
            out_i_q[row] = i_q
            out_angle[row] = theta
            row += 1
        k_q = current_torque_per_ampere(tables, base, frac, pole_pairs * (theta_m - theta))
        omega = rotor_speed(omega, k_q * i_q + position_torque(tables, base, frac), dry_nm, dt, inertia)
        theta += dt * omega
    return row


def drive_tables(simulator: Simulator, encoder_error_lines: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """The rolling kernels' tables, n + 1 rows over a revolution (the first repeated last, n the simulator's
    fine rows): k_q, k_d (N m / A), tau_pos (N m), and e(theta) = ``encoder_error_lines(angle_rad)`` (lines)."""
    m = simulator.model
    n_fine = m.encoder.counts_per_rev * OVERSAMPLE
    pole_pairs = m.winding.pole_pairs
    return np.ascontiguousarray(np.column_stack([
        torque_per_ampere(pole_pairs, simulator.fine[:, :3], n_fine),
        torque_per_ampere(pole_pairs, simulator.fine[:, :3], n_fine, math.pi / 2), simulator.fine[:, 3],
        encoder_error_lines(2.0 * np.pi * np.arange(n_fine + 1) / n_fine)]))


def known_torque_constant(simulator: Simulator) -> float:
    """K*_t, the mean of k_q the controller knows (its back-EMF table, without backemf_scale), N m / A."""
    m = simulator.model
    return float(torque_per_ampere(m.winding.pole_pairs, simulator.backemf_counts, m.encoder.counts_per_rev).mean())


def current_noise_a(model: MotorModel) -> float:
    """The white noise of a phase current's reading, A RMS ([simulator.current_sensors] noise_counts over the
    mean current scale); an i_q reading's is sqrt(2/3) of it."""
    return model.current_sensors.noise_counts / float(np.mean(model.controller.calibration().current_scale))


def _host(plan: LogPlan, control_hz: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, int]:
    """The control periods the drive reads each row at, the rows' stamps (s), and the rows left out for a stamp
    that does not pass the one before."""
    dt = 1.0 / control_hz
    rows = int(plan.duration_s * plan.rate_hz)
    instants = (np.arange(rows) + 0.5) / plan.rate_hz + rng.uniform(-plan.jitter_s, plan.jitter_s, rows)
    asked = np.sort(np.round(np.maximum(instants, 0.0) * control_hz).astype(np.int64))
    read = asked
    if plan.latency_s > 0:
        transit = np.round(rng.uniform(0.0, plan.latency_s, rows) * control_hz).astype(np.int64)
        read = np.maximum.accumulate(asked + transit)
    stamps = asked * dt if plan.stamp_s == 0 else np.floor(asked * dt / plan.stamp_s + _TICK_ROUNDING) * plan.stamp_s
    kept = np.concatenate(([True], np.diff(stamps) > 0))
    return read[kept], stamps[kept], rows - int(kept.sum())


def drive_log(simulator: Simulator, plan: LogPlan) -> DriveLog:
    """The log's columns (time s; position in rad or lines of the plan's encoder, multi-turn or wrapped; i_q or
    i_a..i_c, A), its truth and the true angle at each row."""
    problem = plan.problem(simulator)
    if problem is not None:
        raise SimulationError(f"log plan {problem}")
    m = simulator.model
    cpr = m.encoder.counts_per_rev
    control_hz = m.controller.control_rate_hz
    dt = 1.0 / control_hz
    rng = np.random.default_rng(plan.seed)
    read_steps, stamps, left_out = _host(plan, control_hz, rng)
    rows = read_steps.size
    pole_pairs = m.winding.pole_pairs
    tables = drive_tables(simulator, plan.encoder_error_counts)
    k_q_fine = tables[:, 0]
    k_t_true = float(k_q_fine[:-1].mean())
    k_t_known = known_torque_constant(simulator)
    hold_nm = m.mechanics.coulomb_friction_nm + plan.load_nm
    w_c = 2.0 * np.pi * plan.speed_bandwidth_hz
    k_p = m.mechanics.inertia_kgm2 * w_c / k_t_known
    count, i_q, angle = np.zeros(rows, np.int64), np.zeros(rows), np.zeros(rows)
    lines = 2**plan.encoder_bits
    a_current = 1.0 - math.exp(-2.0 * np.pi * m.controller.bandwidth_hz * dt)
    written = _roll(tables, lines, plan.encoder_line_error_counts, plan.encoder_seed, pole_pairs,
                    int(read_steps[-1]) + 1, dt, m.mechanics.true_inertia_kgm2, hold_nm, 2.0 * np.pi * plan.speed_hz,
                    LOOPS.index(plan.loop), k_p, _INTEGRAL_RATIO * w_c, _POSITION_RATIO * w_c,
                    1.0 - math.exp(-_FILTER_RATIO * w_c * dt), a_current, hold_nm / k_t_known, read_steps, count, i_q,
                    angle)
    if written != rows:
        raise SimulationError(f"the log wrote {written} of its {rows} rows")
    sigma_a = current_noise_a(m)
    reading_rad = count * (2.0 * np.pi / lines)
    position = np.mod(count, lines) if plan.position_wrap else count
    columns = {"time": stamps, "position": position * (2.0 * np.pi / lines) if plan.position_unit == "rad"
               else position.astype(np.float64)}
    if plan.current_column == "q":
        columns["i_q"] = i_q + sigma_a * math.sqrt(2.0 / 3.0) * rng.standard_normal(rows)
    else:
        phases = i_q[:, None] * q_axis(pole_pairs * reading_rad) + sigma_a * rng.standard_normal((rows, 3))
        columns.update({"i_a": phases[:, 0], "i_b": phases[:, 1], "i_c": phases[:, 2]})
    counts = list(range(cpr))
    error = plan.encoder_error_counts(2.0 * np.pi * np.arange(cpr) / cpr)
    terms = encoder_terms(plan.encoder_harmonics) or ()
    step = np.diff(angle)
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
                            "filter_corner_rad_per_s": _FILTER_RATIO * w_c},
             "motion": {"rows_backwards": int(np.sum(step < 0)), "rows_still": int(np.sum(step == 0))},
             "host": {"rows": rows, "rows_left_out": left_out, "jitter_s": plan.jitter_s,
                      "latency_s": plan.latency_s, "stamp_s": plan.stamp_s},
             "drive_encoder": {"bits": plan.encoder_bits, "lines": lines,
                               "eccentricity_counts": plan.encoder_eccentricity_counts,
                               "eccentricity_phase_rad": plan.encoder_eccentricity_phase_rad,
                               "harmonics": {"orders": [t[0] for t in terms], "counts": [t[1] for t in terms],
                                             "phases_rad": [t[2] for t in terms]},
                               "line_error_counts": plan.encoder_line_error_counts, "seed": plan.encoder_seed,
                               "error": {"count": counts, "drive_counts": error.tolist(),
                                         "bench_counts": (error * cpr / lines).tolist()}}}
    return DriveLog(columns, truth, angle)


def write_drive_log(path: str | Path, simulator: Simulator, plan: LogPlan) -> dict:
    """Write `drive_log`'s columns as a CSV log (header ``time,position,i_q`` or ``time,position,i_a,i_b,i_c``),
    atomically (`atomic_write`: a full disk leaves no part of it, and its error names it); returns the truth.

    Truth keys: ``torque_constant_nm_per_a`` K_t (mean of k_q), ``torque_per_ampere`` k_q per count,
    ``cogging`` and ``position_torque`` (cogging plus the position disturbance) per count under the result keys
    ({"count", "torque"}), ``coulomb_friction_nm`` F, ``load_nm`` L, ``viscous_friction_nm_s_per_rad`` (0),
    ``inertia_kgm2`` the true J, ``current_noise_a`` (per phase, RMS), ``current_loop_bandwidth_hz``,
    ``control_rate_hz``, ``speed_loop`` (the loop and its gains), ``motion`` (rows whose true angle fell,
    ``rows_backwards``, or stayed, ``rows_still``), ``host`` (the rows written and left out, the jitter, transit
    and tick) and ``drive_encoder`` (its bits, lines, error terms, line errors and seed, and ``error``: e(theta)
    at each [bench] count, in lines of the drive's encoder, ``drive_counts``, and in [bench] counts,
    ``bench_counts``).
    """
    log = drive_log(simulator, plan)
    decimals = {"time": 7, "position": 9 if plan.position_unit == "rad" else 0}
    values = np.column_stack(list(log.columns.values()))
    body = format_rows(values, np.array([decimals.get(name, 6) for name in log.columns]))
    atomic_write(Path(path), ",".join(log.columns).encode() + b"\n" + body)
    return log.truth
