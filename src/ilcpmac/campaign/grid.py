"""The identification grid: one multisine-excited request per (torque, speed) set point of [trials]."""

from __future__ import annotations

import numpy as np

from ilcpmac.config import CampaignConfig
from ilcpmac.core.records import SensorCalibration, TrialRequest
from ilcpmac.core.seeds import trial_seed
from ilcpmac.signals.multisine import multisine, multisine_phases_rad

__all__ = ["grid_plan", "grid_requests"]


def grid_requests(config: CampaignConfig, calibration: SensorCalibration, seed: int,
                  revolutions: int) -> list[TrialRequest]:
    """One multisine-excited request per (torque, speed) set point, torque-major order, at ``calibration``
    (the bench description's).

    Each trial gets its own seeded multisine phases, so that position-locked
    disturbances do not correlate with the excitation across trials.
    """
    cpr = config.recorded_counts_per_rev()
    exc = config.excitation
    requests: list[TrialRequest] = []
    for torque in config.grid.torque_setpoints_nm:
        for speed in config.grid.speed_setpoints_hz:
            rng = np.random.default_rng([seed, len(requests), 1])
            phases = multisine_phases_rad(exc.harmonics, exc.phases, rng)
            table = multisine(cpr, exc.harmonics, exc.fraction * torque, phases)
            requests.append(TrialRequest(torque, speed, revolutions, np.zeros(cpr), table, calibration,
                                         seed=trial_seed(seed, len(requests))))
    return requests


def grid_plan(config: CampaignConfig, requests: list[TrialRequest]) -> list[tuple[str, TrialRequest]]:
    """The grid's requests, each with the config keys that ask for it (for `check_plan`)."""
    exc = config.excitation
    return [(f"{config.path}: [trials] set point {r.torque_setpoint_nm:g} N m at {r.speed_setpoint_hz:g} Hz, "
             f"revolutions {r.revolutions}, with its [excitation] multisine (fraction {exc.fraction:g} of the set "
             f"point, harmonics {exc.harmonics})", r) for r in requests]
