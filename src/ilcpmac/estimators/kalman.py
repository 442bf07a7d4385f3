"""A random-walk parameter estimator over ``filterpy.kalman.KalmanFilter``.

State: a stage's parameters x, drifting slowly, x_{j+1} = x_j + w_j with
cov(w) = Q. Measurement after trial j: z_j = H_j x_j + v_j, cov(v) = R_j, where
z_j is the stage's block of that trial's joint least-squares fit. With Q = 0
and a vague prior the filter reproduces the batch least-squares answer.
"""

from __future__ import annotations

import numpy as np


class KalmanEstimator:
    """Kalman filter for slowly drifting parameters.

    Parameters
    ----------
    x0 : ndarray, shape (n,)
        Prior mean.
    P0 : ndarray, shape (n, n) or (n,)
        Prior covariance (a vector is its diagonal).
    process_noise : float or ndarray
        Q per trial: a scalar (times identity), a diagonal, or a full matrix.
    """

    def __init__(self, x0: np.ndarray, P0: np.ndarray, process_noise: float | np.ndarray = 0.0) -> None:
        x0 = np.asarray(x0, float).ravel()
        n = x0.size
        from filterpy.kalman import KalmanFilter  # 0.8 s to import (scipy.stats): only when a stage learns

        self._kf = KalmanFilter(dim_x=n, dim_z=n)
        self._kf.x = x0.reshape(n, 1)
        self._kf.P = _as_matrix(P0, n)
        self._kf.F = np.eye(n)
        self._kf.Q = _as_matrix(process_noise, n)

    @property
    def x(self) -> np.ndarray:
        """Posterior mean, shape (n,)."""
        return self._kf.x.ravel().copy()

    @property
    def P(self) -> np.ndarray:
        """Posterior covariance, shape (n, n)."""
        return self._kf.P.copy()

    def update(self, z: np.ndarray, R: np.ndarray, H: np.ndarray | None = None) -> None:
        """One trial: predict (random walk), then update with z = H x + v, cov(v) = R."""
        z = np.asarray(z, float).ravel()
        H = np.eye(self._kf.dim_x) if H is None else np.atleast_2d(np.asarray(H, float))
        self._kf.predict()
        self._kf.update(z.reshape(-1, 1), R=_as_matrix(R, z.size), H=H)

    def update_block(self, estimate: np.ndarray, information: np.ndarray, H: np.ndarray | None = None,
                     rel_tol: float = 1e-10) -> int:
        """Update from a least-squares block: ``estimate`` of H x with Fisher ``information``.

        The information may be singular (a trial without excitation cannot
        see every direction): only its well-determined eigen-directions (eigenvalue
        above ``rel_tol`` times the largest) are used as measurements, each with
        variance 1 / eigenvalue. Returns the number of directions used.
        """
        information = 0.5 * (information + information.T)
        eigval, eigvec = np.linalg.eigh(information)
        keep = eigval > rel_tol * max(eigval.max(), 0.0)
        if not keep.any():
            self._kf.predict()
            return 0
        V = eigvec[:, keep]
        H = np.eye(self._kf.dim_x) if H is None else np.asarray(H, float)
        self.update(V.T @ np.asarray(estimate, float), np.diag(1.0 / eigval[keep]), V.T @ H)
        return int(keep.sum())

    def constrain(self, D: np.ndarray, d: float) -> None:
        """Hold the linear combination D x at ``d``: the estimate and its covariance as after a measurement
        D x = d of no noise (the minimum-variance projection onto the constraint), so that no later update
        moves D x either. No-op when D x has no variance."""
        D = np.asarray(D, float).reshape(1, -1)
        P = self._kf.P
        variance = float((D @ P @ D.T)[0, 0])
        if variance <= 0.0:
            return
        gain = P @ D.T / variance
        self._kf.x = self._kf.x - gain * (float((D @ self._kf.x)[0, 0]) - d)
        self._kf.P = P - gain @ D @ P

    def state(self) -> dict:
        """JSON-able mean and covariance."""
        return {"x": self.x.tolist(), "P": self.P.tolist()}

    def restore(self, state: dict) -> None:
        """Set mean and covariance from `state`."""
        n = self._kf.dim_x
        self._kf.x = np.asarray(state["x"], float).reshape(n, 1)
        self._kf.P = np.asarray(state["P"], float).reshape(n, n)


def _as_matrix(value, n: int) -> np.ndarray:
    value = np.asarray(value, float)
    if value.ndim == 0:
        return np.eye(n) * float(value)
    if value.ndim == 1:
        return np.diag(value)
    return value.copy()
