"""The noise floor of each operating point: the least peak-to-peak ripple its trials can reach and show
(docs/campaign.md, "The noise floor").

Two noises bound what a point ends at:

- the **final trial's own noise** (what it can show): the non-repeatable part of the torque left in its
  synchronous average, of variance v_h per harmonic (its revolution-to-revolution scatter over the number of
  revolutions; `TorqueSpectrum.variance_nm2`); for the true torque on the simulator that is the current sensors'
  noise reaching it through the loop, for the measured one the torque sensor's or the encoder torque's noise;
- the **learning's noise** (what it can reach): the feed-forward that removes the ripple the model-based
  compensation left is estimated from the measured torque of the trials learned from before the final one,
  no better than the inverse-variance mean of their harmonics, of variance P_h = 1 / sum_k (1 / v_k,h), at
  every harmonic where there was ripple to remove: where the measured harmonic of one of those trials stood
  out of its noise by `SIGNIFICANCE` standard deviations (the compensation trial shows the large ripple, the
  longer learning trials what is smaller). A harmonic no trial shows is left out: a learner may leave it alone.
  Where the learned points share their ripple (`shared_harmonics`), a learner that pools the points (the ilc
  stage) learns it from every point's trials: there P_h is that of all of them pooled.

The floor is the expected peak-to-peak of independent harmonics of variance v_h + P_h over the band 1..H
(`expected_noise_pp`), as a fraction of the mean torque. A validation point learns nothing: its learning part
is that of the learned points its feed-forward is interpolated from, weighted as the compensation weighs their
tables (`interpolation_weights`), w^2 P_h summed; and the feed-forward there is an interpolation, whose error
no trial removes. Where three or more points were learned along an axis, the quadratic through the three
nearest estimates that error: the floor's harmonics are centred on the difference between the quadratic's
feed-forward and the bilinear one (`interpolation_error`), not on zero.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ilcpmac.campaign.record import Point
from ilcpmac.compensation import interpolation_weights
from ilcpmac.pipeline.analysis import TorqueSpectrum
from ilcpmac.signals.harmonics import expected_noise_pp, harmonic_amplitudes

__all__ = ["SIGNIFICANCE", "PointFloor", "PointSpectra", "floors_of", "interpolation_error", "learning_variance",
           "point_floors", "shared_harmonics"]

#: standard deviations a harmonic of a trial learned from stands out by to count as ripple to learn
SIGNIFICANCE = 2.0
#: learned points from which on the points' shared ripple is learned pooled (`shared_harmonics`; the ilc
#: stage's `POOLED_MIN`)
POOLED_POINTS = 3
#: the chance that points sharing a harmonic's ripple are taken for differing there (`shared_harmonics`)
SHARED_FALSE_ALARM = 0.01


@dataclass(frozen=True)
class PointSpectra:
    """What the floor of a point needs of one of its trials: its measured spectrum in true-torque units
    (`TorqueMeasurement.in_true_units`) and the measurement's mean torque, N m; its true spectrum and mean
    (simulator only)."""

    measured: TorqueSpectrum
    mean_nm: float
    true: TorqueSpectrum | None = None
    true_mean_nm: float | None = None


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

    def to_json(self) -> dict:
        """Its keys in summary.json's ``points`` entry of the point."""
        out = {"floor_pp_measured": self.measured_pp}
        if self.true_pp is not None:
            out["floor_pp_true"] = self.true_pp
        return out

    @classmethod
    def from_json(cls, data: dict) -> PointFloor | None:
        """The floor in summary.json's ``points`` entry ``data`` (`to_json` beside the point's results); None in
        an entry without one (a run of an earlier release)."""
        if "floor_pp_measured" not in data:
            return None
        true = data.get("floor_pp_true")
        return cls((float(data["torque_setpoint"]), float(data["speed_setpoint"])), bool(data["learned"]),
                   float(data["floor_pp_measured"]), None if true is None else float(true))

    def pp(self, kind: str) -> float | None:
        """`measured_pp` or `true_pp` by name ("measured", "true")."""
        return {"measured": self.measured_pp, "true": self.true_pp}[kind]


def floors_of(summary: dict) -> dict[Point, PointFloor]:
    """The floor of every point of summary.json ``summary`` that has one, by point (`PointFloor.from_json`)."""
    return {floor.point: floor for p in summary.get("points", []) if (floor := PointFloor.from_json(p)) is not None}


def learning_variance(learned_from: list[TorqueSpectrum]) -> np.ndarray:
    """P_h of the module docstring per harmonic 0..H, N m^2: the inverse-variance mean's variance of the spectra
    ``learned_from`` (true units) where the harmonic of one of them stands out at `SIGNIFICANCE`, 0 elsewhere
    and at h = 0."""
    information = sum(1.0 / np.maximum(s.variance_nm2, 1e-300) for s in learned_from)
    ripple = np.any([np.abs(s.harmonics_nm) > SIGNIFICANCE * np.sqrt(s.variance_nm2) for s in learned_from], axis=0)
    ripple[0] = False
    return np.where(ripple, 1.0 / information, 0.0)


def shared_harmonics(learned: dict[Point, list[PointSpectra]]) -> tuple[np.ndarray, np.ndarray]:
    """Where the learned points share their ripple, and the learning variance there with every point's trials
    pooled (a learner that pools the points, as the ilc stage does, reaches it), N m^2, per harmonic 0..H.

    Shared: the compensation trials' harmonics (what each point had to learn) agree across the points within
    their noise, sum_p |c_p - c|^2 / v_p (c their inverse-variance mean) within the 1 - `SHARED_FALSE_ALARM`
    quantile of its Gamma(k - 1) law for k points that share it. Fewer than `POOLED_POINTS` points share
    nothing.
    """
    from scipy.special import gammaincinv  # deferred: scipy.special costs the campaign's import

    first = next(iter(learned.values()))[0].measured if learned else None
    if first is None or len(learned) < POOLED_POINTS:
        size = 0 if first is None else first.variance_nm2.size
        return np.zeros(size, bool), np.zeros(size)
    compensation = [trials[0].measured for trials in learned.values()]
    c = np.array([s.harmonics_nm for s in compensation])
    w = 1.0 / np.maximum(np.array([s.variance_nm2 for s in compensation]), 1e-300)
    mean = (w * c).sum(axis=0) / w.sum(axis=0)
    spread = (w * np.abs(c - mean) ** 2).sum(axis=0)
    shared = spread <= gammaincinv(len(learned) - 1, 1.0 - SHARED_FALSE_ALARM)
    pooled = 1.0 / sum(1.0 / np.maximum(t.measured.variance_nm2, 1e-300) for trials in learned.values()
                       for t in trials[:-1])
    return shared, pooled


def _axis_weights(grid: np.ndarray, x: float) -> np.ndarray:
    """The Lagrange weights at ``x`` of the quadratic through the three values of ``grid`` nearest it (linear,
    as the compensation's, with fewer than three)."""
    if grid.size < 3:
        return interpolation_weights(grid, np.ones(1), x, 1.0)[:, 0]
    nearest = np.sort(np.argsort(np.abs(grid - x), kind="stable")[:3])
    weights = np.zeros(grid.size)
    for i in nearest:
        others = [grid[j] for j in nearest if j != i]
        weights[i] = np.prod([(x - g) / (grid[i] - g) for g in others])
    return weights


def interpolation_error(tables_nm: np.ndarray, torques_nm: np.ndarray, speeds_hz: np.ndarray, point: Point,
                        max_harmonic: int) -> np.ndarray:
    """Harmonics 0..H of the quadratic feed-forward at ``point`` (`_axis_weights` along torque and speed) less
    the bilinear one (`interpolation_weights`) from the learned ``tables_nm`` (n_T, n_S, counts_per_rev), N m:
    the estimated error of the interpolation there (zero at a learned point, and along an axis of one or two)."""
    quadratic = np.outer(_axis_weights(torques_nm, point[0]), _axis_weights(speeds_hz, point[1]))
    difference = np.tensordot(quadratic - interpolation_weights(torques_nm, speeds_hz, *point), tables_nm, axes=2)
    return harmonic_amplitudes(difference, max_harmonic)


def _floor(final: TorqueSpectrum, mean_nm: float, learning: np.ndarray, offset_nm: np.ndarray | None) -> float:
    return expected_noise_pp(final.variance_nm2 + learning, final.counts_per_rev, offset_nm) / abs(mean_nm)


def point_floors(learned: dict[Point, list[PointSpectra]], validated: dict[Point, PointSpectra],
                 torques_nm: np.ndarray, speeds_hz: np.ndarray, tables_nm: np.ndarray) -> list[PointFloor]:
    """The floor of every learned point (``learned``: its compensation trial, its learning trials and its final
    one, in order) and every validation point (``validated``: its compensated trial), learned points first.

    ``torques_nm`` x ``speeds_hz`` is the compensation's grid of learned points and ``tables_nm`` its feed-forward
    tables there (`Compensation`).
    """
    learning = {}
    floors = []
    shared, pooled = shared_harmonics(learned)
    for point, trials in learned.items():
        *before, final = trials
        learning[point] = learning_variance([t.measured for t in before]) if before else \
            np.zeros_like(final.measured.variance_nm2)
        learning[point] = np.where(shared & (learning[point] > 0), pooled, learning[point])
        floors.append(_point(point, True, final, learning[point], None))
    for point, trial in validated.items():
        weights = interpolation_weights(torques_nm, speeds_hz, *point)
        part = np.zeros_like(trial.measured.variance_nm2)
        for (i, j), w in np.ndenumerate(weights):
            if w:
                part = part + w**2 * learning[(float(torques_nm[i]), float(speeds_hz[j]))]
        error = interpolation_error(tables_nm, torques_nm, speeds_hz, point, part.size - 1)
        floors.append(_point(point, False, trial, part, error))
    return floors


def _point(point: Point, learned: bool, final: PointSpectra, learning: np.ndarray, offset_nm: np.ndarray | None
           ) -> PointFloor:
    true = None if final.true is None or final.true_mean_nm is None else \
        _floor(final.true, final.true_mean_nm, learning, offset_nm)
    return PointFloor(point, learned, _floor(final.measured, final.mean_nm, learning, offset_nm), true)
