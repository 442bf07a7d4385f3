"""Helpers for the campaign tests: a small campaign, its simulator, an identification from truth."""

from __future__ import annotations

from pathlib import Path

from ilcpmac.backends.base import Backend
from ilcpmac.backends.simulated import SimulatorBackend
from ilcpmac.campaign.events import CampaignMessage, NoEvents
from ilcpmac.campaign.rundir import RunDir
from ilcpmac.campaign.runner import CampaignRunner
from ilcpmac.config import CampaignConfig
from ilcpmac.core.records import BenchLimits, IdentificationResult, TrialData, TrialRequest
from ilcpmac.sim.bench import truth_dict

#: a small campaign: 1024 counts, a 2 x 2 grid, two learned points at one speed, one validation point, few trials
SMALL_CAMPAIGN = {
    "bench": {"counts_per_rev": 1024},
    "excitation": {"harmonics": 100},
    "trials": {"torque_setpoints_nm": [2.0, 4.0], "speed_setpoints_hz": [0.6, 0.9], "revolutions": 3},
    "campaign": {"learn_torques_nm": [2.0, 4.0], "learn_speeds_hz": [0.9], "learn_revolutions": [6],
                 "learn_trials": 4, "ripple_harmonics": 100, "validate_torques_nm": [3.0],
                 "validate_speeds_hz": [0.9], "validate_revolutions": 6, "torque_source": "sensor"},
    "stages": {"ilc": {"learning_gain": 1.0, "q_cutoff_harmonic": 100, "estimation": "kalman"}},
}


def truth_json(backend: SimulatorBackend) -> dict:
    """The simulator's truth under the result keys, at the controller's calibration."""
    sim = backend.simulator
    return truth_dict(sim, sim.model.controller.calibration())


class TruthIdentification:
    """The identification's answer taken from the simulator's truth (dependency injection), so
    that campaign tests test the campaign; the estimators are tested in test_identify_*.py."""

    def __init__(self, backend: SimulatorBackend) -> None:
        self.result = IdentificationResult.from_json(truth_json(backend))

    def __call__(self, bench) -> IdentificationResult:
        return self.result

    def to_json(self) -> dict:
        """The answer's result JSON (tests/test_identify_record.py reads it)."""
        return self.result.to_json()


class Quiet(NoEvents):
    """Campaign events that only collect the messages."""

    def __init__(self) -> None:
        self.messages: list[CampaignMessage] = []

    def message(self, message: CampaignMessage) -> None:
        self.messages.append(message)


def simulator_backend(cfg: CampaignConfig) -> SimulatorBackend:
    """The simulator of ``cfg`` with its limits, recording as the config's backend does."""
    return SimulatorBackend(cfg.sampled_model(), BenchLimits(cfg.limits.max_current_a, cfg.limits.max_torque_nm,
                                                             cfg.limits.max_speed_hz), cfg.grid.warmup_revolutions,
                            cfg.recorded_counts_per_rev())


class Recording:
    """A backend that records every request reaching it and the trial ``backend`` ran for it."""

    def __init__(self, backend: Backend) -> None:
        self.backend = backend
        self.requests: list[TrialRequest] = []
        self.trials: list[TrialData] = []
        self.max_parallel_trials = 1

    def describe(self):
        return self.backend.describe()

    def run_trial(self, request: TrialRequest) -> TrialData:
        self.requests.append(request)
        self.trials.append(self.backend.run_trial(request))
        return self.trials[-1]

    def close(self) -> None:
        self.backend.close()


def run_campaign(cfg: CampaignConfig, out: Path, backend: Backend | None = None, resume: bool = False,
                 events=None, extra_stages: dict | None = None) -> dict:
    """Run (or resume) ``cfg`` into ``out`` with seed 7; the truth's identification."""
    sim = simulator_backend(cfg)
    backend = backend or sim
    run_dir = RunDir.resume(out, sim.describe()) if resume else \
        RunDir.create(out, sim.describe(), cfg.path.read_text())
    return CampaignRunner(cfg, backend, run_dir, 7, TruthIdentification(sim), events or Quiet(),
                          extra_stages).run()
