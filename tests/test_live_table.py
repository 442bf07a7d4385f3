"""What ``ilcpmac run`` shows (issue 10): the live table and the summary read in 80 and 100 columns with no
cell or header cut, the status line says what runs and what is left, the final message names what was
written and the next command, and summary.json says the units of its figures."""

from __future__ import annotations

import io
import json
import re

import pytest
from campaign_helpers import SMALL_CAMPAIGN
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st
from rich.console import Console

from ilcpmac.campaign.record import TrialRecord
from ilcpmac.campaign.runner import SUMMARY_UNITS
from ilcpmac.cli import main
from ilcpmac.cli.run import CampaignView, duration, files_written
from ilcpmac.report.table import FINAL_TITLE, SUMMARY_TITLE, final_lines, significant, summary_table, trials_table
from ilcpmac.signals.harmonics import RippleFigures

SETPOINTS = [1.0, 3.0, 5.0]
#: every column of the live table, as ``trials_table`` lays it out on a wide console
ALL_COLUMNS = 15


def ripple(pp: float, amp_nm: float) -> RippleFigures:
    return RippleFigures(pp, pp / 6, pp / 50, pp / 6.1, amp_nm, amp_nm / 5, amp_nm * 1.7, amp_nm / 4)


def campaign_records() -> list[TrialRecord]:
    """The records of a campaign of the seed bench's size and figures: a 5 x 6 grid, a baseline and a
    compensation per set point, then 10 ILC trials each, down to about 3000x below uncompensated."""
    records: list[TrialRecord] = []

    def add(phase: str, role: str, torque: float, speed: float, pp: float, amp_nm: float,
            factor: float | None = None) -> None:
        records.append(TrialRecord(len(records) + 1, phase, role, torque, speed, ripple(1.01 * pp, amp_nm),
                                   ripple(pp, amp_nm), factor and factor / 4, factor))

    for torque in (1.0, 2.0, 3.0, 4.0, 5.0):
        for speed in (0.5, 1.0, 1.5, 2.0, 2.5, 3.0):
            add("identify", "grid", torque, speed, 2.55 / torque, 0.26)
    for torque in SETPOINTS:
        add("identify", "baseline", torque, 0.75, 2.39 / torque, 0.24)
    for torque in SETPOINTS:
        add("compensate", "compensate", torque, 0.75, 0.06 / torque, 3.5e-4, 40.0)
    for torque in SETPOINTS:
        for k in range(10):
            pp = 8e-3 / torque / (k + 1)
            add("ilc", "ilc", torque, 0.75, pp, 2e-6, 2.39 / torque / pp)
    return records


def render(*renderables, width: int) -> str:
    console = Console(width=width, record=True, file=io.StringIO(), color_system=None)
    for renderable in renderables:
        console.print(renderable)
    return console.export_text()


def assert_nothing_cut(table, text: str, width: int) -> None:
    """No cell ends in an ellipsis, no line is wider than the console, every header line is whole."""
    assert "…" not in text
    assert max(map(len, text.splitlines())) <= width
    header = text[text.index("┏"):text.index("┡")]
    for column in table.columns:
        for line in str(column.header).split("\n"):
            assert re.search(rf"┃ +{re.escape(line)} +┃", header), (line, header)


@pytest.mark.parametrize("width", [80, 100])
def test_the_live_table_fits_80_and_100_columns_with_no_cell_or_header_cut(width):
    records = campaign_records()
    table = trials_table(records, width, "ilcpmac run  runs/seed-bench-20260101-120000")
    text = render(table, width=width)
    assert_nothing_cut(table, text, width)
    headers = [str(c.header) for c in table.columns]
    for needed in ("#", "phase", "torque\nN m", "meas pp\n%", "true pp\n%", "reduction\nmeas"):
        assert needed in headers
    assert len(headers) < ALL_COLUMNS
    assert re.search(r"│ +1-30 │ grid +│ +1-5 │", text)  # the grid in one row
    assert re.search(r"│ +34 │ compensate │ +1 │", text)
    assert re.search(r"│ +63 │ ilc +│ +5 │", text) and "747x" in text  # 3 significant digits, "x"


def test_a_wider_console_gets_more_columns_and_a_wide_one_all():
    records = campaign_records()
    counts = [len(trials_table(records, width).columns) for width in (80, 100, 120, 200)]
    assert counts == sorted(counts) and counts[0] < counts[1] and counts[-1] == ALL_COLUMNS
    text = render(trials_table(records, 200), width=200)
    assert "cogging" in text and "mN m" in text and "…" not in text


def test_the_live_table_before_any_trial_is_its_headers():
    text = render(trials_table([], 80), width=80)
    assert "meas pp" in text and "grid row" not in text and "…" not in text


figure = st.floats(1e-7, 50.0)
factor = st.none() | st.floats(0.01, 1e6)


@given(st.lists(st.tuples(st.sampled_from(["baseline", "compensate", "ilc"]), st.sampled_from([0.5, 1.0, 12.5]),
                          figure, figure, factor, factor), min_size=1, max_size=12),
       st.integers(1, 990), st.sampled_from([80, 100]))
@settings(max_examples=40, deadline=None)
def test_no_figure_of_any_size_is_cut_at_80_or_100_columns(rows, first, width):
    records = [TrialRecord(first + i, "ilc" if role == "ilc" else "identify", role, torque, 0.75,
                           ripple(pp, amp), ripple(pp / 3, amp / 3), f, f_true)
               for i, (role, torque, pp, amp, f, f_true) in enumerate(rows)]
    table = trials_table(records, width)
    assert_nothing_cut(table, render(table, width=width), width)


@pytest.mark.parametrize("width", [80, 100])
def test_the_summary_fits_with_its_title_on_a_line_of_its_own(width):
    table = summary_table(campaign_records(), SETPOINTS)
    text = render(SUMMARY_TITLE, table, width=width)
    assert_nothing_cut(table, text, width)
    lines = text.splitlines()
    assert lines[0].rstrip() == SUMMARY_TITLE and lines[1].startswith("┏")
    assert re.search(r"│ +1 │ +241 │ +0.0808 │ +239 │ +0.0800 │ +747x │ +2988x │ +10 │", text)


@pytest.mark.parametrize("value, text", [(2.3899, "2.39"), (238.92, "239"), (2934.6, "2935"), (0.08141, "0.0814"),
                                         (0.0, "0"), (-0.5, "-0.500"), (40.0, "40.0"), (1e-9, "0.0000")])
def test_figures_have_3_significant_digits_and_no_exponent(value, text):
    assert significant(value) == text


def test_the_final_figures_are_words_with_units():
    final = {"ripple_pp_true": 0.00081411, "ripple_pp_measured": 0.0039536, "ripple_rms_true": 0.000119,
             "ripple_rms_measured": 0.000679, "reduction_factor": 418.39, "reduction_factor_true": 2034.98}
    assert final_lines(final) == [
        "true ripple 0.0814 % of mean torque, 2035x below uncompensated",
        "measured ripple 0.395 % of mean torque, 418x below uncompensated"]
    measured_only = {k: v for k, v in final.items() if "true" not in k}
    assert final_lines(measured_only) == final_lines(final)[1:]
    assert final_lines({}) == []


def test_summary_json_units_cover_every_figure_of_a_trial_and_of_final():
    numbers = {k for k in campaign_records()[-1].to_json() if k not in ("index", "phase", "role")}
    assert set(SUMMARY_UNITS) == numbers
    assert SUMMARY_UNITS["ripple_pp_true"] == "fraction of mean torque"
    assert SUMMARY_UNITS["amp_1x_measured_nm"] == "N m" and SUMMARY_UNITS["speed_setpoint"] == "Hz"
    assert SUMMARY_UNITS["reduction_factor_true"].startswith("x ")


# ---------------------------------------------------------------- the status line and the plan's bound


def record(index: int, role: str, torque: float, pp: float = 0.01) -> TrialRecord:
    phase = {"grid": "identify", "baseline": "identify"}.get(role, role)
    return TrialRecord(index, phase, role, torque, 0.75, ripple(pp, 1e-3))


def test_the_plan_bounds_the_trials_left(plan):
    """SMALL_CAMPAIGN: a 2 x 2 grid, 2 ILC set points (2 and 4 N m) of at most 4 ILC trials."""
    assert plan.most_remaining([]) == 4 + 2 + 2 + 2 * 4
    records = [record(i + 1, "grid", 2.0) for i in range(4)]
    records += [record(5, "baseline", 2.0), record(6, "baseline", 4.0), record(7, "compensate", 2.0)]
    assert plan.most_remaining(records) == 1 + 2 * 4
    records += [record(8 + k, "ilc", 2.0, 0.01 * (k + 1)) for k in range(4)]  # set point 2 N m done
    assert plan.most_remaining(records) == 1 + 4
    assert plan.next_step(records).role == "compensate"


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_the_status_line_names_the_running_trial_and_bounds_the_time_left(plan):
    clock = Clock()
    view = CampaignView(Console(file=io.StringIO()), plan, "run", [], clock)
    clock.now += 0.5
    assert "trial 1/4 grid, 0.5 s | 0 done, 0.5 s | ≤ 16 to go" in view.status()
    assert view.time_left_s() is None
    records = []
    for k, (role, torque, seconds) in enumerate([("grid", 2.0, 1.0)] * 4 + [("baseline", 2.0, 3.0)]):
        clock.now += seconds
        records.append(record(k + 1, role, torque))
        view.trial(records[-1], records)
    assert view.time_left_s() == 11 * 3.0  # 1 baseline, 2 compensations, 2 x 4 ILC trials at 3 s each
    clock.now += 1.25
    status = view.status()
    assert "trial 6 baseline 4 N m 0.75 Hz, 1.2 s | 5 done, 8.8 s | ≤ 11 to go, ~33.0 s" in status
    assert status[0] in "⠋⠙⠹⠸⠼⠴⠦⠧⠇⠏"
    text = render(view, width=80)
    assert "1-4" in text and "trial 6 baseline" in text and "…" not in text
    view.end("done")
    assert view.status() == "done: 5 trials, 8.8 s"


def test_a_resumed_view_waits_for_its_first_trial(plan):
    clock = Clock()
    view = CampaignView(Console(file=io.StringIO()), plan, "run", None, clock)
    assert view.status().endswith("starting, 0.0 s") and view.time_left_s() is None
    view.end("stopped")
    assert view.status() == "stopped after 0.0 s"


@pytest.mark.parametrize("seconds, text", [(7.44, "7.4 s"), (185, "3m05s"), (7625, "2h07m")])
def test_durations_read_as_people_write_them(seconds, text):
    assert duration(seconds) == text


def test_files_written_leaves_the_lock_out(tmp_path):
    (tmp_path / "states").mkdir()
    (tmp_path / "states" / "a.json").write_bytes(b"x" * 1000)
    (tmp_path / "summary.json").write_bytes(b"y" * 500)
    (tmp_path / ".lock").write_bytes(b"")
    (tmp_path / ".lock.holder").write_bytes(b"pid")
    assert files_written(tmp_path) == (2, 1500)


@pytest.mark.slow
def test_ilcpmac_run_ends_with_what_it_wrote_and_the_next_command(write_config, tmp_path):
    out = tmp_path / "run"
    done = CliRunner().invoke(main, ["run", str(write_config(SMALL_CAMPAIGN)), "--out", str(out)])
    assert done.exit_code == 0, done.output
    text = done.output
    assert "…" not in text and "done: " in text
    count = sum(1 for p in out.rglob("*") if p.is_file() and not p.name.startswith(".lock"))
    assert re.search(rf"wrote {count} files, \d+\.\d MB, in {re.escape(str(out))}", text)
    assert f"next: ilcpmac report {out}" in text
    final = text[text.index(FINAL_TITLE):text.index("wrote ")]
    assert "ripple peak-to-peak" in final and "% of mean torque" in final and "x below uncompensated" in final
    assert not re.search(r"[a-z]+_[a-z]+", final)  # no snake_case keys for people
    summary = json.loads((out / "summary.json").read_text())
    assert summary["units"] == SUMMARY_UNITS
    assert set(summary["final"]) <= set(summary["units"])
