"""The record of one campaign trial: what summary.json and the live table show of it."""

from __future__ import annotations

from dataclasses import dataclass

from ilcpmac.signals.harmonics import RippleFigures

__all__ = ["FIGURE_KEYS", "LEARN_PHASE", "Point", "TrialRecord", "records_of"]

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


def _figures_json(kind: str, figures: RippleFigures | None) -> dict:
    return {} if figures is None else {key.format(kind): getattr(figures, name) for name, key in FIGURE_KEYS}


def _figures_from_json(kind: str, data: dict) -> RippleFigures | None:
    if FIGURE_KEYS[0][1].format(kind) not in data:
        return None
    return RippleFigures(**{name: float(data[key.format(kind)]) for name, key in FIGURE_KEYS})


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

    def to_json(self) -> dict:
        """The record's object in summary.json (and states/trial_NNN.json); absent figures are left out."""
        out = {"index": self.index, "phase": self.phase, "role": self.role, "torque_setpoint": self.torque_setpoint_nm,
               "speed_setpoint": self.speed_setpoint_hz, **_figures_json("true", self.true),
               **_figures_json("measured", self.measured)}
        for f in ("reduction_factor", "reduction_factor_true", "motor_time_s"):
            if getattr(self, f) is not None:
                out[f] = getattr(self, f)
        return out

    @classmethod
    def from_json(cls, data: dict) -> TrialRecord:
        """The record `to_json` wrote."""
        phase = str(data["phase"])
        return cls(int(data["index"]), LEARN_PHASE if phase == _EARLIER_LEARN_PHASE else phase, str(data["role"]),
                   float(data["torque_setpoint"]), float(data["speed_setpoint"]), _figures_from_json("measured", data),
                   _figures_from_json("true", data), data.get("reduction_factor"), data.get("reduction_factor_true"),
                   data.get("motor_time_s"))


def records_of(summary: dict) -> list[TrialRecord]:
    """The trial records of a summary.json."""
    return [TrialRecord.from_json(t) for t in summary["trials"]]

