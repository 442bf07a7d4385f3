"""The run directory: a valid bench folder that grows one trial at a time, atomically.

Layout::

    RUN_DIR/
      campaign.toml        the config the run started with (used by --resume)
      bench.toml           [motor], [sensors], [static] where the campaign has a static trial, and the
                           complete trials so far
      backemf.csv
      static.csv           the campaign's static trial ([bench] static_trial_file), where it has one
      trial_001.parquet ... one Parquet file per trial (docs/bench-format.md; a run
                           begun before Parquet has trial_001.csv ..., and resumes)
      states/run.json      the run's settings (seed, trials, config)
      states/trial_001.json  after each trial: the request, every stage's state,
                           the campaign's own state and the trial's ripple figures
                           (a list of 32 or more floats, not all whole, as {"float64_base64": ...})
      states/identification.json
      states/learned.json  when learning ends: what each stage feeds forward at each learned point
                           (`LearnedPoint`; ilcpmac report draws it)
      compensation.json    what the drive applies (ilcpmac.compensation; written when learning ends, after
                           states/learned.json, again with its fade-out once validation ends; ilcpmac export
                           reads it)
      summary.json
      .lock, .lock.holder  the run's lock, and which process holds it

Creation writes states/run.json, backemf.csv, static.csv and bench.toml first and
campaign.toml last: a directory is a run (resumable) exactly when it holds
campaign.toml. One that holds only what an interrupted creation writes is
*debris*, which a new run may reuse.

Each trial is committed in this order: its trial file, its state file, then
bench.toml (the commit point: a trial is complete once bench.toml lists it),
then summary.json; every file is written to a temporary name, fsynced
(summary.json, derived from the states, is not) and renamed. summary.json is
written at most once a second (`SUMMARY_INTERVAL_S`): a trial's commit within
that time of the last write holds its summary back for the next commit, for
`write_summary` or for `close`, so the file is the last trial's once the run
stops (end, error or Ctrl-C). A background thread commits trials in order
while the campaign runs the next one; after a failed write (a full disk)
nothing more is committed. After a crash, files of trials bench.toml does not
list, and temporary files, are removed.

A run holds an exclusive lock on its directory from before creation (or
resume) to its end: a second run on it fails at once, saying which process
holds it. The operating system releases the lock when its process dies, kill
-9 included. JSON files never hold a non-finite number.

`RunFiles` is the one place that knows this layout: `RunDir` writes through
it, ``ilcpmac report`` reads through it (no lock needed). The states are typed
records (`ilcpmac.campaign.state`); one that cannot be read is a `RunDirError`
naming its file.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import json
import math
import os
import secrets
import socket
import tempfile
import time
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager, suppress
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
from filelock import FileLock, Timeout

from ilcpmac.bench.format import (
    BENCH_FILE,
    Bench,
    StaticTrial,
    bench_toml_text,
    read_trial,
    write_backemf_csv,
    write_static_csv,
    write_trial,
)
from ilcpmac.campaign.record import records_of
from ilcpmac.campaign.state import LearnedPoint, TrialState, learned_from_json, learned_json
from ilcpmac.compensation import COMPENSATION_FILE
from ilcpmac.core.errors import BenchFormatError, IdentificationError, IlcpmacError
from ilcpmac.core.files import atomic_write, read_bounded
from ilcpmac.core.records import BenchDescription, TrialData
from ilcpmac.core.schema import read_toml
from ilcpmac.export import RUN_CONFIG

CONFIG_FILE = RUN_CONFIG  # export finds a run's limits by it
STATES = "states"
RUN_FILE = "run.json"
BACKEMF_FILE = "backemf.csv"
#: the static trial's copy, where the campaign has one ([bench] static_trial_file)
STATIC_FILE = "static.csv"
SUMMARY_FILE = "summary.json"
IDENTIFICATION_FILE = "identification.json"
LEARNED_FILE = "learned.json"
PLOTS = "plots"
LOCK_FILE = ".lock"
HOLDER_FILE = ".lock.holder"
#: what creation writes before campaign.toml, at the top and in states/ (each also as NAME.tmp)
_CREATION_FILES = {LOCK_FILE, HOLDER_FILE, BACKEMF_FILE, STATIC_FILE, BENCH_FILE, CONFIG_FILE}
_CREATION_STATES = {RUN_FILE}
#: a state file stores a flat list of at least this many floats as its bytes ...
PACKED_MIN_LENGTH = 32
#: ... in an object whose one key is this: the base64 of the list's little-endian float64 values
PACKED_KEY = "float64_base64"
#: least time between two writes of summary.json while trials are committed, s
SUMMARY_INTERVAL_S = 1.0
#: the most bytes a run's JSON file is read to, beyond anything a run writes: summary.json grows by about 1.5 kB a
#: trial (64 MiB: some 40 000 trials); a state holds at most MAX_STATE_BYTES of JSON per stage, states/learned.json
#: a table per stage and learned point (at 2^20 counts, 9 points and 3 stages, 0.3 GB)
SUMMARY_MAX_BYTES = 64 << 20
JSON_MAX_BYTES = 1 << 30
#: a state file's and states/identification.json's key holding the SHA-256 of the rest of its JSON text
DIGEST_KEY = "sha256"
#: a state file's key holding the SHA-256 of its trial file
TRIAL_DIGEST_KEY = "trial_sha256"
#: states/identification.json's key holding the SHA-256 of every trial file committed when it was written
TRIALS_DIGEST_KEY = "trials_sha256"
#: states/run.json's key saying the run's states carry digests (a run made before them has none, unchecked)
SEALED_KEY = "sealed"
#: states/run.json's key holding the run's identity, a random 128-bit id that every state and
#: states/identification.json repeat (`RunSeal`)
RUN_ID_KEY = "run_id"
#: states/run.json's key holding the SHA-256 of campaign.toml as the run began
CONFIG_DIGEST_KEY = "config_sha256"
#: a state file's key holding its trial's index
INDEX_KEY = "index"


class RunDirError(IlcpmacError):
    """A run directory cannot be created, resumed, locked or written."""


@dataclass(frozen=True)
class RunSeal:
    """What states/run.json seals a run with (docs/campaign.md, "What the seal guarantees").

    Attributes
    ----------
    run_id : the run's random identity, repeated in every state and in states/identification.json.
    config_sha256 : the SHA-256 of campaign.toml as the run began.
    """

    run_id: str
    config_sha256: str


#: what a run writes its trials as, and what runs written before Parquet hold
TRIAL_SUFFIX = ".parquet"
_OLD_TRIAL_SUFFIX = ".csv"


def trial_file(index: int, suffix: str = TRIAL_SUFFIX) -> str:
    """The file name of trial ``index`` (1-based)."""
    return f"trial_{index:03d}{suffix}"


class RunFiles:
    """The paths of a run directory (the layout of the module docstring) and reading them back.

    Parameters
    ----------
    path : the run directory.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.config = self.path / CONFIG_FILE
        self.bench = self.path / BENCH_FILE
        self.backemf = self.path / BACKEMF_FILE
        self.static = self.path / STATIC_FILE
        self.summary = self.path / SUMMARY_FILE
        self.states = self.path / STATES
        self.settings = self.states / RUN_FILE
        self.identification = self.states / IDENTIFICATION_FILE
        self.learned = self.states / LEARNED_FILE
        self.compensation = self.path / COMPENSATION_FILE
        self.plots = self.path / PLOTS

    def trial(self, index: int) -> Path:
        """Trial ``index``'s file as a run writes it (Parquet)."""
        return self.path / trial_file(index)

    def existing_trial(self, index: int) -> Path:
        """Trial ``index``'s file: Parquet, or CSV in a run begun before Parquet."""
        path = self.trial(index)
        old = self.path / trial_file(index, _OLD_TRIAL_SUFFIX)
        return old if not path.exists() and old.exists() else path

    def state(self, index: int) -> Path:
        """states/trial_NNN.json, the state saved with trial ``index``."""
        return self.states / f"trial_{index:03d}.json"

    @cached_property
    def seal(self) -> RunSeal | None:
        """The run's seal in states/run.json, its digest checked; None when it has none (a run made by a release
        before seals, or one whose seal was removed: `resumable_seal` refuses both)."""
        data = self.read_json(self.settings)
        if not isinstance(data, dict) or DIGEST_KEY not in data:
            return None
        data = self._unsealed(self.settings, dict(data), checked=True)
        run_id, config = data.get(RUN_ID_KEY), data.get(CONFIG_DIGEST_KEY)
        if not (isinstance(run_id, str) and isinstance(config, str)):
            raise RunDirError(f"{self.settings}: sealed without its {RUN_ID_KEY} and {CONFIG_DIGEST_KEY}; the run "
                              "cannot go on from it")
        return RunSeal(run_id, config)

    @cached_property
    def sealed(self) -> bool:
        """Whether the run's files carry digests, which reading them checks: a `seal`, or (a run of an earlier
        release) states/run.json says so or its first trial's state has one."""
        if self.seal is not None or (self.read_json(self.settings) or {}).get(SEALED_KEY):
            return True
        first = self.read_json(self.state(1))
        return isinstance(first, dict) and DIGEST_KEY in first

    def resumable_seal(self) -> RunSeal:
        """The seal a resume goes on from: states/run.json sealed, campaign.toml the config it sealed.

        Raises `RunDirError` naming the file otherwise: a run without a seal (made by an earlier release, or its
        seal removed) is not resumed, as nothing then tells its files from another run's or an edited config;
        ``ilcpmac report`` and ``ilcpmac export`` still read it.
        """
        seal = self.seal
        if seal is None:
            what = "missing" if not self.settings.is_file() else "holds no seal"
            raise RunDirError(f"{self.settings}: {what} (a run made by an earlier release, or its seal removed); "
                              "only a sealed run resumes: start a new run (ilcpmac report and export still read "
                              "this one)")
        if _file_digest(self.config) != seal.config_sha256:
            raise RunDirError(f"{self.config}: not the config this run began with (its SHA-256 differs from "
                              f"{self.settings.name}'s {CONFIG_DIGEST_KEY}); a resumed run keeps the config and "
                              "limits it began with: put that config back, or start a new run")
        return seal

    def read_json(self, path: Path, packed: bool = False) -> dict[str, Any] | None:
        """The JSON object in ``path`` (one of these paths), None when it does not exist; `RunDirError`
        naming it when it cannot be read, is no JSON object, holds NaN or infinity, nests beyond the parser's depth
        or is larger than anything a run writes there (`JSON_MAX_BYTES`, `SUMMARY_MAX_BYTES`: refused before it is
        read). ``packed``: a state file's packed float lists are unpacked."""
        if not path.exists():
            return None
        raw = read_bounded(path, SUMMARY_MAX_BYTES if path == self.summary else JSON_MAX_BYTES, RunDirError)
        try:
            data = json.loads(raw, object_hook=_unpacked if packed else None, parse_constant=_not_finite)
        except (ValueError, RecursionError) as e:
            why = "nested too deeply" if isinstance(e, RecursionError) else str(e)
            raise RunDirError(f"{path}: unreadable ({why})") from None
        if not isinstance(data, dict):
            raise RunDirError(f"{path}: unreadable (a JSON {type(data).__name__}, not an object)")
        return data

    def read_sealed(self, path: Path) -> dict[str, Any] | None:
        """The JSON object in ``path`` without its `DIGEST_KEY`, None when it does not exist; `RunDirError` naming
        it when it is unreadable or, in a `sealed` run, its digest is missing or differs (edited since written;
        a run made before digests is not checked)."""
        data = self.read_json(path)
        if data is None:
            return None
        if not isinstance(data, dict):
            raise RunDirError(f"{path}: unreadable (not a JSON object)")
        return self._unsealed(path, data)

    def _unsealed(self, path: Path, data: dict[str, Any], checked: bool | None = None) -> dict[str, Any]:
        """``data``, the object read from ``path``, without its digest, which must match (`read_sealed`) when
        ``checked`` (default: in a `sealed` run)."""
        claimed = data.pop(DIGEST_KEY, None)
        if (self.sealed if checked is None else checked) and claimed != _digest(json.dumps(data, allow_nan=False)):
            raise RunDirError(f"{path}: does not match its {DIGEST_KEY} digest (changed since the run wrote it); "
                              "the run cannot go on from it")
        return data

    def read_checked_state(self, index: int) -> tuple[TrialState, str | None]:
        """The state saved with trial ``index`` (`read_sealed`) and the digest of its trial file it records (None
        in a run made before digests); `RunDirError` when it is missing or unreadable, or, in a run with a `seal`,
        is not this run's state of trial ``index`` (its run id and index)."""
        path = self.state(index)
        data = self.read_json(path)
        if data is None:
            raise RunDirError(f"{path}: missing (trial {index} is not complete)")
        try:
            state = TrialState.from_json(_unpacked_all(data))
        except (KeyError, TypeError, ValueError, AttributeError) as e:
            raise RunDirError(f"{path}: unreadable ({e!r})") from None
        data = self._unsealed(path, data)
        seal = self.seal
        if seal is not None and (data.get(RUN_ID_KEY), data.get(INDEX_KEY)) != (seal.run_id, index):
            raise RunDirError(f"{path}: not this run's state of trial {index} (it says run {data.get(RUN_ID_KEY)!r}, "
                              f"trial {data.get(INDEX_KEY)!r}; {self.settings.name}: run {seal.run_id!r}): a state of "
                              "another run or trial mixed in; the run cannot go on from it")
        return state, data.get(TRIAL_DIGEST_KEY)

    def read_state(self, index: int) -> TrialState:
        """The state saved with trial ``index`` (`read_checked_state`)."""
        return self.read_checked_state(index)[0]

    def read_learned(self) -> list[LearnedPoint] | None:
        """states/learned.json, None when it does not exist (learning has not ended, or the run was made
        before it was written); `RunDirError` when it is unreadable."""
        data = self.read_json(self.learned, packed=True)
        if data is None:
            return None
        try:
            return learned_from_json(data)
        except (KeyError, TypeError, ValueError, AttributeError) as e:
            raise RunDirError(f"{self.learned}: unreadable ({e!r})") from None

    def read_summary(self) -> dict[str, Any]:
        """summary.json; `RunDirError` when there is none or it is unreadable."""
        summary = self.read_json(self.summary)
        if summary is None:
            raise RunDirError(f"{self.path}: no {SUMMARY_FILE} (not a run directory of ilcpmac run)")
        if not isinstance(summary.get("trials"), list):
            raise RunDirError(f"{self.summary}: unreadable (no list of trials)")
        try:
            records_of(summary)
        except ValueError as e:
            raise RunDirError(f"{self.summary}: unreadable ({e})") from None
        return summary

    def read_trial(self, index: int, torque_setpoint_nm: float, speed_setpoint_hz: float,
                   torque_sensor: bool = True) -> TrialData:
        """Trial ``index`` read back from its file (with a torque column if the bench has a ``torque_sensor``)."""
        try:
            return read_trial(self.existing_trial(index), torque_setpoint_nm, speed_setpoint_hz,
                              torque_sensor=torque_sensor)
        except BenchFormatError as e:
            raise RunDirError(str(e)) from None


def _not_finite(name: str) -> float:
    """The ``parse_constant`` of `json.loads`: NaN and infinity are refused."""
    raise ValueError(f"{name} is not a finite number")


def _digest(text: str) -> str:
    """The SHA-256 of ``text`` (UTF-8), hexadecimal."""
    return hashlib.sha256(text.encode()).hexdigest()


def _file_digest(path: Path) -> str:
    """The SHA-256 of the file ``path``, hexadecimal; `RunDirError` naming it when it cannot be read."""
    try:
        with path.open("rb") as f:
            return hashlib.file_digest(f, "sha256").hexdigest()
    except OSError as e:
        raise RunDirError(f"{path}: unreadable ({e.strerror or e})") from None


def _sealed_text(data: dict[str, Any], target: Path) -> str:
    """``data`` as JSON for ``target`` (`_json_text`) with `DIGEST_KEY`: the digest of its text without it, which
    `RunFiles.read_sealed` checks."""
    return _json_text({**data, DIGEST_KEY: _digest(_json_text(data, target))}, target)


def _non_finite(data: Any, where: str = "") -> tuple[str, float] | None:
    """The first key path in ``data`` holding a non-finite float, and that float."""
    if isinstance(data, float):
        return None if math.isfinite(data) else (where, data)
    items = data.items() if isinstance(data, dict) else enumerate(data) if isinstance(data, list | tuple) else ()
    for key, value in items:
        found = _non_finite(value, f"{where}.{key}" if where else str(key))
        if found is not None:
            return found
    return None


def _json_text(data: Any, target: Path, indent: int | None = None) -> str:
    """``data`` as JSON for ``target``; a non-finite number is a `RunDirError` naming its key."""
    try:
        return json.dumps(data, allow_nan=False, indent=indent)
    except ValueError:
        found = _non_finite(data)
        if found is None:
            raise
        raise RunDirError(f"{target}: {found[0]} is {found[1]}, not a finite number; not written") from None


def _packed(data: Any, target: Path, where: str = "") -> Any:
    """``data`` with every flat list of `PACKED_MIN_LENGTH` or more floats, not all whole numbers, as
    {`PACKED_KEY`: the base64 of its float64 bytes}: the same numbers to the bit in 10.7 characters each (a
    measured value's decimal text takes about 19, a whole number's a few: those stay text), encoded in a
    quarter of the time; a non-finite one is a `RunDirError` naming its key, as `_json_text` names one elsewhere."""
    if isinstance(data, dict):
        return {key: _packed(value, target, f"{where}.{key}" if where else str(key)) for key, value in data.items()}
    if not isinstance(data, list | tuple):
        return data
    if len(data) >= PACKED_MIN_LENGTH and all(isinstance(v, float) for v in data):
        values = np.array(data, "<f8")
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise RunDirError(f"{target}: {where}.{bad[0]} is {values[bad[0]]}, not a finite number; not written")
        whole = np.array_equal(values, np.rint(values))
        return data if whole else {PACKED_KEY: base64.b64encode(values.tobytes()).decode("ascii")}
    return [_packed(value, target, f"{where}.{k}") for k, value in enumerate(data)]


def _unpacked(data: dict[str, Any]) -> Any:
    """A JSON object of a state file as `_packed` was given it (the object_hook of `json.loads`)."""
    if data.keys() != {PACKED_KEY}:
        return data
    text = data[PACKED_KEY]
    if not isinstance(text, str):
        raise ValueError(f"{PACKED_KEY} holds {type(text).__name__}, not text")
    try:
        values = np.frombuffer(base64.b64decode(text, validate=True), "<f8")
    except binascii.Error as e:
        raise ValueError(f"{PACKED_KEY}: {e}") from None
    if not np.isfinite(values).all():
        raise ValueError(f"{PACKED_KEY} holds a non-finite number")
    return values.tolist()


def _unpacked_all(data: Any) -> Any:
    """``data`` (as `json.loads` gave it) with every packed list given back (`_unpacked` at every depth)."""
    if isinstance(data, dict):
        return _unpacked({key: _unpacked_all(value) for key, value in data.items()})
    if isinstance(data, list):
        return [_unpacked_all(value) for value in data]
    return data


@contextmanager
def _writing(target: Path, then: str) -> Iterator[None]:
    """Turn a failed write of ``target`` (full disk, quota, read-only) into one line; remove its temporary file."""
    try:
        yield
    except OSError as e:
        with suppress(OSError):
            target.with_name(target.name + ".tmp").unlink(missing_ok=True)
        raise RunDirError(f"{target}: cannot write ({e.strerror or e}); {then}") from None


def _left_by_creation(names: set[str], allowed: set[str]) -> bool:
    return all(n in allowed or (n.endswith(".tmp") and n[:-4] in allowed) for n in names)


def _contents(path: Path) -> str:
    """What ``path`` holds: "nothing", "debris" (of an interrupted creation), "run" or "other"."""
    if not path.exists():
        return "nothing"
    if not path.is_dir():
        return "other"
    names = {p.name for p in path.iterdir()}
    if CONFIG_FILE in names:
        return "run"
    states = path / STATES
    if not _left_by_creation(names - {STATES}, _CREATION_FILES) or (
            STATES in names and not (states.is_dir() and _left_by_creation({p.name for p in states.iterdir()},
                                                                           _CREATION_STATES))):
        return "other"
    return "debris" if names else "nothing"


def _refuse_other(path: Path, kind: str) -> None:
    if kind == "other":
        raise RunDirError(f"{path}: exists and is not empty (and is not a run to --resume); use another --out")


class RunLock:
    """An exclusive lock on a run directory (``.lock``), with its holder's pid, host and start time
    beside it (``.lock.holder``). Use `RunDir.lock` to take one; `release` (or leaving a ``with``
    block) gives it back."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._lock = FileLock(path / LOCK_FILE, thread_local=False)

    def acquire(self) -> "RunLock":
        """Take the lock at once or fail saying who holds it; check the directory can be written."""
        then = "a run needs a writable directory"
        with _writing(self.path / LOCK_FILE, then):
            try:
                self._lock.acquire(timeout=0)
            except Timeout:
                raise RunDirError(f"{self.path}: in use by {self._holder()}; wait for that run to end, "
                                  "or stop it") from None
        try:
            holder = self.path / HOLDER_FILE
            with _writing(holder, then):
                atomic_write(holder, json.dumps({"pid": os.getpid(), "host": socket.gethostname(),
                                                 "started": time.strftime("%Y-%m-%d %H:%M:%S")}), durable=False)
            states = self.path / STATES
            if states.is_dir():
                with _writing(states, then), tempfile.TemporaryFile(dir=states):
                    pass
        except BaseException:
            self._lock.release()
            raise
        return self

    def _holder(self) -> str:
        """Who holds the lock, from .lock.holder; a dead process's record (kill -9) is not believed."""
        try:
            h = json.loads((self.path / HOLDER_FILE).read_text())
            pid, host, started = int(h["pid"]), str(h["host"]), str(h["started"])
        except (OSError, ValueError, KeyError, TypeError):
            return "another process (not yet recorded)"
        if host == socket.gethostname():
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                return "another process (not yet recorded)"
            except PermissionError:
                pass
        return f"pid {pid} on {host} since {started}"

    def release(self) -> None:
        """Give the lock back (a no-op when not held)."""
        if self._lock.is_locked:
            with suppress(OSError):
                (self.path / HOLDER_FILE).unlink(missing_ok=True)
            self._lock.release()

    def __enter__(self) -> "RunLock":
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


class RunDir:
    """A run directory (see the module docstring)."""

    def __init__(self, path: Path, description: BenchDescription, entries: list[tuple[str, float, float]],
                 lock: RunLock | None = None) -> None:
        """``lock``: one the run releases on `close`."""
        self.path = path
        self.files = RunFiles(path)
        self.description = description
        self._entries = entries
        self._states: dict[int, TrialState] = {}
        #: the digest of each complete trial's file (`TRIAL_DIGEST_KEY`), where the run records them
        self._trial_digests: dict[int, str] = {}
        self._writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rundir")
        self._pending: list[Future[None]] = []
        self._failed = False
        self._closed = False
        #: when summary.json was last written (time.monotonic, s), and the summary a commit held back since
        self._summary_written_s = -math.inf
        self._held_summary: dict[str, Any] | None = None
        #: whether bench.toml lists the static trial's copy ([static])
        self.has_static = False
        self._lock = lock
        self._resumable = f"the run stays resumable: make room or allow writing, then ilcpmac run --resume {path}"
        #: the run's seal: made by `create`, checked by `resume`
        self.seal = RunSeal("", "")

    @staticmethod
    def lock(path: str | Path, new: bool) -> RunLock:
        """Lock ``path`` for a new run (``new``: it must hold nothing, or debris) or to resume the run it holds.

        Nothing is written into a directory that is not fit; the lock is taken before any trial, so a
        second run on ``path`` fails at once, and so does a directory that cannot be written.
        """
        path = Path(path)
        kind = _contents(path)
        if new:
            _refuse_other(path, kind)
        elif kind != "run":
            why = f"; its creation was interrupted: start it again with --out {path}" if kind == "debris" else ""
            raise RunDirError(f"{path}: not a run directory (no {CONFIG_FILE}){why}")
        with _writing(path, "a run needs a writable directory"):
            path.mkdir(parents=True, exist_ok=True)
        return RunLock(path).acquire()

    @classmethod
    def create(cls, path: str | Path, description: BenchDescription, config_text: str,
               settings: dict[str, Any] | None = None, lock: RunLock | None = None,
               static: StaticTrial | None = None) -> "RunDir":
        """Start a new run in ``path``, which must hold nothing or the debris of an interrupted creation.

        ``settings`` (states/run.json) are what ``ilcpmac run --resume`` needs besides the config;
        ``lock`` is `lock` (path, new=True) when the caller took it, else the run takes and keeps it
        until `close`; ``static``: the campaign's static trial, copied as static.csv and listed in bench.toml
        ([static]), so that the run directory identifies as the campaign did.
        """
        path = Path(path)
        run = cls(path, description, [], None if lock else cls.lock(path, new=True))
        try:
            kind = _contents(path)
            if kind == "run":
                raise RunDirError(f"{path}: exists and is not empty: it holds a run; continue it with "
                                  f"--resume {path}, or use another --out")
            _refuse_other(path, kind)
            files = run.files
            for f in [*path.iterdir(), *(files.states.iterdir() if files.states.is_dir() else ())]:
                if f.name not in (LOCK_FILE, HOLDER_FILE, STATES):
                    f.unlink()
            then = f"nothing was created; {path} can be given to --out again"
            with _writing(files.states, then):
                files.states.mkdir(exist_ok=True)
            target = files.settings
            run.seal = RunSeal(secrets.token_hex(16), _digest(config_text))
            with _writing(target, then):
                atomic_write(target, _sealed_text({**(settings or {}), SEALED_KEY: True, RUN_ID_KEY: run.seal.run_id,
                                                   CONFIG_DIGEST_KEY: run.seal.config_sha256}, target))
            with _writing(files.backemf, then):
                write_backemf_csv(files.backemf, description.backemf_nm_per_a)
            if static is not None:
                with _writing(files.static, then):
                    write_static_csv(files.static, static)
                run.has_static = True
            with _writing(files.bench, then):
                run._write_bench_toml()
            with _writing(files.config, then):
                atomic_write(files.config, config_text)
        except BaseException:
            run.close()
            raise
        return run

    @classmethod
    def resume(cls, path: str | Path, description: BenchDescription, lock: RunLock | None = None) -> "RunDir":
        """Reopen ``path``: its complete trials are those bench.toml lists; the rest is removed.

        ``lock`` as in `create` (with new=False).
        """
        path = Path(path)
        run = cls(path, description, [], None if lock else cls.lock(path, new=False))
        try:
            run.seal = run.files.resumable_seal()
            data = read_toml(run.files.bench, RunDirError)
            run.has_static = "static" in data
            run._entries = [(t["file"], float(t["torque_setpoint"]), float(t["speed_setpoint"]))
                            for t in data.get("trials", [])]
            for i, (name, _, _) in enumerate(run._entries, start=1):
                if name != trial_file(i) or not (path / name).is_file() \
                        or not run.files.state(i).is_file():
                    raise RunDirError(f"{path}: trial {i} is listed in {BENCH_FILE} but {name} or its state "
                                      "is missing")
            run._check_trials()
            with _writing(path, run._resumable):
                run._remove_incomplete()
        except BaseException:
            run.close()
            raise
        return run

    def _check_trials(self) -> None:
        """Read every complete trial's state (its digest, run and index checked) and check its trial file is the one
        committed with it; `RunDirError` naming the file otherwise."""
        for i, (name, _, _) in enumerate(self._entries, start=1):
            self._states[i], recorded = self.files.read_checked_state(i)
            if recorded != _file_digest(self.path / name):
                raise RunDirError(f"{self.path / name}: not the file committed with {self.files.state(i)} (its "
                                  "digest differs: changed, swapped or truncated since); the run cannot resume")
            self._trial_digests[i] = recorded

    @staticmethod
    def read_settings(path: str | Path) -> dict[str, Any]:
        """The settings a run was created with (states/run.json without its seal), once its seal is checked
        (`RunFiles.resumable_seal`: `RunDirError` naming the file for a run without one, or whose campaign.toml is
        not the one it began with): a resumed run goes on with its own seed, overrides and config."""
        files = RunFiles(path)
        files.resumable_seal()
        settings = files.read_json(files.settings) or {}
        return {key: value for key, value in settings.items()
                if key not in (SEALED_KEY, DIGEST_KEY, RUN_ID_KEY, CONFIG_DIGEST_KEY)}

    def _remove_incomplete(self) -> None:
        """Delete what a crash left of a trial that was never committed, and temporary files."""
        indices = range(1, len(self._entries) + 1)
        keep = {name for name, _, _ in self._entries} | {self.files.state(i).name for i in indices}
        states = self.files.states
        for f in {*self.path.glob("trial_*"), *states.glob("trial_*"), *self.path.glob("*.tmp"), *states.glob("*.tmp")}:
            if f.name not in keep:
                f.unlink()

    def _write_bench_toml(self, entries: list[tuple[str, float, float]] | None = None) -> None:
        atomic_write(self.files.bench, bench_toml_text(self.description.motor, self.description.calibration,
                                                       self._entries if entries is None else entries,
                                                       static_file=STATIC_FILE if self.has_static else None))

    @property
    def completed(self) -> int:
        """Number of trials added (complete on disk once `flush` returns)."""
        return len(self._entries)

    def flush(self) -> None:
        """Wait until every added trial (and queued summary) is committed; re-raise a failed write."""
        pending, self._pending = self._pending, []
        for future in pending:
            future.result()

    def close(self) -> None:
        """Commit what is pending and the summary held back, stop the writer and release the lock the run
        took itself."""
        try:
            if not self._closed:
                self.flush()
                self._writer.submit(self._write_held_summary).result()
        finally:
            self._closed = True
            self._writer.shutdown(wait=True)
            if self._lock is not None:
                self._lock.release()

    def config_text(self) -> str:
        """The campaign config the run started with."""
        return self.files.config.read_text()

    def trial_names(self, count: int) -> tuple[str, ...]:
        """The file names of trials 1..``count``, as bench.toml lists them."""
        return tuple(name for name, _, _ in self._entries[:count])

    def add_trial(self, trial: TrialData, state: TrialState, summary: dict[str, Any]) -> int:
        """Queue the next trial, its state and the summary for commit, in order; return its index."""
        for future in [f for f in self._pending if f.done()]:
            future.result()  # re-raise a failed write early
        self._pending = [f for f in self._pending if not f.done()]
        index = len(self._entries) + 1
        self._entries.append((trial_file(index), trial.torque_setpoint_nm, trial.speed_setpoint_hz))
        self._states[index] = state
        self._pending.append(self._writer.submit(self._commit, index, trial, state, summary, list(self._entries)))
        return index

    def _commit(self, index: int, trial: TrialData, state: TrialState, summary: dict[str, Any],
                entries: list[tuple[str, float, float]]) -> None:
        if self._failed:  # a later trial must not be listed in bench.toml before the one that failed
            return
        try:
            data, state_file = self.files.trial(index), self.files.state(index)
            # kept: what the campaign learns from and the true torque, for honest ripple figures; not kept:
            # the measured currents, true currents and speed, which nothing reads back (the measured
            # currents' sensor noise alone would more than double the run directory)
            with _writing(data, self._resumable):
                write_trial(data, replace(trial, i_meas_a=None, i_true_a=None, speed_true_rad_s=None))
            self._trial_digests[index] = _file_digest(data)
            with _writing(state_file, self._resumable):
                atomic_write(state_file, _sealed_text({**_packed(state.to_json(), state_file),
                                                       TRIAL_DIGEST_KEY: self._trial_digests[index],
                                                       RUN_ID_KEY: self.seal.run_id, INDEX_KEY: index}, state_file))
            with _writing(self.files.bench, self._resumable):
                self._write_bench_toml(entries)
            if time.monotonic() - self._summary_written_s < SUMMARY_INTERVAL_S:
                self._held_summary = summary
            else:
                self._write_summary(summary)
        except BaseException:
            self._failed = True
            raise

    def state(self, index: int) -> TrialState:
        """The state saved with trial ``index``."""
        if index not in self._states:
            self._states[index] = self.files.read_state(index)
        return self._states[index]

    def write_identification(self, data: dict[str, Any]) -> None:
        """Write states/identification.json atomically, with the digests of the trial files committed so far
        (`flush` first), the run's id and its own digest."""
        self.flush()
        target = self.files.identification
        text = _sealed_text({**data, RUN_ID_KEY: self.seal.run_id, TRIALS_DIGEST_KEY: [
            self._trial_digests[i] for i in range(1, self.completed + 1)]}, target)
        with _writing(target, self._resumable):
            atomic_write(target, text)

    def read_identification(self) -> dict[str, Any] | None:
        """states/identification.json without its digests and run id, or None when it does not exist; `RunDirError`
        naming it when its digest, its run or the trial files it was identified from (their digests) differ."""
        target = self.files.identification
        data = self.files.read_sealed(target)
        if data is None:
            return None
        recorded, run_id = data.pop(TRIALS_DIGEST_KEY, None), data.pop(RUN_ID_KEY, None)
        if run_id != self.seal.run_id:
            raise RunDirError(f"{target}: not this run's (it says run {run_id!r}, {self.files.settings.name}: run "
                              f"{self.seal.run_id!r}); the run cannot resume from it")
        if not isinstance(recorded, list) or recorded != [self._trial_digests.get(i)
                                                          for i in range(1, len(recorded) + 1)]:
            raise RunDirError(f"{target}: not identified from the trial files on disk (their digests differ); the "
                              "run cannot resume")
        return data

    def write_learned(self, points: list[LearnedPoint]) -> None:
        """Write states/learned.json atomically (its long float lists packed, as in a trial's state)."""
        target = self.files.learned
        with _writing(target, self._resumable):
            atomic_write(target, _json_text(_packed(learned_json(points), target), target))

    def write_compensation(self, data: dict[str, Any]) -> None:
        """Write compensation.json atomically."""
        target = self.files.compensation
        with _writing(target, self._resumable):
            atomic_write(target, _json_text(data, target, indent=1))

    def write_summary(self, summary: dict[str, Any]) -> None:
        """Queue summary.json for writing after the trials added before it, in place of any summary a commit
        held back (atomically; not fsynced: it is rebuilt from the states on resume). Complete once `flush`
        returns, which re-raises a failed write."""
        self._pending.append(self._writer.submit(self._write_summary, summary))

    def _write_summary(self, summary: dict[str, Any]) -> None:
        """Write ``summary`` (in the writer's thread)."""
        target = self.files.summary
        self._held_summary = None
        with _writing(target, self._resumable):
            atomic_write(target, _json_text(summary, target, indent=1), durable=False)
        self._summary_written_s = time.monotonic()

    def _write_held_summary(self) -> None:
        if self._held_summary is not None:
            self._write_summary(self._held_summary)

    def read_trials(self, indices: list[int]) -> list[TrialData]:
        """Read complete trials back from their files (waiting for their commit)."""
        if indices:
            self.flush()
        torque_sensor = self.description.motor.torque_sensor
        return [self.files.read_trial(i, *self._entries[i - 1][1:], torque_sensor) for i in indices]


def campaign_grid(bench_dir: Path, bench: Bench) -> tuple[Bench, str | None]:
    """The trials of ``bench`` (read from ``bench_dir``) the identification can use, and a line saying which when
    that is not all.

    A run directory of ``ilcpmac run`` (its campaign.toml and summary.json) holds the identification grid, then
    trials run with a feed-forward and a corrected calibration, which the identification's model of one
    calibration without compensation does not describe: its grid trials, which the campaign identified, are
    the ones. Any other folder: all its trials.
    """
    files = RunFiles(bench_dir)
    if not (files.config.is_file() and files.summary.is_file()):
        return bench, None
    grid = {files.existing_trial(r.index).name for r in records_of(files.read_summary()) if r.role == "grid"}
    kept = [k for k, name in enumerate(bench.trial_files) if name in grid]
    if not kept:
        raise IdentificationError(f"{bench_dir}: a run directory of ilcpmac run without a grid trial in "
                                  f"{files.summary.name}: nothing the identification can use")
    return replace(bench, trials=tuple(bench.trials[k] for k in kept),
                   trial_files=tuple(bench.trial_files[k] for k in kept)), (
        f"a run directory: its {len(kept)} grid trials identified, as the campaign did (its other "
        f"{len(bench.trials) - len(kept)} ran with a compensation, which the identification does not model)")
