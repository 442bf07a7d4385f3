"""A sweep's plots: the distribution of its main figure, and the worst tasks against the parameter that
drives them most."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from ilcpmac.plotting import figure, save
from ilcpmac.sweep.results import column_values

__all__ = ["driving_parameter", "write_plots"]

#: the share of tasks marked as the worst
WORST_FRACTION = 0.05


def _label(column: str) -> str:
    if "pp_true" in column:
        return f"{column} (% of mean torque)"
    return f"|{column}|"


def _scale(column: str) -> float:
    return 100.0 if "pp_true" in column else 1.0


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


def write_plots(table: pa.Table, column: str, folder: Path, fmt: str = "png") -> list[Path]:
    """The distribution of ``column`` over the tasks and, against the parameter that drives it most, every task
    with the worst `WORST_FRACTION` marked; returns the files written."""
    folder.mkdir(parents=True, exist_ok=True)
    scale = _scale(column)
    y = column_values(table, column) * scale
    finite = y[np.isfinite(y)]
    fig, (axis,) = figure()
    axis.hist(finite, bins=max(10, min(60, len(finite) // 4)), color="tab:blue")
    for level, style in ((50, ":"), (95, "--"), (99, "-")):
        axis.axvline(np.percentile(finite, level), color="k", linestyle=style, label=f"{level}th percentile")
    axis.set_xlabel(_label(column))
    axis.set_ylabel("tasks")
    axis.legend(fontsize=7)
    written = [save(fig, folder / "distribution", fmt)]
    parameter = driving_parameter(table, column)
    if parameter is not None:
        x = column_values(table, parameter)
        worst = np.isfinite(y) & (y >= np.percentile(finite, 100 * (1 - WORST_FRACTION)))
        fig, (axis,) = figure()
        axis.scatter(x[~worst], y[~worst], s=8, color="tab:blue", label="tasks")
        axis.scatter(x[worst], y[worst], s=16, color="tab:red", label=f"worst {100 * WORST_FRACTION:g} %")
        axis.set_xlabel(parameter.removeprefix("draw:"))
        axis.set_ylabel(_label(column))
        axis.legend(fontsize=7)
        written.append(save(fig, folder / "worst_against_parameter", fmt))
    return written
