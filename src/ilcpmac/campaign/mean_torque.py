"""The mean torque of each learned and validation point's final trial: what the identification's model says the
shaft carried, with its standard error, and (on the simulator) the truth beside it (issue 38; docs/campaign.md,
"The mean torque").

The model's figure is `ilcpmac.stages.mean_torque.implied_mean_torque` of the trial's request at the speed it
ran at: no sensor of the bench measures the mean (the piezo sees none, the encoder only the viscous part), and the
learning never touches harmonic 0, so the mean is the set point's through the current sensors, the loop and the
back-EMF as identified.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ilcpmac.campaign.record import Point, number_in, optional_in
from ilcpmac.core.records import MAX_SPEED_HZ, MAX_TORQUE_NM
from ilcpmac.core.schema import shown
from ilcpmac.stages.mean_torque import MeanTorque

__all__ = ["MEAN_TORQUE_UNITS", "PointMeanTorque", "mean_torques_of"]

#: the keys of a point's entry in summary.json that `PointMeanTorque.to_json` writes, and their units
MEAN_TORQUE_UNITS = {
    "mean_torque_nm": "N m (the mean torque of the point's final trial by the identified model)",
    "mean_torque_std_nm": "N m (its standard error: eps's, the given inertia's and the loop's and winding's)",
    "mean_torque_backemf_nm": "N m (the part of it the current loop's tracking error to the back-EMF takes; null: "
                              "no winding identified, left out)",
    "mean_torque_saturation_nm": "N m (the part of it the saturation takes)",
    "mean_torque_inertia_std_nm": "N m (the part of its standard error the given inertia's makes; null: the bench "
                                  "states no [bench] inertia_uncertainty, left out, or a static trial pinned eps)",
    "mean_torque_epsilon_pinned": "true or false (whether a static trial pinned eps, [bench] static_trial_file)",
    "mean_torque_model_std_nm": "N m (the part of its standard error the identified loop's and winding's "
                                "parameters make; absent in a run before it was stated)",
    "mean_torque_true_nm": "N m (the simulator's true mean torque of that trial; null on a bench)"}


@dataclass(frozen=True)
class PointMeanTorque:
    """The mean torque of one point's final trial.

    Attributes
    ----------
    point : (torque N m, speed Hz).
    learned : whether the compensation was learned here.
    implied : the model's (`MeanTorque`).
    true_nm : the simulator's true mean, N m; None on a bench.
    """

    point: Point
    learned: bool
    implied: MeanTorque
    true_nm: float | None = None

    @property
    def error(self) -> float:
        """The model's mean over the set point, less 1."""
        return self.implied.error_of(self.point[0])

    @property
    def error_std(self) -> float:
        """Its standard error, relative to the set point."""
        return self.implied.std_nm / abs(self.point[0])

    @property
    def true_error(self) -> float | None:
        """The true mean over the set point, less 1 (None on a bench)."""
        return None if self.true_nm is None else self.true_nm / self.point[0] - 1.0

    def to_json(self) -> dict[str, Any]:
        """Its keys in summary.json's ``points`` entry of the point (`MEAN_TORQUE_UNITS`)."""
        return {"mean_torque_nm": self.implied.mean_nm, "mean_torque_std_nm": self.implied.std_nm,
                "mean_torque_backemf_nm": self.implied.backemf_loss_nm,
                "mean_torque_saturation_nm": self.implied.saturation_loss_nm,
                "mean_torque_inertia_std_nm": self.implied.inertia_std_nm, "mean_torque_true_nm": self.true_nm,
                "mean_torque_epsilon_pinned": self.implied.epsilon_pinned,
                "mean_torque_model_std_nm": self.implied.model_std_nm}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> PointMeanTorque | None:
        """The mean torque in summary.json's ``points`` entry ``data``; None in an entry without one (a run of an
        earlier release). `ValueError` naming the key for a value out of range."""
        if "mean_torque_nm" not in data:
            return None
        point = (number_in(data, "torque_setpoint", -MAX_TORQUE_NM, MAX_TORQUE_NM),
                 number_in(data, "speed_setpoint", -MAX_SPEED_HZ, MAX_SPEED_HZ))
        mean, saturation, std = (number_in(data, key, low, MAX_TORQUE_NM) for key, low in (
            ("mean_torque_nm", -MAX_TORQUE_NM), ("mean_torque_saturation_nm", -MAX_TORQUE_NM),
            ("mean_torque_std_nm", 0.0)))
        backemf, true = (optional_in(data, key, -MAX_TORQUE_NM, MAX_TORQUE_NM)
                         for key in ("mean_torque_backemf_nm", "mean_torque_true_nm"))
        inertia, model = (optional_in(data, key, 0.0, MAX_TORQUE_NM)
                          for key in ("mean_torque_inertia_std_nm", "mean_torque_model_std_nm"))
        pinned = data.get("mean_torque_epsilon_pinned", False)  # absent in a run before static trials
        for key, value in (("learned", data["learned"]), ("mean_torque_epsilon_pinned", pinned)):
            if not isinstance(value, bool):
                raise ValueError(f"{key} is {shown(value)}, not true or false")
        implied = MeanTorque(mean, std, backemf, saturation, inertia, pinned, model)
        return cls(point, data["learned"], implied, true)


def mean_torques_of(summary: dict[str, Any]) -> dict[Point, PointMeanTorque]:
    """The mean torque of every point of summary.json ``summary`` that has one, by point."""
    return {m.point: m for p in summary.get("points", []) if (m := PointMeanTorque.from_json(p)) is not None}
