"""What a backend of a drive without a torque sensor or a load offers beyond `Backend` (docs/moteus.md): rolling
trials on the drive's own velocity loop with its own position table, the limits the drive itself enforces, and
storing a table in the drive's flash."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from ilcpmac.backends.base import Backend
from ilcpmac.bench.rolling import RollingData
from ilcpmac.core.records import DriveTrialRequest

__all__ = ["DriveBackend", "DriveLimits", "DriveTrial"]


@dataclass(frozen=True)
class DriveLimits:
    """The limits a drive enforces by itself, as read from it before any motion (moteus: servo.max_current_A,
    servo.max_velocity, servo.fault_temperature, servo.motor_fault_temperature).

    Attributes
    ----------
    max_current_a : float
        Largest phase current the drive lets flow, A.
    max_speed_hz : float
        Largest mechanical speed it runs at, Hz (inf: none set).
    max_temperature_c : float
        Temperature at which it faults (the lower of its board's and its motor's), deg C (inf: none set).
    current_bandwidth_hz : float or None
        Not a limit but what bounds the speeds one table serves in both directions: its current loop's bandwidth
        (moteus: servo.pid_dq_hz), Hz; None where the drive does not say.
    """

    max_current_a: float
    max_speed_hz: float
    max_temperature_c: float
    current_bandwidth_hz: float | None = None


@dataclass(frozen=True)
class DriveTrial:
    """One rolling trial as the host polled it.

    Attributes
    ----------
    request : DriveTrialRequest
        The request it answers (the copy the guard checked).
    data : RollingData
        The recorded rows in time order: host time stamps, the commutation encoder's position in counts of
        [bench] counts_per_rev (unwrapped, signed: decreasing in reverse), the q current, one segment.
    polls, lost : int
        Queries sent while recording, and those without an answer (what polling lost).
    max_temperature_c : float
        Highest temperature the drive reported, deg C.
    true_residual_nm : ndarray, shape (counts_per_rev,), or None
        Emulated drives only: the true position-locked torque the table left (the position torque plus the
        table's current's torque, averaged over the recorded rows by true position), N m.
    true_position_torque_nm : ndarray, shape (counts_per_rev,), or None
        Emulated drives only: the true position-locked torque without any table (cogging and disturbance), N m.
    """

    request: DriveTrialRequest
    data: RollingData
    polls: int
    lost: int
    max_temperature_c: float
    true_residual_nm: np.ndarray | None = None
    true_position_torque_nm: np.ndarray | None = None


@runtime_checkable
class DriveBackend(Backend, Protocol):
    """A `Backend` of a drive without a torque sensor or a load (moteus): what the drive campaign uses."""

    def drive_limits(self) -> DriveLimits:
        """The drive's own limits, read from it (before any motion)."""
        ...

    def run_drive_trial(self, request: DriveTrialRequest) -> DriveTrial:
        """Upload ``request``'s table into the drive's RAM, run its velocity loop at the request's speed, poll
        it while recording, and stop it on every path (an error, Ctrl-C, a lost connection)."""
        ...

    def store_table(self, request: DriveTrialRequest) -> None:
        """Write ``request``'s table into the drive's flash (moteus: conf write); only on the user's word
        (``--write-config``)."""
        ...
