"""The report of a run directory as one self-contained HTML page (``ilcpmac report`` writes ``report.html``).

The page holds, in order: the run (its directory, config, seed and when its summary was written) and its final
ripple in words; the plan as it ran, trials and the motor's running time per phase; per operating point the
final ripple, measured and true, beside its noise floor, with units; the identification with its standard
errors; every figure with its caption; and the commands that export the compensation.

Everything is in the one file: the figures as base64 PNG, the style inline, no script, no external URL; it
reads offline in any browser. The layout is responsive: figures scale to the width, wide tables scroll inside
their own box, long paths wrap. Every text from the run (its directory, config, messages) is escaped.
"""

from __future__ import annotations

import base64
import io
import math
import re
import shlex
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from html import escape
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from PIL import Image

from ilcpmac import plotting
from ilcpmac.campaign.floors import PointFloor, floors_of
from ilcpmac.campaign.mean_torque import PointMeanTorque, mean_torques_of
from ilcpmac.campaign.quadrants import MIRROR_NOTE
from ilcpmac.campaign.record import Point, TrialRecord
from ilcpmac.campaign.rundir import RunDirError
from ilcpmac.campaign.validation import PointResult, point_results
from ilcpmac.config import REVERSE
from ilcpmac.core.files import atomic_write
from ilcpmac.core.records import IdentificationResult, MethodEstimates
from ilcpmac.report.plots import RunReport, build_figures
from ilcpmac.report.table import final_lines, significant

__all__ = ["HTML_FILE", "RUN_DIR_EXPORTS", "ReportWritten", "figure_caption", "page", "png_of", "write_html",
           "write_report"]

#: the page's file name in the report's folder
HTML_FILE = "report.html"
#: the `ilcpmac export` commands of a run directory (its compensation.json): their options, and what each writes
RUN_DIR_EXPORTS = ((("--format json",), "JSON: the record with its units"),
                   (("--format csv",), "CSV: the calibration, the torque gain and the feed-forward tables"),
                   (("--format c",), "C99: a header and source with the lookup function, the tables int16 at a stated "
                                     "N m per LSB"),
                   (("--format c", "--c-type float"), "C99 with float tables"))
#: a figure's caption by the start of its name (`ilcpmac.report.plots.build_figures`); ``{point}`` is the
#: operating point its name ends with
CAPTIONS = (("ripple_per_trial", "Peak-to-peak ripple of every trial, measured and (simulator) true, coloured by "
                                 "torque set point; the bands are the campaign's phases."),
            ("before_after_", "At {point}: the torque ripple over one revolution uncompensated and with the final "
                              "compensation, torque sensor and (simulator) true, and their spectra."),
            ("learned_", "At {point}: the feed-forward each stage learned by the last trial, as a spectrum and over "
                         "one cogging period."),
            ("operating_range", "The final peak-to-peak ripple over torque x speed, measured and (simulator) true: "
                                "learned points as circles, validation points as squares; a red edge where the "
                                "compensation is worse than none."))
#: an operating point at the end of a figure's name, e.g. "2Nm_0.9Hz"
_POINT_NAME = re.compile(r"(?P<torque>[-+.\deE]+)Nm_(?P<speed>[-+.\deE]+)Hz$")
#: the estimates of the identification's table: label, `MethodEstimates` field, unit, components
_ESTIMATES = (("total system gain δε", "delta_epsilon", "1", ()),
              ("torque-sensor gain δ", "delta", "1", ()),
              ("current-sensor gain ε", "epsilon", "1", ()),
              ("scale imbalance α (mean 1)", "alpha", "1", ("a", "b", "c")),
              ("offset β", "beta", "A", ("a", "b", "c")),
              ("inertia J* = δJ", "inertia_estimate", "kg m²", ()))
#: the methods' names as the page shows them
_METHODS = {"report": "the report's method (ch. 1-4)", "acceleration": "the acceleration method"}

#: the attribute of a left-aligned (text) cell
_TEXT = ' class="text"'
_STYLE = """
*{box-sizing:border-box}
body{margin:0;color:#1f2328;background:#fff;font:15px/1.5 system-ui,-apple-system,"Segoe UI",Roboto,
"DejaVu Sans",sans-serif}
main{max-width:1040px;margin:0 auto;padding:24px 20px 56px}
h1{font-size:1.55rem;line-height:1.25;margin:0 0 .4rem}
h2{font-size:1.2rem;margin:2.2rem 0 .6rem;padding-bottom:.2rem;border-bottom:1px solid #d0d7de}
h1,h2,p,li,dd,dt,figcaption{overflow-wrap:anywhere}
.meta{color:#57606a;margin:.2rem 0}
nav ol{display:flex;flex-wrap:wrap;gap:.2rem 1.2rem;padding:0;margin:.8rem 0 0;list-style:none}
a{color:#0a58ca}
.scroll{max-width:100%;overflow-x:auto;margin:.6rem 0}
table{border-collapse:collapse;font-size:.88rem;font-variant-numeric:tabular-nums}
th,td{padding:.28rem .5rem;border-bottom:1px solid #d0d7de;text-align:right;vertical-align:bottom;
white-space:nowrap}
thead tr:not(:last-child) th{border-bottom:0;padding-bottom:0}
thead tr th.group{text-align:center;border-bottom:1px solid #8c959f;padding-bottom:.15rem}
th{background:#f6f8fa;font-weight:600}
dl{display:grid;grid-template-columns:minmax(8em,max-content) minmax(0,1fr);gap:.15rem 1rem;margin:.6rem 0}
dt{font-weight:600}
dd{margin:0}
th.text,td.text{text-align:left}
tr.total td{font-weight:600}
.worse{color:#b42318;font-weight:600}
.note{color:#57606a;font-size:.9rem}
figure{margin:1.6rem 0}
figure img{display:block;max-width:100%;height:auto;border:1px solid #d0d7de}
figcaption{color:#57606a;font-size:.9rem;margin-top:.35rem}
pre{margin:.3rem 0 1rem;padding:.55rem .75rem;background:#f6f8fa;border:1px solid #d0d7de;border-radius:4px;
white-space:pre-wrap;overflow-wrap:break-word;font-size:.85rem}
code{font-family:ui-monospace,"DejaVu Sans Mono",Menlo,Consolas,monospace}
.nobr{white-space:nowrap}
@media (max-width:900px){main{padding:16px 12px 40px}th,td{padding:.25rem .35rem}table{font-size:.84rem}}
"""


def png_of(fig: Figure) -> bytes:
    """``fig`` drawn as PNG, at the resolution of the PNG files the report writes (`ilcpmac.plotting.save`)."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=plotting.PNG_DPI)
    return buffer.getvalue()


def figure_caption(name: str) -> str:
    """The caption of figure ``name`` (`CAPTIONS`); the name itself for a figure it does not know."""
    match = _POINT_NAME.search(name)
    point = f"{match['torque']} N m and {match['speed']} Hz" if match else name
    return next((text.format(point=point) for start, text in CAPTIONS if name.startswith(start)), name)


def _number(value: float | None, digits: int = 4) -> str:
    """``value`` to ``digits`` significant digits; "-" for None or a value that is not finite."""
    if value is None or not math.isfinite(value):
        return "-"
    return f"{value:.{digits}g}"


def _percent(fraction: float | None) -> str:
    """A fraction of the mean torque as % (3 significant digits); "-" for None."""
    return "-" if fraction is None else significant(100 * fraction)


def _times(factor: float | None) -> str:
    """A factor as "12.3x" (3 significant digits); "-" for None."""
    return "-" if factor is None else f"{significant(factor)}x"


def _cells(values: Iterable[str], tag: str = "td", text_columns: Sequence[int] = (0,), row_class: str = "") -> str:
    """One table row of escaped ``values``; the columns ``text_columns`` left-aligned, the row of ``row_class``."""
    cells = "".join(f"<{tag}{_TEXT if i in text_columns else ''}>{escape(v)}</{tag}>" for i, v in enumerate(values))
    return f'<tr class="{row_class}">{cells}</tr>' if row_class else f"<tr>{cells}</tr>"


def _table(head: Sequence[str] | str, rows: Iterable[str], text_columns: Sequence[int] = (0,)) -> str:
    """A table in its own horizontally scrolling box: the header ``head`` (its cells, escaped, or its rows as HTML)
    and the ``rows`` (HTML)."""
    header = head if isinstance(head, str) else _cells(head, "th", text_columns)
    return f'<div class="scroll"><table><thead>{header}</thead><tbody>{"".join(rows)}</tbody></table></div>'


def _spanned(cells: Sequence[tuple[str, int]]) -> str:
    """A header row of (text, columns spanned) cells, the first left-aligned, a spanning one centred."""
    out = []
    for i, (text, span) in enumerate(cells):
        attributes = _TEXT if i == 0 and span == 1 else f' class="group" colspan="{span}"' if span > 1 else ""
        out.append(f"<th{attributes}>{escape(text)}</th>")
    return f"<tr>{''.join(out)}</tr>"


def _section(anchor: str, title: str, body: str) -> str:
    """A section of the page, its heading linked from the top as ``#anchor``."""
    return f'<section id="{anchor}"><h2>{escape(title)}</h2>{body}</section>'


def _header(report: RunReport, summary_written: float | None) -> str:
    """The run: its directory, config, seed and overrides (states/run.json), stages, trials and the time its summary
    was written (``summary_written``, seconds since the epoch)."""
    settings = report.files.read_json(report.files.settings)
    if not isinstance(settings, dict):  # a run made before states/run.json, or one edited by hand
        settings = {}
    config = settings.get("config") or report.config.path.name
    facts = [f"config {config}", f"seed {settings.get('seed', report.config.grid.seed)}"]
    if settings.get("trials") is not None:
        facts.append(f"--trials {settings['trials']}")
    if settings.get("budget_min") is not None:
        facts.append(f"--budget {settings['budget_min']} min")
    facts.append(f"stages {', '.join(report.config.pipeline.stages)}")
    if settings.get("direction") == REVERSE:
        facts.append(f"the reverse of a campaign in both directions, {MIRROR_NOTE}")
    when = "" if summary_written is None else datetime.fromtimestamp(summary_written, UTC).strftime(
        "%Y-%m-%d %H:%M UTC")
    try:
        made_by = f"ilcpmac {version('ilcpmac')}"
    except PackageNotFoundError:
        made_by = "ilcpmac"
    return (f"<header><h1>Campaign report: {escape(report.files.path.name or str(report.files.path))}</h1>"
            f'<p class="meta">run directory <code>{escape(str(report.files.path))}</code></p>'
            f'<p class="meta">{escape("; ".join(facts))}</p>'
            f'<p class="meta">{len(report.records)} trials; results as of {escape(when or "-")} '
            f"(summary.json written); page made by {escape(made_by)}</p></header>")


def _results(summary: dict) -> str:
    """The final ripple in words, as ``ilcpmac run`` ends with it (`final_lines`)."""
    lines = final_lines(summary)
    if not lines:
        return '<p class="note">No final figures yet: the run stopped before its learned points were done.</p>'
    return "<ul>" + "".join(f"<li>{escape(line)}</li>" for line in lines) + "</ul>"


def _listed(points: Sequence[Point]) -> str:
    """Operating points in words: "2 N m at 0.9 Hz, 4 N m at 0.9 Hz" ("none" for none)."""
    return ", ".join(f"{t:g} N m at {s:g} Hz" for t, s in points) or "none"


def _plan(report: RunReport) -> str:
    """The grid and the points of the config, then per phase the trials that ran and the motor's running time."""
    config, records = report.config, report.records
    phases: dict[str, list[TrialRecord]] = {}
    for record in records:
        phases.setdefault(record.phase, []).append(record)
    total = sum(r.motor_time_s or 0.0 for r in records)
    rows = []
    for phase, group in phases.items():
        seconds = sum(r.motor_time_s or 0.0 for r in group)
        points = sorted({r.point for r in group})
        rows.append(_cells([phase, str(len(group)), str(len(points)), f"{group[0].index}-{group[-1].index}",
                            f"{seconds / 60:.2f}", f"{100 * seconds / total:.0f}" if total > 0 else "-"]))
    rows.append(_cells(["all", str(len(records)), str(len({r.point for r in records})),
                        f"1-{records[-1].index}" if records else "-", f"{total / 60:.2f}",
                        "100" if total > 0 else "-"], row_class="total"))
    table = _table(["phase", "trials", "operating points", "trials (index)", "motor time (min)", "share (%)"], rows)
    unknown = any(r.motor_time_s is None for r in records)

    grid = (f"{len(config.grid.torque_setpoints_nm)} torques x {len(config.grid.speed_setpoints_hz)} speeds "
            f"({', '.join(f'{t:g}' for t in config.grid.torque_setpoints_nm)} N m at "
            f"{', '.join(f'{s:g}' for s in config.grid.speed_setpoints_hz)} Hz), {config.grid.revolutions} "
            "revolutions each")
    facts = [("identification grid", grid),
             ("learned at", f"{_listed(config.learned_points())}; at most {config.campaign.learn_trials} learning "
                            "trials per point"),
             ("validated at (never learned)", _listed(config.validation_points()))]
    listing = "<dl>" + "".join(f"<dt>{escape(k)}</dt><dd>{escape(v)}</dd>" for k, v in facts) + "</dl>"
    note = ('<p class="note">The motor\'s running time: warm-up and recorded revolutions at each trial\'s speed, '
            "as a real bench would run them" + ("; trials of an earlier release have none, left out" if unknown
                                                else "") + ".</p>")
    return listing + table + note


def _points(results: list[PointResult], floors: Mapping[Point, PointFloor]) -> str:
    """Per point its final ripple beside its floor (``floors``: by point, `floors_of`)."""
    if not results:
        return '<p class="note">No operating point has its final trial yet.</p>'
    rows = []
    for result in results:
        floor = floors.get(result.point)
        cells = ["learned" if result.learned else "validation", f"{result.point[0]:g}", f"{result.point[1]:g}"]
        for kind, factor in (("measured", "reduction_factor"), ("true", "reduction_factor_true")):
            after, below = result.after.figures(kind), None if floor is None else floor.pp(kind)
            ratio = after.pp / below if after is not None and below else None
            reduction = getattr(result.after, factor)
            cells += [_percent(None if after is None else after.pp), _percent(below), _times(ratio), _times(reduction)]
        cells.append(f"{result.before.index}, {result.after.index}")
        rows.append(_cells(cells, row_class="worse" if result.worse else ""))
    figures = (("final", 1), ("floor", 1), ("ratio", 1), ("reduction", 1))
    units = (("% pp", 1), ("% pp", 1), ("", 1), ("", 1))
    head = (_spanned([("", 3), ("measured ripple", 4), ("true ripple (simulator)", 4), ("", 1)])
            + _spanned([("point", 1), ("torque", 1), ("speed", 1), *figures, *figures, ("trials", 1)])
            + _spanned([("", 1), ("N m", 1), ("Hz", 1), *units, *units, ("", 1)]))
    note = ('<p class="note">Final and floor: peak-to-peak ripple over harmonics 1..H, % of the mean torque; '
            "ratio: final / floor, how far the final ripple stands above the point's noise floor, what its final "
            "trial's own noise and the learning's leave (docs/campaign.md, \"The noise floor\"); reduction: the "
            "uncompensated trial's ripple over the final one's. \"True\" is the simulator's torque: a real bench has "
            "only the measured one. Trials: the uncompensated and the final trial compared (their indices). A row in "
            "red is a point where the compensation leaves at least as much measured ripple as none (it fades out "
            "there).</p>")
    return _table(head, rows) + note


def _mean_torques(means: Mapping[Point, PointMeanTorque]) -> str:
    """Per point its final trial's mean torque by the identified model, with its standard error, beside the
    simulator's truth (``means``: by point, `mean_torques_of`)."""
    if not means:
        return '<p class="note">No mean torque: the run has not ended, or an earlier release wrote it.</p>'
    rows = []
    for point, m in means.items():
        true = "" if m.true_nm is None else _number(m.true_nm)
        rows.append(_cells(["learned" if m.learned else "validation", f"{point[0]:g}", f"{point[1]:g}",
                            _number(m.implied.mean_nm), _number(m.implied.std_nm), _percent(m.error),
                            "" if m.implied.backemf_loss_nm is None else _number(m.implied.backemf_loss_nm), true,
                            "" if m.true_error is None else _percent(m.true_error)]))
    head = (_spanned([("point", 1), ("torque", 1), ("speed", 1), ("model", 1), ("+-", 1), ("error", 1),
                      ("back-EMF part", 1), ("true (simulator)", 1), ("true error", 1)])
            + _spanned([("", 1), ("N m", 1), ("Hz", 1), ("N m", 1), ("N m", 1), ("%", 1), ("N m", 1), ("N m", 1),
                        ("%", 1)]))
    note = ('<p class="note">The mean torque of each point\'s final trial: no sensor measures it (a piezo sees no '
            "mean), so the model's is the set point through the identified current sensors, loop and back-EMF "
            "(docs/campaign.md, \"The mean torque\"); +-: its standard error, eps's and the given inertia's; "
            "error: over the set point, less 1; back-EMF part: what the loop's tracking error to the back-EMF "
            "takes. The mean-torque stage brings it to the set point where the pipeline has it.</p>")
    return _table(head, rows) + note


def _estimate_cells(estimates: MethodEstimates, name: str, component: int | None) -> tuple[str, str]:
    """The value and standard error of estimate ``name`` (a component of a vector one) of ``estimates``."""
    value, std = getattr(estimates, name), getattr(estimates, name + "_std")
    if component is not None:
        value = None if value is None else float(value[component])
        std = None if std is None else float(std[component])
    return _number(value, 5), _number(std, 2)


def _identification(result: IdentificationResult | None) -> str:
    """The estimates with their standard errors and units, the other methods' beside them, and the messages."""
    if result is None:
        return '<p class="note">No identification yet: the run stopped before its grid was done.</p>'
    # the value is the joint fit's where it succeeded: the other methods beside it
    methods = [name for name in ("report", "acceleration") if name in result.methods]
    rows = []
    for label, name, unit, components in _ESTIMATES:
        for i, component in enumerate(components or (None,)):
            value, std = _estimate_cells(result, name, None if component is None else i)
            cells = [label + ("" if component is None else f", {component}"), unit, value, std]
            for method in methods:
                m_value, m_std = _estimate_cells(result.methods[method], name, None if component is None else i)
                cells.append(m_value if m_std == "-" else f"{m_value} ± {m_std}")
            rows.append(_cells(cells, text_columns=(0, 1)))
    head = ["estimate", "unit", "value", "standard error", *(_METHODS[m] for m in methods)]
    table = _table(head, rows, text_columns=(0, 1))
    facts = [("torque from", result.torque_source.value)]
    if result.cogging_nm is not None:
        cogging = np.asarray(result.cogging_nm)
        facts.append(("cogging torque", f"{_number(float(np.ptp(cogging)) * 1000, 4)} mN m peak-to-peak, "
                                        f"{_number(float(np.sqrt(np.mean(cogging ** 2))) * 1000, 4)} mN m RMS"))
    if result.current_loop_bandwidth_per_phase_hz is not None:
        facts.append(("current-loop corner per phase",
                      ", ".join(_number(b, 4) for b in result.current_loop_bandwidth_per_phase_hz) + " Hz"))
    if result.torque_sensor_highpass_hz is not None:
        facts.append(("torque sensor high-pass corner", f"{_number(result.torque_sensor_highpass_hz, 3)} Hz"))
    if result.encoder_eccentricity_counts is not None:
        facts.append(("encoder eccentricity", f"{_number(result.encoder_eccentricity_counts, 3)} ± "
                                              f"{_number(result.encoder_eccentricity_std_counts, 2)} counts"))
    listing = "<dl>" + "".join(f"<dt>{escape(k)}</dt><dd>{escape(v)}</dd>" for k, v in facts) + "</dl>"
    notes = "" if not result.messages else (
        "<p>What the identification says of itself:</p><ul>"
        + "".join(f'<li class="note">{escape(str(m))}</li>' for m in result.messages) + "</ul>")
    lead = ('<p class="note">The value is the joint fit\'s where it succeeded, else the report\'s method\'s, which '
            'stands beside it; α and β per phase a, b, c; "-" where none was estimated (docs/identification.md).</p>')
    return lead + table + listing + notes


def _figures(images: Mapping[str, bytes], why: str | None) -> str:
    """Every figure (its PNG by name) inline with its caption, and why the learned feed-forward is missing."""
    parts = []
    for name, png in images.items():
        with Image.open(io.BytesIO(png)) as image:
            width, height = image.size
        caption = figure_caption(name)
        parts.append(f'<figure id="figure-{escape(name)}"><img src="data:image/png;base64,'
                     f'{base64.b64encode(png).decode("ascii")}" width="{width}" height="{height}" '
                     f'alt="{escape(caption)}"><figcaption><b>{escape(name)}</b>: {escape(caption)}</figcaption>'
                     "</figure>")
    if why is not None:
        parts.append(f'<p class="note">What each stage learned is not drawn: {escape(why)}.</p>')
    return "".join(parts) or '<p class="note">No figures.</p>'


def _exports(report: RunReport) -> str:
    """The `ilcpmac export` commands of the run's compensation, its directory quoted for a shell."""
    if not report.files.compensation.is_file():
        return (f'<p class="note">No {escape(report.files.compensation.name)} yet: a campaign writes it when its '
                "learning phase ends.</p>")
    run_dir = shlex.quote(str(report.files.path.resolve()))
    parts = [f"<p>The compensation ({escape(report.files.compensation.name)}: the current-sensor calibration, the "
             "torque gain and the feed-forward over torque x speed with its fade-out) for a drive's firmware; each "
             "command writes into DIR and prints the residual ripple the format leaves (docs/export.md).</p>"]
    for options, what in RUN_DIR_EXPORTS:
        parts.append(f"<p>{escape(what)}:</p><pre><code>{_command(run_dir, *options, '--out DIR')}</code></pre>")
    parts.append('<p class="note">harmonics and moteus export a position table (the cogging) from the result JSON '
                 "of ilcpmac identify, not a campaign's compensation: <code>"
                 + _command("result.json", "--format moteus", "--torque-constant NM_PER_A", "--out DIR")
                 + "</code> (docs/export.md).</p>")
    return "".join(parts)


def _command(source: str, *options: str) -> str:
    """``ilcpmac export SOURCE OPTION...`` escaped, each option kept on one line (a line breaks between them, or
    anywhere in a long ``source``)."""
    return " ".join([f"ilcpmac export {escape(source)}", *(f'<span class="nobr">{escape(o)}</span>' for o in options)])


def page(report: RunReport, images: Mapping[str, bytes], why: str | None = None) -> str:
    """The report's HTML text.

    Parameters
    ----------
    report : the run directory.
    images : each figure's PNG by its name (`ilcpmac.report.plots.build_figures`'s names, in that order).
    why : why the learned feed-forward is not drawn (`build_figures`), or None.

    Raises `RunDirError` naming summary.json when its points or identification cannot be read.
    """
    summary = report.files.read_summary()
    try:
        floors, means = floors_of(summary), mean_torques_of(summary)
        identification = summary.get("identification")
        result = None if identification is None else IdentificationResult.from_json(identification)
        in_words = _results(summary)
    except (KeyError, TypeError, ValueError, ZeroDivisionError) as e:
        raise RunDirError(f"{report.files.summary}: unreadable ({e!r})") from None
    validated = sorted({r.point for r in report.records if r.role == "validate"})
    results = point_results(report.records, report.learned_points(), validated)
    sections = [("results", "Results", in_words),
                ("plan", "Plan and motor time", _plan(report)),
                ("points", "Ripple per operating point", _points(results, floors)),
                ("mean-torque", "Mean torque per operating point", _mean_torques(means)),
                ("identification", "Identification", _identification(result)),
                ("figures", "Figures", _figures(images, why)),
                ("export", "Export the compensation", _exports(report))]
    nav = "<nav><ol>" + "".join(f'<li><a href="#{a}">{escape(t)}</a></li>' for a, t, _ in sections) + "</ol></nav>"
    title = f"ilcpmac report: {report.files.path.name or report.files.path}"
    body = "".join(_section(*s) for s in sections)
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            '<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{escape(title)}</title><style>{_STYLE}</style></head>\n"
            f"<body><main>{_header(report, _modified(report.files.summary))}{nav}{body}</main></body></html>\n")


def _modified(path: Path) -> float | None:
    """When ``path`` was last written, seconds since the epoch; None when it cannot be told."""
    try:
        return path.stat().st_mtime
    except OSError:
        return None


def write_html(report: RunReport, figures: Mapping[str, Figure], out_path: Path, why: str | None = None,
               pngs: Mapping[str, Path] | None = None) -> Path:
    """Write the report's page (`page`) to ``out_path`` atomically; returns it.

    Parameters
    ----------
    report : the run directory.
    figures : its figures by name (`ilcpmac.report.plots.build_figures`).
    out_path : the HTML file to write.
    why : why the learned feed-forward is not drawn, or None.
    pngs : PNG files of some of the figures already written, by name: embedded as they are rather than drawn
        again.
    """
    pngs = pngs or {}
    images = {name: pngs[name].read_bytes() if name in pngs else png_of(fig) for name, fig in figures.items()}
    atomic_write(out_path, page(report, images, why), durable=False)
    return out_path


@dataclass(frozen=True)
class ReportWritten:
    """What `write_report` wrote: each figure's file by name, the page, and why the learned feed-forward is not
    drawn (None when it is)."""

    figures: dict[str, Path]
    page: Path
    why: str | None


def write_report(report: RunReport, out_dir: Path, fmt: str = "png") -> ReportWritten:
    """Write every figure of the run (`build_figures`) as ``fmt`` into ``out_dir``, and the page (`write_html`)
    beside them, which embeds the PNGs as written (other formats: drawn again as PNG)."""
    plotting.check_format(fmt, out_dir)
    figures, why = build_figures(report)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = {name: plotting.save(fig, out_dir / name, fmt) for name, fig in figures.items()}
    page_path = write_html(report, figures, out_dir / HTML_FILE, why, written if fmt == "png" else None)
    return ReportWritten(written, page_path, why)
