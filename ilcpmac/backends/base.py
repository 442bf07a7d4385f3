"""The one interface every backend implements (docs/writing-a-backend.md)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from ilcpmac.bench.format import MotorInfo
from ilcpmac.records import SensorCalibration, TrialData, TrialRequest


@dataclass(frozen=True)
class BenchLimits:
    """What the bench accepts; requests beyond these are refused or clipped."""

    max_current_a: float
    max_torque_nm: float
    max_speed_hz: float


@dataclass(frozen=True)
class BenchDescription:
    """What a backend tells about its motor before the first trial.

    Attributes
    ----------
    motor : MotorInfo
        The [motor] data of the bench format.
    backemf_nm_per_a : ndarray, shape (counts_per_rev, 3)
        The back-EMF table (backemf.csv).
    calibration : SensorCalibration
        The controller's calibration today (the [sensors] data).
    limits : BenchLimits
    """

    motor: MotorInfo
    backemf_nm_per_a: np.ndarray
    calibration: SensorCalibration
    limits: BenchLimits


@runtime_checkable
class Backend(Protocol):
    """Runs trials on a motor, simulated or real: everything a campaign uses of a backend.

    Attributes
    ----------
    max_parallel_trials : int
        How many `run_trial` calls may run at once, in threads (1: one at a time).
    """

    max_parallel_trials: int

    def describe(self) -> BenchDescription:
        """The motor, its back-EMF table, today's calibration and the limits."""
        ...

    def run_trial(self, request: TrialRequest) -> TrialData:
        """Run one trial and return its position-sampled data."""
        ...

    def close(self) -> None:
        """Release the bench (connections, devices); called once the campaign ends or fails."""
        ...
