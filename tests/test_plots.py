"""The figures: axis labels with units, a legend wherever lines are many, position in mechanical degrees, formats.

Checked through matplotlib's objects on a small synthetic bench (6 set points), not by looking at pixels.
"""

from __future__ import annotations

import importlib.util
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from identify_helpers import identified, other_bench
from matplotlib.collections import LineCollection, PolyCollection
from PIL import Image

from ilcpmac import plotting
from ilcpmac.bench.format import write_bench
from ilcpmac.cli import main
from ilcpmac.identify.plots import IDENTIFICATION_FIGURES, SIGNAL_FIGURES, build_figures

ROOT = Path(__file__).resolve().parents[1]
#: "quantity (unit)"
UNIT = re.compile(r"\S \(.+\)$")


def _reproduction():
    spec = importlib.util.spec_from_file_location("reproduce_report", ROOT / "benchmarks" / "reproduce_report.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def small():
    """The identification of the small synthetic bench and its truth."""
    return identified("other")


@pytest.fixture(scope="module")
def figures(small):
    result, _ = small
    return build_figures(result, SIGNAL_FIGURES | IDENTIFICATION_FIGURES)


@pytest.fixture(scope="module")
def reproduction(small):
    result, truth = small
    return _reproduction().reproduction_figures(result, truth)


def _data_lines(axis) -> list:
    """The lines that draw data (not the empty proxies that only label the legend)."""
    return [line for line in axis.get_lines() if len(line.get_xdata()) > 0]


def _panels(fig) -> list:
    """The axes that draw data: colorbars left out."""
    return [axis for axis in fig.axes if axis.get_label() != "<colorbar>"]


def assert_readable(name: str, fig) -> None:
    """Every axis label (a colorbar's too) has a unit, the bottom axes has an x label, every axes with two lines
    or more has a legend that names groups rather than lines, position is in mechanical degrees within one
    revolution."""
    axes = fig.axes
    assert axes, name
    assert _panels(fig)[-1].get_xlabel(), f"{name}: no x label on the bottom axes"
    for axis in axes:
        for label in (axis.get_xlabel(), axis.get_ylabel()):
            assert label == "" or UNIT.search(label), f"{name}: axis label {label!r} has no unit"
        assert axis.get_ylabel(), f"{name}: an axes without y label"
        lines = _data_lines(axis)
        if len(lines) + len(axis.containers) >= 2:
            legend = axis.get_legend()
            assert legend is not None, f"{name}: {len(lines)} lines and no legend"
            texts = [t.get_text() for t in legend.get_texts()]
            assert texts and all(texts), name
            assert len(texts) <= 12, f"{name}: {len(texts)} legend entries"
        if axis.get_xlabel() == plotting.ANGLE_LABEL:
            low, high = axis.get_xlim()
            assert low == 0.0 and 0.0 < high <= 360.0, f"{name}: angle axis {low}..{high}"
            assert max(np.max(line.get_xdata()) for line in lines) <= high, name


def test_every_figure_is_built_on_a_small_bench(figures):
    assert set(figures) == set(IDENTIFICATION_FIGURES) | set(SIGNAL_FIGURES)


@pytest.mark.parametrize("name", sorted(IDENTIFICATION_FIGURES) + sorted(SIGNAL_FIGURES))
def test_identification_figures_have_units_and_legends(figures, name):
    assert_readable(name, figures[name])


def test_lines_of_many_set_points_are_grouped_by_torque(small, figures):
    """Fig. 4.2 draws one line per set point (6) and names the 3 torque set points once each."""
    result, _ = small
    axis = figures["cogging_per_setpoint"].axes[0]
    texts = [t.get_text() for t in axis.get_legend().get_texts()]
    torques = sorted({t.torque_setpoint_nm for t in result.details.tables.trials})
    assert len(_data_lines(axis)) == len(result.details.tables.trials) + 1
    assert [t for t in texts if "N m (" in t] == [f"{t:g} N m (2 set points)" for t in torques]


def test_positions_are_in_mechanical_degrees(small, figures):
    """Figs. 4.1-4.3 and 2.1-2.3 span one electrical revolution: 360 / pole pairs degrees, not counts."""
    result, _ = small
    span = 360.0 / result.details.tables.motor.pole_pairs
    for name in ("torque_reference", "measured_ripple_per_setpoint", "ripple_split_currents_cogging",
                 "cogging_per_setpoint", "cogging_spread_per_setpoint"):
        axis = figures[name].axes[-1]
        assert axis.get_xlabel() == plotting.ANGLE_LABEL
        assert axis.get_xlim() == (0.0, span)
        assert max(np.max(line.get_xdata()) for line in _data_lines(axis)) < span


@pytest.mark.parametrize("name", sorted(IDENTIFICATION_FIGURES) + sorted(SIGNAL_FIGURES))
def test_reproduction_figures_have_units_and_legends(reproduction, name):
    assert_readable(name, reproduction[name])


def test_reproduction_figures_show_the_reports_numbers_and_the_truth(reproduction):
    def legend_text(name: str, index: int = 0) -> str:
        return " ".join(t.get_text() for t in reproduction[name].axes[index].get_legend().get_texts())

    assert "report (fig. 2.5): delta*eps = 0.56285" in legend_text("system_gain_fitted_harmonics")
    assert "truth" in legend_text("system_gain_fitted_harmonics")
    assert "report (fig. 3.3): J_mean = 0.00821" in legend_text("inertia_per_setpoint")
    assert "truth" in legend_text("cogging_per_setpoint")
    assert "up to 8 %" in legend_text("cogging_spread_per_setpoint")


def test_the_committed_reproduction_shows_every_figure_and_table_of_chapters_2_to_4():
    text = (ROOT / "docs" / "reproduction.md").read_text()
    assert text.splitlines()[2] == "Generated by `python benchmarks/reproduce_report.py`; do not edit by hand."
    for number in ("2.1", "2.2", "2.3", "2.4", "2.5", "3.1", "3.2", "3.3", "4.1", "4.2", "4.3"):
        assert f"### Figure {number}:" in text
    assert "### Table 3.1:" in text and "### Table 4.1:" in text
    for name in set(IDENTIFICATION_FIGURES) | set(SIGNAL_FIGURES):
        assert f"](reproduction/{name}.png)" in text
        assert (ROOT / "docs" / "reproduction" / f"{name}.png").is_file()
    assert sum(p.stat().st_size for p in (ROOT / "docs" / "reproduction").glob("*.png")) < 600_000


@pytest.mark.parametrize("fmt", plotting.FORMATS)
def test_save_writes_each_format(tmp_path, figures, fmt):
    path = plotting.save(figures["inertia_per_setpoint"], tmp_path / "fig", fmt)
    assert path == tmp_path / f"fig.{fmt}"
    magic = {"png": b"\x89PNG", "svg": b"<?xml", "pdf": b"%PDF"}[fmt]
    assert path.read_bytes().startswith(magic)


def test_a_compact_png_has_a_small_palette(tmp_path, figures):
    fig = figures["cogging_spread_per_setpoint"]
    full = plotting.save(fig, tmp_path / "full", "png")
    compact = plotting.save(fig, tmp_path / "compact", "png", compact=True)
    with Image.open(compact) as image:
        assert image.mode == "P" and len(image.getcolors()) <= plotting.COMPACT_COLOURS
        assert image.size == Image.open(full).size
    assert compact.stat().st_size < full.stat().st_size


def test_an_unknown_format_is_one_line_naming_the_file(tmp_path, figures):
    with pytest.raises(plotting.PlotError, match=r"fig: unknown figure format 'jpg' \(one of png, svg, pdf\)$"):
        plotting.save(figures["inertia_per_setpoint"], tmp_path / "fig", "jpg")


def test_cli_writes_the_figures_in_the_format_asked(tmp_path):
    bench, _ = other_bench()
    write_bench(tmp_path / "bench", bench)
    out = CliRunner().invoke(main, ["identify", str(tmp_path / "bench"), "--output", str(tmp_path / "result.json"),
                                    "--plots", str(tmp_path / "plots"), "--format", "svg"])
    assert out.exit_code == 0, out.output
    assert sorted(p.name for p in (tmp_path / "plots").iterdir()) == sorted(f"{n}.svg" for n in IDENTIFICATION_FIGURES)


def test_cli_refuses_an_unknown_format_before_reading(tmp_path):
    out = CliRunner().invoke(main, ["identify", str(tmp_path), "--output", str(tmp_path / "r.json"),
                                    "--plots", str(tmp_path / "plots"), "--format", "jpg"])
    assert out.exit_code == 2
    assert "'jpg' is not one of 'png', 'svg', 'pdf'" in out.output
    assert not (tmp_path / "plots").exists()


# ---------------------------------------------------------------- the report of a run directory (ilcpmac report)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A tiny campaign's run directory: 2 learned points (2 and 4 N m at 0.9 Hz), 2 learning trials each, a
    validation point (3 N m at 0.9 Hz)."""
    from campaign_helpers import SMALL_CAMPAIGN, run_campaign
    from conftest import SEED_CONFIG, toml_text

    from ilcpmac.config import load_config

    folder = tmp_path_factory.mktemp("report")
    data = tomllib.loads(SEED_CONFIG.read_text())
    for table, values in SMALL_CAMPAIGN.items():
        for key, value in values.items():
            data.setdefault(table, {})[key] = dict(data.get(table, {}).get(key, {}), **value) \
                if isinstance(value, dict) else value
    data["campaign"]["learn_trials"] = 2
    (folder / "campaign.toml").write_text(toml_text(data))
    run_campaign(load_config(folder / "campaign.toml"), folder / "run")
    return folder / "run"


@pytest.fixture(scope="module")
def run_report(run_dir):
    from ilcpmac.report.plots import RunReport

    return RunReport.read(run_dir)


@pytest.fixture(scope="module")
def report_figures(run_report):
    from ilcpmac.report.plots import build_figures

    figures, why = build_figures(run_report)
    assert why is None
    return figures


#: SMALL_CAMPAIGN's figures: per learned point (2 and 4 N m at 0.9 Hz), and the operating range
REPORT_FIGURES = ["ripple_per_trial", "before_after_2Nm_0.9Hz", "before_after_4Nm_0.9Hz", "before_after_3Nm_0.9Hz",
                  "operating_range", "learned_2Nm_0.9Hz", "learned_4Nm_0.9Hz"]


def _legend_texts(axis) -> list[str]:
    return [t.get_text() for t in axis.get_legend().get_texts()]


def test_the_report_has_its_figures_per_learned_point(report_figures):
    assert list(report_figures) == REPORT_FIGURES


@pytest.mark.parametrize("name", REPORT_FIGURES)
def test_report_figures_have_units_and_legends(report_figures, name):
    assert_readable(name, report_figures[name])


def test_ripple_per_trial_marks_set_points_and_phases(run_report, report_figures):
    (axis,) = report_figures["ripple_per_trial"].axes
    assert axis.get_xlabel() == "trial (index)"
    assert axis.get_ylabel() == "ripple peak-to-peak (% of mean torque)"
    assert axis.get_yscale() == "log"
    texts = _legend_texts(axis)
    assert {"2 N m set point", "3 N m set point", "4 N m set point", "measured", "true (simulator)"} <= set(texts)
    assert [t.get_text() for t in axis.texts] == ["identify", "compensate", "learn", "validate"]
    assert len(axis.patches) == 4  # one band per phase
    markers = {(line.get_marker(), tuple(line.get_color())) for line in _data_lines(axis)
               if line.get_marker() != "None"}
    assert len({colour for _, colour in markers}) == 3  # a colour per torque set point, 3 N m validated
    assert {marker for marker, _ in markers} == {"o", "x"}


def test_ripple_per_trial_phase_names_do_not_overlap():
    """The default campaign's phases (a short compensation between the grid and the learning): each name
    readable, none over another or over the title."""
    from ilcpmac.campaign.record import TrialRecord
    from ilcpmac.report.plots import ripple_per_trial
    from ilcpmac.signals.harmonics import RippleFigures

    runs = [("identify", 39), ("compensate", 9), ("learn", 53), ("validate", 12)]
    phases = [phase for phase, n in runs for _ in range(n)]
    ripple = RippleFigures(0.01, *(1e-3,) * 7)
    records = [TrialRecord(i, phase, "learn", 1.0, 0.5, ripple, ripple) for i, phase in enumerate(phases, 1)]
    fig = ripple_per_trial(records)
    fig.canvas.draw()
    (axis,) = fig.axes
    boxes = {t.get_text(): t.get_window_extent() for t in axis.texts}
    assert list(boxes) == [phase for phase, _ in runs]
    title = axis.title.get_window_extent()
    for i, (name, box) in enumerate(boxes.items()):
        assert not box.overlaps(title), name
        for other, other_box in list(boxes.items())[i + 1:]:
            assert not box.overlaps(other_box), (name, other)


def _spectrum_panels(fig) -> list:
    return [axis for axis in fig.axes if axis.get_xlabel() == plotting.HARMONIC_LABEL]


def test_before_after_shows_measured_and_true_torque_over_one_revolution(report_figures):
    fig = report_figures["before_after_2Nm_0.9Hz"]
    top, middle, sensor, true = fig.axes
    assert fig.get_suptitle().startswith("2 N m at 0.9 Hz, learned point: ")
    for axis, when in ((top, "uncompensated"), (middle, "compensated")):
        assert axis.get_title().startswith(f"{when} (trial ")
        assert axis.get_ylabel() == "torque (mN m)"
        assert axis.get_xlabel() == plotting.ANGLE_LABEL and axis.get_xlim() == (0.0, 360.0)
        assert _legend_texts(axis) == ["torque sensor", "true"]
    for axis, kind in ((sensor, "torque sensor"), (true, "true")):
        assert axis.get_xlabel() == "harmonic (per mechanical revolution)"
        assert axis.get_ylabel() == "amplitude (mN m)" and axis.get_yscale() == "log"
        assert kind in axis.get_title()
        assert _legend_texts(axis) == ["uncompensated", "compensated", "noise of the compensated trial (1 std. error)"]


def test_spectra_are_stems_with_no_line_from_one_harmonic_to_the_next(report_figures):
    """Every spectrum (before/after and learned) draws each harmonic as a stem or a dot: no line joins adjacent
    harmonics, and the series drawn first is the wider, so the one over it leaves it visible."""
    for name in ("before_after_2Nm_0.9Hz", "learned_2Nm_0.9Hz"):
        for axis in _spectrum_panels(report_figures[name]):
            for line in _data_lines(axis):
                assert line.get_linestyle() == "None", (name, line.get_label())
            stems = [c for c in axis.collections if isinstance(c, LineCollection)]
            assert len(stems) == 2, name
            widths = [float(c.get_linewidth()[0]) for c in stems]
            assert widths[0] > widths[1], name
            for collection in stems:
                for segment in collection.get_segments():
                    assert segment[0, 0] == segment[1, 0], name  # vertical: one harmonic each


def test_before_after_spectra_show_the_compensated_trials_noise_as_a_band(report_figures):
    for axis in _spectrum_panels(report_figures["before_after_2Nm_0.9Hz"]):
        bands = [c for c in axis.collections if isinstance(c, PolyCollection)]
        assert [b.get_label() for b in bands] == ["noise of the compensated trial (1 std. error)"]


def test_validation_points_have_their_before_and_after(run_report, report_figures):
    """The validation point (3 N m at 0.9 Hz): its baseline trial against its validation trial."""
    fig = report_figures["before_after_3Nm_0.9Hz"]
    assert fig.get_suptitle().startswith("3 N m at 0.9 Hz, validation point (never learned): ")
    at = [r for r in run_report.records if r.point == (3.0, 0.9)]
    baseline = next(r for r in at if r.role == "baseline")
    validation = next(r for r in at if r.role == "validate")
    top, middle = fig.axes[:2]
    assert top.get_title().startswith(f"uncompensated (trial {baseline.index}, baseline)")
    assert middle.get_title().startswith(f"compensated (trial {validation.index}, validate)")
    assert len(_spectrum_panels(fig)) == 2


def test_learned_shows_each_stage_per_point_as_spectrum_and_over_a_whole_revolution(run_report, report_figures):
    H = run_report.max_harmonic
    for torque in (2, 4):
        fig = report_figures[f"learned_{torque}Nm_0.9Hz"]
        top, *stages = fig.axes
        assert top.get_yscale() == "log" and top.get_xlabel() == "harmonic (per mechanical revolution)"
        assert top.get_xlim() == (0.0, H + 1.0)
        assert _legend_texts(top) == ["cogging", "ilc"]
        assert "current-sensor: none" in fig.get_suptitle()
        assert fig.get_suptitle().startswith(f"{torque} N m at 0.9 Hz: ")
        assert [axis.get_title().split(":")[0] for axis in stages] == ["cogging", "ilc"]
        for axis in stages:
            assert axis.get_xlim() == (0.0, 360.0)
            assert axis.get_ylabel() == "feed-forward torque (mN m)"
            (line,) = _data_lines(axis)
            assert line.get_xdata()[-1] > 359.0


def test_learned_spectrum_names_the_harmonics_each_stage_learned_most(run_report, report_figures):
    """The ILC's largest harmonics, wherever they lie in 1..H (not only within one cogging period), are drawn and
    named by their order."""
    from ilcpmac.report.plots import NAMED_HARMONICS, learned_feedforward
    from ilcpmac.signals.harmonics import harmonic_amplitudes

    item = learned_feedforward(run_report)[0]
    amplitude = np.abs(harmonic_amplitudes(item.tables_nm["ilc"], run_report.max_harmonic)[1:])
    largest = {int(k) + 1 for k in np.argsort(amplitude)[::-1][:NAMED_HARMONICS]}
    top = report_figures[f"learned_{item.record.point[0]:g}Nm_0.9Hz"].axes[0]
    assert largest <= {int(t.get_text()) for t in top.texts}
    ilc = next(line for line in _data_lines(top) if line.get_label() == "ilc")
    assert largest <= set(ilc.get_xdata().astype(int))


@pytest.mark.parametrize("name", ["operating_range", "ripple_per_trial"])
def test_percentages_read_as_plain_percent(report_figures, name):
    """The colour bars and the ripple axis read "0.2 %", not 2x10^-1."""
    fig = report_figures[name]
    fig.canvas.draw()
    axes = [a for a in fig.axes if a.get_label() == "<colorbar>"] if name == "operating_range" else fig.axes
    for axis in axes:
        texts = [t.get_text() for t in axis.yaxis.get_ticklabels() if t.get_text()]
        assert texts, name
        for text in texts:
            assert re.fullmatch(r"\d+(\.\d+)? %", text), (name, text)


def _rebuilt(report, index: int) -> dict[str, np.ndarray]:
    """Each stage's part of the feed-forward at trial ``index``'s point, from the states saved with it: the
    stages built from the identification and restored, a request with that trial's calibration through them."""
    from ilcpmac.core.records import TrialRequest
    from ilcpmac.stages.base import Identified, StageSetup
    from ilcpmac.stages.registry import build_stages

    files, cfg, description = report.files, report.config, report.description
    identified = Identified.from_result(files.read_json(files.identification)["result"], description.calibration)
    names = list(cfg.pipeline.stages)
    stages = build_stages(names, {name: StageSetup(description, identified, report.max_harmonic,
                                                   cfg.stage_options.get(name, {})) for name in names})
    state, record = files.read_state(index), report.records[index - 1]
    for stage in stages:
        stage.restore(state.stages[stage.name])
    cpr = description.motor.counts_per_rev
    request = TrialRequest(*record.point, 1, np.zeros(cpr), np.zeros(cpr), state.calibration)
    tables = {}
    for stage in stages:
        shaped = stage.shape(request)
        tables[stage.name] = shaped.feedforward_nm - request.feedforward_nm
        request = shaped
    return tables


def test_each_stage_learned_part_adds_up_to_the_next_requests_feedforward(run_report):
    """Rebuilt from the states of trial 10 (the first learning trial at 4 N m, 0.9 Hz, which ends the first
    learning round), the stages' parts add up to the feed-forward trial 12 (the next there, shaped as its
    round began) ran with."""
    records = run_report.records
    assert [(r.index, r.phase, r.role, r.point) for r in records[8:12]] == [
        (9, "learn", "learn", (2.0, 0.9)), (10, "learn", "learn", (4.0, 0.9)),
        (11, "learn", "learn", (2.0, 0.9)), (12, "learn", "learn", (4.0, 0.9))]
    tables = _rebuilt(run_report, 10)
    assert list(tables) == ["current-sensor", "cogging", "ilc", "mean-torque"] and not tables["current-sensor"].any()
    applied = run_report.files.read_state(12).feedforward_nm
    np.testing.assert_allclose(sum(tables.values()), applied, atol=1e-12)


def test_the_report_draws_what_the_run_saved_each_stage_learned(run_report):
    """states/learned.json holds, per learned point, exactly the parts the stages restored from the point's
    last trial give (to the bit); the report reads them and builds no stage."""
    from ilcpmac.compensation import Compensation
    from ilcpmac.report.plots import learned_feedforward

    learned = learned_feedforward(run_report)
    assert [(item.record.index, item.record.point) for item in learned] == [(11, (2.0, 0.9)), (12, (4.0, 0.9))]
    for item in learned:
        rebuilt = _rebuilt(run_report, item.record.index)
        assert list(item.tables_nm) == list(rebuilt)
        for name, table in rebuilt.items():
            if name == "mean-torque":
                # its model reads the back-EMF table, which backemf.csv holds to 12 decimals: rebuilt from the
                # file, its constant moves by about 1e-12 of itself
                np.testing.assert_allclose(item.tables_nm[name], table, rtol=1e-11, atol=0.0)
                assert np.all(table > 0.0)
            else:
                np.testing.assert_array_equal(item.tables_nm[name].view(np.int64), table.view(np.int64))
    # the last trial of the campaign's learning left the stages as the compensation has them
    compensation = Compensation.read(run_report.files.compensation)
    np.testing.assert_allclose(sum(learned[1].tables_nm.values()), compensation.feedforward_nm(4.0, 0.9),
                               atol=1e-12)


def test_a_run_without_what_the_stages_learned_is_reported_without_its_figures(run_dir, tmp_path):
    """A run stopped before learning ended, or made before states/learned.json: every other figure, and one
    line saying why the learned ones are missing."""
    import shutil

    from ilcpmac.report.plots import RunReport, build_figures, learned_feedforward

    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    (copy / "states" / "learned.json").unlink()
    report = RunReport.read(copy)
    assert learned_feedforward(report) is None
    figures, why = build_figures(report)
    assert list(figures) == [name for name in REPORT_FIGURES if not name.startswith("learned_")]
    assert why is not None and why.startswith("no states/learned.json (") and "\n" not in why
    out = CliRunner().invoke(main, ["report", str(copy), "--out", str(tmp_path / "plots"), "--format", "svg"])
    assert out.exit_code == 0, out.output
    assert f"what each stage learned is not drawn: {why}" in " ".join(out.output.split())


def test_report_cli_writes_every_figure_in_the_format_asked(run_dir, tmp_path):
    out = CliRunner().invoke(main, ["report", str(run_dir), "--out", str(tmp_path / "plots"), "--format", "svg"])
    assert out.exit_code == 0, out.output
    assert sorted(p.name for p in (tmp_path / "plots").glob("*.svg")) == sorted(f"{n}.svg" for n in REPORT_FIGURES)


def test_report_cli_refuses_an_unknown_format(run_dir, tmp_path):
    out = CliRunner().invoke(main, ["report", str(run_dir), "--out", str(tmp_path / "plots"), "--format", "jpg"])
    assert out.exit_code == 2 and "'jpg' is not one of 'png', 'svg', 'pdf'" in out.output
    assert not (tmp_path / "plots").exists()


def test_a_stage_that_is_not_installed_where_the_report_runs_leaves_out_nothing(run_dir, tmp_path):
    """The report draws what the run saved (states/learned.json): it builds no stage."""
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    config = copy / "campaign.toml"
    config.write_text(config.read_text().replace('stages = ["current-sensor"', 'stages = ["absent", "current-sensor"'))
    out = CliRunner().invoke(main, ["report", str(copy), "--format", "pdf"])
    assert out.exit_code == 0, out.output
    assert "warning" not in out.output
    assert sorted(p.name for p in (copy / "plots").glob("*.pdf")) == sorted(f"{n}.pdf" for n in REPORT_FIGURES)


def test_report_of_a_folder_without_a_run_is_one_error_line(tmp_path):
    out = CliRunner().invoke(main, ["report", str(tmp_path)])
    assert out.exit_code == 2
    assert out.output == f"error: {tmp_path}: no summary.json (not a run directory of ilcpmac run)\n"


# ---------------------------------------------------------------- the operating range


def _scatters(axis) -> dict[str, object]:
    """The point collections of an operating-range panel by legend label."""
    return {c.get_label(): c for c in axis.collections}


def test_operating_range_shows_learned_and_validation_points_measured_and_true(run_report, report_figures):
    fig = report_figures["operating_range"]
    fig.canvas.draw()  # drawing maps a collection's values to colours (the legend's handles' below)
    panels = _panels(fig)
    assert [a.get_label() for a in fig.axes].count("<colorbar>") == len(panels) == 2
    bars = [a for a in fig.axes if a.get_label() == "<colorbar>"]
    assert [bar.get_ylabel() for bar in bars] == [f"{kind} ripple pp (% of mean torque)"
                                                  for kind in ("measured", "true")]
    for axis, kind in zip(panels, ("measured", "true")):
        assert axis.get_xlabel() == "speed (Hz, mechanical)"
        assert axis.get_ylabel() == "torque set point (N m)"
        assert kind in axis.get_title()
        assert _legend_texts(axis) == ["learned", "validation (never learned)"]
        for handle in axis.get_legend().legend_handles:  # shapes only: no colour of the ripple scale
            np.testing.assert_array_equal(handle.get_facecolor(), [[1.0, 1.0, 1.0, 1.0]])
        scatters = _scatters(axis)
        np.testing.assert_array_equal(scatters["learned"].get_offsets(), [[0.9, 2.0], [0.9, 4.0]])
        np.testing.assert_array_equal(scatters["validation (never learned)"].get_offsets(), [[0.9, 3.0]])
        last = {r.point: r for r in run_report.records if r.role in ("learn", "validate")}
        np.testing.assert_allclose(scatters["learned"].get_array(),
                                   [100 * last[p].figures(kind).pp for p in ((2.0, 0.9), (4.0, 0.9))])
        for collection in scatters.values():
            np.testing.assert_array_equal(collection.get_edgecolor()[:, :3], 0.0)  # better than none: black


def _point_records(points: dict, true: bool = True) -> list:
    """By hand: per point (torque, speed) -> (learned, uncompensated pp %, compensated pp %), its uncompensated
    trial and its compensated one (learn or validate) with their reduction factor; true figures if ``true``."""
    from ilcpmac.campaign.record import TrialRecord
    from ilcpmac.signals.harmonics import RippleFigures

    def ripple(pp_percent: float) -> RippleFigures:
        return RippleFigures(pp_percent / 100, *(1e-3,) * 7)

    records = []
    for (torque, speed), (learned, before, after) in points.items():
        phases = ("identify", "ilc", "learn") if learned else ("validate", "validate", "validate")
        factor = before / after
        records.append(TrialRecord(len(records) + 1, phases[0], "baseline", torque, speed, ripple(before),
                                   ripple(before) if true else None))
        records.append(TrialRecord(len(records) + 1, phases[1], phases[2], torque, speed, ripple(after),
                                   ripple(after) if true else None, factor, factor if true else None))
    return records


def test_operating_range_edges_a_point_worse_than_none_in_red():
    from ilcpmac.report.plots import operating_range

    points = {(1.0, 0.5): (True, 2.0, 0.01), (1.0, 1.5): (True, 2.0, 0.02), (2.0, 0.5): (False, 1.0, 0.05),
              (2.0, 1.5): (False, 1.0, 1.25)}
    records = _point_records(points)
    fig = operating_range(records, [(1.0, 0.5), (1.0, 1.5)], [(2.0, 0.5), (2.0, 1.5)])
    assert_readable("operating_range", fig)
    for axis in _panels(fig):
        scatters = _scatters(axis)
        assert scatters["learned"].get_edgecolor()[:, :3].tolist() == [[0, 0, 0]] * 2
        assert scatters["validation (never learned)"].get_edgecolor()[:, :3].tolist() == [[0, 0, 0], [1, 0, 0]]
        np.testing.assert_allclose(scatters["validation (never learned)"].get_array(), [0.05, 1.25])
        assert sorted(t.get_text() for t in axis.texts) == ["0.01 %\n200x", "0.02 %\n100x", "0.05 %\n20x",
                                                            "1.25 %\n0.8x"]


def test_operating_range_of_a_real_bench_has_the_measured_panel_alone():
    from ilcpmac.report.plots import operating_range

    records = _point_records({(1.0, 0.5): (True, 2.0, 0.01), (2.0, 0.5): (False, 1.0, 0.05)}, true=False)
    fig = operating_range(records, [(1.0, 0.5)], [(2.0, 0.5)])
    (panel,) = _panels(fig)
    assert "measured" in panel.get_title()
    assert _legend_texts(panel) == ["learned", "validation (never learned)"]
