"""Physical parameters of the simulated drive (report ch. 1, fig. 1.1).

Every field name carries its unit; the report's symbols keep their names.
Each dataclass is one TOML section of a campaign config (see
``ilcpmac.config``); a field's ``metadata["check"]`` validates its value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ilcpmac.records import SensorCalibration


def _positive(x) -> bool:
    return np.all(np.asarray(x) > 0)


def _non_negative(x) -> bool:
    return np.all(np.asarray(x) >= 0)


def _three(x) -> bool:
    return len(x) == 3


def _param(check=None, doc: str = "", **kw):
    return field(metadata={"check": check, "doc": doc}, **kw)


@dataclass(frozen=True)
class Winding:
    """Motor geometry and per-phase electrical parameters."""

    pole_pairs: int = _param(_positive, "electrical revolutions per mechanical revolution")
    slots: int = _param(_positive, "stator slots")
    phase_resistance_ohm: float = _param(_positive, "R per phase, ohm")
    phase_inductance_h: float = _param(_positive, "L per phase, H")

    @property
    def cogging_order(self) -> int:
        """lcm(slots, 2 pole_pairs): cogging periods per mechanical revolution."""
        return math.lcm(self.slots, 2 * self.pole_pairs)


@dataclass(frozen=True)
class BackEmf:
    """Per-phase torque constant K_p(theta_e), N m / A.

    ``K_p = (1 + asymmetry_p) sum_n k_n sin(n (theta_e - 2 pi p / 3) + phi_n)``
    with theta_e = pole_pairs * theta the electrical angle.
    """

    harmonics: tuple[int, ...] = _param(_positive, "harmonic orders n of the electrical angle")
    amplitudes_nm_per_a: tuple[float, ...] = _param(None, "k_n, N m / A")
    phases_rad: tuple[float, ...] = _param(None, "phi_n, rad")
    asymmetry: tuple[float, ...] = _param(_three, "relative amplitude deviation per phase")


@dataclass(frozen=True)
class Cogging:
    """Cogging torque tau_c = sum_m a_m sin(m N_c theta + phi_m), N_c = lcm(slots, 2 pole_pairs)."""

    multiples: tuple[int, ...] = _param(_positive, "m: multiples of the cogging order")
    amplitudes_nm: tuple[float, ...] = _param(None, "a_m, N m")
    phases_rad: tuple[float, ...] = _param(None, "phi_m, rad")


@dataclass(frozen=True)
class Unexplained:
    """Ripple the linear model (1.3) does not capture.

    A saturation term ``-saturation_per_a2 * sum_p K_p i_p^3`` (current
    dependent) and a position disturbance ``sum_k d_k sin(o_k theta + phi_k)``
    at orders that are not multiples of the cogging order.
    """

    saturation_per_a2: float = _param(_non_negative, "relative torque-constant drop per A^2")
    orders: tuple[int, ...] = _param(_positive, "disturbance orders per mechanical revolution")
    amplitudes_nm: tuple[float, ...] = _param(None, "d_k, N m")
    phases_rad: tuple[float, ...] = _param(None, "phi_k, rad")


@dataclass(frozen=True)
class Mechanics:
    """J d(omega)/dt = torque - b omega - coulomb sign(omega) (eq. 3.1)."""

    inertia_kgm2: float = _param(_positive, "J, kg m^2")
    coulomb_friction_nm: float = _param(_non_negative, "Coulomb friction, N m")


@dataclass(frozen=True)
class Controller:
    """Discrete PI current control per phase and the controller's calibration."""

    control_rate_hz: float = _param(_positive, "control (and simulation) rate, Hz")
    bandwidth_hz: float = _param(_positive, "closed-loop current bandwidth, Hz")
    voltage_limit_v: float = _param(_positive, "phase voltage limit, V")
    current_scale_counts_per_a: tuple[float, ...] = _param(
        lambda x: _three(x) and _positive(x), "(G*_s)^-1 per phase, counts / A")
    current_offset_counts: tuple[float, ...] = _param(_three, "o*_s per phase, counts")
    torque_gain_v_per_nm: float = _param(_positive, "g*_t, V / N m")

    def calibration(self) -> SensorCalibration:
        """The calibration the controller starts with."""
        return SensorCalibration(self.current_scale_counts_per_a, self.current_offset_counts,
                                 self.torque_gain_v_per_nm)


@dataclass(frozen=True)
class CurrentSensors:
    """True current sensors, relative to the controller's starting calibration.

    epsilon, alpha and beta follow eqs. (1.5)-(1.7); alpha is normalised to mean 1.
    """

    epsilon: float = _param(_positive, "mean current-sensor gain error")
    alpha: tuple[float, ...] = _param(lambda x: _three(x) and _positive(x), "scale imbalance per phase")
    beta_a: tuple[float, ...] = _param(_three, "offset error per phase, A")
    noise_counts: float = _param(_non_negative, "white reading noise, counts RMS")

    def __post_init__(self) -> None:
        alpha = np.asarray(self.alpha, float)
        object.__setattr__(self, "alpha", tuple(alpha / alpha.mean()))

    def true_scale_counts_per_a(self, calibration: SensorCalibration) -> np.ndarray:
        """G_s^-1 per phase, counts / A, from G*_s^-1 G_s = epsilon alpha (eqs. 1.5, 1.6)."""
        return calibration.current_scale / (self.epsilon * np.asarray(self.alpha))

    def true_offset_counts(self, calibration: SensorCalibration) -> np.ndarray:
        """o_s per phase, counts, from beta = G_s (o_s - o*_s) (eq. 1.7)."""
        return calibration.current_offset + np.asarray(self.beta_a) * self.true_scale_counts_per_a(calibration)


@dataclass(frozen=True)
class TorqueSensor:
    """Piezo torque sensor: measured = delta * highpass(torque) + DC + drift t + noise."""

    delta: float = _param(_positive, "g_t / g*_t at the controller's starting calibration (eq. 1.4)")
    noise_nm: float = _param(_non_negative, "white noise, N m RMS per sample")
    highpass_hz: float = _param(_non_negative, "first-order high-pass corner of the piezo, Hz")
    dc_level_nm: float = _param(_non_negative, "bound of the unknown DC level (uniform, seeded), N m")
    drift_nm_per_s: float = _param(_non_negative, "bound of the unknown linear drift (uniform, seeded), N m / s")

    def true_gain_v_per_nm(self, starting_calibration: SensorCalibration) -> float:
        """g_t, V / N m."""
        return self.delta * starting_calibration.torque_gain


@dataclass(frozen=True)
class Encoder:
    """Incremental encoder with position-triggered sampling."""

    counts_per_rev: int = _param(_positive, "encoder counts per mechanical revolution")
    timer_resolution_s: float = _param(_positive, "time-stamp quantum, s")


@dataclass(frozen=True)
class Excitation:
    """Multisine added to the torque reference over mechanical harmonics 1..harmonics."""

    harmonics: int = _param(_positive, "highest excited harmonic of the mechanical revolution")
    fraction: float = _param(_non_negative, "multisine RMS as a fraction of the torque set point")
    phases: str = _param(lambda x: x in ("random", "schroeder"), '"random" (seeded) or "schroeder"')


@dataclass(frozen=True)
class TrialGrid:
    """The set-point grid of an identification campaign."""

    torque_setpoints_nm: tuple[float, ...] = _param(_positive, "torque set points, N m")
    speed_setpoints_hz: tuple[float, ...] = _param(_positive, "mechanical speed set points, Hz")
    revolutions: int = _param(_positive, "recorded revolutions per trial")
    warmup_revolutions: int = _param(_positive, "revolutions simulated and dropped first")
    seed: int = _param(_non_negative, "seed of every random generator")


@dataclass(frozen=True)
class MotorModel:
    """The whole simulated drive: motor, sensors, controller and mechanics."""

    winding: Winding
    backemf: BackEmf
    cogging: Cogging
    unexplained: Unexplained
    mechanics: Mechanics
    controller: Controller
    current_sensors: CurrentSensors
    torque_sensor: TorqueSensor
    encoder: Encoder
