"""The ``ilcpmac`` command line."""

from __future__ import annotations

import sys
from pathlib import Path

import click
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from ilcpmac.errors import IlcpmacError

console = Console(stderr=True)


class _Group(click.Group):
    """Reports an `IlcpmacError` as one line on stderr and exit status 2, never a traceback."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except IlcpmacError as e:
            click.echo(f"error: {e}", err=True)
            sys.exit(2)


def _progress() -> Progress:
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TimeElapsedColumn(), console=console, transient=False)


@click.group(cls=_Group)
@click.version_option(package_name="ilcpmac")
def main() -> None:
    """Identify and compensate the torque ripple of PM AC motors (Grassens 2009 and beyond)."""


@main.command()
@click.argument("config", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Bench folder to write.")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="Override [trials] seed.")
@click.option("--revolutions", type=click.IntRange(min=1), default=None,
              help="Override [trials] revolutions (recorded, after the warm-up).")
def simulate(config: Path, out_dir: Path, seed: int | None, revolutions: int | None) -> None:
    """Simulate CONFIG's multisine set-point grid into a bench folder with truth.json."""
    from ilcpmac.config import load_config
    from ilcpmac.sim.grid import simulate_bench

    cfg = load_config(config)
    n = len(cfg.grid.torque_setpoints_nm) * len(cfg.grid.speed_setpoints_hz)
    with _progress() as progress:
        task = progress.add_task("simulating trials", total=n)
        bench = simulate_bench(cfg, out_dir, seed=seed, revolutions=revolutions,
                               on_done=lambda i, trial: progress.advance(task))
    samples = sum(t.n_samples for t in bench.trials)
    console.print(f"wrote {len(bench.trials)} trials ({samples} samples) and truth.json to {out_dir}")
