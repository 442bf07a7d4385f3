"""The default backend: the numba simulator."""

from __future__ import annotations

import os
import threading
from dataclasses import replace
from typing import TYPE_CHECKING

from ilcpmac.backends.base import BenchDescription, BenchLimits
from ilcpmac.core.errors import ConfigError
from ilcpmac.core.records import TrialData, TrialRequest, mirrored_request
from ilcpmac.core.schema import finite_number
from ilcpmac.model.motor import MotorModel
from ilcpmac.sim.bench import simulated_description
from ilcpmac.sim.simulator import Simulator

if TYPE_CHECKING:
    from ilcpmac.backends.registry import BackendSetup


class SimulatorBackend:
    """Runs trials on `Simulator`; trial data include the true torque and currents. A trial of a negative speed
    set point runs in reverse: the mirror image's forward lap (`Simulator.mirrored`, the `Backend` contract).

    The kernel releases the GIL, so a campaign may run ``max_parallel_trials``
    trials at once in threads.

    Parameters
    ----------
    model : MotorModel
    limits : BenchLimits
    warmup_revolutions : int
    record_counts_per_rev : int or None
        `Simulator`'s.
    inertia_uncertainty : float or None
        What the bench states of its inertia's relative uncertainty ([bench] inertia_uncertainty; None: nothing),
        as its description tells it (`MotorInfo.inertia_uncertainty`).
    """

    #: it runs trials of a negative speed set point (`ilcpmac.backends.base.runs_reverse`)
    reverses = True

    def __init__(self, model: MotorModel, limits: BenchLimits, warmup_revolutions: int = 1,
                 record_counts_per_rev: int | None = None, inertia_uncertainty: float | None = None) -> None:
        self.simulator = Simulator(model, warmup_revolutions, record_counts_per_rev)
        self._mirror: Simulator | None = None
        self._mirroring = threading.Lock()
        self.limits = limits
        self.inertia_uncertainty = inertia_uncertainty
        self.max_parallel_trials = os.cpu_count() or 1

    @classmethod
    def from_setup(cls, setup: BackendSetup) -> SimulatorBackend:
        """The numba simulator of the config's [bench] and [simulator.*] tables, within its [limits].

        Raises `ConfigError` when given an address (``--address``): the simulator runs here, and a user who gave one
        meant a bench, which must never be taken for the simulator."""
        setup.refuse_options("sim")
        if setup.address is not None:
            raise ConfigError(f"--address {setup.address}: the sim backend runs the simulator in this process and "
                              "takes no address; for a bench at that address give --backend remote (or the "
                              "backend that drives it)")
        config = setup.config
        return cls(config.sampled_model(), config.limits.bench_limits(), config.grid.warmup_revolutions,
                   config.recorded_counts_per_rev(), config.bench.inertia_uncertainty)

    def describe(self) -> BenchDescription:
        description = simulated_description(self.simulator, self.limits)
        if self.inertia_uncertainty is None:
            return description
        return replace(description, motor=replace(description.motor, inertia_uncertainty=self.inertia_uncertainty))

    def run_trial(self, request: TrialRequest) -> TrialData:
        if finite_number(request.speed_setpoint_hz) and request.speed_setpoint_hz < 0:
            return self.mirror().run_trial(mirrored_request(request))
        return self.simulator.run_trial(request)

    def mirror(self) -> Simulator:
        """The simulator of the motor's mirror image (`Simulator.mirrored`), made at the first reverse trial (its
        tables are as large as the motor's) and kept."""
        with self._mirroring:  # trials run in threads
            if self._mirror is None:
                self._mirror = self.simulator.mirrored()
            return self._mirror

    def close(self) -> None:
        """Nothing to release."""
