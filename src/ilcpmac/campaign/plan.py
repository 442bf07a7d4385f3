"""The campaign's plan: its limits, grid and operating points, checked before anything runs, and which trial
comes next.

The next trial is a function of the records of the trials done so far alone
(`CampaignPlan.next_step`), so ``--resume`` continues exactly where a run stopped.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ilcpmac.bench.format import StaticTrial, check_bench, config_static_trial
from ilcpmac.campaign.grid import grid_plan, grid_requests
from ilcpmac.campaign.record import LEARN_PHASE, Point, TrialRecord
from ilcpmac.config import MIN_REVOLUTIONS, CampaignConfig
from ilcpmac.core.errors import ConfigError
from ilcpmac.core.records import BenchDescription, TrialRequest
from ilcpmac.core.seeds import trial_seed
from ilcpmac.core.torque_source import AUTO, ChoiceReason, TorqueSource, TorqueSourceChoice
from ilcpmac.pipeline.safety import SafetyLimits, check_plan, torque_violation, trust_edges

__all__ = ["INDEPENDENT_ROLES", "MAX_BUDGET_MIN", "CampaignPlan", "Step", "preset_choice", "records_at",
           "torque_source"]

#: roles of trials that neither learn nor depend on learning (the campaign runs them at once)
INDEPENDENT_ROLES = ("grid", "baseline", "validate")
#: the longest motor-time budget a plan takes (``--budget``), minutes: some 70 days of running
MAX_BUDGET_MIN = 1e5


@dataclass(frozen=True)
class Step:
    """The next trial: its phase, its role in the phase and its unshaped (uncompensated) request."""

    phase: str
    role: str
    request: TrialRequest


def preset_choice(config: CampaignConfig, description: BenchDescription) -> TorqueSourceChoice | None:
    """What measures the torque when it is fixed before the grid: [campaign] torque_source named, or "auto" on a
    bench without a torque sensor (the encoder) or with grid trials too short for the encoder's torque (fewer than
    `MIN_REVOLUTIONS`: the sensor); None where "auto" chooses after the grid (`choose_torque_source`).

    Raises `ConfigError` for a named source that reads a torque sensor the bench does not have, and for one that
    reads the encoder when the grid's trials record fewer than `MIN_REVOLUTIONS` (the encoder's torque needs two
    whole revolutions, and a trial need not begin at a revolution's start).
    """
    has_sensor = description.motor.torque_sensor
    short = config.grid.revolutions < MIN_REVOLUTIONS
    named = config.campaign.torque_source
    if named == AUTO:
        if has_sensor:
            return TorqueSourceChoice(TorqueSource.SENSOR, True, ChoiceReason.SHORT_GRID) if short else None
        chosen = TorqueSourceChoice(TorqueSource.ENCODER, True, ChoiceReason.NO_SENSOR)
    else:
        chosen = TorqueSourceChoice(TorqueSource(named), False, ChoiceReason.CONFIG)
    said = f" = {named!r}"
    if chosen.source.reads_sensor and not has_sensor:
        raise ConfigError(f"{config.path}: [campaign] torque_source{said}: the bench has no torque "
                          f'sensor (use "{TorqueSource.ENCODER.value}")')
    if chosen.source.reads_encoder and short:
        raise ConfigError(f"{config.path}: [trials] revolutions = {config.grid.revolutions}: [campaign] "
                          f"torque_source{said} reads the encoder's time stamps"
                          f"{' (the bench has no torque sensor)' if chosen.automatic else ''}, whose torque needs at "
                          f"least {MIN_REVOLUTIONS} recorded revolutions per trial (two whole ones); record more, or "
                          'use torque_source = "sensor"')
    return chosen


def torque_source(config: CampaignConfig, description: BenchDescription) -> TorqueSource:
    """What the grid is identified with and measured by: the `preset_choice`'s source, or "both" where "auto" chooses
    after the grid (the sensor's identification and the encoder's graduation error against it)."""
    preset = preset_choice(config, description)
    return TorqueSource.BOTH if preset is None else preset.source


def records_at(records: list[TrialRecord], point: Point, roles: tuple[str, ...]) -> list[TrialRecord]:
    """The records of ``roles`` at operating point ``point`` (torque N m, speed Hz), in order."""
    return [r for r in records if r.role in roles and r.point == point]


@dataclass(frozen=True)
class CampaignPlan:
    """The limits of a campaign, its grid and operating points, checked against the bench before anything
    runs or is written.

    Attributes
    ----------
    config : the campaign.
    description : the bench.
    seed : trial k (1-based) is seeded with ``trial_seed(seed, k)``.
    limits : the config's limits, tightened by the bench's.
    grid : the identification grid's requests.
    learned : the operating points learned at, (torque N m, speed Hz) (`CampaignConfig.learned_points`).
    validated : the operating points validated at (`CampaignConfig.validation_points`).
    static : the static trial of [bench] static_trial_file, which the identification takes eps from; None: none.
    """

    config: CampaignConfig
    description: BenchDescription
    seed: int
    limits: SafetyLimits
    grid: list[TrialRequest]
    learned: list[Point]
    validated: list[Point]
    budget_s: float | None = None
    scale: float = 1.0
    static: StaticTrial | None = None

    @classmethod
    def build(cls, config: CampaignConfig, description: BenchDescription, seed: int) -> CampaignPlan:
        """Check the bench against [bench] (`check_bench`) and every request the campaign will make: the grid,
        each operating point as its uncompensated trial runs it, and as the stages may run it (any calibration
        of the trust region); raise `ConfigError` naming the keys."""
        check_bench(config, description)
        torque_source(config, description)
        limits = SafetyLimits.of_campaign(config.limits, description.limits, config.grid.warmup_revolutions)
        grid = [replace(r, seed=trial_seed(seed, i + 1))
                for i, r in enumerate(grid_requests(config, description.calibration, seed, config.grid.revolutions))]
        plan = cls(config, description, seed, limits, grid, config.learned_points(), config.validation_points(),
                   static=config_static_trial(config, description.motor))
        points = [(f"{config.path}: [campaign] {kind}_torques_nm {t:g} N m at {kind}_speeds_hz {s:g} Hz, "
                   f"{kind}_revolutions {config.trial_revolutions(point)}", plan.base_request(point, 0))
                  for kind, chosen in (("learn", plan.learned), ("validate", plan.validated))
                  for point in chosen for t, s in [point]]
        check_plan([*grid_plan(config, grid), *points], description, limits)
        for place, request in points:
            for edge in trust_edges(limits):
                why = torque_violation(request.torque_reference_nm(), description.backemf_nm_per_a, limits, edge)
                if why is not None:
                    raise ConfigError(f"{place}: with a calibration at the edge of the trust region ([limits] "
                                      f"max_scale_deviation, max_offset_deviation_a): {why}")
        return plan

    @classmethod
    def within_budget(cls, config: CampaignConfig, description: BenchDescription, seed: int, budget_s: float
                      ) -> CampaignPlan:
        """The plan of ``config`` with its trials after the grid as long as fits ``budget_s`` of motor time
        (`CampaignConfig.with_trial_lengths`, in steps of 2^(1/8), from 1/64 to 16 times the config's; the
        longest that fits, and passes the limits). Raises `ConfigError` when even the shortest does not fit.

        Longer trials never take less motor time nor pass a limit the shorter broke, so the longest that fits is
        found by bisection (a plan of the seed bench takes some 40 ms to build and time: a scan of the 81 took 3 s).
        """
        def fitting(k: int) -> CampaignPlan | None:
            try:
                plan = cls.build(config.with_trial_lengths(2.0 ** (k / 8)), description, seed)
            except ConfigError:
                return None  # longer trials break a limit: longer still would too
            return plan if plan.motor_time_s() <= budget_s else None

        low, high = -48, 33  # fitting(low) is checked below; high stands for "too long"
        shortest = cls.build(config.with_trial_lengths(2.0 ** (low / 8)), description, seed)  # its error, if any
        best = shortest if shortest.motor_time_s() <= budget_s else None
        if best is None:
            phases = ", ".join(f"{phase} {t / 60:.1f}" for phase, t in shortest.bench_time_left([]).items())
            raise ConfigError(f"--budget {budget_s / 60:g} min: the shortest plan of {config.path} takes "
                              f"{shortest.motor_time_s() / 60:.1f} min of motor time ({phases} min)")
        while high - low > 1:
            middle = (low + high) // 2
            if (plan := fitting(middle)) is None:
                high = middle
            else:
                low, best = middle, plan
        return replace(best, budget_s=budget_s, scale=2.0 ** (low / 8))

    def motor_time_s(self) -> float:
        """The motor's running time of the whole plan, s (`bench_time_left` from the start)."""
        return sum(self.bench_time_left([]).values())

    def base_request(self, point: Point, seed: int, revolutions: int | None = None) -> TrialRequest:
        """An uncompensated request at ``point``, with the bench's own calibration, of ``revolutions`` (None: the
        point's longest trial, `CampaignConfig.trial_revolutions`)."""
        cpr = self.description.motor.counts_per_rev
        revolutions = self.config.trial_revolutions(point) if revolutions is None else revolutions
        return TrialRequest(point[0], point[1], revolutions, np.zeros(cpr), np.zeros(cpr),
                            self.description.calibration, seed=seed)

    def revolutions(self, records: list[TrialRecord], point: Point, role: str) -> int:
        """The revolutions of the next trial of ``role`` at ``point`` after ``records``: [campaign]
        baseline_revolutions uncompensated, the learning schedule's next (`CampaignConfig.trial_revolutions`)
        where the pipeline learns, the point's longest otherwise."""
        if role == "baseline":
            return self.config.campaign.baseline_revolutions
        if role in ("compensate", "learn"):
            return self.config.trial_revolutions(point, len(records_at(records, point, ("compensate", "learn"))))
        return self.config.trial_revolutions(point)

    def step(self, records: list[TrialRecord], phase: str, role: str, point: Point, seed: int) -> Step:
        """The step of ``role`` at ``point`` after ``records``, its request uncompensated (`base_request`)."""
        return Step(phase, role, self.base_request(point, seed, self.revolutions(records, point, role)))

    def bench_seconds(self, request: TrialRequest) -> float:
        """The motor's running time for ``request``: its warm-up and recorded revolutions at its speed, s."""
        return (self.config.grid.warmup_revolutions + request.revolutions) / request.speed_setpoint_hz

    def stops_early(self) -> bool:
        """Whether a learned point may stop before [campaign] learn_trials (patience below it)."""
        return self.config.campaign.patience < self.config.campaign.learn_trials

    def steps_left(self, records: list[TrialRecord]) -> list[Step]:
        """Every step after ``records``, in order, with every learned point still learning running to [campaign]
        learn_trials (`stops_early`: at most); their requests uncompensated, seeds 0."""
        steps: list[Step] = []
        done = list(records)
        finished = {p for p in self.learned if self.learn_finished(records, p)}
        while (step := self._next(done, finished, 0)) is not None:
            steps.append(step)
            done.append(TrialRecord(len(done) + 1, step.phase, step.role, step.request.torque_setpoint_nm,
                                    step.request.speed_setpoint_hz))
        return steps

    def bench_time_left(self, records: list[TrialRecord]) -> dict[str, float]:
        """The motor's running time of `steps_left` per phase, s (warm-up included), phases in order."""
        left: dict[str, float] = {}
        for step in self.steps_left(records):
            left[step.phase] = left.get(step.phase, 0.0) + self.bench_seconds(step.request)
        return left

    def learn_finished(self, records: list[TrialRecord], point: Point) -> bool:
        """Whether learning at ``point`` is over: [campaign] learn_trials done, or the measured repeatable
        ripple has not improved by min_improvement for patience trials."""
        c = self.config.campaign
        if len(records_at(records, point, ("learn",))) >= c.learn_trials:
            return True
        # judged on the repeatable part: at low torque the noise left in the average hides progress
        history = [r.measured_ripple.rms_repeatable for r in records_at(records, point, ("compensate", "learn"))]
        if len(history) <= c.patience:
            return False
        best_before = min(history[: -c.patience])
        return all(p > (1.0 - c.min_improvement) * best_before for p in history[-c.patience:])

    def most_remaining(self, records: list[TrialRecord]) -> int:
        """The most trials that can follow ``records``: the grid, uncompensated and compensation trials left,
        every unfinished learned point running to [campaign] learn_trials, and the validation trials left
        (`steps_left`)."""
        return len(self.steps_left(records))

    def independent_steps(self, records: list[TrialRecord]) -> list[Step]:
        """The steps after ``records`` up to the next that learns or depends on learning: grid, uncompensated
        and validation trials (`INDEPENDENT_ROLES`), which may run at once; their requests and seeds are those
        `next_step` gives one by one. The grid's steps come alone: what follows them waits for the
        identification, which also bounds the current that flows (`LimitGuard`)."""
        steps: list[Step] = []
        done = list(records)
        while (step := self.next_step(done)) is not None and step.role in INDEPENDENT_ROLES:
            if steps and (step.role == "grid") != (steps[0].role == "grid"):
                break
            steps.append(step)
            done.append(TrialRecord(len(done) + 1, step.phase, step.role, step.request.torque_setpoint_nm,
                                    step.request.speed_setpoint_hz))
        return steps

    def learning_round(self, records: list[TrialRecord]) -> tuple[int, list[Step]]:
        """The steps left in the current round of the compensate or learning phase, and how many records came
        before the round began (``len(records)`` when none of it has run); no steps in any other phase.

        A round is one trial at every learned point still learning (`learn_finished`), in the plan's order;
        the compensation trials are the first. Its requests are shaped from the pipeline as it stood when the
        round began, so its trials may run at once; the pipeline learns from them in the plan's order. The
        steps and seeds are those `next_step` gives one by one.
        """
        step = self.next_step(records)
        if step is None or step.role not in ("compensate", "learn"):
            return len(records), []
        if step.role == "compensate":
            left = [p for p in self.learned if not records_at(records, p, ("compensate",))]
            begun = len(records) - sum(r.role == "compensate" for r in records)
        else:
            counts = {p: len(records_at(records, p, ("learn",))) for p in self.learned}
            learning = [p for p in self.learned if not self.learn_finished(records, p)]
            lap = min(counts[p] for p in learning)
            left = [p for p in learning if counts[p] == lap]
            begun = len(records) - sum(counts[p] == lap + 1 for p in self.learned)
        return begun, [self.step(records, step.phase, step.role, point, trial_seed(self.seed, len(records) + k))
                       for k, point in enumerate(left, start=1)]

    def next_step(self, records: list[TrialRecord]) -> Step | None:
        """The trial after ``records`` (every trial done so far); None when the campaign is over.

        Order: the grid; an uncompensated trial at every learned point; a compensation trial at each; learning
        in rounds (`learning_round`): the next trial at the point still learning with the fewest learning
        trials, the first such in the plan's order; then, per validation point, an uncompensated and a
        compensated trial.
        """
        finished = {p for p in self.learned if self.learn_finished(records, p)}
        return self._next(records, finished, trial_seed(self.seed, len(records) + 1))

    def _next(self, records: list[TrialRecord], finished: set[Point], seed: int) -> Step | None:
        """`next_step`, the learned points in ``finished`` (and those at learn_trials) done learning."""
        n = len(records)
        if n < len(self.grid):
            return Step("identify", "grid", self.grid[n])
        for role, phase in (("baseline", "identify"), ("compensate", "compensate")):
            for point in self.learned:
                if not records_at(records, point, (role,)):
                    return self.step(records, phase, role, point, seed)
        counts = {p: len(records_at(records, p, ("learn",))) for p in self.learned}
        learning = {p: n for p, n in counts.items() if p not in finished and n < self.config.campaign.learn_trials}
        if learning:
            point = min(learning, key=learning.__getitem__)  # the first of the fewest: dicts keep the plan's order
            return self.step(records, LEARN_PHASE, "learn", point, seed)
        for point in self.validated:
            for role in ("baseline", "validate"):
                if not records_at(records, point, (role,)):
                    return self.step(records, "validate", role, point, seed)
        return None
