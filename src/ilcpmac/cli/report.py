"""``ilcpmac report``: the figures of a run directory, and its report as one HTML page."""

from __future__ import annotations

from pathlib import Path

import click

from ilcpmac.cli import FIGURE_FORMATS, console, main


@main.command()
@click.argument("run_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Where to write the figures and report.html (default RUN_DIR/plots).")
@click.option("--format", "fmt", type=click.Choice(FIGURE_FORMATS), default="png", show_default=True,
              help="File format of the figures (report.html embeds them as PNG).")
def report(run_dir: Path, out_dir: Path | None, fmt: str) -> None:
    """Plot the run in RUN_DIR and write its report as one HTML page.

    A campaign in both directions gets one per direction, in its forward/ and reverse/.

    Ripple per trial; per set point, the torque before and after compensation with its spectrum, and
    what each stage learned. report.html holds them with the plan and motor time, the ripple per operating
    point beside its floor, the identification with its standard errors and the export commands; it is
    self-contained, to open offline in any browser (docs/report.md).
    """
    # imported when the command runs (ilcpmac.cli's docstring says why)
    from rich.markup import escape
    from rich.text import Text

    from ilcpmac.campaign.quadrants import QUADRANTS_FILE, is_quadrants_dir
    from ilcpmac.campaign.rundir import RunDirError
    from ilcpmac.config import DIRECTIONS
    from ilcpmac.report.html import write_report
    from ilcpmac.report.plots import RunReport

    # a campaign in both directions: each direction's report, in its own run directory (or under --out)
    runs = [(run_dir, out_dir)] if not is_quadrants_dir(run_dir) else \
        [(run_dir / d, None if out_dir is None else out_dir / d) for d in DIRECTIONS if (run_dir / d).is_dir()]
    if not runs:
        raise RunDirError(f"{run_dir / QUADRANTS_FILE}: a campaign in both directions with neither direction's run "
                          "directory in it")
    for path, out in runs:
        run = RunReport.read(path)
        out = out or run.files.plots
        try:
            written = write_report(run, out, fmt)
        except OSError as e:
            raise RunDirError(f"{e.filename or out}: {e.strerror or e}") from None
        if written.why is not None:
            console.print(f"[yellow]warning:[/yellow] what each stage learned is not drawn: {escape(written.why)}")
        for figure in written.figures.values():
            console.print(f"wrote {escape(str(figure))}")
        # not wrapped: the path stays whole, to copy
        console.print(Text(f"wrote {written.page} (the report as one page: open it in a browser)"), soft_wrap=True)
