"""A campaign in both directions, all four quadrants: a forward campaign and a reverse one, each at positive speeds.

A reverse lap of a motor M is a forward lap of its mirror image M' (docs/bench-format.md, "Reverse laps"), so the
points of negative speed (T, S) are learned as the mirror's campaign at (-T, -S) (`CampaignConfig.in_direction`):
`MirroredBackend` shows the runner M' and turns each request it passes, already checked by the campaign's
`LimitGuard` against M' (every limit reads the same numbers in both: `mirrored_request`), into M's reverse request
for a backend that runs one (`runs_reverse`). The reverse campaign learns with the forward grid's identification
in the mirror's coordinates (`mirror_image`), so that both directions' tables rest on one calibration; its own
grid is identified too, and the two compared (`MirroredIdentification`).

A run directory of both (`run_quadrants`) holds campaign.toml, `QUADRANTS_FILE`, forward/ and reverse/ (each a
run directory of its own, reverse/ in the mirror's coordinates: its point (T', S') is the motor's (-T', -S')), and
compensation.json of both directions (`both_directions`).
"""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from ilcpmac.backends.base import Backend, report_progress_to, runs_reverse
from ilcpmac.bench.format import Bench, check_bench
from ilcpmac.campaign.events import CampaignEvents, DirectionsPlanned, NoEvents
from ilcpmac.campaign.plan import CampaignPlan
from ilcpmac.campaign.rundir import CONFIG_FILE, RunDir, RunLock
from ilcpmac.campaign.service import (
    CampaignResult,
    built_backend,
    campaign_in,
    default_run_dir,
    given_config,
    overridden,
    planned,
    refuse_with_resume,
    resumed_budget_min,
)
from ilcpmac.compensation import COMPENSATION_FILE, Compensation, FadeOut
from ilcpmac.config import FORWARD, REVERSE, CampaignConfig, config_text, load_config
from ilcpmac.core.errors import ConfigError, IlcpmacError
from ilcpmac.core.files import atomic_write, read_bounded
from ilcpmac.core.records import (
    MIRROR_COORDINATES,
    BenchDescription,
    IdentificationResult,
    SensorCalibration,
    TrialData,
    TrialRequest,
    mirrored_request,
    mirrored_table,
)
from ilcpmac.core.seeds import reverse_seed
from ilcpmac.core.torque_source import TorqueSource

if TYPE_CHECKING:
    from ilcpmac.identify import Identifier
    from ilcpmac.stages.base import Stage, StageSetup

__all__ = ["CALIBRATION_RTOL", "MIRROR_NOTE", "QUADRANTS_FILE", "SENSOR_STAGE", "MirroredBackend",
           "MirroredIdentification", "QuadrantsResult", "at_calibration", "both_directions", "held_calibration",
           "is_quadrants_dir", "mirrored_description", "run_quadrants"]

#: how the reverse campaign's points read: the mirror's
MIRROR_NOTE = "as the mirror image's forward laps: the motor's torque and speed are the negated ones shown"
#: the stage whose calibration the reverse campaign holds at the forward one's (`held_calibration`)
SENSOR_STAGE = "current-sensor"
#: how far the two directions' calibrations may differ, relative: rounding (`at_calibration` and back)
CALIBRATION_RTOL = 1e-9
#: what makes a folder the run directory of a campaign in both directions: its directions and settings
QUADRANTS_FILE = "quadrants.json"
#: largest quadrants.json read, bytes
_MAX_SETTINGS_BYTES = 1 << 16


def mirrored_description(description: BenchDescription) -> BenchDescription:
    """The bench of the motor's mirror image: its back-EMF table mirrored (`mirrored_table`) and its [motor]
    mirrored = true (a bench folder of reverse laps), the rest as it is."""
    return replace(description, motor=replace(description.motor, mirrored=True),
                   backemf_nm_per_a=mirrored_table(description.backemf_nm_per_a))


class MirroredBackend:
    """The mirror image of a backend that runs reverse trials (`runs_reverse`): its forward trials are the
    backend's reverse ones (`mirrored_request`), its description `mirrored_description`; the trial data come back
    as the backend returns them, the mirror's forward laps. Closing it leaves the backend open (its maker's)."""

    def __init__(self, backend: Backend) -> None:
        if not runs_reverse(backend):
            raise IlcpmacError(f"the {type(backend).__name__} backend runs no reverse trials (no reverses = True)")
        self.backend = backend

    @property
    def max_parallel_trials(self) -> int:
        return self.backend.max_parallel_trials

    def describe(self) -> BenchDescription:
        return mirrored_description(self.backend.describe())

    def run_trial(self, request: TrialRequest) -> TrialData:
        if not request.speed_setpoint_hz > 0:
            raise IlcpmacError(f"the mirror runs forward trials only, got {request.speed_setpoint_hz!r} Hz")
        return self.backend.run_trial(mirrored_request(request))

    def set_progress(self, callback: Callable[[float], None] | None) -> None:
        report_progress_to(self.backend, callback)

    def close(self) -> None:
        """Nothing of its own to release."""


#: the scalar estimates `MirroredIdentification` compares between the directions
_COMPARED = (("delta_epsilon", "delta eps"), ("epsilon", "eps"), ("delta", "delta"))


@dataclass(frozen=True)
class MirroredIdentification:
    """The reverse campaign's identification (an `Identifier`), in the mirror's coordinates it learns in
    (`mirror_image`): the forward one (``forward``), with a message comparing it to what the reverse grid gives
    on its own (``identify`` of the mirrored bench folder, in the motor's coordinates); without a forward one, the
    reverse grid's own."""

    forward: IdentificationResult | None
    identify: Identifier

    def __call__(self, bench: Bench, *, torque_source: TorqueSource | None = None) -> IdentificationResult:
        # the identification imports numba: deferred so that importing this module stays light
        from ilcpmac.identify.mirror import MIRRORED_MESSAGE, mirror_image

        own = self.identify(bench) if torque_source is None else self.identify(bench, torque_source=torque_source)
        if self.forward is None:
            mirrored = mirror_image(own)
            return replace(mirrored, messages=(*(m for m in mirrored.messages if m != MIRRORED_MESSAGE),
                                               MIRROR_COORDINATES))
        mirrored = mirror_image(self.forward)
        return replace(mirrored, messages=(*mirrored.messages, MIRROR_COORDINATES, self.agreement(own)))

    def agreement(self, own: IdentificationResult) -> str:
        """The line saying how the reverse grid's own estimates compare with the forward ones it learns with."""
        parts = []
        for name, shown in _COMPARED:
            mine, theirs = getattr(own, name), getattr(self.forward, name)
            if mine is None or theirs is None:
                continue
            spread = math.hypot(getattr(own, f"{name}_std") or 0.0, getattr(self.forward, f"{name}_std") or 0.0)
            parts.append(f"{shown} {mine:.5g} against {theirs:.5g} forward ({100 * (mine / theirs - 1):+.2f} %"
                         + (f", {(mine - theirs) / spread:+.1f} sigma)" if spread > 0 else ")"))
        return ("reverse grid identified on its own: " + ", ".join(parts) + "; the reverse learns with the forward "
                "identification, mirrored, at the forward campaign's final calibration, so that both directions "
                "share one")


def at_calibration(result: IdentificationResult, calibration: SensorCalibration,
                   bench: SensorCalibration) -> IdentificationResult:
    """``result`` with the current sensors that make ``calibration`` exact where the bench's is ``bench`` (the
    inverse of `ilcpmac.pipeline.safety.identified_truth`): eps alpha_p = bench scale_p / scale_p and beta_p =
    (offset_p - bench offset_p) / scale_p, A; delta eps follows eps. The reverse campaign learns at the forward
    campaign's final calibration so (its current-sensor stage holding it: `SENSOR_STAGE`), and both directions'
    tables rest on one calibration."""
    eps_alpha = bench.current_scale / calibration.current_scale
    epsilon = float(eps_alpha.mean())
    return replace(result, epsilon=epsilon, alpha=eps_alpha / epsilon,
                   beta=(calibration.current_offset - bench.current_offset) / calibration.current_scale,
                   delta_epsilon=None if result.delta is None else result.delta * epsilon)


def held_calibration(config: CampaignConfig) -> CampaignConfig:
    """``config`` with its current-sensor stage (`SENSOR_STAGE`, where it runs) learning from no trial: the
    calibration holds at the identification's (`at_calibration`)."""
    if SENSOR_STAGE not in config.pipeline.stages:
        return config
    options = {**config.stage_options, SENSOR_STAGE: {**config.stage_options.get(SENSOR_STAGE, {}),
                                                      "trials_per_point": 0}}
    return replace(config, stage_options=options)


def both_directions(forward: Compensation | None, reverse: Compensation) -> Compensation:
    """The compensation of both directions in the motor's coordinates: the reverse campaign's tables (the mirror's,
    at (T', S')) mirrored back (`mirrored_table`) at (-T', -S'), beside the forward ones; one fade-out, the earlier
    of the two at each end (it fades by the speed's size). Needs the same torques and calibration in both
    (`IlcpmacError` otherwise)."""
    cpr = reverse.counts_per_rev
    tables = -reverse.tables_nm[::-1, ::-1][..., -np.arange(cpr) % cpr]
    back = Compensation(cpr, reverse.calibration, -reverse.torques_nm[::-1], -reverse.speeds_hz[::-1], tables,
                        reverse.fade)
    if forward is None:
        return back
    if not np.array_equal(forward.torques_nm, back.torques_nm) or forward.counts_per_rev != cpr:
        raise IlcpmacError(f"the directions learned at different torques ({forward.torques_nm.tolist()} and "
                           f"{back.torques_nm.tolist()} N m) or counts: no one table holds both")
    for key, a, b in (("current_scale", forward.calibration.current_scale, back.calibration.current_scale),
                      ("current_offset", forward.calibration.current_offset, back.calibration.current_offset)):
        if not np.allclose(a, b, rtol=CALIBRATION_RTOL, atol=CALIBRATION_RTOL * np.abs(a).max()):
            raise IlcpmacError(f"the directions' stages set different calibrations ({key} {a.tolist()} forward, "
                               f"{b.tolist()} reverse); a compensation holds one")
    fade = FadeOut(min(forward.fade.full_hz, back.fade.full_hz), min(forward.fade.zero_hz, back.fade.zero_hz))
    return Compensation(cpr, forward.calibration, forward.torques_nm, np.concatenate([back.speeds_hz,
                                                                                      forward.speeds_hz]),
                        np.concatenate([back.tables_nm, forward.tables_nm], axis=1), fade)


@dataclass(frozen=True)
class QuadrantsResult:
    """What a campaign in both directions ended with.

    Attributes
    ----------
    path : its run directory.
    directions : each direction's campaign, by `DIRECTIONS` name, in the order they ran (reverse in the mirror's
        coordinates).
    compensation : the compensation of both (`both_directions`), as written in compensation.json.
    """

    path: Path
    directions: dict[str, CampaignResult]
    compensation: Compensation


def is_quadrants_dir(path: str | Path) -> bool:
    """Whether ``path`` holds a campaign in both directions (`QUADRANTS_FILE`)."""
    return (Path(path) / QUADRANTS_FILE).is_file()


def _settings(path: Path) -> dict[str, Any]:
    """quadrants.json of the run directory ``path``: its seed, trials and budget."""
    source = path / QUADRANTS_FILE
    try:
        data = json.loads(read_bounded(source, _MAX_SETTINGS_BYTES, ConfigError))
    except ValueError as e:
        raise ConfigError(f"{source}: cannot be read as a campaign's settings: {e}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: must hold a JSON object")
    return data


def run_quadrants(config: str | Path | CampaignConfig | None = None, *, out: str | Path | None = None,
                  backend: str | Backend | None = None, address: str | None = None, trials: int | None = None,
                  seed: int | None = None, budget_min: float | None = None, resume: str | Path | None = None,
                  events: CampaignEvents | None = None, identify: Identifier | None = None,
                  extra_stages: dict[str, Callable[[StageSetup], Stage]] | None = None) -> QuadrantsResult:
    """Run a campaign in both directions (``ilcpmac run`` of a config whose [campaign] learn_speeds_hz holds a
    negative speed): forward, then reverse, each a campaign of its own in the run directory's forward/ and reverse/,
    then the compensation of both. Arguments as `ilcpmac.campaign.service.run`'s; ``budget_min`` is shared equally.

    Both plans are checked before the first trial; `ConfigError` names the key of any that cannot run, and of a
    backend that runs no reverse trials.
    """
    from ilcpmac.identify import identify_bench

    events = events or NoEvents()
    if resume is not None:
        refuse_with_resume(config, out, budget_min, seed, trials)
        path = Path(resume)
        settings = _settings(path)
        cfg = load_config(path / CONFIG_FILE)
        seed, trials = settings.get("seed"), settings.get("trials")
        budget_min = resumed_budget_min(settings, path / QUADRANTS_FILE)
    else:
        cfg = given_config(config)
    cfg = overridden(cfg, trials, seed, extra_stages)
    seed = cfg.grid.seed
    directions = cfg.directions()
    path = Path(resume) if resume is not None else Path(out) if out is not None else default_run_dir(cfg)
    made = None if resume is not None or path.exists() else path  # removed if the run never starts
    lock = RunDir.lock(path, new=resume is None)
    try:
        bench = built_backend(cfg, backend, address) if backend is None or isinstance(backend, str) else backend
        try:
            description = bench.describe()
            check_bench(cfg, description)
            if REVERSE in directions and not runs_reverse(bench):
                raise ConfigError(f"{cfg.path}: [campaign] learn_speeds_hz {min(cfg.learned_speeds_hz()):g}: the "
                                  f"{type(bench).__name__} backend runs no reverse trials (docs/writing-a-backend.md)")
            share = None if budget_min is None else budget_min / len(directions)
            sides = {d: (bench, description) if d == FORWARD else
                     (MirroredBackend(bench), mirrored_description(description)) for d in directions}
            plans = _plans(cfg, {d: side[1] for d, side in sides.items()}, share)
            for d in directions:
                if (path / d / CONFIG_FILE).exists():
                    _check_resumable(path, d, plans[d], trials)
            if len(directions) > 1:
                events.message(DirectionsPlanned(
                    {d: len(plans[d].steps_left([])) for d in directions},
                    {d: sum(plans[d].bench_seconds(step.request) for step in plans[d].steps_left([]))
                     for d in directions}, not any(plans[d].stops_early() for d in directions)))
            if resume is None:
                made = None
                atomic_write(path / CONFIG_FILE, config_text(cfg))
                atomic_write(path / QUADRANTS_FILE, json.dumps({"directions": list(directions), "seed": seed,
                                                                "trials": trials, "budget_min": budget_min,
                                                                "config": str(cfg.path)}, indent=1))
            results: dict[str, CampaignResult] = {}
            learned: dict[str, Compensation] = {}
            for direction in directions:
                ahead = results.get(FORWARD)
                told = identify if direction == FORWARD else MirroredIdentification(
                    None if ahead is None or ahead.identification is None else at_calibration(
                        ahead.identification, learned[FORWARD].calibration, description.calibration),
                    identify or identify_bench)
                results[direction] = _direction(direction, plans[direction], *sides[direction], path, cfg, trials,
                                                share, events, told, extra_stages)
                learned[direction] = Compensation.read(results[direction].path / COMPENSATION_FILE)
        finally:
            if backend is None or isinstance(backend, str):
                bench.close()
        compensation = both_directions(learned.get(FORWARD), learned[REVERSE]) if REVERSE in learned else \
            learned[FORWARD]
        atomic_write(path / COMPENSATION_FILE, json.dumps(compensation.to_json(), indent=1))
    finally:
        lock.release()
        if made is not None:
            shutil.rmtree(made, ignore_errors=True)
    return QuadrantsResult(path, results, compensation)


def _plans(cfg: CampaignConfig, descriptions: dict[str, BenchDescription], budget_min: float | None
           ) -> dict[str, CampaignPlan]:
    """Each direction's plan on its description (the reverse one the mirror's), within its share ``budget_min`` of
    --budget: the reverse at its own seed (`reverse_seed`) and, after a forward one, at its calibration
    (`held_calibration`). `ConfigError` for any that cannot run."""
    configs = {d: cfg.in_direction(d) for d in descriptions}
    if REVERSE in configs:
        reverse = configs[REVERSE]
        configs[REVERSE] = replace(held_calibration(reverse) if FORWARD in configs else reverse,
                                   grid=replace(reverse.grid, seed=reverse_seed(cfg.grid.seed)))
    try:
        return {d: planned(configs[d], descriptions[d], configs[d].grid.seed, budget_min) for d in descriptions}
    except ConfigError as e:
        if budget_min is None or len(descriptions) == 1:
            raise
        raise ConfigError(f"{e} (each direction's share of --budget {budget_min * len(descriptions):g} min)") \
            from None


def _check_resumable(root: Path, direction: str, plan: CampaignPlan, trials: int | None) -> None:
    """`ConfigError` where the run of ``direction`` in ``root`` did not begin as ``plan`` would (its sealed
    campaign.toml, seed, trials and direction: `RunDir.read_settings`): an edited campaign.toml or quadrants.json
    must not plan the rest of a run."""
    path = root / direction
    settings = RunDir.read_settings(path)
    began = {"seed": plan.seed, "trials": trials, "direction": direction}
    changed = [key for key, value in began.items() if settings.get(key) != value]
    if (root / CONFIG_FILE).read_bytes() != (path / CONFIG_FILE).read_bytes():
        changed.insert(0, CONFIG_FILE)
    if changed:
        raise ConfigError(f"--resume {root}: {', '.join(changed)} not what {path} began with (its seal keeps them): "
                          f"put {root / CONFIG_FILE} and {root / QUADRANTS_FILE} back, or start a new run")


def _direction(direction: str, plan: CampaignPlan, backend: Backend, description: BenchDescription, root: Path,
               cfg: CampaignConfig, trials: int | None, budget_min: float | None, events: CampaignEvents,
               identify: Identifier | None,
               extra_stages: dict[str, Callable[[StageSetup], Stage]] | None) -> CampaignResult:
    """One direction's campaign in ``root``/``direction``: created, or resumed where it holds a run."""
    path = root / direction
    resume = (path / CONFIG_FILE).exists()
    lock: RunLock = RunDir.lock(path, new=not resume)
    try:
        run_dir = RunDir.resume(path, description, lock) if resume else \
            RunDir.create(path, description, config_text(cfg),
                          {"seed": plan.seed, "trials": trials, "budget_min": budget_min, "config": str(cfg.path),
                           "direction": direction}, lock, plan.static)
        return campaign_in(backend, description, run_dir, plan, resume, events, identify, extra_stages)
    finally:
        lock.release()
