"""The identification on the simulated seed bench (the report's set-up), scored against the simulator's truth.

Targets (the issue): delta*eps within 0.5 %, delta within 1.5 %, eps within 2 %,
alpha within 0.003, beta within 0.01 A, cogging RMS error within 3 %; the
report's own method, which ignores the current loop, is far worse.
"""

from __future__ import annotations

import numpy as np
import pytest
from identify_helpers import assert_targets, identified, relative_error

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def seed():
    return identified("seed")


def test_joint_fit_meets_the_targets(seed):
    result, truth = seed
    assert_targets(result, truth)
    assert relative_error(result.inertia_estimate, truth["inertia_estimate"]) < 0.015


def test_result_holds_the_joint_estimates(seed):
    result, _ = seed
    joint = result.methods["joint"]
    assert result.delta_epsilon == joint.delta_epsilon
    np.testing.assert_array_equal(result.alpha, joint.alpha)
    np.testing.assert_array_equal(result.beta, joint.beta)


def test_report_method_is_far_worse(seed):
    """The report's ch. 2-4 leave a residue (the current loop's roll-off): its errors are many times the joint's."""
    result, truth = seed
    report, joint = result.methods["report"], result.methods["joint"]
    assert result.diagnostics["system_gain"]["residue"] > 0.02
    report_gain_error = relative_error(report.delta_epsilon, truth["total_system_gain"])
    assert report_gain_error > 0.02
    assert report_gain_error > 10 * relative_error(joint.delta_epsilon, truth["total_system_gain"])
    assert np.abs(report.alpha - truth["alpha"]).max() > 10 * np.abs(joint.alpha - truth["alpha"]).max()


def test_current_loop_is_identified(seed):
    """A PI loop tuned for 140 Hz on sensors with gain error eps alpha_p closes near 140 / (eps alpha_p) Hz."""
    result, truth = seed
    expected = 140.0 / (truth["epsilon"] * np.asarray(truth["alpha"]))
    np.testing.assert_allclose(result.current_loop_bandwidth_per_phase_hz, expected, rtol=0.1)


def test_standard_errors_cover_the_errors(seed):
    result, truth = seed
    assert abs(result.delta_epsilon - truth["total_system_gain"]) < 4 * result.delta_epsilon_std
    assert np.all(np.abs(result.alpha - truth["alpha"]) < 4 * result.alpha_std)


def test_calibration_corrects_the_sensors(seed):
    result, truth = seed
    np.testing.assert_allclose(result.calibration.current_scale, truth["calibration"]["current_scale"], rtol=0.02)
    np.testing.assert_allclose(result.calibration.current_offset, truth["calibration"]["current_offset"], atol=0.3)
    assert relative_error(result.calibration.torque_gain, truth["calibration"]["torque_gain"]) < 0.015


def test_every_inflated_standard_error_says_whose_it_is(seed):
    """The seed bench warns that the report's chapters' models miss structure (standard errors inflated x12 ...):
    those are the report's method's estimates, shown beside the joint fit's, which the result takes."""
    result, _ = seed
    inflated = [m for m in result.messages if "inflated" in m]
    assert inflated and all("shown beside the joint fit's" in m for m in inflated)
