"""Benchmark of the campaign's time, size and ILC (issues: compensation pipeline targets, issue 10).

Runs ``ilcpmac run`` as a user would, in subprocesses, on two configs:

- the *one-speed campaign* of issue 10: configs/seed-bench.toml as it was then (learning at 1, 3 and 5 N m
  at 0.75 Hz, 64/32/32 revolutions, patience 4, no validation), with a cold numba cache (an empty
  NUMBA_CACHE_DIR) and then warm, best of two; and the same with fixed-gain ILC (gamma = 0.5, estimation
  "fixed") side by side with the default estimation-based ILC;
- the default campaign of today (learning over the operating range, then validation), warm: what the later
  phases add (benchmarks/operating_range.py measures its accuracy).

It prints, per ILC set point of the one-speed campaign, the uncompensated and final true ripple
(peak-to-peak, % of mean torque), the reduction factors and the ILC trials used, against the targets: final
true ripple <= 0.1 % pp at every set point, >= 20x below the uncompensated trial, within <= 10 ILC trials;
estimation-based below fixed-gain; whole run <= 4 s warm and <= 15 s cold, and its run directory <= 60 MB
(issue 10; benchmarks/storage.py sets these beside the CSV run directories of an earlier revision).

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
ILCPMAC = [sys.executable, "-m", "ilcpmac"]


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


#: the [campaign] of issue 10's default run: one speed, no validation
ONE_SPEED = ("campaign", {"learn_speeds_hz": "[0.75]", "learn_revolutions": "[64, 32, 32]", "patience": "4",
                          "validate_torques_nm": "[]", "validate_speeds_hz": "[]"})
#: classical fixed-gain ILC, gamma = 0.5
FIXED_GAIN = ("stages.ilc", {"learning_gain": "0.5", "estimation": '"fixed"'})


def variant(directory: Path, name: str, *changes: tuple[str, dict[str, str]]) -> Path:
    """The seed config with ``changes`` (section, {key: TOML value}) applied, written to ``directory/name``: a key
    the seed config sets is replaced, one it leaves out is added at the top of its section."""
    text = CONFIG.read_text()
    for section, change in changes:
        for key, value in change.items():
            text, n = re.subn(rf"(?m)^{key} = .*$", f"{key} = {value}", text)
            if n == 0:
                text, n = re.subn(rf"(?m)^\[{re.escape(section)}\][^\n]*$", rf"\g<0>\n{key} = {value}", text)
            if n != 1:
                sys.exit(f"{CONFIG}: [{section}] {key} is set {n} times, or the section is missing")
    path = directory / name
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
            entry["ilc_trials"] += r["role"] == "learn"
    return out


def verdict(ok: bool) -> str:
    return "PASS" if ok else "MISS"


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cache = tmp / "numba-cache"
        one_speed = variant(tmp, "one-speed.toml", ONE_SPEED)
        cold_s, _ = run_campaign(one_speed, tmp / "cold", cache)
        warm = [run_campaign(one_speed, tmp / f"warm{k}", cache) for k in range(2)]
        warm_s, summary = min(warm, key=lambda w: w[0])
        _, fixed = run_campaign(variant(tmp, "fixed.toml", ONE_SPEED, FIXED_GAIN), tmp / "fixed", cache)
        default_s, default = run_campaign(CONFIG, tmp / "default", cache)
        shutil.rmtree(cache, ignore_errors=True)

    est, fix = per_setpoint(summary), per_setpoint(fixed)
    print("\nOne-speed campaign of issue 10 (seed bench, 0.75 Hz), estimation-based ILC vs fixed-gain ILC "
          "(gamma 0.5)")
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
    print(f"  whole run, warm numba cache (best of 2): {warm_s:6.1f} s (<= 4 s)    {verdict(warm_s <= 4)}")
    print(f"  whole run, cold numba cache:             {cold_s:6.1f} s (<= 15 s)   {verdict(cold_s <= 15)}")
    size = summary["run_dir_mb"]
    print(f"  run directory:                           {size:6.1f} MB (<= 60 MB) {verdict(size <= 60)}")
    print(f"\nThe default campaign of today (learning over 9 operating points, validation at 6): "
          f"{len(default['trials'])} trials against {len(summary['trials'])}, {default_s:.1f} s warm, "
          f"{default['run_dir_mb']:.1f} MB; load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
