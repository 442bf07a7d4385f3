"""``ilcpmac run`` of a config with a [drive] table: the drive campaign (docs/moteus.md) on a drive backend."""

from __future__ import annotations

import shlex
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import click
from rich.text import Text

from ilcpmac.cli import console
from ilcpmac.core.errors import ConfigError

if TYPE_CHECKING:
    from ilcpmac.config import CampaignConfig


def run_drive(config: CampaignConfig, out_dir: Path | None, backend_name: str | None, address: str | None,
              write_config: bool) -> None:
    """Run the drive campaign of ``config`` on its backend (``backend_name``, else its [campaign] backend) into
    ``out_dir`` (default runs/<config name>-<date>-<time>), printing each trial's line and the result."""
    # imported when the command runs (ilcpmac.cli's docstring says why)
    from ilcpmac.campaign.drive import run_drive_campaign
    from ilcpmac.campaign.service import built_backend

    path = out_dir or Path("runs") / f"{config.path.stem}-{time.strftime('%Y%m%d-%H%M%S')}"
    if path.exists() and (not path.is_dir() or any(path.iterdir())):
        raise ConfigError(f"--out {path}: exists and is not an empty directory: a drive campaign writes a new one")
    backend = built_backend(config, backend_name, address, write_config)
    try:
        result = run_drive_campaign(config, backend, path, lambda line: console.print(Text(line)), write_config)
    except KeyboardInterrupt:
        click.echo("error: interrupted: the drive was told to stop; nothing was written to its flash", err=True)
        sys.exit(130)
    finally:
        backend.close()
    written = ", ".join(sorted(p.name for p in path.iterdir()))
    store = ("" if result.stored else "\nthe drive's flash is unchanged; to store the table: ilcpmac run "
             f"{shlex.quote(str(config.path))} --write-config, or send moteus_cogging.txt's conf set lines, then "
             "conf write")
    console.print(Text(f"wrote {written} in {path}{store}"), soft_wrap=True)
