"""Decoupling of the pulsating torque (report sec. 1.4 and ch. 4).

With the total system gain delta*eps known (ch. 2), the measured pulsating
torque of each set point, less delta*eps sum_p K_p I*_p (eq. 1.8), is fitted
by the pseudo-inverse of X = [K . I*_i  K] (eqs. 1.9, 1.10, 1.12):

    y = [alpha*; beta*] = X^+ tau*_p,     tau*_c = tau*_p - X y   (eq. 1.13),

with alpha* = delta eps (alpha - 1) and beta* = delta beta (eq. 1.11). The
residual restricted to the cogging harmonics (multiples of the cogging order,
fig. 4.1) is the cogging torque; the rest is unexplained. alpha, beta and the
cogging are averaged over the set points, then alpha and beta follow from
eq. (1.11) with the two gains. Everything is done on each trial's synchronous
average over one revolution; the piezo sensor cannot see the mean, so the
means of the data and of X are removed.

The standard errors of the averages are the scatter over set points, plus,
where a set point's residual at the electrical harmonics (where X lives)
exceeds its noise, that excess: a misfit the model lacks is shared by the set
points and does not average out (docs/identification.md, "Uncertainty on
mismatched data").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ilcpmac.identify.reduction import BenchTables, trial_amplitudes
from ilcpmac.signals.harmonics import filtered, harmonic_band


@dataclass(frozen=True)
class DecouplingEstimate:
    """The report's decoupling per set point and averaged (torques in measured units).

    Attributes
    ----------
    alpha_star, beta_star : ndarray, shape (n_trials, 3)
        y of eq. (1.12) per set point.
    explained_nm, residual_nm, cogging_nm, rest_nm : ndarray, shape (n_trials, counts_per_rev)
        X y, z = tau*_p - X y, z on the cogging harmonics, and z - cogging (fig. 4.1).
    measured_nm : ndarray, shape (n_trials, counts_per_rev)
        tau*_p, the pulsating torque less delta*eps sum_p K_p I*_p.
    delta_epsilon : float
        The total system gain the decoupling used.
    chi2_reduced : ndarray, shape (n_trials,)
        Per set point, the residual's chi-square per degree of freedom at the electrical harmonics.
    misfit_variance : ndarray, shape (n_trials, 6)
        Per set point, (chi2 - 1)+ sigma^2 diag (X^T X)^-1 of [alpha*, beta*]: the misfit's share of y's variance.
    electrical_harmonics : ndarray of int
        The multiples of the pole pairs (not of the cogging order) the chi-square is taken over.
    """

    alpha_star: np.ndarray
    beta_star: np.ndarray
    explained_nm: np.ndarray
    residual_nm: np.ndarray
    cogging_nm: np.ndarray
    rest_nm: np.ndarray
    measured_nm: np.ndarray
    delta_epsilon: float
    chi2_reduced: np.ndarray
    misfit_variance: np.ndarray
    electrical_harmonics: np.ndarray

    def alpha(self) -> np.ndarray:
        """alpha = alpha* / (delta eps) + 1 (eq. 1.11), averaged over set points."""
        return self.alpha_star.mean(axis=0) / self.delta_epsilon + 1.0

    def alpha_std(self) -> np.ndarray:
        """Standard error of alpha: the scatter over set points and the shared misfit."""
        return _standard_error(self.alpha_star, self.misfit_variance[:, :3]) / self.delta_epsilon

    def beta_star_mean(self) -> np.ndarray:
        """beta* = delta beta (eq. 1.11) averaged over set points, A."""
        return self.beta_star.mean(axis=0)

    def beta_star_std(self) -> np.ndarray:
        """Standard error of that mean: the scatter over set points and the shared misfit, A."""
        return _standard_error(self.beta_star, self.misfit_variance[:, 3:])

    @property
    def warnings(self) -> tuple[str, ...]:
        """One line when the set points' residuals at the electrical harmonics exceed their noise."""
        worst = float(self.chi2_reduced.max())
        if worst <= MISFIT_CHI2:
            return ()
        h = self.electrical_harmonics
        y = np.hstack([self.alpha_star, self.beta_star])
        inflated, scatter = _standard_error(y, self.misfit_variance), _standard_error(y)
        seen = scatter > 0  # one set point has no scatter: nothing to inflate
        inflation = float(np.max(inflated[seen] / scatter[seen], initial=1.0))
        return (f"decoupling (ch. 4, the report's method, shown beside the joint fit's): "
                f"residual chi2/dof up to {worst:.3g} at the electrical harmonics "
                f"{h.min()}-{h.max()} ({int(np.sum(self.chi2_reduced > MISFIT_CHI2))} of {self.chi2_reduced.size} "
                f"set points) - the model misses structure there; standard errors inflated up to x{inflation:.2g}",)

    def mean_cogging_nm(self) -> np.ndarray:
        """The cogging torque, the mean over set points (ch. 4), N m (measured units)."""
        return self.cogging_nm.mean(axis=0)


#: a set point's reduced chi-square at the electrical harmonics above which the decoupling says it is off
MISFIT_CHI2 = 1.5


def _standard_error(per_set_point: np.ndarray, misfit_variance: np.ndarray | None = None) -> np.ndarray:
    """Scatter over set points over sqrt(n), plus the mean misfit variance, which no average removes."""
    n = per_set_point.shape[0]
    if n < 2:
        return np.full(per_set_point.shape[1], np.nan)
    shared = 0.0 if misfit_variance is None else misfit_variance.mean(axis=0)
    return np.sqrt(per_set_point.var(axis=0, ddof=1) / n + shared)


def cogging_band(table: np.ndarray, cogging_order: int) -> np.ndarray:
    """The part of per-count tables (last axis) on the multiples of the cogging order."""
    n = table.shape[-1]
    return filtered(table, harmonic_band(n, cogging_order, n // 2, cogging_order), axis=-1)


def decouple(tables: BenchTables, delta_epsilon: float) -> DecouplingEstimate:
    """Eqs. (1.12) and (1.13) per set point with the given total system gain."""
    k = tables.backemf_nm_per_a
    columns = np.concatenate([k * np.stack([t.i_ref_table_a for t in tables.trials]),
                              np.broadcast_to(k, (len(tables.trials),) + k.shape)], axis=2)
    columns = columns - columns.mean(axis=1, keepdims=True)
    torque = np.stack([t.torque_table_nm for t in tables.trials])
    measured = torque - torque.mean(axis=1, keepdims=True) - delta_epsilon * columns[:, :, :3].sum(axis=2)
    # X^+ tau*_p = (X^T X)^-1 X^T tau*_p for the full column rank of X (eq. 1.12), all set points at once
    gram = np.einsum("kni,knj->kij", columns, columns)
    y = np.linalg.solve(gram, np.einsum("kni,kn->ki", columns, measured)[:, :, None])[:, :, 0]
    explained = np.einsum("kni,ki->kn", columns, y)
    residual = measured - explained
    cogging = cogging_band(residual, tables.motor.cogging_order)
    chi2, misfit_variance, electrical = _misfit(tables, residual, gram)
    return DecouplingEstimate(y[:, :3], y[:, 3:], explained, residual, cogging, residual - cogging, measured,
                              delta_epsilon, chi2, misfit_variance, electrical)


def _misfit(tables: BenchTables, residual: np.ndarray, gram: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                                  np.ndarray]:
    """Per set point: chi2/dof of z at the electrical harmonics, and (chi2 - 1)+ sigma^2 diag (X^T X)^-1.

    Each harmonic amplitude of the per-count table carries noise variance v
    (``harmonic_variance_nm2``, or per harmonic ``harmonic_variances_nm2`` up
    to the highest it holds) in its real and in its imaginary part; the six
    columns take six degrees of freedom. A count of the table carries
    sigma^2 = v n / 2 (Parseval over n counts, v averaged over those harmonics).
    """
    motor = tables.motor
    n = motor.counts_per_rev
    top = min([n // 2 - 1] + [t.harmonic_variances_nm2.size - 1 for t in tables.trials
                              if t.harmonic_variances_nm2 is not None])
    h = np.arange(motor.pole_pairs, top + 1, motor.pole_pairs)
    electrical = h[h % motor.cogging_order != 0]
    amplitudes = trial_amplitudes(residual[:, :, None], top)[:, electrical, 0]
    variance = np.stack([np.full(electrical.size, t.harmonic_variance_nm2) if t.harmonic_variances_nm2 is None
                         else t.harmonic_variances_nm2[electrical] for t in tables.trials])
    # noise-free data (v = 0) have nothing to compare with: no misfit test there
    ratio = np.divide(np.abs(amplitudes) ** 2, variance, out=np.zeros(variance.shape), where=variance > 0.0)
    chi2 = np.sum(ratio, axis=1) / max(2 * electrical.size - 6, 1)
    per_count = variance.mean(axis=1) * n / 2.0
    excess = np.clip(chi2 - 1.0, 0.0, None) * per_count
    return chi2, excess[:, None] * np.diagonal(np.linalg.inv(gram), axis1=1, axis2=2), electrical
