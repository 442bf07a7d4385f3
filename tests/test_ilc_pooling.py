"""The ILC's pooling over set points (issue 25: a ripple every set point shares, each set point seeing it only at
its own noise, as an encoder's line errors leave it through the cogging's slope), against a known truth.

The plant is the stage's own model (G = G^), so what is left after learning is what the estimates miss: the
true ripple d, the learned feed-forward u, and the residual d + G u per harmonic, at every set point.
"""

from __future__ import annotations

import numpy as np
import pytest

from ilcpmac.backends.base import BenchDescription, BenchLimits
from ilcpmac.core.records import MotorInfo, SensorCalibration, TrialData, TrialRequest
from ilcpmac.signals.harmonics import harmonic_amplitudes
from ilcpmac.stages.base import Frame, Identified, StageSetup
from ilcpmac.stages.ilc import IterativeLearningControl

CPR = 1024
H = 150
POINTS = [(t, s) for t in (1.0, 3.0, 5.0) for s in (0.5, 1.0, 1.5)]
CALIBRATION = SensorCalibration(np.full(3, 14.0), np.zeros(3), 0.9)
#: the variance of each harmonic of one trial's synchronous average, N m^2 (0.2 mN m standard deviation)
VARIANCE_NM2 = 0.2e-3**2


def stage(pooling: str, max_torque_nm: float = 8.0, **options: object) -> IterativeLearningControl:
    description = BenchDescription(MotorInfo(8, 48, CPR, 0.01), np.ones((CPR, 3)), CALIBRATION,
                                   BenchLimits(30.0, max_torque_nm, 1.5))
    identified = Identified(1.0, 1.0, np.ones(3), np.zeros(3), np.zeros(CPR), CALIBRATION)
    return IterativeLearningControl(StageSetup(description, identified, H, {"pooling": pooling, **options}))


def residuals(ilc: IterativeLearningControl, ripple_nm: dict, trials: int, seed: int,
              variance_nm2: float = VARIANCE_NM2) -> dict:
    """``trials`` rounds of one trial at every set point of ``ripple_nm`` (harmonics 1..H of d, N m), each harmonic
    measured with noise of ``variance_nm2``; the residual d + G u per set point after the last."""
    rng = np.random.default_rng(seed)

    def request(point) -> TrialRequest:
        plain = TrialRequest(*point, 4, np.zeros(CPR), np.zeros(CPR), CALIBRATION)
        return ilc.shape(plain)

    def left(point) -> np.ndarray:
        r = request(point)
        G = ilc.plant(r, point[1])
        return ripple_nm[point] + G * harmonic_amplitudes(r.feedforward_nm)[1: H + 1]

    for _ in range(trials):
        for point in ripple_nm:
            noise = rng.normal(size=H) + 1j * rng.normal(size=H)
            measured = np.concatenate([[0.0], left(point) + noise * np.sqrt(variance_nm2 / 2)])
            trial = TrialData(*point, np.arange(CPR), np.zeros(CPR), np.zeros((CPR, 3)), np.zeros(CPR),
                              request=request(point))
            ilc.learn(trial, Frame({}, measured, np.full(H + 1, variance_nm2), 1.0, point[1]))
    return {point: left(point) for point in ripple_nm}


def shared_ripple(seed: int) -> np.ndarray:
    """A ripple over every harmonic at about 0.6 standard deviations of one trial (1.2 of a set point's four):
    no set point's trials show a harmonic of it, the nine set points' together do."""
    rng = np.random.default_rng(seed)
    return 0.6 * np.sqrt(VARIANCE_NM2 / 2) * (rng.normal(size=H) + 1j * rng.normal(size=H))


@pytest.mark.parametrize("seed", [3, 4])
def test_pooling_learns_a_ripple_the_set_points_share_below_each_ones_noise(seed):
    d = shared_ripple(seed)
    truth = {point: d for point in POINTS}
    pooled = residuals(stage("points"), truth, 4, seed)
    alone = residuals(stage("none"), truth, 4, seed)
    power = float(np.sum(np.abs(d) ** 2))
    left_pooled = np.mean([np.sum(np.abs(r) ** 2) for r in pooled.values()])
    left_alone = np.mean([np.sum(np.abs(r) ** 2) for r in alone.values()])
    assert left_alone > 0.6 * power  # alone, each set point leaves most of it (75 % measured)
    assert left_pooled < 0.25 * power  # pooled, 16 % measured
    assert left_pooled < 0.3 * left_alone


def test_a_motor_24x_smaller_in_torque_and_noise_learns_the_same():
    """The seed bench's torque limit, 8 N m, against a 0.336 N m motor's, its ripple and noise scaled alike: what
    pooling leaves is scaled alike. With the process noise an absolute 1e-5 N m per trial (above the small motor's
    8.4e-6 N m of noise per harmonic), the small motor left 41 % of the shared ripple against the large one's 16 %."""
    scale = 0.336 / 8.0
    d = shared_ripple(3)
    large = residuals(stage("points"), {point: d for point in POINTS}, 4, 3)
    small = residuals(stage("points", 8.0 * scale), {point: scale * d for point in POINTS}, 4, 3,
                      scale**2 * VARIANCE_NM2)
    for point in POINTS:
        np.testing.assert_allclose(small[point], scale * large[point], rtol=1e-6, atol=1e-12 * scale)


def test_a_ripple_of_one_set_point_stays_there():
    """What one set point has and the others do not is learned where it is, and not fed forward elsewhere."""
    own = np.zeros(H, complex)
    own[[19, 35, 99]] = 5e-3  # 25 standard deviations of one trial: plain to see
    truth = {point: own if point == (5.0, 1.0) else np.zeros(H, complex) for point in POINTS}
    left = residuals(stage("points"), truth, 4, 5)
    assert np.sum(np.abs(left[(5.0, 1.0)]) ** 2) < 0.01 * np.sum(np.abs(own) ** 2)
    for point in POINTS:
        if point != (5.0, 1.0):
            assert np.abs(left[point][[19, 35, 99]]).max() < 3 * np.sqrt(VARIANCE_NM2)


def test_a_set_points_next_feed_forward_has_every_trial_to_date_whatever_the_order():
    """With the model exact (G = G^, no model uncertainty, gamma 1) what the stage delivers next depends on the
    trials alone, not on the order the set points ran in: a set point's next trial has the other set points' trials
    since its own last one too (its feed-forward was fixed at its own last trial once, so the first set point's
    final trial missed the last round of the eight others')."""
    d = shared_ripple(6)

    def learned(order: list) -> dict:
        ilc = stage("points", model_uncertainty=0.0)
        for round_ in range(3):
            for point in order:
                rng = np.random.default_rng([round_, POINTS.index(point)])
                request = ilc.shape(TrialRequest(*point, 4, np.zeros(CPR), np.zeros(CPR), CALIBRATION))
                u = harmonic_amplitudes(request.feedforward_nm)[1: H + 1]
                noise = (rng.normal(size=H) + 1j * rng.normal(size=H)) * np.sqrt(VARIANCE_NM2 / 2)
                measured = np.concatenate([[0.0], d + ilc.plant(request, point[1]) * u + noise])
                trial = TrialData(*point, np.arange(CPR), np.zeros(CPR), np.zeros((CPR, 3)), np.zeros(CPR),
                                  request=request)
                ilc.learn(trial, Frame({}, measured, np.full(H + 1, VARIANCE_NM2), 1.0, point[1]))
        return {point: ilc.shape(TrialRequest(*point, 4, np.zeros(CPR), np.zeros(CPR), CALIBRATION)).feedforward_nm
                for point in POINTS}

    forward, backward = learned(POINTS), learned(POINTS[::-1])
    assert np.abs(forward[POINTS[0]]).max() > 0.1 * np.sqrt(VARIANCE_NM2)  # something shared was learned
    for point in POINTS:
        np.testing.assert_allclose(forward[point], backward[point], rtol=0, atol=1e-12)
