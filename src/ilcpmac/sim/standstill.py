"""A standstill position scan of the simulated drive, as a drive would log it, with its truth.

Quasi-static: the rotor moves so slowly (a ramp over whole revolutions,
forward then back) that inertia, the current loop's lag and viscous damping
vanish. At the true angle theta, moving in direction s = +-1, the rotor is in
equilibrium under the position torque tau_pos (cogging plus the position
disturbance of [simulator.unexplained]), Coulomb friction s F and a
hysteresis torque s H (1 + sin(N_c theta)) / 2 (an iron loss that varies
with position like the cogging, N_c the cogging order), so the torque that
holds it is

    h_s(theta) = -tau_pos(theta) + s (F + H (1 + sin(N_c theta)) / 2).

``holding = "currents"``: the drive holds the rotor itself. Its torque
reference follows from the current law (`current_references` at the count
the encoder reads) through the true sensors (i = eps alpha_p i*_p + beta_p,
`Simulator.truth`) and the true back-EMF with saturation (eq. 1.3); the log
holds the currents as the controller measures them (i* plus the current
sensors' reading noise, [simulator.current_sensors] noise_counts) and their
q-axis component (amplitude-invariant Park at angle offset 0).

``holding = "torque"``: an external drive turns the unpowered motor through
a torque sensor that holds DC (a strain-gauge or reaction transducer; a piezo
cannot measure a scan's quasi-static torque, so [simulator.torque_sensor]
highpass_hz and drift_nm_per_s are not used): the log holds delta h plus a
constant zero offset (drawn within dc_level_nm) and noise_nm per sample.

A log may lack counts (``ScanPlan.skipped_forward``, ``skipped_reverse``): every sample nearest to such a
count, moving that way, is left out, as a drive that logs too slowly for its ramp would.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ilcpmac.bench.fastcsv import format_rows
from ilcpmac.core.errors import SimulationError
from ilcpmac.core.files import atomic_write
from ilcpmac.core.schema import in_range, shown
from ilcpmac.model.tables import current_references, q_axis
from ilcpmac.sim.simulator import OVERSAMPLE, Simulator, airgap_torque_nm

__all__ = ["ScanPlan", "scan_log", "write_scan_log"]

#: Most samples of a simulated scan (a scan folder's bound).
MAX_SCAN_SAMPLES = 2**22
#: Newton steps for the torque reference through the saturation term: it changes the torque by parts in 1e4
_STEPS = 4


@dataclass(frozen=True)
class ScanPlan:
    """A simulated scan: ``revolutions`` forward, then (``reverse``) the same positions back.

    Attributes
    ----------
    revolutions : int
        Revolutions per direction, 1..64.
    samples_per_count : int
        Rows per encoder count of the ramp, 1..256.
    rate_hz : float
        Log rate, Hz.
    coulomb_friction_nm, hysteresis_nm : float
        F and H, N m, >= 0.
    holding : str
        "currents" or "torque".
    reverse : bool
    seed : int
    skipped_forward, skipped_reverse : tuple of int
        Counts of a revolution, 0..counts_per_rev - 1, whose samples the log lacks in that direction.
    """

    revolutions: int = 1
    samples_per_count: int = 4
    rate_hz: float = 1000.0
    coulomb_friction_nm: float = 0.05
    hysteresis_nm: float = 0.02
    holding: str = "currents"
    reverse: bool = True
    seed: int = 0
    skipped_forward: tuple[int, ...] = ()
    skipped_reverse: tuple[int, ...] = ()

    def problem(self, counts_per_rev: int) -> str | None:
        """The first value out of its range, as "name: why", or None."""
        checks = [("revolutions", in_range(1, 64)), ("samples_per_count", in_range(1, 256)),
                  ("rate_hz", in_range(0.0, 1e6, low_open=True)), ("coulomb_friction_nm", in_range(0.0, 1e3)),
                  ("hysteresis_nm", in_range(0.0, 1e3)), ("seed", in_range(0, 2**63 - 1))]
        for name, check in checks:
            if not check(getattr(self, name)):
                return f"{name}: invalid value {shown(getattr(self, name))}"
        for name in ("skipped_forward", "skipped_reverse"):
            if not in_range(0, counts_per_rev - 1)(getattr(self, name)):
                return f"{name}: counts 0..{counts_per_rev - 1}, got {shown(getattr(self, name))}"
        if self.holding not in ("currents", "torque"):
            return f'holding: "currents" or "torque", got {shown(self.holding)}'
        rows = self.revolutions * counts_per_rev * self.samples_per_count * (2 if self.reverse else 1) - self.reverse
        if rows > MAX_SCAN_SAMPLES:
            return f"{rows} samples: more than {MAX_SCAN_SAMPLES}"
        return None


def _periodic(fine: np.ndarray, position_counts: np.ndarray) -> np.ndarray:
    """Rows of the simulator's fine table (the first row repeated last) at real positions, linearly
    interpolated."""
    n = fine.shape[0] - 1
    u = np.mod(position_counts * OVERSAMPLE, n)
    base = np.floor(u).astype(np.int64)
    frac = u - base
    if fine.ndim == 1:
        return (1.0 - frac) * fine[base] + frac * fine[base + 1]
    return (1.0 - frac)[:, None] * fine[base] + frac[:, None] * fine[base + 1]


def scan_log(simulator: Simulator, plan: ScanPlan) -> tuple[dict[str, np.ndarray], dict]:
    """The scan's log columns (time, position in counts, direction, i_a..i_c and i_q, or torque) and its truth.

    The truth holds, per count, ``cogging`` (the simulator's cogging torque) and ``position_torque``
    (cogging plus the position disturbance), under the result keys ({"count", "torque"}), and F and H.
    """
    m = simulator.model
    cpr = m.encoder.counts_per_rev
    problem = plan.problem(cpr)
    if problem is not None:
        raise SimulationError(f"scan plan {problem}")
    rng = np.random.default_rng(plan.seed)
    up = (np.arange(plan.revolutions * cpr * plan.samples_per_count) + 0.5) / plan.samples_per_count
    position = np.concatenate([up, up[-2::-1]]) if plan.reverse else up  # the turn is one row, moving forward
    direction = np.where(np.arange(position.size) < up.size, 1.0, -1.0)
    theta = 2.0 * np.pi * position / cpr
    torque_pos = _periodic(simulator.fine[:, 3], position)
    holding = -torque_pos + direction * (plan.coulomb_friction_nm
                                         + plan.hysteresis_nm * (1.0 + np.sin(m.winding.cogging_order * theta)) / 2)
    columns = {"time": np.arange(position.size) / plan.rate_hz, "position": position, "direction": direction}
    calibration = m.controller.calibration()
    if plan.holding == "torque":
        delta = simulator.truth(calibration).delta
        offset = rng.uniform(-1.0, 1.0) * m.torque_sensor.dc_level_nm
        columns["torque"] = delta * holding + offset + m.torque_sensor.noise_nm * rng.standard_normal(
            position.size)
    else:
        columns.update(_holding_currents(simulator, position, holding, rng))
    nearest = np.round(position).astype(np.int64) % cpr
    logged = ~np.where(direction > 0, np.isin(nearest, plan.skipped_forward), np.isin(nearest, plan.skipped_reverse))
    columns = {name: values[logged] for name, values in columns.items()}
    count = np.arange(cpr)
    truth = {"cogging": {"count": count.tolist(), "torque": simulator.cogging_counts().tolist()},
             "position_torque": {"count": count.tolist(),
                                 "torque": simulator.torque_pos_fine[::OVERSAMPLE].tolist()},
             "coulomb_friction_nm": plan.coulomb_friction_nm, "hysteresis_nm": plan.hysteresis_nm}
    return columns, truth


def _holding_currents(simulator: Simulator, position: np.ndarray, holding_nm: np.ndarray,
                      rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The measured phase currents (and their q-axis part) whose true torque is ``holding_nm``."""
    m = simulator.model
    cpr = m.encoder.counts_per_rev
    calibration = m.controller.calibration()
    truth = simulator.truth(calibration)
    gain = truth.epsilon * truth.alpha
    k_true = _periodic(simulator.fine[:, :3], position)
    per_nm = current_references(np.ones(position.size), simulator.backemf_counts[np.floor(position).astype(np.int64)
                                                                                  % cpr])
    slope = np.sum(k_true * gain * per_nm, axis=1)
    if np.any(np.abs(slope) < 1e-9):
        raise SimulationError("the scan passes a position where no current makes torque")
    c = m.unexplained.saturation_per_a2
    reference = np.zeros(position.size)
    for _ in range(_STEPS):
        i_true = gain * (reference[:, None] * per_nm) + truth.beta_a
        reference += (holding_nm - airgap_torque_nm(k_true, i_true, c)) / slope
    i_true = gain * (reference[:, None] * per_nm) + truth.beta_a
    miss = np.abs(airgap_torque_nm(k_true, i_true, c) - holding_nm).max()
    if miss > 1e-9 * max(1.0, np.abs(holding_nm).max()):
        raise SimulationError(f"the holding currents do not converge through saturation ({miss:.3g} N m off)")
    measured = reference[:, None] * per_nm + (m.current_sensors.noise_counts / calibration.current_scale
                                              * rng.standard_normal((position.size, 3)))
    theta_e = m.winding.pole_pairs * 2.0 * np.pi * position / cpr
    return {"i_a": measured[:, 0], "i_b": measured[:, 1], "i_c": measured[:, 2],
            "i_q": 2.0 / 3.0 * np.sum(measured * q_axis(theta_e), axis=1)}


def write_scan_log(path: str | Path, simulator: Simulator, plan: ScanPlan) -> dict:
    """Write `scan_log`'s columns as a CSV log (header ``time,position,direction,...``); returns the truth."""
    columns, truth = scan_log(simulator, plan)
    decimals = {"time": 7, "position": 6, "direction": 0}
    values = np.column_stack(list(columns.values()))
    body = format_rows(values, np.array([decimals.get(name, 6) for name in columns]))
    atomic_write(Path(path), ",".join(columns).encode() + b"\n" + body)
    return truth
