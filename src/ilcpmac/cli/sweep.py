"""``ilcpmac sweep``: many simulated campaigns (or identifications) with drawn parameters, on Dask."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from ilcpmac.cli import FIGURE_FORMATS, console, main, progress_bar

#: the combined table's formats (ilcpmac.sweep.results.TABLE_FORMATS, named here so that --help imports no Dask)
TABLE_FORMATS = ("parquet", "csv")


class _Progress:
    """The sweep's events on a rich progress bar: tasks done, and failures so far in its description."""

    def __init__(self, progress) -> None:
        self.progress = progress
        self.bar = None
        self.failed = 0

    def started(self, total: int, done: int) -> None:
        self.bar = self.progress.add_task("sweeping", total=total, completed=done)

    def finished(self, result) -> None:
        self.failed += result.failure is not None
        self.progress.update(self.bar, advance=1,
                             description=f"sweeping ({self.failed} failed)" if self.failed else "sweeping")


def _percent(column: str, value: float) -> str:
    return f"{100 * value:.3g} %" if "pp_true" in column else f"{value:.3g}"


@main.command()
@click.argument("config", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--spec", "spec_path", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="The sweep spec: what varies and how (docs/sweep.md).")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Sweep folder: tasks/, results/, results.parquet, summary.json, plots/.")
@click.option("--scheduler", default=None, help="A Dask scheduler, tcp://HOST:PORT (default: a local cluster).")
@click.option("--connect-timeout", "connect_timeout_s", type=click.FloatRange(min=0, max=3600, min_open=True),
              default=10.0, show_default=True, help="Seconds to wait for the --scheduler to answer.")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Worker processes of the local cluster, at most 4 per core (default: one per core).")
@click.option("--resume", is_flag=True, help="Continue the sweep in --out: its finished tasks are skipped.")
@click.option("--table-format", type=click.Choice(TABLE_FORMATS), default="parquet", show_default=True,
              help="Format of the combined results table.")
@click.option("--format", "plot_format", type=click.Choice(FIGURE_FORMATS), default="png", show_default=True,
              help="Format of the plots.")
@click.option("--worst", type=click.IntRange(min=0), default=5, show_default=True,
              help="How many of the worst tasks to name, with the command that reruns each.")
def sweep(config: Path, spec_path: Path, out_dir: Path, scheduler: str | None, connect_timeout_s: float,
          workers: int | None, resume: bool, table_format: str, plot_format: str, worst: int) -> None:
    """Run CONFIG many times with drawn parameters, on Dask.

    Every task's draws are checked first; each task's config is written to OUT/tasks/task_NNNN.toml as it is
    submitted; its results stream to OUT/results/ as it finishes. At the end: the combined table, the
    percentiles (summary.json), the failures and the worst tasks with the command that reruns each alone, and
    plots (docs/sweep.md).
    """
    # imported when the command runs (ilcpmac.cli's docstring says why)
    from rich.table import Table

    from ilcpmac.core.errors import ConfigError
    from ilcpmac.core.files import atomic_write
    from ilcpmac.sweep.plots import write_plots
    from ilcpmac.sweep.results import SUMMARY_FILE, combine, read_results, summarize
    from ilcpmac.sweep.runner import SweepRunner, check_local_workers, local_client, remote_client
    from ilcpmac.sweep.spec import load_spec

    if scheduler is not None and workers is not None:
        raise ConfigError("--workers sizes the local cluster: with --scheduler, the cluster's own workers run")
    if workers is not None:
        check_local_workers(workers)
    spec = load_spec(spec_path, config)
    runner = SweepRunner(spec, out_dir)
    try:
        tasks = runner.prepare(resume)
        # a resumed sweep with nothing left starts no cluster; one that cannot start is the command's one line
        client = None if not runner.pending(tasks) else \
            local_client(workers) if scheduler is None else remote_client(scheduler, connect_timeout_s)
        console.print(f"{len(tasks)} {spec.kind} tasks; their configs are in {out_dir / 'tasks'} as each is "
                      "submitted")
        if client is not None:
            try:
                with progress_bar() as progress:
                    runner.run(client, tasks, _Progress(progress))
            finally:
                client.close()
                if client.cluster is not None and scheduler is None:
                    client.cluster.close()
    except KeyboardInterrupt:  # its finished tasks' results are written: a resume skips them
        click.echo(f"error: interrupted; continue the sweep with {runner.resume_command()}", err=True)
        sys.exit(130)
    table_path = combine(out_dir, table_format)
    table = read_results(out_dir)
    summary = summarize(table, spec.kind, len(tasks), runner.rerun_command, worst)
    view = Table(title=f"sweep: {summary.finished - len(summary.failed)} of {len(tasks)} tasks ok",
                 title_justify="left", header_style="bold")
    for name in ("figure", "tasks", "median", "95th", "99th", "worst"):
        view.add_column(name, justify="left" if name == "figure" else "right")
    for p in summary.spread:
        view.add_row(p.column, str(p.count), *(_percent(p.column, v) for v in (p.median, p.p95, p.p99, p.worst)))
    console.print(view)
    for task in summary.failed:
        console.print(f"task {task.task} (seed {task.seed}) failed: {task.detail}\n  rerun: {task.rerun}",
                      soft_wrap=True)
    column = summary.main_figure
    if column is not None:  # else no task has a main figure, nor is the worst
        for case in summary.worst:
            console.print(f"worst {column} {_percent(column, case.detail)}: task {case.task} (seed {case.seed})\n"
                          f"  rerun: {case.rerun}", soft_wrap=True)
    atomic_write(out_dir / SUMMARY_FILE, json.dumps(summary.to_json(), indent=1))
    plots = write_plots(table, column, out_dir / "plots", plot_format) if column is not None else []
    console.print(f"wrote {table_path}, {out_dir / SUMMARY_FILE} and {len(plots)} plots in {out_dir / 'plots'}",
                  soft_wrap=True)
