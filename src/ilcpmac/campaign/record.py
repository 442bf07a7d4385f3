"""The record of one campaign trial: what summary.json and the live table show of it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ilcpmac.core.records import MAX_SPEED_HZ, MAX_TORQUE_NM
from ilcpmac.core.schema import shown
from ilcpmac.signals.harmonics import RippleFigures

__all__ = ["FIGURE_KEYS", "LEARN_PHASE", "Point", "TrialRecord", "number_in", "records_of"]

#: the learning phase's name, whatever stages learn in it
LEARN_PHASE = "learn"
#: its name in records of earlier releases when the ``ilc`` stage ran
_EARLIER_LEARN_PHASE = "ilc"

#: an operating point: (torque set point N m, speed set point Hz)
Point = tuple[float, float]

#: summary.json's key of each `RippleFigures` field; ``{}`` is "measured" or "true"
FIGURE_KEYS = (("pp", "ripple_pp_{}"), ("rms", "ripple_rms_{}"), ("rest_rms", "rest_rms_{}"),
               ("rms_repeatable", "ripple_rms_repeatable_{}"), ("amp_1x", "amp_1x_{}_nm"),
               ("amp_2x", "amp_2x_{}_nm"), ("amp_cogging", "amp_cogging_{}_nm"), ("amp_rest", "amp_rest_{}_nm"))


#: the largest ripple figure a record holds, as a fraction of the mean torque: a million times the mean, beyond any
#: trial (its N m figures are bounded by `MAX_TORQUE_NM`); and the largest reduction factor and motor time, s
MAX_RIPPLE_FRACTION = 1e6
MAX_REDUCTION_FACTOR = 1e15
MAX_MOTOR_TIME_S = 1e9
#: the largest mean torque error a record holds, relative (a summary with more was not written by a run)
MAX_MEAN_TORQUE_ERROR = 1e6


def number_in(data: dict[str, Any], key: str, low: float, high: float) -> float:
    """``data[key]`` as a float within [low, high]; `ValueError` naming ``key`` for anything else (a bool, text,
    NaN, a number beyond the range): what a reader of summary.json takes from it."""
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not low <= value <= high:
        raise ValueError(f"{key} is {shown(value)}, not a number within [{low:g}, {high:g}]")
    return float(value)


def optional_in(data: dict[str, Any], key: str, low: float, high: float) -> float | None:
    """`number_in`, or None where ``data`` has no ``key`` or holds null there."""
    return None if data.get(key) is None else number_in(data, key, low, high)


def _figures_json(kind: str, figures: RippleFigures | None) -> dict[str, Any]:
    return {} if figures is None else {key.format(kind): getattr(figures, name) for name, key in FIGURE_KEYS}


def _figures_from_json(kind: str, data: dict[str, Any]) -> RippleFigures | None:
    if FIGURE_KEYS[0][1].format(kind) not in data:
        return None
    return RippleFigures(**{name: number_in(data, key.format(kind), 0.0, MAX_TORQUE_NM if key.endswith("_nm")
                                            else MAX_RIPPLE_FRACTION) for name, key in FIGURE_KEYS})


@dataclass(frozen=True)
class TrialRecord:
    """One trial of a campaign (docs/campaign.md, summary.json).

    Attributes
    ----------
    index : int
        1-based, in the order trials ran.
    phase : str
        "identify", "compensate", "learn" or "validate" (records of earlier releases that named the learning
        phase "ilc" are read as "learn").
    role : str
        "grid", "baseline" (uncompensated, at a learned or a validation point), "compensate", "learn" or
        "validate" (the final compensation, no learning).
    torque_setpoint_nm, speed_setpoint_hz : float
    measured : RippleFigures or None
        Of the measured torque; None until the identification (which gives the mean it refers to).
    true : RippleFigures or None
        Of the true torque (simulator only).
    reduction_factor, reduction_factor_true : float or None
        The operating point's uncompensated peak-to-peak ripple over this trial's, measured and true
        (compensate, learn and validate trials; None where the trial's ripple is zero).
    motor_time_s : float or None
        How long the motor ran for it: warm-up and recorded revolutions at its speed set point, s
        (`CampaignPlan.bench_seconds`); None in records of earlier releases.
    mean_torque_error : float or None
        Its mean torque by the identified model over its torque set point, less 1 (`ilcpmac.stages.mean_torque`;
        docs/campaign.md, "The mean torque"); None before the identification and in records of earlier releases.
    """

    index: int
    phase: str
    role: str
    torque_setpoint_nm: float
    speed_setpoint_hz: float
    measured: RippleFigures | None = None
    true: RippleFigures | None = None
    reduction_factor: float | None = None
    reduction_factor_true: float | None = None
    motor_time_s: float | None = None
    mean_torque_error: float | None = None

    @property
    def learns(self) -> bool:
        """Whether the pipeline learns from this trial (the compensate and learn roles)."""
        return self.role in ("compensate", "learn")

    @property
    def point(self) -> Point:
        """Its operating point, (torque set point N m, speed set point Hz)."""
        return (self.torque_setpoint_nm, self.speed_setpoint_hz)

    @property
    def measured_ripple(self) -> RippleFigures:
        """`measured`, which every trial has from the identification on; `ValueError` for one before it."""
        if self.measured is None:
            raise ValueError(f"trial {self.index} has no measured ripple: it ran before the identification")
        return self.measured

    def figures(self, kind: str) -> RippleFigures | None:
        """`measured` or `true` by name."""
        return {"measured": self.measured, "true": self.true}[kind]

    def to_json(self) -> dict[str, Any]:
        """The record's object in summary.json (and states/trial_NNN.json); absent figures are left out."""
        out = {"index": self.index, "phase": self.phase, "role": self.role, "torque_setpoint": self.torque_setpoint_nm,
               "speed_setpoint": self.speed_setpoint_hz, **_figures_json("true", self.true),
               **_figures_json("measured", self.measured)}
        for f in ("reduction_factor", "reduction_factor_true", "motor_time_s", "mean_torque_error"):
            if getattr(self, f) is not None:
                out[f] = getattr(self, f)
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> TrialRecord:
        """The record `to_json` wrote; `ValueError` (or `KeyError`, `TypeError`) naming the key of a value no run
        writes (a number out of its range, text for a number, a missing key)."""
        index, phase, role = data["index"], data["phase"], data["role"]
        if isinstance(index, bool) or not isinstance(index, int) or index < 1:
            raise ValueError(f"index is {shown(index)}, not a trial's (1, 2, ...)")
        if not (isinstance(phase, str) and isinstance(role, str)):
            raise ValueError(f"phase {shown(phase)} and role {shown(role)} must be text")
        return cls(index, LEARN_PHASE if phase == _EARLIER_LEARN_PHASE else phase, role,
                   number_in(data, "torque_setpoint", -MAX_TORQUE_NM, MAX_TORQUE_NM),
                   number_in(data, "speed_setpoint", -MAX_SPEED_HZ, MAX_SPEED_HZ),
                   _figures_from_json("measured", data), _figures_from_json("true", data),
                   optional_in(data, "reduction_factor", 0.0, MAX_REDUCTION_FACTOR),
                   optional_in(data, "reduction_factor_true", 0.0, MAX_REDUCTION_FACTOR),
                   optional_in(data, "motor_time_s", 0.0, MAX_MOTOR_TIME_S),
                   optional_in(data, "mean_torque_error", -MAX_MEAN_TORQUE_ERROR, MAX_MEAN_TORQUE_ERROR))


def records_of(summary: dict[str, Any]) -> list[TrialRecord]:
    """The trial records of a summary.json, one per trial in the order they ran (trial k's index k); `ValueError`
    naming the trial otherwise (`TrialRecord.from_json`)."""
    records = []
    for k, data in enumerate(summary["trials"], start=1):
        if not isinstance(data, dict):
            raise ValueError(f"trials.{k - 1} is {shown(data)}, not a trial's object")
        try:
            record = TrialRecord.from_json(data)
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"trials.{k - 1}: {e}") from None
        if record.index != k:
            raise ValueError(f"trials.{k - 1}: index {record.index}, not {k} (the trials in the order they ran)")
        records.append(record)
    return records

