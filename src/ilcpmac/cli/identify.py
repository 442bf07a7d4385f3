"""``ilcpmac identify``: the report's identification (ch. 1-4) and the joint fit on a bench folder."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import click
from rich.markup import escape
from rich.table import Table

from ilcpmac.cli import FIGURE_FORMATS, console, main, progress_bar

if TYPE_CHECKING:
    import numpy as np  # imported where used: the command's startup does without


#: the true values a simulated bench folder holds (``ilcpmac simulate``), under the result keys
TRUTH_FILE = "truth.json"


#: longest 'value ± std' at full precision; a longer one (extreme magnitudes) is shortened to fit 80 columns
CELL_CHARACTERS = 16
#: what a cell shows for an estimate its torque source cannot give (the reason in the table's caption)
NOT_IDENTIFIED = "not identified"
#: the lines a result on the encoder-derived torque cannot fill, and why
NEEDS_A_SENSOR = ("delta*eps", "delta", "J* (kg m²)")
#: what eps rests on without a static trial
INERTIA_NOTE = ("a relative error of the inertia is one of eps and of the mean torque; a static trial pins eps "
                "(docs/real-bench.md, \"Pinning eps\")")
#: the encoder error's lines: label, `IdentificationResult` field (with a ``_std`` one or None), comparison
ENCODER_LINES = (("enc. 1x (cnt)", "encoder_eccentricity_counts", "encoder_eccentricity_std_counts", "rel"),
                 ("enc. 1x (rad)", "encoder_eccentricity_phase_rad", None, "abs"),
                 ("enc. lines (cnt)", "encoder_line_rms_counts", None, "rel"))


def _cell(value, std) -> str:
    """'value ± std' (4 and 2 significant digits, 3 and 1 where that is too long); '-' when unknown."""
    if value is None:
        return "-"
    if std is None:
        return f"{value:.4g}"
    text = f"{value:.4g} ± {std:.2g}"
    return text if len(text) <= CELL_CHARACTERS else f"{value:.3g} ± {std:.1g}"


def _rms(values) -> float:
    # imported when the command runs (ilcpmac.cli's docstring says why)
    import numpy as np

    return float(np.sqrt(np.mean(np.square(values))))


def _error(estimate, truth, kind: str) -> str:
    """The estimate's error against the truth: "rel" in % (a difference against a zero truth), "abs" as a
    difference, "rms" as RMS % of the truth's."""
    if estimate is None or truth is None:
        return "-"
    if kind == "abs" or (kind == "rel" and truth == 0):
        return f"{estimate - truth:+.2g}"
    if kind == "rms":
        return "-" if len(estimate) != len(truth) else f"{100 * _rms(estimate - truth) / _rms(truth):.2g} % RMS"
    return f"{100 * (estimate / truth - 1):+.2g} %"


def _rows(result, columns: list[str]) -> list[tuple[str, float | np.ndarray | None, str, list]]:
    """Per line of the table: its label, the result's value, how it is compared with the truth ("rel",
    "abs" or "rms") and per column (value, std, what equals the result's value when the result took it)."""
    estimates = [result.methods.get(name, result) for name in columns]

    def at(value, p: int | None):
        return value if value is None or p is None else value[p]

    def line(label: str, name: str, kind: str, p: int | None = None) -> tuple:
        cells = [(at(getattr(m, name), p), at(getattr(m, name + "_std"), p), at(getattr(m, name), p))
                 for m in estimates]
        return label, at(getattr(result, name), p), kind, cells

    rows = [line("delta*eps", "delta_epsilon", "rel"), line("delta", "delta", "rel"), line("eps", "epsilon", "rel")]
    rows += [line(f"alpha {phase}", "alpha", "abs", p) for p, phase in enumerate("abc")]
    rows += [line(f"beta {phase} (A)", "beta", "abs", p) for p, phase in enumerate("abc")]
    rows.append(line("J* (kg m²)", "inertia_estimate", "rel"))
    rows.append(("cogging (mN m)", result.cogging_nm, "rms",
                 [(None if m.cogging_nm is None else 1000 * _rms(m.cogging_nm), None, m.cogging_nm)
                  for m in estimates]))
    loop = result.current_loop_bandwidth_per_phase_hz  # the joint fit's
    if loop is None:
        rows.append(("loop (Hz)", None, "rel", [(None, None, None)] * len(columns)))
    else:
        rows += [(f"loop {phase} (Hz)", loop[p], "rel",
                  [(loop[p], None, loop[p]) if name in ("joint", "result") else (None, None, None)
                   for name in columns]) for p, phase in enumerate("abc")]
    if result.torque_source.reads_encoder or result.encoder_error_counts is not None:
        for label, name, std_name, kind in ENCODER_LINES:  # the joint fit's residual gives it
            value, std = getattr(result, name), None if std_name is None else getattr(result, std_name)
            rows.append((label, value, kind, [(value, std, value) if column in ("joint", "result")
                                              else (None, None, None) for column in columns]))
    return rows


def read_truth(bench_dir: Path):
    """The bench folder's truth.json (a simulated bench's) as an `IdentificationResult`, or None without one."""
    # imported when the command runs (ilcpmac.cli's docstring says why)
    from ilcpmac.bench.format import BenchFormatError
    from ilcpmac.core.records import IdentificationResult

    path = bench_dir / TRUTH_FILE
    if not path.is_file():
        return None
    try:
        return IdentificationResult.from_json(json.loads(path.read_text()))
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as e:
        raise BenchFormatError(f"{path}: unreadable ({e})") from None


def estimates_table(result, truth=None) -> Table:
    """Each estimate of each method with its standard error, "*" on the one the result took (a "result" column
    where it took a value of no method's, as eps, beta and the cogging over another method's delta); with ``truth``
    (an `IdentificationResult` of the true values, `read_truth`), the result's error against it.

    One line per phase, so that the table fits 80 columns. The cogging line gives the RMS of the cogging
    torque (mN m) and, against the truth, the RMS of the difference relative to the truth's RMS; gains are
    compared in relative %, alpha and beta as differences; the current loop is the joint method's. On the
    encoder-derived torque, the encoder error's once-per-revolution amplitude and phase and its line-to-line
    RMS follow, and what needs a torque sensor reads "not identified", the reasons in the caption.
    """
    # imported when the command runs (ilcpmac.cli's docstring says why)
    import numpy as np

    columns = list(result.methods) or ["result"]
    taken = [any(raw is not None and np.array_equal(raw, value) for _, _, raw in cells)
             for _, value, _, cells in _rows(result, columns) if value is not None]
    if not all(taken):  # a value of no method's (eps, beta, the cogging over the delta taken): its own column
        columns.append("result")
    encoder = result.torque_source.reads_encoder
    caption = None
    if encoder:
        caption = (f"torque from the encoder's time stamps, J given; {NOT_IDENTIFIED}: "
                   f"{', '.join(NEEDS_A_SENSOR)} (no torque sensor)")
        if result.encoder_error_counts is None:
            caption += ", the encoder error (see the warnings)"
    elif "static" not in result.methods and result.epsilon is not None:
        caption = f"eps = delta*eps / delta, delta from [motor] inertia: {INERTIA_NOTE}"
    table = Table(title="identification (value ± standard error; * the result's)", title_justify="left",
                  header_style="bold", padding=(0, 1), caption=None if caption is None else escape(caption),
                  caption_justify="left")
    table.add_column("estimate")
    for name in columns:
        table.add_column(name if name == "result" else f"{name} method")
    if truth is not None:
        table.add_column("vs truth")
        truths = {label: value for label, value, _, _ in _rows(truth, ["result"])}
    for label, value, kind, cells in _rows(result, columns):
        if encoder and value is None and (label in NEEDS_A_SENSOR or label.startswith("enc.")):
            table.add_row(label, *[NOT_IDENTIFIED] * len(cells), *([NOT_IDENTIFIED] if truth is not None else []))
            continue
        row = [label] + [_cell(shown, std) + (" *" if len(columns) > 1 and name != "result" and raw is not None
                                              and value is not None and np.array_equal(raw, value) else "")
                         for name, (shown, std, raw) in zip(columns, cells)]
        if truth is not None:
            row.append(_error(value, truths.get(label), kind))
        table.add_row(*row)
    return table


@main.command()
@click.argument("bench_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--output", "output", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Result JSON to write (docs/bench-format.md).")
@click.option("--plots", "plots_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Folder for the report-style figures.")
@click.option("--format", "plot_format", type=click.Choice(FIGURE_FORMATS), default="png", show_default=True,
              help="File format of the figures written by --plots.")
@click.option("--torque-source", "torque_source", type=click.Choice(["sensor", "encoder"]), default=None,
              help="The torque sensor's column, or the torque from the encoder's time stamps; default: the "
                   "sensor where the bench has one.")
def identify(bench_dir: Path, output: Path, plots_dir: Path | None, plot_format: str,
             torque_source: str | None) -> None:
    """Identify the sensors, inertia and cogging torque of BENCH_DIR.

    Estimates delta*eps, delta, eps, alpha, beta, J* and the cogging torque with both methods, prints them and
    writes the result to --output (checked writable before the work); with a truth.json in BENCH_DIR (a
    simulated bench), also each estimate's error. A bench without a torque sensor at one operating point (a
    rolling drive log) is identified by the acceleration method (docs/sensorless.md): its position-locked
    torque and friction. A run directory of ``ilcpmac run`` is identified on its grid trials
    (`ilcpmac.campaign.rundir.campaign_grid`). A rolling folder (``ilcpmac import`` of logs kept row by row) gets its
    position torque from the currents averaged by position, corrected by J domega/dt where the data support it
    (docs/rolling-logs.md).
    An estimate too uncertain to take (`ilcpmac.identify.TOO_UNCERTAIN`, or a scan's cogging) is shown but not
    taken, and ends the command with an error (exit 2) once the result is written.
    """
    # imported when the command runs (ilcpmac.cli's docstring says why)
    from ilcpmac.bench.format import read_bench
    from ilcpmac.core.errors import IdentificationError, IlcpmacError
    from ilcpmac.core.files import atomic_write, check_writable
    from ilcpmac.core.torque_source import TorqueSource
    from ilcpmac.identify import STEPS, TOO_UNCERTAIN, identify_bench
    from ilcpmac.identify.folders import folder_kind

    check_writable(output, IlcpmacError)
    kind = folder_kind(bench_dir)
    if kind is not None:  # a scan, rolling or holding-map folder (ilcpmac.identify.folders)
        if torque_source is not None or plots_dir is not None:
            raise IlcpmacError(f"--{'torque-source' if torque_source is not None else 'plots'}: not for {kind.what} "
                               f"({bench_dir / kind.marker}): its torque is what the folder holds, it has no figures")
        result, lines = kind.identify(bench_dir, output)
        for message in result.messages:
            console.print(f"[yellow]warning:[/yellow] {escape(message)}")
        for line in lines:
            console.print(line)
        too_uncertain = getattr(result, "too_uncertain", None)
        if too_uncertain is not None:
            raise IdentificationError(f"{bench_dir}: {too_uncertain}")
        return
    truth = read_truth(bench_dir)
    with progress_bar() as progress:
        task = progress.add_task("reading bench folder", total=len(STEPS) + 1)
        from ilcpmac.campaign.rundir import campaign_grid

        bench, grid = campaign_grid(bench_dir, read_bench(bench_dir, extras=False))  # extras: the simulator's own

        def advance(step: str, index: int, total: int) -> None:
            progress.update(task, description=step, completed=index + 1)

        result = identify_bench(bench, advance, None if torque_source is None else TorqueSource(torque_source))
        progress.update(task, description="done", completed=len(STEPS) + 1)
    if grid is not None:
        console.print(grid)
    for message in result.messages:
        console.print(f"[yellow]warning:[/yellow] {escape(message)}")
    click.echo()
    from rich.console import Console

    Console().print(estimates_table(result, truth))  # first: a result that cannot be written is still shown
    for line in acceleration_lines(result):
        console.print(line)
    try:
        atomic_write(output, json.dumps(result.to_json(), indent=1, allow_nan=False))
    except OSError as e:
        raise IlcpmacError(f"{output}: cannot write the result ({e.strerror or e}); the estimates shown above "
                           "are not saved") from None
    console.print(f"wrote {output}")
    if plots_dir is not None:
        from ilcpmac.identify.plots import write_plots

        written = write_plots(result, plots_dir, plot_format)
        console.print(f"wrote {len(written)} figures to {plots_dir}")
    uncertain = result.diagnostics.get(TOO_UNCERTAIN)
    if uncertain:
        raise IdentificationError(f"{bench_dir}: {uncertain}")


def acceleration_lines(result) -> list[str]:
    """The acceleration method's summary (docs/sensorless.md): the harmonics estimated with their standard
    errors, the position-locked torque's RMS and the friction; none for another method's result."""
    summary = result.diagnostics.get("acceleration")
    if summary is None:
        return []
    estimated = [h for h in summary["harmonics"] if h["status"] == "estimated"]
    if summary.get("inertia") == "identified":
        speeds = ", ".join(f"{f:.4g}" for f in sorted(set(summary["speeds_hz"])))
        lines = [f"acceleration method at {speeds} Hz, {summary['revolutions']} revolutions, J identified: "
                 f"{_cell(summary['inertia_kgm2'], summary['inertia_std_kgm2'])} kg m² (given "
                 f"{summary['inertia_given_kgm2']:.4g})",
                 f"Coulomb friction: {_cell(summary['coulomb_friction_nm'], summary['coulomb_friction_std_nm'])} N m"]
        if summary["viscous_friction_nm_s"] is not None:
            viscous = _cell(summary["viscous_friction_nm_s"], summary["viscous_friction_std_nm_s"])
            lines.append(f"viscous friction: {viscous} N m s")
    else:
        lines = [f"acceleration method at {summary['speed_hz']:.4g} Hz, {summary['revolutions']} revolutions, "
                 f"J given ({summary['inertia_kgm2']:.4g} kg m²)",
                 f"Coulomb friction (b = 0): "
                 f"{_cell(summary['coulomb_friction_nm'], summary['coulomb_friction_std_nm'])} N m"]
    if result.position_torque_nm is not None:
        lines.append(f"position-locked torque: {1000 * _rms(result.position_torque_nm):.4g} mN m RMS, ± "
                     f"{1000 * _rms(result.position_torque_std_nm):.2g} mN m per count")
    lines += [f"  order {h['order']}: {_cell(1000 * abs(complex(h['re'], h['im'])), 1000 * h['std'])} mN m; an "
              f"encoder error of {h['encoder_error_counts_per_std']:.2g} counts biases it by one std"
              for h in estimated]
    return lines
