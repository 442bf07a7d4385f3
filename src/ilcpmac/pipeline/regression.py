"""One joint least-squares fit per trial over every stage's regressors (eq. 1.12 generalised).

The fit runs in the harmonic domain (report sec. 2.3): the measured torque's
synchronous average over the trial's revolutions, detrended first (its DC
level and drift carry no information), is compared harmonic by harmonic with
every stage's per-count regressors over the harmonics the stages' models
claim: the multiples of the pole-pair count (1x, 2x electrical and their
multiples, which include the cogging orders). All other harmonics are
absorbed by a nuisance block, one free coefficient per harmonic (equivalent
to leaving them out): position-locked ripple nobody models there (the
residual ILC learns) can then not leak into a stage's estimate. Each harmonic
is weighted by the inverse of its revolution-to-revolution variance, and the
information is inflated by the Birge ratio when the fit is worse than that
noise (model mismatch). Each stage reads its own block: the estimate and the
block's marginal Fisher information (Schur complement over the others), so
overlapping regressors (cogging and current-dependent ripple at 6x
electrical) are not confused. ``y`` is what is left to explain: the pipeline
passes the measured harmonics less the torque of the trial's feed-forward
through the identified response (ilcpmac.pipeline.pipeline).
"""

from __future__ import annotations

import numpy as np

from ilcpmac.stages.base import Block


class Regression:
    """Weighted least squares of complex harmonics ``y`` on named blocks of complex regressors.

    Parameters
    ----------
    y : ndarray of complex, shape (m,)
        Harmonics of the measured torque, N m.
    variance : ndarray, shape (m,)
        Variance of each harmonic (E|noise|^2).
    blocks : dict of name -> ndarray of complex, shape (m, k)
        Each stage's regressors at the same harmonics.
    """

    def __init__(self, y: np.ndarray, variance: np.ndarray, blocks: dict[str, np.ndarray]) -> None:
        self._slices: dict[str, slice] = {}
        start = 0
        for name, cols in blocks.items():
            self._slices[name] = slice(start, start + cols.shape[1])
            start += cols.shape[1]
        X = np.hstack(list(blocks.values())) if blocks else np.zeros((len(y), 0))
        # real and imaginary parts are separate equations, each with variance/2
        w = np.sqrt(2.0 / np.concatenate([variance, variance]))
        A = np.vstack([X.real, X.imag]) * w[:, None]
        b = np.concatenate([y.real, y.imag]) * w
        coef, _, rank, _ = np.linalg.lstsq(A, b, rcond=None)
        self.coefficients = coef
        chi2 = float(np.sum((b - A @ coef) ** 2))
        self.birge_ratio = max(1.0, chi2 / max(b.size - rank, 1))
        self._information = (A.T @ A) / self.birge_ratio

    def block(self, name: str) -> Block:
        """The estimate and marginal information of block ``name``."""
        s = self._slices[name]
        idx = np.arange(self._information.shape[0])
        own, other = idx[s], np.setdiff1d(idx, idx[s])
        info = self._information
        schur = info[np.ix_(own, own)]
        if other.size:
            schur = schur - info[np.ix_(own, other)] @ np.linalg.pinv(
                info[np.ix_(other, other)], hermitian=True) @ info[np.ix_(other, own)]
        return Block(self.coefficients[s].copy(), 0.5 * (schur + schur.T))
