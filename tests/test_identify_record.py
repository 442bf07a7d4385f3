"""The identification record: its JSON round trip, what the stages take from it, what the runner checks."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from campaign_helpers import SMALL_CAMPAIGN, Quiet, TruthIdentification, simulator_backend
from hypothesis import given
from hypothesis import strategies as st
from identify_helpers import identified

from ilcpmac.campaign.rundir import RunDir
from ilcpmac.campaign.runner import CampaignRunner
from ilcpmac.config import load_config
from ilcpmac.core.errors import IdentificationError
from ilcpmac.core.records import IdentificationResult, SensorCalibration
from ilcpmac.stages.base import Identified
from ilcpmac.stages.registry import stage_needs

finite = st.floats(-1e6, 1e6, allow_nan=False)


@given(st.lists(finite, min_size=3, max_size=3), st.lists(finite, min_size=3, max_size=3), finite)
def test_sensor_calibration_round_trips_through_its_json(scale, offset, gain):
    calibration = SensorCalibration(scale, offset, gain)
    back = SensorCalibration.from_json(calibration.to_json())
    assert back.to_json() == calibration.to_json()
    assert set(calibration.to_json()) == {"current_scale", "current_offset", "torque_gain"}


def test_identification_round_trips_through_its_json_exactly():
    """A resumed campaign reads the result back from identification.json: the stages must start from
    the very same numbers, the identified loop (time constants and delay) included."""
    result, _ = identified("other", 110.0)
    data = result.to_json()
    back = IdentificationResult.from_json(data)
    assert back.to_json() == data
    assert data["current_loop_delay_s"] == result.current_loop.delay_s
    np.testing.assert_array_equal(back.current_loop.time_constant_s, result.current_loop.time_constant_s)
    calibration = SensorCalibration([10.0] * 3, [0.0] * 3, 1.0)
    direct, resumed = Identified.from_result(result, calibration), Identified.from_result(back, calibration)
    for name in ("delta", "epsilon", "alpha", "beta_a", "cogging_nm", "alpha_std", "beta_std_a"):
        np.testing.assert_array_equal(getattr(resumed, name), getattr(direct, name))
    np.testing.assert_array_equal(resumed.current_loop.time_constant_s, direct.current_loop.time_constant_s)
    assert resumed.current_loop.delay_s == direct.current_loop.delay_s


def test_a_truth_without_time_constants_gives_the_loop_of_its_corners():
    data = {"torque_sensor_gain": 0.9, "epsilon": 0.8, "alpha": [1.0] * 3, "beta": [0.0] * 3,
            "current_loop_bandwidth_per_phase_hz": [100.0, 200.0, 400.0]}
    loop = IdentificationResult.from_json(data).current_loop
    np.testing.assert_allclose(loop.bandwidth_hz, [100.0, 200.0, 400.0], rtol=1e-15)
    assert loop.delay_s == 0.0
    assert IdentificationResult.from_json({**data, "current_loop_bandwidth_per_phase_hz": None}).current_loop is None


def test_the_built_in_stages_declare_what_they_need():
    assert stage_needs(["current-sensor", "cogging", "ilc"]) == {"current-sensor": (), "cogging": ("cogging_nm",),
                                                                 "ilc": ()}


def test_the_runner_checks_exactly_what_the_configured_stages_need(write_config, tmp_path):
    """No cogging identified: refused with the cogging stage, accepted without it."""
    config = load_config(write_config(SMALL_CAMPAIGN))
    sim = simulator_backend(config)
    truth = IdentificationResult.from_json(TruthIdentification(sim).to_json())
    lacking = replace(truth, cogging_nm=None, messages=("cogging: not seen",))

    def runner(cfg, name):
        run_dir = RunDir.create(tmp_path / name, sim.describe(), cfg.path.read_text())
        return CampaignRunner(cfg, sim, run_dir, 7, lambda bench: lacking, Quiet())

    with pytest.raises(IdentificationError, match=r"stage 'cogging' needs cogging_nm, .*\(cogging: not seen\)"):
        runner(config, "with")._set_identified(lacking)
    without = replace(config, pipeline=replace(config.pipeline, stages=("current-sensor", "ilc")))
    accepted = runner(without, "without")
    accepted._set_identified(lacking)
    assert accepted.identified.cogging_nm is None
    with pytest.raises(IdentificationError, match=r"the pipeline needs epsilon, which"):
        accepted._set_identified(replace(truth, epsilon=None))
