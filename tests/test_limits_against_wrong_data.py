"""The limits against wrong data (issue 27, items 1, 2, 3, 10): a back-EMF table the bench describes wrongly, a
stage that writes into what it shares, a run directory changed between a stop and its ``--resume``."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from campaign_helpers import SMALL_CAMPAIGN, simulator_backend
from click.testing import CliRunner

import ilcpmac.campaign as campaign
from ilcpmac.campaign.rundir import RunDirError
from ilcpmac.cli import main
from ilcpmac.config import load_config
from ilcpmac.core.errors import SafetyError
from ilcpmac.core.records import TrialData, TrialRequest


@pytest.fixture
def config(write_config):
    return load_config(write_config(SMALL_CAMPAIGN))


class Bench:
    """The simulator, describing its back-EMF ``factor`` times, stopping at call ``stop_at``; it keeps the
    largest true phase current that flowed."""

    def __init__(self, config, factor: float = 1.0, stop_at: int = 0) -> None:
        self.backend, self.factor, self.stop_at = simulator_backend(config), factor, stop_at
        self.calls, self.max_parallel_trials, self.peak_a = 0, 1, 0.0

    def describe(self):
        description = self.backend.describe()
        return dataclasses.replace(description, backemf_nm_per_a=description.backemf_nm_per_a * self.factor)

    def run_trial(self, request: TrialRequest) -> TrialData:
        self.calls += 1
        if self.calls == self.stop_at:
            raise Stop
        trial = self.backend.run_trial(request)
        self.peak_a = max(self.peak_a, float(np.abs(trial.i_true_a).max()))
        return trial

    def close(self) -> None:
        self.backend.close()


class Stop(RuntimeError):
    pass


def test_a_back_emf_table_described_3x_is_refused_before_any_compensated_trial(config, tmp_path):
    """Before: epsilon 0.229 identified, the current-sensor stage set 4-5.5x the current scale and 47.6 A flowed
    against 30 A, exit 0. With no [bench.backemf] to confirm the table, the identification is refused."""
    unconfirmed = dataclasses.replace(config, bench=dataclasses.replace(config.bench, backemf=None))
    bench = Bench(config, factor=3.0)
    with pytest.raises(SafetyError, match=r"campaign.toml: the identified epsilon 0.229 puts the current scales at "
                                          r".*\[limits\] max_scale_deviation.*back-EMF table is wrong, 4.37x"):
        campaign.run(unconfirmed, out=tmp_path / "run", backend=bench, seed=7)
    assert bench.calls == 4  # the grid only
    assert bench.peak_a < config.limits.max_current_a


def test_a_stage_cannot_write_into_the_bench_or_the_identification(write_config, tmp_path):
    """Before: a stage scaling setup.description.backemf_nm_per_a in place made the guard underestimate the
    currents. Every array a stage shares is read-only."""
    written: list[str] = []

    def probe(setup):
        shared = {"description.backemf_nm_per_a": setup.description.backemf_nm_per_a,
                  "description.calibration.current_scale": setup.description.calibration.current_scale,
                  "identified.calibration.current_offset": setup.identified.calibration.current_offset,
                  "identified.alpha": setup.identified.alpha, "identified.beta_a": setup.identified.beta_a,
                  "identified.cogging_nm": setup.identified.cogging_nm,
                  "identified.current_loop.time_constant_s": setup.identified.current_loop.time_constant_s}
        for name, array in shared.items():
            try:
                array *= 3.0
                written.append(name)
            except ValueError:
                pass
        raise Stop

    cfg = load_config(write_config({**SMALL_CAMPAIGN, "pipeline": {"stages": ["current-sensor", "ilc", "probe"]}}))
    with pytest.raises(Exception) as stopped:  # Stop, or the one-line stage error it becomes
        campaign.run(cfg, out=tmp_path / "run", seed=7, extra_stages={"probe": probe})
    assert "Stop" in repr(stopped.value) or "Stop" in str(stopped.value)
    assert written == []


def stopped(config, out: Path, stop_at: int) -> Path:
    """A run of ``config`` into ``out`` stopped at the backend's call ``stop_at``."""
    with pytest.raises(Stop):
        campaign.run(config, out=out, backend=Bench(config, stop_at=stop_at), seed=7)
    return out


def test_an_edited_identification_is_refused_on_resume(config, tmp_path):
    """Before: epsilon / 3 in states/identification.json resumed and drove 44.3 A against 30 A, exit 0."""
    run = stopped(config, tmp_path / "run", 8)
    path = run / "states" / "identification.json"
    data = json.loads(path.read_text())
    data["result"]["epsilon"] /= 3
    path.write_text(json.dumps(data))
    bench = Bench(config)
    with pytest.raises(RunDirError, match=r"states/identification.json: does not match its sha256 digest"):
        campaign.run(resume=run, backend=bench)
    assert bench.calls == 0


def nan_in_a_stage_state(run: Path) -> str:
    path = run / "states" / "trial_008.json"
    data = json.loads(path.read_text())
    data["gains"] = {"2@0.9": float("nan")}
    path.write_text(json.dumps(data))
    return r"states/trial_008.json: unreadable \(NaN is not a finite number\)"


def swapped_trial_files(run: Path) -> str:
    a, b = run / "trial_007.parquet", run / "trial_008.parquet"
    a.rename(run / "x")
    b.rename(a)
    (run / "x").rename(b)
    return r"trial_007.parquet: not the file committed with .*states/trial_007.json"


def truncated_grid_trial(run: Path) -> str:
    path = run / "trial_002.parquet"
    path.write_bytes(path.read_bytes()[:-100])
    return r"trial_002.parquet: not the file committed with .*states/trial_002.json"


@pytest.mark.parametrize("change", [nan_in_a_stage_state, swapped_trial_files, truncated_grid_trial])
def test_a_changed_run_directory_is_one_line_naming_the_file_at_resume(config, tmp_path, change):
    """Before: a NaN in a state resumed (or gave a traceback), swapped trial files resumed with exit 0, a truncated
    grid trial failed only when the identification read it, after a trial ran."""
    run = stopped(config, tmp_path / "run", 9 if change is not truncated_grid_trial else 4)
    message = change(run)
    bench = Bench(config)
    with pytest.raises(RunDirError, match=message):
        campaign.run(resume=run, backend=bench)
    assert bench.calls == 0
    done = CliRunner().invoke(main, ["run", "--resume", str(run)])
    assert done.exit_code != 0 and done.output.count("\n") == 1 and "Traceback" not in done.output
    assert done.output.startswith("error: ") and run.name in done.output


def test_an_untouched_run_directory_resumes_to_the_same_end_and_one_without_its_seal_is_refused(config, tmp_path):
    """Digests change nothing of what a run learns; a run without its seal (no digests, states/run.json without
    "sealed": made before them, or unsealed by hand) is refused before the backend is built (issue 34, item 4:
    it resumed unchecked, and then an edited trial, state or seed was accepted)."""
    reference = campaign.run(config, out=tmp_path / "reference", seed=7).summary
    run = stopped(config, tmp_path / "untouched", 9)
    assert campaign.run(resume=run, backend=Bench(config)).summary == reference
    run = stopped(config, tmp_path / "old", 9)
    for path in [run / "states" / "run.json", run / "states" / "identification.json",
                 *(run / "states").glob("trial_*.json")]:
        data = json.loads(path.read_text())
        for key in ("sealed", "sha256", "trial_sha256", "trials_sha256", "run_id", "config_sha256", "index"):
            data.pop(key, None)
        path.write_text(json.dumps(data))
    bench = Bench(config)
    with pytest.raises(RunDirError, match=r"states/run.json: holds no seal"):
        campaign.run(resume=run, backend=bench)
    assert bench.calls == 0


@pytest.mark.parametrize("unseal", ["resealed", "run.json deleted", "every digest stripped"])
def test_an_identification_edited_behind_the_digests_is_refused_on_resume(config, tmp_path, unseal):
    """Before (benchmarks/fuzz.py): epsilon / 3 with its digest recomputed, or with states/run.json deleted or every
    digest stripped, resumed and drove 39.7 A against 30 A. The saved identification is checked against the grid
    trials' identified again, and a run whose states carry digests stays sealed without run.json."""
    import hashlib

    run = stopped(config, tmp_path / "run", 8)
    path = run / "states" / "identification.json"
    data = json.loads(path.read_text())
    data["result"]["epsilon"] /= 3
    if unseal == "resealed":
        data.pop("sha256")
        data["sha256"] = hashlib.sha256(json.dumps(data, allow_nan=False).encode()).hexdigest()
        path.write_text(json.dumps(data))
    else:
        data.pop("sha256", None)
        path.write_text(json.dumps(data))
        (run / "states" / "run.json").unlink()
        if unseal == "every digest stripped":
            for state in (run / "states").glob("trial_*.json"):
                saved = json.loads(state.read_text())
                for key in ("sha256", "trial_sha256"):
                    saved.pop(key, None)
                state.write_text(json.dumps(saved))
    bench = Bench(config)
    with pytest.raises(RunDirError, match=r"states/(identification.json: (epsilon .* is not what the grid trials on "
                                          r"disk give|does not match its sha256 digest)|run.json: missing|run.json: "
                                          r"holds no seal)"):
        campaign.run(resume=run, backend=bench)
    assert bench.calls == 0


@pytest.mark.parametrize("edit, message", [
    (lambda choice: {**choice, "source": "encoder"}, r"torque_source 'encoder' \(least_error\) is not what the grid "
                                                     r"trials on disk choose \('(both|sensor)', "),
    (lambda choice: None, r"torque_source: no torque source choice recorded"),
])
def test_a_torque_source_choice_edited_behind_its_digest_is_refused_on_resume(write_config, tmp_path, edit, message):
    """"auto" chooses after the grid and records the choice: resealed with another source (or none), a resume
    would have measured with what the file said, not with what the grid trials on disk choose."""
    import hashlib

    config = load_config(write_config({**SMALL_CAMPAIGN, "campaign": {**SMALL_CAMPAIGN["campaign"],
                                                                      "torque_source": "auto"}}))
    run = stopped(config, tmp_path / "run", 8)
    path = run / "states" / "identification.json"
    data = json.loads(path.read_text())
    assert data["torque_source"]["automatic"] and data["torque_source"]["reason"] == "least_error"
    changed = edit(data["torque_source"])
    data.pop("sha256")
    if changed is None:
        del data["torque_source"]
    else:
        data["torque_source"] = changed
    data["sha256"] = hashlib.sha256(json.dumps(data, allow_nan=False).encode()).hexdigest()
    path.write_text(json.dumps(data))
    bench = Bench(config)
    with pytest.raises(RunDirError, match=message):
        campaign.run(resume=run, backend=bench)
    assert bench.calls == 0
