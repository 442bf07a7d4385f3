"""The stage of docs/writing-a-stage.md (examples/custom_stage.py) in the campaign's rounds (issue 34, item 15).

A round shapes every request from one state of the stages, then learns from each of its trials in turn; a stage
whose step ignores that (one correction for all set points) took as many steps per round as the round had
points, and diverged.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from ilcpmac.backends.base import BenchDescription, BenchLimits
from ilcpmac.core.records import MotorInfo, SensorCalibration, TrialRequest
from ilcpmac.signals.harmonics import harmonic_amplitudes
from ilcpmac.stages import Frame
from ilcpmac.stages.base import Identified, StageSetup

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "custom_stage.py"
CPR, ORDER, H = 64, 20, 30
CAL = SensorCalibration([14.0, 14.0, 14.0], [0.0, 0.0, 0.0], 0.908)
_THETA = 2 * np.pi * np.arange(CPR) / CPR
DESCRIPTION = BenchDescription(MotorInfo(8, 48, CPR, 0.01056),
                               0.2 * np.sin(8 * _THETA[:, None] - 2 * np.pi * np.arange(3) / 3), CAL,
                               BenchLimits(max_current_a=30.0, max_torque_nm=8.0, max_speed_hz=1.5))
#: the default campaign's learned points, in the plan's order: one round is one trial at each
POINTS = [(torque, speed) for torque in (1.0, 3.0, 5.0) for speed in (0.5, 1.0, 1.5)]


@pytest.fixture(scope="module")
def example():
    spec = importlib.util.spec_from_file_location("custom_stage", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_guide_shows_the_example_stage_as_it_is():
    guide = (ROOT / "docs" / "writing-a-stage.md").read_text()
    shown = guide[guide.index("class OneHarmonicCanceller"):]
    assert shown[:shown.index("```")] in EXAMPLE.read_text()


def test_the_example_stage_takes_one_step_per_set_point_and_round(example):
    """A plant the stage models exactly, a disturbance of its own at each set point: after n rounds each point's
    residual is (1 - gain)^n of its disturbance (one fixed-gain step per round); it grew 3.5x per round."""
    identified = Identified(1.0, 1.0, np.ones(3), np.zeros(3), None, CAL)
    setup = StageSetup(DESCRIPTION, identified, H, {"order": ORDER, "gain": 0.5})
    stage = example.OneHarmonicCanceller(setup)
    disturbance_nm = {p: 0.01 * (1 + k) * np.exp(1j * k) for k, p in enumerate(POINTS)}
    requests = [TrialRequest(t, s, 4, np.zeros(CPR), np.zeros(CPR), CAL) for t, s in POINTS]
    for n in range(1, 7):
        shaped = [stage.shape(r) for r in requests]  # the whole round from one state
        for point, request in zip(POINTS, shaped):
            response = setup.shaft_response(np.array([ORDER]), point[1], CAL, point[0])[0]
            ripple_nm = np.zeros(H + 1, complex)
            ripple_nm[ORDER] = disturbance_nm[point] + response * harmonic_amplitudes(request.feedforward_nm)[ORDER]
            stage.learn(SimpleNamespace(requested=lambda request=request: request),
                        Frame({}, ripple_nm, np.full(H + 1, 1e-12), 1.0, point[1]))
        for point, request in zip(POINTS, requests):
            response = setup.shaft_response(np.array([ORDER]), point[1], CAL, point[0])[0]
            left = disturbance_nm[point] + response * harmonic_amplitudes(stage.shape(request).feedforward_nm)[ORDER]
            assert abs(left) == pytest.approx(0.5**n * abs(disturbance_nm[point]), rel=1e-9), (n, point)


@pytest.mark.slow
def test_the_example_stage_converges_in_the_default_campaign(example, tmp_path):
    """The guide's stage (after the current-sensor and cogging stages) on the packaged default campaign: at every
    validation point the true torque at its harmonic ends far below the uncompensated trial's (it was 5x above:
    11.9 against 59-61 mN m), and so does the true ripple."""
    import ilcpmac.campaign
    from ilcpmac.bench.format import read_bench

    result = ilcpmac.campaign.run(example.campaign_config(), out=tmp_path / "run",
                                  extra_stages={"one-harmonic": example.OneHarmonicCanceller})
    bench = read_bench(result.path)
    validated = [p for p in result.points if not p.learned]
    assert len(validated) == 6
    for point in validated:
        before, after = (example.true_harmonic_nm(bench.trials[r.index - 1], bench.motor.counts_per_rev, ORDER)
                         for r in (point.before, point.after))
        assert after < before / 10, (point.point, before, after)
        assert point.after.true.pp < point.before.true.pp
