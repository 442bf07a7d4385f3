"""Benchmark of the compensation over the operating range (issue: compensation over the whole envelope).

Runs the default campaign, ``ilcpmac run`` on configs/seed-bench.toml (the README's main job), twice with a
warm numba cache, and prints per learned and per validation point (never learned) the uncompensated and final
true ripple (peak-to-peak, % of mean torque) and the reduction, against the targets:

- every validation point: true ripple <= 0.2 % pp and >= 100x below uncompensated, none worse than it;
- every learned point: <= 0.1 % pp;
- the whole default run, validation included: its trials and wall time, <= 20 s warm (best of two).

Side by side, on the same simulated bench and validation points, two compensations of the kind in use today,
built from the same run's compensation.json: a position-only table (the open-source anti-cogging maps: the
table learned at the middle torque and the slowest speed, applied everywhere), and a map over torque learned
at one speed (position-domain ILC learned at one speed: the slowest).

Usage: python benchmarks/operating_range.py
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "seed-bench.toml"
ILCPMAC = [sys.executable, "-m", "ilcpmac"]
#: seeds of the comparison trials, away from the campaign's
COMPARISON_SEED = 77_000


def run_campaign(out: Path) -> tuple[float, dict]:
    start = time.perf_counter()
    done = subprocess.run([*ILCPMAC, "run", str(CONFIG), "--out", str(out)], cwd=ROOT, capture_output=True,
                          text=True, env=dict(os.environ))
    elapsed = time.perf_counter() - start
    if done.returncode != 0:
        sys.exit(f"ilcpmac run failed ({done.returncode}): {done.stderr.strip().splitlines()[-1:]}")
    return elapsed, json.loads((out / "summary.json").read_text())


def comparison_ripple(run_dir: Path, points: list[tuple[float, float]]) -> dict[str, list[float]]:
    """True pp ripple (fraction) at ``points`` with the position-only and the one-speed compensations."""
    from ilcpmac.backends.registry import BackendSetup, build_backend
    from ilcpmac.campaign.plan import CampaignPlan
    from ilcpmac.compensation import Compensation, FadeOut
    from ilcpmac.config import load_config
    from ilcpmac.pipeline.analysis import TrialAnalysis

    cfg = load_config(run_dir / "campaign.toml")
    backend = build_backend("sim", BackendSetup(cfg, None))
    plan = CampaignPlan.build(cfg, backend.describe(), cfg.grid.seed)
    full = Compensation.read(run_dir / "compensation.json")
    middle = len(full.torques_nm) // 2
    never = FadeOut(float("inf"), float("inf"))
    variants = {
        "position only": replace(full, torques_nm=full.torques_nm[middle:middle + 1], speeds_hz=full.speeds_hz[:1],
                                 tables_nm=full.tables_nm[middle:middle + 1, :1], fade=never),
        "one speed": replace(full, speeds_hz=full.speeds_hz[:1], tables_nm=full.tables_nm[:, :1], fade=never)}
    motor = backend.describe().motor
    out = {}
    for name, compensation in variants.items():
        ripple = []
        for k, point in enumerate(points):
            request = compensation.apply(plan.base_request(point, COMPARISON_SEED + k))
            trial = replace(backend.run_trial(request), request=request)
            analysis = TrialAnalysis.of(trial, motor.counts_per_rev, cfg.campaign.ripple_harmonics)
            ripple.append(analysis.true.figures(analysis.true_mean_nm, motor.pole_pairs, motor.cogging_order).pp)
        out[name] = ripple
    backend.close()
    return out


def verdict(ok: bool) -> str:
    return "PASS" if ok else "MISS"


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        times = []
        for k in range(3):  # the first warms the numba cache
            seconds, summary = run_campaign(Path(tmp) / f"run{k}")
            times.append(seconds)
        run = Path(tmp) / "run2"
        size_mb = sum(p.stat().st_size for p in run.rglob("*") if p.is_file()) / 1e6
        validation = summary["validation"]
        others = comparison_ripple(run, [(v["torque_setpoint"], v["speed_setpoint"]) for v in validation])
    trials = summary["trials"]
    learned = {}
    for r in trials:
        if r["role"] in ("baseline", "compensate", "learn") and r["phase"] != "validate":
            entry = learned.setdefault((r["torque_setpoint"], r["speed_setpoint"]), {"trials": 0})
            if r["role"] == "baseline":
                entry["base"] = r["ripple_pp_true"]
            else:
                entry["final"], entry["reduction"] = r["ripple_pp_true"], r["reduction_factor_true"]
                entry["trials"] += 1
    print("\nOperating range of the default campaign (configs/seed-bench.toml); true ripple peak-to-peak, % of "
          "mean torque")
    header = (f"{'point':>6} {'torque N m':>10} {'speed Hz':>9} {'uncomp. %':>10} {'final %':>8} {'reduction':>10} "
              f"{'trials':>7} | {'position only %':>15} {'one speed %':>12}")
    print(header)
    print("-" * len(header))
    ok_learned = ok_valid = ok_reduction = ok_never_worse = True
    for (torque, speed), e in sorted(learned.items()):
        print(f"{'learn':>6} {torque:>10g} {speed:>9g} {100 * e['base']:>10.2f} {100 * e['final']:>8.4f} "
              f"{e['reduction']:>9.0f}x {e['trials']:>7d} | {'':>15} {'':>12}")
        ok_learned &= e["final"] <= 0.001
        ok_never_worse &= e["final"] < e["base"]
    for k, v in enumerate(validation):
        print(f"{'valid':>6} {v['torque_setpoint']:>10g} {v['speed_setpoint']:>9g} "
              f"{100 * v['uncompensated_pp_true']:>10.2f} "
              f"{100 * v['ripple_pp_true']:>8.4f} {v['reduction_factor_true']:>9.0f}x {'-':>7} | "
              f"{100 * others['position only'][k]:>15.3f} {100 * others['one speed'][k]:>12.3f}")
        ok_valid &= v["ripple_pp_true"] <= 0.002
        ok_reduction &= v["reduction_factor_true"] >= 100
        ok_never_worse &= not v["worse_than_uncompensated"]
    best = min(times[1:])
    print(f"\n{len(trials)} trials ({sum(r['role'] == 'grid' for r in trials)} grid), run directory {size_mb:.1f} MB; "
          f"wall time {', '.join(f'{t:.1f}' for t in times)} s (the first may warm the numba cache); "
          f"load average at the end {os.getloadavg()[0]:.2f}")
    print("\nTargets")
    print(f"  validation points: true ripple <= 0.2 % pp                 {verdict(ok_valid)}")
    print(f"  validation points: >= 100x below uncompensated            {verdict(ok_reduction)}")
    print(f"  no point worse than uncompensated                         {verdict(ok_never_worse)}")
    print(f"  learned points: true ripple <= 0.1 % pp                   {verdict(ok_learned)}")
    print(f"  whole default run, warm: best {best:5.1f} s (<= 20 s)             {verdict(best <= 20)}")


if __name__ == "__main__":
    main()
