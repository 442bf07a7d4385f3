"""The noise floor of each operating point: the least peak-to-peak ripple its trials can reach and show
(docs/campaign.md, "The noise floor").

Two noises, and what the trials cannot resolve, bound what a point ends at:

- the **final trial's own noise** (what it can show): the non-repeatable part of the torque left in its
  synchronous average, of variance v_h per harmonic (its revolution-to-revolution scatter over the number of
  revolutions, pooled with the neighbouring harmonics': `TorqueSpectrum.variance_nm2`); for the true torque on
  the simulator that is the current sensors' noise reaching it through the loop, for the measured one the torque
  sensor's or the encoder torque's noise;
- the **learning** (what it can reach): the ripple with no feed-forward, d, is estimated from the trials
  learned from before the final one, each trial's measured harmonics less the torque its feed-forward delivered
  through the identified response, both at the speed it ran at (`PointSpectra.of`, `RippleEstimate`), no better
  than their inverse-variance mean, of variance
  P_h = 1 / sum_k (1 / v_k,h). A learner learns a harmonic where the data show it (`stands_out`, `SIGNIFICANCE`
  standard deviations) and leaves the rest (`learning_floors`): where the learned points' mean stands out, what
  they share, at the pooled variance A_h (the ilc stage pools them); where a point's own ripple stands out of
  that, at its own P_h; and what stands out nowhere stays, its power estimated from the estimates
  (`unresolved_power`): what the points share from their mean, what each has of its own over all of them at
  once (`_own_unresolved`). Per harmonic this is about the Wiener bound D P / (D + P) of a ripple of power D: the
  least mean-square error of any learner that knew D.

The floor is the expected peak-to-peak of independent harmonics of variance v_h plus the learning's over the
band 1..H (`expected_noise_pp`), as a fraction of the mean torque. A validation point learns nothing: its
learning part is that of the learned points its feed-forward is interpolated from, weighted as the compensation
weighs their tables (`interpolation_weights`): their learning noise w^2, the ripple they left w (it is there
too); and the feed-forward there is an interpolation, whose error no trial removes: the floor's harmonics are
centred on the torque the ideal feed-forward there, u*, would deliver beyond the bilinear one, G^ (u* - u)
(`interpolation_error`), not on zero. Along an axis of three or more learned points, u* is the quadratic through
the three nearest tables (their curvature shows the loop's and the ripple's alike); along a speed axis of one or
two, it is what each table cancels, G^(f_p) u_p, seen through the identified response at the point's speed,
G^(f_p) / G^(f) u_p, interpolated as the compensation does: the ripple the tables cancel is taken as linear in
speed between them, and its curvature in speed (the back-EMF's tracking error through the loop, say) is left out.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ilcpmac.campaign.record import MAX_RIPPLE_FRACTION, Point, number_in, optional_in
from ilcpmac.compensation import interpolation_weights
from ilcpmac.core.records import MAX_SPEED_HZ, MAX_TORQUE_NM, TrialData, TrialRequest
from ilcpmac.core.schema import shown
from ilcpmac.pipeline.analysis import TorqueSpectrum
from ilcpmac.signals.harmonics import expected_noise_pp, harmonic_amplitudes

if TYPE_CHECKING:
    from ilcpmac.pipeline.analysis import TorqueMeasurement, TrialAnalysis
    from ilcpmac.pipeline.pipeline import Pipeline

__all__ = ["SIGNIFICANCE", "LearningFloor", "PointFloor", "PointSpectra", "Response", "RippleEstimate", "floors_of",
           "interpolation_error", "learning_floors", "point_floors", "stands_out", "unresolved_power"]

#: standard deviations an estimated harmonic stands out by to count as ripple a learner learns (`stands_out`)
SIGNIFICANCE = 2.0
#: learned points from which on what they share is learned pooled (`learning_floors`; the ilc stage's
#: `POOLED_MIN`)
POOLED_POINTS = 3


@dataclass(frozen=True)
class PointSpectra:
    """What the floor of a point needs of one of its trials: its measured spectrum in true-torque units
    (`TorqueMeasurement.in_true_units`) and the measurement's mean torque, N m; its true spectrum and mean
    (simulator only); the harmonics 0..H of the torque its feed-forward delivered through the identified response,
    G^ u, N m (`Pipeline.delivered_nm`; None: none); the speed it ran at, Hz (its mean over the trial)."""

    measured: TorqueSpectrum
    mean_nm: float
    true: TorqueSpectrum | None = None
    true_mean_nm: float | None = None
    delivered_nm: np.ndarray | None = None
    speed_hz: float | None = None

    @classmethod
    def of(cls, ran: TrialRequest, trial: TrialData, analysis: TrialAnalysis, measurement: TorqueMeasurement,
           pipeline: Pipeline) -> PointSpectra:
        """Of a ``trial`` that ran ``ran``, from its ``analysis``: converted and its feed-forward's torque taken at
        the trial's mean speed, as the stages take them (`Pipeline.frame`), not at its set point's."""
        assert analysis.measured is not None
        speed_hz = trial.mean_speed_hz(analysis.measured.counts_per_rev)
        measured = measurement.in_true_units(analysis.measured, speed_hz, ran.calibration)
        return cls(measured, measurement.mean_torque_nm(ran), analysis.true, analysis.true_mean_nm,
                   pipeline.delivered_nm(ran, speed_hz)[: measured.max_harmonic + 1], speed_hz)


@dataclass(frozen=True)
class PointFloor:
    """The noise floor of one operating point, peak-to-peak as fractions of the mean torque.

    Attributes
    ----------
    point : (torque N m, speed Hz).
    learned : whether the compensation was learned here.
    measured_pp : of the measured ripple.
    true_pp : of the true ripple (simulator only), else None.
    """

    point: Point
    learned: bool
    measured_pp: float
    true_pp: float | None

    def to_json(self) -> dict[str, Any]:
        """Its keys in summary.json's ``points`` entry of the point."""
        out = {"floor_pp_measured": self.measured_pp}
        if self.true_pp is not None:
            out["floor_pp_true"] = self.true_pp
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> PointFloor | None:
        """The floor in summary.json's ``points`` entry ``data`` (`to_json` beside the point's results); None in
        an entry without one (a run of an earlier release)."""
        if "floor_pp_measured" not in data:
            return None
        point = (number_in(data, "torque_setpoint", -MAX_TORQUE_NM, MAX_TORQUE_NM),
                 number_in(data, "speed_setpoint", -MAX_SPEED_HZ, MAX_SPEED_HZ))
        if not isinstance(data["learned"], bool):
            raise ValueError(f"learned is {shown(data['learned'])}, not true or false")
        true = optional_in(data, "floor_pp_true", 0.0, MAX_RIPPLE_FRACTION)
        return cls(point, data["learned"], number_in(data, "floor_pp_measured", 0.0, MAX_RIPPLE_FRACTION), true)

    def pp(self, kind: str) -> float | None:
        """`measured_pp` or `true_pp` by name ("measured", "true")."""
        return {"measured": self.measured_pp, "true": self.true_pp}[kind]


def floors_of(summary: dict[str, Any]) -> dict[Point, PointFloor]:
    """The floor of every point of summary.json ``summary`` that has one, by point (`PointFloor.from_json`)."""
    return {floor.point: floor for p in summary.get("points", []) if (floor := PointFloor.from_json(p)) is not None}


@dataclass(frozen=True)
class RippleEstimate:
    """What the trials a point learned from tell of its ripple with no feed-forward, d, per harmonic 0..H.

    Attributes
    ----------
    estimate_nm : the inverse-variance mean d^ of their harmonics less what their feed-forward delivered
        (`PointSpectra.delivered_nm`), N m.
    variance_nm2 : its variance P = 1 / sum_k 1 / v_k, N m^2.
    """

    estimate_nm: np.ndarray
    variance_nm2: np.ndarray

    @classmethod
    def of(cls, learned_from: list[PointSpectra]) -> RippleEstimate:
        """From the trials ``learned_from`` (true units)."""
        weights = [1.0 / np.maximum(t.measured.variance_nm2, 1e-300) for t in learned_from]
        P = 1.0 / sum(weights)
        unforced = [t.measured.harmonics_nm - (0.0 if t.delivered_nm is None else t.delivered_nm)
                    for t in learned_from]
        return cls(sum(w * d for w, d in zip(weights, unforced)) * P, P)


def stands_out(estimate_nm: np.ndarray, variance_nm2: np.ndarray) -> np.ndarray:
    """Where ``estimate_nm`` stands out of its noise at `SIGNIFICANCE` (never at h = 0)."""
    out: np.ndarray = np.abs(estimate_nm) ** 2 > SIGNIFICANCE**2 * variance_nm2
    out[0] = False
    return out


def _excess_power(residual_nm: np.ndarray, variance_nm2: np.ndarray, quiet: np.ndarray) -> float:
    """sum (|r_h|^2 - m V_h) over the ``quiet`` harmonics, N m^2 (may be negative): the power of the ripple
    ``residual_nm`` (of noise ``variance_nm2``) where it did not stand out (`stands_out`), m = E[X | X <
    SIGNIFICANCE^2] for X ~ Exp(1), what the noise leaves there given it did not stand out."""
    k2 = SIGNIFICANCE**2
    m = (1.0 - (1.0 + k2) * np.exp(-k2)) / (1.0 - np.exp(-k2))
    return float(np.sum(np.abs(residual_nm[quiet]) ** 2 - m * variance_nm2[quiet]))


def unresolved_power(residual_nm: np.ndarray, variance_nm2: np.ndarray, quiet: np.ndarray) -> np.ndarray:
    """The power of the ripple ``residual_nm`` (of noise ``variance_nm2``) at the ``quiet`` harmonics, where it did
    not stand out, N m^2 per harmonic: `_excess_power`, at least 0, spread over them as V_h. Per harmonic, with
    what stands out counted at V_h, about the Wiener bound D V / (D + V) of a ripple of power D
    (docs/campaign.md)."""
    return _spread(max(0.0, _excess_power(residual_nm, variance_nm2, quiet)), variance_nm2, quiet)


def _spread(power_nm2: float, variance_nm2: np.ndarray, quiet: np.ndarray) -> np.ndarray:
    """``power_nm2`` spread over the ``quiet`` harmonics as their noise ``variance_nm2``, N m^2 per harmonic."""
    return np.where(quiet, power_nm2 * variance_nm2 / max(float(np.sum(variance_nm2[quiet])), 1e-300), 0.0)


@dataclass(frozen=True)
class LearningFloor:
    """The learning's part of a learned point's floor, N m^2 per harmonic 0..H (`learning_floors`).

    Attributes
    ----------
    noise_nm2 : what the learned harmonics keep of the noise they were learned with.
    unresolved_nm2 : the ripple no trial resolved, which stays.
    """

    noise_nm2: np.ndarray
    unresolved_nm2: np.ndarray

    @property
    def total_nm2(self) -> np.ndarray:
        total: np.ndarray = self.noise_nm2 + self.unresolved_nm2
        return total


def learning_floors(estimates: dict[Point, RippleEstimate]) -> dict[Point, LearningFloor]:
    """The learning part of each learned point's floor: the error of a learner that learns a harmonic where the
    data show it, and leaves the rest.

    Shared by the points (`POOLED_POINTS` or more): where their inverse-variance mean s^ (variance A) stands out,
    a learner that pools them (the ilc stage) learns it at A. At a point: where d^_p - s^ (or d^_p where nothing
    is shared; variance V = P_p - A, or P_p) stands out, the point's own at P_p; elsewhere the ripple stays.
    What stays has two parts, each estimated where its noise is least (`unresolved_power`, `_own_unresolved`):
    what the points share, where s^ did not stand out, from s^ (noise A: a ninth of a point's, over nine
    points); what each point has of its own, d^_p - s^, as one power per harmonic over every point's
    estimates (docs/campaign.md).
    """
    first = next(iter(estimates.values()))
    shared, mean = np.zeros(first.estimate_nm.shape, complex), np.zeros(first.estimate_nm.shape, complex)
    A = np.zeros(first.variance_nm2.shape)
    if len(estimates) >= POOLED_POINTS:
        weights = {point: 1.0 / np.maximum(e.variance_nm2, 1e-300) for point, e in estimates.items()}
        A = 1.0 / sum(weights.values())
        mean = sum(weights[point] * e.estimate_nm for point, e in estimates.items()) * A
        shared = np.where(stands_out(mean, A), mean, 0.0)
    pooled = shared != 0
    learned, quiet = {}, {}
    for point, e in estimates.items():
        V = np.where(pooled, np.maximum(e.variance_nm2 - A, 0.0), e.variance_nm2)
        learned[point] = stands_out(e.estimate_nm - shared, V)
        quiet[point] = ~learned[point]
        quiet[point][0] = False
    own = _own_unresolved({point: (e.estimate_nm - mean, np.maximum(e.variance_nm2 - A, 1e-300), quiet[point])
                           for point, e in estimates.items()})
    return {point: LearningFloor(np.where(learned[point], e.variance_nm2, np.where(pooled, A, 0.0)),
                                 unresolved_power(mean, A, quiet[point] & ~pooled) + own[point])
            for point, e in estimates.items()}


def _own_unresolved(deviations: dict[Point, tuple[np.ndarray, np.ndarray, np.ndarray]]) -> dict[Point, np.ndarray]:
    """What each point's own ripple (its deviation from the points' mean, of noise V, quiet where it did not
    stand out: ``deviations[point]``) leaves at its quiet harmonics, N m^2 per harmonic: one power per quiet
    harmonic for every point, the inverse-variance mean of the points' (`_excess_power` over their quiet
    harmonics, n of them, of variance about sum V^2 / n^2), at least 0, spread over each point's as its V.

    One point's estimate, over some hundred harmonics, scatters by about sqrt(100) V, as much as it measures
    (on the simulated motor with encoder line errors, 0.7 (mN m)^2 against 0.6); the points' together by a
    third of that. What is lost: a point whose own unresolved ripple is larger than the others' is given
    their mean."""
    means, weights = [], []
    for deviation, V, quiet in deviations.values():
        n = int(quiet.sum())
        if n:
            means.append(_excess_power(deviation, V, quiet) / n)
            weights.append(n**2 / max(float(np.sum(V[quiet] ** 2)), 1e-300))
    per_harmonic = max(0.0, float(np.average(means, weights=weights))) if weights else 0.0
    return {point: _spread(per_harmonic * int(quiet.sum()), V, quiet) for point, (_, V, quiet) in deviations.items()}


def _axis_weights(grid: np.ndarray, x: float) -> np.ndarray:
    """The Lagrange weights at ``x`` of the quadratic through the three values of ``grid`` nearest it, of two as
    near the one nearer zero (linear, as the compensation's, with fewer than three).

    Nearer zero, not first in the grid: the same choice at -x as at x on an axis through zero (-5 to 5 N m, on
    configs/four-quadrant.toml: at 2 N m -1, 1 and 3, at -2 N m -3, -1 and 1, where the grid's order took -5, -3
    and -1, which saw half the interpolation error the trials showed at 1.5 Hz), and the grid's order on one of a
    sign."""
    if grid.size < 3:
        return interpolation_weights(grid, np.ones(1), x, 1.0)[:, 0]
    nearest = np.sort(np.lexsort((np.abs(grid), np.abs(grid - x)))[:3])
    weights = np.zeros(grid.size)
    for i in nearest:
        others = [grid[j] for j in nearest if j != i]
        weights[i] = np.prod([(x - g) / (grid[i] - g) for g in others])
    return weights


#: the identified torque response G^ at harmonics h at a speed, Hz (`StageSetup.torque_response` at the
#: compensation's calibration)
Response = Callable[[np.ndarray, float], np.ndarray]


def interpolation_error(tables_nm: np.ndarray, torques_nm: np.ndarray, speeds_hz: np.ndarray, point: Point,
                        max_harmonic: int, response: Response | None = None) -> np.ndarray:
    """Harmonics 0..H of the torque the ideal feed-forward u* at ``point`` delivers beyond the bilinear one u
    (`interpolation_weights`) from the learned ``tables_nm`` (n_T, n_S, counts_per_rev), G^ (u* - u), N m: the
    estimated error of the interpolation there (zero at a learned point).

    u* is the quadratic through the three nearest learned points along an axis of three or more (`_axis_weights`);
    along a speed axis of fewer, each table seen through the ``response`` at the point's speed, G^(f_p) / G^(f) u_p,
    weighted as the compensation weighs it (None: G^ = 1, and no error along such an axis).
    """
    h = np.arange(max_harmonic + 1)
    tables = harmonic_amplitudes(tables_nm, max_harmonic, axis=-1)
    at = np.ones(h.size) if response is None else response(h, point[1])
    if response is None or speeds_hz.size >= 3:
        seen = tables
    else:
        seen = tables * np.stack([response(h, float(speed)) / at for speed in speeds_hz])
    ideal = np.einsum("i,j,ijh->h", _axis_weights(torques_nm, point[0]), _axis_weights(speeds_hz, point[1]), seen)
    bilinear = np.einsum("ij,ijh->h", interpolation_weights(torques_nm, speeds_hz, *point), tables)
    error_nm: np.ndarray = at * (ideal - bilinear)
    return error_nm


def _floor(final: TorqueSpectrum, mean_nm: float, learning: np.ndarray, offset_nm: np.ndarray | None) -> float:
    return expected_noise_pp(final.variance_nm2 + learning, final.counts_per_rev, offset_nm) / abs(mean_nm)


def point_floors(learned: dict[Point, list[PointSpectra]], validated: dict[Point, PointSpectra],
                 torques_nm: np.ndarray, speeds_hz: np.ndarray, tables_nm: np.ndarray, response: Response
                 ) -> list[PointFloor]:
    """The floor of every learned point (``learned``: its compensation trial, its learning trials and its final
    one, in order) and every validation point (``validated``: its compensated trial), learned points first.

    ``torques_nm`` x ``speeds_hz`` is the compensation's grid of learned points, ``tables_nm`` its feed-forward
    tables there (`Compensation`) and ``response`` the identified torque response they go through
    (`interpolation_error`).
    """
    estimates = {point: RippleEstimate.of(trials[:-1]) for point, trials in learned.items() if len(trials) > 1}
    learning = learning_floors(estimates) if estimates else {}
    for point, trials in learned.items():
        nothing = np.zeros_like(trials[-1].measured.variance_nm2)
        learning.setdefault(point, LearningFloor(nothing, nothing))
    floors = [_point(point, True, trials[-1], learning[point].total_nm2, None) for point, trials in learned.items()]
    for point, trial in validated.items():
        # the learned points' learning noise as the interpolation weighs it, w^2; the ripple they left as it is
        # there, interpolated (w)
        weights = interpolation_weights(torques_nm, speeds_hz, *point)
        part = np.zeros_like(trial.measured.variance_nm2)
        for (i, j), w in np.ndenumerate(weights):
            if w:
                near = learning[(float(torques_nm[i]), float(speeds_hz[j]))]
                part = part + w**2 * near.noise_nm2 + w * near.unresolved_nm2
        error = interpolation_error(tables_nm, torques_nm, speeds_hz, point, part.size - 1, response)
        floors.append(_point(point, False, trial, part, error))
    return floors


def _point(point: Point, learned: bool, final: PointSpectra, learning: np.ndarray, offset_nm: np.ndarray | None
           ) -> PointFloor:
    true = None if final.true is None or final.true_mean_nm is None else \
        _floor(final.true, final.true_mean_nm, learning, offset_nm)
    return PointFloor(point, learned, _floor(final.measured, final.mean_nm, learning, offset_nm), true)
