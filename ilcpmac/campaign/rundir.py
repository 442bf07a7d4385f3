"""The run directory: a valid bench folder that grows one trial at a time, atomically.

Layout::

    RUN_DIR/
      campaign.toml        the config the run started with (used by --resume)
      bench.toml           [motor], [sensors] and the complete trials so far
      backemf.csv
      trial_001.csv ...    one CSV per trial
      states/trial_001.json  after each trial: the request, every stage's state,
                           the campaign's own state and the trial's ripple figures
      states/identification.json
      summary.json

Each trial is committed in this order: its CSV, its state file, then
bench.toml (the commit point: a trial is complete once bench.toml lists it),
then summary.json; every file is written to a temporary name, fsynced
(summary.json, derived from the states, is not) and renamed. A background
thread commits trials in order while the campaign runs the next one. After a
crash, files of trials bench.toml does not list are removed.
"""

from __future__ import annotations

import json
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path

from ilcpmac.backends.base import BenchDescription
from ilcpmac.bench.format import (
    BENCH_FILE,
    atomic_write,
    bench_toml_text,
    read_trial_csv,
    write_backemf_csv,
    write_trial_csv,
)
from ilcpmac.config import read_toml
from ilcpmac.errors import BenchFormatError, IlcpmacError
from ilcpmac.records import TrialData

CONFIG_FILE = "campaign.toml"
STATES = "states"


class RunDirError(IlcpmacError):
    """A run directory cannot be created or resumed."""


def trial_file(index: int) -> str:
    """The CSV name of trial ``index`` (1-based)."""
    return f"trial_{index:03d}.csv"


class RunDir:
    """A run directory (see the module docstring)."""

    def __init__(self, path: Path, description: BenchDescription, entries: list[tuple[str, float, float]]) -> None:
        self.path = path
        self.description = description
        self._entries = entries
        self._states: dict[int, dict] = {}
        self._writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rundir")
        self._pending: list[Future] = []

    @classmethod
    def create(cls, path: str | Path, description: BenchDescription, config_text: str) -> "RunDir":
        """Start a new run in ``path``, which must not hold a run already."""
        path = Path(path)
        if path.exists() and any(path.iterdir()):
            raise RunDirError(f"{path}: exists and is not empty; use --resume {path} or another --out")
        (path / STATES).mkdir(parents=True, exist_ok=True)
        atomic_write(path / CONFIG_FILE, config_text)
        write_backemf_csv(path / "backemf.csv", description.backemf_nm_per_a)
        run = cls(path, description, [])
        run._write_bench_toml()
        return run

    @classmethod
    def resume(cls, path: str | Path, description: BenchDescription) -> "RunDir":
        """Reopen ``path``: its complete trials are those bench.toml lists; the rest is removed."""
        path = Path(path)
        if not (path / CONFIG_FILE).is_file():
            raise RunDirError(f"{path}: not a run directory (no {CONFIG_FILE})")
        data = read_toml(path / BENCH_FILE, RunDirError)
        entries = [(t["file"], float(t["torque_setpoint"]), float(t["speed_setpoint"]))
                   for t in data.get("trials", [])]
        for i, (name, _, _) in enumerate(entries, start=1):
            if name != trial_file(i) or not (path / name).is_file() or not cls._state_path(path, i).is_file():
                raise RunDirError(f"{path}: trial {i} is listed in {BENCH_FILE} but {name} or its state is missing")
        run = cls(path, description, entries)
        run._remove_incomplete()
        return run

    @staticmethod
    def _state_path(path: Path, index: int) -> Path:
        return path / STATES / f"trial_{index:03d}.json"

    def _remove_incomplete(self) -> None:
        """Delete what a crash left of a trial that was never committed, and temporary files."""
        indices = range(1, len(self._entries) + 1)
        keep = {trial_file(i) for i in indices} | {self._state_path(self.path, i).name for i in indices}
        for f in {*self.path.glob("trial_*"), *(self.path / STATES).glob("trial_*"),
                  *self.path.glob("*.tmp"), *(self.path / STATES).glob("*.tmp")}:
            if f.name not in keep:
                f.unlink()

    def _write_bench_toml(self, entries: list[tuple[str, float, float]] | None = None) -> None:
        atomic_write(self.path / BENCH_FILE, bench_toml_text(self.description.motor, self.description.calibration,
                                                             self._entries if entries is None else entries))

    @property
    def completed(self) -> int:
        """Number of trials added (complete on disk once `flush` returns)."""
        return len(self._entries)

    def flush(self) -> None:
        """Wait until every added trial is committed; re-raise a failed write."""
        pending, self._pending = self._pending, []
        for future in pending:
            future.result()

    def close(self) -> None:
        """Commit what is pending and stop the writer."""
        try:
            self.flush()
        finally:
            self._writer.shutdown(wait=True)

    def config_text(self) -> str:
        """The campaign config the run started with."""
        return (self.path / CONFIG_FILE).read_text()

    def add_trial(self, trial: TrialData, state: dict, summary: dict) -> int:
        """Queue the next trial, its state and the summary for commit, in order; return its index."""
        for future in [f for f in self._pending if f.done()]:
            future.result()  # re-raise a failed write early
        self._pending = [f for f in self._pending if not f.done()]
        index = len(self._entries) + 1
        self._entries.append((trial_file(index), trial.torque_setpoint_nm, trial.speed_setpoint_hz))
        self._states[index] = state
        self._pending.append(self._writer.submit(self._commit, index, trial, state, summary, list(self._entries)))
        return index

    def _commit(self, index: int, trial: TrialData, state: dict, summary: dict,
                entries: list[tuple[str, float, float]]) -> None:
        # the simulator's true currents and speed are not kept (the true torque is, for honest
        # ripple figures): a 64-revolution trial is 30 % smaller and quicker to write
        write_trial_csv(self.path / trial_file(index), replace(trial, i_true_a=None, speed_true_rad_s=None))
        atomic_write(self._state_path(self.path, index), json.dumps(state))
        self._write_bench_toml(entries)
        self.write_summary(summary)

    def state(self, index: int) -> dict:
        """The state saved with trial ``index``."""
        if index not in self._states:
            self._states[index] = json.loads(self._state_path(self.path, index).read_text())
        return self._states[index]

    def write_json(self, name: str, data: dict) -> None:
        """Write ``states/NAME`` atomically."""
        atomic_write(self.path / STATES / name, json.dumps(data))

    def read_json(self, name: str) -> dict | None:
        """``states/NAME``, or None when it does not exist."""
        f = self.path / STATES / name
        return json.loads(f.read_text()) if f.is_file() else None

    def write_summary(self, summary: dict) -> None:
        """Write summary.json atomically (not fsynced: it is rebuilt from the states on resume)."""
        atomic_write(self.path / "summary.json", json.dumps(summary, indent=1), durable=False)

    def read_trials(self, indices: list[int]) -> list[TrialData]:
        """Read complete trials back from their CSVs."""
        self.flush()
        trials = []
        for i in indices:
            name, torque, speed = self._entries[i - 1]
            try:
                trials.append(read_trial_csv(self.path / name, torque, speed))
            except BenchFormatError as e:
                raise RunDirError(str(e)) from None
        return trials
