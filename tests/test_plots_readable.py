"""Plots a person can read (issue 26, item 6): a sweep's plots with titles, whole task counts and labels in
words with units; percentages as plain percent ticks; identification figures named and labelled for what they
show, not in the report's notation."""

from __future__ import annotations

import re

import numpy as np
import pyarrow as pa
import pytest
from identify_helpers import identified

from ilcpmac import plotting
from ilcpmac.identify.plots import IDENTIFICATION_FIGURES, SIGNAL_FIGURES, build_figures
from ilcpmac.sweep.plots import build_plots, quantity


@pytest.fixture(scope="module")
def sweep_plots():
    """12 identification tasks: the error of δε grows with phase a's drawn scale."""
    rng = np.random.default_rng(3)
    alpha = rng.normal(0.8, 0.02, 12)
    table = pa.table({"task": np.arange(12), "draw:simulator.current_sensors.alpha[0]": alpha,
                      "draw:simulator.mechanics.inertia_scale": rng.uniform(0.8, 1.2, 12),
                      "id_error:delta_epsilon": 1e-3 * (alpha - 0.7) + 1e-5 * rng.normal(size=12)})
    return build_plots(table, "id_error:delta_epsilon")


def test_sweep_plots_have_titles_and_labels_in_words_with_units(sweep_plots):
    (histogram,) = sweep_plots["distribution"].axes
    (scatter,) = sweep_plots["worst_against_parameter"].axes
    for axis in (histogram, scatter):
        assert axis.get_title()
    assert histogram.get_xlabel() == "identified system gain δε: |error| (%)"
    assert histogram.get_ylabel() == "tasks (count)"
    assert scatter.get_xlabel() == "current-sensor scale α, phase a: error (%)"
    assert "current-sensor scale α, phase a" in scatter.get_title()
    np.testing.assert_allclose(scatter.collections[0].get_offsets()[:, 0].min() < -15, True)  # (α - 1) in %


def test_sweep_task_counts_are_whole_numbers(sweep_plots):
    fig = sweep_plots["distribution"]
    fig.canvas.draw()
    (axis,) = fig.axes
    ticks = [t for t in axis.get_yticks() if axis.get_ylim()[0] <= t <= axis.get_ylim()[1]]
    assert ticks and all(float(t).is_integer() for t in ticks), ticks


@pytest.mark.parametrize(("column", "label"), [
    ("final_pp_true", "true ripple pp, worst learned point (% of mean torque)"),
    ("pp_true:3 Nm@0.5 Hz", "true ripple pp at 3 Nm@0.5 Hz (% of mean torque)"),
    ("draw:simulator.current_sensors.beta_a[2]", "current-sensor offset β, phase c (A)"),
    ("draw:magnet_temperature_rise_k", "magnets' temperature rise (K)"),
    ("draw:simulator.load.torque_nm", "simulator.load.torque_nm (N m)"),
    ("draw:trials.some_ratio[4]", "trials.some_ratio[4] (-)"),
])
def test_every_sweep_column_has_a_label_with_its_unit(column, label):
    assert quantity(column).label == label


@pytest.mark.parametrize(("low", "high", "expected"), [
    (0.18, 0.57, ["0.2 %", "0.3 %", "0.5 %"]),
    (0.05, 300.0, ["0.1 %", "1 %", "10 %", "100 %"]),
])
def test_percent_ticks_read_as_plain_percent(low, high, expected):
    fig, (axis,) = plotting.figure()
    axis.set_yscale("log")
    axis.set_ylim(low, high)
    plotting.percent_ticks(axis.yaxis, low, high)
    fig.canvas.draw()
    shown = [label.get_text() for tick, label in zip(axis.get_yticks(), axis.yaxis.get_ticklabels())
             if low <= tick <= high]
    assert shown == expected


@pytest.fixture(scope="module")
def identification_figures():
    result, _ = identified("other")
    return build_figures(result, SIGNAL_FIGURES | IDENTIFICATION_FIGURES)


#: the report's notation, which a reader without the report does not have
REPORT_NOTATION = re.compile(r"^fig\d|X y|\bz \(|tau\*|I\*_|sum_p|\|H\||\bJ\*|delta\*eps")


def test_identification_figures_are_named_for_what_they_show():
    for name in [*IDENTIFICATION_FIGURES, *SIGNAL_FIGURES]:
        assert not REPORT_NOTATION.search(name), name


def test_identification_labels_are_words_not_the_reports_symbols(identification_figures):
    for name, fig in identification_figures.items():
        for axis in fig.axes:
            texts = [axis.get_title(), axis.get_xlabel(), axis.get_ylabel()]
            if axis.get_legend() is not None:
                texts += [t.get_text() for t in axis.get_legend().get_texts()]
            for text in texts:
                assert not REPORT_NOTATION.search(text), (name, text)


def test_the_learning_phase_has_one_name_in_the_plots():
    """The campaign names its learning phase "learn" (old runs' "ilc" is read as "learn"): no band for "ilc"."""
    from ilcpmac.report.plots import PHASE_SHADES

    assert list(PHASE_SHADES) == ["identify", "compensate", "learn", "validate"]
