"""The run directory under hostile conditions: concurrent runs, kill -9, full disks, read-only places,
non-finite numbers, and errors printed while the live table is on screen."""

from __future__ import annotations

import base64
import builtins
import dataclasses
import errno
import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from filelock import FileLock
from hypothesis import given, settings
from hypothesis import strategies as st

from ilcpmac.backends.base import BenchDescription, BenchLimits
from ilcpmac.bench.format import as_written, read_bench, write_trial_csv
from ilcpmac.campaign import rundir
from ilcpmac.campaign.events import GuardEvent
from ilcpmac.campaign.record import TrialRecord
from ilcpmac.campaign.rundir import (
    HOLDER_FILE,
    LOCK_FILE,
    PACKED_KEY,
    PACKED_MIN_LENGTH,
    RunDir,
    RunDirError,
    RunFiles,
    _packed,
    _unpacked,
    trial_file,
)
from ilcpmac.campaign.state import TrialState
from ilcpmac.cli import main
from ilcpmac.core.errors import ConfigError
from ilcpmac.core.records import MotorInfo, SensorCalibration, TrialData
from ilcpmac.signals.harmonics import RippleFigures

CPR = 64
_ANGLE = 4 * 2 * np.pi * np.arange(CPR)[:, None] / CPR - 2 * np.pi / 3 * np.arange(3)
DESCRIPTION = BenchDescription(MotorInfo(4, 12, CPR, 1e-3), 0.1 * np.cos(_ANGLE),
                               SensorCalibration(np.ones(3), np.zeros(3), 1.0), BenchLimits(10.0, 10.0, 5.0))


def trial(torque_nm: float = 1.0) -> TrialData:
    count = np.arange(CPR, dtype=np.int64)
    # K . i_ref = 0.1 x 1.5 x i_ref's amplitude: the set point
    return TrialData(torque_nm, 0.5, count, count / (0.5 * CPR), torque_nm / 0.15 * np.cos(_ANGLE),
                     torque_nm + 0.01 * np.sin(_ANGLE[:, 0]))


def state_of(torque_nm: float = 1.0, feedforward_nm=None, pipeline: dict | None = None,
             record: TrialRecord | None = None) -> TrialState:
    """A trial's state: no feed-forward, pipeline or guard unless given."""
    return TrialState(record or TrialRecord(1, "identify", "grid", torque_nm, 0.5), pipeline, {}, None,
                      DESCRIPTION.calibration, np.zeros(CPR) if feedforward_nm is None else np.asarray(feedforward_nm),
                      3, 0)


def add(run: RunDir, torque_nm: float = 1.0, state: TrialState | None = None) -> int:
    return run.add_trial(trial(torque_nm), state or state_of(torque_nm), {"trials": run.completed})


def new_run(path: Path, trials: int = 0) -> Path:
    """A closed run directory holding ``trials`` complete trials."""
    run = RunDir.create(path, DESCRIPTION, "[campaign]\n", {"seed": 3, "trials": None})
    for k in range(trials):
        add(run, 1.0 + k)
    run.close()
    return path


def completed(path: Path) -> int:
    """Complete trials of the run in ``path``, as a resume finds them."""
    run = RunDir.resume(path, DESCRIPTION)
    run.close()
    return run.completed


def temporary_files(path: Path) -> list[Path]:
    return sorted(path.rglob("*.tmp"))


# ---------------------------------------------------------------- the lock

def test_a_second_run_on_a_locked_directory_fails_at_once_saying_who_holds_it(tmp_path):
    path = new_run(tmp_path / "run")
    first = RunDir.resume(path, DESCRIPTION)
    who = f"in use by pid {os.getpid()} on {socket.gethostname()} since "
    with pytest.raises(RunDirError, match=who):
        RunDir.resume(path, DESCRIPTION)
    with pytest.raises(RunDirError, match=who):
        RunDir.lock(path, new=True)
    first.close()
    assert not (path / HOLDER_FILE).exists()
    RunDir.resume(path, DESCRIPTION).close()  # released on close


def test_a_dead_holders_record_is_not_believed(tmp_path):
    path = new_run(tmp_path / "run")
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (path / HOLDER_FILE).write_text(json.dumps({"pid": dead.pid, "host": socket.gethostname(),
                                                "started": "2000-01-01 00:00:00"}))
    with FileLock(path / LOCK_FILE).acquire(timeout=0):  # a new holder that has not written its record yet
        with pytest.raises(RunDirError, match=r"in use by another process \(not yet recorded\)"):
            RunDir.resume(path, DESCRIPTION)
    RunDir.resume(path, DESCRIPTION).close()  # the stale record does not block


class RecordingBackends:
    """Stands in for backends.registry.build_backend: records that a backend was asked for."""

    def __init__(self) -> None:
        self.built = 0

    def __call__(self, *args):
        self.built += 1
        raise AssertionError("the backend must not be built")


@pytest.fixture
def backends(monkeypatch) -> RecordingBackends:
    recording = RecordingBackends()
    monkeypatch.setattr("ilcpmac.backends.registry.build_backend", recording)
    return recording


def error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if "error:" in line]


def test_cli_resume_of_a_locked_run_is_one_line_and_never_builds_the_backend(tmp_path, backends):
    path = new_run(tmp_path / "run")
    with RunDir.lock(path, new=False):
        out = CliRunner().invoke(main, ["run", "--resume", str(path)])
    assert out.exit_code == 2, out.output
    [line] = error_lines(out.stderr)
    assert line.startswith(f"error: {path}: in use by pid {os.getpid()} on {socket.gethostname()} since ")
    assert backends.built == 0


# ---------------------------------------------------------------- kill -9

class Crash(BaseException):
    """A kill at this instant (BaseException: nothing may handle it)."""


CREATION_WRITES = [HOLDER_FILE, "run.json", "backemf.csv", "bench.toml", "campaign.toml"]


@pytest.mark.parametrize("at", CREATION_WRITES)
@pytest.mark.parametrize("before_rename", [True, False])
def test_a_crash_at_any_creation_step_leaves_debris_that_a_new_run_reuses(tmp_path, monkeypatch, at, before_rename):
    real_open, real_replace = builtins.open, os.replace

    def crashing_open(file, mode="r", *args, **kwargs):
        if not before_rename and Path(file).name == at + ".tmp" and "w" in mode:
            raise Crash(at)
        return real_open(file, mode, *args, **kwargs)

    def crashing_replace(src, dst, *args, **kwargs):
        if before_rename and Path(dst).name == at:
            raise Crash(at)  # the temporary file is complete, not renamed yet
        return real_replace(src, dst, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", crashing_open)
    monkeypatch.setattr(os, "replace", crashing_replace)
    path = tmp_path / "run"
    with pytest.raises(Crash):
        RunDir.create(path, DESCRIPTION, "[campaign]\n", {"seed": 3})
    monkeypatch.undo()
    with pytest.raises(RunDirError, match=f"not a run directory.*interrupted: start it again with --out {path}"):
        RunDir.resume(path, DESCRIPTION)
    new_run(path, trials=1)
    assert completed(path) == 1
    assert RunDir.read_settings(path) == {"seed": 3, "trials": None}
    assert temporary_files(path) == []


def test_debris_next_to_other_files_is_not_reused(tmp_path):
    path = tmp_path / "run"
    (path / "states").mkdir(parents=True)
    (path / "bench.toml").write_text("")
    (path / "notes.txt").write_text("mine")
    with pytest.raises(RunDirError, match="exists and is not empty"):
        RunDir.create(path, DESCRIPTION, "")
    assert (path / "notes.txt").read_text() == "mine"
    assert not (path / LOCK_FILE).exists()  # nothing written into it


def test_a_run_is_not_created_over_another(tmp_path):
    path = new_run(tmp_path / "run", trials=1)
    with pytest.raises(RunDirError, match=f"holds a run; continue it with --resume {path}"):
        RunDir.create(path, DESCRIPTION, "")
    assert completed(path) == 1


CHILD = """
import os, signal, sys
sys.path.insert(0, {tests!r})
from test_rundir import new_run, RunDir, DESCRIPTION

run = RunDir.resume(new_run({path!r}, trials=1), DESCRIPTION)  # holds the lock
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_after_a_real_kill_9_the_lock_is_free_and_the_run_resumes(tmp_path):
    path = tmp_path / "run"
    child = subprocess.run([sys.executable, "-c", CHILD.format(tests=str(Path(__file__).parent), path=str(path))],
                           capture_output=True)
    assert child.returncode == -signal.SIGKILL, child.stderr.decode()
    assert (path / HOLDER_FILE).exists()  # a dead process's record, which must not block
    assert completed(path) == 1


# ---------------------------------------------------------------- read-only directories

@pytest.fixture
def read_only(monkeypatch):
    """Make a directory read-only: chmod when that binds (not as root), else refuse every write under it
    (opening for writing, creating a file or a directory), as a read-only file system does."""
    def make(path: Path) -> None:
        if os.geteuid() != 0:
            for d in (path, *(p for p in path.rglob("*") if p.is_dir())):
                d.chmod(0o555)
                restore.append(d)
            return
        real_open, real_os_open, real_mkdir = builtins.open, os.open, os.mkdir

        def under(file) -> bool:
            return isinstance(file, (str, Path)) and Path(file).resolve().is_relative_to(path.resolve())

        def refuse(file):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(file))

        def guarded_open(file, mode="r", *args, **kwargs):
            if under(file) and any(c in mode for c in "wax+"):
                refuse(file)
            return real_open(file, mode, *args, **kwargs)

        def guarded_os_open(file, flags, *args, **kwargs):
            if under(file) and flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT):
                refuse(file)
            return real_os_open(file, flags, *args, **kwargs)

        def guarded_mkdir(file, *args, **kwargs):
            if under(file):
                refuse(file)
            return real_mkdir(file, *args, **kwargs)

        monkeypatch.setattr(builtins, "open", guarded_open)
        monkeypatch.setattr(os, "open", guarded_os_open)
        monkeypatch.setattr(os, "mkdir", guarded_mkdir)

    restore: list[Path] = []
    yield make
    for d in restore:
        d.chmod(0o755)


def test_resume_of_a_read_only_run_is_one_line_before_the_backend_is_built(tmp_path, read_only, backends):
    path = new_run(tmp_path / "run", trials=1)
    read_only(path)
    out = CliRunner().invoke(main, ["run", "--resume", str(path)])
    assert out.exit_code == 2, out.output
    [line] = error_lines(out.stderr)  # .lock (read-only file system) or .lock.holder (read-only directory)
    assert line.startswith(f"error: {path / LOCK_FILE}")
    assert line.endswith(": cannot write (Permission denied); a run needs a writable directory")
    assert backends.built == 0


def test_a_new_run_in_a_read_only_place_is_one_line_before_the_backend_is_built(tmp_path, read_only, backends,
                                                                               write_config):
    config = write_config()
    (tmp_path / "ro").mkdir()
    read_only(tmp_path / "ro")
    out = CliRunner().invoke(main, ["run", str(config), "--out", str(tmp_path / "ro" / "run")])
    assert out.exit_code == 2, out.output
    [line] = error_lines(out.stderr)
    assert line.startswith(f"error: {tmp_path / 'ro'}") and "cannot write (Permission denied)" in line
    assert backends.built == 0


# ---------------------------------------------------------------- full disks

class FailingFile:
    """A file whose write stores half its data, then fails like a full disk."""

    def __init__(self, f, error: int) -> None:
        self.f, self.error = f, error

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.f.close()

    def write(self, data) -> None:
        self.f.write(data[: len(data) // 2])
        raise OSError(self.error, os.strerror(self.error))


def fail_writing(monkeypatch, name: str, error: int, before: threading.Event | None = None) -> None:
    """Writing the file ``name`` fails with ``error`` (after ``before`` is set, when given)."""
    real_open = builtins.open

    def open_(file, mode="r", *args, **kwargs):
        f = real_open(file, mode, *args, **kwargs)
        if Path(file).name == name + ".tmp" and "w" in mode:
            if before is not None:
                before.wait()
            return FailingFile(f, error)
        return f

    monkeypatch.setattr(builtins, "open", open_)


@pytest.mark.parametrize("name, error, committed", [(trial_file(2), errno.ENOSPC, 1),
                                                    ("states/trial_002.json", errno.EDQUOT, 1),
                                                    ("bench.toml", errno.EROFS, 1),
                                                    ("summary.json", errno.ENOSPC, 2)])
def test_a_full_disk_while_committing_is_one_line_and_the_run_stays_resumable(tmp_path, monkeypatch, name, error,
                                                                               committed):
    path = new_run(tmp_path / "run", trials=1)
    run = RunDir.resume(path, DESCRIPTION)
    fail_writing(monkeypatch, Path(name).name, error)
    add(run, 2.0)
    with pytest.raises(RunDirError, match=f"^{path / name}: cannot write \\({os.strerror(error)}\\); the run "
                                          f"stays resumable: .* ilcpmac run --resume {path}$"):
        run.close()
    monkeypatch.undo()
    assert temporary_files(path) == []
    resumed = RunDir.resume(path, DESCRIPTION)
    assert resumed.completed == committed
    assert (path / trial_file(2)).exists() == (committed == 2)
    resumed.close()


def test_nothing_is_committed_after_a_failed_trial(tmp_path, monkeypatch):
    path = new_run(tmp_path / "run", trials=1)
    run = RunDir.resume(path, DESCRIPTION)
    go = threading.Event()
    fail_writing(monkeypatch, trial_file(2), errno.ENOSPC, before=go)
    add(run, 2.0)
    add(run, 3.0)  # queued while trial 2 is being written
    go.set()
    with pytest.raises(RunDirError, match=f"{trial_file(2)}: cannot write"):
        run.close()
    monkeypatch.undo()
    resumed = RunDir.resume(path, DESCRIPTION)  # bench.toml does not list trial 3 without trial 2
    assert resumed.completed == 1
    assert sorted(p.name for p in path.glob("trial_*")) == [trial_file(1)]
    resumed.close()


# ---------------------------------------------------------------- non-finite numbers

def test_json_of_a_run_never_holds_a_non_finite_number(tmp_path):
    path = new_run(tmp_path / "run", trials=1)
    run = RunDir.resume(path, DESCRIPTION)
    with pytest.raises(RunDirError, match=r"identification.json: result.cogging.1 is nan, not a finite number"):
        run.write_identification({"result": {"cogging": [1.0, float("nan")]}})
    add(run, 2.0, state_of(record=TrialRecord(2, "identify", "grid", 2.0, 0.5, reduction_factor=float("inf"))))
    with pytest.raises(RunDirError, match=r"trial_002.json: record.reduction_factor is inf, not a finite number"):
        run.close()
    assert not (path / "states" / "identification.json").exists()
    resumed = RunDir.resume(path, DESCRIPTION)
    assert resumed.completed == 1
    resumed.close()
    for f in path.rglob("*.json"):
        json.loads(f.read_text(), parse_constant=lambda c, f=f: pytest.fail(f"{f} holds {c}"))


# ---------------------------------------------------------------- the live table and errors

class FailingRunner:
    """A campaign that finds a config error once the live table is on screen (as the runner's checks do)."""

    def __init__(self, *args, **kwargs) -> None:
        pass

    def run(self) -> dict:
        raise ConfigError("campaign.toml: [campaign] learn_speeds_hz: beyond the bench's limit")


def test_an_error_raised_under_the_live_table_starts_its_own_line(tmp_path, write_config, monkeypatch):
    monkeypatch.setattr("ilcpmac.campaign.runner.CampaignRunner", FailingRunner)
    out = CliRunner().invoke(main, ["run", str(write_config()), "--out", str(tmp_path / "run")])
    assert out.exit_code == 2, out.output
    assert "┘" in out.stderr  # the table was on screen
    assert error_lines(out.stderr) == ["error: campaign.toml: [campaign] learn_speeds_hz: beyond the bench's "
                                       "limit"]


# ---------------------------------------------------------------- trial files (issue 10)

def test_trials_are_parquet_and_hold_what_the_campaign_reads_back(tmp_path):
    """Everything the campaign learns from, and the true torque; not the measured currents nobody reads."""
    path = new_run(tmp_path / "run")
    run = RunDir.resume(path, DESCRIPTION)
    measured = dataclasses.replace(trial(2.0), i_meas_a=np.ones((CPR, 3)), torque_true_nm=np.full(CPR, 2.5))
    run.add_trial(measured, state_of(2.0), {})
    [back] = run.read_trials([1])
    run.close()
    assert sorted(p.name for p in path.glob("trial_*")) == ["trial_001.parquet"]
    np.testing.assert_array_equal(back.torque_true_nm, measured.torque_true_nm)
    np.testing.assert_array_equal(back.i_ref_a, as_written(measured).i_ref_a)
    assert back.i_meas_a is None


def test_a_run_of_an_earlier_release_is_read_but_not_resumed(tmp_path):
    """A run begun before Parquet (CSV trials) was made before digests and seals too: nothing tells its files from
    another run's, so it is not resumed (one line naming states/run.json); its trials still read."""
    path = new_run(tmp_path / "run", trials=2)
    before = read_bench(path)
    for i in (1, 2):
        (path / trial_file(i)).unlink()
        write_trial_csv(path / trial_file(i, ".csv"), before.trials[i - 1])
    (path / "bench.toml").write_text((path / "bench.toml").read_text().replace(".parquet", ".csv"))
    (path / "states" / "run.json").write_text("{}")
    for state in (path / "states").glob("trial_*.json"):
        saved = json.loads(state.read_text())
        for key in ("sha256", "trial_sha256", "run_id", "index"):
            saved.pop(key, None)
        state.write_text(json.dumps(saved))
    with pytest.raises(RunDirError, match=r"states/run.json: holds no seal \(a run made by an earlier release, or "
                                          r"its seal removed\); only a sealed run resumes"):
        RunDir.resume(path, DESCRIPTION)
    after = read_bench(path)
    assert after.trial_files == ("trial_001.csv", "trial_002.csv")
    for a, b in zip(before.trials, after.trials):
        np.testing.assert_array_equal(a.torque_nm, b.torque_nm)
    assert RunFiles(path).read_state(2).record.role == "grid"  # its states too, unchecked


# ---------------------------------------------------------------- what a commit writes, cheaply (issue 10)

def bits(values) -> np.ndarray:
    return np.asarray(values, np.float64).view(np.int64)


def test_a_state_reads_back_to_the_bit_with_its_long_float_lists_packed(tmp_path):
    table = [0.1 + 0.2, -0.0, 5e-324, -1.7976931348623157e308, *np.random.default_rng(5).normal(size=40).tolist()]
    stages = {"short": table[:PACKED_MIN_LENGTH - 1], "P": [None, *table], "ints": list(range(40)),
              "zeros": [0.0] * 40, "nested": [table, table[:3]], "empty": []}
    state = state_of(feedforward_nm=table, pipeline={"stage": stages})
    path = new_run(tmp_path / "run")
    run = RunDir.resume(path, DESCRIPTION)
    run.add_trial(trial(), state, {})
    run.close()
    raw = json.loads((path / "states" / "trial_001.json").read_text())
    saved = raw["pipeline"]["stage"]
    assert set(raw["request"]["feedforward_nm"]) == {PACKED_KEY} and set(saved["nested"][0]) == {PACKED_KEY}
    for key in ("short", "P", "ints", "zeros", "empty"):
        assert saved[key] == stages[key], key
    assert saved["nested"][1] == table[:3]
    back = RunFiles(path).read_state(1)
    assert back.to_json() == state.to_json()
    np.testing.assert_array_equal(bits(back.feedforward_nm), bits(table))
    assert RunDir.resume(path, DESCRIPTION).state(1).to_json() == state.to_json()  # as a resume reads it
    (path / "states" / "trial_001.json").write_text(json.dumps(state.to_json()))  # a run written before packing
    (path / "states" / "run.json").write_text("{}")  # (and before digests)
    assert RunFiles(path).read_state(1).to_json() == state.to_json()


def test_a_typed_state_writes_the_same_bytes_it_reads(tmp_path):
    """Read back and written again, a state file is byte for byte the one the run wrote: the typed record
    keeps every key, its order and every number."""
    ripple = RippleFigures(0.012, 0.004, 0.001, 0.0035, 1e-3, 2e-4, 3e-4, 1e-5)
    record = TrialRecord(1, "learn", "learn", 2.0, 0.9, ripple, ripple, 3.25, 4.5)
    table = np.random.default_rng(3).normal(size=CPR) * 1e-3
    state = TrialState(record, {"ilc": {"2@0.9": {"u": table.tolist(), "trials": 2}}, "current-sensor": {}},
                       {"2@0.9": 0.5}, GuardEvent("2@0.9", 1, 0.5), DESCRIPTION.calibration, table, 6, 12345)
    path = new_run(tmp_path / "run")
    run = RunDir.resume(path, DESCRIPTION)
    run.add_trial(trial(2.0), state, {})
    run.close()
    written = (path / "states" / "trial_001.json").read_bytes()
    assert list(json.loads(written)) == ["record", "pipeline", "gains", "guard", "request", "trial_sha256", "run_id",
                                         "index", "sha256"]
    again = new_run(tmp_path / "again")
    run = RunDir.resume(again, DESCRIPTION)
    run.add_trial(trial(2.0), RunFiles(path).read_state(1), {})
    run.close()
    rewritten = (again / "states" / "trial_001.json").read_bytes()
    ids = [json.loads(text)["run_id"] for text in (written, rewritten)]  # each run's own, and its digest with it
    assert ids[0] != ids[1] and re.sub(rb'"(run_id|sha256)": "[0-9a-f]+"', b"", rewritten) == re.sub(
        rb'"(run_id|sha256)": "[0-9a-f]+"', b"", written)


def test_the_request_a_state_says_ran_carries_its_feed_forward_as_the_feed_forward():
    """A resumed run analyses the trials before the resume with the request their state saved; it took the
    feed-forward for the excitation (found by the floors, which subtract what the feed-forward delivered: a
    resumed run's floors differed from the uninterrupted run's)."""
    table = np.random.default_rng(4).normal(size=CPR) * 1e-3
    ran = state_of(2.0, table).ran()
    np.testing.assert_array_equal(ran.feedforward_nm, table)
    assert not np.any(ran.excitation_nm) and ran.revolutions == 3 and ran.torque_setpoint_nm == 2.0


def test_the_learning_phase_has_one_name_in_records_of_earlier_releases_too():
    """Earlier releases named the learning phase "ilc" when the ilc stage ran (issue 26, item 6)."""
    ripple = RippleFigures(0.012, 0.004, 0.001, 0.0035, 1e-3, 2e-4, 3e-4, 1e-5)
    earlier = {**TrialRecord(9, "learn", "learn", 2.0, 0.9, ripple).to_json(), "phase": "ilc"}
    assert TrialRecord.from_json(earlier).phase == "learn"


@pytest.mark.parametrize("damage", [{"record": None}, {"guard": {"set_point": "1@0.5"}}, {"pipeline": [1]},
                                    {"gains": []}, {"request": {"seed": 0}}, {"record": {"index": 1}}])
def test_a_malformed_state_is_one_line_naming_the_state_file(tmp_path, damage):
    path = new_run(tmp_path / "run", trials=1)
    state_file = path / "states" / "trial_001.json"
    state_file.write_text(json.dumps(state_of().to_json() | damage))
    with pytest.raises(RunDirError) as error:
        RunFiles(path).read_state(1)
    assert str(error.value).startswith(f"{state_file}: unreadable (")
    assert "\n" not in str(error.value)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(allow_nan=False, allow_infinity=False), max_size=2 * PACKED_MIN_LENGTH))
def test_packed_float_lists_unpack_to_the_same_bits(values):
    state = {"a": values, "b": [values]}
    back = json.loads(json.dumps(_packed(state, Path("s.json"))), object_hook=_unpacked)
    assert back == state
    np.testing.assert_array_equal(bits(back["a"]), bits(values))


def test_a_non_finite_number_in_a_packed_list_is_named_and_not_written(tmp_path):
    table = [0.0] * PACKED_MIN_LENGTH
    table[7] = float("-inf")
    path = new_run(tmp_path / "run", trials=1)
    run = RunDir.resume(path, DESCRIPTION)
    add(run, 2.0, state_of(feedforward_nm=table))
    with pytest.raises(RunDirError, match=r"trial_002\.json: request\.feedforward_nm\.7 is -inf, not a finite "
                                          r"number; not written$"):
        run.close()
    assert completed(path) == 1


@pytest.mark.parametrize("packed", ["AAAA", "not base64!", 5, None, base64.b64encode(np.array([1.0, np.nan]).tobytes()
                                                                                    ).decode()])
def test_a_damaged_packed_list_is_one_line_naming_the_state_file(tmp_path, packed):
    path = new_run(tmp_path / "run", trials=1)
    (path / "states" / "trial_001.json").write_text(json.dumps({"request": {"feedforward_nm": {PACKED_KEY: packed}}}))
    with pytest.raises(RunDirError) as error:
        RunFiles(path).read_state(1)
    assert str(error.value).startswith(f"{path / 'states' / 'trial_001.json'}: unreadable (")
    assert "\n" not in str(error.value)


def summary_of(path: Path) -> dict:
    return json.loads((path / "summary.json").read_text())


def test_summary_json_is_held_back_within_its_interval_and_is_the_last_trials_once_the_run_stops(tmp_path,
                                                                                                monkeypatch):
    path = new_run(tmp_path / "run")
    monkeypatch.setattr(rundir, "SUMMARY_INTERVAL_S", 1e9)
    run = RunDir.resume(path, DESCRIPTION)
    for k in range(3):
        add(run, 1.0 + k)  # summary {"trials": trials before this one}
    run.flush()
    assert summary_of(path) == {"trials": 0}  # a run's first commit writes it, the next two are held back
    run.close()
    assert summary_of(path) == {"trials": 2}

    run = RunDir.resume(path, DESCRIPTION)
    add(run, 4.0)
    add(run, 5.0)
    run.write_summary({"trials": "final"})  # after the commits, and in place of what they held back
    run.close()
    assert summary_of(path) == {"trials": "final"}

    monkeypatch.setattr(rundir, "SUMMARY_INTERVAL_S", 0.0)
    run = RunDir.resume(path, DESCRIPTION)
    add(run, 6.0)
    add(run, 7.0)
    run.flush()
    assert summary_of(path) == {"trials": 6}
    run.close()
