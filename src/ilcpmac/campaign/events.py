"""What a campaign tells its user interface (`CampaignEvents`): typed records, each with the line people read
(``text``), so that a program counts what happened by type and never parses the text."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from ilcpmac.campaign.plan import CampaignPlan
from ilcpmac.campaign.record import Point, TrialRecord
from ilcpmac.campaign.validation import PointResult
from ilcpmac.compensation import FadeOut
from ilcpmac.core.torque_source import TorqueSource, TorqueSourceChoice

__all__ = ["CampaignEvents", "CampaignMessage", "CampaignStart", "CompensationBeatsNone", "CompensationWorse",
           "CompensationWritten", "DirectionsPlanned", "FloorsExpected", "GridStarted", "GuardEvent", "Identifying",
           "MeanTorqueUncertain", "NoEvents", "PipelineNote", "PlanStated", "Resumed", "TorqueSourceChosen"]


@dataclass(frozen=True)
class CampaignStart:
    """The campaign is about to run: its plan, run directory and torque source are fixed.

    Attributes
    ----------
    plan : the campaign's plan.
    path : its run directory.
    resumed : whether it continues a run (its records are loaded once it starts).
    torque_source : what the measured figures come from ([campaign] torque_source, resolved).
    """

    plan: CampaignPlan
    path: Path
    resumed: bool
    torque_source: TorqueSource


def minutes(seconds: float) -> str:
    """Motor time for people: "9.9 min"."""
    return f"{seconds / 60:.1f} min"


@dataclass(frozen=True)
class PlanStated:
    """Before the first trial (and on resume): the trials left and the motor's running time per phase, warm-ups
    included (`CampaignPlan.steps_left`).

    Attributes
    ----------
    trials : trials left per phase, phases in order.
    motor_time_s : the motor's running time left per phase, s.
    exact : False when learned points may stop early (`CampaignPlan.stops_early`): the figures are then at most.
    budget_s : the ``--budget`` the plan was sized to, s; None without one.
    scale : the trials after the grid against the config's (`CampaignConfig.with_trial_lengths`); 1 without a
        budget.
    recorded : (recorded, encoder) counts per revolution where the trials record fewer than the encoder has
        (`CampaignConfig.recorded_counts_per_rev`); None where they record every count.
    harmonics : [campaign] ripple_harmonics H, the band whose feed-forward the recorded resolution holds.
    """

    trials: dict[str, int]
    motor_time_s: dict[str, float]
    exact: bool = True
    budget_s: float | None = None
    scale: float = 1.0
    recorded: tuple[int, int] | None = None
    harmonics: int = 150

    @property
    def text(self) -> str:
        total = sum(self.motor_time_s.values())
        phases = ", ".join(f"{phase} {self.trials[phase]} trials {minutes(t)}"
                           for phase, t in self.motor_time_s.items())
        head = (f"plan: {sum(self.trials.values())} trials, {'at most ' if not self.exact else ''}{minutes(total)} "
                f"of motor time ({phases}; warm-ups included)")
        if self.recorded is not None:
            n, cpr = self.recorded
            held = math.sin(math.pi * self.harmonics / n) / (math.pi * self.harmonics / n)
            head += (f"\ntrials recorded at {n} of the encoder's {cpr} counts per revolution (every "
                     f"{cpr // n}th line); the feed-forward held over a recorded count delivers harmonic "
                     f"{self.harmonics} x {held:.4f}")
        if self.budget_s is None:
            return head
        return (f"{head}\nbudget {minutes(self.budget_s)}: the trials after the grid {self.scale:.2f}x the config's; "
                f"the final trials' noise floor {1 / self.scale**0.5:.2f}x the config plan's (it falls as one over "
                "the square root of a trial's duration; the floors expected are stated after the grid)")


@dataclass(frozen=True)
class DirectionsPlanned:
    """Before the first trial of a campaign in both directions (`ilcpmac.campaign.quadrants`): each direction's
    trials and motor time (its `PlanStated` follows as it starts), in the order they run.

    Attributes
    ----------
    trials : trials per direction.
    motor_time_s : the motor's running time per direction, warm-ups included, s.
    exact : False when learned points may stop early: the figures are then at most.
    """

    trials: dict[str, int]
    motor_time_s: dict[str, float]
    exact: bool = True

    @property
    def text(self) -> str:
        each = ", then ".join(f"{d} {self.trials[d]} trials {minutes(t)}" for d, t in self.motor_time_s.items())
        return (f"plan of both directions: {each}; {'at most ' if not self.exact else ''}"
                f"{minutes(sum(self.motor_time_s.values()))} of motor time in all (reverse as the motor's mirror "
                "image turning forward)")


@dataclass(frozen=True)
class FloorsExpected:
    """After the identification: the noise floor the final trials' own noise sets, predicted from the grid's
    (each point's nearest grid trial, its variance scaled by its duration over the final trial's), peak-to-peak as
    fractions of the mean torque (docs/campaign.md, "The noise floor"); the learning's part comes on top.

    Attributes
    ----------
    measured : (learned, validated) ranges (lowest, highest); None where there are no such points.
    true : the same for the true torque (simulator only); None without it.
    """

    measured: tuple[tuple[float, float] | None, tuple[float, float] | None]
    true: tuple[tuple[float, float] | None, tuple[float, float] | None] | None

    @property
    def text(self) -> str:
        def span(r: tuple[float, float] | None) -> str:
            return "-" if r is None else f"{100 * r[0]:.3g}-{100 * r[1]:.3g} %"

        parts = [f"{name} {span(self.measured[k])} measured" + ("" if self.true is None else
                                                                f", {span(self.true[k])} true")
                 for k, name in enumerate(("learned", "validation")) if self.measured[k] is not None]
        return "expected noise floor of the final trials (from the grid's noise): " + "; ".join(parts)


@dataclass(frozen=True)
class GridStarted:
    """The identification grid's trials start (again, after a resume within the grid)."""

    trials: int

    @property
    def text(self) -> str:
        return f"identify: {self.trials} multisine trials over the set-point grid"


@dataclass(frozen=True)
class Identifying:
    """The grid is done; the identification runs."""

    @property
    def text(self) -> str:
        return "identify: estimating delta*epsilon, delta, alpha, beta and cogging"


@dataclass(frozen=True)
class PipelineNote:
    """What the pipeline says (the limits clipping what a stage asked for)."""

    text: str


@dataclass(frozen=True)
class TorqueSourceChosen:
    """What measures the torque from the grid's identification on, and why (`TorqueSourceChoice`; "auto" decides
    it there)."""

    choice: TorqueSourceChoice

    @property
    def text(self) -> str:
        return self.choice.text


@dataclass(frozen=True)
class GuardEvent:
    """The guard acted: the measured ripple at ``set_point`` grew twice in a row, so its correction went back to
    that of trial ``reverted_to_trial`` and its learning gain was halved to ``learning_gain``."""

    set_point: str
    reverted_to_trial: int
    learning_gain: float

    @property
    def text(self) -> str:
        return (f"guard: measured ripple at {self.set_point} grew twice in a row; reverted to the correction of "
                f"trial {self.reverted_to_trial} and halved the learning gain to {self.learning_gain:g}")

    def to_json(self) -> dict[str, Any]:
        """The trial state's "guard" object (states/trial_NNN.json)."""
        return {"set_point": self.set_point, "reverted_to_trial": self.reverted_to_trial,
                "learning_gain": self.learning_gain}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> GuardEvent:
        """The event `to_json` wrote."""
        return cls(str(data["set_point"]), int(data["reverted_to_trial"]), float(data["learning_gain"]))


@dataclass(frozen=True)
class CompensationWritten:
    """Learning ended: the compensation over ``torques`` x ``speeds`` learned points is in ``file``."""

    phase: str
    torques: int
    speeds: int
    file: str

    @property
    def text(self) -> str:
        return (f"{self.phase}: the compensation over the learned points ({self.torques} torques x {self.speeds} "
                f"speeds) is in {self.file}")


@dataclass(frozen=True)
class CompensationWorse:
    """The validation found the compensation worse than none at ``points``; ``fade`` is the fade-out it got."""

    points: tuple[Point, ...]
    fade: FadeOut

    @property
    def text(self) -> str:
        where = ", ".join(f"{torque:g} N m at {speed:g} Hz" for torque, speed in self.points)
        applies = ("never applies" if self.fade.zero_hz == 0 else
                   f"fades it out from {self.fade.full_hz:g} Hz to {self.fade.zero_hz:g} Hz")
        return (f"validate: the compensation is WORSE than none at {where}; compensation.json {applies} "
                "(docs/export.md)")


@dataclass(frozen=True)
class MeanTorqueUncertain:
    """The mean torque is stated less surely than [campaign] mean_torque_tolerance at ``points``: each point and its
    stated standard uncertainty in N m (`PointMeanTorque`), the largest relative one first."""

    points: tuple[tuple[Point, float], ...]
    tolerance: float

    @property
    def text(self) -> str:
        (torque, speed), std_nm = self.points[0]
        return (f"mean torque: known to no better than {100 * self.tolerance:g} % of the set point "
                f"([campaign] mean_torque_tolerance) at {len(self.points)} point(s), at worst +- {std_nm:.3g} N m "
                f"({100 * std_nm / abs(torque):.2g} %) at {torque:g} N m, {speed:g} Hz: the split of delta eps into "
                "delta and eps, the given inertia and the identified loop carry it (a static trial pins eps: "
                "docs/real-bench.md, \"Pinning eps\")")


@dataclass(frozen=True)
class CompensationBeatsNone:
    """At every point, ``learned`` (their last trial) and ``validated``, the compensated trial's measured
    peak-to-peak ripple is below the uncompensated one's (`PointResult.worse` nowhere); the least reduction,
    ``least_reduction`` (inf: no ripple left), is at ``point``. Nothing more: the ripple at one harmonic may
    still have grown where the others fell further."""

    learned: int
    validated: int
    least_reduction: float
    point: Point

    @classmethod
    def of(cls, results: list[PointResult]) -> CompensationBeatsNone:
        """From the points' results, none of them worse (`PointResult.worse`)."""
        least = min(results, key=lambda r: r.reduction)
        validated = sum(not r.learned for r in results)
        return cls(len(results) - validated, validated, least.reduction, least.point)

    @property
    def text(self) -> str:
        return (f"validate: the measured peak-to-peak ripple is below the uncompensated trial's at every point, "
                f"{self.least_reduction:.3g}x at least ({self.point[0]:g} N m at {self.point[1]:g} Hz; "
                f"{self.learned} learned points, their last trial, and {self.validated} validated)")


@dataclass(frozen=True)
class Resumed:
    """A resumed run: ``trials`` were already complete in ``path``."""

    trials: int
    path: Path

    @property
    def text(self) -> str:
        return f"resume: {self.trials} trials already complete in {self.path}"


@dataclass(frozen=True)
class AlreadyComplete:
    """A resumed run had ended: no trial ran and no file changed."""

    path: Path

    @property
    def text(self) -> str:
        return f"the run in {self.path} had ended: nothing to do, no file changed"


#: what the campaign says between its trials
CampaignMessage = (PlanStated | DirectionsPlanned | GridStarted | Identifying | FloorsExpected | PipelineNote
                   | TorqueSourceChosen | GuardEvent | CompensationWritten | CompensationWorse | CompensationBeatsNone
                   | MeanTorqueUncertain | Resumed | AlreadyComplete)


class CampaignEvents(Protocol):
    """What the campaign tells its user interface."""

    def start(self, start: CampaignStart) -> None:
        """The campaign starts (`ilcpmac.campaign.service.run`, before its first trial)."""

    def trial(self, record: TrialRecord, records: list[TrialRecord]) -> None:
        """A trial finished (``records`` holds every trial so far, updated)."""

    def message(self, message: CampaignMessage) -> None:
        """Something worth saying (phase changes, the guard acting)."""

    def progress(self, fraction: float) -> None:
        """The running trial is ``fraction`` (0..1) done, where the backend reports it; called from any thread."""

    def end(self, how: str) -> None:
        """The campaign is over: "done", or "stopped" by an error (`ilcpmac.campaign.service.run`)."""


class NoEvents:
    """Campaign events that show nothing; subclass it to hear only some."""

    def start(self, start: CampaignStart) -> None:
        pass

    def trial(self, record: TrialRecord, records: list[TrialRecord]) -> None:
        pass

    def message(self, message: CampaignMessage) -> None:
        pass

    def progress(self, fraction: float) -> None:
        pass

    def end(self, how: str) -> None:
        pass
