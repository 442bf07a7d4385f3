"""Issue 37: the current sensors' offsets applied as far as the identification supports them, and the ripple a
calibration removes cancelled once.

On the family's fast motor 2 (tests/test_other_motors.py) the compensation trial showed the offsets' ripple at 1x
electrical; the current-sensor stage moved the calibration from it and the ilc stage learned it, and the next trial
carried both corrections (143 against 124 mN m, the sign turned); and beta, identified at 1.7 times the truth with
a standard error as large, was applied whole.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from test_stages import identified, make_pipeline, run_trials, true_calibration, true_harmonics

from ilcpmac.backends.base import BenchDescription, BenchLimits
from ilcpmac.backends.simulated import SimulatorBackend
from ilcpmac.core.records import MotorInfo, SensorCalibration
from ilcpmac.stages.base import Identified, StageSetup
from ilcpmac.stages.sensor import CurrentSensorCorrection, calibration_change_nm, offsets_applied

CPR = 1024
SCALE = 14.0  # counts per ampere
CALIBRATION = SensorCalibration(np.full(3, SCALE), np.zeros(3), 0.9)


@pytest.fixture(scope="module")
def bench(small_model) -> SimulatorBackend:
    """The seed bench at 1024 counts per revolution (test_stages.py's)."""
    return SimulatorBackend(small_model, BenchLimits(30.0, 8.0, 1.5))


def backemf(third: float) -> np.ndarray:
    """A balanced three-phase K_p (N m / A) with a third harmonic of ``third`` of its fundamental, per count."""
    theta = 2 * np.pi * 4 * np.arange(CPR)[:, None] / CPR - 2 * np.pi * np.arange(3) / 3
    return 0.2 * (np.sin(theta) + third * np.sin(3 * theta))


def identification(beta_a, beta_std_a) -> Identified:
    """Ideal sensors but for the offsets ``beta_a`` (A) identified with standard errors ``beta_std_a``."""
    return Identified(1.0, 1.0, np.ones(3), np.asarray(beta_a, float), None, CALIBRATION,
                      beta_std_a=np.asarray(beta_std_a, float))


def sensor_stage(ident: Identified) -> CurrentSensorCorrection:
    description = BenchDescription(MotorInfo(4, 24, CPR, 0.01), backemf(0.0), CALIBRATION, BenchLimits(30.0, 8.0, 1.5))
    return CurrentSensorCorrection(StageSetup(description, ident, 150))


def test_an_offset_is_applied_as_far_as_it_stands_out_of_its_standard_error():
    """Within one standard error of 0 not at all, two standard errors out by 1 - 1/4, without a standard error
    whole; and the weights are in the stage's state."""
    beta, std = np.array([0.3, -0.2, 0.1]), np.array([0.3, 0.1, 0.0])
    stage = sensor_stage(identification(beta, std))
    weights = np.array([0.0, 0.75, 1.0])
    # the controller's offset o*_s = beta G_s^-1 (counts) removes an offset current beta (eq. 1.7)
    np.testing.assert_allclose(stage.calibration().current_offset, weights * beta * SCALE, atol=1e-12)
    np.testing.assert_allclose(stage.state()["identified_offsets_weight"], weights)


@given(st.floats(-1e3, 1e3), st.floats(0.0, 1e3))
def test_an_offsets_weight_is_within_0_and_1_and_0_within_its_standard_error(beta, std):
    (weight,) = offsets_applied(np.array([beta]), np.array([std]))
    assert 0.0 <= weight <= 1.0
    if abs(beta) <= std and std > 0:
        assert weight == 0.0
    # more standard errors out, no less of it
    (further,) = offsets_applied(np.array([2 * beta]), np.array([std]))
    assert further >= weight


@pytest.mark.parametrize("third", [0.0, 0.05])
def test_a_common_offset_moves_the_torque_by_the_offset_times_the_back_emfs_sum(third):
    """A common offset o0 (counts) in every phase moves each phase's current by -G_s o0, and the torque by
    -G_s o0 sum_p K_p: nothing where the back-EMFs sum to zero (a pure sine, or a star's phases measured to
    its neutral), at 3x electrical through a third harmonic."""
    k = backemf(third)
    ident = identification(np.zeros(3), np.zeros(3))
    moved = SensorCalibration(CALIBRATION.current_scale, CALIBRATION.current_offset + 2.8, CALIBRATION.torque_gain)
    change = calibration_change_nm(ident, k, CALIBRATION, moved, 3.0, 1.0)
    np.testing.assert_allclose(change, -2.8 / SCALE * k.sum(axis=1), atol=1e-15)


def test_a_scale_moves_the_torque_by_its_phases_share_of_the_reference():
    """With an ideal loop the references are tau K_p / sum K^2 (minimum copper loss): a phase's scale moved by
    1 % moves the torque by 1 % of tau K_p^2 / sum K^2."""
    k = backemf(0.05)
    ident = identification(np.zeros(3), np.zeros(3))  # its loop ideal: none identified
    moved = SensorCalibration(CALIBRATION.current_scale * [1.01, 1.0, 1.0], CALIBRATION.current_offset, 0.9)
    change = calibration_change_nm(ident, k, CALIBRATION, moved, 3.0, 1.0)
    np.testing.assert_allclose(change, 0.01 * 3.0 * k[:, 0] ** 2 / (k**2).sum(axis=1), atol=1e-12)


def test_the_ilc_does_not_cancel_again_what_a_moved_calibration_removed(bench):
    """The simulator's bench, its true sensors known: a trial at a calibration with offsets 3 counts and scales
    1 % off, the ilc learning its ripple (1x electrical from the offsets, 2x from the imbalance), then one at the
    true calibration. Before, the ilc's feed-forward cancelled the offsets' and the imbalance's ripple a second
    time: the second trial kept 98 % of the first's at 1x and 112 % at 2x (now 3 % and 5 %)."""
    right = true_calibration(bench)
    wrong = SensorCalibration(right.current_scale * [1.01, 0.99, 1.0], right.current_offset + [3.0, 0.0, -3.0],
                              right.torque_gain)
    pipeline = make_pipeline(bench, ["ilc"], identified(bench))
    trials = run_trials(bench, pipeline, 1, 5, calibration=wrong) + run_trials(bench, pipeline, 1, 6, calibration=right)
    first, moved = (true_harmonics(bench, t) for t in trials)
    for h in (8, 16):  # 1x and 2x electrical
        assert moved[h] < 0.1 * first[h], (h, moved[h], first[h])
