"""Shared benches for the identification tests: cached, seeded, built in memory.

Not a conftest: the tests import what they need from here.
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import numpy as np

from ilcpmac.bench.format import Bench
from ilcpmac.identify import IdentificationResult, identify_bench
from ilcpmac.sim.reduced import ReducedCampaign, ReducedMotor, ReducedSensors, reduced_bench

SEED_CONFIG = "configs/seed-bench.toml"


@lru_cache(maxsize=None)
def seed_bench() -> tuple[Bench, dict]:
    """The seed bench of configs/seed-bench.toml, simulated in memory (30 trials, 8 revolutions)."""
    from pathlib import Path

    from ilcpmac.config import load_config
    from ilcpmac.sim.grid import simulated_bench

    return simulated_bench(load_config(Path(__file__).resolve().parents[1] / SEED_CONFIG))


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
