"""The campaign's plan: its limits and grid, checked before anything runs, and which trial comes next.

The next trial is a function of the records of the trials done so far alone
(`CampaignPlan.next_step`), so ``--resume`` continues exactly where a run stopped.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ilcpmac.campaign.record import TrialRecord
from ilcpmac.config import CampaignConfig, check_bench
from ilcpmac.errors import ConfigError
from ilcpmac.pipeline.safety import SafetyLimits, check_plan, torque_violation, trust_edges
from ilcpmac.records import BenchDescription, TrialRequest
from ilcpmac.sim.grid import grid_plan, grid_requests
from ilcpmac.sim.simulator import trial_seed

__all__ = ["CampaignPlan", "Step", "base_request", "records_at"]


@dataclass(frozen=True)
class Step:
    """The next trial: its phase, its role in the phase and its unshaped request."""

    phase: str
    role: str
    request: TrialRequest


def base_request(config: CampaignConfig, description: BenchDescription, torque_nm: float,
                 seed: int) -> TrialRequest:
    """An uncompensated request at an ILC set point, with the bench's own calibration."""
    cpr = description.motor.counts_per_rev
    c = config.campaign
    return TrialRequest(torque_nm, c.ilc_speed_setpoint_hz, c.revolutions_at(torque_nm), np.zeros(cpr),
                        np.zeros(cpr), description.calibration, seed=seed)


def records_at(records: list[TrialRecord], torque_nm: float, roles: tuple[str, ...]) -> list[TrialRecord]:
    """The records of ``roles`` at the ILC set point ``torque_nm``, in order."""
    return [r for r in records if r.role in roles and r.torque_setpoint_nm == torque_nm]


@dataclass(frozen=True)
class CampaignPlan:
    """The limits of a campaign and its grid, checked against the bench before anything runs or is written.

    Attributes
    ----------
    config : the campaign.
    description : the bench.
    seed : trial k (1-based) is seeded with ``trial_seed(seed, k)``.
    limits : the config's limits, tightened by the bench's.
    grid : the identification grid's requests.
    """

    config: CampaignConfig
    description: BenchDescription
    seed: int
    limits: SafetyLimits
    grid: list[TrialRequest]

    @classmethod
    def build(cls, config: CampaignConfig, description: BenchDescription, seed: int) -> CampaignPlan:
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
        return cls(config, description, seed, limits, grid)

    def ilc_finished(self, records: list[TrialRecord], torque_nm: float) -> bool:
        """Whether the ILC phase at ``torque_nm`` is over: [campaign] ilc_trials done, or the measured
        repeatable ripple has not improved by min_improvement for patience trials."""
        c = self.config.campaign
        if len(records_at(records, torque_nm, ("ilc",))) >= c.ilc_trials:
            return True
        # judged on the repeatable part: at low torque the noise left in the average hides progress
        history = [r.measured.rms_repeatable for r in records_at(records, torque_nm, ("compensate", "ilc"))]
        if len(history) <= c.patience:
            return False
        best_before = min(history[: -c.patience])
        return all(p > (1.0 - c.min_improvement) * best_before for p in history[-c.patience:])

    def most_remaining(self, records: list[TrialRecord]) -> int:
        """The most trials that can follow ``records``: the grid, baselines and compensations left, and every
        unfinished ILC set point running to [campaign] ilc_trials."""
        c = self.config.campaign
        left = max(len(self.grid) - len(records), 0)
        for torque in c.ilc_torque_setpoints_nm:
            left += sum(not records_at(records, torque, (role,)) for role in ("baseline", "compensate"))
            if not self.ilc_finished(records, torque):
                left += c.ilc_trials - len(records_at(records, torque, ("ilc",)))
        return left

    def next_step(self, records: list[TrialRecord]) -> Step | None:
        """The trial after ``records`` (every trial done so far); None when the campaign is over."""
        n = len(records)
        if n < len(self.grid):
            return Step("identify", "grid", self.grid[n])
        setpoints = self.config.campaign.ilc_torque_setpoints_nm
        for role, phase in (("baseline", "identify"), ("compensate", "compensate")):
            for torque in setpoints:
                if not records_at(records, torque, (role,)):
                    return Step(phase, role, base_request(self.config, self.description, torque,
                                                          trial_seed(self.seed, n + 1)))
        for torque in setpoints:
            if not self.ilc_finished(records, torque):
                return Step("ilc", "ilc", base_request(self.config, self.description, torque,
                                                       trial_seed(self.seed, n + 1)))
        return None
