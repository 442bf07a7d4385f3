"""benchmarks/campaign.py's variants of the seed config: each is a config the campaign accepts, with the keys the
benchmark sets (a key the seed config leaves out once made the benchmark stop at its first line)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from ilcpmac.config import load_config

_spec = importlib.util.spec_from_file_location(
    "campaign_benchmark", Path(__file__).resolve().parents[1] / "benchmarks" / "campaign.py")
assert _spec is not None and _spec.loader is not None
campaign_benchmark = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(campaign_benchmark)


def test_the_one_speed_and_fixed_gain_variants_load_with_what_they_set(tmp_path):
    one_speed = load_config(campaign_benchmark.variant(tmp_path, "one.toml", campaign_benchmark.ONE_SPEED))
    fixed = load_config(campaign_benchmark.variant(tmp_path, "fixed.toml", campaign_benchmark.ONE_SPEED,
                                                   campaign_benchmark.FIXED_GAIN))
    for config in (one_speed, fixed):
        assert config.campaign.learn_speeds_hz == (0.75,)
        assert config.campaign.patience == 4
        assert config.campaign.validate_torques_nm == ()
    assert one_speed.stage_options["ilc"]["estimation"] == "kalman"
    assert fixed.stage_options["ilc"]["estimation"] == "fixed" and fixed.stage_options["ilc"]["learning_gain"] == 0.5
