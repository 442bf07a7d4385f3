"""The simulated drive as people have one (`ilcpmac.sim.drive_log`): its own encoder read once per control period,
with a position-locked error; a host polling it with jitter, transit and a coarse clock; dry friction that sticks;
and a speed bound set by what the model integrates, not by either encoder's lines."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ilcpmac.sim.drive_log import LogPlan, _host, drive_log, encoder_terms, highest_order
from ilcpmac.sim.simulator import Simulator

TWO_PI = 2.0 * np.pi


@pytest.fixture(scope="module")
def simulator(seed_config) -> Simulator:
    """The seed bench (4096 counts, 20 kHz control, tables up to order 100)."""
    return Simulator(seed_config.model)


@pytest.fixture(scope="module")
def quiet(seed_config) -> Simulator:
    """The seed bench without current noise (the logged i_q is the flowing one) and with 0.05 N m of Coulomb
    friction."""
    m = seed_config.model
    return Simulator(dataclasses.replace(
        m, current_sensors=dataclasses.replace(m.current_sensors, noise_counts=0.0),
        mechanics=dataclasses.replace(m.mechanics, coulomb_friction_nm=0.05)))


def lines_off(log, plan: LogPlan) -> np.ndarray:
    """The logged position (rad, multi-turn) less the true angle, in lines of the drive's encoder."""
    return (log.columns["position"] - log.angle_rad) * 2**plan.encoder_bits / TWO_PI


def profile(angle_rad: np.ndarray, eccentricity: float, phase: float, harmonics) -> np.ndarray:
    """E sin(theta + phi_1) + sum_k A_k sin(k theta + phi_k), written out here rather than taken from the plan."""
    error = eccentricity * np.sin(angle_rad + phase)
    for order, amplitude, phi in harmonics:
        error += amplitude * np.sin(order * angle_rad + phi)
    return error


@pytest.mark.parametrize("bits, eccentricity, phase, harmonics", [
    (14, 0.1, 0.0, []),                                          # the brief's small actuator
    (12, 2.0, 1.0, [(2, 1.5, 0.0), (3, 0.4, -0.7), (4, 0.2, 0.0)]),  # a magnetic encoder's nonlinearity
    (20, 0.0, 0.0, [(2, 30.0, 0.5)]),
])
def test_the_reading_is_the_true_angle_plus_its_error_profile_rounded_to_a_line(simulator, bits, eccentricity,
                                                                                phase, harmonics):
    spec = ",".join(f"{k}:{a}:{p}" for k, a, p in harmonics)
    plan = LogPlan(duration_s=2.0, encoder_bits=bits, encoder_eccentricity_counts=eccentricity,
                   encoder_eccentricity_phase_rad=phase, encoder_harmonics=spec)
    log = drive_log(simulator, plan)
    off = lines_off(log, plan)
    expected = profile(log.angle_rad, eccentricity, phase, harmonics)
    assert np.abs(off - expected).max() <= 0.5 + 1e-6
    # the truth: e at each [bench] count, in the drive's lines and in [bench] counts
    cpr, lines = simulator.model.encoder.counts_per_rev, 2**bits
    error = log.truth["drive_encoder"]["error"]
    at_counts = profile(TWO_PI * np.arange(cpr) / cpr, eccentricity, phase, harmonics)
    np.testing.assert_allclose(error["drive_counts"], at_counts, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(error["bench_counts"]) * lines / cpr, at_counts, rtol=0, atol=1e-12)
    # the log read at the nearest [bench] count gives the truth's profile back within a quantum and the profile's
    # change over half a count (its slope, E + sum k A_k lines per rad, times pi / cpr)
    count = np.floor(log.angle_rad % TWO_PI * cpr / TWO_PI + 0.5).astype(int) % cpr
    slope = eccentricity + sum(k * a for k, a, _ in harmonics)
    assert np.abs(off - np.asarray(error["drive_counts"])[count]).max() <= 0.5 + slope * np.pi / cpr + 1e-6


def test_a_known_eccentricity_reads_back_from_the_log(simulator):
    """0.1 lines at 14 bits over one revolution: the reading's once-per-revolution error, fitted, is 0.1 lines."""
    plan = LogPlan(duration_s=2.0, encoder_bits=14, encoder_eccentricity_counts=0.1, encoder_eccentricity_phase_rad=0.6)
    log = drive_log(simulator, plan)
    basis = np.column_stack([np.sin(log.angle_rad), np.cos(log.angle_rad), np.ones_like(log.angle_rad)])
    (a, b, _), *_ = np.linalg.lstsq(basis, lines_off(log, plan), rcond=None)
    assert math.hypot(a, b) == pytest.approx(0.1, abs=0.02)
    assert math.atan2(b, a) == pytest.approx(0.6, abs=0.2)


def test_line_errors_shift_each_lines_span_the_same_in_every_log_of_an_encoder_seed(simulator):
    """Spans shifted within +-0.3 lines: the reading errs by up to 0.8 lines, and two logs of the same encoder at
    other instants (other polling seeds) read the same line at the same angle; another encoder seed does not."""
    def rows(encoder_seed: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
        plan = LogPlan(duration_s=2.0, encoder_bits=10, jitter_s=3e-4, encoder_line_error_counts=0.3,
                       encoder_seed=encoder_seed, seed=seed)
        log = drive_log(simulator, plan)
        off = lines_off(log, plan)
        assert 0.6 < np.abs(off).max() <= 0.8 + 1e-6
        return log.angle_rad, np.round(log.columns["position"] * 2**10 / TWO_PI)

    def monotone(*logs) -> bool:
        angle, reading = (np.concatenate(parts) for parts in zip(*logs))
        return bool(np.all(np.diff(reading[np.argsort(angle)]) >= 0))

    same = rows(4, 0), rows(4, 1)
    assert monotone(*same)
    assert not monotone(same[0], rows(5, 1))


def test_the_position_comes_in_lines_or_rad_multi_turn_or_wrapped(simulator):
    base = LogPlan(duration_s=2.0, speed_hz=2.0, encoder_bits=10)
    rad = drive_log(simulator, base).columns["position"]
    counts = drive_log(simulator, dataclasses.replace(base, position_unit="counts")).columns["position"]
    assert np.array_equal(counts, np.round(counts)) and counts[-1] > 3 * 1024
    np.testing.assert_allclose(counts * TWO_PI / 1024, rad, rtol=0, atol=1e-12)
    wrapped = drive_log(simulator, dataclasses.replace(base, position_unit="counts", position_wrap=True))
    assert wrapped.columns["position"].min() >= 0 and wrapped.columns["position"].max() <= 1023
    assert np.array_equal(np.unwrap(wrapped.columns["position"], period=1024), counts)
    wrapped_rad = drive_log(simulator, dataclasses.replace(base, position_wrap=True)).columns["position"]
    assert wrapped_rad.min() >= 0 and wrapped_rad.max() < TWO_PI
    np.testing.assert_allclose(np.unwrap(wrapped_rad), rad, rtol=0, atol=1e-9)


CONTROL_HZ = 20000.0


@settings(max_examples=60, deadline=None)
@given(rate_hz=st.sampled_from([100.0, 1000.0, 10000.0]), jitter_s=st.floats(0.0, 0.01),
       latency_s=st.floats(0.0, 0.01), stamp_s=st.sampled_from([0.0, 1e-6, 1e-4, 1e-3]),
       seed=st.integers(0, 2**32))
def test_the_hosts_rows_keep_time_order_on_its_clock_and_each_reading_follows_its_stamp(rate_hz, jitter_s, latency_s,
                                                                                       stamp_s, seed):
    plan = LogPlan(rate_hz=rate_hz, duration_s=0.2, jitter_s=jitter_s, latency_s=latency_s, stamp_s=stamp_s,
                   seed=seed)
    read, stamps, left_out = _host(plan, CONTROL_HZ, np.random.default_rng(seed))
    dt = 1.0 / CONTROL_HZ
    assert read.size + left_out == int(0.2 * rate_hz) and read.size >= 1
    assert np.all(np.diff(stamps) > 0) and np.all(np.diff(read) >= 0) and read[0] >= 0
    if stamp_s:
        ticks = stamps / stamp_s
        assert np.abs(ticks - np.round(ticks)).max() < 1e-6
    lag = read * dt - stamps  # the reading comes after its stamp by the transit, within a tick and half a period
    assert lag.min() >= -1e-9 and lag.max() <= latency_s + stamp_s + dt / 2 + 1e-9
    if not (stamp_s or left_out):  # the k-th row within the jitter of the k-th slot (order statistics)
        slots = (np.arange(read.size) + 0.5) / rate_hz
        assert np.all(stamps >= slots - jitter_s - dt) and np.all(stamps <= slots + jitter_s + dt)


def test_a_host_without_jitter_transit_or_tick_stamps_each_slot_on_its_control_period():
    plan = LogPlan(duration_s=0.1)
    read, stamps, left_out = _host(plan, CONTROL_HZ, np.random.default_rng(0))
    steps = np.round((np.arange(100) + 0.5) / 1000.0 * CONTROL_HZ)
    assert left_out == 0 and np.array_equal(read, steps) and np.array_equal(stamps, steps * (1.0 / CONTROL_HZ))


def test_a_1_ms_clock_on_a_jittery_1_khz_poll_leaves_rows_out_and_varies_the_intervals():
    """The case of a Python loop: rows 0.2-5 ms apart in truth, stamps in whole milliseconds, increasing."""
    plan = LogPlan(duration_s=2.0, jitter_s=2e-3, stamp_s=1e-3, latency_s=5e-4)
    read, stamps, left_out = _host(plan, CONTROL_HZ, np.random.default_rng(3))
    intervals = np.diff(stamps)
    assert 0 < left_out < 1000 and np.all(intervals > 0)
    assert np.allclose(intervals, np.round(intervals * 1e3) * 1e-3) and intervals.max() >= 3e-3
    assert np.diff(read).min() < 0.2e-3 * CONTROL_HZ


def test_a_soft_speed_loop_on_a_cogging_motor_sticks_runs_back_and_breaks_away(quiet):
    """0.1 Hz under a 1 Hz speed loop against 0.5 N m of cogging and 0.15 N m of dry friction: the rotor stops
    where the cogging holds it, runs back, and the loop's integrator breaks it away, as on the ODrive log; it sticks
    only where the drive's torque and the position torque stay within the dry friction."""
    plan = LogPlan(speed_hz=0.1, speed_bandwidth_hz=1.0, duration_s=10.0, load_nm=0.1)
    log = drive_log(quiet, plan)
    step = np.diff(log.angle_rad)
    assert log.truth["motion"] == {"rows_backwards": int(np.sum(step < 0)), "rows_still": int(np.sum(step == 0))}
    assert np.sum(step < 0) > 20 and np.sum(step == 0) > 200
    assert (log.angle_rad[-1] - log.angle_rad[0]) / TWO_PI > 0.8
    cpr = quiet.model.encoder.counts_per_rev
    grid = TWO_PI * np.arange(cpr + 1) / cpr

    def table(key: str, column: str) -> np.ndarray:
        values = np.asarray(log.truth[key][column])
        return np.interp(log.angle_rad % TWO_PI, grid, np.append(values, values[0]))

    applied = table("torque_per_ampere", "nm_per_a") * log.columns["i_q"] + table("position_torque", "torque")
    still = np.flatnonzero(step == 0)  # within the per-count tables' interpolation error (0.3 mN m at order 48)
    assert np.abs(applied[still]).max() <= 0.05 + 0.1 + 1e-3


def test_a_14_bit_drive_at_6_hz_simulates_at_the_seed_control_rate(simulator):
    """The log kernel reads the tables at the rotor's angle: 6 Hz x 2^14 lines (or x 4096 counts) is far above
    half of 20 kHz, and no count needs two control periods."""
    plan = LogPlan(speed_hz=6.0, encoder_bits=14, duration_s=1.0, encoder_eccentricity_counts=0.1)
    assert plan.problem(simulator) is None
    log = drive_log(simulator, plan)
    assert (log.angle_rad[-1] - log.angle_rad[0]) / TWO_PI == pytest.approx(6.0, rel=0.02)


def test_the_speed_bound_is_the_fastest_tabled_order_against_the_control_rate(simulator):
    """The seed bench's tables reach order 100 (its disturbance; cogging 96, torque per ampere (7 + 1) x 8 = 64):
    20 control periods per period at 20 kHz allow 10 Hz; an encoder error harmonic of order 200 halves it."""
    m = simulator.model
    assert highest_order(m, LogPlan()) == 100
    assert LogPlan(speed_hz=10.0).problem(simulator) is None
    assert LogPlan(speed_hz=10.01).problem(simulator) == (
        "speed_hz: 10.01 Hz x the tables' highest order 100 is more than the control rate / 20 = 1000 Hz (each "
        "period of the fastest position-locked term needs 20 control periods)")
    plan = LogPlan(speed_hz=6.0, encoder_harmonics="200:0.1")
    assert highest_order(m, plan) == 200 and plan.problem(simulator).startswith("speed_hz: 6 Hz x the tables' ")


@pytest.mark.parametrize("options, start", [
    ({"encoder_harmonics": "1:0.1"}, "encoder_harmonics: invalid value '1:0.1' (the drive encoder's error"),
    ({"encoder_harmonics": "3000:0.1"}, "encoder_harmonics: invalid value"),
    ({"encoder_harmonics": "2:0.1,2:0.2"}, "encoder_harmonics: invalid value"),
    ({"encoder_eccentricity_counts": 400.0, "encoder_bits": 12},
     "encoder_eccentricity_counts: the error's slope E + sum k A_k = 400 lines per rad is more than 2^encoder_bits"),
    ({"encoder_harmonics": "4:100", "encoder_bits": 12}, "encoder_harmonics: the error's slope"),
    ({"encoder_line_error_counts": 0.5}, "encoder_line_error_counts: invalid value 0.5"),
    ({"jitter_s": 0.02}, "jitter_s: invalid value 0.02"),
    ({"stamp_s": 0.002}, "stamp_s: invalid value 0.002"),
    ({"position_unit": "deg"}, "position_unit: invalid value 'deg'"),
    ({"rate_hz": 20000.0}, "rate_hz: 20000 Hz is more than half the control rate 20000 Hz"),
    ({"duration_s": 0.001}, "duration_s: 0.001 s x 1000 Hz is 1 rows, not within a log's 2..4194304"),
])
def test_a_plan_out_of_range_is_named(simulator, options, start):
    problem = LogPlan(**options).problem(simulator)
    assert problem is not None and problem.startswith(start), problem


@settings(max_examples=200, deadline=None)
@given(st.text(alphabet="0123456789:,.-+eEinfa ", max_size=24))
def test_any_harmonics_text_is_terms_in_range_or_refused_never_an_exception(simulator, text):
    terms = encoder_terms(text)
    if terms is not None:
        assert len({order for order, _, _ in terms}) == len(terms)
        assert all(2 <= order <= 256 and 0 <= amplitude <= 2**22 and abs(phase) <= TWO_PI
                   for order, amplitude, phase in terms)
    problem = LogPlan(encoder_harmonics=text).problem(simulator)
    if terms is None:
        assert problem is not None and problem.startswith("encoder_harmonics: invalid value")
    else:  # in range, and then within the slope's and the speed's bounds or refused by them
        assert problem is None or problem.startswith(("encoder_harmonics: the error's slope", "speed_hz: "))
