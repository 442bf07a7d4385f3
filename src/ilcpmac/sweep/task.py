"""One task of a sweep: what it runs (an identification, or a whole campaign) and what it returns.

`run_task` runs anywhere a Dask worker does: the task carries its config as text and needs no file of the
sweep's folder. It never raises for a failing campaign: the `TaskResult` holds the one-line reason.
"""

from __future__ import annotations

import shlex
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ilcpmac.campaign.events import CampaignMessage, GuardEvent, NoEvents
from ilcpmac.core.errors import IlcpmacError
from ilcpmac.core.records import IdentificationResult

__all__ = ["CampaignFigures", "IdentificationErrors", "SweepTask", "TaskResult", "run_task"]


@dataclass(frozen=True)
class SweepTask:
    """One task.

    Attributes
    ----------
    index : its number, 0-based.
    seed : its campaign seed ([trials] seed and ``ilcpmac run --seed``).
    kind : "identify" or "campaign".
    config_text : its config (the base config with its draws put in), TOML.
    config_path : where the sweep wrote it (DIR/tasks/task_NNNN.toml), for the rerun command.
    parameters : (column, value) of each number drawn.
    """

    index: int
    seed: int
    kind: str
    config_text: str
    config_path: str
    parameters: tuple[tuple[str, float], ...]

    def rerun_command(self) -> str:
        """The command that reruns this task alone."""
        config = shlex.quote(self.config_path)
        if self.kind == "campaign":
            return f"ilcpmac run {config} --seed {self.seed}"
        bench = shlex.quote(str(Path(self.config_path).with_suffix("")) + "-bench")
        return f"ilcpmac simulate {config} --out {bench} --seed {self.seed} && ilcpmac identify {bench} " \
               f"--output {bench}/result.json"


@dataclass(frozen=True)
class IdentificationErrors:
    """The identification against the simulator's truth (truth.json's keys).

    Attributes
    ----------
    delta_epsilon, delta, epsilon, inertia : relative errors (estimate / truth - 1).
    alpha : largest |error| over the phases.
    beta_a : largest |error| over the phases, A.
    cogging : RMS of the cogging torque's error over the truth's RMS.
    """

    delta_epsilon: float
    delta: float
    epsilon: float
    inertia: float
    alpha: float
    beta_a: float
    cogging: float

    @classmethod
    def of(cls, result, truth) -> IdentificationErrors:
        """The errors of `IdentificationResult` ``result`` against ``truth`` (one of the true values)."""
        def rel(name: str) -> float:
            estimate = getattr(result, name)
            return float("nan") if estimate is None else float(estimate / getattr(truth, name) - 1)

        def worst(name: str) -> float:
            estimate = getattr(result, name)
            return float("nan") if estimate is None else float(np.max(np.abs(estimate - getattr(truth, name))))

        cogging = float("nan") if result.cogging_nm is None else float(
            np.sqrt(np.mean((result.cogging_nm - truth.cogging_nm) ** 2) / np.mean(truth.cogging_nm ** 2)))
        return cls(rel("delta_epsilon"), rel("delta"), rel("epsilon"), rel("inertia_estimate"), worst("alpha"),
                   worst("beta"), cogging)


@dataclass(frozen=True)
class CampaignFigures:
    """What a whole campaign ended with (summary.json).

    Attributes
    ----------
    ripple_pp_true : per learned and validated point, (label "T Nm@S Hz", its final true peak-to-peak ripple,
        fraction of mean torque), learned points first.
    learned_pp_true, validation_pp_true : the worst of the learned, and of the validated, points (NaN if none).
    trials : trials run, the grid's included.
    guard_events : times the guard reverted a point's correction.
    worse_points : points where the compensation is worse than none (measured).
    """

    ripple_pp_true: tuple[tuple[str, float], ...]
    learned_pp_true: float
    validation_pp_true: float
    trials: int
    guard_events: int
    worse_points: int


@dataclass(frozen=True)
class TaskResult:
    """What one task returned.

    Attributes
    ----------
    task : the task (its index, seed, kind and draws).
    seconds : its wall time on the worker, s.
    failure : the one-line reason it failed, or None.
    identification : its identification's errors (None if it failed before).
    campaign : a campaign's final figures (None for an identification task, or a failed campaign).
    """

    task: SweepTask
    seconds: float
    failure: str | None = None
    identification: IdentificationErrors | None = None
    campaign: CampaignFigures | None = None

    def row(self) -> dict:
        """The task's row of the results table (docs/sweep.md): its draws, status and figures."""
        t = self.task
        row = {"task": t.index, "seed": t.seed, "kind": t.kind, "status": "failed" if self.failure else "ok",
               "reason": self.failure or "", "seconds": self.seconds, "config": t.config_path}
        row.update({f"draw:{name}": value for name, value in t.parameters})
        if self.identification is not None:
            row.update({f"id_error:{name}": value for name, value in vars(self.identification).items()})
        if self.campaign is not None:
            c = self.campaign
            row.update({"final_pp_true": c.learned_pp_true, "validation_pp_true": c.validation_pp_true,
                        "trials": c.trials, "guard_events": c.guard_events, "worse_points": c.worse_points})
            row.update({f"pp_true:{label}": value for label, value in c.ripple_pp_true})
        return row


def run_task(task: SweepTask) -> TaskResult:
    """Run ``task`` on this process's simulator, one thread; any error becomes the result's ``failure``."""
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix=f"ilcpmac-task-{task.index:04d}-") as scratch:
        try:
            config_path = Path(scratch) / Path(task.config_path).name
            config_path.write_text(task.config_text)
            if task.kind == "campaign":
                errors, figures = _campaign(config_path, task.seed, Path(scratch) / "run")
            else:
                errors, figures = _identification(config_path, task.seed), None
        except Exception as e:  # a task's failure is its result, whatever it is
            return TaskResult(task, time.perf_counter() - started, _one_line(e))
    return TaskResult(task, time.perf_counter() - started, None, errors, figures)


def _one_line(error: Exception) -> str:
    text = " ".join(str(error).split())
    return text if isinstance(error, IlcpmacError) else f"{type(error).__name__}: {text}"


def _identification(config_path: Path, seed: int) -> IdentificationErrors:
    """``ilcpmac simulate`` then ``ilcpmac identify``, in memory: the grid's trials as written, identified."""
    # imported in the worker that runs the task: the client that submits it loads no numba or scipy
    from ilcpmac.bench.format import as_written
    from ilcpmac.campaign.service import simulated_bench
    from ilcpmac.config import load_config
    from ilcpmac.identify import identify_bench

    bench, truth = simulated_bench(load_config(config_path), seed, workers=1)
    bench = replace(bench, trials=tuple(as_written(t) for t in bench.trials))
    return IdentificationErrors.of(identify_bench(bench), IdentificationResult.from_json(truth))


class _GuardCount(NoEvents):
    """Campaign events that count the guard's interventions (`GuardEvent`) and show nothing."""

    def __init__(self) -> None:
        self.guard_events = 0

    def message(self, message: CampaignMessage) -> None:
        self.guard_events += isinstance(message, GuardEvent)


def _campaign(config_path: Path, seed: int, run_path: Path) -> tuple[IdentificationErrors, CampaignFigures]:
    """``ilcpmac run CONFIG --seed SEED`` on the simulator, one trial at a time, into ``run_path``."""
    # imported in the worker that runs the task, as in `_identification`
    from ilcpmac.backends.registry import BackendSetup
    from ilcpmac.backends.simulated import SimulatorBackend
    from ilcpmac.campaign.service import load_campaign_config, run
    from ilcpmac.sim.bench import true_result

    config = load_campaign_config(config_path)
    backend = SimulatorBackend.from_setup(BackendSetup(config))
    backend.max_parallel_trials = 1  # a worker process per core: no threads of its own
    events = _GuardCount()
    try:
        result = run(config, out=run_path, backend=backend, seed=seed, events=events)
    finally:
        backend.close()
    results = result.points
    true_pp = [r.after.true.pp if r.after.true is not None else float("nan") for r in results]  # the simulator's
    ripple = tuple((f"{r.point[0]:g}Nm@{r.point[1]:g}Hz", pp) for r, pp in zip(results, true_pp))

    def worst(learned: bool) -> float:
        return max((pp for r, pp in zip(results, true_pp) if r.learned == learned), default=float("nan"))

    figures = CampaignFigures(ripple, worst(True), worst(False), len(result.records), events.guard_events,
                              sum(r.worse for r in results))
    truth = true_result(backend.simulator, result.plan.description.calibration)
    return IdentificationErrors.of(result.identification, truth), figures
