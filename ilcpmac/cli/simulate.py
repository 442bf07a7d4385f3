"""``ilcpmac simulate``: the multisine set-point grid on the simulator, as a bench folder."""

from __future__ import annotations

from pathlib import Path

import click

from ilcpmac.cli import console, main, progress_bar


@main.command()
@click.argument("config", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Bench folder to write.")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="Override [trials] seed.")
@click.option("--revolutions", type=click.IntRange(min=1), default=None,
              help="Override [trials] revolutions (recorded, after the warm-up).")
@click.option("--no-torque-sensor", "no_torque_sensor", is_flag=True,
              help="A bench without a torque sensor: no torque column, [motor] torque_sensor = false.")
def simulate(config: Path, out_dir: Path, seed: int | None, revolutions: int | None, no_torque_sensor: bool) -> None:
    """Simulate CONFIG's multisine set-point grid into a bench folder.

    The folder also gets truth.json: the simulator's true values under the result keys (the encoder's
    line errors included).
    """
    # imported when the command runs (ilcpmac.cli's docstring says why)
    import dataclasses

    from ilcpmac.campaign import simulate_bench
    from ilcpmac.config import check_config, load_config

    cfg = load_config(config)
    if seed is not None or revolutions is not None:
        grid = cfg.grid
        cfg = dataclasses.replace(cfg, grid=dataclasses.replace(
            grid, seed=grid.seed if seed is None else seed,
            revolutions=grid.revolutions if revolutions is None else revolutions))
        check_config(cfg)
    out_dir.mkdir(parents=True, exist_ok=True)  # a folder that cannot be made fails before the trials run
    n = len(cfg.grid.torque_setpoints_nm) * len(cfg.grid.speed_setpoints_hz)
    with progress_bar() as progress:
        task = progress.add_task("simulating trials", total=n)
        bench = simulate_bench(cfg, out_dir, on_done=lambda i, trial: progress.advance(task),
                               torque_sensor=not no_torque_sensor)
    samples = sum(t.n_samples for t in bench.trials)
    console.print(f"wrote {len(bench.trials)} trials ({samples} samples) and truth.json to {out_dir}")
