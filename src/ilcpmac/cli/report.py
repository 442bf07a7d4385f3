"""``ilcpmac report``: the figures of a run directory."""

from __future__ import annotations

from pathlib import Path

import click

from ilcpmac.cli import FIGURE_FORMATS, console, main


@main.command()
@click.argument("run_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Where to write the figures (default RUN_DIR/plots).")
@click.option("--format", "fmt", type=click.Choice(FIGURE_FORMATS), default="png", show_default=True,
              help="File format of the figures.")
def report(run_dir: Path, out_dir: Path | None, fmt: str) -> None:
    """Plot the run in RUN_DIR.

    Ripple per trial; per set point, the torque before and after compensation with its spectrum, and
    what each stage learned.
    """
    # imported when the command runs (ilcpmac.cli's docstring says why)
    from rich.markup import escape

    from ilcpmac.campaign.rundir import RunDirError
    from ilcpmac.report.plots import RunReport, write_report

    run = RunReport.read(run_dir)
    out_dir = out_dir or run.files.plots
    try:
        written, why = write_report(run, out_dir, fmt)
    except OSError as e:
        raise RunDirError(f"{e.filename or out_dir}: {e.strerror or e}") from None
    if why is not None:
        console.print(f"[yellow]warning:[/yellow] what each stage learned is not drawn: {escape(why)}")
    for path in written:
        console.print(f"wrote {escape(str(path))}")
