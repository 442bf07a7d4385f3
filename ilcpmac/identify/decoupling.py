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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ilcpmac.identify.reduction import BenchTables
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
    """

    alpha_star: np.ndarray
    beta_star: np.ndarray
    explained_nm: np.ndarray
    residual_nm: np.ndarray
    cogging_nm: np.ndarray
    rest_nm: np.ndarray
    measured_nm: np.ndarray
    delta_epsilon: float

    def alpha(self) -> np.ndarray:
        """alpha = alpha* / (delta eps) + 1 (eq. 1.11), averaged over set points."""
        return self.alpha_star.mean(axis=0) / self.delta_epsilon + 1.0

    def alpha_std(self) -> np.ndarray:
        """Standard error of alpha from the scatter over set points."""
        return _standard_error(self.alpha_star) / self.delta_epsilon

    def beta_star_mean(self) -> np.ndarray:
        """beta* = delta beta (eq. 1.11) averaged over set points, A."""
        return self.beta_star.mean(axis=0)

    def beta_star_std(self) -> np.ndarray:
        """Standard error of that mean from the scatter over set points, A."""
        return _standard_error(self.beta_star)

    def mean_cogging_nm(self) -> np.ndarray:
        """The cogging torque, the mean over set points (ch. 4), N m (measured units)."""
        return self.cogging_nm.mean(axis=0)


def _standard_error(per_set_point: np.ndarray) -> np.ndarray:
    n = per_set_point.shape[0]
    return per_set_point.std(axis=0, ddof=1) / np.sqrt(n) if n > 1 else np.full(per_set_point.shape[1], np.nan)


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
    return DecouplingEstimate(y[:, :3], y[:, 3:], explained, residual, cogging, residual - cogging, measured,
                              delta_epsilon)
