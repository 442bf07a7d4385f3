"""The simulated bench: what it tells before its first trial, and the truth behind its trials."""

from __future__ import annotations

import numpy as np

from ilcpmac.core.records import BenchDescription, BenchLimits, IdentificationResult, SensorCalibration
from ilcpmac.signals.encoder_torque import encoder_error_summary
from ilcpmac.signals.harmonics import harmonic_amplitudes
from ilcpmac.sim.simulator import Simulator

__all__ = ["encoder_error_json", "simulated_description", "true_result", "truth_dict"]


def truth_dict(simulator: Simulator, calibration: SensorCalibration) -> dict:
    """truth.json: the true parameters under the result keys of docs/bench-format.md, at ``calibration``."""
    t = simulator.truth(calibration)
    cpr = simulator.record_counts_per_rev
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
        "encoder_error": encoder_error_json(simulator.line_errors_counts()),
    }


def true_result(simulator: Simulator, calibration: SensorCalibration) -> IdentificationResult:
    """The true parameters at ``calibration`` as an identification's result (`truth_dict` read back)."""
    return IdentificationResult.from_json(truth_dict(simulator, calibration))


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
        motor=simulator.motor_info(),
        backemf_nm_per_a=simulator.backemf_counts,
        calibration=m.controller.calibration(),
        limits=limits,
    )
