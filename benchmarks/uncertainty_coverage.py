"""Uncertainty coverage: |error| / reported standard error of every estimate on mismatched benches.

    python benchmarks/uncertainty_coverage.py [--seeds N]

The seed bench (configs/seed-bench.toml, simulated in memory) as it is, with
Coulomb friction, with a slower and a faster current loop, with a first-order
lag for a current loop and with more saturation, over N simulator seeds (default 2). Per bench, method and
estimate the largest |estimate - truth| / std over seeds and phases (honest
errors keep it within 3), the joint fit's reduced chi-square per harmonic
family, and the misfit warnings of the first seed.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from ilcpmac.bench.format import Bench
from ilcpmac.campaign.grid import grid_requests
from ilcpmac.config import load_config
from ilcpmac.core.records import MotorInfo
from ilcpmac.identify import identify_bench
from ilcpmac.model.motor import MotorModel
from ilcpmac.sim.bench import truth_dict
from ilcpmac.sim.simulator import Simulator

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "seed-bench.toml"
#: (label, result field, truth key)
ESTIMATES = (("delta*eps", "delta_epsilon", "total_system_gain"), ("delta", "delta", "torque_sensor_gain"),
             ("eps", "epsilon", "epsilon"), ("J*", "inertia_estimate", "inertia_estimate"),
             ("alpha", "alpha", "alpha"), ("beta", "beta", "beta"))


def benches(model: MotorModel) -> dict[str, MotorModel]:
    """The seed bench's drive and its mismatched variants."""
    def changed(part: str, **values) -> MotorModel:
        return replace(model, **{part: replace(getattr(model, part), **values)})

    return {"seed bench": model,
            "friction 0.05 N m": changed("mechanics", coulomb_friction_nm=0.05),
            "friction 0.2 N m": changed("mechanics", coulomb_friction_nm=0.2),
            "loop 80 Hz": changed("controller", bandwidth_hz=80.0),
            "loop 400 Hz": changed("controller", bandwidth_hz=400.0),
            "first-order lag": changed("controller", loop="lag"),
            "saturation x10": changed("unexplained", saturation_per_a2=3.0e-4)}


def simulated(model: MotorModel, seed: int) -> tuple[Bench, dict]:
    config = load_config(CONFIG)
    simulator = Simulator(model, config.grid.warmup_revolutions)
    requests = grid_requests(config, model.controller.calibration(), seed, config.grid.revolutions)
    bench = Bench(MotorInfo(model.winding.pole_pairs, model.winding.slots, model.encoder.counts_per_rev,
                            model.mechanics.inertia_kgm2),
                  simulator.backemf_counts, requests[0].calibration, tuple(simulator.run_trials(requests)),
                  tuple(f"trial_{i + 1:02d}.csv" for i in range(len(requests))))
    return bench, truth_dict(simulator, requests[0].calibration)


def ratio(method, field: str, truth: dict, key: str) -> float:
    value, std = getattr(method, field), getattr(method, field + "_std")
    if value is None or std is None:
        return float("nan")
    return float(np.max(np.abs(np.asarray(value) - truth[key]) / np.asarray(std)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=2, help="simulator seeds per bench (default 2)")
    args = parser.parse_args()
    seeds = [2009 + k for k in range(args.seeds)]
    print(f"largest |error| / std over seeds {seeds} and phases (honest: <= 3)")
    labels = " ".join(f"{label:>9}" for label, _, _ in ESTIMATES)
    print(f"  {'bench':<18} {'method':<7} {labels}   joint chi2/dof per harmonic family (largest over seeds)")
    for name, model in benches(load_config(CONFIG).model).items():
        results = [(identify_bench(bench), truth) for bench, truth in (simulated(model, s) for s in seeds)]
        for method in ("joint", "report"):
            worst = [max(ratio(r.methods[method], field, truth, key) for r, truth in results)
                     for _, field, key in ESTIMATES]
            families = ""
            if method == "joint":
                families = ", ".join(f"{g.label} {max(r.details.joint.misfit[i].chi2_reduced for r, _ in results):.2f}"
                                     for i, g in enumerate(results[0][0].details.joint.misfit))
            print(f"  {name:<18} {method:<7} " + " ".join(f"{w:>9.2f}" for w in worst) + f"   {families}")
        details = results[0][0].details
        for warning in (details.joint.warnings + details.system.warnings + details.sensor.warnings
                        + details.decoupling.warnings):
            print(f"    warning: {warning}")


if __name__ == "__main__":
    main()
