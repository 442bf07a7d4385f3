"""``ilcpmac identify``: the report's identification (ch. 1-4) and the joint fit on a bench folder."""

from __future__ import annotations

import json
from pathlib import Path

import click
from rich.table import Table

from ilcpmac.cli import console, main, progress_bar


def _cell(value, std, digits: int = 4) -> str:
    """'value +- std' for scalars and vectors; '-' when unknown."""
    if value is None:
        return "-"
    if hasattr(value, "__len__"):
        return ", ".join(_cell(v, s, digits) for v, s in zip(value, [None] * len(value) if std is None else std))
    return f"{value:.{digits}g} ± {std:.2g}" if std is not None else f"{value:.{digits}g}"


def estimates_table(result) -> Table:
    """The estimates of both methods with their standard errors; the chosen one first."""
    table = Table(title="identification (value ± standard error)")
    table.add_column("estimate")
    table.add_column("result")
    for name in result.methods:
        table.add_column(f"{name} method")
    rows = (("delta*eps", "delta_epsilon"), ("delta", "delta"), ("eps", "epsilon"), ("alpha", "alpha"),
            ("beta (A)", "beta"), ("J* (kg m²)", "inertia_estimate"))
    for label, name in rows:
        table.add_row(label, _cell(getattr(result, name), getattr(result, name + "_std")),
                      *(_cell(getattr(m, name), getattr(m, name + "_std")) for m in result.methods.values()))
    loop = result.current_loop_bandwidth_per_phase_hz
    table.add_row("current loop (Hz)", "-" if loop is None else ", ".join(f"{b:.0f}" for b in loop), "", "")
    return table


@main.command()
@click.argument("bench_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--output", "output", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Result JSON to write (docs/bench-format.md).")
@click.option("--plots", "plots_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Folder for the report-style figures.")
@click.option("--format", "plot_format", type=click.Choice(["png", "svg", "pdf"]), default="png", show_default=True,
              help="File format of the figures written by --plots.")
def identify(bench_dir: Path, output: Path, plots_dir: Path | None, plot_format: str) -> None:
    """Identify delta*eps, delta, eps, alpha, beta, J* and the cogging torque of BENCH_DIR."""
    from ilcpmac.bench.format import read_bench
    from ilcpmac.identify import STEPS, identify_bench

    with progress_bar() as progress:
        task = progress.add_task("reading bench folder", total=len(STEPS) + 1)
        bench = read_bench(bench_dir)

        def advance(step: str, index: int, total: int) -> None:
            progress.update(task, description=step, completed=index + 1)

        result = identify_bench(bench, advance)
        progress.update(task, description="done", completed=len(STEPS) + 1)
    for message in result.messages:
        console.print(f"[yellow]warning:[/yellow] {message}")
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(json.dumps(result.to_json(), indent=1, allow_nan=False))
    console.print(f"wrote {output}")
    if plots_dir is not None:
        from ilcpmac.identify.plots import write_plots

        written = write_plots(result, plots_dir, plot_format)
        console.print(f"wrote {len(written)} figures to {plots_dir}")
    click.echo()
    from rich.console import Console

    Console().print(estimates_table(result))
