"""``ilcpmac run``: the full campaign (identify, compensate, ILC) with a live table of the ripple."""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import click
from rich.live import Live

from ilcpmac.cli import console, main

#: the packaged config ``ilcpmac run`` runs with no CONFIG
DEFAULT_CONFIG = "seed-bench.toml"


class LiveTable(Live):
    """The live table of trials; like rich's Progress, it ends its last line when the console is not a
    terminal, so that what follows (an error too) starts on a line of its own."""

    def stop(self) -> None:
        started = self.is_started
        super().stop()
        if started and not self.console.is_terminal:
            self.console.line()


@main.command()
@click.argument("config", required=False, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Run directory to create (default runs/<config name>-<date>-<time>).")
@click.option("--backend", "backend_kind", default="sim", show_default=True,
              help="Where trials run: any installed backend (ilcpmac backends lists them): sim, the simulator; "
                   "remote, a bench target (docs/protocol.md).")
@click.option("--address", help="Where the bench is, for backends that need it (remote: HOST:PORT).")
@click.option("--trials", type=click.IntRange(min=1), default=None,
              help="Most ILC trials per set point (overrides [campaign] ilc_trials).")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="Override [trials] seed.")
@click.option("--resume", "resume_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Continue the run in this directory from its last complete trial.")
def run(config: Path | None, out_dir: Path | None, backend_kind: str, address: str | None, trials: int | None,
        seed: int | None, resume_dir: Path | None) -> None:
    """Run a campaign: identify, compensate, then learn the residual ripple with ILC.

    With no CONFIG, runs the packaged seed-bench.toml on the simulator. Every trial is
    persisted as it finishes in the run directory (a bench folder); see
    docs/campaign.md.
    """
    import dataclasses

    from ilcpmac.backends.registry import BackendSetup, build_backend
    from ilcpmac.campaign.plan import CampaignPlan
    from ilcpmac.campaign.record import TrialRecord, records_of
    from ilcpmac.campaign.rundir import RunDir, RunFiles
    from ilcpmac.campaign.runner import CampaignRunner
    from ilcpmac.config import check_config, load_config, packaged_config
    from ilcpmac.errors import ConfigError
    from ilcpmac.identify import identify_bench
    from ilcpmac.report.table import summary_table, trials_table

    if resume_dir is not None and (config is not None or out_dir is not None):
        raise ConfigError("--resume continues a run with its own config: give no CONFIG or --out")
    # the run directory is locked before the backend is built: a second run on it, or one that cannot
    # write there, stops before the bench moves
    lock = RunDir.lock(resume_dir, new=False) if resume_dir is not None else None
    made_out_dir, run_dir = False, None
    try:
        if resume_dir is not None:
            settings = RunDir.read_settings(resume_dir)
            config_path = RunFiles(resume_dir).config
            seed, trials = settings.get("seed"), settings.get("trials")
        else:
            config_path = config or packaged_config(DEFAULT_CONFIG)
        cfg = load_config(config_path)
        if trials is not None:
            cfg = dataclasses.replace(cfg, campaign=dataclasses.replace(cfg.campaign, ilc_trials=trials))
        if seed is not None:
            cfg = dataclasses.replace(cfg, grid=dataclasses.replace(cfg.grid, seed=seed))
        check_config(cfg)  # the overrides obey the same ranges as the file
        seed = cfg.grid.seed
        if lock is None:
            out_dir = out_dir or Path("runs") / f"{config_path.stem}-{time.strftime('%Y%m%d-%H%M%S')}"
            made_out_dir = not out_dir.exists()
            lock = RunDir.lock(out_dir, new=True)
        backend = build_backend(backend_kind, BackendSetup(cfg, address))
        try:
            description = backend.describe()
            CampaignPlan.build(cfg, description, seed)  # before anything is written
            if resume_dir is not None:
                run_dir = RunDir.resume(resume_dir, description, lock)
            else:
                run_dir = RunDir.create(out_dir, description, config_path.read_text(),
                                        {"seed": seed, "trials": trials, "config": str(config_path)}, lock)
            class Events:
                def trial(self, record: TrialRecord, records: list[TrialRecord]) -> None:
                    live.update(trials_table(records, f"ilcpmac run  {run_dir.path}"))

                def message(self, text: str) -> None:
                    live.console.print(f"[bold]{text}[/bold]")

            with LiveTable(trials_table([], f"ilcpmac run  {run_dir.path}"), console=console, refresh_per_second=4,
                           vertical_overflow="visible") as live:
                runner = CampaignRunner(cfg, backend, run_dir, seed, identify_bench, Events())
                summary = runner.run()
        finally:
            backend.close()
    finally:
        if lock is not None:
            lock.release()
        if made_out_dir and run_dir is None:  # nothing was created: leave no empty directory behind
            shutil.rmtree(out_dir, ignore_errors=True)
    console.print(summary_table(records_of(summary), list(cfg.campaign.ilc_torque_setpoints_nm)))
    final = summary["final"]
    if final:
        console.print("final (worst over the ILC set points): " + ", ".join(
            f"{k} = {100 * v:.3f} %" if k.startswith("ripple") else f"{k} = {v:.0f}x" for k, v in final.items()))
    console.print(f"run directory: {run_dir.path} (summary.json, bench.toml, states/)")
