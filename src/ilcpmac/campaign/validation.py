"""What the validation phase concludes: the ripple at operating points never learned, and where the
compensation applies.

Each validation point has an uncompensated trial and one with the final compensation (no learning). The
fade-out rule (docs/export.md) retires the compensation over speed where any point, learned or validated,
shows it worse than none: judged on the measured ripple, which a real bench has (the simulator's true ripple
is reported beside it). With W the slowest speed of a point that is worse (its measured peak-to-peak ripple at
least its uncompensated trial's) and F the fastest point speed below W, the feed-forward applies fully up to F
and fades linearly to zero at W (at the slowest speed: it never applies); with no such point it never fades.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from ilcpmac.campaign.record import Point, TrialRecord, records_of
from ilcpmac.compensation import FadeOut

__all__ = ["PointResult", "fade_out", "point_results", "results_of"]


@dataclass(frozen=True)
class PointResult:
    """The compensation at one operating point, against none.

    Attributes
    ----------
    point : (torque N m, speed Hz).
    learned : whether the compensation was learned here (else validated only).
    before, after : the uncompensated trial and the compensated one (a learned point's last).
    """

    point: Point
    learned: bool
    before: TrialRecord
    after: TrialRecord

    @property
    def worse(self) -> bool:
        """Whether the compensation leaves at least as much measured peak-to-peak ripple as none."""
        return self.after.measured_ripple.pp >= self.before.measured_ripple.pp

    @property
    def reduction(self) -> float:
        """The uncompensated trial's measured peak-to-peak ripple over the compensated one's (inf where that is
        0)."""
        after = self.after.measured_ripple.pp
        return self.before.measured_ripple.pp / after if after > 0 else math.inf

    def to_json(self) -> dict[str, Any]:
        """Its object in summary.json's ``validation`` list (ripple as fractions of the mean torque)."""
        out = {"torque_setpoint": self.point[0], "speed_setpoint": self.point[1], "learned": self.learned,
               "uncompensated_trial": self.before.index, "compensated_trial": self.after.index}
        for kind in ("measured", "true"):
            before, after = self.before.figures(kind), self.after.figures(kind)
            if before is not None and after is not None:
                out[f"uncompensated_pp_{kind}"] = before.pp
                out[f"ripple_pp_{kind}"] = after.pp
        for key in ("reduction_factor", "reduction_factor_true"):
            if getattr(self.after, key) is not None:
                out[key] = getattr(self.after, key)
        out["worse_than_uncompensated"] = self.worse
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any], trials: dict[int, TrialRecord]) -> PointResult:
        """The result `to_json` wrote, its two trials taken from ``trials`` (by index); `ValueError` naming the key
        of a trial that is not among them."""
        pair = []
        for key in ("uncompensated_trial", "compensated_trial"):
            if (trial := trials.get(data[key])) is None:
                raise ValueError(f"{key} {data[key]!r} is not a trial of the summary")
            pair.append(trial)
        return cls((float(data["torque_setpoint"]), float(data["speed_setpoint"])), bool(data["learned"]), *pair)


def _pair(records: list[TrialRecord], point: Point, roles: tuple[str, ...]) -> tuple[TrialRecord, TrialRecord] | None:
    before = [r for r in records if r.point == point and r.role == "baseline"]
    after = [r for r in records if r.point == point and r.role in roles]
    if not before or not after or before[0].measured is None or after[-1].measured is None:
        return None
    return before[0], after[-1]


def point_results(records: list[TrialRecord], learned: list[Point], validated: list[Point]) -> list[PointResult]:
    """Each learned and validated point whose trials are done, learned points first."""
    out = []
    for points, roles, is_learned in ((learned, ("compensate", "learn"), True), (validated, ("validate",), False)):
        for point in points:
            pair = _pair(records, point, roles)
            if pair is not None:
                out.append(PointResult(point, is_learned, *pair))
    return out


def results_of(summary: dict[str, Any]) -> list[PointResult]:
    """The results of summary.json ``summary``'s ``points``, learned points first (`PointResult.from_json`, with the
    trials of its ``trials``: `records_of`)."""
    points = summary.get("points", [])
    trials = {r.index: r for r in records_of(summary)} if points else {}
    return [PointResult.from_json(p, trials) for p in points]


def fade_out(results: list[PointResult]) -> FadeOut:
    """The fade-out over speed of the module docstring."""
    worse = [r.point[1] for r in results if r.worse]
    if not worse:
        return FadeOut(math.inf, math.inf)
    zero_hz = min(worse)
    below = [r.point[1] for r in results if r.point[1] < zero_hz]
    if not below:  # worse already at the slowest speed: it never applies
        return FadeOut(0.0, 0.0)
    return FadeOut(max(below), zero_hz)
