"""Shared benches for the identification tests: cached, seeded, built in memory.

Not a conftest: the tests import what they need from here.
"""

from __future__ import annotations

import tomllib
from dataclasses import replace
from functools import lru_cache
from pathlib import Path
from tempfile import TemporaryDirectory

import numpy as np
from conftest import COUNTS_PER_REV, SEED_CONFIG

from ilcpmac.bench.format import Bench
from ilcpmac.campaign.service import simulated_bench
from ilcpmac.config import load_config
from ilcpmac.core.schema import toml_text
from ilcpmac.identify import IdentificationResult, identify_bench
from ilcpmac.sim.reduced import ReducedCampaign, ReducedMotor, ReducedSensors, reduced_bench


@lru_cache(maxsize=None)
def seed_bench() -> tuple[Bench, dict]:
    """The seed bench of configs/seed-bench.toml, simulated in memory (30 trials, 8 revolutions)."""
    return simulated_bench(load_config(SEED_CONFIG))


#: a motor unlike the seed bench: 4 pole pairs, 36 slots (cogging order 72), 2048 counts
OTHER_MOTOR = ReducedMotor()
#: delta 0.9, epsilon 0.8, alpha (0.9, 1.05, 1.05) normalised, beta (0.3, -0.2, 0.1) A
OTHER_SENSORS = ReducedSensors()


def other_campaign(seed: int, **changes) -> ReducedCampaign:
    """The default reduced campaign with ``seed`` and some of its fields (or its grid's) changed."""
    campaign = ReducedCampaign()
    grid = replace(campaign.grid, seed=seed, **{k: changes.pop(k) for k in list(changes) if hasattr(campaign.grid, k)})
    return replace(campaign, grid=grid, **changes)


@lru_cache(maxsize=None)
def other_bench(loop_hz: float | None = None, skip_fraction: float = 0.0, highpass_hz: float = 0.0,
                seed: int = 1) -> tuple[Bench, dict]:
    """A synthetic bench of OTHER_MOTOR (3 torques x 2 speeds, 4 revolutions)."""
    sensors = replace(OTHER_SENSORS, torque=replace(OTHER_SENSORS.torque, highpass_hz=highpass_hz))
    return reduced_bench(OTHER_MOTOR, sensors, other_campaign(seed, current_loop_hz=loop_hz,
                                                              skip_fraction=skip_fraction))


@lru_cache(maxsize=None)
def identified(kind: str, *args) -> tuple[IdentificationResult, dict]:
    """identify_bench on ``seed_bench()`` ("seed") or ``other_bench(*args)`` ("other"), with the truth."""
    bench, truth = seed_bench() if kind == "seed" else other_bench(*args)
    return identify_bench(bench), truth


def relative_error(estimate: float, truth: float) -> float:
    return abs(estimate / truth - 1.0)


def cogging_error(estimate: np.ndarray, truth: dict) -> float:
    """RMS error of the cogging table relative to the true cogging's RMS."""
    true = np.asarray(truth["cogging"]["torque"])
    return float(np.sqrt(np.mean((estimate - true) ** 2) / np.mean(true**2)))


def assert_targets(result, truth) -> None:
    """The issue's accuracy targets for a bench without current-loop lag."""
    assert relative_error(result.delta_epsilon, truth["total_system_gain"]) < 0.005
    assert relative_error(result.delta, truth["torque_sensor_gain"]) < 0.015
    assert relative_error(result.epsilon, truth["epsilon"]) < 0.02
    assert np.abs(result.alpha - truth["alpha"]).max() < 0.003
    assert np.abs(result.beta - truth["beta"]).max() < 0.01
    assert cogging_error(result.cogging_nm, truth) < 0.03


#: 3 torques x 2 slow speeds (0.5, 0.6 Hz) of 4 revolutions: a small grid whose speed ripples
SLOW_GRID = {"torque_setpoints_nm": [1.0, 3.0, 5.0], "speed_setpoints_hz": [0.5, 0.6], "revolutions": 4}


def slow_grid_bench(seed: int, simulator: dict[str, dict]) -> tuple[Bench, dict]:
    """The 1024-count seed bench's `SLOW_GRID` with ``seed``, its [simulator.X] tables updated by ``simulator``
    ({"controller": {"bandwidth_hz": 80.0}}), simulated in memory: the bench and its truth."""
    data = tomllib.loads(SEED_CONFIG.read_text())
    data["bench"]["counts_per_rev"] = COUNTS_PER_REV
    data["trials"].update(SLOW_GRID, seed=seed)
    for table, values in simulator.items():
        data["simulator"][table].update(values)
    with TemporaryDirectory() as folder:
        path = Path(folder) / "campaign.toml"
        path.write_text(toml_text(data))
        config = load_config(path)
    return simulated_bench(config)
