"""The joint fit's current-sensor offsets with a slow PI loop: the fit moved to the minimum of the data less the
torque sensor's speed-ripple part (`ilcpmac.identify.joint._gauss_newton_step`; docs/identification.md,
"Uncertainty on mismatched data")."""

from __future__ import annotations

import tomllib
from functools import lru_cache
from pathlib import Path
from tempfile import TemporaryDirectory

import numpy as np
from conftest import COUNTS_PER_REV, SEED_CONFIG, toml_text

from ilcpmac.bench.format import Bench
from ilcpmac.config import load_config
from ilcpmac.identify import identify_bench
from ilcpmac.identify import joint as joint_module
from ilcpmac.sim.grid import simulated_bench

#: 3 torques x 2 slow speeds of 4 revolutions on the 1024-count seed bench
GRID = {"torque_setpoints_nm": [1.0, 3.0, 5.0], "speed_setpoints_hz": [0.5, 0.6], "revolutions": 4}


@lru_cache(maxsize=None)
def slow_loop_bench(seed: int) -> tuple[Bench, dict]:
    """The PI loop at 80 Hz, the torque sensor's noise 1e-5 N m: the errors are the misfit's alone."""
    data = tomllib.loads(SEED_CONFIG.read_text())
    data["bench"]["counts_per_rev"] = COUNTS_PER_REV
    data["trials"].update(GRID, seed=seed)
    data["simulator"]["controller"]["bandwidth_hz"] = 80.0
    data["simulator"]["torque_sensor"]["noise_nm"] = 1e-5
    with TemporaryDirectory() as folder:
        path = Path(folder) / "campaign.toml"
        path.write_text(toml_text(data))
        config = load_config(path)
    return simulated_bench(config)


def _offset_error_over_std(bench: Bench, truth: dict) -> float:
    """The largest |beta* - delta beta| / std over the phases, delta and beta the simulator's."""
    joint = identify_bench(bench).details.joint
    expected = truth["torque_sensor_gain"] * np.asarray(truth["beta"])
    return float(np.max(np.abs(joint.beta_star_a - expected) / joint.beta_star_std))


def test_the_offsets_are_covered_with_the_fit_moved_to_the_corrected_datas_minimum(monkeypatch):
    """Within 3 standard errors on two seeds (1.4, 0.9); with the first fit's nonlinear parameters kept (the
    linear ones solved again on the corrected data only) 4.4 and 3.7."""
    moved = [_offset_error_over_std(*slow_loop_bench(seed)) for seed in (101, 106)]
    monkeypatch.setattr(joint_module, "_gauss_newton_step", lambda problem, phi, *_: phi)
    kept = [_offset_error_over_std(*slow_loop_bench(seed)) for seed in (101, 106)]
    assert max(moved) <= 3.0, moved
    assert min(kept) > 3.0, kept
