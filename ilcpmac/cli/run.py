"""``ilcpmac run``: the full campaign (identify, compensate, ILC) with a live table of the ripple."""

from __future__ import annotations

import json
import time
from pathlib import Path

import click
from rich.live import Live

from ilcpmac.cli import console, main

DEFAULT_CONFIG = Path("configs/seed-bench.toml")
RUN_FILE = "run.json"


def _backend(kind: str, address: str | None, config, limits):
    """The backend the campaign runs on; ``limits`` are the config's, announced by the simulator."""
    from ilcpmac.backends.base import BenchLimits
    from ilcpmac.errors import ConfigError

    if kind == "sim":
        from ilcpmac.backends.simulated import SimulatorBackend

        return SimulatorBackend(config.model, BenchLimits(limits.max_current_a, limits.max_torque_nm,
                                                          limits.max_speed_hz),
                                config.grid.warmup_revolutions)
    if not address:
        raise ConfigError("--backend remote needs --address HOST:PORT")
    from ilcpmac.backends.remote import RemoteBackend

    return RemoteBackend(address)


@main.command()
@click.argument("config", required=False, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Run directory to create (default runs/<config name>-<date>-<time>).")
@click.option("--backend", "backend_kind", type=click.Choice(["sim", "remote"]), default="sim", show_default=True,
              help="Run trials on the simulator or on a bench target (docs/protocol.md).")
@click.option("--address", help="HOST:PORT of the bench target, with --backend remote.")
@click.option("--trials", type=click.IntRange(min=1), default=None,
              help="Most ILC trials per set point (overrides [campaign] ilc_trials).")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="Override [trials] seed.")
@click.option("--resume", "resume_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Continue the run in this directory from its last complete trial.")
def run(config: Path | None, out_dir: Path | None, backend_kind: str, address: str | None, trials: int | None,
        seed: int | None, resume_dir: Path | None) -> None:
    """Run a campaign: identify, compensate, then learn the residual ripple with ILC.

    With no CONFIG, runs configs/seed-bench.toml on the simulator. Every trial is
    persisted as it finishes in the run directory (a bench folder); see
    docs/campaign.md.
    """
    import dataclasses

    from ilcpmac.campaign.rundir import RunDir, RunDirError
    from ilcpmac.campaign.runner import CampaignRunner
    from ilcpmac.config import load_config
    from ilcpmac.errors import ConfigError
    from ilcpmac.identify import identify_bench
    from ilcpmac.report.table import summary_table, trials_table

    if resume_dir is not None:
        if config is not None or out_dir is not None:
            raise ConfigError("--resume continues a run with its own config: give no CONFIG or --out")
        settings = json.loads((resume_dir / "states" / RUN_FILE).read_text()) \
            if (resume_dir / "states" / RUN_FILE).is_file() else None
        if settings is None:
            raise RunDirError(f"{resume_dir}: not a run directory (no states/{RUN_FILE})")
        config_path = resume_dir / "campaign.toml"
        seed, trials = settings["seed"], settings["trials"]
    else:
        config_path = config or DEFAULT_CONFIG
        if config is None and not config_path.is_file():
            raise ConfigError(f"no CONFIG given and {DEFAULT_CONFIG} is not here; give a campaign config")
    cfg = load_config(config_path)
    if trials is not None:
        cfg = dataclasses.replace(cfg, campaign=dataclasses.replace(cfg.campaign, ilc_trials=trials))
    seed = cfg.grid.seed if seed is None else seed
    backend = _backend(backend_kind, address, cfg, cfg.limits)
    try:
        description = backend.describe()
        if resume_dir is not None:
            run_dir = RunDir.resume(resume_dir, description)
        else:
            out_dir = out_dir or Path("runs") / f"{config_path.stem}-{time.strftime('%Y%m%d-%H%M%S')}"
            run_dir = RunDir.create(out_dir, description, config_path.read_text())
            run_dir.write_json(RUN_FILE, {"seed": seed, "trials": trials, "config": str(config_path)})
        records: list[dict] = []

        class Events:
            def trial(self, record: dict, all_records: list[dict]) -> None:
                records[:] = all_records
                live.update(trials_table(records, f"ilcpmac run  {run_dir.path}"))

            def message(self, text: str) -> None:
                live.console.print(f"[bold]{text}[/bold]")

        with Live(trials_table([], f"ilcpmac run  {run_dir.path}"), console=console, refresh_per_second=4,
                  vertical_overflow="visible") as live:
            runner = CampaignRunner(cfg, backend, run_dir, seed, identify_bench, Events())
            summary = runner.run()
    finally:
        close = getattr(backend, "close", None)
        if close is not None:
            close()
    console.print(summary_table(summary, list(cfg.campaign.ilc_torque_setpoints_nm)))
    final = summary["final"]
    if final:
        console.print("final (worst over the ILC set points): " + ", ".join(
            f"{k} = {100 * v:.3f} %" if k.startswith("ripple") else f"{k} = {v:.0f}x" for k, v in final.items()))
    console.print(f"run directory: {run_dir.path} (summary.json, bench.toml, states/)")
