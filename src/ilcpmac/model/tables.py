"""Tables over one mechanical revolution, sampled at n equally spaced angles.

The simulator uses fine tables (linearly interpolated); the bench format uses
one row per encoder count.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ilcpmac.core.binning import per_line
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


def _sines(orders: Sequence[float], amplitudes: Sequence[float], phases: Sequence[float], n_points: int
           ) -> np.ndarray:
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
    phases: np.ndarray = np.sin(np.asarray(theta_e_rad)[:, None] - 2.0 * np.pi * np.arange(3) / 3.0)
    return phases


def dead_counts(backemf_nm_per_a: np.ndarray) -> np.ndarray:
    """The counts whose back-EMF row is zero: no current makes torque there, shape (n,)."""
    vanishing: np.ndarray = np.sum(backemf_nm_per_a**2, axis=1) == 0
    return vanishing


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
    references: np.ndarray = np.divide(torque_reference_nm[:, None] * backemf_nm_per_a, norm,
                                      out=np.zeros(np.shape(backemf_nm_per_a)), where=norm != 0)
    return references


def references_per_line(references_a: np.ndarray, backemf_nm_per_a: np.ndarray, b: int
                        ) -> tuple[np.ndarray, np.ndarray]:
    """The back-EMF table at the N b lines, shape (N b, 3), and the current references there, shape (..., N b, 3),
    of per-count references ``references_a`` (..., N, 3) of a controller that holds each count's torque reference
    sum_p K*_p I*_p over its b lines and commutes at every line (`current_references`; K* at the lines from its
    harmonics, `per_line`): a record of count means (`ilcpmac.core.binning`) as the simulator makes it."""
    backemf = per_line(backemf_nm_per_a, b)
    torque = np.repeat(np.sum(references_a * backemf_nm_per_a, axis=-1), b, axis=-1)
    lines = np.stack([current_references(t, backemf) for t in torque.reshape(-1, torque.shape[-1])])
    return backemf, lines.reshape(torque.shape + (3,))
