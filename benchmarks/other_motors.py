"""The default campaign on simulated motors other than the seed bench: every point against its floor, and the motor
time the plan stated against the time the motor ran (issue: minutes, not hours, on the bench).

Three motors differ from the seed bench in pole pairs, slots, encoder lines, inertia, current-loop bandwidth,
sensor errors, noise, friction and encoder error; each runs the seed config's [trials], [campaign] and [limits]
with the torque source left to its default (the sensor: their encoders are not perfect). Prints per motor the
stated and the run motor time, and per point the final true ripple against its floor (target: learned points
within 1.5x, validation points within 2x).

With ``--seeds``, each motor (and the seed bench) runs once per seed (``ilcpmac run --seed``: other noise,
other grid excitation), and a last table counts the points above their targets over all runs.

Usage: python benchmarks/other_motors.py [--out DIR] [--seeds N [N ...]]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SEED = ROOT / "configs" / "seed-bench.toml"

#: each motor's changes to the seed config, by dotted table
MOTORS = {
    "4 pole pairs, 24 slots, 2048 lines, J 0.005, 250 Hz loop, encoder 0.05 + 0.01 counts": {
        "bench": {"pole_pairs": 4, "slots": 24, "counts_per_rev": 2048, "inertia_kgm2": 0.005},
        "bench.backemf": {"amplitudes_nm_per_a": [0.3, 0.02, 0.01, 0.004]},
        "simulator.cogging": {"amplitudes_nm": [0.3, 0.05]},
        "simulator.controller": {"bandwidth_hz": 250.0},
        "simulator.current_sensors": {"epsilon": 0.9, "alpha": [1.05, 0.95, 1.0], "beta_a": [0.3, -0.2, -0.1],
                                      "noise_counts": 0.7},
        "simulator.torque_sensor": {"delta": 1.1, "noise_nm": 0.03},
        "simulator.mechanics": {"coulomb_friction_nm": 0.02},
        "simulator.encoder": {"eccentricity_counts": 0.05, "line_std_counts": 0.01, "line_seed": 3}},
    "7 pole pairs, 21 slots, 4096 lines, J 0.02, 180 Hz loop, encoder 0.03 + 0.015 counts": {
        "bench": {"pole_pairs": 7, "slots": 21, "counts_per_rev": 4096, "inertia_kgm2": 0.02},
        "bench.backemf": {"amplitudes_nm_per_a": [0.15, 0.01, 0.005, 0.002]},
        "simulator.cogging": {"amplitudes_nm": [0.4, 0.06]},
        "simulator.controller": {"bandwidth_hz": 180.0},
        "simulator.current_sensors": {"epsilon": 1.2, "alpha": [0.9, 1.05, 1.05], "beta_a": [-0.5, 0.4, 0.1],
                                      "noise_counts": 0.4},
        "simulator.torque_sensor": {"delta": 0.9, "noise_nm": 0.015},
        "simulator.mechanics": {"coulomb_friction_nm": 0.05},
        "simulator.encoder": {"eccentricity_counts": 0.03, "line_std_counts": 0.015, "line_seed": 5}},
    "5 pole pairs, 12 slots, 1024 lines, J 0.008, 110 Hz loop, encoder 0.05 + 0.02 counts": {
        "bench": {"pole_pairs": 5, "slots": 12, "counts_per_rev": 1024, "inertia_kgm2": 0.008},
        "bench.backemf": {"amplitudes_nm_per_a": [0.25, 0.015, 0.008, 0.003]},
        "simulator.cogging": {"amplitudes_nm": [0.6, 0.1]},
        "simulator.controller": {"bandwidth_hz": 110.0},
        "simulator.current_sensors": {"epsilon": 0.8, "alpha": [1.0, 1.1, 0.9], "beta_a": [0.6, -0.3, -0.3],
                                      "noise_counts": 0.5},
        "simulator.torque_sensor": {"delta": 0.75, "noise_nm": 0.02},
        "simulator.mechanics": {"coulomb_friction_nm": 0.01},
        "simulator.encoder": {"eccentricity_counts": 0.05, "line_std_counts": 0.02, "line_seed": 7}},
}


def config(changes: dict[str, dict], path: Path) -> Path:
    """The seed config with ``changes`` and the torque source left to its default, written to ``path``."""
    from ilcpmac.core.schema import toml_text

    data = tomllib.loads(SEED.read_text())
    data["campaign"].pop("torque_source", None)
    for dotted, values in changes.items():
        table = data
        for part in dotted.split("."):
            table = table.setdefault(part, {})
        table.update(values)
    path.write_text(toml_text(data))
    return path


def stated_s(path: Path) -> float:
    """The motor time the plan of config ``path`` states before its first trial, on the simulator, s."""
    from ilcpmac.backends.simulated import SimulatorBackend
    from ilcpmac.campaign.plan import CampaignPlan
    from ilcpmac.config import load_config

    cfg = load_config(path)
    limits = cfg.limits.bench_limits()
    description = SimulatorBackend(cfg.simulated_model(), limits, cfg.grid.warmup_revolutions).describe()
    return CampaignPlan.build(cfg, description, cfg.grid.seed).motor_time_s()


def run(config_path: Path, run_dir: Path, seed: int | None) -> dict:
    """summary.json of ``ilcpmac run CONFIG`` into ``run_dir`` (reused when it is there)."""
    if not (run_dir / "summary.json").exists():
        command = [sys.executable, "-m", "ilcpmac", "run", str(config_path), "--out", str(run_dir)]
        done = subprocess.run(command + ([] if seed is None else ["--seed", str(seed)]), cwd=ROOT,
                              capture_output=True, text=True)
        if done.returncode != 0:
            sys.exit(f"{run_dir.name} failed ({done.returncode}): {done.stderr.strip()[-400:]}")
    return json.loads((run_dir / "summary.json").read_text())


def ratios(summary: dict) -> tuple[list[float], list[float]]:
    """Each learned and each validation point's final true ripple over its floor."""
    learned, validated = [], []
    for p in summary["points"]:
        (learned if p["learned"] else validated).append(p["ripple_pp_true"] / p["floor_pp_true"])
    return learned, validated


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None, help="where the runs go (default: a temp dir)")
    parser.add_argument("--seeds", type=int, nargs="+", default=None,
                        help="run every motor once per seed and count the points above target over all runs")
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="other_motors-"))
    out.mkdir(parents=True, exist_ok=True)
    if args.seeds:
        rows = [("seed bench", SEED)] + [(f"motor {k}", config(changes, out / f"motor{k}.toml"))
                                         for k, changes in enumerate(MOTORS.values(), start=1)]
        print(f"{'':<12}{'seed':>6}  {'learned / floor':>16}  {'validation / floor':>18}  {'worst learned':>13}  "
              f"{'worst valid.':>12}")
        above = below = points = 0
        for name, path in rows:
            for seed in args.seeds:
                summary = run(path, out / f"{name.replace(' ', '')}-s{seed}", seed)
                learned, validated = ratios(summary)
                above += sum(r > 1.5 for r in learned) + sum(r > 2.0 for r in validated)
                below += sum(r < 1.0 for r in learned + validated)
                points += len(learned) + len(validated)
                worst = [100 * max(p["ripple_pp_true"] for p in summary["points"] if p["learned"] == kind)
                         for kind in (True, False)]
                print(f"{name:<12}{seed:>6}  {min(learned):>7.2f}-{max(learned):<8.2f}  "
                      f"{min(validated):>9.2f}-{max(validated):<8.2f}  {worst[0]:>11.3f} %  {worst[1]:>10.3f} %")
        print(f"points above target (learned 1.5x, validation 2x): {above} of {points}; below their floor: {below}")
        return
    for k, (name, changes) in enumerate(MOTORS.items(), start=1):
        summary = run(config(changes, out / f"motor{k}.toml"), out / f"motor{k}", None)
        print(f"motor {k}: {name}")
        print(f"  motor time {summary['motor_time_s']['all'] / 60:.2f} min, the plan stated "
              f"{stated_s(out / f'motor{k}.toml') / 60:.2f} min")
        print(f"  {'point':<18}{'true %':>9}{'floor %':>9}{'ratio':>7}  target")
        for p in summary["points"]:
            ratio = p["ripple_pp_true"] / p["floor_pp_true"]
            target = 1.5 if p["learned"] else 2.0
            label = f"{p['torque_setpoint']:g} N m {p['speed_setpoint']:g} Hz{'' if p['learned'] else ' v'}"
            print(f"  {label:<18}{100 * p['ripple_pp_true']:>9.3f}{100 * p['floor_pp_true']:>9.3f}{ratio:>7.2f}  "
                  f"{'ok' if ratio <= target else f'above {target:g}x'}")


if __name__ == "__main__":
    main()
