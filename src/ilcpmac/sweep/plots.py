"""A sweep's plots: the distribution of its main figure, and the worst tasks against the parameter that
drives them most.

Every column is drawn under a label a reader knows, with its unit (`quantity`): the one table `QUANTITIES`
names the figures and the drawn keys of docs/sweep.md; any other key is labelled with the unit its name ends
in.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
from matplotlib.figure import Figure

from ilcpmac import plotting
from ilcpmac.sweep.results import column_values

__all__ = ["QUANTITIES", "Quantity", "build_plots", "driving_parameter", "quantity", "write_plots"]

#: the share of tasks marked as the worst
WORST_FRACTION = 0.05
#: the height of each figure, inches (room for a label with its unit along the y axis)
FIGURE_HEIGHT_IN = 3.6


@dataclass(frozen=True)
class Quantity:
    """How a column of the results table is drawn.

    Attributes
    ----------
    label : what it is, with its unit in brackets ("current-sensor scale α, phase a: error (%)").
    convert : from the table's value to the value drawn (a fraction to %, say).
    """

    label: str
    convert: Callable[[np.ndarray], np.ndarray]


def _percent(x: np.ndarray) -> np.ndarray:
    return 100.0 * x


def _percent_off_one(x: np.ndarray) -> np.ndarray:
    return 100.0 * (x - 1.0)


def _same(x: np.ndarray) -> np.ndarray:
    return x


#: column (a drawn key without "draw:" and its element) -> its label and conversion; "{element}" in a label is
#: the list element's name
QUANTITIES: dict[str, Quantity] = {
    "final_pp_true": Quantity("true ripple pp, worst learned point (% of mean torque)", _percent),
    "validation_pp_true": Quantity("true ripple pp, worst validation point (% of mean torque)", _percent),
    "pp_true": Quantity("true ripple pp at {element} (% of mean torque)", _percent),
    "trials": Quantity("trials of the campaign (count)", _same),
    "guard_events": Quantity("guard's reverts (count)", _same),
    "worse_points": Quantity("points worse than uncompensated (count)", _same),
    "id_error:delta_epsilon": Quantity("identified system gain δε: |error| (%)", _percent),
    "id_error:delta": Quantity("identified torque-sensor gain δ: |error| (%)", _percent),
    "id_error:epsilon": Quantity("identified current-sensor gain ε: |error| (%)", _percent),
    "id_error:inertia": Quantity("identified inertia J: |error| (%)", _percent),
    "id_error:alpha": Quantity("identified scale α, worst phase: |error| (%)", _percent),
    "id_error:beta_a": Quantity("identified offset β, worst phase: |error| (A)", _same),
    "id_error:cogging": Quantity("identified cogging: RMS |error| (%)", _percent),
    "simulator.current_sensors.alpha": Quantity("current-sensor scale α, phase {element}: error (%)",
                                                _percent_off_one),
    "simulator.current_sensors.beta_a": Quantity("current-sensor offset β, phase {element} (A)", _same),
    "simulator.current_sensors.epsilon": Quantity("current-sensor gain ε: error (%)", _percent_off_one),
    "simulator.torque_sensor.delta": Quantity("torque-sensor gain δ: error (%)", _percent_off_one),
    "simulator.mechanics.inertia_scale": Quantity("inertia: true against nominal (%)", _percent_off_one),
    "simulator.winding.backemf_scale": Quantity("back-EMF: true against nominal (%)", _percent_off_one),
    "simulator.mechanics.coulomb_friction_nm": Quantity("Coulomb friction (N m)", _same),
    "simulator.controller.bandwidth_hz": Quantity("current-loop bandwidth (Hz)", _same),
    "magnet_temperature_rise_k": Quantity("magnets' temperature rise (K)", _same),
}
#: the unit a key's name ends in, for a key `QUANTITIES` does not name
UNIT_SUFFIXES = {"_nm": "N m", "_hz": "Hz", "_k": "K", "_a": "A", "_s": "s", "_v": "V", "_kgm2": "kg m²",
                 "_ohm": "ohm", "_h": "H"}
#: the elements of a per-phase list
PHASES = "abc"
_ELEMENT = re.compile(r"(.+)\[(\d+)\]$")


def quantity(column: str) -> Quantity:
    """How ``column`` of the results table is drawn: its `QUANTITIES` entry (a list element's with the phase or
    element named), else its key with the unit its name ends in (`UNIT_SUFFIXES`; "-" without one)."""
    name = column.removeprefix("draw:")
    element = ""
    if (match := _ELEMENT.fullmatch(name)) is not None:
        name, index = match[1], int(match[2])
        element = PHASES[index] if index < len(PHASES) else str(index)
    elif name.startswith("pp_true:"):
        name, element = name.split(":", 1)
    known = QUANTITIES.get(name)
    if known is not None:
        return Quantity(known.label.format(element=element), known.convert)
    unit = next((u for suffix, u in UNIT_SUFFIXES.items() if name.endswith(suffix)), "-")
    shown = f"{name}[{element}]" if element else name
    return Quantity(f"{shown} ({unit})", _same)


def _name(shown: Quantity) -> str:
    """A quantity's label without its unit."""
    return shown.label.rsplit(" (", 1)[0]


def driving_parameter(table: pa.Table, column: str) -> str | None:
    """The drawn parameter whose rank correlation with ``column`` is largest in magnitude (Spearman), or None."""
    y = column_values(table, column)
    best, best_r = None, 0.0
    for name in table.column_names:
        if not name.startswith("draw:"):
            continue
        x = column_values(table, name)
        ok = np.isfinite(x) & np.isfinite(y)
        if ok.sum() < 3 or np.ptp(x[ok]) == 0 or np.ptp(y[ok]) == 0:
            continue
        r = abs(np.corrcoef(np.argsort(np.argsort(x[ok])), np.argsort(np.argsort(y[ok])))[0, 1])
        if r > best_r:
            best, best_r = name, r
    return best


def build_plots(table: pa.Table, column: str) -> dict[str, Figure]:
    """The distribution of ``column`` over the tasks and, against the parameter that drives it most, every task
    with the worst `WORST_FRACTION` marked; by file name."""
    shown = quantity(column)
    y = shown.convert(column_values(table, column))
    finite = y[np.isfinite(y)]
    fig, (axis,) = plotting.figure(1, FIGURE_HEIGHT_IN)
    axis.hist(finite, bins=max(10, min(60, len(finite) // 4)), color="tab:blue")
    for level, style in ((50, ":"), (95, "--"), (99, "-")):
        axis.axvline(np.percentile(finite, level), color="k", linestyle=style, label=f"{level}th percentile")
    axis.set_title(f"{_name(shown)} over {finite.size} tasks")
    axis.set_xlabel(shown.label)
    axis.set_ylabel("tasks (count)")
    plotting.count_ticks(axis.yaxis)
    plotting.legend(axis)
    figures = {"distribution": fig}
    parameter = driving_parameter(table, column)
    if parameter is not None:
        drawn = quantity(parameter)
        x = drawn.convert(column_values(table, parameter))
        worst = np.isfinite(y) & (y >= np.percentile(finite, 100 * (1 - WORST_FRACTION)))
        fig, (axis,) = plotting.figure(1, FIGURE_HEIGHT_IN)
        axis.scatter(x[~worst], y[~worst], s=8, color="tab:blue", label="tasks")
        axis.scatter(x[worst], y[worst], s=16, color="tab:red", label=f"worst {100 * WORST_FRACTION:g} %")
        axis.set_title(f"{_name(shown)}, per task,\nagainst the drawn parameter that drives it most: {_name(drawn)}",
                       fontsize=10)
        axis.set_xlabel(drawn.label)
        axis.set_ylabel(shown.label)
        plotting.legend(axis)
        figures["worst_against_parameter"] = fig
    return figures


def write_plots(table: pa.Table, column: str, folder: Path, fmt: str = "png") -> list[Path]:
    """Write `build_plots` as ``fmt`` into ``folder``; returns the files written."""
    folder.mkdir(parents=True, exist_ok=True)
    return [plotting.save(fig, folder / name, fmt) for name, fig in build_plots(table, column).items()]
