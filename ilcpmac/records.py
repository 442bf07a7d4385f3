"""The two records that flow between campaign, stages and backends.

`TrialRequest` describes a trial before it runs; `TrialData` is what comes
back, sampled once per encoder count (position-triggered, report sec. 2.3).
Both are plain frozen dataclasses of numpy arrays and round-trip through the
bench format (docs/bench-format.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np


@dataclass(frozen=True)
class SensorCalibration:
    """The controller's sensor calibration (the report's starred estimates).

    Attributes
    ----------
    current_scale : ndarray, shape (3,)
        (G*_s)^-1 per phase, counts per ampere.
    current_offset : ndarray, shape (3,)
        o*_s per phase, counts. The controller converts a raw reading r to
        amperes as ``(r + o*_s) / current_scale``, so that with a true sensor
        ``i = G_s (r + o_s)`` the tracked current obeys eq. (1.2).
    torque_gain : float
        g*_t, volts per newton metre.
    """

    current_scale: np.ndarray
    current_offset: np.ndarray
    torque_gain: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "current_scale", np.asarray(self.current_scale, float).reshape(3))
        object.__setattr__(self, "current_offset", np.asarray(self.current_offset, float).reshape(3))
        object.__setattr__(self, "torque_gain", float(self.torque_gain))


@dataclass(frozen=True)
class TrialRequest:
    """Everything a backend needs to run one trial.

    Attributes
    ----------
    torque_setpoint_nm : float
        Mean torque asked for, N m.
    speed_setpoint_hz : float
        Mechanical speed the brake is set for, Hz.
    revolutions : int
        Recorded revolutions (after the warm-up revolution).
    feedforward_nm, excitation_nm : ndarray, shape (counts_per_rev,)
        Per-count additions to the torque reference, N m:
        tau_ref(count) = set point + feed-forward + excitation.
    calibration : SensorCalibration
        The controller's current and torque calibration for this trial.
    seed : int
        32-bit seed of every random draw of a simulated trial (ignored by real benches).
    """

    torque_setpoint_nm: float
    speed_setpoint_hz: float
    revolutions: int
    feedforward_nm: np.ndarray
    excitation_nm: np.ndarray
    calibration: SensorCalibration
    seed: int = 0

    def torque_reference_nm(self) -> np.ndarray:
        """tau_ref per encoder count over one mechanical revolution, N m."""
        return self.torque_setpoint_nm + self.feedforward_nm + self.excitation_nm

    def with_changes(self, **changes) -> "TrialRequest":
        """A copy with some fields replaced."""
        return replace(self, **changes)


@dataclass(frozen=True)
class TrialData:
    """One trial, one row per encoder count in acquisition order.

    Attributes
    ----------
    torque_setpoint_nm, speed_setpoint_hz : float
        The set point (as listed in bench.toml).
    count : ndarray of int64, shape (n,)
        Unwrapped encoder position, strictly increasing (counts may be skipped).
    time_s : ndarray, shape (n,)
        Sample time stamps, s.
    i_ref_a : ndarray, shape (n, 3)
        Current references I*_i tracked by the controller, A.
    torque_nm : ndarray, shape (n,)
        Torque-sensor output converted with the trial's g*_t, N m (drifts).
    i_meas_a : ndarray, shape (n, 3), optional
        Currents as the controller measures them, A.
    torque_true_nm, i_true_a, speed_true_rad_s : optional
        Simulator only: true air-gap plus cogging torque, true phase currents
        and true mechanical speed.
    request : TrialRequest, optional
        The request this trial answers, when known.
    """

    torque_setpoint_nm: float
    speed_setpoint_hz: float
    count: np.ndarray
    time_s: np.ndarray
    i_ref_a: np.ndarray
    torque_nm: np.ndarray
    i_meas_a: np.ndarray | None = None
    torque_true_nm: np.ndarray | None = None
    i_true_a: np.ndarray | None = None
    speed_true_rad_s: np.ndarray | None = None
    request: TrialRequest | None = field(default=None, compare=False)

    @property
    def n_samples(self) -> int:
        """Number of recorded encoder counts."""
        return int(self.count.size)
