"""A simulated static trial (`ilcpmac.bench.format.StaticTrial`; docs/real-bench.md, "Pinning eps"): the rotor held
at counts spread over a revolution, the drive commanding torque references there through the current sensors,
a DC torque reference measuring what the shaft carries, with a Gaussian scatter.

At rest the current loop holds each phase's reading at its reference, so the true current is the one whose
noiseless reading is the reference, eps alpha_p I*_p + beta_p (eqs. 1.5-1.7, `Simulator.truth`); the shaft carries
sum_p K_p i_p (1 - c i_p^2) + tau_pos at the held line's true angle (its encoder error included), the simulator's
own tables (`Simulator.fine`).
"""

from __future__ import annotations

import numpy as np

from ilcpmac.bench.format import StaticTrial
from ilcpmac.core.records import SensorCalibration
from ilcpmac.model.tables import current_references
from ilcpmac.sim.simulator import OVERSAMPLE, Simulator, airgap_torque_nm

__all__ = ["HELD_COUNTS", "TORQUE_FRACTIONS", "simulated_static_trial"]

#: counts the rotor is held at, evenly over a revolution
HELD_COUNTS = 8
#: the torque references at each, as fractions of the largest asked for
TORQUE_FRACTIONS = (0.25, 0.5, 0.75, 1.0)


def simulated_static_trial(simulator: Simulator, calibration: SensorCalibration, torque_nm: float, noise_nm: float,
                           seed: int) -> StaticTrial:
    """`HELD_COUNTS` counts x `TORQUE_FRACTIONS` of ``torque_nm``, at ``calibration``, the reference's scatter
    ``noise_nm`` (N m RMS, seeded by ``seed``)."""
    cpr = simulator.record_counts_per_rev
    counts = (np.arange(HELD_COUNTS) * cpr) // HELD_COUNTS + cpr // (2 * HELD_COUNTS)
    count = np.repeat(counts, len(TORQUE_FRACTIONS))
    references = torque_nm * np.tile(TORQUE_FRACTIONS, HELD_COUNTS)
    i_ref = current_references(references, simulator.backemf_counts[count])
    truth = simulator.truth(calibration)
    i_true = truth.epsilon * truth.alpha * i_ref + truth.beta_a
    line = count * simulator.lines_per_count
    rows = simulator.fine.shape[0] - 1  # the fine table's rows over a revolution (its first repeated at the end)
    position = (simulator.lines_counts[line + 1] * OVERSAMPLE) % rows  # line c truly at lines_counts[c + 1]
    j = np.minimum(position.astype(np.int64), simulator.fine.shape[0] - 2)
    f = (position - j)[:, None]
    table = simulator.fine[j] + f * (simulator.fine[j + 1] - simulator.fine[j])
    torque = airgap_torque_nm(table[:, :3], i_true, simulator.model.unexplained.saturation_per_a2) + table[:, 3]
    scatter = noise_nm * np.random.default_rng([seed, 38]).standard_normal(torque.size)
    return StaticTrial(count, i_ref, torque + scatter)
