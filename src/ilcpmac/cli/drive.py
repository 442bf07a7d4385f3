"""``ilcpmac run`` of a config with a [drive] table: the drive campaign (docs/moteus.md) on a drive backend."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import click
from rich.text import Text

from ilcpmac.cli import console

if TYPE_CHECKING:
    from ilcpmac.config import CampaignConfig


def run_drive(config: CampaignConfig, out_dir: Path | None, backend_name: str | None, address: str | None,
              write_config: bool) -> None:
    """Run the drive campaign of ``config`` (`ilcpmac.campaign.service.run_drive`), printing each trial's line, the
    result and the files written."""
    # imported when the command runs (ilcpmac.cli's docstring says why)
    from ilcpmac.campaign.service import run_drive as run

    try:
        with console.status("drive campaign running: a line as each trial ends"):
            result = run(config, out=out_dir, backend=backend_name, address=address, write_config=write_config,
                         on_event=lambda line: console.print(Text(line)))
    except KeyboardInterrupt:
        click.echo("error: interrupted: the drive was told to stop; nothing was written to its flash", err=True)
        sys.exit(130)
    written = ", ".join(sorted(p.name for p in result.path.iterdir()))
    store = ("" if result.stored else "\nthe drive's flash is unchanged; to store the table: ilcpmac run "
             f"{shlex.quote(str(config.path))} --write-config, or send moteus_cogging.txt's conf set lines, then "
             "conf write")
    console.print(Text(f"wrote {written} in {result.path}{store}"), soft_wrap=True)
