"""The sweep on Dask: check every task's draws, run the tasks on the cluster's workers, stream the results.

A local cluster by default (one single-threaded worker process per core), or any scheduler at
``tcp://HOST:PORT``: the same code. Each worker warms the numba kernels once before its first task
(`NumbaWarmup`), under a file lock on the numba cache, so that processes never write the cache at once.
Tasks are submitted a few per worker at a time; each task's config is written and loaded as it is submitted
(tens of milliseconds: 100000 tasks would take the better part of an hour before the first ran).
Results are written as tasks finish (`ilcpmac.sweep.results`); a failing task is a result too.
"""

from __future__ import annotations

import asyncio
import hashlib
import os
import shlex
import signal
import tempfile
from pathlib import Path
from typing import Protocol

from distributed import Client, LocalCluster, WorkerPlugin, as_completed
from distributed.comm import CommClosedError, connect, get_address_host_port
from filelock import FileLock

from ilcpmac.config import packaged_config
from ilcpmac.core.errors import IlcpmacError
from ilcpmac.core.runtime import tune_process
from ilcpmac.core.schema import read_toml, toml_text
from ilcpmac.sweep.results import finished_tasks, read_results, write_result
from ilcpmac.sweep.spec import SweepSpec, SweepSpecError, TaskDraw
from ilcpmac.sweep.task import SweepTask, TaskResult, run_task

__all__ = ["CONNECT_TIMEOUT_S", "MAX_WORKERS_PER_CORE", "SPEC_COPY", "NumbaWarmup", "SweepEvents", "SweepRunError",
           "SweepRunner", "check_local_workers", "local_client", "numba_lock", "remote_client", "warm_kernels"]

#: the spec and base config a sweep folder was made with (a resume must give the same)
SPEC_COPY, CONFIG_COPY = "sweep.toml", "config.toml"
#: DIR/tasks: each task's config
TASKS_DIR = "tasks"
#: most worker processes of a local cluster per core (more only share the cores, each with its memory)
MAX_WORKERS_PER_CORE = 4
#: how long a client waits for a scheduler to answer, s (--connect-timeout)
CONNECT_TIMEOUT_S = 10.0
#: tasks submitted per worker thread ahead of the results: enough to keep every worker busy
TASKS_IN_FLIGHT_PER_THREAD = 2
#: the config of the warm-up task: the seed bench, small (seconds, and every kernel a task uses compiled)
WARMUP_CHANGES: dict[str, dict[str, object]] = {
    "bench": {"counts_per_rev": 512},
    "excitation": {"harmonics": 60},
    "trials": {"torque_setpoints_nm": [2.0, 4.0], "speed_setpoints_hz": [0.6, 0.9], "revolutions": 3},
    "campaign": {"learn_torques_nm": [2.0, 4.0], "learn_speeds_hz": [0.9], "learn_revolutions": [3],
                 "learn_trials": 2, "ripple_harmonics": 60, "validate_torques_nm": [3.0],
                 "validate_speeds_hz": [0.9], "validate_revolutions": 3},
    "stages": {"ilc": {"q_cutoff_harmonic": 60}},
}


class SweepRunError(IlcpmacError):
    """A sweep folder cannot be used as asked (another sweep's, or not one to resume)."""


def numba_lock() -> FileLock:
    """The lock over the numba cache of this machine's ilcpmac (NUMBA_CACHE_DIR, else the package's own
    __pycache__ folders), in the temporary folder: one process at a time compiles and writes it."""
    cache = os.environ.get("NUMBA_CACHE_DIR") or str(Path(__file__).resolve().parents[1])
    digest = hashlib.sha1(cache.encode()).hexdigest()[:12]
    return FileLock(Path(tempfile.gettempdir()) / f"ilcpmac-numba-{digest}.lock")


def warm_kernels(kind: str) -> None:
    """Run a small task of ``kind`` under `numba_lock`, so that every kernel it uses is compiled (or loaded
    from the cache) before the real tasks run."""
    data = read_toml(packaged_config("seed-bench.toml"))
    for table, values in WARMUP_CHANGES.items():
        data.setdefault(table, {})
        for key, value in values.items():
            if isinstance(value, dict):
                data[table].setdefault(key, {}).update(value)
            else:
                data[table][key] = value
    task = SweepTask(-1, 0, kind, toml_text(data), "warmup.toml", ())
    with numba_lock():
        result = run_task(task)
    if result.failure is not None:
        raise SweepRunError(f"the warm-up task failed: {result.failure}")


class NumbaWarmup(WorkerPlugin):
    """Warms the numba kernels of a sweep's tasks on each worker, before its first task (`warm_kernels`)."""

    name = "ilcpmac-numba-warmup"

    def __init__(self, kind: str) -> None:
        self.kind = kind

    def setup(self, worker) -> None:
        tune_process()
        warm_kernels(self.kind)


def check_local_workers(workers: int) -> None:
    """A local cluster's worker count: 1 to `MAX_WORKERS_PER_CORE` per core, else `SweepRunError`."""
    most = MAX_WORKERS_PER_CORE * (os.cpu_count() or 1)
    if not 1 <= workers <= most:
        raise SweepRunError(f"--workers {workers}: a local cluster takes 1 to {most} worker processes "
                            f"({MAX_WORKERS_PER_CORE} per core)")


def local_client(workers: int | None = None) -> Client:
    """A client of a local cluster of ``workers`` single-threaded worker processes (default: one per core;
    `check_local_workers`).

    The worker processes start with SIGINT ignored (they inherit it): Ctrl-C reaches the whole process group,
    and the sweep, not each worker with its traceback, handles it by closing the cluster. Called from the main
    thread (the only one that may set a signal's handler).
    """
    workers = workers or os.cpu_count() or 1
    check_local_workers(workers)
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
    finally:
        signal.signal(signal.SIGINT, previous)
    return Client(cluster)


async def _identity(address: str, timeout_s: float) -> object:
    """The answer of the server at ``address`` to Dask's handshake and "identity" request (a scheduler's: a dict
    with "type": "Scheduler")."""
    comm = await connect(address, timeout=timeout_s)
    try:
        await comm.write({"op": "identity", "reply": True})
        return await comm.read()
    finally:
        comm.abort()


def _no_answer(address: str, timeout_s: float, e: BaseException) -> SweepRunError:
    """What stopped the server at ``address`` answering: it closed the connection, or said nothing in time."""
    reason = " ".join(str(e).split()) or type(e).__name__
    if isinstance(e, CommClosedError):
        return SweepRunError(f"--scheduler {address}: the server closed the connection before answering "
                             f"Dask's identity request ({reason})")
    return SweepRunError(f"--scheduler {address}: no scheduler answered within {timeout_s:g} s ({reason})")


def remote_client(address: str, timeout_s: float = CONNECT_TIMEOUT_S) -> Client:
    """A client of the Dask scheduler at ``address`` (tcp://HOST:PORT), or `SweepRunError` naming the address:
    one it cannot parse, no answer within ``timeout_s``, or a server that is no Dask scheduler.

    Before the client connects, one request, all of it within ``timeout_s``, asks the server what it is
    (`_identity`): Dask's own handshake waits for an answer without a limit, and reads any server's first 8
    bytes as the length of a message to allocate (an HTTP server's "HTTP/1.1" asks for 3 EiB). Any failure
    of that request past the connection (a garbled answer, an echo of the request) is one line.
    """
    try:
        get_address_host_port(address)
    except (ValueError, NotImplementedError) as e:
        raise SweepRunError(f"--scheduler {address}: not a scheduler's address, tcp://HOST:PORT ({e})") from None
    try:
        answer = asyncio.run(asyncio.wait_for(_identity(address, timeout_s), timeout_s))
    except (OSError, TimeoutError) as e:
        raise _no_answer(address, timeout_s, e) from None
    except Exception:  # whatever a garbled answer makes of Dask's protocol: it is not a scheduler's
        raise SweepRunError(f"--scheduler {address}: not a Dask scheduler (its answer is not Dask's protocol)") \
            from None
    if not (isinstance(answer, dict) and answer.get("type") == "Scheduler"):
        kind = answer.get("type") if isinstance(answer, dict) and isinstance(answer.get("type"), str) else None
        raise SweepRunError(f"--scheduler {address}: not a Dask scheduler (it answered Dask's identity request "
                            f"{f'as a {kind}' if kind else 'with no scheduler identity'})")
    try:
        return Client(address, timeout=timeout_s)
    except (OSError, TimeoutError) as e:
        raise _no_answer(address, timeout_s, e) from None


class SweepEvents(Protocol):
    """What a sweep tells its user interface."""

    def started(self, total: int, done: int) -> None:
        """The sweep runs ``total`` tasks, ``done`` of them finished before (a resume)."""

    def finished(self, result: TaskResult) -> None:
        """A task finished (or failed)."""


class SweepRunner:
    """Runs (or resumes) a sweep into a folder.

    Parameters
    ----------
    spec : the sweep.
    out_dir : its folder: sweep.toml and config.toml (copies), tasks/, results/.
    """

    def __init__(self, spec: SweepSpec, out_dir: Path) -> None:
        self.spec = spec
        self.out_dir = Path(out_dir)

    def prepare(self, resume: bool) -> list[TaskDraw]:
        """Check the folder, every task's draws (`SweepSpec.check_draws`) and the first task's whole config
        (`task`: a problem no draw's value causes shows there); return the tasks' draws.

        A new sweep needs a folder without results; ``resume`` needs one made by the same spec and config, its
        results readable (`read_results`).
        """
        spec, out = self.spec, self.out_dir
        copies = {SPEC_COPY: spec.path.read_text(), CONFIG_COPY: spec.config.path.read_text()}
        if resume:
            for name, text in copies.items():
                if not (out / name).is_file():
                    raise SweepRunError(f"{out}: no {name}: not a sweep folder to resume")
                if (out / name).read_text() != text:
                    raise SweepRunError(f"{out}: its {name} differs from the one given: resume with the same "
                                        "spec and config")
            read_results(out)
        elif finished_tasks(out):
            raise SweepRunError(f"{out}: holds a sweep's results: give --resume, or another --out")
        draws = [spec.draw(index) for index in range(spec.task_count)]
        for draw in draws:
            spec.check_draws(draw)
        (out / TASKS_DIR).mkdir(parents=True, exist_ok=True)
        for name, text in copies.items():
            (out / name).write_text(text)
        self.task(draws[0])
        return draws

    def config_path(self, index: int) -> Path:
        """DIR/tasks/task_NNNN.toml: task ``index``'s config."""
        return self.out_dir / TASKS_DIR / f"task_{index:04d}.toml"

    def task(self, draw: TaskDraw) -> SweepTask:
        """The task of ``draw``, its config written to `config_path` and loaded (`SweepSpec.check_task`: a config
        the draws make invalid raises `SweepSpecError`)."""
        path = self.config_path(draw.index)
        text = self.spec.task_config(draw)
        path.write_text(text)
        self.spec.check_task(draw, path)
        return SweepTask(draw.index, draw.seed, self.spec.kind, text, str(path), draw.parameters)

    def rerun_command(self, index: int) -> str:
        """The command that reruns task ``index`` alone (`SweepTask.rerun_command`)."""
        return SweepTask(index, self.spec.draw(index).seed, self.spec.kind, "", str(self.config_path(index)),
                         ()).rerun_command()

    def resume_command(self) -> str:
        """The command that continues this sweep in its folder (after a crash or Ctrl-C)."""
        config, spec, out = (shlex.quote(str(p)) for p in (self.spec.config.path, self.spec.path, self.out_dir))
        return f"ilcpmac sweep {config} --spec {spec} --out {out} --resume"

    def pending(self, draws: list[TaskDraw]) -> list[TaskDraw]:
        """The tasks the folder has no result of."""
        done = finished_tasks(self.out_dir)
        return [d for d in draws if d.index not in done]

    def run(self, client: Client, draws: list[TaskDraw], events: SweepEvents) -> list[TaskResult]:
        """Run the tasks the folder has no result of (`pending`) on ``client``'s workers, each warmed first
        (then ``events.started``); keep `TASKS_IN_FLIGHT_PER_THREAD` tasks per worker thread submitted, each
        `task` made as it is submitted (one whose config is invalid is a failed result at once); write each
        result as it arrives; return them in the order they finished."""
        todo = self.pending(draws)
        if todo:
            client.register_plugin(NumbaWarmup(self.spec.kind))
        events.started(len(draws), len(draws) - len(todo))
        queue, running, results = iter(todo), as_completed(), []

        def finish(result: TaskResult) -> None:
            write_result(self.out_dir, result)
            results.append(result)
            events.finished(result)

        def submit_next() -> bool:
            for draw in queue:
                try:
                    task = self.task(draw)
                except SweepSpecError as e:
                    finish(TaskResult(SweepTask(draw.index, draw.seed, self.spec.kind, "",
                                                str(self.config_path(draw.index)), draw.parameters), 0.0, str(e)))
                    continue
                running.add(client.submit(run_task, task, pure=False))
                return True
            return False

        def fill() -> None:
            wanted = TASKS_IN_FLIGHT_PER_THREAD * max(sum(client.nthreads().values()), 1)
            while running.count() < wanted and submit_next():
                pass

        fill()
        for future in running:
            finish(future.result())
            fill()
        return results
