"""``ilcpmac report``: PNG plots of a run directory."""

from __future__ import annotations

import json
from pathlib import Path

import click

from ilcpmac.cli import console, main


@main.command()
@click.argument("run_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Where to write the PNGs (default RUN_DIR/plots).")
def report(run_dir: Path, out_dir: Path | None) -> None:
    """Plot a run: ripple per trial, torque before and after, its spectrum, the learned correction."""
    from ilcpmac.campaign.rundir import RunDirError
    from ilcpmac.config import load_config, read_toml
    from ilcpmac.report import plots

    summary_path = run_dir / "summary.json"
    if not summary_path.is_file():
        raise RunDirError(f"{run_dir}: no summary.json (not a run directory of ilcpmac run)")
    try:
        summary = json.loads(summary_path.read_text())
        records = summary["trials"]
    except (json.JSONDecodeError, KeyError) as e:
        raise RunDirError(f"{summary_path}: unreadable ({e})") from None
    cfg = load_config(run_dir / "campaign.toml")
    cpr = int(read_toml(run_dir / "bench.toml", RunDirError)["motor"]["counts_per_rev"])
    out_dir = out_dir or run_dir / "plots"
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        written = [out_dir / "ripple_per_trial.png"]
        plots.ripple_per_trial(records, written[0])
        written += plots.before_after(run_dir, records, cpr, cfg.campaign.ripple_harmonics, out_dir)
        feedforward = {}
        for r in records:
            if r["role"] in ("compensate", "ilc"):
                state = json.loads((run_dir / "states" / f"trial_{r['index']:03d}.json").read_text())
                feedforward[r["torque_setpoint"]] = state["request"]["feedforward_nm"]
        if feedforward:
            written.append(plots.learned_correction(feedforward, out_dir))
    except OSError as e:
        raise RunDirError(f"{e.filename or out_dir}: {e.strerror or e}") from None
    for path in written:
        console.print(f"wrote {path}")
