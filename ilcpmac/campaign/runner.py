"""The campaign of ``ilcpmac run``: identify, compensate, learn; every trial persisted as it finishes.

Phases (report ch. 1-4, then beyond):

1. ``identify``: the multisine set-point grid of [trials] x [excitation],
   identified as ``ilcpmac identify`` does; then one uncompensated trial
   (no excitation) per ILC set point, the baseline of every reduction factor.
2. ``compensate``: one trial per ILC set point with the pipeline's corrections
   (current-sensor calibration, cogging feed-forward) applied.
3. ``ilc``: per ILC set point in turn, trials until the measured ripple stops
   improving or [campaign] ilc_trials.

The next trial is always a function of the trials done so far and the states
saved with them, so ``--resume`` continues exactly where a run stopped and
ends with the same result as an uninterrupted run with the same seed.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Callable, Protocol

import numpy as np

from ilcpmac.backends.base import Backend, BenchDescription
from ilcpmac.bench.format import Bench, as_written
from ilcpmac.campaign.rundir import RunDir, trial_file
from ilcpmac.config import CampaignConfig, check_bench
from ilcpmac.errors import ConfigError, IdentificationError
from ilcpmac.pipeline.pipeline import Pipeline
from ilcpmac.pipeline.safety import (
    LimitGuard,
    SafetyLimits,
    check_plan,
    identified_truth,
    torque_violation,
    trust_edges,
)
from ilcpmac.records import IdentificationResult, TrialData, TrialRequest
from ilcpmac.signals.harmonics import RippleFigures, ripple_figures
from ilcpmac.sim.grid import grid_plan, grid_requests
from ilcpmac.sim.simulator import trial_seed
from ilcpmac.stages.base import PIPELINE_NEEDS, Identified, StageSetup
from ilcpmac.stages.registry import build_stages, stage_needs


class CampaignEvents(Protocol):
    """What the campaign tells its user interface."""

    def trial(self, record: dict, records: list[dict]) -> None:
        """A trial finished (``records`` holds every trial so far, updated)."""

    def message(self, text: str) -> None:
        """Something worth saying (phase changes, the guard acting)."""


@dataclass(frozen=True)
class Step:
    """The next trial: its phase, its role in the phase and its unshaped request."""

    phase: str
    role: str
    request: TrialRequest


def _figures(prefix: str, f: RippleFigures | None) -> dict:
    if f is None:
        return {}
    return {f"ripple_pp_{prefix}": f.pp, f"ripple_rms_{prefix}": f.rms, f"rest_rms_{prefix}": f.rest_rms,
            f"ripple_rms_repeatable_{prefix}": f.rms_repeatable,
            f"amp_1x_{prefix}_nm": f.amp_1x, f"amp_2x_{prefix}_nm": f.amp_2x,
            f"amp_cogging_{prefix}_nm": f.amp_cogging, f"amp_rest_{prefix}_nm": f.amp_rest}


def base_request(config: CampaignConfig, description: BenchDescription, torque_nm: float,
                 seed: int) -> TrialRequest:
    """An uncompensated request at an ILC set point, with the bench's own calibration."""
    cpr = description.motor.counts_per_rev
    c = config.campaign
    return TrialRequest(torque_nm, c.ilc_speed_setpoint_hz, c.revolutions_at(torque_nm), np.zeros(cpr),
                        np.zeros(cpr), description.calibration, seed=seed)


@dataclass(frozen=True)
class CampaignPlan:
    """The limits of a campaign and its grid, checked against the bench before anything runs or is written.

    Attributes
    ----------
    limits : the config's limits, tightened by the bench's.
    grid : the identification grid's requests; trial k (1-based) is seeded with ``trial_seed(seed, k)``.
    """

    limits: SafetyLimits
    grid: list[TrialRequest]

    @classmethod
    def build(cls, config: CampaignConfig, description: BenchDescription, seed: int) -> "CampaignPlan":
        """Check the bench against [bench] (`check_bench`) and every request the campaign will make: the grid,
        each ILC set point as its baseline runs it, and as the stages may run it (any calibration of the trust
        region); raise `ConfigError` naming the keys."""
        check_bench(config, description)
        limits = SafetyLimits.of_campaign(config.limits, description.limits, config.grid.warmup_revolutions)
        grid = [replace(r, seed=trial_seed(seed, i + 1))
                for i, r in enumerate(grid_requests(config, description.calibration, seed, config.grid.revolutions))]
        c = config.campaign
        baselines = [(f"{config.path}: [campaign] ilc_torque_setpoints_nm {torque:g} N m at ilc_speed_setpoint_hz "
                      f"{c.ilc_speed_setpoint_hz:g} Hz, ilc_revolutions {c.revolutions_at(torque)}",
                      base_request(config, description, torque, 0)) for torque in c.ilc_torque_setpoints_nm]
        check_plan([*grid_plan(config, grid), *baselines], description, limits)
        for place, request in baselines:
            for edge in trust_edges(limits):
                why = torque_violation(request.torque_reference_nm(), description.backemf_nm_per_a, limits, edge)
                if why is not None:
                    raise ConfigError(f"{place}: with a calibration at the edge of the trust region ([limits] "
                                      f"max_scale_deviation, max_offset_deviation_a): {why}")
        return cls(limits, grid)


class CampaignRunner:
    """Runs (or resumes) a campaign.

    Parameters
    ----------
    config : the campaign.
    backend : where trials run; every request reaches it through a `LimitGuard`.
    run_dir : where they are persisted.
    seed : seeds every trial (trial k uses ``trial_seed(seed, k)``).
    identify : the identification, ``identify(bench) -> result``.
    events : the user interface.
    extra_stages : stage factories by name, for stages a script defines without packaging them.
    """

    def __init__(self, config: CampaignConfig, backend: Backend, run_dir: RunDir, seed: int,
                 identify: Callable[[Bench], IdentificationResult], events: CampaignEvents,
                 extra_stages: dict[str, Callable[[StageSetup], object]] | None = None) -> None:
        self.extra_stages = extra_stages
        self.config = config
        self.run_dir = run_dir
        self.seed = seed
        self.identify = identify
        self.events = events
        self.description: BenchDescription = run_dir.description
        plan = CampaignPlan.build(config, self.description, seed)
        self.limits = plan.limits
        #: every request of every phase passes the limits here (the identified sensors join them later)
        self.backend = LimitGuard(backend, self.description, self.limits)
        self.grid = plan.grid
        self.records: list[dict] = []
        self.identified: Identified | None = None
        self.identification_json: dict | None = None
        self.pipeline: Pipeline | None = None
        self.gains: dict[str, float] = {}
        self._grid_data: dict[int, TrialData] = {}

    # ---------------------------------------------------------------- planning

    def _base_request(self, torque_nm: float, index: int) -> TrialRequest:
        return base_request(self.config, self.description, torque_nm, trial_seed(self.seed, index))

    def _records_at(self, torque_nm: float, roles: tuple[str, ...]) -> list[dict]:
        return [r for r in self.records if r["role"] in roles and r["torque_setpoint"] == torque_nm]

    def _ilc_finished(self, torque_nm: float) -> bool:
        c = self.config.campaign
        ilc = self._records_at(torque_nm, ("ilc",))
        if len(ilc) >= c.ilc_trials:
            return True
        # judged on the repeatable part: at low torque the noise left in the average hides progress
        history = [r["ripple_rms_repeatable_measured"] for r in self._records_at(torque_nm, ("compensate", "ilc"))]
        if len(history) <= c.patience:
            return False
        best_before = min(history[: -c.patience])
        return all(p > (1.0 - c.min_improvement) * best_before for p in history[-c.patience:])

    def next_step(self) -> Step | None:
        """The next trial to run, from the trials done so far; None when the campaign is over."""
        n = len(self.records)
        index = n + 1
        if n < len(self.grid):
            return Step("identify", "grid", self.grid[n])
        for role, phase in (("baseline", "identify"), ("compensate", "compensate")):
            for torque in self.config.campaign.ilc_torque_setpoints_nm:
                if not self._records_at(torque, (role,)):
                    return Step(phase, role, self._base_request(torque, index))
        for torque in self.config.campaign.ilc_torque_setpoints_nm:
            if not self._ilc_finished(torque):
                return Step("ilc", "ilc", self._base_request(torque, index))
        return None

    # ---------------------------------------------------------------- running

    def run(self) -> dict:
        """Run the campaign to its end (resuming what ``run_dir`` holds); return the summary."""
        try:
            self._resume()
            self._loop()
            self.run_dir.flush()
            summary = self.summary()
            self.run_dir.write_summary(summary)
        finally:
            self.run_dir.close()
        return summary

    def _loop(self) -> None:
        while (step := self.next_step()) is not None:
            if step.role == "grid":
                self._run_grid()
                continue
            if self.pipeline is None:
                self._start_pipeline()
            request = step.request
            if step.role != "baseline":
                request = self.pipeline.shape(request)
            trial = self._run(request)
            self._finish(step, trial)

    def _run(self, request: TrialRequest) -> TrialData:
        trial = self.backend.run_trial(request)
        return as_written(replace(trial, request=request))

    def _run_grid(self) -> None:
        """Run the remaining grid trials (in parallel where the backend allows), persist them in order."""
        start = len(self.records)
        steps = self.grid[start:]
        self.events.message(f"identify: {len(self.grid)} multisine trials over the set-point grid")
        workers = min(getattr(self.backend, "max_parallel_trials", 1), os.cpu_count() or 1)
        with ThreadPoolExecutor(max_workers=max(workers, 1)) as pool:
            for request, trial in zip(steps, pool.map(self._run, steps)):
                self._finish(Step("identify", "grid", request), trial)

    def _finish(self, step: Step, trial: TrialData) -> None:
        """Learn from a finished trial, measure its ripple, persist it, tell the user."""
        key = step.request.setpoint_key
        record = {"index": len(self.records) + 1, "phase": step.phase, "role": step.role,
                  "torque_setpoint": step.request.torque_setpoint_nm, "speed_setpoint": step.request.speed_setpoint_hz}
        guard = None
        if step.role in ("compensate", "ilc"):
            self.pipeline.learn(trial, self.gains.get(key, 1.0))
        record.update(self._ripple(trial))
        baseline = self._records_at(step.request.torque_setpoint_nm, ("baseline",))
        if step.role in ("compensate", "ilc") and baseline:
            for kind in ("measured", "true"):
                before, after = baseline[0].get(f"ripple_pp_{kind}"), record.get(f"ripple_pp_{kind}")
                if before is not None and after is not None and after > 0:  # a flat trace has no factor
                    record["reduction_factor" + ("_true" if kind == "true" else "")] = before / after
        self.records.append(record)
        if step.role == "ilc":
            guard = self._guard(step.request.torque_setpoint_nm, key)
        state = {"record": record, "pipeline": self.pipeline.state() if self.pipeline else None,
                 "gains": dict(self.gains), "guard": guard,
                 "request": {"calibration": step.request.calibration.to_json(),
                             "feedforward_nm": trial.request.feedforward_nm.tolist(),
                             "revolutions": step.request.revolutions, "seed": step.request.seed}}
        self.run_dir.add_trial(trial, state, self.summary())
        if step.role == "grid":
            self._grid_data[record["index"]] = trial
            if len(self.records) == len(self.grid):
                self._identify(self._grid_trials())
        self.events.trial(record, self.records)

    def _grid_trials(self) -> list[TrialData]:
        """The grid trials: from memory, or read back from the run directory after a resume
        (the same numbers either way: trials are kept as written)."""
        missing = [i for i in range(1, len(self.grid) + 1) if i not in self._grid_data]
        self._grid_data.update(zip(missing, self.run_dir.read_trials(missing)))
        return [self._grid_data[i] for i in range(1, len(self.grid) + 1)]

    def _ripple(self, trial: TrialData) -> dict:
        m = self.description.motor
        H = self.config.campaign.ripple_harmonics
        out = {}
        if trial.torque_true_nm is not None:
            out.update(_figures("true", ripple_figures(trial.count, trial.torque_true_nm, m.counts_per_rev,
                                                       float(trial.torque_true_nm.mean()), m.pole_pairs,
                                                       m.cogging_order, H)))
        if self.identified is not None:
            out.update(_figures("measured", self._measured_figures(trial)))
        return out

    def _measured_figures(self, trial: TrialData) -> RippleFigures:
        """Measured ripple, as a fraction of the mean torque the sensor would show (delta epsilon set point)."""
        m = self.description.motor
        cal = trial.request.calibration
        ident = self.identified
        mean = trial.torque_setpoint_nm * ident.delta_at(cal) * float(np.mean(ident.epsilon_alpha_at(cal)))
        return ripple_figures(trial.count, trial.torque_nm, m.counts_per_rev, mean, m.pole_pairs, m.cogging_order,
                              self.config.campaign.ripple_harmonics)

    def _identify(self, grid_trials: list[TrialData]) -> None:
        """Identify from the grid; measured ripple of the grid trials follows from it."""
        self.run_dir.flush()  # the grid records change below; nothing may be serialising them
        self.events.message("identify: estimating delta*epsilon, delta, alpha, beta and cogging")
        bench = Bench(self.description.motor, self.description.backemf_nm_per_a, self.description.calibration,
                      tuple(grid_trials), tuple(trial_file(i) for i in range(1, len(grid_trials) + 1)))
        result = self.identify(bench)
        self.identification_json = result.to_json()
        if not isinstance(result, IdentificationResult):  # an injected answer (a truth) known by its JSON alone
            result = IdentificationResult.from_json(self.identification_json)
        self._set_identified(result)
        for record, trial in zip(self.records, grid_trials):
            trial = replace(trial, request=replace(self.grid[record["index"] - 1]))
            record.update(_figures("measured", self._measured_figures(trial)))
        self.run_dir.write_json("identification.json", {
            "result": self.identification_json, "grid_records": self.records[: len(self.grid)]})
        self.run_dir.write_summary(self.summary())

    def _set_identified(self, result: IdentificationResult) -> None:
        """Take the identification: the stages start from it, the limits bound the flowing current with it.

        Raises `IdentificationError` when it lacks an estimate the pipeline (`PIPELINE_NEEDS`) or a
        configured stage (its factory's ``needs``) needs.
        """
        needs = {"the pipeline": PIPELINE_NEEDS, **{f"stage {name!r}": needed for name, needed in stage_needs(
            list(self.config.pipeline.stages), self.extra_stages).items()}}
        missing = {who: result.missing(needed) for who, needed in needs.items()}
        missing = {who: names for who, names in missing.items() if names}
        if missing:
            why = "; ".join(result.messages) or "no reason given"
            wanted = "; ".join(f"{who} needs {', '.join(names)}" for who, names in missing.items())
            raise IdentificationError(f"{wanted}, which the identification could not estimate ({why})")
        self.identified = Identified.from_result(result, self.description.calibration)
        self.backend.truth = identified_truth(self.identified)

    def _start_pipeline(self) -> None:
        names = list(self.config.pipeline.stages)
        setups = {name: StageSetup(self.description, self.identified, self.config.campaign.ripple_harmonics,
                                   self.config.stage_options.get(name, {})) for name in names}
        stages = build_stages(names, setups, self.extra_stages)
        self.pipeline = Pipeline(stages, self.description, self.identified, self.limits,
                                 self.config.campaign.ripple_harmonics, self.events.message)

    def _guard(self, torque_nm: float, key: str) -> dict | None:
        """Revert to the best correction and halve the learning gain when the ripple grew twice in a row."""
        history = self._records_at(torque_nm, ("compensate", "ilc"))
        pp = [r["ripple_pp_measured"] for r in history]
        if len(pp) < 3 or not (pp[-1] > pp[-2] > pp[-3]):
            return None
        best = min(history, key=lambda r: r["ripple_pp_measured"])
        self.pipeline.restore(self.run_dir.state(best["index"])["pipeline"])
        self.gains[key] = self.gains.get(key, 1.0) * 0.5
        event = {"set_point": key, "reverted_to_trial": best["index"], "learning_gain": self.gains[key]}
        self.events.message(f"guard: measured ripple at {key} grew twice in a row; reverted to the correction "
                            f"of trial {best['index']} and halved the learning gain to {self.gains[key]:g}")
        return event

    # ---------------------------------------------------------------- resume and summary

    def _resume(self) -> None:
        """Reload what the run directory holds: records, identification, stage states, gains."""
        done = self.run_dir.completed
        if done == 0:
            return
        self.records = [self.run_dir.state(i)["record"] for i in range(1, done + 1)]
        saved = self.run_dir.read_json("identification.json")
        if len(self.records) >= len(self.grid):
            if saved is None:
                self._identify(self._grid_trials())
            else:
                self.identification_json = saved["result"]
                self._set_identified(IdentificationResult.from_json(saved["result"]))
                self.records[: len(self.grid)] = saved["grid_records"]
        last = self.run_dir.state(done)
        self.gains = dict(last.get("gains", {}))
        if last["pipeline"] is not None:
            self._start_pipeline()
            self.pipeline.restore(last["pipeline"])
        self.events.message(f"resume: {done} trials already complete in {self.run_dir.path}")

    def summary(self) -> dict:
        """summary.json: every trial, the identification and the final figures."""
        trials = [{k: v for k, v in r.items()} for r in self.records]
        final = {}
        last = [self._records_at(t, ("compensate", "ilc"))[-1:] for t in self.config.campaign.ilc_torque_setpoints_nm]
        last = [r[0] for r in last if r]
        if last and len(last) == len(self.config.campaign.ilc_torque_setpoints_nm):
            for key in ("ripple_pp_true", "ripple_pp_measured", "ripple_rms_true", "ripple_rms_measured"):
                if all(key in r for r in last):
                    final[key] = max(r[key] for r in last)
            for key in ("reduction_factor", "reduction_factor_true"):
                if all(key in r for r in last):
                    final[key] = min(r[key] for r in last)
        return {"trials": trials, "identification": self.identification_json, "final": final}

