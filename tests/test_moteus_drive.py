"""The emulated moteus-class drive (`ilcpmac.sim.moteus_drive`): its table applied as the firmware applies it, the
true ripple it reports, its watchdog, limits and faults, and its state carried exactly from one `advance` to the
next; on the small actuator (7 pole pairs, 12 slots, J 1e-4 kg m^2, a 14-bit encoder at 40 kHz)."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest

from ilcpmac.config import load_config
from ilcpmac.core.errors import SimulationError
from ilcpmac.export import MOTEUS_TABLE_SIZE, MoteusTable
from ilcpmac.model.motor import MotorModel
from ilcpmac.sim import moteus_drive
from ilcpmac.sim.drive_log import drive_tables
from ilcpmac.sim.moteus_drive import MODES, X_I_COMP, DriveSpec, EmulatedDrive
from ilcpmac.sim.simulator import OVERSAMPLE, Simulator

ACTUATOR = Path(__file__).resolve().parents[1] / "benchmarks" / "motors" / "small-actuator.toml"
#: the drive without current noise: what it reports is what flows
QUIET = DriveSpec(current_noise_a=0.0)


@pytest.fixture(scope="module")
def model() -> MotorModel:
    return load_config(ACTUATOR).model


@pytest.fixture(scope="module")
def held(model) -> MotorModel:
    """The actuator against 100 N m of dry friction: its rotor stays where it is put."""
    return dataclasses.replace(model, mechanics=dataclasses.replace(model.mechanics, coulomb_friction_nm=100.0))


def put(drive: EmulatedDrive, angle_rad: float) -> None:
    """Place the rotor at the true angle ``angle_rad``, at rest (the tests' hand on the rotor)."""
    drive._state[moteus_drive.X_THETA] = angle_rad
    drive._state[moteus_drive.X_OMEGA] = 0.0


def upload(drive: EmulatedDrive, table: MoteusTable) -> None:
    """``conf set`` the table as moteus's console would (`MoteusTable.lines`)."""
    for line in table.lines():
        _, _, name, value = line.split()
        drive.set_config(name, float(value))


def mean_speed_hz(drive: EmulatedDrive, seconds: float) -> float:
    """The reading's mean speed over the next ``seconds``, rev/s."""
    start = drive.status().position_rev
    drive.advance(seconds)
    return (drive.status().position_rev - start) / seconds


def test_the_table_is_applied_as_the_firmware_interpolates_it_at_the_encoders_reading(held):
    rng = np.random.default_rng(3)
    table = MoteusTable(rng.integers(-127, 128, MOTEUS_TABLE_SIZE).astype(np.int8), 2.0**-7)
    drive = EmulatedDrive(held, QUIET)
    upload(drive, table)
    drive.set_config("servo.pid_position.kp", 0.0)
    drive.set_config("servo.pid_position.kd", 0.0)
    # within an entry, on one, and within the last entry (which interpolates towards entry 0)
    for where in (0.3217, 512 / 1024, 1023.6 / 1024):
        put(drive, 2 * math.pi * where)
        drive.command_position(0.0)
        drive.advance(0.05)  # 157 time constants of the current's lag
        status = drive.status()
        expected = table.sample_a(np.array([status.encoder0_position_rev]))[0]
        assert status.mode == MODES["position"]
        assert abs(status.encoder0_position_rev - where) < 2 / 2**14
        assert status.q_current_a == pytest.approx(expected, rel=1e-6, abs=1e-7)
        drive.command_stop()
    drive.advance(0.05)
    assert abs(drive.status().q_current_a) < 1e-9  # the table only in position mode


def test_without_a_table_the_truth_is_the_models_cogging_plus_disturbance_by_position(model):
    drive = EmulatedDrive(model, QUIET)
    drive.command_position(3.7)  # not a whole number of control periods per revolution: each bin's samples spread
    drive.advance(0.5)
    drive.truth_reset()
    drive.advance(2.0)
    residual, position_torque = drive.truth(2048)
    expected = Simulator(model).torque_pos_fine[::OVERSAMPLE]
    assert np.array_equal(residual, position_torque)
    # a bin's mean against the value at its centre: within sinc(pi order / 2048) of order 168, 1 %
    assert np.max(np.abs(position_torque - expected)) < 0.015 * np.max(np.abs(expected))


def centred_bins(fine: np.ndarray) -> np.ndarray:
    """The mean per [bench] count of a revolution's `OVERSAMPLE` x 2048 fine rows over the angles nearest it
    (the truth's bins)."""
    return np.roll(fine, OVERSAMPLE // 2).reshape(-1, OVERSAMPLE).mean(axis=1)


def test_a_table_of_minus_the_position_torque_over_k_q_leaves_its_interpolation_and_int8_floor_through_the_lag(
        model):
    speed_hz, bandwidth_hz, rate_hz = 0.5, 4000.0, QUIET.control_rate_hz
    fast = dataclasses.replace(model, controller=dataclasses.replace(model.controller, bandwidth_hz=bandwidth_hz))
    tables = drive_tables(Simulator(fast), np.zeros_like)[:-1]  # k_q, k_d, tau_pos, e = 0
    n_fine = tables.shape[0]
    entries = np.arange(MOTEUS_TABLE_SIZE) * (n_fine // MOTEUS_TABLE_SIZE)
    table = MoteusTable.of(-tables[entries, 2] / tables[entries, 0], "test")
    drive = EmulatedDrive(fast, dataclasses.replace(QUIET, encoder_eccentricity_lines=0.0))
    upload(drive, table)
    drive.command_position(speed_hz)
    drive.advance(0.5)
    drive.truth_reset()
    drive.advance(2.2)
    residual, position_torque = drive.truth(2048)
    # the floor: the table's current at a steady speed through the current's lag, a / (1 - (1 - a) z^-1)
    a = 1.0 - math.exp(-2.0 * math.pi * bandwidth_hz / rate_hz)
    order = np.fft.rfftfreq(n_fine, 1.0 / n_fine)
    lag = a / (1.0 - (1.0 - a) * np.exp(-2j * math.pi * order * speed_hz / rate_hz))
    current_a = np.fft.irfft(np.fft.rfft(table.sample_a(np.arange(n_fine) / n_fine)) * lag, n_fine)
    floor = centred_bins(tables[:, 2] + tables[:, 0] * current_a)
    rms = lambda x: float(np.sqrt(np.mean(x**2)))  # noqa: E731
    assert rms(residual) < 0.05 * rms(position_torque)
    assert rms(residual - floor) < 0.1 * rms(floor)


def test_the_watchdog_stops_a_command_not_renewed_and_only_a_stop_leaves_the_timeout(model):
    drive = EmulatedDrive(model, QUIET)
    for _ in range(10):
        drive.command_position(2.0, watchdog_timeout_s=0.05)
        drive.advance(0.04)
    assert drive.status().mode == MODES["position"]
    drive.advance(0.02)
    assert drive.status().mode == MODES["timeout"]
    drive.command_position(2.0, watchdog_timeout_s=0.05)  # ignored: moteus stays timed out until a stop
    drive.advance(1.0)
    status = drive.status()
    assert status.mode == MODES["timeout"]
    assert abs(status.q_current_a) < 1e-9 and status.velocity_hz == pytest.approx(0.0, abs=1e-9)
    drive.command_stop()
    drive.command_position(2.0, watchdog_timeout_s=0.0)  # 0: servo.default_timeout_s
    drive.advance(drive.config["servo.default_timeout_s"] - 0.01)
    assert drive.status().mode == MODES["position"]
    drive.advance(0.02)
    assert drive.status().mode == MODES["timeout"]


def test_a_stop_lets_the_rotor_coast_to_rest(model):
    drive = EmulatedDrive(model, QUIET)
    drive.command_position(3.0)
    drive.advance(1.0)
    drive.command_stop()
    drive.advance(0.01)
    moving = drive.status().position_rev
    drive.advance(2.0)
    status = drive.status()
    assert status.mode == MODES["stopped"] and abs(status.q_current_a) < 1e-9
    assert status.position_rev > moving and mean_speed_hz(drive, 0.5) == 0.0


def test_the_current_limit_holds_and_is_reported_and_over_temperature_faults(held):
    spec = dataclasses.replace(QUIET, max_current_a=5.0, fault_temperature_c=30.0, thermal_time_constant_s=1.0)
    drive = EmulatedDrive(held, spec)
    drive.command_position(0.0, position_rev=10.0)  # 10 revolutions of error: the loop asks for far more
    drive.advance(0.01)
    status = drive.status()
    assert status.mode == MODES["position"] and status.fault == moteus_drive.FAULTS["kLimitMaxCurrent"]
    assert status.q_current_a == pytest.approx(5.0, rel=1e-3)
    # 3/2 x 0.1 ohm x 25 A^2 x 2 deg C / W = 7.5 deg C above 25 within a time constant: 30 at 1.1 s
    drive.advance(2.0)
    status = drive.status()
    assert status.mode == MODES["fault"] and status.fault == moteus_drive.FAULTS["kOverTemperature"]
    assert abs(status.q_current_a) < 1e-9 and status.temperature_c < 30.0
    drive.command_position(0.0, position_rev=10.0)
    drive.advance(0.01)
    assert drive.status().mode == MODES["fault"]
    drive.command_stop()
    assert drive.status().mode == MODES["stopped"] and drive.status().fault == 0


def test_beyond_servo_max_velocity_the_current_is_derated_and_reported(model):
    drive = EmulatedDrive(model, QUIET)
    drive.set_config("servo.max_velocity", 2.0)
    drive.set_config("servo.max_velocity_derate", 0.5)
    drive.command_position(5.0)
    drive.advance(1.0)
    assert drive.status().fault == moteus_drive.FAULTS["kLimitMaxVelocity"]
    # the limit reaches 0 at 2.5 rev/s; the cogging's speed ripple (0.03 rev/s) lets the current push in its dips
    assert 2.0 < mean_speed_hz(drive, 1.0) < 2.6


@pytest.mark.parametrize("speed_hz", [2.0, -4.0, 6.0])
def test_the_position_mode_holds_the_commanded_speed_on_a_cogging_motor(model, speed_hz):
    drive = EmulatedDrive(model, DriveSpec())
    drive.command_position(speed_hz)
    drive.advance(1.0)
    assert mean_speed_hz(drive, 1.0) == pytest.approx(speed_hz, rel=0.005)
    assert drive.status().velocity_hz == pytest.approx(speed_hz, rel=0.05)


def test_many_small_advances_equal_one_large_one(model):
    one, many = EmulatedDrive(model, DriveSpec(), seed=5), EmulatedDrive(model, DriveSpec(), seed=5)
    for drive in (one, many):
        upload(drive, MoteusTable(np.arange(MOTEUS_TABLE_SIZE).astype(np.int8), 0.001))
        drive.command_position(3.0)
    one.advance(0.3)
    for _ in range(9000):
        many.advance(1 / 30000)  # 4/3 of a period: the fraction carried
    assert one.time_s == many.time_s == pytest.approx(0.3)
    assert np.array_equal(one._state, many._state) and np.array_equal(one._truth, many._truth)
    assert one.status() == many.status()


def test_the_current_loop_s_bandwidth_is_servo_pid_dq_hz_and_sets_the_lag_of_the_table_s_current(model):
    """A constant table current through the first-order lag reaches 1 - e^-1 of itself in 1 / (2 pi f) s."""
    reached = []
    for bandwidth_hz in (model.controller.bandwidth_hz, 50.0):
        drive = EmulatedDrive(model, QUIET)
        assert drive.config["servo.pid_dq_hz"] == model.controller.bandwidth_hz
        drive.set_config("servo.pid_dq_hz", bandwidth_hz)
        drive.set_config("motor.cogging_dq_scale", 0.01)
        for k in range(1024):
            drive.set_config(f"motor.cogging_dq_comp.{k}", 100)
        drive.command_position(0.0, watchdog_timeout_s=math.nan)
        drive.advance(1.0 / (2 * math.pi * bandwidth_hz))
        reached.append(drive._state[X_I_COMP] / 1.0)
    np.testing.assert_allclose(reached, 1 - math.exp(-1), rtol=0.02)  # to the whole control period


def test_conf_set_changes_ram_and_only_conf_write_reaches_the_flash(model):
    drive = EmulatedDrive(model, QUIET)
    before = dict(drive.flash)
    assert before == drive.config
    drive.set_config("motor.cogging_dq_scale", 0.01)
    drive.set_config("motor.cogging_dq_comp.7", -3)
    drive.set_config("servo.max_current_A", 4.0)
    assert drive.flash == before and drive.config["motor.cogging_dq_comp.7"] == -3.0
    drive.write_flash()
    assert drive.flash == drive.config and drive.flash["servo.max_current_A"] == 4.0


@pytest.mark.parametrize("name, value, error", [
    ("motor.cogging_dq_comp.1024", 0, KeyError), ("servo.no_such", 1.0, KeyError),
    ("motor.cogging_dq_comp.-1", 0, KeyError), ("motor.cogging_dq_comp.3", 128, SimulationError),
    ("motor.cogging_dq_comp.3", 1.5, SimulationError), ("motor.cogging_dq_scale", math.nan, SimulationError),
    ("servo.max_current_A", 0.0, SimulationError), ("servo.max_current_A", math.inf, SimulationError),
    ("servo.pid_position.kp", -1.0, SimulationError), ("servo.fault_temperature", -math.inf, SimulationError),
    ("servo.max_velocity", "5", SimulationError), ("servo.max_velocity", True, SimulationError),
    ("servo.pid_dq_hz", 0.0, SimulationError), ("servo.pid_dq_hz", 4001.0, SimulationError),
])
def test_conf_set_refuses_what_the_drive_would_not_hold(model, name, value, error):
    drive = EmulatedDrive(model, QUIET)
    before = dict(drive.config)
    with pytest.raises(error, match=re.escape(name)):
        drive.set_config(name, value)
    assert drive.config == before


@pytest.mark.parametrize("call, match", [
    (lambda d: d.advance(-1.0), "advance"), (lambda d: d.advance(math.nan), "advance"),
    (lambda d: d.advance(1e9), "advance"), (lambda d: d.command_position(math.nan), "velocity_hz"),
    (lambda d: d.command_position(1.0, position_rev=math.inf), "position_rev"),
    (lambda d: d.command_position(1.0, max_torque_nm=-1.0), "max_torque_nm"),
    (lambda d: d.command_position(1.0, watchdog_timeout_s=-1.0), "watchdog_timeout_s"),
    (lambda d: d.command_position(1.0, feedforward_nm=math.inf), "feedforward_nm"),
    (lambda d: d.truth(1024), "counts_per_rev"),
])
def test_bad_calls_raise_one_line_naming_the_value_and_change_nothing(model, call, match):
    drive = EmulatedDrive(model, QUIET)
    state = drive._state.copy()
    with pytest.raises(SimulationError, match=match):
        call(drive)
    assert np.array_equal(drive._state, state) and drive.time_s == 0.0


@pytest.mark.parametrize("changes, match", [
    ({"encoder_bits": 14.5}, "encoder_bits"), ({"control_rate_hz": math.nan}, "control_rate_hz"),
    ({"velocity_filter_hz": 10000.0}, "velocity_filter_hz"), ({"velocity_bandwidth_hz": 200.0},
                                                                "velocity_bandwidth_hz"),
    ({"max_current_a": "20"}, "max_current_a"), ({"encoder_eccentricity_lines": 2000.0}, "eccentricity"),
    ({"current_noise_a": -1.0}, "current_noise_a"),
])
def test_a_spec_out_of_range_is_refused_naming_its_setting(model, changes, match):
    with pytest.raises(SimulationError, match=match):
        EmulatedDrive(model, dataclasses.replace(DriveSpec(), **changes))
