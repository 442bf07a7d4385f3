"""Issue 34, items 3 and 4: what the seal guarantees (docs/campaign.md, "What the seal guarantees").

A resumed run goes on with the config, limits, seed and files it began with: an edited or swapped campaign.toml,
a seal removed, a state or trial of another run or of another trial mixed in, another run's run.json, and options
that would change a resumed run are refused in one line naming the file or option, before the backend is built.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner
from test_rundir import DESCRIPTION, add, new_run

import ilcpmac.campaign
from ilcpmac.campaign.rundir import RunDir, RunDirError, RunFiles
from ilcpmac.cli import main
from ilcpmac.core.errors import ConfigError


def resumes(path: Path) -> int:
    """Complete trials of the run in ``path`` as a resume finds them (its settings first, as ``ilcpmac run``)."""
    RunDir.read_settings(path)
    run = RunDir.resume(path, DESCRIPTION)
    run.close()
    return run.completed


def edit_json(path: Path, change) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


@pytest.fixture
def runs(tmp_path) -> tuple[Path, Path]:
    """Two runs of three trials each, the same config and seed, their trials different."""
    first, second = new_run(tmp_path / "first", trials=3), tmp_path / "second"
    run = RunDir.create(second, DESCRIPTION, "[campaign]\n", {"seed": 3, "trials": None})
    for k in range(3):
        add(run, 4.0 + k)
    run.close()
    assert resumes(first) == resumes(second) == 3
    return first, second


def test_a_config_changed_since_the_run_began_is_refused(runs):
    """Before, a campaign.toml with higher [limits] resumed and drove 72.3 A where the run began at 30 A."""
    first, _ = runs
    (first / "campaign.toml").write_text("[limits]\nmax_current_a = 80.0\n")
    for resume in (lambda: RunDir.read_settings(first), lambda: RunDir.resume(first, DESCRIPTION)):
        with pytest.raises(RunDirError, match=r"campaign.toml: not the config this run began with \(its SHA-256 "
                                              r"differs from run.json's config_sha256\); a resumed run keeps the "
                                              r"config and limits it began with"):
            resume()


def test_a_removed_seal_is_refused(runs):
    """Before, deleting "sealed" from run.json and the digests from the states unsealed the run; then an edited
    trial, state or seed was accepted."""
    first, _ = runs
    edit_json(first / "states" / "run.json", lambda d: [d.pop(k) for k in ("sealed", "sha256")])
    for state in (first / "states").glob("trial_*.json"):
        edit_json(state, lambda d: [d.pop(k) for k in ("sha256", "trial_sha256", "run_id", "index")])
    with pytest.raises(RunDirError, match=r"states/run.json: holds no seal"):
        resumes(first)


@pytest.mark.parametrize("key, value", [("seed", 8), ("trials", 1), ("run_id", "0" * 32)])
def test_an_edited_run_json_is_refused(runs, key, value):
    first, _ = runs
    edit_json(first / "states" / "run.json", lambda d: d.__setitem__(key, value))
    with pytest.raises(RunDirError, match=r"states/run.json: does not match its sha256 digest"):
        resumes(first)


def test_a_trial_and_state_of_another_run_are_refused(runs):
    """Before, another run's trial-and-state pair, each matching the other, was accepted and changed the result."""
    first, second = runs
    for name in ("trial_002.parquet", "states/trial_002.json"):
        shutil.copy(second / name, first / name)
    with pytest.raises(RunDirError, match=r"states/trial_002.json: not this run's state of trial 2 \(it says run "
                                          r"'[0-9a-f]{32}', trial 2; run.json: run '[0-9a-f]{32}'\)"):
        resumes(first)


def test_another_run_s_run_json_is_refused(runs):
    first, second = runs
    shutil.copy(second / "states" / "run.json", first / "states" / "run.json")
    with pytest.raises(RunDirError, match=r"states/trial_001.json: not this run's state of trial 1"):
        resumes(first)


def test_a_trial_and_state_of_another_trial_are_refused(runs):
    first, _ = runs
    for name in ("trial_00{}.parquet", "states/trial_00{}.json"):
        shutil.copy(first / name.format(1), first / name.format(3))
    with pytest.raises(RunDirError, match=r"states/trial_003.json: not this run's state of trial 3 \(it says run "
                                          r"'[0-9a-f]{32}', trial 1;"):
        resumes(first)


def test_another_run_s_identification_is_refused(runs):
    first, second = runs
    for path in (first, second):
        run = RunDir.resume(path, DESCRIPTION)
        run.write_identification({"result": {}})
        run.close()
    shutil.copy(second / "states" / "identification.json", first / "states" / "identification.json")
    run = RunDir.resume(first, DESCRIPTION)
    with pytest.raises(RunDirError, match=r"identification.json: not this run's \(it says run '[0-9a-f]{32}', "
                                          r"run.json: run '[0-9a-f]{32}'\)"):
        run.read_identification()
    run.close()


@pytest.mark.parametrize("option, value", [("seed", 8), ("trials", 1), ("budget_min", 5.0)])
def test_options_that_would_change_a_resumed_run_are_refused(runs, option, value):
    """Before, ``--resume DIR --seed 8`` or ``--trials 1`` was silently ignored."""
    first, _ = runs
    flag = {"budget_min": "--budget"}.get(option, f"--{option}")
    with pytest.raises(ConfigError, match=rf"^--resume continues a run with the config, seed, trials and budget it "
                                          rf"began with: give no {flag} \(start a new run to change them\)$"):
        ilcpmac.campaign.run(resume=first, **{option: value})
    done = CliRunner().invoke(main, ["run", "--resume", str(first), flag, str(value)])
    assert done.exit_code == 2 and done.output.strip().startswith("error: --resume continues a run"), done.output


def test_the_cli_refuses_a_swapped_config_in_one_line_before_any_trial(runs):
    first, _ = runs
    (first / "campaign.toml").write_text((first / "campaign.toml").read_text() + "\n[limits]\nmax_current_a = 80\n")
    done = CliRunner().invoke(main, ["run", "--resume", str(first)])
    assert done.exit_code == 2 and done.output.count("\n") == 1, done.output
    assert "campaign.toml: not the config this run began with" in done.output
    assert resumes_after_putting_back(first) == 3


def resumes_after_putting_back(path: Path) -> int:
    (path / "campaign.toml").write_text("[campaign]\n")
    return resumes(path)


@pytest.mark.parametrize("content, message", [
    (b"[1, 2, 3]", r"summary.json: unreadable \(a JSON list, not an object\)"),
    (b'{"trials": ' + b"[" * 100_000 + b"]" * 100_000 + b"}", r"summary.json: unreadable \(nested too deeply\)"),
    (None, r"summary.json: more than 67108864 bytes \(refused\)"),
    (b'{"trials": [{"index": 1, "phase": "identify", "role": "grid", "torque_setpoint": 1e308, '
     b'"speed_setpoint": 0.5}]}', r"summary.json: unreadable \(trials.0: torque_setpoint is 1e\+308, not a number "
                                  r"within \[-100000, 100000\]\)"),
])
def test_a_summary_no_run_writes_is_one_line_and_never_read_whole(runs, content, message):
    """Issue 34, item 12: ilcpmac report on a summary.json that is a list, nested deeply or holds 1e308 gave a
    traceback; a sparse 2 GB one was read whole (2.1 GB of memory)."""
    first, _ = runs
    path = first / "summary.json"
    if content is None:
        with path.open("wb") as f:
            f.truncate(2 << 30)  # sparse: nothing is written
    else:
        path.write_bytes(content)
    with pytest.raises(RunDirError, match=message):
        RunFiles(first).read_summary()
    done = CliRunner().invoke(main, ["report", str(first)])
    assert done.exit_code == 2 and done.output.count("error:") == 1, done.output
