"""Benchmark of the default campaign (issue: compensation pipeline targets).

Runs ``ilcpmac run`` on configs/seed-bench.toml (the README's main job) as a
user would, in subprocesses:

1. with a cold numba cache (an empty NUMBA_CACHE_DIR), then warm, timing each;
2. the same campaign with fixed-gain ILC (gamma = 0.5, estimation "fixed")
   side by side with the default estimation-based ILC.

It prints, per ILC set point, the uncompensated and final true ripple
(peak-to-peak, % of mean torque), the reduction factors and the ILC trials
used, against the targets: final true ripple <= 0.1 % pp at every ILC set
point, >= 20x below the uncompensated trial, within <= 10 ILC trials;
estimation-based below fixed-gain; whole run <= 4 s warm and <= 15 s cold, and
its run directory <= 60 MB (issue 10; benchmarks/storage.py sets these beside
the CSV run directories of an earlier revision).

Usage: python benchmarks/campaign.py
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "seed-bench.toml"
ILCPMAC = [sys.executable, "-c", "from ilcpmac.cli import main; main()"]


def run_campaign(config: Path, out: Path, cache_dir: Path) -> tuple[float, dict]:
    """Run ``ilcpmac run CONFIG --out OUT``; return its wall time and summary.json (with the run directory's
    size in MB under ``"run_dir_mb"``)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir))
    start = time.perf_counter()
    done = subprocess.run([*ILCPMAC, "run", str(config), "--out", str(out)], cwd=ROOT, env=env,
                          capture_output=True, text=True)
    elapsed = time.perf_counter() - start
    if done.returncode != 0:
        sys.exit(f"ilcpmac run failed ({done.returncode}): {done.stderr.strip().splitlines()[-1:]}")
    summary = json.loads((out / "summary.json").read_text())
    summary["run_dir_mb"] = sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) / 1e6
    return elapsed, summary


def fixed_gain_config(directory: Path) -> Path:
    """The seed config with classical fixed-gain ILC, gamma = 0.5."""
    text = CONFIG.read_text()
    text = re.sub(r"(?m)^learning_gain = .*$", "learning_gain = 0.5", text)
    text = re.sub(r'(?m)^estimation = .*$', 'estimation = "fixed"', text)
    path = directory / "seed-bench-fixed-gain.toml"
    path.write_text(text)
    return path


def per_setpoint(summary: dict) -> dict[float, dict]:
    """Uncompensated and final figures per ILC set point."""
    out = {}
    for r in summary["trials"]:
        entry = out.setdefault(r["torque_setpoint"], {"ilc_trials": 0}) if r["role"] != "grid" else None
        if entry is None:
            continue
        if r["role"] == "baseline":
            entry["base"] = r
        else:
            entry["final"] = r
            entry["ilc_trials"] += r["role"] == "ilc"
    return out


def verdict(ok: bool) -> str:
    return "PASS" if ok else "MISS"


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cache = tmp / "numba-cache"
        cold_s, _ = run_campaign(CONFIG, tmp / "cold", cache)
        warm_s, summary = run_campaign(CONFIG, tmp / "warm", cache)
        _, fixed = run_campaign(fixed_gain_config(tmp), tmp / "fixed", cache)
        shutil.rmtree(cache, ignore_errors=True)

    est, fix = per_setpoint(summary), per_setpoint(fixed)
    print("\nDefault campaign (configs/seed-bench.toml), estimation-based ILC vs fixed-gain ILC (gamma 0.5)")
    header = (f"{'set point':>10} {'uncomp. true pp %':>18} {'final true pp %':>16} {'fixed-gain pp %':>16} "
              f"{'reduction true':>15} {'reduction meas':>15} {'ILC trials':>11}")
    print(header)
    print("-" * len(header))
    ok_pp = ok_red = ok_trials = ok_est = True
    for torque, e in sorted(est.items()):
        f = fix[torque]
        pp, pp_fixed = e["final"]["ripple_pp_true"], f["final"]["ripple_pp_true"]
        red = e["final"]["reduction_factor_true"]
        print(f"{torque:>8g} Nm {100 * e['base']['ripple_pp_true']:>18.3f} {100 * pp:>16.4f} "
              f"{100 * pp_fixed:>16.4f} {red:>14.0f}x {e['final']['reduction_factor']:>14.0f}x "
              f"{e['ilc_trials']:>11d}")
        ok_pp &= pp <= 0.001
        ok_red &= red >= 20
        ok_trials &= e["ilc_trials"] <= 10
        ok_est &= pp < pp_fixed
    print("\nTargets")
    print(f"  final true ripple <= 0.1 % pp at every ILC set point   {verdict(ok_pp)}")
    print(f"  >= 20x below the uncompensated trial                  {verdict(ok_red)}")
    print(f"  within <= 10 ILC trials per set point                 {verdict(ok_trials)}")
    print(f"  estimation-based ILC below fixed-gain (gamma 0.5)     {verdict(ok_est)}")
    print(f"  whole default run, warm numba cache: {warm_s:6.1f} s (<= 4 s)    {verdict(warm_s <= 4)}")
    print(f"  whole default run, cold numba cache: {cold_s:6.1f} s (<= 15 s)   {verdict(cold_s <= 15)}")
    size = summary["run_dir_mb"]
    print(f"  run directory:                       {size:6.1f} MB (<= 60 MB) {verdict(size <= 60)}")


if __name__ == "__main__":
    main()
