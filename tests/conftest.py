"""Shared fixtures: the seed bench made small and fast, ideal variants of it, campaign files."""

from __future__ import annotations

import dataclasses
import tomllib
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

from ilcpmac.config import CampaignConfig, load_config
from ilcpmac.core.records import SensorCalibration, TrialRequest
from ilcpmac.core.schema import toml_text
from ilcpmac.model.motor import MotorModel
from ilcpmac.sim.simulator import Simulator

#: every property test draws the same examples on every run, seeded like every other random draw here
settings.register_profile("seeded", derandomize=True, database=None)
settings.load_profile("seeded")

SEED_CONFIG = Path(__file__).resolve().parents[1] / "src" / "ilcpmac" / "configs" / "seed-bench.toml"
REAL_BENCH_CONFIG = SEED_CONFIG.with_name("real-bench.toml")
#: encoder resolution of the fast test model (the seed bench has 4096)
COUNTS_PER_REV = 1024
#: the [bench] table of an import mapping (docs/bench-format.md) for the tests' motor
MAPPING_BENCH = f"""\
[bench]
pole_pairs = 8
slots = 48
counts_per_rev = {COUNTS_PER_REV}
inertia_kgm2 = 0.01056
backemf_file = "backemf.csv"
"""
#: the [log] table of a drive log with phase currents and torque, the position in radians (columns of
#: tests/test_importer.py's logs)
PHASE_LOG = """\
[log]
time = "t"
position = "theta"
position_unit = "rad"
phase_currents = ["ia", "ib", "ic"]
torque = "tq"
"""
#: recorded revolutions of a test trial
REVOLUTIONS = 2


def _table(data: dict, dotted: str, create: bool = False) -> dict:
    """The table ``data[a][b]...`` named ``"a.b..."`` (created if asked)."""
    for part in dotted.split("."):
        data = data.setdefault(part, {}) if create else data[part]
    return data


@pytest.fixture
def write_config(tmp_path: Path) -> Callable[..., Path]:
    """Write the seed campaign with changes into ``tmp_path``; returns a writer.

    ``write(changes, drop)``: ``changes`` maps a table, dotted if nested ("simulator.cogging"), to
    {key: value} (new tables allowed); ``drop`` lists tables or keys, dotted ("simulator.cogging",
    "bench.slots"), to remove; ``base`` is the config changed (default the seed campaign).
    """
    def write(changes: dict[str, dict] | None = None, drop: Iterable[str] = (),
              name: str = "campaign.toml", base: Path = SEED_CONFIG) -> Path:
        data = tomllib.loads(base.read_text())
        for table, values in (changes or {}).items():
            _table(data, table, create=True).update(values)
        for entry in drop:
            parent, _, key = entry.rpartition(".")
            del (_table(data, parent) if parent else data)[key]
        path = tmp_path / name
        path.write_text(toml_text(data))
        return path

    return write


@pytest.fixture(scope="session")
def seed_config() -> CampaignConfig:
    """The packaged seed-bench.toml."""
    return load_config(SEED_CONFIG)


@pytest.fixture(scope="session")
def small_model(seed_config: CampaignConfig) -> MotorModel:
    """The seed bench with a coarser encoder, so that trials are quick."""
    m = seed_config.model
    return dataclasses.replace(m, encoder=dataclasses.replace(m.encoder, counts_per_rev=COUNTS_PER_REV))


@pytest.fixture(scope="session")
def ideal_model(small_model: MotorModel) -> MotorModel:
    """The small seed bench without any error: ideal sensors, no cogging, nothing unexplained."""
    m = small_model
    return dataclasses.replace(
        m,
        cogging=dataclasses.replace(m.cogging, amplitudes_nm=(0.0,) * len(m.cogging.multiples)),
        unexplained=dataclasses.replace(m.unexplained, saturation_per_a2=0.0,
                                        amplitudes_nm=(0.0,) * len(m.unexplained.orders)),
        current_sensors=dataclasses.replace(m.current_sensors, epsilon=1.0, alpha=(1.0, 1.0, 1.0),
                                            beta_a=(0.0, 0.0, 0.0), noise_counts=0.0),
        torque_sensor=dataclasses.replace(m.torque_sensor, delta=1.0, noise_nm=0.0, highpass_hz=0.0,
                                          dc_level_nm=0.0, drift_nm_per_s=0.0),
    )


@pytest.fixture(scope="session")
def make_request() -> Callable[..., TrialRequest]:
    """Build a request for a model: constant torque unless a feed-forward table is given."""
    def make(model: MotorModel, torque_nm: float = 2.0, speed_hz: float = 0.5, *,
             feedforward_nm: np.ndarray | None = None, calibration: SensorCalibration | None = None,
             seed: int = 1) -> TrialRequest:
        cpr = model.encoder.counts_per_rev
        return TrialRequest(
            torque_nm, speed_hz, REVOLUTIONS,
            np.zeros(cpr) if feedforward_nm is None else feedforward_nm, np.zeros(cpr),
            model.controller.calibration() if calibration is None else calibration, seed=seed)

    return make


@pytest.fixture(scope="session")
def small_simulator(small_model: MotorModel) -> Simulator:
    """A simulator of the small seed bench (all its errors present)."""
    return Simulator(small_model)


@pytest.fixture
def plan(write_config):
    """The small campaign's plan (seed 7) on its simulator's bench."""
    from campaign_helpers import SMALL_CAMPAIGN, simulator_backend

    from ilcpmac.campaign.plan import CampaignPlan

    cfg = load_config(write_config(SMALL_CAMPAIGN))
    return CampaignPlan.build(cfg, simulator_backend(cfg).describe(), 7)


@pytest.fixture
def quick_emulator_stop(monkeypatch) -> None:
    """Bench emulators started in the test check for a stop (or a restart) every 10 ms instead of 100 ms
    (ilcpmac.backends.emulator._POLL_S, their listener's accept timeout): each stop() waited up to 0.1 s."""
    monkeypatch.setattr("ilcpmac.backends.emulator._POLL_S", 0.01)


@pytest.fixture(scope="session")
def limits_bench(small_model):
    """The small seed bench under the default [limits] (backend, description, identification from the truth,
    limits, a request at 3 N m, 0.75 Hz)."""
    from ilcpmac.backends.base import BenchLimits
    from ilcpmac.backends.simulated import SimulatorBackend
    from ilcpmac.config import LimitSettings
    from ilcpmac.pipeline.safety import SafetyLimits
    from ilcpmac.sim.bench import truth_dict
    from ilcpmac.stages.base import Identified

    backend = SimulatorBackend(small_model, BenchLimits(30.0, 8.0, 1.5))
    description = backend.describe()
    cpr = description.motor.counts_per_rev
    base = TrialRequest(3.0, 0.75, 2, np.zeros(cpr), np.zeros(cpr), description.calibration, seed=3)
    identified = Identified.from_result(truth_dict(backend.simulator, base.calibration), description.calibration)
    limits = SafetyLimits.of_campaign(LimitSettings(), description.limits, 1)
    return backend, description, identified, limits, base
