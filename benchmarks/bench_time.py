"""Bench time of the default campaign, before and after (issue: minutes, not hours, on the bench).

Runs ``ilcpmac run`` as a user would, in subprocesses, on the simulator:

- *before*: the design of commit 615b840 from its own tree and config (git archive of that commit: 30 grid
  trials of 8 revolutions, learning trials of 160 s at 1 N m until the ripple stops improving, validation
  trials of 64 s), so nothing of today's code runs it;
- *after*: today's default, ``ilcpmac run`` (configs/seed-bench.toml);
- *quick*: ``ilcpmac run configs/quick.toml``.

It prints the motor's running time per phase (warm-ups included: each trial's warm-up and recorded revolutions
at its speed set point, from the trials' saved requests), the worst true ripple (peak-to-peak, % of mean torque)
at the learned and at the validation points, every point's final true ripple beside its noise floor (after and
quick; before has no floors: the noise its final trial's own true torque leaves in its average is shown
instead, computed here from the trial), the run directories' sizes, and plots the true ripple of every trial
after the identification against the cumulative motor time (bench_time.png in the output folder).

Usage: python benchmarks/bench_time.py [--out DIR] [--before COMMIT]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PHASES = ("identify", "compensate", "ilc", "validate")


def run(tree: Path, config: str, out: Path) -> None:
    """``python -m ilcpmac run CONFIG --out OUT`` with the package of ``tree`` (its folder first on the path)."""
    done = subprocess.run([sys.executable, "-m", "ilcpmac", "run", config, "--out", str(out)], cwd=tree,
                          env=dict(os.environ, COLUMNS="160"), capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"ilcpmac run {config} in {tree} failed ({done.returncode}): {done.stderr.strip()[-400:]}")


def trials(run_dir: Path) -> list[dict]:
    """summary.json's trials, each with its motor time ``motor_s`` from its saved request."""
    summary = json.loads((run_dir / "summary.json").read_text())
    warmup = tomllib.loads((run_dir / "campaign.toml").read_text())["trials"]["warmup_revolutions"]
    out = []
    for t in summary["trials"]:
        state = json.loads((run_dir / "states" / f"trial_{t['index']:03d}.json").read_text())
        out.append({**t, "motor_s": (warmup + state["request"]["revolutions"]) / t["speed_setpoint"]})
    return out


def final_noise_pp(run_dir: Path, index: int, torque: float, speed: float) -> float:
    """The peak-to-peak the true torque's own noise leaves in trial ``index``'s average, % of the set point."""
    from ilcpmac.bench.format import read_trial
    from ilcpmac.pipeline.analysis import TorqueSpectrum
    from ilcpmac.signals.harmonics import expected_noise_pp

    trial = read_trial(run_dir / f"trial_{index:03d}.parquet", torque, speed)
    spectrum = TorqueSpectrum.of(trial.count, trial.time_s, trial.torque_true_nm, 4096, 150)
    return 100 * expected_noise_pp(spectrum.variance_nm2, 4096) / float(np.mean(trial.torque_true_nm))


def points(run_dir: Path) -> list[dict]:
    """Every learned and validation point: its final true ripple, %, and its floor, % (summary.json's, or its
    final trial's own noise where the run has none)."""
    summary = json.loads((run_dir / "summary.json").read_text())
    if "points" in summary:
        return [{"point": (p["torque_setpoint"], p["speed_setpoint"]), "learned": p["learned"],
                 "true": 100 * p["ripple_pp_true"], "floor": 100 * p["floor_pp_true"], "kind": "floor"}
                for p in summary["points"]]
    finals: dict[tuple[float, float], dict] = {}
    for t in summary["trials"]:
        if t["role"] in ("compensate", "learn", "validate"):
            finals[(t["torque_setpoint"], t["speed_setpoint"])] = t
    return [{"point": p, "learned": t["role"] != "validate", "true": 100 * t["ripple_pp_true"],
             "floor": final_noise_pp(run_dir, t["index"], *p), "kind": "final trial's noise"}
            for p, t in finals.items()]


def size_mb(run_dir: Path) -> float:
    return sum(p.stat().st_size for p in run_dir.rglob("*") if p.is_file()) / 1e6


def plot(runs: dict[str, Path], path: Path) -> None:
    """The true ripple of every trial after the identification against the cumulative motor time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 5))
    for (name, run_dir), colour in zip(runs.items(), ("tab:red", "tab:blue", "tab:green")):
        done = trials(run_dir)
        minutes = np.cumsum([t["motor_s"] for t in done]) / 60
        shown = [(m, 100 * t["ripple_pp_true"], t["role"]) for m, t in zip(minutes, done)
                 if t["role"] in ("compensate", "learn", "validate")]
        for role, marker in (("compensate", "s"), ("learn", "o"), ("validate", "^")):
            xs = [m for m, _, r in shown if r == role]
            ax.scatter(xs, [v for _, v, r in shown if r == role], s=14, color=colour, marker=marker,
                       label=f"{name}: {role} trials" if xs else None, alpha=0.8)
        ax.axvline(minutes[-1], color=colour, lw=1, ls="--")
    ax.axhline(0.1, color="grey", lw=0.8, ls=":", label="0.1 % (learned-point target)")
    ax.axhline(0.2, color="grey", lw=0.8, ls="-.", label="0.2 % (validation-point target)")
    ax.set(xscale="log", yscale="log", xlabel="cumulative motor running time, min (warm-ups included)",
           ylabel="true ripple, % pp of the mean torque",
           title="Default campaign on the seed bench: each trial's true ripple against the motor's time so far")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None, help="where the runs and the plot go (default: a temp dir)")
    parser.add_argument("--before", default="615b840", help="the commit whose design is 'before'")
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_time-"))
    out.mkdir(parents=True, exist_ok=True)
    old = out / "before-tree"
    if not old.exists():
        old.mkdir()
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", args.before], capture_output=True, check=True)
        subprocess.run(["tar", "-x", "-C", str(old)], input=archive.stdout, check=True)
    runs = {"before": out / "before", "after": out / "after", "quick": out / "quick"}
    for name, tree, config in (("before", old, "configs/seed-bench.toml"), ("after", ROOT, "configs/seed-bench.toml"),
                               ("quick", ROOT, "configs/quick.toml")):
        if not (runs[name] / "summary.json").exists():
            run(tree, config, runs[name])
    print(f"motor running time per phase, min (warm-ups included); runs in {out}")
    print(f"{'phase':<12}" + "".join(f"{name:>10}" for name in runs))
    times = {name: trials(d) for name, d in runs.items()}
    for phase in (*PHASES, "all"):
        row = [sum(t["motor_s"] for t in done if phase in ("all", {"learn": "ilc"}.get(t["phase"], t["phase"])))
               / 60 for done in times.values()]
        print(f"{phase:<12}" + "".join(f"{v:>10.1f}" for v in row))
    print(f"{'trials':<12}" + "".join(f"{len(done):>10d}" for done in times.values()))
    print(f"{'run dir MB':<12}" + "".join(f"{size_mb(d):>10.1f}" for d in runs.values()))
    found = {name: points(d) for name, d in runs.items()}
    print("\nworst final true ripple, % pp of the mean torque (targets: learned <= 0.1, validation <= 0.2; quick "
          "<= 0.5 everywhere)")
    for learned in (True, False):
        row = [max(p["true"] for p in pts if p["learned"] == learned) for pts in found.values()]
        print(f"{'learned' if learned else 'validation':<12}" + "".join(f"{v:>10.3f}" for v in row))
    print("\nper point: final true ripple / its floor, % pp (before: the final trial's own noise in place of a floor)")
    print(f"{'point':<16}" + "".join(f"{name:>22}" for name in runs))
    for p in found["after"]:
        cells = []
        for pts in found.values():
            q = next((q for q in pts if q["point"] == p["point"]), None)
            cells.append("-" if q is None else f"{q['true']:.3f} / {q['floor']:.3f} ({q['true'] / q['floor']:.2f}x)")
        label = f"{p['point'][0]:g} N m {p['point'][1]:g} Hz{'' if p['learned'] else ' v'}"
        print(f"{label:<16}" + "".join(f"{c:>22}" for c in cells))
    plot(runs, out / "bench_time.png")
    print(f"\nplot: {out / 'bench_time.png'}")


if __name__ == "__main__":
    main()
