"""Issue 27, items 4 and 5: a plugin stage that raises, returns garbage, writes into its trial or hangs ends the
run with one line naming it (`StageError`), every trial that ran kept on disk, and the run resumable.

Each test runs the small campaign through ``ilcpmac.campaign.run`` with one broken stage after the built-ins
(``extra_stages``) on a backend that counts the requests it receives.
"""

from __future__ import annotations

import json
import re
import threading

import numpy as np
import pytest
from campaign_helpers import SMALL_CAMPAIGN, TruthIdentification, simulator_backend

import ilcpmac.campaign
from ilcpmac.bench.format import read_bench
from ilcpmac.config import CampaignConfig, load_config
from ilcpmac.core.errors import IlcpmacError, StageError
from ilcpmac.core.records import TrialData, TrialRequest
from ilcpmac.pipeline import pipeline as pipeline_module

#: the broken stage's name, in [pipeline] stages after the built-ins
NAME = "broken"
#: how long the hanging stage waits at most, s: only so that a pipeline without a time limit fails the test
#: instead of hanging it
HANG_S = 30.0


class Counting:
    """A backend that counts the requests reaching it, as parallel as the simulator."""

    def __init__(self, backend) -> None:
        self.backend = backend
        self.requests: list[TrialRequest] = []
        self.max_parallel_trials = backend.max_parallel_trials

    def describe(self):
        return self.backend.describe()

    def run_trial(self, request: TrialRequest) -> TrialData:
        self.requests.append(request)
        return self.backend.run_trial(request)

    def close(self) -> None:
        self.backend.close()


class Inert:
    """A stage that does nothing; each test's stage breaks one of its calls."""

    name = NAME

    def __init__(self, setup) -> None:
        self.counts_per_rev = setup.description.motor.counts_per_rev
        self.calls = {"learn": 0, "state": 0}

    def columns(self, trial):
        return None

    def shape(self, request: TrialRequest) -> TrialRequest:
        return request

    def learn(self, trial, frame) -> None:
        self.calls["learn"] += 1

    def state(self) -> dict:
        self.calls["state"] += 1
        return {"learned": self.calls["learn"]}

    def restore(self, state: dict) -> None:
        pass


class RaisesInInit(Inert):
    def __init__(self, setup) -> None:
        raise RuntimeError("no bench for me")


class RaisesInShape(Inert):
    def shape(self, request):
        raise ValueError("cannot shape this")


class RaisesInLearn(Inert):
    def learn(self, trial, frame):
        super().learn(trial, frame)
        if self.calls["learn"] == 3:  # the first learning round: the other trial of the round ran too
            raise RuntimeError("diverged")


class RaisesInState(Inert):
    def state(self):
        saved = super().state()
        if self.calls["state"] == 4:  # the stages' start, the two baselines, then the first compensation trial
            raise RuntimeError("lost my memory")
        return saved


class StateNotJson(Inert):
    def state(self):
        return {"seen": {1, 2}}


class NanColumns(Inert):
    def columns(self, trial):
        return np.full((self.counts_per_rev, 2), np.nan)


class HugeColumns(Inert):
    def columns(self, trial):
        return np.zeros((self.counts_per_rev, pipeline_module.MAX_COLUMNS + 1))


class HugeState(Inert):
    def state(self):
        return {"memory": "x" * (2 * pipeline_module.MAX_STATE_BYTES)}


class WritesNan(Inert):
    def learn(self, trial, frame):
        trial.torque_nm[:] = np.nan


class QuitsInShape(Inert):
    def shape(self, request):
        raise SystemExit(0)


released = threading.Event()


class Hangs(Inert):
    def learn(self, trial, frame):
        if not released.wait(HANG_S):
            raise AssertionError("the pipeline did not abandon a hanging stage")


def small_campaign(write_config) -> CampaignConfig:
    """The small campaign, two learning trials per point, with the broken stage after the built-ins."""
    stages = ["current-sensor", "cogging", "ilc", NAME]
    return load_config(write_config({**SMALL_CAMPAIGN, "pipeline": {"stages": stages},
                                     "campaign": {**SMALL_CAMPAIGN["campaign"], "learn_trials": 2}}))


def fails(write_config, tmp_path, stage, message: str) -> Counting:
    """The campaign with ``stage`` ends with one line naming it and matching ``message``; every trial that ran is
    on disk, with its state. The counting backend."""
    cfg = small_campaign(write_config)
    backend = Counting(simulator_backend(cfg))
    with pytest.raises(StageError) as raised:
        ilcpmac.campaign.run(cfg, out=tmp_path / "run", backend=backend, seed=7,
                             identify=TruthIdentification(backend.backend), extra_stages={NAME: stage})
    text = str(raised.value)
    assert isinstance(raised.value, IlcpmacError) and "\n" not in text  # the CLI prints it on one line, exits 2
    assert text.startswith(f"stage {NAME!r}: ") and re.search(message, text), text
    run = tmp_path / "run"
    ran = len(backend.requests)
    assert ran >= 4  # the grid at least
    assert len(read_bench(run).trials) == ran  # committed (bench.toml lists them)
    assert len(list(run.glob("trial_*.parquet"))) == ran
    assert len(list((run / "states").glob("trial_*.json"))) == ran
    return backend


def test_a_stage_raising_in_its_factory(write_config, tmp_path):
    backend = fails(write_config, tmp_path, RaisesInInit, r"its factory raised RuntimeError: no bench for me$")
    assert len(backend.requests) == 4  # the grid; the stages start after it


def test_a_stage_raising_in_shape(write_config, tmp_path):
    backend = fails(write_config, tmp_path, RaisesInShape, r"shape raised ValueError: cannot shape this$")
    assert len(backend.requests) == 6  # the grid and the baselines: nothing was shaped


def test_a_stage_raising_in_learn_keeps_every_trial_and_resumes_once_fixed(write_config, tmp_path):
    """Issue 27: 13 requests sent, 11 saved; now the trial it failed on and the other of its round are kept."""
    backend = fails(write_config, tmp_path, RaisesInLearn, r"learn raised RuntimeError: diverged$")
    # the grid, baselines, compensation, the first learning trial and, when it ran beside it, the other of its round
    assert len(backend.requests) >= 9
    states = [json.loads(path.read_text()) for path in sorted((tmp_path / "run" / "states").glob("trial_*.json"))]
    assert states[8]["pipeline"] == states[7]["pipeline"]  # saved with the stages as they were before it
    fixed = Counting(simulator_backend(small_campaign(write_config)))
    result = ilcpmac.campaign.run(resume=tmp_path / "run", backend=fixed, identify=TruthIdentification(fixed.backend),
                                  extra_stages={NAME: Inert})
    assert len(result.records) == len(read_bench(tmp_path / "run").trials) == 10 + len(fixed.requests)
    assert result.records[-1].role == "validate" and result.summary["validation"]


def test_a_stage_raising_in_state(write_config, tmp_path):
    fails(write_config, tmp_path, RaisesInState, r"state raised RuntimeError: lost my memory$")


def test_a_state_that_is_not_json(write_config, tmp_path):
    fails(write_config, tmp_path, StateNotJson, r"state is not JSON: seen holds set$")


def test_nan_columns(write_config, tmp_path):
    fails(write_config, tmp_path, NanColumns, r"columns returned NaN or infinity$")


def test_too_many_columns(write_config, tmp_path):
    fails(write_config, tmp_path, HugeColumns, r"columns returned \(1024, 513\), not \(1024, k\) with k <= 512$")


def test_a_huge_state(write_config, tmp_path, monkeypatch):
    monkeypatch.setattr(pipeline_module, "MAX_STATE_BYTES", 1 << 20)
    fails(write_config, tmp_path, HugeState, r"state is more than 1 MiB of JSON text \(MAX_STATE_BYTES\)$")


def test_a_stage_writing_into_its_trial_fails_and_the_trial_stays_as_it_ran(write_config, tmp_path):
    fails(write_config, tmp_path, WritesNan, r"learn raised ValueError: assignment destination is read-only$")
    assert all(np.isfinite(trial.torque_nm).all() for trial in read_bench(tmp_path / "run").trials)


def test_a_stage_raising_system_exit_is_no_success(write_config, tmp_path):
    fails(write_config, tmp_path, QuitsInShape, r"shape raised SystemExit: 0$")


def test_a_hanging_stage_is_abandoned(write_config, tmp_path, monkeypatch):
    monkeypatch.setattr(pipeline_module, "STAGE_CALL_S", 0.5)
    released.clear()
    try:
        fails(write_config, tmp_path, Hangs, r"learn did not return within 0.5 s")
    finally:
        released.set()
