"""An emulated moteus-class drive: the rolling drive of `ilcpmac.sim.drive_log` made stateful and chunked,
configured, commanded and polled as a moteus is (docs/simulator.md, "An emulated moteus").

The motor is a config's `MotorModel` as `drive_log` has it (k(theta, delta) i_q + tau_pos, dry friction, the
current a first-order lag of [simulator.controller] bandwidth_hz on its command); the drive reads its magnetic
encoder (2^encoder_bits lines, once-per-revolution eccentricity) once per control period and commutates and
indexes its cogging table at that reading. Each period, in position mode (moteus's mode 10):

    control += v dt                          (the control position; a NaN position leaves it where it is,
                                              entering the mode it starts at the reading)
    torque = clamp(kp (control - reading) + kd (v - v^) + feedforward, +-max_torque)
    q = clamp(torque / K*_t, +-limit)        (limit servo.max_current_A, derated to 0 over
                                              servo.max_velocity_derate beyond servo.max_velocity as the firmware
                                              does; fault register 99 or 96 while it limits, the mode unchanged)
    q_comp = the table at the commutation position p = reading / 2^encoder_bits mod 1, as fw/bldc_servo_control.h:
             left = min(N - 1, int(N p)), right = (left + 1) mod N, frac = (p - left / N) N,
             (table[right] - table[left]) frac + table[left], table[k] = motor.cogging_dq_comp.k x cogging_dq_scale
    i_q* = q + q_comp                        (the firmware adds the table after its limit)

v^ the reading's difference over a period through two first-order stages of corner velocity_filter_hz; kp, kd
(servo.pid_position, N m per rev and per rev/s) J w^2 and 2 J w, w = 2 pi velocity_bandwidth_hz, J the
controller's inertia. Stopped (0), timed out (11) or faulted (1), i_q* = 0 and the rotor coasts to rest under
friction; a position command leaves mode 11 or 1 only after a stop. The watchdog: a position command not renewed
within its watchdog_timeout_s (0: servo.default_timeout_s; NaN: never) -> mode 11. The copper's temperature T
follows tau_th dT/dt = T_ambient + R_th (3/2) R i_q^2 - T (one node, reported as the board's and the motor's);
T >= servo.fault_temperature (or a finite servo.motor_fault_temperature) -> mode 1, fault 38.

The truth: per [bench] count c (the bin of true angles nearest c), the mean over the periods the rotor spent there
of tau_pos + k(theta, delta) i_comp, i_comp the table's current through its own copy of the current's lag
(the lag is linear: the part of the flowing i_q the table put there), and of tau_pos alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Callable

import numpy as np
from numba import njit

from ilcpmac.core.errors import SimulationError
from ilcpmac.core.schema import finite_number, in_range, setting, shown, value_problem
from ilcpmac.export import MOTEUS_TABLE_SIZE
from ilcpmac.model.motor import MotorModel
from ilcpmac.sim.drive_log import (
    current_noise_a,
    current_torque_per_ampere,
    drive_tables,
    fine_point,
    known_torque_constant,
    position_torque,
    read_encoder,
    rotor_speed,
)
from ilcpmac.sim.simulator import Simulator

__all__ = ["FAULTS", "MAX_ADVANCE_S", "MODES", "DriveSpec", "DriveStatus", "EmulatedDrive"]

#: moteus.Mode numbers the emulated drive takes
MODE_STOPPED, MODE_FAULT, MODE_POSITION, MODE_TIMEOUT = 0, 1, 10, 11
MODES = {"stopped": MODE_STOPPED, "fault": MODE_FAULT, "position": MODE_POSITION, "timeout": MODE_TIMEOUT}
#: fw/error.h codes the emulated drive reports (limits 96, 99 in position mode; 38 with mode FAULT)
FAULT_NONE, FAULT_OVER_TEMPERATURE, FAULT_LIMIT_MAX_VELOCITY, FAULT_LIMIT_MAX_CURRENT = 0, 38, 96, 99
FAULTS = {"none": FAULT_NONE, "kOverTemperature": FAULT_OVER_TEMPERATURE,
          "kLimitMaxVelocity": FAULT_LIMIT_MAX_VELOCITY, "kLimitMaxCurrent": FAULT_LIMIT_MAX_CURRENT}
#: the truth's bins per [bench] count (`EmulatedDrive.truth`)
TRUTH_SUB_BINS = 16
#: the longest one `EmulatedDrive.advance` runs, s
MAX_ADVANCE_S = 3600.0
#: moteus's defaults of the settings DriveSpec leaves to the drive
_DEFAULT_TIMEOUT_S, _VELOCITY_DERATE_HZ = 0.1, 2.0
_INT8 = (-128, 127)
_TABLE_PREFIX = "motor.cogging_dq_comp."

# the kernel's constants (`_consts`), settings (`_settings`) and state (`_state`), by index
(C_DT, C_INERTIA, C_DRY_NM, C_POLE_PAIRS, C_LINES, C_A_CURRENT, C_A_FILTER, C_K_T, C_HEAT_C_PER_A2, C_A_THERMAL,
 C_AMBIENT_C, C_SIZE) = range(12)
(S_VELOCITY, S_FEEDFORWARD_NM, S_MAX_TORQUE_NM, S_KP, S_KD, S_MAX_CURRENT_A, S_MAX_VELOCITY, S_VELOCITY_DERATE,
 S_FAULT_C, S_MOTOR_FAULT_C, S_SIZE) = range(11)
(X_THETA, X_OMEGA, X_I_Q, X_I_COMP, X_CONTROL, X_COUNT, X_SPEED_1, X_SPEED_2, X_TEMPERATURE_C, X_WATCHDOG_S,
 X_MODE, X_FAULT, X_SIZE) = range(13)
#: what a servo.* setting holds: its words, its check
_POSITIVE = ("a finite positive number", lambda v: finite_number(v) and v > 0)
_NON_NEGATIVE = ("finite and >= 0", lambda v: finite_number(v) and v >= 0)
_TEMPERATURE = ("a temperature, deg C, or NaN (none)", lambda v: v > -math.inf or math.isnan(v))
#: the servo.* settings the drive holds: their kernel setting's index (None: Python's alone), the power of 2 pi that
#: turns moteus's per-revolution unit into the kernel's per-radian one, and what they hold
_SERVO_SETTINGS: dict[str, tuple[int | None, int, tuple[str, Callable[[float], bool]]]] = {
    "servo.max_current_A": (S_MAX_CURRENT_A, 0, _POSITIVE), "servo.max_velocity": (S_MAX_VELOCITY, 1, _POSITIVE),
    "servo.max_velocity_derate": (S_VELOCITY_DERATE, 1, _POSITIVE),
    "servo.fault_temperature": (S_FAULT_C, 0, _TEMPERATURE),
    "servo.motor_fault_temperature": (S_MOTOR_FAULT_C, 0, _TEMPERATURE),
    "servo.default_timeout_s": (None, 0, _POSITIVE), "servo.pid_position.kp": (S_KP, -1, _NON_NEGATIVE),
    "servo.pid_position.kd": (S_KD, -1, _NON_NEGATIVE)}

def _float32(value: float) -> float:
    """``value`` as the firmware's float holds it."""
    return float(np.float32(value))


@dataclass(frozen=True)
class DriveSpec:
    """The emulated drive's own settings (the module's docstring states the model); `problem` checks them."""

    control_rate_hz: float = setting(in_range(1e3, 1e6), "control periods per second, Hz, within [1e3, 1e6] "
                                     "(a moteus's 30-40 kHz)", 40000.0)
    encoder_bits: int = setting(in_range(8, 24), "its magnetic encoder: 2^encoder_bits lines per revolution, "
                                "read once per control period, within [8, 24]", 14)
    encoder_eccentricity_lines: float = setting(in_range(0.0, 1e3), "the encoder's once-per-revolution reading "
                                                "error, lines of that encoder, within [0, 1e3]", 0.1)
    encoder_eccentricity_phase_rad: float = setting(in_range(-2 * math.pi, 2 * math.pi), "its phase at angle 0, "
                                                    "rad, within [-2 pi, 2 pi]", 0.0)
    velocity_bandwidth_hz: float = setting(in_range(0.0, 1e3, low_open=True), "the position-mode loop's corner "
                                           "(kp = J w^2, kd = 2 J w), Hz, within (0, 1e3]", 10.0)
    velocity_filter_hz: float = setting(in_range(0.0, 1e5, low_open=True), "corner of the velocity estimate's two "
                                        "first-order stages, Hz, within (0, control_rate_hz / 10]", 400.0)
    max_current_a: float = setting(in_range(0.0, 1e3, low_open=True), "servo.max_current_A, A, within (0, 1e3]",
                                   20.0)
    max_velocity_hz: float = setting(in_range(0.0, 1e3, low_open=True), "servo.max_velocity, rev/s, within "
                                     "(0, 1e3]", 20.0)
    fault_temperature_c: float = setting(in_range(-50.0, 1e3), "servo.fault_temperature, deg C, within "
                                         "[-50, 1e3]", 75.0)
    motor_fault_temperature_c: float = setting(in_range(-50.0, math.inf), "servo.motor_fault_temperature, deg C, "
                                               "within [-50, inf] (inf: none)", math.inf)
    current_noise_a: float | None = setting(in_range(0.0, 1e3), "white noise of the reported q (and d) current, "
                                            "A RMS, within [0, 1e3] (None: [simulator.current_sensors]'s, as "
                                            "--kind log has it)", None)
    ambient_temperature_c: float = setting(in_range(-50.0, 200.0), "the copper's temperature at rest, deg C, "
                                           "within [-50, 200]", 25.0)
    thermal_resistance_c_per_w: float = setting(in_range(0.0, 1e3), "R_th, the copper's rise per watt of "
                                                "(3/2) R i_q^2, deg C / W, within [0, 1e3]", 2.0)
    thermal_time_constant_s: float = setting(in_range(0.0, 1e5, low_open=True), "tau_th, the copper's, s, within "
                                             "(0, 1e5]", 300.0)
    voltage_v: float = setting(in_range(0.0, 1e3, low_open=True), "the supply voltage it reports, V, within "
                               "(0, 1e3]", 24.0)

    def problem(self) -> str | None:
        """The first value out of its range, as "name: why", or None."""
        for f in fields(self):
            value = getattr(self, f.name)
            if not ((value is None and f.default is None) or isinstance(value, int if f.type == "int" else (int, float))
                    and not isinstance(value, bool)):
                return f"{f.name}: invalid value {shown(value)} (not {'an integer' if f.type == 'int' else 'a number'})"
            problem = value_problem(f, value)
            if problem is not None:
                return problem
        if self.velocity_filter_hz > self.control_rate_hz / 10:
            return (f"velocity_filter_hz: {self.velocity_filter_hz:g} Hz is more than control_rate_hz / 10 = "
                    f"{self.control_rate_hz / 10:g} Hz")
        if self.velocity_bandwidth_hz > self.velocity_filter_hz / 4:
            return (f"velocity_bandwidth_hz: {self.velocity_bandwidth_hz:g} Hz is more than velocity_filter_hz / 4 "
                    f"= {self.velocity_filter_hz / 4:g} Hz")
        slope = self.encoder_eccentricity_lines
        if slope > 2**self.encoder_bits / (4 * math.pi):
            return (f"encoder_eccentricity_lines: {slope:g} lines is more than 2^encoder_bits / (4 pi): the reading "
                    "would not keep rising with the angle")
        return None


@dataclass(frozen=True)
class DriveStatus:
    """What a query of the drive returns (moteus's registers; position and velocity of the rotor, which is the
    output).

    Attributes
    ----------
    mode, fault : int
        moteus.Mode number (`MODES`); fw/error.h code (`FAULTS`): the fault in mode 1, the limit active in mode 10.
    position_rev, velocity_hz : float
        The encoder's reading, multi-turn, rev; the velocity estimate, rev/s.
    q_current_a, d_current_a : float
        Measured: the flowing q current (d: 0) plus white noise, A.
    torque_nm : float
        K*_t times the measured q current, N m.
    temperature_c, motor_temperature_c, voltage_v : float
        The board's and the motor's temperature (the one thermal node), deg C; the supply, V.
    encoder0_position_rev, encoder0_velocity_hz : float
        The commutation encoder's reading within [0, 1) of a revolution, and its velocity estimate, rev/s.
    """

    mode: int
    fault: int
    position_rev: float
    velocity_hz: float
    q_current_a: float
    d_current_a: float
    torque_nm: float
    temperature_c: float
    motor_temperature_c: float
    voltage_v: float
    encoder0_position_rev: float
    encoder0_velocity_hz: float


@njit(cache=True, inline="always")
def _table_current(table_a, position):
    """The firmware's q_comp at commutation position ``position`` in [0, 1) (the module's docstring), A."""
    size = table_a.size
    left = min(size - 1, int(size * position))
    right = (left + 1) % size
    fraction = (position - left / size) * size
    return (table_a[right] - table_a[left]) * fraction + table_a[left]


@njit(cache=True)
def _run(tables, table_a, consts, settings, state, truth, steps):
    """Run ``steps`` control periods from ``state``, updating it and the ``truth`` sums (rows: residual, tau_pos,
    periods; a column per `TRUTH_SUB_BINS`th of a [bench] count, the first centred on count 0) in place. Indices:
    the module's C_, S_ and X_ constants."""
    n_fine = tables.shape[0] - 1
    counts = truth.shape[1]
    two_pi = 2.0 * np.pi
    dt, lines = consts[C_DT], int(consts[C_LINES])
    for _ in range(steps):
        theta = state[X_THETA]
        base, frac = fine_point(theta, n_fine)
        count = read_encoder(theta, tables, base, frac, lines, 0.0, 0)
        reading = count * two_pi / lines
        raw = (count - state[X_COUNT]) * two_pi / lines / dt
        state[X_COUNT] = count
        state[X_SPEED_1] += consts[C_A_FILTER] * (raw - state[X_SPEED_1])
        state[X_SPEED_2] += consts[C_A_FILTER] * (state[X_SPEED_1] - state[X_SPEED_2])
        speed = state[X_SPEED_2]
        if state[X_MODE] == MODE_POSITION:
            state[X_WATCHDOG_S] -= dt
            if state[X_WATCHDOG_S] <= 0.0:
                state[X_MODE] = MODE_TIMEOUT
                state[X_FAULT] = FAULT_NONE
        q_loop, q_comp = 0.0, 0.0
        if state[X_MODE] == MODE_POSITION:
            velocity = settings[S_VELOCITY]
            state[X_CONTROL] += velocity * dt
            torque = (settings[S_KP] * (state[X_CONTROL] - reading) + settings[S_KD] * (velocity - speed)
                      + settings[S_FEEDFORWARD_NM])
            torque = min(max(torque, -settings[S_MAX_TORQUE_NM]), settings[S_MAX_TORQUE_NM])
            q_loop = torque / consts[C_K_T]
            limit, code = settings[S_MAX_CURRENT_A], FAULT_LIMIT_MAX_CURRENT
            if abs(speed) >= settings[S_MAX_VELOCITY] and speed * q_loop >= 0.0:
                derate = 1.0 - (abs(speed) - settings[S_MAX_VELOCITY]) / settings[S_VELOCITY_DERATE]
                limit = max(0.0, derate * limit)
                if derate < 1.0:
                    code = FAULT_LIMIT_MAX_VELOCITY
            state[X_FAULT] = code if abs(q_loop) > limit else FAULT_NONE
            q_loop = min(max(q_loop, -limit), limit)
            q_comp = _table_current(table_a, (count % lines) / lines)
        state[X_I_Q] += consts[C_A_CURRENT] * (q_loop + q_comp - state[X_I_Q])
        state[X_I_COMP] += consts[C_A_CURRENT] * (q_comp - state[X_I_COMP])
        i_q = state[X_I_Q]
        state[X_TEMPERATURE_C] += consts[C_A_THERMAL] * (consts[C_AMBIENT_C] + consts[C_HEAT_C_PER_A2] * i_q * i_q
                                                         - state[X_TEMPERATURE_C])
        if state[X_MODE] != MODE_FAULT and (state[X_TEMPERATURE_C] >= settings[S_FAULT_C]
                                            or state[X_TEMPERATURE_C] >= settings[S_MOTOR_FAULT_C]):
            state[X_MODE] = MODE_FAULT
            state[X_FAULT] = FAULT_OVER_TEMPERATURE
        k = current_torque_per_ampere(tables, base, frac, consts[C_POLE_PAIRS] * (reading - theta))
        tau_pos = position_torque(tables, base, frac)
        column = int(math.floor(theta / two_pi * counts + 0.5 * TRUTH_SUB_BINS)) % counts
        truth[0, column] += tau_pos + k * state[X_I_COMP]
        truth[1, column] += tau_pos
        truth[2, column] += 1.0
        state[X_OMEGA] = rotor_speed(state[X_OMEGA], k * i_q + tau_pos, consts[C_DRY_NM], dt, consts[C_INERTIA])
        state[X_THETA] = theta + dt * state[X_OMEGA]


class EmulatedDrive:
    """A moteus-class drive on ``model``'s motor (the module's docstring states the model), at rest at angle 0
    and stopped, its RAM config and its flash the same, its table all zeros.

    Parameters
    ----------
    model : MotorModel
        The motor ([simulator.*] of a config).
    spec : DriveSpec
        The drive.
    seed : int
        Seed of the reported currents' noise.

    Attributes
    ----------
    time_s : float
        Virtual seconds since power-up (whole control periods).
    config, flash : dict of str to float
        The RAM config and what ``conf write`` stored, by moteus's names: servo.max_current_A, servo.max_velocity,
        servo.max_velocity_derate, servo.fault_temperature, servo.motor_fault_temperature, servo.default_timeout_s,
        servo.pid_position.kp, servo.pid_position.kd, motor.cogging_dq_scale, motor.cogging_dq_comp.0..1023.
    """

    def __init__(self, model: MotorModel, spec: DriveSpec, seed: int = 0) -> None:
        problem = spec.problem()
        if problem is not None:
            raise SimulationError(f"emulated drive {problem}")
        if not (isinstance(seed, int) and 0 <= seed < 2**63):
            raise SimulationError(f"emulated drive seed must be an integer within 0..2^63-1, got {shown(seed)}")
        simulator = Simulator(model, warmup_revolutions=0)
        self.model, self.spec = model, spec
        lines = 2**spec.encoder_bits
        self._tables = drive_tables(simulator, lambda angle: spec.encoder_eccentricity_lines
                                    * np.sin(angle + spec.encoder_eccentricity_phase_rad))
        self._k_t = known_torque_constant(simulator)
        dt = 1.0 / spec.control_rate_hz
        heat = 1.5 * model.winding.phase_resistance_ohm * spec.thermal_resistance_c_per_w
        self._consts = np.array([
            dt, model.mechanics.true_inertia_kgm2, model.mechanics.coulomb_friction_nm, model.winding.pole_pairs,
            lines, 1.0 - math.exp(-2.0 * math.pi * model.controller.bandwidth_hz * dt),
            1.0 - math.exp(-2.0 * math.pi * spec.velocity_filter_hz * dt), self._k_t, heat,
            1.0 - math.exp(-dt / spec.thermal_time_constant_s), spec.ambient_temperature_c])
        self._settings = np.zeros(S_SIZE)
        self._settings[S_MAX_TORQUE_NM] = math.inf
        self._state = np.zeros(X_SIZE)
        self._state[X_COUNT] = math.floor(self._tables[0, 3] + 0.5)
        self._state[X_TEMPERATURE_C] = spec.ambient_temperature_c
        self._table_a = np.zeros(MOTEUS_TABLE_SIZE)
        self._truth = np.zeros((3, TRUTH_SUB_BINS * model.encoder.counts_per_rev))
        self._rng = np.random.default_rng(seed)
        self._noise_q_a = (current_noise_a(model) * math.sqrt(2.0 / 3.0) if spec.current_noise_a is None
                           else spec.current_noise_a)
        self._rate_hz = spec.control_rate_hz
        self._periods, self._carry = 0, 0.0
        self.time_s = 0.0
        inertia_w = model.mechanics.inertia_kgm2 * 2.0 * math.pi * spec.velocity_bandwidth_hz
        self.config = {
            "servo.max_current_A": spec.max_current_a, "servo.max_velocity": spec.max_velocity_hz,
            "servo.max_velocity_derate": _VELOCITY_DERATE_HZ, "servo.fault_temperature": spec.fault_temperature_c,
            "servo.motor_fault_temperature": spec.motor_fault_temperature_c,
            "servo.default_timeout_s": _DEFAULT_TIMEOUT_S, "servo.pid_dq_hz": model.controller.bandwidth_hz,
            "servo.pid_position.kp": 2.0 * math.pi * inertia_w * 2.0 * math.pi * spec.velocity_bandwidth_hz,
            "servo.pid_position.kd": 2.0 * math.pi * 2.0 * inertia_w, "motor.cogging_dq_scale": 0.0,
            **{f"{_TABLE_PREFIX}{k}": 0.0 for k in range(MOTEUS_TABLE_SIZE)}}
        for name, value in self.config.items():
            if name in _SERVO_SETTINGS:
                self.set_config(name, value)
        self.flash = dict(self.config)

    def set_config(self, name: str, value: float) -> None:
        """``conf set NAME VALUE`` into RAM (`config` lists the names): an unknown ``name`` raises KeyError, a
        value the drive would not hold `SimulationError` (a table entry not an int8, the scale not finite, a
        temperature neither NaN (none) nor above -inf, a gain negative, the rest not finite and positive)."""
        if name not in self.config:
            raise KeyError(name)
        if not (isinstance(value, (int, float)) and not isinstance(value, bool)):
            raise SimulationError(f"conf set {name}: {shown(value)} is not a number")
        value = float(value)
        if name.startswith(_TABLE_PREFIX):
            if not (value.is_integer() and _INT8[0] <= value <= _INT8[1]):
                raise SimulationError(f"conf set {name}: {shown(value)} is not an int8")
            self._table_a[int(name[len(_TABLE_PREFIX):])] = value * _float32(self.config["motor.cogging_dq_scale"])
        elif name == "servo.pid_dq_hz":  # the current loop's bandwidth: the corner of its first-order lag
            if not (finite_number(value) and 0 < value <= self._rate_hz / 10):
                raise SimulationError(f"conf set {name}: {shown(value)} is not a bandwidth within (0, control rate "
                                      f"/ 10 = {self._rate_hz / 10:g}] Hz")
            self._consts[C_A_CURRENT] = 1.0 - math.exp(-2.0 * math.pi * value / self._rate_hz)
        elif name == "motor.cogging_dq_scale":
            if not finite_number(value):
                raise SimulationError(f"conf set {name}: {shown(value)} is not finite")
            entries = [self.config[f"{_TABLE_PREFIX}{k}"] for k in range(MOTEUS_TABLE_SIZE)]
            self._table_a[:] = np.array(entries) * _float32(value)
        else:
            index, per_rev, (words, check) = _SERVO_SETTINGS[name]
            if not check(value):
                raise SimulationError(f"conf set {name}: {shown(value)} is not {words}")
            if index is not None:
                self._settings[index] = math.inf if math.isnan(value) else value * (2.0 * math.pi) ** per_rev
        self.config[name] = value

    def write_flash(self) -> None:
        """``conf write``: the RAM config into flash."""
        self.flash = dict(self.config)

    def command_position(self, velocity_hz: float, *, position_rev: float = math.nan, max_torque_nm: float = math.inf,
                         feedforward_nm: float = 0.0, watchdog_timeout_s: float = math.nan) -> None:
        """A position-mode command (ignored in mode timeout or fault, which only a stop leaves): the control
        position advances at ``velocity_hz`` (rev/s) from ``position_rev`` (NaN: where it is; entering the mode,
        the reading); the loop's torque within ``max_torque_nm`` (NaN: no limit) plus ``feedforward_nm``; the
        watchdog at ``watchdog_timeout_s`` (0: servo.default_timeout_s; NaN: none)."""
        for name, value in (("velocity_hz", velocity_hz), ("feedforward_nm", feedforward_nm)):
            if not finite_number(value):
                raise SimulationError(f"position command {name}: {shown(value)} is not finite")
        if not (isinstance(position_rev, (int, float)) and not math.isinf(position_rev)):
            raise SimulationError(f"position command position_rev: {shown(position_rev)} is neither finite nor NaN")
        if not (isinstance(max_torque_nm, (int, float)) and (math.isnan(max_torque_nm) or max_torque_nm >= 0)):
            raise SimulationError(f"position command max_torque_nm: {shown(max_torque_nm)} is not >= 0 or NaN")
        if not (isinstance(watchdog_timeout_s, (int, float))
                and (math.isnan(watchdog_timeout_s) or 0 <= watchdog_timeout_s < math.inf)):
            raise SimulationError(f"position command watchdog_timeout_s: {shown(watchdog_timeout_s)} is not finite, "
                                  ">= 0 or NaN")
        x, s = self._state, self._settings
        if x[X_MODE] in (MODE_TIMEOUT, MODE_FAULT):
            return
        if x[X_MODE] == MODE_STOPPED:
            x[X_CONTROL] = x[X_COUNT] * 2.0 * math.pi / self._consts[C_LINES]
            x[X_MODE] = MODE_POSITION
        if not math.isnan(position_rev):
            x[X_CONTROL] = 2.0 * math.pi * position_rev
        s[S_VELOCITY] = 2.0 * math.pi * velocity_hz
        s[S_FEEDFORWARD_NM] = feedforward_nm
        s[S_MAX_TORQUE_NM] = math.inf if math.isnan(max_torque_nm) else max_torque_nm
        x[X_WATCHDOG_S] = (math.inf if math.isnan(watchdog_timeout_s) else
                           watchdog_timeout_s or self.config["servo.default_timeout_s"])

    def command_stop(self) -> None:
        """A stop command: mode stopped, fault cleared, no current."""
        self._state[X_MODE] = MODE_STOPPED
        self._state[X_FAULT] = FAULT_NONE

    def advance(self, seconds: float) -> None:
        """Run the drive for ``seconds`` (within [0, `MAX_ADVANCE_S`]): the whole control periods that bring its
        time nearest to the total asked so far (the fraction carried)."""
        if not (isinstance(seconds, (int, float)) and 0.0 <= seconds <= MAX_ADVANCE_S):
            raise SimulationError(f"advance: {shown(seconds)} s is not within [0, {MAX_ADVANCE_S:g}]")
        periods = seconds * self._rate_hz + self._carry
        steps = round(periods)
        self._carry = periods - steps
        _run(self._tables, self._table_a, self._consts, self._settings, self._state, self._truth, steps)
        self._periods += steps
        self.time_s = self._periods / self._rate_hz

    def status(self) -> DriveStatus:
        """A query's answer, now."""
        x = self._state
        lines = self._consts[C_LINES]
        noise_q, noise_d = self._noise_q_a * self._rng.standard_normal(2)
        q = float(x[X_I_Q] + noise_q)
        velocity_hz = float(x[X_SPEED_2] / (2.0 * math.pi))
        temperature_c = float(x[X_TEMPERATURE_C])
        return DriveStatus(
            mode=int(x[X_MODE]), fault=int(x[X_FAULT]), position_rev=float(x[X_COUNT] / lines),
            velocity_hz=velocity_hz, q_current_a=q, d_current_a=float(noise_d), torque_nm=self._k_t * q,
            temperature_c=temperature_c, motor_temperature_c=temperature_c, voltage_v=self.spec.voltage_v,
            encoder0_position_rev=float(x[X_COUNT] % lines / lines), encoder0_velocity_hz=velocity_hz)

    def truth_reset(self) -> None:
        """Start the truth's averages afresh."""
        self._truth[:] = 0.0

    def truth(self, counts_per_rev: int) -> tuple[np.ndarray, np.ndarray]:
        """Since `truth_reset`, per [bench] count (``counts_per_rev`` must be the model's): the mean true
        position-locked residual torque (tau_pos plus the table's flowing current's torque) and tau_pos alone,
        N m, by true angle; NaN at counts the rotor did not visit. Each count's is the mean of its
        `TRUTH_SUB_BINS` sub-bins' means (those visited), so that how long the rotor dwelt where within a count
        does not weigh in: the box average over the count, whatever the speed's ripple."""
        cpr = self.model.encoder.counts_per_rev
        if counts_per_rev != cpr:
            raise SimulationError(f"truth: counts_per_rev {shown(counts_per_rev)} is not the model's [bench] "
                                  f"counts_per_rev {cpr}")
        periods = self._truth[2]
        with np.errstate(invalid="ignore", divide="ignore"):
            means = (self._truth[:2] / periods).reshape(2, cpr, TRUTH_SUB_BINS)
        visited = np.isfinite(means)
        with np.errstate(invalid="ignore", divide="ignore"):
            residual, position = np.where(visited, means, 0.0).sum(axis=2) / visited.sum(axis=2)
        return residual, position
