"""``ilcpmac export``: a run's compensation.json as a drive's firmware reads it: JSON, CSV or C99."""

from __future__ import annotations

from pathlib import Path

import click
from rich.text import Text

from ilcpmac.cli import console, main


def _size(n_bytes: int) -> str:
    """``n_bytes`` for people: "812 B", "14.2 kB", "3.1 MB"."""
    if n_bytes < 1000:
        return f"{n_bytes} B"
    return f"{n_bytes / 1e3:.1f} kB" if n_bytes < 1e6 else f"{n_bytes / 1e6:.1f} MB"


#: ilcpmac.export.FORMATS, named here so that starting the CLI does not import numpy
FORMATS = ("json", "csv", "c")


@main.command()
@click.argument("run_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--format", "fmt", type=click.Choice(FORMATS), default="json", show_default=True,
              help="json: the record with its units; csv: calibration, torque gain, feed-forward and map tables; "
                   "c: a C99 header and source with the lookup function (docs/export.md).")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder to write into (made if missing).")
@click.option("--c-type", "c_type", type=click.Choice(("int16", "float")), default="int16", show_default=True,
              help="Element type of the C tables: int16 at a stated N m per LSB, or float.")
def export(run_dir: Path, fmt: str, out_dir: Path, c_type: str) -> None:
    """Export RUN_DIR's compensation for a drive's firmware.

    Reads RUN_DIR/compensation.json, which a campaign writes: the current-sensor calibration, the torque
    gain and the torque feed-forward per encoder count over the learned torque x speed points; writes them
    as JSON, CSV or C99 into --out (docs/export.md).
    """
    # imported when the command runs (ilcpmac.cli's docstring says why)
    from ilcpmac.campaign.rundir import RunFiles
    from ilcpmac.compensation import Compensation
    from ilcpmac.core.errors import BenchFormatError
    from ilcpmac.export import export as write

    path = RunFiles(run_dir).compensation
    if not path.exists():
        raise BenchFormatError(f"{run_dir} has no {path.name} (a campaign writes it when its learning "
                               "phase ends)")
    compensation = Compensation.read(path)
    exported = write(compensation, out_dir, fmt, c_type, str(path))
    width = max(len(p.name) for p in exported.files)
    lines = [f"  {p.name:<{width}}  {_size(p.stat().st_size)}" for p in exported.files]
    total = sum(p.stat().st_size for p in exported.files)
    if exported.quantisation_error_nm is not None:
        lines.append(f"int16 tables: quantisation error max |float - int16| = {exported.quantisation_error_nm:.3g} N m")
    # not wrapped: the path stays whole, to copy
    console.print(Text(f"wrote {len(exported.files)} files, {_size(total)}, in {out_dir}\n" + "\n".join(lines)),
                  soft_wrap=True)
