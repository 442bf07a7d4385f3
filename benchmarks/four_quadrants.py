"""Benchmark of the campaign in all four quadrants (issue 38, item 4): configs/four-quadrant.toml on the simulated
seed bench, forward and reverse, motoring and generating.

Per point of each seed's run: its quadrant, the true peak-to-peak ripple after compensation against its true floor,
and the true mean torque against the set point; against the targets (every learned point within 1.5x its floor,
every validation point within 2x, the mean within 0.3 %). Side by side at each reverse validation point, with
trials run here at the motor's negative speed (the simulator's reverse laps): no compensation; the forward half
of the run's compensation.json alone (what a campaign learned turning one way gives in reverse: the record clamps
a negative speed to its slowest learned one); and the run's whole compensation.json of both directions (its
reverse tables mirrored back into the motor's coordinates).

Usage: python benchmarks/four_quadrants.py [--seeds 2009 1 2] [--config CONFIG] (default configs/four-quadrant.toml;
benchmarks/motors/small-actuator-four-quadrant.toml another motor)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "four-quadrant.toml"
#: seeds of the comparison trials, away from the campaign's
COMPARISON_SEED = 78_000
#: the targets of the issue
LEARNED_MAX, VALIDATION_MAX, MEAN_MAX = 1.5, 2.0, 0.003


def quadrant(torque: float, speed: float) -> str:
    return {(True, True): "Q1", (False, True): "Q4", (False, False): "Q3", (True, False): "Q2"}[(torque > 0,
                                                                                                speed > 0)]


def run(config: Path, out: Path, seed: int) -> float:
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "ilcpmac", "run", str(config), "--out", str(out), "--seed",
                           str(seed)], cwd=ROOT, capture_output=True, text=True, env=dict(os.environ))
    if done.returncode != 0:
        sys.exit(f"ilcpmac run failed ({done.returncode}): {done.stderr.strip().splitlines()[-1:]}")
    return time.perf_counter() - start


def points(run_dir: Path) -> list[dict]:
    """Every point of both directions in the motor's signs: quadrant, torque, speed, learned, ratio, mean error."""
    from ilcpmac.campaign.mean_torque import mean_torques_of

    rows = []
    for direction, sign in (("forward", 1.0), ("reverse", -1.0)):
        summary = json.loads((run_dir / direction / "summary.json").read_text())
        means = mean_torques_of(summary)
        for p in summary["points"]:
            torque, speed = p["torque_setpoint"], p["speed_setpoint"]
            mean = means[(torque, speed)]
            rows.append({"torque": sign * torque, "speed": sign * speed, "learned": p["learned"],
                         "pp": p["ripple_pp_true"], "floor": p["floor_pp_true"],
                         "mean": mean.true_nm / mean.point[0] - 1.0})
    return rows


def reverse_comparison(run_dir: Path, reverse_points: list[tuple[float, float]]) -> dict[str, list[float]]:
    """True pp ripple (fraction) at the motor's reverse points (T, S < 0) with none, the forward half and the whole
    of the run's compensation, on trials run here in reverse."""
    from ilcpmac.backends.registry import BackendSetup, build_backend
    from ilcpmac.compensation import Compensation
    from ilcpmac.config import load_config
    from ilcpmac.core.records import TrialRequest
    from ilcpmac.pipeline.analysis import TrialAnalysis

    cfg = load_config(run_dir / "campaign.toml")
    backend = build_backend("sim", BackendSetup(cfg, None))
    whole = Compensation.read(run_dir / "compensation.json")
    forward = whole.speeds_hz > 0
    half = replace(whole, speeds_hz=whole.speeds_hz[forward], tables_nm=whole.tables_nm[:, forward])
    motor = backend.describe().motor
    cpr = motor.counts_per_rev
    reverse = cfg.in_direction("reverse")
    out: dict[str, list[float]] = {"none": [], "forward half": [], "both directions": []}
    for k, (torque, speed) in enumerate(reverse_points):
        revolutions = reverse.trial_revolutions((-torque, -speed))
        for name, compensation in (("none", None), ("forward half", half), ("both directions", whole)):
            request = TrialRequest(torque, speed, revolutions, np.zeros(cpr), np.zeros(cpr),
                                   backend.describe().calibration, COMPARISON_SEED + k)
            if compensation is not None:
                request = compensation.apply(request)
            trial = backend.run_trial(request)  # the reverse lap, as the mirror's forward lap
            analysis = TrialAnalysis.of(replace(trial, request=trial.request), cpr, cfg.campaign.ripple_harmonics)
            out[name].append(analysis.true.figures(analysis.true_mean_nm, motor.pole_pairs, motor.cogging_order).pp)
    backend.close()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[2009, 1, 2])
    parser.add_argument("--config", type=Path, default=CONFIG)
    arguments = parser.parse_args()
    seeds, config = arguments.seeds, arguments.config.resolve()
    verdicts = {"learned": True, "validation": True, "mean": True}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            out = Path(tmp) / f"run{seed}"
            seconds = run(config, out, seed)
            rows = points(out)
            valid_reverse = [(r["torque"], r["speed"]) for r in rows if not r["learned"] and r["speed"] < 0]
            others = reverse_comparison(out, valid_reverse)
            print(f"\n{config.relative_to(ROOT) if config.is_relative_to(ROOT) else config}, seed {seed}: "
                  f"{len(rows)} points, wall {seconds:.1f} s; true ripple "
                  "pp, % of |mean torque|; true mean torque vs set point")
            header = (f"{'':>2} {'kind':>5} {'T N m':>6} {'S Hz':>5} {'final %':>8} {'floor %':>8} {'ratio':>6} "
                      f"{'mean %':>7} | {'none %':>7} {'fwd half %':>10} {'both %':>7}")
            print(header)
            print("-" * len(header))
            for r in sorted(rows, key=lambda r: (quadrant(r["torque"], r["speed"]), not r["learned"], r["torque"],
                                                   r["speed"])):
                ratio = r["pp"] / r["floor"]
                limit = LEARNED_MAX if r["learned"] else VALIDATION_MAX
                verdicts["learned" if r["learned"] else "validation"] &= ratio <= limit
                verdicts["mean"] &= abs(r["mean"]) <= MEAN_MAX
                side = ""
                if (r["torque"], r["speed"]) in valid_reverse:
                    k = valid_reverse.index((r["torque"], r["speed"]))
                    side = " ".join(f"{100 * others[n][k]:>{w}.3f}" for n, w in
                                    (("none", 7), ("forward half", 10), ("both directions", 7)))
                print(f"{quadrant(r['torque'], r['speed']):>2} {'learn' if r['learned'] else 'valid':>5} "
                      f"{r['torque']:>6g} {r['speed']:>5g} {100 * r['pp']:>8.4f} {100 * r['floor']:>8.4f} "
                      f"{ratio:>5.2f}x {100 * r['mean']:>+7.3f} | {side}")
            worst = {q: max(r["pp"] / r["floor"] for r in rows if quadrant(r["torque"], r["speed"]) == q
                            and r["learned"]) for q in ("Q1", "Q2", "Q3", "Q4")}
            print("worst learned ratio per quadrant: " + ", ".join(f"{q} {v:.2f}x" for q, v in worst.items()))
            print("reverse validation, median true pp: none {:.3f} %, forward half {:.3f} %, both directions {:.4f} %"
                  .format(*(100 * float(np.median(others[n])) for n in ("none", "forward half", "both directions"))))
    print("\nTargets (every seed, every point of every quadrant)")
    for key, target in (("learned", f"learned points within {LEARNED_MAX}x their true floor"),
                        ("validation", f"validation points within {VALIDATION_MAX}x their true floor"),
                        ("mean", f"true mean torque within {100 * MEAN_MAX:g} % of the set point")):
        print(f"  {target:<50} {'PASS' if verdicts[key] else 'MISS'}")


if __name__ == "__main__":
    main()
