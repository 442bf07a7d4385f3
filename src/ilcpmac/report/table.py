"""Rich tables of a campaign's trials, laid out for the console's width, and the final figures in words.

Every cell is formatted to a few characters (3 significant digits, units in the
header) and never wrapped: a layout keeps the columns that fit the width, in
order of importance, so no cell or header is ever cut.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from rich.console import JustifyMethod
from rich.table import Table

from ilcpmac.campaign.floors import PointFloor, floors_of
from ilcpmac.campaign.mean_torque import PointMeanTorque, mean_torques_of
from ilcpmac.campaign.record import Point, TrialRecord
from ilcpmac.campaign.validation import PointResult, point_results, results_of

__all__ = ["FINAL_TITLE", "SOURCE_CAPTIONS", "SUMMARY_TITLE", "final_lines", "mean_torque_lines", "significant",
           "summary_table", "trials_table"]

#: width of a column's padding (one space each side) and its left border
_COLUMN_FRAME = 3


def significant(value: float) -> str:
    """``value`` to 3 significant digits without an exponent (at most 4 decimals; 0 stays "0")."""
    if value == 0 or not math.isfinite(value):
        return f"{value:g}"
    decimals = min(4, max(0, 2 - math.floor(math.log10(abs(value)))))
    return f"{value:.{decimals}f}"


def _span(values: list[float]) -> str:
    low, high = min(values), max(values)
    return f"{low:g}" if low == high else f"{low:g}-{high:g}"


def _worst(rows: list[TrialRecord], kind: str, name: str, scale: float) -> str:
    """The largest figure ``name`` of ``kind`` over ``rows``, times ``scale``; "-" where none has it."""
    values = [getattr(f, name) for r in rows if (f := r.figures(kind)) is not None]
    return significant(scale * max(values)) if values else "-"


def _factor(rows: list[TrialRecord], name: str) -> str:
    values = [getattr(r, name) for r in rows if getattr(r, name) is not None]
    return f"{significant(min(values))}x" if values else "-"


def _index(rows: list[TrialRecord]) -> str:
    first, last = rows[0].index, rows[-1].index
    return str(first) if first == last else f"{first}-{last}"


@dataclass(frozen=True)
class _Column:
    """A column of the live table: its header (quantity, then unit, on two lines), its rank (0 is kept first
    when the width is short) and its cell for a row of trials (one trial, or the grid)."""

    header: str
    rank: int
    cell: Callable[[list[TrialRecord]], str]
    justify: JustifyMethod = "right"


def _figure(header: str, rank: int, kind: str, name: str, scale: float) -> _Column:
    return _Column(header, rank, lambda rows: _worst(rows, kind, name, scale))


#: the live table's columns in display order; ripple in % of mean torque, amplitudes in mN m
_COLUMNS = (
    _Column("#", 0, _index),
    _Column("role", 0, lambda rows: rows[0].role, "left"),
    _Column("torque\nN m", 0, lambda rows: _span([r.torque_setpoint_nm for r in rows])),
    _Column("speed\nHz", 1, lambda rows: _span([r.speed_setpoint_hz for r in rows])),
    _figure("meas pp\n%", 0, "measured", "pp", 100),
    _figure("meas rms\n%", 3, "measured", "rms", 100),
    _figure("true pp\n%", 0, "true", "pp", 100),
    _figure("true rms\n%", 3, "true", "rms", 100),
    _figure("1x\nmN m", 4, "measured", "amp_1x", 1000),
    _figure("2x\nmN m", 4, "measured", "amp_2x", 1000),
    _figure("cogging\nmN m", 4, "measured", "amp_cogging", 1000),
    _figure("rest\nmN m", 4, "measured", "amp_rest", 1000),
    _figure("noise\n%", 2, "measured", "rest_rms", 100),
    _Column("reduction\nmeas", 0, lambda rows: _factor(rows, "reduction_factor")),
    _Column("reduction\ntrue", 2, lambda rows: _factor(rows, "reduction_factor_true")),
    _Column("mean\nerr %", 3, lambda rows: _mean_error(rows)),
)


def _mean_error(rows: list[TrialRecord]) -> str:
    """The trials' mean torque error by the model, %: the largest in size over a row of several; "-" where none
    has one (before the identification)."""
    errors = [r.mean_torque_error for r in rows if r.mean_torque_error is not None]
    return f"{100 * max(errors, key=abs):+.2f}" if errors else "-"


def _rows(records: list[TrialRecord]) -> list[list[TrialRecord]]:
    """The table's rows: the grid in one row, then one row per trial."""
    grid = [r for r in records if r.role == "grid"]
    return ([grid] if grid else []) + [[r] for r in records if r.role != "grid"]


def _text_width(text: str) -> int:
    return max(len(line) for line in text.split("\n"))


def _fit(columns: list[tuple[_Column, list[str]]], width: int) -> list[tuple[_Column, list[str]]]:
    """The columns that fit ``width`` side by side, unwrapped: rank by rank, while a whole rank fits
    (rank 0 always)."""
    needs = [max([_text_width(c.header), *map(len, cells)]) + _COLUMN_FRAME for c, cells in columns]
    used, kept = 1, 0
    for rank in sorted({c.rank for c, _ in columns}):
        used += sum(n for (c, _), n in zip(columns, needs) if c.rank == rank)
        if used > width:
            break
        kept = rank
    return [(c, cells) for c, cells in columns if c.rank <= kept]


def _table(columns: list[tuple[str, JustifyMethod, list[str]]], title: str | None = None,
           caption: str | None = None) -> Table:
    table = Table(header_style="bold", title=title, title_justify="left", caption=caption, caption_justify="left")
    for header, justify, _ in columns:
        table.add_column(header, justify=justify, no_wrap=True)
    for row in zip(*(cells for *_, cells in columns)):
        table.add_row(*row)
    return table


#: what the "meas" columns estimate the ripple from, per [campaign] torque_source, when not the torque sensor
SOURCE_CAPTIONS = {"encoder": "meas: estimated from the encoder's time stamps",
                   "both": "meas: the torque sensor and the encoder's time stamps fused"}


def trials_table(records: list[TrialRecord], width: int, title: str | None = None, source: str = "sensor",
                 hidden: int = 0) -> Table:
    """The live table, for a console ``width`` characters wide: per trial its phase, set point, measured and true
    ripple, harmonic amplitudes, reduction factors and mean torque error by the model, as many columns as fit. The
    identification grid is one row (its trials' range, set points and largest figures), then a row per trial but
    the first ``hidden`` after the grid (left out to fit a terminal's height; the caption says so). The measured
    figures are estimated from ``source`` ([campaign] torque_source; the caption names it unless it is the torque
    sensor); the true ones are the simulator's."""
    rows = _rows(records)
    grid = int(bool(rows) and rows[0][0].role == "grid")
    rows = rows[:grid] + rows[grid + hidden:]
    columns = _fit([(c, [c.cell(row) for row in rows]) for c in _COLUMNS], width)
    notes = [SOURCE_CAPTIONS[source]] if source in SOURCE_CAPTIONS else []
    if any(r.role == "grid" for r in records):
        notes.append("grid row: the largest figure over its trials")
    if hidden:
        notes.append(f"{hidden} trials after the grid left out to fit the terminal (all in summary.json)")
    caption = "\n".join(notes) or None
    return _table([(c.header, c.justify, cells) for c, cells in columns], title=title, caption=caption)


#: the summary's title, printed on a line of its own above `summary_table`
SUMMARY_TITLE = "summary per operating point (ripple peak-to-peak after, % of mean torque)"


def summary_table(records: list[TrialRecord], learned: list[Point], validated: list[Point],
                  floors: dict[Point, PointFloor] | None = None, width: int = 80,
                  means: dict[Point, PointMeanTorque] | None = None) -> Table:
    """Per learned, then validation point: the final ripple beside its floor (``floors``: by point, when known,
    `floors_of`), the reduction factors against the uncompensated trial there, the learning trials used and the
    final trial's mean torque over the set point, less 1, by the model (``means``, `mean_torques_of`)
    (`SUMMARY_TITLE`); the columns that fit ``width``, as the live table's."""
    floors, means = floors or {}, means or {}
    results = point_results(records, learned, validated)
    rows = [(result, floors.get(result.point),
             sum(r.role == "learn" and r.point == result.point for r in records)) for result in results]
    columns = [
        (_Column("torque\nN m", 0, str), [f"{r.point[0]:.4g}" for r, _, _ in rows]),
        (_Column("speed\nHz", 0, str), [f"{r.point[1]:.4g}" for r, _, _ in rows]),
        (_Column("point", 0, str), ["learned" if r.learned else "valid." for r, _, _ in rows]),
        (_Column("meas\n%", 0, str), [_worst([r.after], "measured", "pp", 100) for r, _, _ in rows]),
        (_Column("floor\n%", 2, str), [_floor(f, "measured") for _, f, _ in rows]),
        (_Column("true\n%", 0, str), [_worst([r.after], "true", "pp", 100) for r, _, _ in rows]),
        (_Column("floor\n%", 1, str), [_floor(f, "true") for _, f, _ in rows]),
        (_Column("reduction\nmeas", 0, str), [_factor([r.after], "reduction_factor") for r, _, _ in rows]),
        (_Column("reduction\ntrue", 1, str), [_factor([r.after], "reduction_factor_true") for r, _, _ in rows]),
        (_Column("learn\ntrials", 0, str), [str(n) if r.learned else "-" for r, _, n in rows]),
        (_Column("mean\nerr %", 2, str), [f"{100 * m.error:+.2f}" if (m := means.get(r.point)) else "-"
                                      for r, _, _ in rows]),
    ]
    if not floors:
        columns = [c for c in columns if not c[0].header.startswith("floor")]
    if not means:
        columns = [c for c in columns if not c[0].header.startswith("mean")]
    return _table([(c.header, c.justify, cells) for c, cells in _fit(columns, width)])


def _floor(floor: PointFloor | None, kind: str) -> str:
    value = None if floor is None else floor.pp(kind)
    return "-" if value is None else significant(100 * value)


#: the line above `final_lines`
FINAL_TITLE = "final ripple peak-to-peak, each figure beside its point:"


def _at(point: Point) -> str:
    return f"{point[0]:g} N m, {point[1]:g} Hz"


def _ripple_lines(where: str, kind: str, results: list[PointResult], floors: dict[Point, PointFloor]) -> list[str]:
    """The final lines of one set of points and kind of ripple: the worst ripple with its point and that point's
    reduction, the least reduction with its point and its ripple (where another point has it), and every point's
    ripple over its floor."""
    factor = "reduction_factor_true" if kind == "true" else "reduction_factor"
    ripple = {r.point: pp.pp for r in results if (pp := r.after.figures(kind)) is not None}
    if not ripple:
        return []
    reduction = {r.point: f for r in results if r.point in ripple and (f := getattr(r.after, factor)) is not None}
    worst = max(ripple, key=ripple.__getitem__)
    words = f"{where}: {kind} ripple {significant(100 * ripple[worst])} % of mean torque at worst ({_at(worst)})"
    if worst in reduction:
        words += f", {significant(reduction[worst])}x below uncompensated"
    ratios = [ripple[p] / below for p in ripple if p in floors and (below := floors[p].pp(kind)) is not None
              and below > 0]
    if ratios:
        words += f"; each point {significant(min(ratios))}-{significant(max(ratios))}x its floor"
    lines = [words]
    least = min(reduction, key=reduction.__getitem__, default=worst)
    if least != worst:
        lines.append(f"{where}: {kind} ripple {significant(reduction[least])}x below uncompensated at least "
                     f"({_at(least)}), {significant(100 * ripple[least])} % of mean torque")
    return lines


def mean_torque_lines(means: dict[Point, PointMeanTorque]) -> list[str]:
    """The final lines of the points' mean torque (`mean_torques_of`): the model's largest error with its point and
    standard error, and the range over the points; the truth's where the simulator gives it, with the largest
    distance between the two in the model's standard errors."""
    if not means:
        return []
    errors = {p: m.error for p, m in means.items()}
    worst = max(errors, key=lambda p: abs(errors[p]))
    caveats = "" if all(m.implied.inertia_std_nm is not None or m.implied.epsilon_pinned for m in means.values()) \
        else " (the given inertia taken as exact, its uncertainty not stated in [bench]: eps and the mean move with it)"
    if all(m.implied.epsilon_pinned for m in means.values()):
        caveats = " (eps from the static trial)"
    if any(m.implied.backemf_loss_nm is None for m in means.values()):
        caveats += " (no winding identified: what the loop loses to the back-EMF is not in it)"
    lines = [f"mean torque (model): {significant(100 * abs(errors[worst]))} % {_side(errors[worst])} the set point "
             f"at worst ({_at(worst)}), +- {significant(100 * means[worst].error_std)} %{caveats}; each point "
             f"{100 * min(errors.values()):+.2f} to {100 * max(errors.values()):+.2f} %"]
    truths = {p: error for p, m in means.items() if (error := m.true_error) is not None}
    if truths:
        worst = max(truths, key=lambda p: abs(truths[p]))
        apart = max(_in_std(truths[p] - errors[p], means[p].error_std) for p in truths)
        lines.append(f"mean torque (true): {significant(100 * abs(truths[worst]))} % {_side(truths[worst])} the set "
                     f"point at worst ({_at(worst)}); each point within {significant(apart)} standard errors of the "
                     "model's")
    return lines


def _in_std(difference: float, std: float) -> float:
    """|``difference``| in standard errors ``std``: 0 for none, infinite for some over a zero standard error."""
    if difference == 0.0:
        return 0.0
    return abs(difference) / std if std > 0 else math.inf


def _side(error: float) -> str:
    return "below" if error < 0 else "above"


def final_lines(summary: dict) -> list[str]:
    """summary.json's points in words (`results_of`, `floors_of`, `mean_torques_of`): per set of points (learned,
    then validation) and kind of peak-to-peak ripple (true, then measured) `_ripple_lines`, each figure beside the
    point it belongs to; the points' mean torque (`mean_torque_lines`); then the motor time per phase.
    `FINAL_TITLE` heads them."""
    results, floors = results_of(summary), floors_of(summary)
    lines = [line for where, learned in (("learned", True), ("validation", False)) for kind in ("true", "measured")
             for line in _ripple_lines(where, kind, [r for r in results if r.learned == learned], floors)]
    lines += mean_torque_lines(mean_torques_of(summary))
    motor = summary.get("motor_time_s")
    if motor:
        phases = ", ".join(f"{phase} {t / 60:.1f}" for phase, t in motor.items() if phase != "all")
        lines.append(f"motor time: {motor['all'] / 60:.1f} min ({phases} min; warm-ups included)")
    return lines
