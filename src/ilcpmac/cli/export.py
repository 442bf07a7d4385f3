"""``ilcpmac export``: a run's compensation.json, or an identification's position table, as a drive's firmware
reads it: JSON, CSV, C99, Fourier coefficients or moteus's cogging table."""

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


#: ilcpmac.export.FORMATS and ilcpmac.compensation.CONTENTS, named here so that starting the CLI does not import
#: numpy
FORMATS = ("json", "csv", "c", "harmonics", "moteus")
CONTENTS = ("cogging", "position-torque")


@main.command()
@click.argument("source", metavar="RUN_DIR|RESULT_JSON", type=click.Path(path_type=Path))
@click.option("--format", "fmt", type=click.Choice(FORMATS), default="json", show_default=True,
              help="json: the record with its units; csv: calibration, torque gain, feed-forward (and map) tables; "
                   "c: a C99 header and source with the lookup function; harmonics: Fourier coefficients per order "
                   "(a result only); moteus: its cogging_dq_comp conf lines (a result only) (docs/export.md).")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder to write into (made if missing).")
@click.option("--c-type", "c_type", type=click.Choice(("int16", "float")), default="int16", show_default=True,
              help="Element type of the C tables: int16 at a stated N m per LSB, or float.")
@click.option("--content", type=click.Choice(CONTENTS), default=None,
              help="Of a result: the cogging band (the default) or all the position-locked torque it holds.")
@click.option("--torque-constant", "torque_constant", type=float, default=None, metavar="NM_PER_A",
              help="q-axis torque constant, N m per A: needed by harmonics and moteus.")
@click.option("--rated-torque", "rated_torque", type=float, default=None, metavar="NM",
              help="Torque the residual ripple is stated in % of [default: the table's peak-to-peak].")
def export(source: Path, fmt: str, out_dir: Path, c_type: str, content: str | None, torque_constant: float | None,
           rated_torque: float | None) -> None:
    """Export a compensation for a drive's firmware.

    A run directory, or its compensation.json: the compensation a campaign writes (current-sensor calibration,
    torque gain, torque feed-forward per encoder count over the learned torque x speed points). A result JSON of ilcpmac
    identify (a bench's or a standstill scan's): the position torque feed-forward, which applies at every
    torque and speed, and the identified calibration. Writes into --out, all files or none, and prints the bounds
    the export keeps (a run directory's [limits], the drive's current) and the residual ripple the format leaves
    (docs/export.md); a record beyond them, or one the format cannot hold, is refused before anything is written.
    """
    # imported when the command runs (ilcpmac.cli's docstring says why)
    from ilcpmac.export import export_source

    exported = export_source(source, out_dir, fmt, c_type, content, torque_constant, rated_torque)
    width = max(len(p.name) for p in exported.files)
    lines = [f"  {p.name:<{width}}  {_size(p.stat().st_size)}" for p in exported.files]
    total = sum(p.stat().st_size for p in exported.files)
    assert exported.residual is not None
    lines += [bound.line() for bound in exported.bounds]
    lines.append(exported.residual.line(fmt))
    # not wrapped: the path stays whole, to copy
    console.print(Text(f"wrote {len(exported.files)} file{'s' if len(exported.files) > 1 else ''}, {_size(total)}, "
                       f"in {out_dir}\n" + "\n".join(lines)), soft_wrap=True)
