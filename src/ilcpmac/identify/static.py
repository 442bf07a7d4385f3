"""eps from a static trial (issue 38): the rotor held at rest, the drive commanding currents, a DC-capable reference
(a lever on a scale, a reaction torque sensor) measuring the torque (docs/real-bench.md, "Pinning eps").

Without one, eps rests on the inertia the bench gives: delta is the torque sensor's reading of J domega/dt (ch. 3),
eps = delta eps / delta, so a relative error of ``[motor] inertia`` is one of eps, of the calibration the
current-sensor stage sets and of the mean torque, which no running trial shows. At rest the current loop holds
each phase's measured current at its reference (no lag at DC, no back-EMF), so phase p carries
i_p = eps alpha_p I*_p + beta_p (eqs. 1.5-1.7) and the shaft, at sample j held at count c_j,

    tau_j = sum_p K_p(c_j) i_pj (1 - c i_pj^2) + tau_pos(c_j).

What does not grow with the currents (the offsets' torque sum_p K_p beta_p, the cogging and every other position
torque, the reference's zero) is one intercept per count held. With the current's part of the torque

    g_j(eps) = sum_p K_p(c_j) [eps alpha_p I*_pj - c ((eps alpha_p I*_pj + beta_p)^3 - beta_p^3)]

(alpha, beta and the saturation c identified; c's own standard error adds its share to eps's, 0.04-0.05 % on the
seed bench, `ilcpmac.identify`), eps is found by Gauss-Newton steps on the samples less their mean at each count held,

    eps <- eps + sum_j g'_j (tau_j - g_j(eps)) / sum_j g'_j^2,   g' = dg / deps, both less their means at c_j,

from eps = 1; its standard error s / sqrt(sum_j g'_j^2), s^2 the residual's variance over n - (counts held) - 1
degrees of freedom: the reference's scatter, measured.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ilcpmac.bench.format import StaticTrial
from ilcpmac.core.errors import IdentificationError

__all__ = ["StaticEpsilon", "static_epsilon"]

#: Gauss-Newton steps (g is linear in eps but for the saturation: the second step moves eps by 1e-9)
STEPS = 3


@dataclass(frozen=True)
class StaticEpsilon:
    """eps from a static trial (module docstring).

    Attributes
    ----------
    epsilon, epsilon_std : the slope and its standard error.
    """

    epsilon: float
    epsilon_std: float


def static_epsilon(trial: StaticTrial, backemf_nm_per_a: np.ndarray, alpha: np.ndarray, beta_a: np.ndarray,
                   saturation_per_a2: float = 0.0) -> StaticEpsilon:
    """eps from ``trial`` through the bench's back-EMF table and the identified ``alpha``, ``beta_a`` (A) and
    saturation c (module docstring).

    Raises
    ------
    IdentificationError
        Where no count holds two distinct currents (no slope), or the samples leave no degree of freedom for the
        scatter (no standard error).
    """
    k = backemf_nm_per_a[trial.count]
    held, group = np.unique(trial.count, return_inverse=True)
    dof = trial.count.size - held.size - 1
    if dof < 1:
        raise IdentificationError(f"static trial: {trial.count.size} samples at {held.size} counts leave no degree "
                                  "of freedom for the reference's scatter: take two or more currents at a count, "
                                  "and more samples than counts plus one")

    def within(x: np.ndarray) -> np.ndarray:
        """``x`` less its mean at each count held."""
        return x - (np.bincount(group, x) / np.bincount(group))[group]

    scaled, c = alpha * trial.i_ref_a, saturation_per_a2
    torque = within(trial.torque_nm)
    epsilon, slope = 1.0, np.zeros(0)
    for _ in range(STEPS):
        current = epsilon * scaled + beta_a
        g = within(np.sum(k * (epsilon * scaled - c * (current**3 - beta_a**3)), axis=1))
        slope = within(np.sum(k * scaled * (1.0 - 3.0 * c * current**2), axis=1))
        spread = float(slope @ slope)
        if not spread > 0.0:
            raise IdentificationError("static trial: no count holds two distinct currents: eps is the torque's slope "
                                      "in the current at a count held")
        epsilon += float(slope @ (torque - g)) / spread
    current = epsilon * scaled + beta_a
    residual = torque - within(np.sum(k * (epsilon * scaled - c * (current**3 - beta_a**3)), axis=1))
    return StaticEpsilon(epsilon, float(np.sqrt(residual @ residual / dof)) / np.sqrt(float(slope @ slope)))
