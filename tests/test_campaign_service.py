"""The campaign as a service: `ilcpmac.campaign.run` from a script, its typed events, the sweep counting them."""

from __future__ import annotations

import json

import pytest
from campaign_helpers import SMALL_CAMPAIGN, TruthIdentification, simulator_backend

import ilcpmac.campaign
from ilcpmac.campaign.events import CampaignStart, GuardEvent, NoEvents, PipelineNote
from ilcpmac.campaign.record import records_of
from ilcpmac.config import load_config
from ilcpmac.core.errors import BackendError, ConfigError
from ilcpmac.core.torque_source import TorqueSource
from ilcpmac.sweep.task import _GuardCount

#: SMALL_CAMPAIGN cut to one learning trial per point: the shortest campaign with every phase
SHORT_CAMPAIGN = {**SMALL_CAMPAIGN, "campaign": {**SMALL_CAMPAIGN["campaign"], "learn_trials": 1}}


class Kept(NoEvents):
    """Campaign events, kept in order."""

    def __init__(self) -> None:
        self.seen: list = []

    def start(self, start: CampaignStart) -> None:
        self.seen.append(start)

    def message(self, message) -> None:
        self.seen.append(message)

    def end(self, how: str) -> None:
        self.seen.append(how)


def test_a_script_runs_a_campaign_with_one_call(write_config, tmp_path):
    cfg = load_config(write_config(SHORT_CAMPAIGN))
    backend = simulator_backend(cfg)
    events = Kept()
    result = ilcpmac.campaign.run(cfg, out=tmp_path / "run", backend=backend, seed=7, events=events,
                                  identify=TruthIdentification(backend))
    assert result.path == tmp_path / "run"
    assert json.loads((result.path / "summary.json").read_text()) == result.summary
    assert result.records == records_of(result.summary) and len(result.records) == len(result.plan.grid) + 8
    assert result.identification is not None and result.identification.delta == pytest.approx(
        TruthIdentification(backend).result.delta)
    assert [(p.point, p.learned) for p in result.points] == [((2.0, 0.9), True), ((4.0, 0.9), True),
                                                            ((3.0, 0.9), False)]
    start = events.seen[0]
    assert isinstance(start, CampaignStart) and not start.resumed and start.path == result.path
    assert start.plan.seed == 7 and start.torque_source is TorqueSource.SENSOR
    assert events.seen[-1] == "done"
    assert all(isinstance(m.text, str) for m in events.seen[1:-1])


def test_a_resume_takes_no_config_and_a_failed_start_leaves_no_directory(write_config, tmp_path):
    config = write_config(SHORT_CAMPAIGN)
    with pytest.raises(ConfigError, match="--resume continues a run with the config, seed, trials and budget it began "
                                          "with: give no CONFIG"):
        ilcpmac.campaign.run(config, resume=tmp_path / "run")
    with pytest.raises(ConfigError, match="--backend: no backend named 'nowhere'"):
        ilcpmac.campaign.run(config, out=tmp_path / "new", backend="nowhere")
    assert not (tmp_path / "new").exists()


def test_the_guard_event_reads_as_the_guard_line_and_is_saved_as_the_trials_state():
    event = GuardEvent("3@0.75", 12, 0.25)
    assert event.text == ("guard: measured ripple at 3@0.75 grew twice in a row; reverted to the correction of "
                          "trial 12 and halved the learning gain to 0.25")
    assert event.to_json() == {"set_point": "3@0.75", "reverted_to_trial": 12, "learning_gain": 0.25}


def test_the_sweep_counts_guard_events_by_type_not_by_their_text():
    events = _GuardCount()
    events.message(GuardEvent("3@0.75", 12, 0.25))
    events.message(PipelineNote("guard: a stage's note that merely starts like the guard's"))
    events.message(GuardEvent("2@0.9", 14, 0.5))
    assert events.guard_events == 2


class FailingAt:
    """A backend that runs ``inner``'s trials and fails at trial ``n`` (a bench that drops its link)."""

    def __init__(self, inner, n: int) -> None:
        self.inner, self.n, self.ran = inner, n, 0
        self.max_parallel_trials = 1

    def describe(self):
        return self.inner.describe()

    def run_trial(self, request):
        self.ran += 1
        if self.ran == self.n:
            raise BackendError("link lost")
        return self.inner.run_trial(request)

    def close(self) -> None:
        self.inner.close()


def test_a_run_that_fails_after_its_first_trials_keeps_them_to_resume(write_config, tmp_path):
    """The run directory a failed run made stays with its finished trials (it was removed whole once)."""
    cfg = load_config(write_config(SHORT_CAMPAIGN))
    backend = FailingAt(simulator_backend(cfg), 3)
    with pytest.raises(BackendError, match="link lost"):
        ilcpmac.campaign.run(cfg, out=tmp_path / "run", backend=backend, seed=7,
                             identify=TruthIdentification(backend.inner))
    assert (tmp_path / "run" / "states" / "trial_002.json").is_file()
    result = ilcpmac.campaign.run(resume=tmp_path / "run", backend=simulator_backend(cfg),
                                  identify=TruthIdentification(backend.inner))
    assert len(result.records) == len(result.plan.grid) + 8


def test_an_unknown_stage_stops_the_run_before_its_first_trial(write_config, tmp_path):
    stages = ["current-sensor", "cogging", "ilc", "nowhere"]
    cfg = load_config(write_config({**SHORT_CAMPAIGN, "pipeline": {"stages": stages}}))
    backend = FailingAt(simulator_backend(cfg), 1)
    with pytest.raises(ConfigError, match="no stage named 'nowhere'"):
        ilcpmac.campaign.run(cfg, out=tmp_path / "run", backend=backend)
    assert backend.ran == 0 and not (tmp_path / "run").exists()
