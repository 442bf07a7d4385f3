"""The one interface every backend implements (docs/writing-a-backend.md), and its optional progress reports."""

from __future__ import annotations

import time
from typing import Callable, Protocol, runtime_checkable

from ilcpmac.core.records import BenchDescription, BenchLimits, TrialData, TrialRequest

#: `BenchDescription` and `BenchLimits` live in `ilcpmac.core.records`; plugins may import them from here
__all__ = ["Backend", "BenchDescription", "BenchLimits", "ProgressCallback", "ProgressThrottle",
           "report_progress_to", "runs_reverse"]

#: ``callback(fraction)``: the running trial is ``fraction`` (0..1) done
ProgressCallback = Callable[[float], None]


@runtime_checkable
class Backend(Protocol):
    """Runs trials on a motor, simulated or real: everything a campaign uses of a backend.

    A backend may also run the motor in reverse (optional, not part of this protocol): with a class attribute
    ``reverses = True``, a `run_trial` of a negative speed set point turns the motor backwards and returns the
    reverse lap as its mirror image's forward lap, as a bench folder stores one (docs/bench-format.md, "Reverse
    laps"; `ilcpmac.core.records.mirrored_request` gives the mirror's request); `runs_reverse` asks. Without it a
    campaign learns forward only.

    A backend may also report how far its running trial is (optional, not part of this protocol):
    ``set_progress(callback: ProgressCallback | None) -> None`` keeps ``callback`` (None: report nothing
    more), and every later `run_trial` calls it, from any thread, at most a few times per second
    (`ProgressThrottle`), with the fraction of the trial done. Use `report_progress_to` to ask for it.

    Attributes
    ----------
    max_parallel_trials : int
        How many `run_trial` calls may run at once, in threads (1: one at a time).
    """

    @property
    def max_parallel_trials(self) -> int: ...

    def describe(self) -> BenchDescription:
        """The motor, its back-EMF table, today's calibration and the limits."""
        ...

    def run_trial(self, request: TrialRequest) -> TrialData:
        """Run one trial and return its position-sampled data."""
        ...

    def close(self) -> None:
        """Release the bench (connections, devices); called once the campaign ends or fails."""
        ...


def runs_reverse(backend: Backend) -> bool:
    """Whether ``backend`` runs trials of a negative speed set point (its ``reverses``; `Backend`)."""
    return getattr(backend, "reverses", False) is True


def report_progress_to(backend: Backend, callback: ProgressCallback | None) -> None:
    """Have ``backend`` report the progress of its trials to ``callback`` (None: stop) if it can (its
    ``set_progress``); a backend without it reports nothing."""
    set_progress = getattr(backend, "set_progress", None)
    if set_progress is not None:
        set_progress(callback)


class ProgressThrottle:
    """A `ProgressCallback` that passes fractions on to ``callback`` at most once per ``interval_s``, but
    always a trial's start (0) and end (1), and never the same fraction twice in a row.

    Parameters
    ----------
    callback : ProgressCallback
    interval_s : float
        Shortest time between two fractions passed on, other than a start or an end, s.
    clock : callable
        Seconds, monotonic.
    """

    def __init__(self, callback: ProgressCallback, interval_s: float = 0.1,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.callback = callback
        self.interval_s = interval_s
        self.clock = clock
        self._last: float | None = None
        self._last_s = -float("inf")

    def __call__(self, fraction: float) -> None:
        now = self.clock()
        if fraction == self._last or not (fraction <= 0 or fraction >= 1 or now - self._last_s >= self.interval_s):
            return
        self._last, self._last_s = fraction, now
        self.callback(fraction)
