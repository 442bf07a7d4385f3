"""``ilcpmac simulate``: the multisine set-point grid on the simulator as a bench folder, or a simulated drive
log (a standstill scan, a rolling log) with its import mapping."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from ilcpmac.cli import console, main, progress_bar
from ilcpmac.core.errors import IlcpmacError, OptionError

#: the options of one kind only, by kind (--seed serves every kind)
_KIND_OPTIONS = {"grid": ("revolutions", "no_torque_sensor"), "scan": ("revolutions", "rate_hz"),
                 "log": ("rate_hz", "speed_hz", "duration_s", "loop", "current_column", "jitter_s", "load_nm",
                         "encoder_bits")}


@main.command()
@click.argument("config", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder to write.")
@click.option("--kind", type=click.Choice(["grid", "scan", "log"]), default="grid", show_default=True,
              help="grid: the multisine set-point grid as a bench folder; scan: a standstill scan log; log: a "
                   "rolling drive log (both with mapping.toml for ilcpmac import).")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="Override [trials] seed.")
@click.option("--revolutions", type=click.IntRange(min=1), default=None,
              help="grid: override [trials] revolutions (recorded, after the warm-up); scan: revolutions each "
                   "way (default 1).")
@click.option("--no-torque-sensor", "no_torque_sensor", is_flag=True,
              help="grid: a bench without a torque sensor: no torque column, [motor] torque_sensor = false.")
@click.option("--rate-hz", type=float, default=None, help="scan, log: rows per second (default 1000).")
@click.option("--speed-hz", type=float, default=None, help="log: mechanical speed reference, Hz (default 0.5).")
@click.option("--duration-s", type=float, default=None, help="log: duration, s (default 10).")
@click.option("--loop", type=click.Choice(["speed", "position", "current"]), default=None,
              help="log: the loop the drive closes (default speed).")
@click.option("--current-column", type=click.Choice(["q", "phases"]), default=None,
              help="log: i_q, or the phase currents i_a, i_b, i_c (default q).")
@click.option("--jitter-s", type=float, default=None,
              help="log: each row's instant drawn within +-JITTER_S of its slot (default 0).")
@click.option("--load-nm", type=float, default=None,
              help="log: constant load torque against the motion, N m (default 0.2).")
@click.option("--encoder-bits", type=int, default=None,
              help="log: the drive's encoder, which its loop reads and its log holds in rad: 2^BITS lines per "
                   "revolution, the reading rounded to the nearest line, independent of [bench] counts_per_rev "
                   "(default 20).")
def simulate(config: Path, out_dir: Path, kind: str, seed: int | None, revolutions: int | None,
             no_torque_sensor: bool, **log_options) -> None:
    """Simulate CONFIG's grid, scan or drive log into a folder.

    grid: a bench folder of the multisine set-point grid, and truth.json: the simulator's true values under the
    result keys (the encoder's line errors included). scan, log: the log, mapping.toml (ilcpmac import LOG --map
    mapping.toml --out BENCH takes it as it is), backemf.csv and truth.json (docs/simulator.md, "ilcpmac
    simulate").
    """
    # imported when the command runs (ilcpmac.cli's docstring says why)
    from ilcpmac import api
    from ilcpmac.config import load_config
    from ilcpmac.sim.log_folders import DRIVE_LOG, MAPPING, SCAN_LOG

    given = {"revolutions": revolutions, "no_torque_sensor": no_torque_sensor or None, **log_options}
    for name, value in given.items():
        if value is not None and name not in _KIND_OPTIONS[kind]:
            raise IlcpmacError(f"--{name.replace('_', '-')}: not for --kind {kind}")
    cfg = load_config(config)
    if kind == "grid":
        cfg = cfg.with_grid(seed, revolutions)
        out_dir.mkdir(parents=True, exist_ok=True)  # a folder that cannot be made fails before the progress bar
        n = len(cfg.grid.torque_setpoints_nm) * len(cfg.grid.speed_setpoints_hz)
        with progress_bar() as progress:
            task = progress.add_task("simulating trials", total=n)
            bench = api.simulate_bench(cfg, out_dir, torque_sensor=not no_torque_sensor,
                                       on_trial=lambda i, trial: progress.advance(task)).bench
        samples = sum(t.n_samples for t in bench.trials)
        console.print(f"wrote {len(bench.trials)} trials ({samples} samples) and truth.json to {out_dir}")
        return
    chosen: dict[str, Any] = {name: value for name, value in given.items() if value is not None}
    try:
        if kind == "scan":
            scan = api.simulate_scan(cfg, out_dir, seed=seed, **chosen)
            console.print(f"wrote {SCAN_LOG} (a standstill scan, {scan.plan.revolutions} revolution(s) each way), "
                          f"{MAPPING}, backemf.csv and truth.json to {out_dir}")
            return
        log = api.simulate_log(cfg, out_dir, seed=seed, **chosen)
    except OptionError as e:
        raise IlcpmacError(f"--{e.name.replace('_', '-')}: {e.why}") from None
    plan = log.plan
    console.print(f"wrote {DRIVE_LOG} ({plan.loop} loop, {plan.duration_s:g} s at {plan.rate_hz:g} Hz, "
                  f"K_t = {log.truth['torque_constant_nm_per_a']:.4g} N m / A), {MAPPING}, backemf.csv and truth.json "
                  f"to {out_dir}")
