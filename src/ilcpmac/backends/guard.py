"""`LimitGuard`: the one safety gate every trial of a campaign passes, whatever the backend (docs/safety.md)."""

from __future__ import annotations

from ilcpmac.backends.base import Backend, ProgressCallback, report_progress_to
from ilcpmac.backends.drive import DriveBackend, DriveTrial
from ilcpmac.core.errors import SafetyError
from ilcpmac.core.records import BenchDescription, DriveTrialRequest, SensorCalibration, TrialData, TrialRequest
from ilcpmac.pipeline.safety import (
    MalformedRequest,
    SafetyLimits,
    drive_violation,
    limit_violation,
    owned_drive_request,
    owned_request,
)

__all__ = ["LimitGuard"]


class LimitGuard:
    """A backend (the whole `Backend` protocol) that passes on only requests within the limits, and of each only
    the copy it checked: `owned_request` copies the request into values the host owns, `limit_violation` checks
    that copy, and the backend gets exactly it (nothing the request's maker still holds, or whose class lies to a
    comparison, reaches the bench).

    The campaign wraps whatever backend it is given in one, so no phase can bypass the limits. It forwards
    ``set_progress`` to the backend, which reports nothing if it cannot (`report_progress_to`).

    Parameters
    ----------
    backend : the backend that runs the trials.
    description : the bench.
    limits : the limits.

    Attributes
    ----------
    truth : SensorCalibration or None
        The identified true sensors, once known (bounds the flowing current and centres the trust region).
    """

    def __init__(self, backend: Backend, description: BenchDescription, limits: SafetyLimits) -> None:
        self.backend = backend
        self.description = description
        self.limits = limits
        self.truth: SensorCalibration | None = None

    @property
    def max_parallel_trials(self) -> int:
        return self.backend.max_parallel_trials

    def describe(self) -> BenchDescription:
        return self.description

    def run_trial(self, request: TrialRequest) -> TrialData:
        try:
            owned = owned_request(request, self.description.motor.counts_per_rev)
        except MalformedRequest as e:
            raise SafetyError(f"a trial refused before it reached the backend: {e}") from None
        why = limit_violation(owned, self.description, self.limits, self.truth)
        if why is not None:
            raise SafetyError(f"trial at {owned.torque_setpoint_nm!r} N m, {owned.speed_setpoint_hz!r} Hz "
                              f"refused before it reached the backend: {why}")
        return self.backend.run_trial(owned)

    def run_drive_trial(self, request: DriveTrialRequest) -> DriveTrial:
        """A drive trial (`DriveBackend`), checked as `run_trial` checks a bench trial."""
        return self._drive().run_drive_trial(self._drive_checked(request, "trial"))

    def store_table(self, request: DriveTrialRequest) -> None:
        """A table written to a drive's flash (`DriveBackend`), checked as a trial that runs it."""
        self._drive().store_table(self._drive_checked(request, "table"))

    def _drive(self) -> DriveBackend:
        if not isinstance(self.backend, DriveBackend):
            raise SafetyError(f"a drive trial refused: the {type(self.backend).__name__} backend drives no drive "
                              "without a load (it has no run_drive_trial, store_table or drive_limits)")
        return self.backend

    def _drive_checked(self, request: DriveTrialRequest, what: str) -> DriveTrialRequest:
        try:
            owned = owned_drive_request(request)
        except MalformedRequest as e:
            raise SafetyError(f"a drive {what} refused before it reached the backend: {e}") from None
        why = drive_violation(owned, self.description, self.limits)
        if why is not None:
            raise SafetyError(f"drive {what} at {owned.speed_hz!r} Hz refused before it reached the backend: {why}")
        return owned

    def set_progress(self, callback: ProgressCallback | None) -> None:
        report_progress_to(self.backend, callback)

    def close(self) -> None:
        self.backend.close()
