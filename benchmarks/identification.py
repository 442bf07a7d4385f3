"""Identification benchmark: accuracy of the report's method and the joint fit, Cramer-Rao, wall time.

    python benchmarks/identification.py [--seeds N] [--bench DIR]

1. The error of each estimate for the report's method and for the joint fit,
   side by side with the targets, on the seed bench (configs/seed-bench.toml,
   simulated), on a bench of another motor generated from eqs. (1.3) and (3.1),
   and on that motor with a first-order current-loop lag near the top
   excitation harmonic.
2. A Monte Carlo over simulator seeds: the spread of each joint estimate
   against its Cramer-Rao bound sigma^2 (X^T X)^-1 of the joint model (target
   at most 1.5x).
3. The wall time to identify the seed-bench folder after JIT warm-up, with
   its reading timed apart, as CSV and as Parquet.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ilcpmac.bench.format import Bench, convert_bench, read_bench
from ilcpmac.campaign.service import simulate_bench, simulated_bench
from ilcpmac.config import load_config
from ilcpmac.identify import identify_bench
from ilcpmac.sim.reduced import ReducedCampaign, ReducedMotor, ReducedSensors, reduced_bench

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "seed-bench.toml"
#: (label, result field, kind, target): kind "rel" is a relative error, "abs" the largest absolute error
ROWS = (("delta*eps", "delta_epsilon", "total_system_gain", "rel", 0.005),
        ("delta", "delta", "torque_sensor_gain", "rel", 0.015),
        ("eps", "epsilon", "epsilon", "rel", 0.02),
        ("alpha", "alpha", "alpha", "abs", 0.003),
        ("beta (A)", "beta", "beta", "abs", 0.01))
LAG_TARGETS = {"delta_epsilon": 0.03, "delta": 0.03, "alpha": 0.01}


def seed_bench(seed: int) -> tuple[Bench, dict]:
    """The seed bench simulated in memory with ``seed``."""
    return simulated_bench(load_config(CONFIG), seed)


def error(method, field: str, truth: dict, key: str, kind: str) -> float | None:
    value = getattr(method, field)
    if value is None:
        return None
    if kind == "rel":
        return abs(value / truth[key] - 1.0)
    return float(np.max(np.abs(np.asarray(value) - truth[key])))


def cogging_error(method, truth: dict) -> float | None:
    if method.cogging_nm is None:
        return None
    true = np.asarray(truth["cogging"]["torque"])
    return float(np.sqrt(np.mean((method.cogging_nm - true) ** 2) / np.mean(true**2)))


def fmt(value: float | None, kind: str) -> str:
    if value is None:
        return "-"
    return f"{100 * value:.3f} %" if kind == "rel" else f"{value:.4f}"


def accuracy_table(label: str, bench: Bench, truth: dict, targets: dict | None = None) -> None:
    result = identify_bench(bench)
    report, joint = result.methods["report"], result.methods["joint"]
    print(f"\n{label}: {len(bench.trials)} trials; current loop identified: "
          f"{result.current_loop_bandwidth_per_phase_hz and np.round(result.current_loop_bandwidth_per_phase_hz, 1)}"
          f" Hz; report's residue {100 * result.diagnostics['system_gain']['residue']:.1f} %")
    print(f"  {'estimate':<10} {'report':>12} {'joint':>12} {'target':>10}")
    for name, field, key, kind, target in ROWS:
        if targets is not None:
            if field not in targets:
                continue
            target = targets[field]
        print(f"  {name:<10} {fmt(error(report, field, truth, key, kind), kind):>12} "
              f"{fmt(error(joint, field, truth, key, kind), kind):>12} {fmt(target, kind):>10}")
    if targets is None:
        print(f"  {'cogging':<10} {fmt(cogging_error(report, truth), 'rel'):>12} "
              f"{fmt(cogging_error(joint, truth), 'rel'):>12} {fmt(0.03, 'rel'):>10}")
    for message in result.messages:
        print("  message:", message)


def monte_carlo(seeds: int) -> None:
    """Spread over simulator seeds of the joint estimates against their Cramer-Rao bound."""
    names = ["delta*eps", "alpha_a", "alpha_b", "alpha_c", "delta beta_a", "delta beta_b", "delta beta_c"]
    estimates, bounds = [], []
    for seed in range(1, seeds + 1):
        bench, _ = seed_bench(seed)
        joint = identify_bench(bench).details.joint
        crb = joint.cramer_rao
        beta_std = [joint.std_of({f"beta_star_{p}": 1.0}, crb) for p in "abc"]
        estimates.append([joint.delta_epsilon, *joint.alpha, *joint.beta_star_a])
        bounds.append([joint.delta_epsilon_std_of(crb), *joint.alpha_std_of(crb), *beta_std])
    estimates, bounds = np.array(estimates), np.array(bounds)
    spread = estimates.std(axis=0, ddof=1)
    bound = np.sqrt(np.mean(bounds**2, axis=0))
    print(f"\nMonte Carlo over {seeds} simulator seeds (joint fit): spread against the Cramer-Rao bound")
    print(f"  {'estimate':<14} {'spread':>11} {'CRB':>11} {'ratio':>7}   (target <= 1.5)")
    for name, s, b in zip(names, spread, bound):
        print(f"  {name:<14} {s:>11.3g} {b:>11.3g} {s / b:>7.2f}")


def read_times(folder: Path, repeats: int) -> str:
    """Best read_bench time of ``folder`` with its trials as CSV and as Parquet (converted in a temporary folder)."""
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for suffix in (".csv", ".parquet"):
            copy = Path(tmp) / suffix[1:]
            convert_bench(folder, copy, suffix)
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                read_bench(copy)
                times.append(time.perf_counter() - t0)
            out.append(f"{suffix[1:]} {min(times):.2f} s")
    return ", ".join(out)


def timing(folder: Path, repeats: int = 3) -> None:
    bench = read_bench(folder)
    read = read_times(folder, repeats)
    identify_bench(bench)  # JIT warm-up (numba caches compiled code on disk)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        identify_bench(bench)
        times.append(time.perf_counter() - t0)
    print(f"\nwall time, seed-bench folder ({len(bench.trials)} trials, {sum(t.n_samples for t in bench.trials)} "
          f"samples): read_bench best {read} (not counted); identify_bench best {min(times):.2f} s, "
          f"median {np.median(times):.2f} s (target <= 2 s for the whole process: benchmarks/storage.py)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=10, help="Monte Carlo seeds (default 10)")
    parser.add_argument("--bench", type=Path, default=None, help="seed-bench folder to time (default: simulate one)")
    args = parser.parse_args()

    accuracy_table("seed bench (simulator, seed 2009)", *seed_bench(2009))
    motor, sensors, campaign = ReducedMotor(), ReducedSensors(), ReducedCampaign()
    piezo = replace(sensors, torque=replace(sensors.torque, highpass_hz=0.05))
    accuracy_table("other motor (eqs. 1.3, 3.1; 4 pole pairs, 36 slots, 2048 counts; 1 % skipped counts, "
                   "0.05 Hz piezo)", *reduced_bench(motor, piezo, replace(
                       campaign, grid=replace(campaign.grid, seed=7), skip_fraction=0.01)))
    accuracy_table("other motor with a 110 Hz current-loop lag (top harmonic at 100 Hz)",
                   *reduced_bench(motor, sensors, replace(campaign, grid=replace(campaign.grid, seed=8),
                                                          current_loop_hz=110.0)), LAG_TARGETS)
    monte_carlo(args.seeds)
    if args.bench is not None:
        timing(args.bench)
    else:
        with tempfile.TemporaryDirectory() as folder:
            simulate_bench(load_config(CONFIG), folder)
            timing(Path(folder))


if __name__ == "__main__":
    main()
