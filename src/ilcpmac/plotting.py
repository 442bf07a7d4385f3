"""The one matplotlib set-up of every plot: figures, colours per set point, angle axes, percent and count ticks,
spectra as stems, saving as PNG, SVG or PDF.

Figures are `matplotlib.figure.Figure` objects made without pyplot: no global
backend or figure registry is touched (PNG is drawn by Agg), nothing has to be
closed, and building figures in a library or a test leaves no state behind.
Axis labels are ``"quantity (unit)"``; position is in mechanical degrees.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.axis import Axis
from matplotlib.figure import Figure
from matplotlib.legend import Legend
from matplotlib.ticker import FuncFormatter, LogLocator, MaxNLocator, NullFormatter
from PIL import Image

from ilcpmac.core.errors import IlcpmacError

__all__ = ["ANGLE_LABEL", "FORMATS", "HARMONIC_LABEL", "PlotError", "angle_axis", "check_format", "count_ticks",
           "figure", "group_colours", "harmonic_stems", "legend", "mechanical_degrees", "percent_text", "percent_ticks",
           "plot_groups", "save"]

#: the formats `save` writes
FORMATS = ("png", "svg", "pdf")
#: resolution of PNG files (modest: the figures are read on screen and kept in the repository)
PNG_DPI = 90
#: width of every figure, inches
WIDTH_IN = 8.0
#: colours of a compact PNG
COMPACT_COLOURS = 64
#: the label of every position axis
ANGLE_LABEL = "position (mechanical deg)"
#: the label of every harmonic axis
HARMONIC_LABEL = "harmonic (per mechanical revolution)"
#: font size of legends
LEGEND_FONT_SIZE = 7
#: spectrum amplitudes below this fraction of a figure's largest are numerical zeros and not drawn
SPECTRUM_FLOOR = 1e-6
#: width of the last series' stems in `harmonic_stems`, points; each series before it is `STEM_STEP_PT` wider
STEM_WIDTH_PT = 1.0
STEM_STEP_PT = 2.5


class PlotError(IlcpmacError):
    """A figure cannot be written as asked (unknown format)."""


def figure(rows: int = 1, height_in: float = 3.0, sharex: bool = True) -> tuple[Figure, list[Axes]]:
    """A figure of ``rows`` stacked axes with a light grid, laid out automatically.

    Parameters
    ----------
    rows : number of axes, one above the other.
    height_in : height of each axes, inches.
    sharex : whether the axes share their x axis.
    """
    fig = Figure(figsize=(WIDTH_IN, height_in * rows), layout="constrained")
    axes = fig.subplots(rows, 1, squeeze=False, sharex=sharex)[:, 0]
    for axis in axes:
        axis.grid(True, alpha=0.3)
    return fig, list(axes)


def legend(axis: Axes, ncol: int = 1, **options: Any) -> Legend:
    """The legend of ``axis`` in the common style."""
    return axis.legend(fontsize=LEGEND_FONT_SIZE, ncol=ncol, **options)


def save(fig: Figure, path: str | Path, fmt: str = "png", compact: bool = False) -> Path:
    """Write ``fig`` as ``fmt`` (png, svg or pdf) to ``path`` plus that suffix; returns the path written.

    ``compact`` writes a PNG with a palette of `COMPACT_COLOURS` colours (a quarter of the bytes, for figures
    kept in the repository).

    Raises
    ------
    PlotError
        When ``fmt`` is not one of `FORMATS`.
    """
    check_format(fmt, path)
    path = Path(path)
    path = path.with_name(f"{path.name}.{fmt}")  # not with_suffix: "before_after_2Nm_0.5Hz" holds a dot
    if compact and fmt == "png":
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=PNG_DPI)
        with Image.open(buffer) as image:
            image.convert("RGB").quantize(COMPACT_COLOURS, Image.Quantize.FASTOCTREE).save(path, optimize=True)
    else:
        fig.savefig(path, format=fmt, dpi=PNG_DPI, metadata=_METADATA[fmt])
    return path


def check_format(fmt: str, path: str | Path) -> None:
    """Raise `PlotError` naming ``path`` unless ``fmt`` is one of `FORMATS`."""
    if fmt not in FORMATS:
        raise PlotError(f"{path}: unknown figure format {fmt!r} (one of {', '.join(FORMATS)})")


#: no creation date or version in the files, so that the same figure gives the same bytes
_METADATA = {"png": {"Software": None}, "svg": {"Date": None, "Creator": None},
             "pdf": {"CreationDate": None, "Creator": None, "Producer": None}}


def mechanical_degrees(counts: np.ndarray, counts_per_rev: int) -> np.ndarray:
    """Encoder counts as mechanical degrees."""
    return 360.0 * np.asarray(counts, float) / counts_per_rev


def angle_axis(axis: Axes, span_deg: float = 360.0) -> None:
    """Label ``axis``'s x axis as position in mechanical degrees over 0..``span_deg``."""
    axis.set_xlabel(ANGLE_LABEL)
    axis.set_xlim(0.0, span_deg)


def group_colours(keys: Sequence[float]) -> dict[float, tuple]:
    """One colour per distinct key (a set point), in order along viridis."""
    distinct = sorted(set(keys))
    cmap = colormaps["viridis"]
    return {key: cmap(0.85 * i / max(len(distinct) - 1, 1)) for i, key in enumerate(distinct)}


def plot_groups(axis: Axes, x: np.ndarray | Sequence[np.ndarray], ys: Sequence[np.ndarray], keys: Sequence[float],
                label: Callable[[float, int], str | None], method: str = "plot", **style: Any) -> dict[float, tuple]:
    """Many lines coloured by group, one legend entry per group; returns the colours.

    Parameters
    ----------
    axis : the axes.
    x : one array for every line, or a sequence of arrays, one per line.
    ys : the lines.
    keys : the group of each line (e.g. its torque set point).
    label : ``label(key, n)``, the legend entry of a group of ``n`` lines (None: none).
    method : the Axes method that draws a line ("plot", "semilogx", ...).
    style : passed to it.
    """
    colours = group_colours(keys)
    counts = {key: list(keys).count(key) for key in colours}
    labelled = set()
    draw = getattr(axis, method)
    for i, (y, key) in enumerate(zip(ys, keys)):
        xi = x[i] if isinstance(x, (list, tuple)) else x
        name = None if key in labelled else label(key, counts[key])
        labelled.add(key)
        draw(xi, y, color=colours[key], label=name, **style)
    return colours


def percent_text(value: float) -> str:
    """A percentage as a reader writes it, to 3 significant digits: ``"0.4 %"``, ``"0.05 %"``, ``"120 %"``."""
    return f"{float(f'{value:.3g}'):g} %"


def percent_ticks(axis: Axis, low: float, high: float) -> None:
    """Tick a log-scaled ``axis`` (an axes' x or y axis, or a colour bar's) holding percentages from ``low`` to
    ``high`` with plain labels ("0.1 %", "0.4 %", not 4x10^-1): ticks at 1, 2, 3, 5 and 7 of a decade over less
    than one decade, 1, 2 and 5 over less than three, else at the decades; minor ticks unlabelled."""
    decades = np.log10(max(high, low) / low) if low > 0 else np.inf
    subs = (1.0, 2.0, 3.0, 5.0, 7.0) if decades < 1 else (1.0, 2.0, 5.0) if decades < 3 else (1.0,)
    axis.set_major_locator(LogLocator(subs=subs))
    axis.set_major_formatter(FuncFormatter(lambda value, _: percent_text(value)))
    axis.set_minor_formatter(NullFormatter())


def count_ticks(axis: Axis) -> None:
    """Tick ``axis`` at whole numbers only (a count of tasks, trials): no 2.5 tasks."""
    axis.set_major_locator(MaxNLocator(integer=True))


def harmonic_stems(axis: Axes, series: dict[str, tuple[np.ndarray, np.ndarray]], colours: Sequence[Any],
                   scale: float = 1.0, stemmed: dict[str, np.ndarray] | None = None) -> float:
    """Spectra as stems on a log amplitude axis: per series a vertical line from the bottom of the axes to the
    amplitude of each harmonic, with a dot on top, and no line from one harmonic to the next; returns the
    bottom of the axes.

    The first series' stems are the widest and each later one's narrower (`STEM_WIDTH_PT`, `STEM_STEP_PT`),
    so a series drawn over another at the same harmonic leaves it visible around it. Amplitudes below
    `SPECTRUM_FLOOR` of the largest are numerical zeros and left out.

    Parameters
    ----------
    axis : the axes (set to a log y scale, its y limits from a decade below the least amplitude drawn to above
        the largest).
    series : label -> (harmonics, amplitudes, in the unit of the axis before ``scale``).
    colours : one colour per series, in order.
    scale : the factor from the amplitudes' unit to the axis's (1000: N m drawn as mN m).
    stemmed : label -> which of its harmonics get a stem (those that stand out of their noise, say); the others
        a dot alone. Default: all.
    """
    largest = max((float(np.max(a, initial=0.0)) for _, a in series.values()), default=0.0)
    kept = {name: a > SPECTRUM_FLOOR * largest for name, (_, a) in series.items()}
    shown = {name: (h[kept[name]], scale * a[kept[name]]) for name, (h, a) in series.items()}
    stems = {name: np.ones(a.size, bool)[kept[name]] if stemmed is None else stemmed[name][kept[name]]
             for name, (_, a) in series.items()}
    values = np.concatenate([a for _, a in shown.values()] + [np.zeros(0)])
    if not values.size:
        return 1.0
    bottom = 10.0 ** np.floor(np.log10(values.min()) - 0.3)
    axis.set_yscale("log")
    axis.set_ylim(bottom, 2.0 * values.max())
    for i, ((name, (harmonics, amplitudes)), colour) in enumerate(zip(shown.items(), colours)):
        width = STEM_WIDTH_PT + STEM_STEP_PT * (len(shown) - 1 - i)
        axis.vlines(harmonics[stems[name]], bottom, amplitudes[stems[name]], color=colour, lw=width,
                    alpha=0.45 if i < len(shown) - 1 else 1.0)
        axis.plot(harmonics, amplitudes, "o", color=colour, ms=2 + width / 2, ls="none", label=name)
    axis.set_xlabel(HARMONIC_LABEL)
    return float(bottom)
