"""Tables over one mechanical revolution, sampled at n equally spaced angles.

The simulator uses fine tables (linearly interpolated); the bench format uses
one row per encoder count.
"""

from __future__ import annotations

import numpy as np

from ilcpmac.core.records import MotorInfo
from ilcpmac.model.motor import BackEmf, Cogging, Unexplained, Winding


def mechanical_angles_rad(n_points: int) -> np.ndarray:
    """theta_k = 2 pi k / n, k = 0..n-1."""
    return 2.0 * np.pi * np.arange(n_points) / n_points


def backemf_table(winding: Winding | MotorInfo, backemf: BackEmf, n_points: int) -> np.ndarray:
    """K_p(theta) per phase, N m / A, shape (n_points, 3) (the matrix K of eq. 1.1), for a motor of
    ``winding.pole_pairs`` (the simulated winding, or a bench's motor)."""
    theta_e = winding.pole_pairs * mechanical_angles_rad(n_points)
    table = np.zeros((n_points, 3))
    for p in range(3):
        shifted = theta_e - 2.0 * np.pi * p / 3.0
        for n, k, phi in zip(backemf.harmonics, backemf.amplitudes_nm_per_a, backemf.phases_rad):
            table[:, p] += k * np.sin(n * shifted + phi)
        table[:, p] *= 1.0 + backemf.asymmetry[p]
    return table


def _sines(orders, amplitudes, phases, n_points: int) -> np.ndarray:
    theta = mechanical_angles_rad(n_points)
    table = np.zeros(n_points)
    for order, amplitude, phase in zip(orders, amplitudes, phases):
        table += amplitude * np.sin(order * theta + phase)
    return table


def cogging_table(winding: Winding, cogging: Cogging, n_points: int) -> np.ndarray:
    """tau_c(theta), N m, shape (n_points,)."""
    orders = [m * winding.cogging_order for m in cogging.multiples]
    return _sines(orders, cogging.amplitudes_nm, cogging.phases_rad, n_points)


def disturbance_table(unexplained: Unexplained, n_points: int) -> np.ndarray:
    """The unexplained position disturbance, N m, shape (n_points,)."""
    return _sines(unexplained.orders, unexplained.amplitudes_nm, unexplained.phases_rad, n_points)


def q_axis(theta_e_rad: np.ndarray) -> np.ndarray:
    """sin(theta_e - 2 pi p / 3) per phase p, shape (n, 3): the phase currents of a unit amplitude-invariant i_q
    (i_d = 0, the inverse Park transform); i_q = 2/3 sum_p i_p of it, and a back-EMF table K gives the q-axis
    torque per ampere sum_p K_p of it."""
    return np.sin(np.asarray(theta_e_rad)[:, None] - 2.0 * np.pi * np.arange(3) / 3.0)


def dead_counts(backemf_nm_per_a: np.ndarray) -> np.ndarray:
    """The counts whose back-EMF row is zero: no current makes torque there, shape (n,)."""
    return np.sum(backemf_nm_per_a**2, axis=1) == 0


def current_references(torque_reference_nm: np.ndarray, backemf_nm_per_a: np.ndarray) -> np.ndarray:
    """Minimum-copper-loss currents i*_p = tau_ref K*_p / sum_q K*_q^2, A (report sec. 2.1).

    0 A at the `dead_counts` (no current makes torque there).

    Parameters
    ----------
    torque_reference_nm : ndarray, shape (n,)
    backemf_nm_per_a : ndarray, shape (n, 3)
        The controller's back-EMF table K*.
    """
    norm = np.sum(backemf_nm_per_a**2, axis=1)[:, None]
    return np.divide(torque_reference_nm[:, None] * backemf_nm_per_a, norm,
                     out=np.zeros(np.shape(backemf_nm_per_a)), where=norm != 0)
