"""Safety limits: whatever the stages ask, a request keeps its feed-forward, currents and torque in bounds."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from conftest import SEED_CONFIG
from ilcpmac.config import load_config
from ilcpmac.errors import ConfigError
from ilcpmac.model.tables import backemf_table
from ilcpmac.pipeline.safety import SafetyLimits, enforce_limits, torque_bound_nm
from ilcpmac.records import SensorCalibration, TrialRequest

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
    with pytest.raises(ConfigError, match="set point"):
        enforce_limits(request, backemf, limits)


def test_torque_bound_is_the_tighter_of_current_and_torque_limit():
    backemf = np.array([[0.2, -0.1, -0.1], [0.0, 0.3, -0.3], [1.0, 0.0, 0.0]])
    limits = SafetyLimits(1.0, 10.0, 8.0)
    bound = torque_bound_nm(backemf, limits)
    # I* = tau K_p / sum K^2 reaches 10 A at tau = 10 sum K^2 / max |K_p|
    np.testing.assert_allclose(bound, [np.minimum(10 * 0.06 / 0.2, 8.0), 10 * 0.18 / 0.3, 8.0])
    assert bound[0] == pytest.approx(3.0) and bound[1] == pytest.approx(6.0)


def test_excitation_beyond_the_limits_raises_and_names_them():
    backemf = np.tile([0.2, -0.1, -0.1], (N, 1))
    limits = SafetyLimits(1.0, 10.0, 8.0)  # bound 3 N m
    excitation = np.zeros(N)
    excitation[5] = 0.6
    request = TrialRequest(2.5, 0.5, 1, np.zeros(N), excitation, CALIBRATION)
    with pytest.raises(ConfigError, match=r"max_current_a 10\.0.*max_torque_nm 8\.0"):
        enforce_limits(request, backemf, limits)
    # the same excitation at a lower set point is fine
    enforce_limits(request.with_changes(torque_setpoint_nm=2.3), backemf, limits)


def test_huge_feedforward_is_clipped_to_the_limits():
    backemf = np.tile([0.2, -0.1, -0.1], (N, 1))
    limits = SafetyLimits(1.5, 10.0, 8.0)  # torque bound 3 N m
    ff = np.full(N, 1e308)
    ff[1::2] = -1e308
    out = enforce_limits(TrialRequest(2.0, 0.5, 1, ff, np.zeros(N), CALIBRATION), backemf, limits)
    np.testing.assert_allclose(out.feedforward_nm[0::2], 1.0)  # up to the 3 N m torque bound
    np.testing.assert_allclose(out.feedforward_nm[1::2], -1.5)  # down by the correction limit
