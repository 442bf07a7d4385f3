"""What the run directory keeps besides the trials: the state saved with each trial (states/trial_NNN.json) and
what each stage feeds forward when learning ends (states/learned.json), as typed records.

`RunDir` writes them and `RunFiles` reads them back (`ilcpmac.campaign.rundir`); ``from_json`` raises
`KeyError`, `TypeError`, `ValueError` or `AttributeError` on a malformed object, which `RunFiles` reports
as a `RunDirError` naming the file.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ilcpmac.campaign.events import GuardEvent
from ilcpmac.campaign.record import TrialRecord
from ilcpmac.core.records import SensorCalibration, TrialRequest

__all__ = ["LearnedPoint", "TrialState", "learned_from_json", "learned_json"]

#: every stage's state by name (`ilcpmac.pipeline.pipeline.Pipeline.state`)
StageStates = dict[str, dict[str, Any]]


@dataclass(frozen=True, eq=False)
class TrialState:
    """What is saved with a trial: enough to continue the campaign after it (``ilcpmac run --resume``).

    Attributes
    ----------
    record : the trial's record (its ripple figures).
    pipeline : every stage's state after learning from the trial; None before the pipeline started.
    gains : the learning gain of each set point the guard has halved (`GuardEvent`), by set-point key.
    guard : what the guard did after the trial, or None.
    calibration, feedforward_nm : of the request the trial ran (shaped by the pipeline).
    revolutions, seed : of the request the plan asked for.
    """

    record: TrialRecord
    pipeline: StageStates | None
    gains: dict[str, float]
    guard: GuardEvent | None
    calibration: SensorCalibration
    feedforward_nm: np.ndarray
    revolutions: int
    seed: int

    @property
    def stages(self) -> StageStates:
        """`pipeline`, of a trial after the pipeline started; `ValueError` for one before it."""
        if self.pipeline is None:
            raise ValueError(f"trial {self.record.index} ran before the pipeline started: no stage states")
        return self.pipeline

    def ran(self) -> TrialRequest:
        """The request the trial ran, as saved: its set point, revolutions, seed, calibration and feed-forward (its
        excitation zero, which a trial after the grid's is)."""
        record = self.record
        return TrialRequest(record.torque_setpoint_nm, record.speed_setpoint_hz, self.revolutions,
                            feedforward_nm=self.feedforward_nm, excitation_nm=np.zeros_like(self.feedforward_nm),
                            calibration=self.calibration, seed=self.seed)

    def to_json(self) -> dict[str, Any]:
        """The object of states/trial_NNN.json."""
        return {"record": self.record.to_json(), "pipeline": self.pipeline, "gains": self.gains,
                "guard": None if self.guard is None else self.guard.to_json(),
                "request": {"calibration": self.calibration.to_json(), "feedforward_nm": self.feedforward_nm.tolist(),
                            "revolutions": self.revolutions, "seed": self.seed}}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> TrialState:
        """The state `to_json` wrote."""
        request, guard, pipeline = data["request"], data["guard"], data["pipeline"]
        if pipeline is not None and not isinstance(pipeline, dict):
            raise TypeError(f"pipeline holds {type(pipeline).__name__}, not an object")
        return cls(TrialRecord.from_json(data["record"]), pipeline,
                   {str(key): float(gain) for key, gain in data["gains"].items()},
                   None if guard is None else GuardEvent.from_json(guard),
                   SensorCalibration.from_json(request["calibration"]),
                   np.asarray(request["feedforward_nm"], float), int(request["revolutions"]), int(request["seed"]))


@dataclass(frozen=True, eq=False)
class LearnedPoint:
    """What each stage feeds forward at one learned point, as the point's last trial left the stages.

    Attributes
    ----------
    trial : the point's last trial (compensate or learn), 1-based.
    tables_nm : each stage's own feed-forward per encoder count, N m, in the pipeline's order (zero for a
        stage that feeds nothing forward): what it adds to a request at the point (`of`).
    """

    trial: int
    tables_nm: dict[str, np.ndarray]

    @classmethod
    def of(cls, trial: int, request: TrialRequest, shaped: list[tuple[str, TrialRequest]]) -> LearnedPoint:
        """What each stage adds to the feed-forward of ``request`` (one at the point) as it passes through them:
        ``shaped``, each stage's name and answer in turn (`Pipeline.stage_by_stage`)."""
        tables = {}
        for name, answer in shaped:
            tables[name] = answer.feedforward_nm - request.feedforward_nm
            request = answer
        return cls(trial, tables)

    def to_json(self) -> dict[str, Any]:
        """Its object in states/learned.json's ``points``."""
        return {"trial": self.trial, "tables_nm": {name: table.tolist() for name, table in self.tables_nm.items()}}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> LearnedPoint:
        """The point `to_json` wrote."""
        return cls(int(data["trial"]), {str(name): np.asarray(table, float)
                                        for name, table in data["tables_nm"].items()})


def learned_json(points: list[LearnedPoint]) -> dict[str, Any]:
    """The object of states/learned.json."""
    return {"points": [point.to_json() for point in points]}


def learned_from_json(data: dict[str, Any]) -> list[LearnedPoint]:
    """The points `learned_json` wrote."""
    return [LearnedPoint.from_json(point) for point in data["points"]]
