"""``ilcpmac simulate``: the multisine set-point grid on the simulator as a bench folder, or a simulated drive
log (a standstill scan, a rolling log) with its import mapping."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from ilcpmac.cli import console, main, progress_bar
from ilcpmac.core.errors import IlcpmacError, OptionError

#: the options of one kind only, by kind (--seed serves every kind)
_KIND_OPTIONS = {"grid": ("revolutions", "no_torque_sensor", "static_trial"), "scan": ("revolutions", "rate_hz"),
                 "log": ("rate_hz", "speed_hz", "duration_s", "loop", "current_column", "jitter_s", "latency_s",
                         "stamp_s", "position_unit", "position_wrap", "load_nm", "speed_bandwidth_hz", "encoder_bits",
                         "encoder_eccentricity_counts", "encoder_eccentricity_phase_rad", "encoder_harmonics",
                         "encoder_line_error_counts", "encoder_seed")}


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
@click.option("--static-trial", "static_trial", is_flag=True,
              help="grid: with a static trial (static.csv, [static] in bench.toml), the rotor held at 8 counts "
                   "under 4 torques up to the grid's largest, measured by a DC reference: it pins eps "
                   "(docs/real-bench.md, \"Pinning eps\").")
@click.option("--rate-hz", type=float, default=None, help="scan, log: rows per second (default 1000).")
@click.option("--speed-hz", type=float, default=None, help="log: mechanical speed reference, Hz (default 0.5).")
@click.option("--duration-s", type=float, default=None, help="log: duration, s (default 10).")
@click.option("--loop", type=click.Choice(["speed", "position", "current"]), default=None,
              help="log: the loop the drive closes (default speed).")
@click.option("--current-column", type=click.Choice(["q", "phases"]), default=None,
              help="log: i_q, or the phase currents i_a, i_b, i_c (default q).")
@click.option("--jitter-s", type=float, default=None,
              help="log: the host's polling: each request drawn within +-JITTER_S of its slot, the rows in time "
                   "order, s, within [0, 0.01] (default 0).")
@click.option("--latency-s", type=float, default=None,
              help="log: the drive's reading a uniform draw within [0, LATENCY_S] after the host stamps its "
                   "request, s, within [0, 0.01] (default 0).")
@click.option("--stamp-s", type=float, default=None,
              help="log: the host clock's tick: stamps in whole ticks (floor), a row whose stamp repeats the one "
                   "before left out, s, within [0, 0.001] (default 0: exact to a control period).")
@click.option("--position-unit", type=click.Choice(["rad", "counts"]), default=None,
              help="log: the position in rad, or in lines of the drive's encoder (default rad).")
@click.option("--position-wrap", "position_wrap", is_flag=True,
              help="log: the position wrapped into one revolution (a count_in_cpr column), not multi-turn.")
@click.option("--load-nm", type=float, default=None,
              help="log: constant load torque against the motion, N m (default 0.2).")
@click.option("--speed-bandwidth-hz", type=float, default=None,
              help="log: the speed loop's crossover, Hz, at most the control rate / 100 (default 30; a soft loop "
                   "of about 1 Hz stick-slips on a cogging motor).")
@click.option("--encoder-bits", type=int, default=None,
              help="log: the drive's encoder, read once per control period, which its loop reads and its log "
                   "holds: 2^BITS lines per revolution, within [8, 24], independent of [bench] counts_per_rev "
                   "(default 20).")
@click.option("--encoder-eccentricity-counts", type=float, default=None,
              help="log: the drive encoder's once-per-revolution error, lines (default 0).")
@click.option("--encoder-eccentricity-phase-rad", type=float, default=None,
              help="log: its phase at angle 0, rad (default 0).")
@click.option("--encoder-harmonics", type=str, default=None,
              help='log: the drive encoder\'s error harmonics, "ORDER:LINES[:PHASE_RAD],..." (e.g. "2:0.3,3:0.1:1.2"; '
                   "a magnetic encoder's nonlinearity; default none).")
@click.option("--encoder-line-error-counts", type=float, default=None,
              help="log: each line's span shifted by a uniform draw within +-this, lines, within [0, 0.5) "
                   "(default 0).")
@click.option("--encoder-seed", type=click.IntRange(min=0), default=None,
              help="log: seed of the lines' errors: the same encoder in every log of that seed (default 0).")
def simulate(config: Path, out_dir: Path, kind: str, seed: int | None, revolutions: int | None,
             no_torque_sensor: bool, static_trial: bool, position_wrap: bool, **log_options) -> None:
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

    given = {"revolutions": revolutions, "no_torque_sensor": no_torque_sensor or None,
             "static_trial": static_trial or None, "position_wrap": position_wrap or None, **log_options}
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
            bench = api.simulate_bench(cfg, out_dir, torque_sensor=not no_torque_sensor, static_trial=static_trial,
                                       on_trial=lambda i, trial: progress.advance(task)).bench
        samples = sum(t.n_samples for t in bench.trials)
        static = "" if bench.static is None else f", a static trial ({bench.static.count.size} samples)"
        console.print(f"wrote {len(bench.trials)} trials ({samples} samples){static} and truth.json to {out_dir}")
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
    plan, host = log.plan, log.truth["host"]
    left_out = f", {host['rows_left_out']} left out for a repeated stamp" if host["rows_left_out"] else ""
    console.print(f"wrote {DRIVE_LOG} ({plan.loop} loop, {plan.duration_s:g} s at {plan.rate_hz:g} Hz: {host['rows']} "
                  f"rows{left_out}; K_t = {log.truth['torque_constant_nm_per_a']:.4g} N m / A), {MAPPING}, "
                  f"backemf.csv and truth.json to {out_dir}")
