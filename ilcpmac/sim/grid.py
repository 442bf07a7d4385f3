"""Identification campaigns on the simulator: the multisine set-point grid and its truth."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Callable

import numpy as np

from ilcpmac.bench.format import Bench, write_bench
from ilcpmac.config import CampaignConfig
from ilcpmac.core.records import BenchDescription, BenchLimits, MotorInfo, SensorCalibration, TrialData, TrialRequest
from ilcpmac.pipeline.safety import SafetyLimits, check_plan
from ilcpmac.signals.encoder_torque import encoder_error_summary
from ilcpmac.signals.harmonics import harmonic_amplitudes
from ilcpmac.signals.multisine import multisine, multisine_phases_rad
from ilcpmac.sim.simulator import Simulator, trial_seed


def grid_requests(config: CampaignConfig, calibration: SensorCalibration, seed: int,
                  revolutions: int) -> list[TrialRequest]:
    """One multisine-excited request per (torque, speed) set point, torque-major order, at ``calibration``
    (the bench description's).

    Each trial gets its own seeded multisine phases, so that position-locked
    disturbances do not correlate with the excitation across trials.
    """
    cpr = config.bench.counts_per_rev
    exc = config.excitation
    requests = []
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


def truth_dict(simulator: Simulator, request: TrialRequest) -> dict:
    """The true parameters under the result keys of docs/bench-format.md, for ``request``'s calibration."""
    t = simulator.truth(request.calibration)
    cpr = simulator.model.encoder.counts_per_rev
    return {
        # the true back-EMF over the controller's table scales the torque per reference ampere, as epsilon does
        "total_system_gain": t.delta * t.epsilon * simulator.model.winding.backemf_scale,
        "torque_sensor_gain": t.delta,
        "epsilon": t.epsilon,
        "alpha": t.alpha.tolist(),
        "beta": t.beta_a.tolist(),
        "inertia_estimate": t.delta * simulator.model.mechanics.true_inertia_kgm2,
        "cogging": {"count": list(range(cpr)), "torque": simulator.cogging_counts().tolist()},
        "current_loop_bandwidth_per_phase_hz": t.loop_bandwidth_hz.tolist(),
        "calibration": SensorCalibration(simulator.scale_true, simulator.offset_true,
                                         simulator.torque_gain_true).to_json(),
        "encoder_error": encoder_error_json(simulator.model.encoder.line_errors_counts()),
    }


def encoder_error_json(line_errors_counts: np.ndarray) -> dict:
    """The result JSON's "encoder_error" object (`IdentificationResult.to_json`) of known line errors e_c,
    counts: without standard errors."""
    harmonics = harmonic_amplitudes(line_errors_counts)[: line_errors_counts.size // 2]  # as an estimate's
    amplitude, _, phase, line_rms = encoder_error_summary(harmonics)
    return {"count": list(range(line_errors_counts.size)), "error_counts": line_errors_counts.tolist(),
            "eccentricity_counts": amplitude, "eccentricity_phase_rad": phase, "line_rms_counts": line_rms}


def simulated_description(simulator: Simulator, limits: BenchLimits) -> BenchDescription:
    """What the simulated bench tells before its first trial: what its controller knows, and ``limits``."""
    m = simulator.model
    return BenchDescription(
        motor=MotorInfo(m.winding.pole_pairs, m.winding.slots, m.encoder.counts_per_rev, m.mechanics.inertia_kgm2),
        backemf_nm_per_a=simulator.backemf_counts,
        calibration=m.controller.calibration(),
        limits=limits,
    )


def simulated_bench(config: CampaignConfig, seed: int | None = None, revolutions: int | None = None,
                    on_done: Callable[[int, TrialData], None] | None = None,
                    torque_sensor: bool = True) -> tuple[Bench, dict]:
    """Run the set-point grid in memory: the bench folder's contents and its truth (`truth_dict`).

    Parameters
    ----------
    config : the campaign.
    seed, revolutions : override the config's ``[trials]`` values.
    on_done : called with (index, trial) as each trial finishes.
    torque_sensor : False: a bench without a torque sensor (no torque column, [motor] torque_sensor =
        false, with the encoder's timer_resolution_s); the simulator's torque sensor still runs, unrecorded.

    Raises `ConfigError` before any trial runs when a grid request breaks the config's [limits].
    """
    seed = config.grid.seed if seed is None else seed
    revolutions = config.grid.revolutions if revolutions is None else revolutions
    lim = config.limits
    simulator = Simulator(config.simulated_model(), config.grid.warmup_revolutions)
    bench_limits = BenchLimits(lim.max_current_a, lim.max_torque_nm, lim.max_speed_hz)
    description = simulated_description(simulator, bench_limits)
    requests = grid_requests(config, description.calibration, seed, revolutions)
    check_plan(grid_plan(config, requests), description,
               SafetyLimits.of_campaign(lim, bench_limits, config.grid.warmup_revolutions))
    trials = simulator.run_trials(requests, on_done=on_done)
    if not torque_sensor:
        trials = [replace(trial, torque_nm=None) for trial in trials]
    bench = Bench(
        motor=description.motor if torque_sensor else replace(
            description.motor, torque_sensor=False, timer_resolution_s=simulator.model.encoder.timer_resolution_s),
        backemf_nm_per_a=simulator.backemf_counts,
        sensors=requests[0].calibration,
        trials=tuple(trials),
        trial_files=tuple(f"trial_{i + 1:02d}.csv" for i in range(len(trials))),
    )
    return bench, truth_dict(simulator, requests[0])


def simulate_bench(config: CampaignConfig, out_dir: str | Path, seed: int | None = None,
                   revolutions: int | None = None,
                   on_done: Callable[[int, TrialData], None] | None = None, torque_sensor: bool = True) -> Bench:
    """`simulated_bench`, written as a bench folder plus ``truth.json`` in ``out_dir`` (created if needed)."""
    bench, truth = simulated_bench(config, seed, revolutions, on_done, torque_sensor)
    out_dir = Path(out_dir)
    write_bench(out_dir, bench)
    (out_dir / "truth.json").write_text(json.dumps(truth, indent=1))
    return bench
