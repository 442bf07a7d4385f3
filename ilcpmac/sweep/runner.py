"""The sweep on Dask: write every task's config, run the tasks on the cluster's workers, stream the results.

A local cluster by default (one single-threaded worker process per core), or any scheduler at
``tcp://HOST:PORT``: the same code. Each worker warms the numba kernels once before its first task
(`NumbaWarmup`), under a file lock on the numba cache, so that processes never write the cache at once.
Results are written as tasks finish (`ilcpmac.sweep.results`); a failing task is a result too.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path
from typing import Protocol

from distributed import Client, LocalCluster, WorkerPlugin, as_completed
from filelock import FileLock

from ilcpmac.errors import IlcpmacError
from ilcpmac.sweep.results import finished_tasks, write_result
from ilcpmac.sweep.spec import SweepSpec, toml_text
from ilcpmac.sweep.task import SweepTask, TaskResult, run_task

__all__ = ["SPEC_COPY", "NumbaWarmup", "SweepEvents", "SweepRunner", "SweepRunError", "local_client",
           "numba_lock", "warm_kernels"]

#: the spec and base config a sweep folder was made with (a resume must give the same)
SPEC_COPY, CONFIG_COPY = "sweep.toml", "config.toml"
#: DIR/tasks: each task's config
TASKS_DIR = "tasks"
#: the config of the warm-up task: the seed bench, small (seconds, and every kernel a task uses compiled)
WARMUP_CHANGES = {
    "bench": {"counts_per_rev": 512},
    "excitation": {"harmonics": 60},
    "trials": {"torque_setpoints_nm": [2.0, 4.0], "speed_setpoints_hz": [0.6, 0.9], "revolutions": 2},
    "campaign": {"learn_torques_nm": [2.0, 4.0], "learn_speeds_hz": [0.9], "learn_revolutions": [2],
                 "learn_trials": 2, "ripple_harmonics": 60, "validate_torques_nm": [3.0],
                 "validate_speeds_hz": [0.9], "validate_revolutions": 2},
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
    from ilcpmac.config import packaged_config, read_toml

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
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
        warm_kernels(self.kind)


def local_client(workers: int | None = None) -> Client:
    """A client of a local cluster of ``workers`` single-threaded worker processes (default: one per core)."""
    cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                           dashboard_address=None)
    return Client(cluster)


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

    def prepare(self, resume: bool) -> list[SweepTask]:
        """Check the folder, write every task's config (checked: `SweepSpec.check_task`) and return the tasks.

        A new sweep needs a folder without results; ``resume`` needs one made by the same spec and config.
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
        elif finished_tasks(out):
            raise SweepRunError(f"{out}: holds a sweep's results: give --resume, or another --out")
        (out / TASKS_DIR).mkdir(parents=True, exist_ok=True)
        for name, text in copies.items():
            (out / name).write_text(text)
        tasks = []
        for index in range(spec.task_count):
            draw = spec.draw(index)
            path = out / TASKS_DIR / f"task_{index:04d}.toml"
            text = spec.task_config(draw)
            path.write_text(text)
            spec.check_task(draw, path)
            tasks.append(SweepTask(index, draw.seed, spec.kind, text, str(path), draw.parameters))
        return tasks

    def pending(self, tasks: list[SweepTask]) -> list[SweepTask]:
        """The tasks the folder has no result of."""
        done = finished_tasks(self.out_dir)
        return [t for t in tasks if t.index not in done]

    def run(self, client: Client, tasks: list[SweepTask], events: SweepEvents) -> list[TaskResult]:
        """Run the tasks the folder has no result of (`pending`) on ``client``'s workers, each warmed first
        (then ``events.started``); write each result as it arrives; return them in the order they finished."""
        todo = self.pending(tasks)
        if todo:
            client.register_plugin(NumbaWarmup(self.spec.kind))
        events.started(len(tasks), len(tasks) - len(todo))
        futures = [client.submit(run_task, t, pure=False) for t in todo]
        results = []
        for future in as_completed(futures):
            result = future.result()
            write_result(self.out_dir, result)
            results.append(result)
            events.finished(result)
        return results
