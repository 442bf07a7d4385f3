"""The one interface every backend implements (docs/writing-a-backend.md)."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from ilcpmac.records import BenchDescription, BenchLimits, TrialData, TrialRequest

#: `BenchDescription` and `BenchLimits` live in `ilcpmac.records`; plugins may import them from here
__all__ = ["Backend", "BenchDescription", "BenchLimits"]


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
