"""The campaign as a service: what the CLI, the sweep and a user's script call to run one (`run`), or to simulate
the identification grid into a bench folder (`simulated_bench`, `simulate_bench`).

From a script or a notebook::

    import ilcpmac.campaign
    result = ilcpmac.campaign.run("my-bench.toml", out="runs/first", seed=3)
    print(result.path, result.summary["final"])
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from ilcpmac.backends.base import Backend
from ilcpmac.backends.registry import BackendSetup, build_backend
from ilcpmac.bench.format import Bench, write_bench
from ilcpmac.campaign.events import CampaignEvents, CampaignStart, NoEvents
from ilcpmac.campaign.grid import grid_plan, grid_requests
from ilcpmac.campaign.plan import MAX_BUDGET_MIN, CampaignPlan
from ilcpmac.campaign.record import TrialRecord, records_of
from ilcpmac.campaign.rundir import RunDir, RunFiles
from ilcpmac.campaign.validation import PointResult, point_results
from ilcpmac.config import FORWARD, CampaignConfig, check_config, config_text, load_config, packaged_config
from ilcpmac.core.errors import ConfigError
from ilcpmac.core.files import atomic_write
from ilcpmac.core.records import BenchDescription, IdentificationResult, TrialData
from ilcpmac.pipeline.safety import SafetyLimits, check_plan
from ilcpmac.stages.registry import check_stage_options

if TYPE_CHECKING:
    from ilcpmac.campaign.drive import DriveCampaignResult
    from ilcpmac.identify import Identifier
    from ilcpmac.stages.base import Stage, StageSetup

__all__ = ["DEFAULT_CONFIG", "CampaignResult", "built_backend", "campaign_in", "check_campaign_config",
           "default_run_dir", "given_config", "load_campaign_config", "overridden", "planned", "refuse_with_resume",
           "resumed_budget_min", "run", "run_drive", "simulate_bench", "simulated_bench"]

#: the packaged config `run` runs with no config
DEFAULT_CONFIG = "seed-bench.toml"
#: a simulated static trial's reference scatter, of the largest torque it holds (a load cell's 0.1 % of full scale)
STATIC_SCATTER = 1e-3


@dataclass(frozen=True)
class CampaignResult:
    """What a campaign ended with.

    Attributes
    ----------
    path : its run directory (a bench folder, docs/campaign.md).
    plan : its plan (limits, grid, learned and validated points).
    summary : summary.json as written.
    records : every trial, in the order they ran.
    identification : the grid's identification (None if the campaign ran no grid).
    """

    path: Path
    plan: CampaignPlan
    summary: dict[str, Any]
    records: list[TrialRecord]
    identification: IdentificationResult | None

    @property
    def points(self) -> list[PointResult]:
        """Each learned, then validated, operating point's result (`point_results`)."""
        return point_results(self.records, self.plan.learned, self.plan.validated)


def check_campaign_config(config: CampaignConfig,
                          extra_stages: dict[str, Callable[[StageSetup], Stage]] | None = None) -> None:
    """`check_config` and the stages' options (`check_stage_options`: every stage whose factory declares them,
    installed or in ``extra_stages``): everything a campaign's config can be refused for before its first trial;
    call it again after changing a loaded config."""
    check_config(config)
    check_stage_options(config, extra_stages)


def load_campaign_config(path: str | Path) -> CampaignConfig:
    """`load_config`, then the stages' options checked (`check_stage_options`): `ConfigError` names the file and
    key."""
    config = load_config(path)
    check_stage_options(config)
    return config


def run(config: str | Path | CampaignConfig | None = None, *, out: str | Path | None = None,
        backend: str | Backend | None = None, address: str | None = None, trials: int | None = None,
        seed: int | None = None, budget_min: float | None = None, resume: str | Path | None = None,
        events: CampaignEvents | None = None, identify: Identifier | None = None,
        extra_stages: dict[str, Callable[[StageSetup], Stage]] | None = None) -> CampaignResult:
    """Run a campaign (``ilcpmac run``): identify, learn, validate a compensation, every trial persisted in its
    run directory as it finishes.

    Parameters
    ----------
    config : the campaign's config file, or a loaded config (its file's text is what the run directory keeps);
        None: the packaged seed-bench.toml (`DEFAULT_CONFIG`).
    out : the run directory to create (default runs/<config name>-<date>-<time>).
    backend : where trials run: an installed backend's name (``ilcpmac backends``), built here from the config's
        ``[backends.NAME]`` table and closed at the end, or a `Backend`, which stays the caller's to close; None:
        the config's [campaign] backend.
    address : where the bench is, for backends built by name that need it.
    trials : most learning trials per learned point (overrides [campaign] learn_trials).
    seed : overrides [trials] seed.
    budget_min : the motor's running time to plan the campaign to, minutes: the trials after the grid as long as
        fit (`CampaignPlan.within_budget`); None: as the config says.
    resume : continue the run in this directory from its last complete trial, sealed (docs/campaign.md, "What the
        seal guarantees"); no ``config``, ``out``, ``budget_min``, ``seed`` or ``trials`` then: the run goes on with
        the ones it began with.
    events : told what happens (`CampaignEvents`); default nothing.
    identify : the identification, ``identify(bench, torque_source=...) -> result`` (`Identifier`; default
        `ilcpmac.identify.identify_bench`).
    extra_stages : stage factories by name, for stages a script defines without packaging them.

    Raises `ConfigError` before anything runs for a config, a plan or an override that cannot run; a run
    directory that exists (or, with ``resume``, is locked) is left untouched.
    """
    events = events or NoEvents()
    if resume is not None:
        refuse_with_resume(config, out, budget_min, seed, trials)
    resume_dir = None if resume is None else Path(resume)
    out_dir = None if out is None else Path(out)
    # the run directory is locked before the backend is built: a second run on it, or one that cannot
    # write there, stops before the bench moves
    lock = RunDir.lock(resume_dir, new=False) if resume_dir is not None else None
    made: Path | None = None  # the directory made for the run, removed if the run never starts
    run_dir = None
    try:
        if resume_dir is not None:
            settings = RunDir.read_settings(resume_dir)
            cfg = load_config(RunFiles(resume_dir).config)
            if settings.get("direction") is not None:
                raise ConfigError(f"--resume {resume_dir}: the {settings['direction']} of a campaign in both "
                                  f"directions: resume the run directory that holds it, {resume_dir.parent}")
            seed, trials = settings.get("seed"), settings.get("trials")
            budget_min = resumed_budget_min(settings, RunFiles(resume_dir).settings)
        else:
            cfg = given_config(config)
        cfg = overridden(cfg, trials, seed, extra_stages)
        if cfg.directions() != (FORWARD,):
            raise ConfigError(f"{cfg.path}: [campaign] learn_speeds_hz learns in reverse: a campaign in both "
                              "directions runs with ilcpmac run, ilcpmac.api.run_quadrants or "
                              "ilcpmac.campaign.run_quadrants (docs/campaign.md, \"Four quadrants\")")
        seed = cfg.grid.seed
        path = resume_dir or out_dir or default_run_dir(cfg)
        if lock is None:
            made = None if path.exists() else path
            lock = RunDir.lock(path, new=True)
        bench = built_backend(cfg, backend, address) if backend is None or isinstance(backend, str) else backend
        try:
            description = bench.describe()
            # before anything is written
            plan = planned(cfg, description, seed, budget_min)
            run_dir = RunDir.resume(path, description, lock) if resume_dir is not None else \
                RunDir.create(path, description, config_text(cfg), {"seed": seed, "trials": trials,
                                                                    "budget_min": budget_min, "config": str(cfg.path)},
                              lock, plan.static)
            result = campaign_in(bench, description, run_dir, plan, resume_dir is not None, events, identify,
                                 extra_stages)
        finally:
            if backend is None or isinstance(backend, str):
                bench.close()
    finally:
        if lock is not None:
            lock.release()
        if made is not None and run_dir is None:  # nothing was created: leave no empty directory behind
            shutil.rmtree(made, ignore_errors=True)
    return result


def refuse_with_resume(config: object, out: object, budget_min: object, seed: object, trials: object) -> None:
    """`ConfigError` for what a resumed run takes from its run directory and was given all the same."""
    given = [name for name, value in (("CONFIG", config), ("--out", out), ("--budget", budget_min),
                                      ("--seed", seed), ("--trials", trials)) if value is not None]
    if given:
        raise ConfigError(f"--resume continues a run with the config, seed, trials and budget it began with: "
                          f"give no {', '.join(given)} (start a new run to change them)")


def resumed_budget_min(settings: dict[str, Any], source: Path) -> float | None:
    """The budget a run began with, from its settings ``source``: `ConfigError` naming the file if not minutes."""
    budget_min = settings.get("budget_min")
    if budget_min is not None and not (isinstance(budget_min, (int, float)) and 0 < budget_min <= MAX_BUDGET_MIN):
        raise ConfigError(f"{source}: budget_min: {budget_min!r} is not a number of minutes within (0, "
                          f"{MAX_BUDGET_MIN:g}]")
    return budget_min


def given_config(config: str | Path | CampaignConfig | None) -> CampaignConfig:
    """The campaign of ``config``: a loaded config as it is, a file loaded, None the packaged `DEFAULT_CONFIG`."""
    return config if isinstance(config, CampaignConfig) else load_config(config or packaged_config(DEFAULT_CONFIG))


def overridden(cfg: CampaignConfig, trials: int | None, seed: int | None,
               extra_stages: dict[str, Callable[[StageSetup], Stage]] | None) -> CampaignConfig:
    """``cfg`` with --trials and --seed where given, checked (`check_campaign_config`): the overrides obey the same
    ranges as the file; an unknown stage or option stops here, not after the grid."""
    if trials is not None:
        cfg = replace(cfg, campaign=replace(cfg.campaign, learn_trials=trials))
    if seed is not None:
        cfg = replace(cfg, grid=replace(cfg.grid, seed=seed))
    check_campaign_config(cfg, extra_stages)
    return cfg


def planned(cfg: CampaignConfig, description: BenchDescription, seed: int, budget_min: float | None) -> CampaignPlan:
    """The campaign's plan on the bench ``description`` (`CampaignPlan.build`, or `CampaignPlan.within_budget`
    of ``budget_min`` minutes): `ConfigError` before anything is written."""
    return CampaignPlan.build(cfg, description, seed) if budget_min is None else \
        CampaignPlan.within_budget(cfg, description, seed, budget_min * 60.0)


def campaign_in(backend: Backend, description: BenchDescription, run_dir: RunDir, plan: CampaignPlan, resume: bool,
                events: CampaignEvents, identify: Identifier | None,
                extra_stages: dict[str, Callable[[StageSetup], Stage]] | None) -> CampaignResult:
    """`plan` run on a built ``backend`` (which ``description`` describes) in its created (or resumed) run
    directory."""
    summary = _run(plan.config, backend, description, run_dir, plan, plan.seed, resume, events, identify,
                   extra_stages)
    identification = summary["identification"]
    return CampaignResult(run_dir.path, plan, summary, records_of(summary),
                          None if identification is None else IdentificationResult.from_json(identification))


def default_run_dir(cfg: CampaignConfig) -> Path:
    """runs/<config name>-<date>-<time>: where a run goes when no directory is given."""
    return Path("runs") / f"{cfg.path.stem}-{time.strftime('%Y%m%d-%H%M%S')}"


def run_drive(cfg: CampaignConfig, *, out: str | Path | None = None, backend: str | Backend | None = None,
              address: str | None = None, write_config: bool = False,
              on_event: Callable[[str], None] | None = None) -> DriveCampaignResult:
    """The drive campaign of a config with a [drive] table (``ilcpmac run`` of it; docs/moteus.md), written into
    ``out`` (default `default_run_dir`; refused where it exists and is not empty).

    ``backend``: an installed backend's name, built from the config's ``[backends.NAME]`` table and closed at the
    end (None: the config's [campaign] backend), or a `DriveBackend` instance, which stays the caller's to close.
    ``write_config``: the final table into the drive's flash at the end. ``on_event``: each line as it happens."""
    from ilcpmac.campaign.drive import run_drive_campaign

    path = Path(out) if out is not None else default_run_dir(cfg)
    if path.exists() and (not path.is_dir() or any(path.iterdir())):
        raise ConfigError(f"--out {path}: exists and is not an empty directory: a drive campaign writes a new one")
    if backend is not None and not isinstance(backend, str):
        return run_drive_campaign(cfg, backend, path, on_event, write_config)
    drive = built_backend(cfg, backend, address, write_config)
    try:
        return run_drive_campaign(cfg, drive, path, on_event, write_config)
    finally:
        drive.close()


def built_backend(cfg: CampaignConfig, name: str | None, address: str | None, write_config: bool = False) -> Backend:
    """The installed backend ``name`` (None: the config's [campaign] backend) built from the config and its
    ``[backends.NAME]`` table."""
    name = name or cfg.campaign.backend
    return build_backend(name, BackendSetup(cfg, address, cfg.backend_options.get(name, {}), write_config))


def _run(cfg: CampaignConfig, backend: Backend, description: BenchDescription, run_dir: RunDir, plan: CampaignPlan,
         seed: int, resume: bool, events: CampaignEvents, identify: Identifier | None,
         extra_stages: dict[str, Callable[[StageSetup], Stage]] | None) -> dict[str, Any]:
    """`run`'s campaign on a built backend (which ``description`` describes) in its created (or resumed) run
    directory: the summary."""
    # the runner's estimators import numba: deferred so that importing ilcpmac.campaign stays light
    from ilcpmac.campaign.runner import CampaignRunner, torque_source
    from ilcpmac.identify import identify_bench

    events.start(CampaignStart(plan, run_dir.path, resume, torque_source(cfg, description)))
    try:
        summary = CampaignRunner(cfg, backend, run_dir, seed, identify or identify_bench, events, extra_stages,
                                 plan).run()
    except BaseException:
        events.end("stopped")
        raise
    events.end("done")
    return summary


def simulated_bench(config: CampaignConfig, seed: int | None = None, revolutions: int | None = None,
                    on_done: Callable[[int, TrialData], None] | None = None,
                    torque_sensor: bool = True, workers: int | None = None,
                    static_trial: bool = False) -> tuple[Bench, dict[str, Any]]:
    """Run the set-point grid on the simulator, in memory: the bench folder's contents and its truth
    (`ilcpmac.sim.bench.truth_dict`).

    Parameters
    ----------
    config : the campaign.
    seed, revolutions : override the config's ``[trials]`` values.
    on_done : called with (index, trial) as each trial finishes.
    torque_sensor : False: a bench without a torque sensor (no torque column, [motor] torque_sensor =
        false, with the encoder's timer_resolution_s); the simulator's torque sensor still runs, unrecorded.
    workers : trials simulated at once in threads (default one per core).
    static_trial : True: with a static trial (`ilcpmac.sim.static_trial`, the grid's largest torque set point, the
        reference's scatter `STATIC_SCATTER` of it), which pins eps.

    Raises `ConfigError` before any trial runs when a grid request breaks the config's [limits].
    """
    # the simulator's kernel imports numba: deferred so that importing ilcpmac.campaign stays light
    from ilcpmac.sim.bench import simulated_description, truth_dict
    from ilcpmac.sim.simulator import Simulator

    seed = config.grid.seed if seed is None else seed
    revolutions = config.grid.revolutions if revolutions is None else revolutions
    lim = config.limits
    simulator = Simulator(config.sampled_model(), config.grid.warmup_revolutions, config.recorded_counts_per_rev())
    bench_limits = lim.bench_limits()
    description = simulated_description(simulator, bench_limits)
    requests = grid_requests(config, description.calibration, seed, revolutions)
    check_plan(grid_plan(config, requests), description,
               SafetyLimits.of_campaign(lim, bench_limits, config.grid.warmup_revolutions))
    trials = simulator.run_trials(requests, workers, on_done)
    if not torque_sensor:
        trials = [replace(trial, torque_nm=None) for trial in trials]
    bench = Bench(
        motor=description.motor if torque_sensor else replace(
            description.motor, torque_sensor=False, timer_resolution_s=simulator.model.encoder.timer_resolution_s),
        backemf_nm_per_a=simulator.backemf_counts,
        sensors=requests[0].calibration,
        trials=tuple(trials),
        trial_files=tuple(f"trial_{i + 1:02d}.csv" for i in range(len(trials))),
    )
    if static_trial:
        from ilcpmac.sim.static_trial import simulated_static_trial

        top = max(config.grid.torque_setpoints_nm)
        bench = replace(bench, static=simulated_static_trial(simulator, requests[0].calibration, top,
                                                             STATIC_SCATTER * top, seed))
    return bench, truth_dict(simulator, requests[0].calibration)


def simulate_bench(config: CampaignConfig, out_dir: str | Path, seed: int | None = None,
                   revolutions: int | None = None,
                   on_done: Callable[[int, TrialData], None] | None = None, torque_sensor: bool = True,
                   static_trial: bool = False) -> Bench:
    """`simulated_bench`, written as a bench folder plus ``truth.json`` in ``out_dir`` (created if needed):
    ``ilcpmac simulate``."""
    bench, truth = simulated_bench(config, seed, revolutions, on_done, torque_sensor, static_trial=static_trial)
    out_dir = Path(out_dir)
    write_bench(out_dir, bench)
    atomic_write(out_dir / "truth.json", json.dumps(truth, indent=1))
    return bench
