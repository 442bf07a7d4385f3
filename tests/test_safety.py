"""Safety limits: whatever the stages ask, a request keeps its feed-forward, currents, torque, speed and
calibration in bounds; one check (`request_violation`) decides what may reach a backend."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest
from conftest import SEED_CONFIG
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from ilcpmac.config import load_config
from ilcpmac.core.records import SensorCalibration, TrialRequest
from ilcpmac.model.tables import backemf_table
from ilcpmac.pipeline.safety import (
    FlowingCurrent,
    SafetyError,
    SafetyLimits,
    calibration_violation,
    clip_to_trust_region,
    enforce_limits,
    torque_interval_nm,
)

N = 32  # counts per revolution of the generated tables
TOL = 1e-9
CALIBRATION = SensorCalibration(np.full(3, 14.0), np.zeros(3), 0.908)

PROPERTY = settings(max_examples=200, derandomize=True, deadline=None, database=None,
                    suppress_health_check=[HealthCheck.too_slow])

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
limits_strategy = st.builds(
    SafetyLimits,
    max_correction_nm=st.floats(1e-3, 10.0),
    max_current_a=st.floats(0.5, 100.0),
    max_torque_nm=st.floats(0.05, 50.0),
)


_seed = load_config(SEED_CONFIG).model
#: the seed motor's back-EMF (asymmetric phases, harmonics 1, 3, 5, 7) at N counts
SEED_BACKEMF = backemf_table(_seed.winding, _seed.backemf, N)


def torque_bound_nm(backemf: np.ndarray, limits: SafetyLimits) -> np.ndarray:
    """The symmetric bound on |tau_ref| per count when only the references are bounded."""
    low, high = torque_interval_nm(backemf, limits)
    np.testing.assert_array_equal(low, -high)
    return high


@st.composite
def backemf_strategy(draw) -> np.ndarray:
    """Back-EMF tables K_p per count, N m / A: the seed motor's, or arbitrary ones (no all-zero count)."""
    if draw(st.booleans()):
        return SEED_BACKEMF
    table = draw(arrays(np.float64, (N, 3), elements=st.floats(-2.0, 2.0)))
    row_max = np.abs(table).max(axis=1)
    table[row_max < 1e-3, 0] = 1e-3  # a motor always has torque somewhere
    return table


@st.composite
def case(draw):
    """Limits, a back-EMF table, and a set point plus excitation within the limits, and any feed-forward."""
    limits = draw(limits_strategy)
    backemf = draw(backemf_strategy())
    bound = torque_bound_nm(backemf, limits)
    room = float(bound.min())
    setpoint = draw(st.floats(-1.0, 1.0)) * room
    # excitation keeps |set point + excitation| <= bound at every count (sometimes exactly on it)
    fractions = draw(arrays(np.float64, N, elements=st.one_of(st.floats(-1.0, 1.0), st.sampled_from([-1.0, 1.0]))))
    excitation = fractions * (bound - abs(setpoint)) * draw(st.sampled_from([0.0, 0.3, 1.0]))
    feedforward = draw(st.one_of(
        arrays(np.float64, N, elements=finite),  # anything, up to +-1.8e308
        arrays(np.float64, N, elements=st.floats(-3.0, 3.0)).map(lambda a: a * limits.max_correction_nm),
    ))
    request = TrialRequest(setpoint, 0.5, 1, feedforward, excitation, CALIBRATION)
    return limits, backemf, request


def currents(tau_ref: np.ndarray, backemf: np.ndarray) -> np.ndarray:
    """I*_p = tau_ref K_p / sum K^2 per count and phase."""
    return tau_ref[:, None] * backemf / np.sum(backemf**2, axis=1, keepdims=True)


@PROPERTY
@given(case())
def test_enforced_request_stays_within_every_limit(args):
    limits, backemf, request = args
    out = enforce_limits(request, backemf, limits)
    ff = out.feedforward_nm
    assert ff.shape == (N,) and np.all(np.isfinite(ff))
    assert np.all(np.abs(ff) <= limits.max_correction_nm * (1 + TOL) + TOL)
    tau_ref = out.torque_reference_nm()
    assert np.all(np.abs(tau_ref) <= limits.max_torque_nm * (1 + TOL) + TOL)
    assert np.all(np.abs(currents(tau_ref, backemf)) <= limits.max_current_a * (1 + TOL) + TOL)
    # only the feed-forward changes
    assert out.torque_setpoint_nm == request.torque_setpoint_nm
    np.testing.assert_array_equal(out.excitation_nm, request.excitation_nm)
    assert out.calibration is request.calibration


@PROPERTY
@given(case())
def test_clipping_is_minimal(args):
    """A count whose feed-forward already obeys the limits keeps it; a clipped one ends on a limit."""
    limits, backemf, request = args
    out = enforce_limits(request, backemf, limits)
    ff_in, ff_out = request.feedforward_nm, out.feedforward_nm
    base = request.torque_setpoint_nm + request.excitation_nm
    bound = torque_bound_nm(backemf, limits)
    scale = np.maximum(np.abs(base), 1.0)
    fine = (np.abs(ff_in) <= limits.max_correction_nm) & (np.abs(base + ff_in) <= bound)
    np.testing.assert_allclose(ff_out[fine], ff_in[fine], rtol=0, atol=1e-12 * scale[fine].max(initial=1.0))
    clipped = ~fine
    on_correction_limit = np.isclose(np.abs(ff_out), limits.max_correction_nm, rtol=TOL, atol=TOL)
    on_torque_bound = np.isclose(np.abs(base + ff_out), bound, rtol=TOL, atol=TOL * scale)
    assert np.all((on_correction_limit | on_torque_bound)[clipped])
    # clipping never flips the correction's sign
    assert np.all(ff_out * np.sign(ff_in) >= -TOL * scale)
    # and it is idempotent
    again = enforce_limits(out, backemf, limits)
    np.testing.assert_allclose(again.feedforward_nm, ff_out, rtol=0, atol=TOL * scale.max())


@PROPERTY
@given(limits_strategy, backemf_strategy(), st.floats(1.0 + 1e-6, 100.0), st.booleans())
def test_setpoint_alone_beyond_the_limits_raises(limits, backemf, factor, negative):
    bound = torque_bound_nm(backemf, limits)
    setpoint = float(bound.min()) * factor * (-1.0 if negative else 1.0)
    request = TrialRequest(setpoint, 0.5, 1, np.zeros(N), np.zeros(N), CALIBRATION)
    with pytest.raises(SafetyError, match="set point"):
        enforce_limits(request, backemf, limits)


def test_torque_bound_is_the_tighter_of_current_and_torque_limit():
    backemf = np.array([[0.2, -0.1, -0.1], [0.0, 0.3, -0.3], [1.0, 0.0, 0.0]])
    limits = SafetyLimits(max_correction_nm=1.0, max_current_a=10.0, max_torque_nm=8.0)
    bound = torque_bound_nm(backemf, limits)
    # I* = tau K_p / sum K^2 reaches 10 A at tau = 10 sum K^2 / max |K_p|
    np.testing.assert_allclose(bound, [np.minimum(10 * 0.06 / 0.2, 8.0), 10 * 0.18 / 0.3, 8.0])
    assert bound[0] == pytest.approx(3.0) and bound[1] == pytest.approx(6.0)


def test_excitation_beyond_the_limits_raises_and_names_them():
    backemf = np.tile([0.2, -0.1, -0.1], (N, 1))
    limits = SafetyLimits(max_correction_nm=1.0, max_current_a=10.0, max_torque_nm=8.0)  # bound 3 N m
    excitation = np.zeros(N)
    excitation[5] = 0.6
    request = TrialRequest(2.5, 0.5, 1, np.zeros(N), excitation, CALIBRATION)
    with pytest.raises(SafetyError, match=r"set point 2.5 N m with its excitation: current reference 10\.\d+ A in "
                                          r"phase a at count 5 exceeds the bench limit of 10 A"):
        enforce_limits(request, backemf, limits)
    # the same excitation at a lower set point is fine
    enforce_limits(request.with_changes(torque_setpoint_nm=2.3), backemf, limits)


def test_huge_feedforward_is_clipped_to_the_limits():
    backemf = np.tile([0.2, -0.1, -0.1], (N, 1))
    limits = SafetyLimits(max_correction_nm=1.5, max_current_a=10.0, max_torque_nm=8.0)  # torque bound 3 N m
    ff = np.full(N, 1e308)
    ff[1::2] = -1e308
    out = enforce_limits(TrialRequest(2.0, 0.5, 1, ff, np.zeros(N), CALIBRATION), backemf, limits)
    np.testing.assert_allclose(out.feedforward_nm[0::2], 1.0)  # up to the 3 N m torque bound
    np.testing.assert_allclose(out.feedforward_nm[1::2], -1.5)  # down by the correction limit


# ---------------------------------------------------------------- the flowing current


def test_a_zero_back_emf_row_admits_only_zero_torque_and_never_a_nan_bound():
    backemf = np.tile([0.2, -0.1, -0.1], (N, 1))
    backemf[7] = 0.0
    limits = SafetyLimits(max_correction_nm=1.0, max_current_a=10.0, max_torque_nm=8.0)
    for flowing in (None, FlowingCurrent(np.full(3, 1.1), np.array([0.5, -0.5, 0.0]))):
        low, high = torque_interval_nm(backemf, limits, flowing)
        assert np.all(np.isfinite(low)) and np.all(np.isfinite(high))
        assert low[7] == 0.0 and high[7] == 0.0 and high[0] > 2.0
    with pytest.raises(SafetyError, match="torque reference 1 N m at count 7, where the back-EMF table is zero"):
        enforce_limits(TrialRequest(1.0, 0.5, 1, np.zeros(N), np.zeros(N), CALIBRATION), backemf, limits)
    out = enforce_limits(TrialRequest(0.0, 0.5, 1, np.ones(N), np.zeros(N), CALIBRATION), backemf, limits)
    assert out.feedforward_nm[7] == 0.0 and out.feedforward_nm[0] == 1.0


def test_the_flowing_current_bounds_the_torque_with_the_sensors_gain_and_offset():
    """i_p = epsilon alpha_p I*_p + beta_p: a sensor reading half the current lets twice the reference flow."""
    backemf = np.tile([0.2, -0.1, -0.1], (N, 1))  # I*_a = tau / 0.3 per N m
    limits = SafetyLimits(max_correction_nm=10.0, max_current_a=10.0, max_torque_nm=8.0)
    low, high = torque_interval_nm(backemf, limits, FlowingCurrent(np.array([2.0, 1.0, 1.0]), np.array([1.0, 0, 0])))
    # phase a: |2 tau / 0.3 + 1| <= 10 -> tau in [-1.65, 1.35]; phases b, c: |tau / 0.6| <= 10
    np.testing.assert_allclose(low, -1.65)
    np.testing.assert_allclose(high, 1.35)
    request = TrialRequest(1.0, 0.5, 1, np.full(N, 5.0), np.zeros(N), CALIBRATION)
    out = enforce_limits(request, backemf, limits, FlowingCurrent(np.array([2.0, 1.0, 1.0]), np.array([1.0, 0, 0])))
    np.testing.assert_allclose(out.torque_reference_nm(), 1.35)


def test_calibration_truth_and_flowing_current_agree_with_the_simulator(small_simulator):
    """FlowingCurrent.at is the simulator's epsilon alpha and beta for any calibration."""
    sim = small_simulator
    truth = SensorCalibration(sim.scale_true, sim.offset_true, sim.torque_gain_true)
    calibration = SensorCalibration([15.0, 17.0, 30.0], [3.0, -2.0, 0.5], 0.8)
    flowing, t = FlowingCurrent.at(calibration, truth), sim.truth(calibration)
    np.testing.assert_allclose(flowing.gain, t.epsilon * t.alpha)
    np.testing.assert_allclose(flowing.offset_a, t.beta_a)


# ---------------------------------------------------------------- the calibration trust region

TRUST = SafetyLimits(max_correction_nm=1.5, max_current_a=30.0, max_torque_nm=8.0, max_scale_deviation=0.1,
                     max_offset_deviation_a=0.5, max_torque_gain_deviation=0.1, from_config=True)
TRUTH = SensorCalibration([25.0, 18.0, 18.0], [25.0, -9.0, -9.0], 0.75)


@pytest.mark.parametrize("calibration, message", [
    (CALIBRATION, None),  # the bench's own
    (TRUTH, None),
    (SensorCalibration([27.4, 18.0, 18.0], [25.0, -9.0, -9.0], 0.75), None),
    (SensorCalibration([25.0, 20.0, 18.0], [25.0, -9.0, -9.0], 0.75),
     r"current scale of phase b deviates \+11.11 % from the identified sensors, beyond 10 % "
     r"\(\[limits\] max_scale_deviation\)"),
    (SensorCalibration([25.0, 18.0, 18.0], [25.0, -9.0, 1.0], 0.75),
     r"current offset of phase c deviates \+0.5556 A from the identified sensors, beyond 0.5 A "
     r"\(\[limits\] max_offset_deviation_a\)"),
    (SensorCalibration([25.0, 18.0, 18.0], [25.0, -9.0, -9.0], 0.9),
     r"torque gain deviates \+20 % from the identified sensors, beyond 10 % \(\[limits\] max_torque_gain_deviation\)"),
])
def test_a_calibration_is_trusted_near_the_bench_s_or_the_identified_one(calibration, message):
    why = calibration_violation(calibration, CALIBRATION, TRUTH, TRUST)
    assert why is None if message is None else re.fullmatch(message, why)
    clipped = clip_to_trust_region(calibration, CALIBRATION, TRUTH, TRUST)
    if message is None:
        assert clipped is calibration
    else:
        assert calibration_violation(clipped, CALIBRATION, TRUTH, TRUST) is None
    # before identification only the bench's calibration is trusted
    assert (calibration_violation(calibration, CALIBRATION, None, TRUST) is None) == (calibration is CALIBRATION)


def test_a_calibration_far_off_is_clipped_to_the_edge_of_the_region_around_the_identified_one():
    far = SensorCalibration([250.0, 1.0, 18.0], [-100.0, 100.0, -9.0], 75.0)
    clipped = clip_to_trust_region(far, CALIBRATION, TRUTH, TRUST)
    np.testing.assert_allclose(clipped.current_scale, [27.5, 16.2, 18.0])
    np.testing.assert_allclose(clipped.current_offset, [25.0 - 12.5, -9.0 + 9.0, -9.0])
    assert clipped.torque_gain == pytest.approx(0.825)


# ---------------------------------------------------------------- the one check, the pipeline, the guard


@pytest.mark.parametrize("changes, malformed, message", [
    ({}, None, None),
    ({"speed_setpoint_hz": 3.0}, False,
     r"speed set point 3 Hz exceeds 1.5 Hz \(\[limits\] max_speed_hz or the bench's\)"),
    ({"speed_setpoint_hz": np.nan}, True, "speed set point must be positive, got nan Hz"),
    ({"torque_setpoint_nm": np.inf}, True, "torque set point must be finite, got inf"),
    ({"excitation_nm": np.full(1024, np.nan)}, True, "excitation_nm holds NaN or infinite values"),
    ({"feedforward_nm": np.zeros(1023)}, True, r"feedforward_nm has shape \(1023,\), the bench needs \(1024,\)"),
    ({"feedforward_nm": [0.0] * 1024}, True, "feedforward_nm must be an array of real numbers, got list"),
    ({"revolutions": 2.5}, True, "revolutions must be an integer, got 2.5"),
    ({"revolutions": 2000}, False, r"2000 revolutions of 1024 counts \(2048000 samples\) exceed 2e\+06 samples "
                                   r"\(\[limits\] max_samples_per_trial\)"),
    ({"revolutions": 600}, False, r"the trial lasts 801.3 s \(1 warm-up and 600 revolutions at 0.75 Hz\), beyond "
                                  r"600 s \(\[limits\] max_trial_duration_s\)"),
    ({"torque_setpoint_nm": 9.0}, False, r"torque reference 9 N m at count 0 .* exceeds 8 N m \(\[limits\] "
                                         r"max_torque_nm or the bench's\)"),
])
def test_request_violation_names_what_is_wrong(limits_bench, changes, malformed, message):
    from ilcpmac.pipeline.safety import request_violation

    _, description, _, limits, base = limits_bench
    violation = request_violation(base.with_changes(**changes), description, limits)
    if message is None:
        assert violation is None
    else:
        assert violation.malformed is malformed and re.fullmatch(message, violation.message), violation


def test_the_flowing_current_is_bounded_once_the_sensors_are_identified(limits_bench):
    """At 5 N m with the identified calibration scaled by 4, the references stay under 20 A but 4 times
    that would flow: refused once the identified sensors are known."""
    from ilcpmac.pipeline.safety import identified_truth, request_violation

    _, description, identified, _, base = limits_bench
    truth = identified_truth(identified)
    # no trust region
    limits = SafetyLimits(max_correction_nm=1.5, max_current_a=30.0, max_torque_nm=8.0, from_config=True)
    four = base.with_changes(torque_setpoint_nm=5.0, calibration=dataclasses.replace(
        truth, current_scale=4 * truth.current_scale))
    assert request_violation(four, description, limits) is None  # the references alone are fine
    violation = request_violation(four, description, limits, truth)
    assert re.fullmatch(r"flowing current -?[67]\d\.\d+ A in phase [abc] at count \d+ \(epsilon alpha and beta of "
                        r"the identified sensors at this calibration\) exceeds 30 A \(\[limits\] max_current_a or "
                        r"the bench's\)", violation.message), violation


class Stage:
    """A stage whose output is ``change(request)``."""

    def __init__(self, name, change) -> None:
        self.name, self.change = name, change

    def shape(self, request):
        return self.change(request)


@pytest.mark.parametrize("change, message", [
    (lambda r: r.with_changes(feedforward_nm=r.feedforward_nm * np.nan), "feedforward_nm holds NaN"),
    (lambda r: r.with_changes(feedforward_nm=np.zeros(7)), r"feedforward_nm has shape \(7,\)"),
    (lambda r: r.with_changes(speed_setpoint_hz=3.0), r"speed set point 3 Hz exceeds 1.5 Hz"),
    (lambda r: r.with_changes(calibration=dataclasses.replace(r.calibration, torque_gain=np.nan)), "calibration"),
    (lambda r: r.with_changes(torque_setpoint_nm=12.0), "set point 12 N m with its excitation: torque reference"),
    (lambda r: None, "a request must be a TrialRequest, got None"),
])
def test_the_pipeline_rejects_a_stage_s_invalid_output_naming_the_stage(limits_bench, change, message):
    from ilcpmac.pipeline.pipeline import Pipeline

    _, description, identified, limits, base = limits_bench
    pipeline = Pipeline([Stage("fine", lambda r: r), Stage("rogue", change)], description, identified, limits, 40)
    with pytest.raises(SafetyError, match=f"^stage 'rogue': {message}|^stage 'rogue' {message}"):
        pipeline.shape(base)


def test_the_guard_refuses_before_the_backend_sees_anything(limits_bench):
    from ilcpmac.backends.guard import LimitGuard

    _, description, _, limits, base = limits_bench
    seen = []

    class Recording:
        max_parallel_trials = 3

        def run_trial(self, request):
            seen.append(request)

    guard = LimitGuard(Recording(), description, limits)
    assert guard.max_parallel_trials == 3 and guard.describe() is description
    guard.run_trial(base)
    with pytest.raises(SafetyError, match=r"^trial at 3.0 N m, 3.0 Hz refused before it reached the backend: "
                                          r"speed set point 3 Hz exceeds 1.5 Hz"):
        guard.run_trial(base.with_changes(speed_setpoint_hz=3.0))
    (sent,) = seen  # the guard's own copy of what it checked
    assert sent is not base and all(np.array_equal(getattr(sent, f.name), getattr(base, f.name))
                                    for f in dataclasses.fields(base) if f.name != "calibration")
