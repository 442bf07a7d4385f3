"""What a campaign tells its user interface (`CampaignEvents`): typed records, each with the line people read
(``text``), so that a program counts what happened by type and never parses the text."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from ilcpmac.campaign.plan import CampaignPlan
from ilcpmac.campaign.record import Point, TrialRecord
from ilcpmac.compensation import FadeOut
from ilcpmac.core.torque_source import TorqueSource

__all__ = ["CampaignEvents", "CampaignMessage", "CampaignStart", "CompensationBeatsNone", "CompensationWorse",
           "CompensationWritten", "GridStarted", "GuardEvent", "Identifying", "NoEvents", "PipelineNote", "Resumed"]


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

    def to_json(self) -> dict:
        """The trial state's "guard" object (states/trial_NNN.json)."""
        return {"set_point": self.set_point, "reverted_to_trial": self.reverted_to_trial,
                "learning_gain": self.learning_gain}

    @classmethod
    def from_json(cls, data: dict) -> GuardEvent:
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
class CompensationBeatsNone:
    """The validation found the compensation better than none at every point, ``learned`` and ``validated``."""

    learned: int
    validated: int

    @property
    def text(self) -> str:
        return (f"validate: the compensation beats none at every point ({self.learned} learned, {self.validated} "
                "validated)")


@dataclass(frozen=True)
class Resumed:
    """A resumed run: ``trials`` were already complete in ``path``."""

    trials: int
    path: Path

    @property
    def text(self) -> str:
        return f"resume: {self.trials} trials already complete in {self.path}"


#: what the campaign says between its trials
CampaignMessage = (GridStarted | Identifying | PipelineNote | GuardEvent | CompensationWritten | CompensationWorse
                   | CompensationBeatsNone | Resumed)


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
