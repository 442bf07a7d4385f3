"""The one interface every backend implements."""

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
    """Runs trials on a motor, simulated or real."""

    def describe(self) -> BenchDescription:
        """The motor, its back-EMF table, today's calibration and the limits."""
        ...

    def run_trial(self, request: TrialRequest) -> TrialData:
        """Run one trial and return its position-sampled data."""
        ...
