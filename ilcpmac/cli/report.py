"""``ilcpmac report``: PNG plots of a run directory."""

from __future__ import annotations

from pathlib import Path

import click

from ilcpmac.cli import console, main


@main.command()
@click.argument("run_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Where to write the PNGs (default RUN_DIR/plots).")
def report(run_dir: Path, out_dir: Path | None) -> None:
    """Plot a run: ripple per trial, torque before and after, its spectrum, the learned correction."""
    from ilcpmac.campaign.record import records_of
    from ilcpmac.campaign.rundir import RunDirError, RunFiles
    from ilcpmac.config import load_config, read_toml
    from ilcpmac.report import plots

    files = RunFiles(run_dir)
    summary = files.read_summary()
    try:
        records = records_of(summary)
    except (KeyError, TypeError, ValueError) as e:
        raise RunDirError(f"{files.summary}: unreadable ({e!r})") from None
    cfg = load_config(files.config)
    cpr = int(read_toml(files.bench, RunDirError)["motor"]["counts_per_rev"])
    out_dir = out_dir or files.plots
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        written = [out_dir / "ripple_per_trial.png"]
        plots.ripple_per_trial(records, written[0])
        written += plots.before_after(files, records, cpr, cfg.campaign.ripple_harmonics, out_dir)
        feedforward = {r.torque_setpoint_nm: files.read_state(r.index)["request"]["feedforward_nm"]
                       for r in records if r.learns}
        if feedforward:
            written.append(plots.learned_correction(feedforward, out_dir))
    except OSError as e:
        raise RunDirError(f"{e.filename or out_dir}: {e.strerror or e}") from None
    for path in written:
        console.print(f"wrote {path}")
