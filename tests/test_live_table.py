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

from ilcpmac.campaign.mean_torque import MEAN_TORQUE_UNITS
from ilcpmac.campaign.record import TrialRecord
from ilcpmac.campaign.runner import SUMMARY_UNITS
from ilcpmac.campaign.validation import point_results
from ilcpmac.cli import main
from ilcpmac.cli.run import CampaignView, duration, files_written
from ilcpmac.report.table import FINAL_TITLE, SUMMARY_TITLE, final_lines, significant, summary_table, trials_table
from ilcpmac.signals.harmonics import RippleFigures

#: the seed campaign's learned and validation points, (torque N m, speed Hz)
LEARNED = [(t, s) for t in (1.0, 3.0, 5.0) for s in (0.5, 1.0, 1.5)]
VALIDATED = [(t, s) for t in (2.0, 4.0) for s in (0.5, 1.0, 1.5)]
#: SMALL_CAMPAIGN's one learned speed
SMALL_SPEED_HZ = SMALL_CAMPAIGN["campaign"]["learn_speeds_hz"][0]
#: every column of the live table, as ``trials_table`` lays it out on a wide console
ALL_COLUMNS = 16


def ripple(pp: float, amp_nm: float) -> RippleFigures:
    return RippleFigures(pp, pp / 6, pp / 50, pp / 6.1, amp_nm, amp_nm / 5, amp_nm * 1.7, amp_nm / 4)


def campaign_records() -> list[TrialRecord]:
    """The records of a campaign of the seed bench's size and figures: a 5 x 6 grid, a baseline and a
    compensation per learned point, then 10 ILC trials each, down to about 3000x below uncompensated, then a
    baseline and a validation trial per validation point, about 1200x below uncompensated."""
    records: list[TrialRecord] = []

    def add(phase: str, role: str, torque: float, speed: float, pp: float, amp_nm: float,
            factor: float | None = None) -> None:
        records.append(TrialRecord(len(records) + 1, phase, role, torque, speed, ripple(1.01 * pp, amp_nm),
                                   ripple(pp, amp_nm), factor and factor / 4, factor))

    for torque in (1.0, 2.0, 3.0, 4.0, 5.0):
        for speed in (0.5, 1.0, 1.5, 2.0, 2.5, 3.0):
            add("identify", "grid", torque, speed, 2.55 / torque, 0.26)
    for torque, speed in LEARNED:
        add("identify", "baseline", torque, speed, 2.39 / torque, 0.24)
    for torque, speed in LEARNED:
        add("compensate", "compensate", torque, speed, 0.06 / torque, 3.5e-4, 40.0)
    for torque, speed in LEARNED:
        for k in range(10):
            pp = 8e-3 / torque / (k + 1)
            add("learn", "learn", torque, speed, pp, 2e-6, 2.39 / torque / pp)
    for torque, speed in VALIDATED:
        add("validate", "baseline", torque, speed, 2.39 / torque, 0.24)
        add("validate", "validate", torque, speed, 2e-3 / torque, 5e-6, 2.39 / 2e-3)
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
    for needed in ("#", "role", "torque\nN m", "meas pp\n%", "true pp\n%", "reduction\nmeas"):
        assert needed in headers
    assert len(headers) < ALL_COLUMNS
    assert re.search(r"│ +1-30 │ grid +│ +1-5 │", text)  # the grid in one row
    assert re.search(r"│ +40 │ compensate │ +1 │", text)
    assert re.search(r"│ +138 │ learn +│ +5 │", text) and "747x" in text  # 3 significant digits, "x"
    assert re.search(r"│ +149 │ baseline +│ +4 │", text) and re.search(r"│ +150 │ validate +│ +4 │", text)
    assert sum(line.startswith("│") for line in text.splitlines()) == 1 + len(records) - 30  # no cell wrapped


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


#: the phase of each role after the grid
PHASES = {"baseline": "identify", "compensate": "compensate", "learn": "ilc", "validate": "validate"}


@given(st.lists(st.tuples(st.sampled_from(sorted(PHASES)), st.sampled_from([0.5, 1.0, 12.5]),
                          st.sampled_from([0.05, 0.75, 125.0]), figure, figure, factor, factor), min_size=1,
                max_size=12),
       st.integers(1, 990), st.sampled_from([80, 100]))
@settings(max_examples=40, deadline=None)
def test_no_figure_of_any_size_is_cut_at_80_or_100_columns(rows, first, width):
    records = [TrialRecord(first + i, PHASES[role], role, torque, speed, ripple(pp, amp), ripple(pp / 3, amp / 3),
                           f, f_true)
               for i, (role, torque, speed, pp, amp, f, f_true) in enumerate(rows)]
    table = trials_table(records, width)
    assert_nothing_cut(table, render(table, width=width), width)


def body(text: str) -> list[list[str]]:
    """The cells of each row of a rendered table."""
    return [[cell.strip() for cell in line.strip().strip("│").split("│")] for line in text.splitlines()
            if line.startswith("│")]


@pytest.mark.parametrize("width", [80, 100])
def test_the_summary_fits_with_its_title_on_a_line_of_its_own(width):
    table = summary_table(campaign_records(), LEARNED, VALIDATED)
    text = render(SUMMARY_TITLE, table, width=width)
    assert_nothing_cut(table, text, width)
    lines = text.splitlines()
    assert lines[0].rstrip() == SUMMARY_TITLE and lines[1].startswith("┏")
    rows = body(text)
    assert [(float(row[0]), float(row[1]), row[2]) for row in rows] == \
        [(*p, "learned") for p in LEARNED] + [(*p, "valid.") for p in VALIDATED]  # one row per point, learned first
    assert rows[0] == ["1", "0.5", "learned", "0.0808", "0.0800", "747x", "2988x", "10"]
    assert rows[-1] == ["4", "1.5", "valid.", "0.0505", "0.0500", "299x", "1195x", "-"]


def test_the_summary_gives_each_point_s_mean_torque_error_where_the_run_stated_one():
    from ilcpmac.campaign.mean_torque import PointMeanTorque
    from ilcpmac.stages.mean_torque import MeanTorque

    means = {p: PointMeanTorque(p, True, MeanTorque(p[0] * (1 - 0.0412), 0.001, -0.03, 0.0)) for p in LEARNED}
    table = summary_table(campaign_records(), LEARNED, VALIDATED, width=120, means=means)
    text = render(SUMMARY_TITLE, table, width=120)
    assert_nothing_cut(table, text, 120)
    rows = body(text)
    assert rows[0][-1] == "-4.12" and rows[-1][-1] == "-"  # a validation point without one
    assert "err %" in text and "err %" not in render(SUMMARY_TITLE, summary_table(
        campaign_records(), LEARNED, VALIDATED, width=120), width=120)


#: set points as a config gives them, and the odd ones (shown to 4 significant digits: at most 6 characters)
setpoint = st.sampled_from([0.05, 0.75, 12.5, 125.0, 0.0625, 1 / 3, 2 / 3, 1234.5678])


@given(st.lists(st.tuples(setpoint, setpoint, figure, figure, figure, factor, factor), min_size=2, max_size=8,
                unique_by=lambda row: row[:2]),
       st.sampled_from([80, 100]))
@settings(max_examples=40, deadline=None)
def test_no_summary_figure_of_any_size_is_cut_at_80_or_100_columns(rows, width):
    """Per point a baseline and its last trial, learned and validation points alternating."""
    records = []
    for k, (torque, speed, before, after, after_true, f, f_true) in enumerate(rows):
        phase, role = ("learn", "learn") if k % 2 else ("validate", "validate")
        records.append(TrialRecord(len(records) + 1, "identify", "baseline", torque, speed, ripple(before, 1.0)))
        records.append(TrialRecord(len(records) + 1, phase, role, torque, speed, ripple(after, 1.0),
                                   ripple(after_true, 1.0), f, f_true))
    points = [row[:2] for row in rows]
    table = summary_table(records, points[1::2], points[::2])
    text = render(SUMMARY_TITLE, table, width=width)
    assert_nothing_cut(table, text, width)
    assert len(body(text)) == len(points)


@pytest.mark.parametrize("value, text", [(2.3899, "2.39"), (238.92, "239"), (2934.6, "2935"), (0.08141, "0.0814"),
                                         (0.0, "0"), (-0.5, "-0.500"), (40.0, "40.0"), (1e-9, "0.0000")])
def test_figures_have_3_significant_digits_and_no_exponent(value, text):
    assert significant(value) == text


def validation_json(records: list[TrialRecord]) -> list[dict]:
    """summary.json's "validation" of ``records``."""
    return [r.to_json() for r in point_results(records, LEARNED, VALIDATED) if not r.learned]


def summary_of(records: list[TrialRecord], learned: list, validated: list) -> dict:
    """summary.json's "trials", "points" and "final" as `CampaignRunner.summary` writes them (no floors)."""
    results = point_results(records, learned, validated)
    last = [r.after for r in results if r.learned]
    final = {f"ripple_pp_{kind}": max(r.figures(kind).pp for r in last) for kind in ("true", "measured")
             if all(r.figures(kind) is not None for r in last)}
    final |= {f: min(getattr(r, f) for r in last) for f in ("reduction_factor", "reduction_factor_true")
              if all(getattr(r, f) is not None for r in last)}
    return {"trials": [r.to_json() for r in records], "final": final,
            "validation": [r.to_json() for r in results if not r.learned], "points": [r.to_json() for r in results]}


def two_point_records(true: bool = True) -> list[TrialRecord]:
    """Per set of points, one with the worst ripple and one with the least reduction: 1 N m at 0.5 Hz, 0.100 %
    after 2.00 % (20x), and 5 N m at 1.5 Hz, 0.0800 % after 0.400 % (5x), learned; the same halved, validated."""
    records: list[TrialRecord] = []
    for point, before, after, phase in (((1.0, 0.5), 0.02, 0.001, "learn"), ((5.0, 1.5), 0.004, 0.0008, "learn"),
                                        ((2.0, 0.5), 0.01, 0.0005, "validate"),
                                        ((4.0, 1.5), 0.002, 0.0004, "validate")):
        factor = before / after
        records += [TrialRecord(len(records) + 1, "identify" if phase == "learn" else phase, "baseline", *point,
                                ripple(before, 1e-3), ripple(before, 1e-3) if true else None),
                    TrialRecord(len(records) + 2, phase, phase, *point, ripple(after, 1e-3),
                                ripple(after, 1e-3) if true else None, factor, factor if true else None)]
    return records


def test_each_final_line_gives_the_figures_of_one_point():
    """Issue 34, item 17: "worst ripple 0.100 %, 5.00x below uncompensated" gave one point's ripple and another's
    reduction (summary.json's "final": the largest ripple and the smallest factor)."""
    records = two_point_records()
    lines = [
        "learned: true ripple 0.100 % of mean torque at worst (1 N m, 0.5 Hz), 20.0x below uncompensated",
        "learned: true ripple 5.00x below uncompensated at least (5 N m, 1.5 Hz), 0.0800 % of mean torque",
        "learned: measured ripple 0.100 % of mean torque at worst (1 N m, 0.5 Hz), 20.0x below uncompensated",
        "learned: measured ripple 5.00x below uncompensated at least (5 N m, 1.5 Hz), 0.0800 % of mean torque",
        "validation: true ripple 0.0500 % of mean torque at worst (2 N m, 0.5 Hz), 20.0x below uncompensated",
        "validation: true ripple 5.00x below uncompensated at least (4 N m, 1.5 Hz), 0.0400 % of mean torque",
        "validation: measured ripple 0.0500 % of mean torque at worst (2 N m, 0.5 Hz), 20.0x below uncompensated",
        "validation: measured ripple 5.00x below uncompensated at least (4 N m, 1.5 Hz), 0.0400 % of mean torque"]
    learned, validated = [(1.0, 0.5), (5.0, 1.5)], [(2.0, 0.5), (4.0, 1.5)]
    assert final_lines(summary_of(records, learned, validated)) == lines
    assert final_lines(summary_of(two_point_records(true=False), learned, validated)) == \
        [line for line in lines if "measured" in line]
    assert final_lines(summary_of(records, learned, [])) == lines[:4]
    assert final_lines(summary_of(records[:2], learned[:1], [])) == [lines[0], lines[2]]  # one point: one line
    assert final_lines({"points": []}) == final_lines({}) == []


def test_the_final_lines_of_a_campaign_give_its_worst_point_against_the_floors():
    records = campaign_records()
    summary = summary_of(records, LEARNED, VALIDATED)
    summary["points"] = [{**p, "floor_pp_measured": p["ripple_pp_measured"] / 2, "floor_pp_true": p["ripple_pp_true"]}
                         for p in summary["points"]]
    worst_learned, worst_validated = final_lines(summary)[0], [line for line in final_lines(summary)
                                                               if line.startswith("validation: true")][0]
    assert worst_learned == ("learned: true ripple 0.0800 % of mean torque at worst (1 N m, 0.5 Hz), 2988x below "
                             "uncompensated; each point 1.00-1.00x its floor")
    assert worst_validated == ("validation: true ripple 0.100 % of mean torque at worst (2 N m, 0.5 Hz), 1195x below "
                               "uncompensated; each point 1.00-1.00x its floor")


def test_summary_json_units_cover_every_number_of_a_trial_a_validation_point_and_the_compensation():
    records = campaign_records()
    numbers = {k for k in records[-1].to_json() if k not in ("index", "phase", "role")}
    points = {k for k in validation_json(records)[0]
              if k not in ("learned", "uncompensated_trial", "compensated_trial", "worse_than_uncompensated")}
    later = {"motor_time_s", "floor_pp_measured", "floor_pp_true", "mean_torque_error", *MEAN_TORQUE_UNITS}
    assert set(SUMMARY_UNITS) == numbers | points | later | {"fade_full_hz", "fade_zero_hz"}
    assert SUMMARY_UNITS["ripple_pp_true"] == "fraction of mean torque"
    assert SUMMARY_UNITS["uncompensated_pp_measured"] == "fraction of mean torque"
    assert SUMMARY_UNITS["amp_1x_measured_nm"] == "N m" and SUMMARY_UNITS["speed_setpoint"] == "Hz"
    assert SUMMARY_UNITS["reduction_factor_true"].startswith("x ")
    assert SUMMARY_UNITS["fade_full_hz"].startswith("Hz ") and SUMMARY_UNITS["fade_zero_hz"].startswith("Hz ")


# ---------------------------------------------------------------- the status line and the plan's bound


def record(index: int, role: str, torque: float, pp: float = 0.01) -> TrialRecord:
    """A trial of SMALL_CAMPAIGN after the grid, at its one learned speed."""
    phase = {"grid": "identify", "baseline": "identify", "learn": "learn"}.get(role, role)
    return TrialRecord(index, phase, role, torque, SMALL_SPEED_HZ, ripple(pp, 1e-3))


def test_the_plan_bounds_the_trials_left(plan):
    """SMALL_CAMPAIGN: a 2 x 2 grid, 2 learned points (2 and 4 N m) of at most 4 learning trials, 1 validation
    point (3 N m): an uncompensated and a validation trial."""
    assert plan.most_remaining([]) == 4 + 2 + 2 + 2 * 4 + 2
    records = [record(i + 1, "grid", 2.0) for i in range(4)]
    records += [record(5, "baseline", 2.0), record(6, "baseline", 4.0), record(7, "compensate", 2.0)]
    assert plan.most_remaining(records) == 1 + 2 * 4 + 2
    records += [record(8 + k, "learn", 2.0, 0.01 * (k + 1)) for k in range(4)]  # point (2 N m, 0.9 Hz) done
    assert plan.most_remaining(records) == 1 + 4 + 2
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
    assert "trial 1/4 grid, 0.5 s | 0 done, 0.5 s | ≤ 18 to go" in view.status()
    assert view.time_left_s() is None
    records = []
    for k, (role, torque, seconds) in enumerate([("grid", 2.0, 1.0)] * 4 + [("baseline", 2.0, 3.0)]):
        clock.now += seconds
        records.append(record(k + 1, role, torque))
        view.trial(records[-1], records)
    # 1 baseline, 2 compensations, 2 x 4 learning trials, 2 validation trials at 3 s each
    assert view.time_left_s() == 13 * 3.0
    clock.now += 1.25
    status = view.status()
    motor = duration(sum(plan.bench_time_left(records).values()))
    assert f"trial 6 baseline 4 N m 0.9 Hz, 1.2 s | 5 done, 8.8 s | ≤ 13 to go, motor {motor} (wall ~39.0 s)" \
        in view.status(200)
    assert status.endswith(f"≤ 13 to go, motor {motor} (wall ~39.0 s)")  # at 80 columns, without the trials done
    assert status[0] in "⠋⠙⠹⠸⠼⠴⠦⠧⠇⠏"
    text = render(view, width=80)
    assert "1-4" in text and "trial 6 baseline" in text and "…" not in text
    view.end("done")
    assert view.status() == "done: 5 trials, 8.8 s"


def run_grid(view: CampaignView, plan, clock: Clock, seconds: float) -> list[TrialRecord]:
    """Finish the plan's grid in ``view``, ``seconds`` per trial; the records."""
    records: list[TrialRecord] = []
    while (step := plan.next_step(records)).role == "grid":
        clock.now += seconds
        records.append(record(len(records) + 1, "grid", step.request.torque_setpoint_nm))
        view.trial(records[-1], records)
    return records


def test_the_status_line_shows_the_running_trials_progress_and_the_eta_follows_it(plan):
    clock = Clock()
    view = CampaignView(Console(file=io.StringIO()), plan, "run", [], clock)
    records = run_grid(view, plan, clock, 1.0)
    step = plan.next_step(records)
    left = plan.most_remaining(records)
    assert view.time_left_s() is None  # no trial after the grid has finished yet
    clock.now += 10.0
    view.progress(0.0)  # warming up: nothing recorded yet
    assert view.time_left_s() is None
    r = step.request
    assert f"trial {len(records) + 1} {step.role} {r.torque_setpoint_nm:g} N m {r.speed_setpoint_hz:g} Hz 0 %, 10.0 s" \
        in view.status(200)
    view.progress(0.25)  # 10 s for a quarter: 40 s a trial, 30 s left of this one
    assert view.time_left_s() == pytest.approx((left - 1) * 40.0 + 30.0)
    assert f"Hz 25 %, 10.0 s | {len(records)} done" in view.status(200)
    assert view.status().endswith(f"(wall ~{duration((left - 1) * 40.0 + 30.0)})")
    motor = sum(plan.bench_time_left(records).values()) - 0.25 * plan.bench_seconds(step.request)
    assert f"to go, motor {duration(motor)} (wall" in view.status()  # the quarter done counted off
    for ignored in (float("nan"), -0.1, 1.5):
        view.progress(ignored)
    view.progress(0.999)
    assert "Hz 99 %, 10.0 s" in view.status(200)  # never 100 % before the trial is complete
    clock.now += 30.0
    records.append(record(len(records) + 1, step.role, r.torque_setpoint_nm))
    view.trial(records[-1], records)
    assert view.fraction is None and " %" not in view.status()
    assert view.time_left_s() == pytest.approx(plan.most_remaining(records) * 40.0)


def test_the_status_line_leaves_out_the_speed_then_the_trials_done_when_narrow(plan):
    clock = Clock()
    view = CampaignView(Console(file=io.StringIO()), plan, "run", [], clock)
    records = run_grid(view, plan, clock, 1.0)
    clock.now += 7300.0
    view.progress(0.5)
    full = view.status(200)
    speed = f" {plan.next_step(records).request.speed_setpoint_hz:g} Hz"
    assert speed + " 50 %, 2h01m | " in full and view.status(len(full)) == full
    assert view.status(len(full) - 1) == full.replace(speed, "")
    short = view.status(len(full) - len(speed) - 1)
    assert " done" not in short and short.startswith(full[:2] + "trial ") and " 50 %, 2h01m | ≤ " in short


@pytest.mark.parametrize("width", [80, 100])
def test_a_trial_in_progress_fits_80_and_100_columns_on_one_line(plan, width):
    clock = Clock()
    view = CampaignView(Console(file=io.StringIO()), plan, "ilcpmac run  runs/seed-bench-20260101-120000", [],
                        clock)
    records = run_grid(view, plan, clock, 100.0)
    clock.now += 3725.0
    view.progress(0.37)
    text = render(view, width=width)
    assert "…" not in text and max(map(len, text.splitlines())) <= width
    status = text.rstrip("\n").splitlines()[-1]
    assert " 37 %, 1h02m | " in status and re.search(r"≤ \d+ to go, motor \S+ \(wall ~\d+h\d\dm\)$", status.rstrip())
    assert status.startswith(view.status(width)[:2] + f"trial {len(records) + 1} ")


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
    assert "\n  learned: true ripple " in final and "\n  validation: measured ripple " in final
    assert not re.search(r"[a-z]+_[a-z]+", final)  # no snake_case keys for people
    summary = json.loads((out / "summary.json").read_text())
    assert summary["units"] == SUMMARY_UNITS
    assert set(summary["final"]) <= set(summary["units"])
    (point,) = summary["validation"]
    assert (point["torque_setpoint"], point["speed_setpoint"], point["learned"]) == (3.0, SMALL_SPEED_HZ, False)
    assert {k for k, v in point.items() if isinstance(v, float)} <= set(summary["units"])
    assert set(summary["compensation"]) - {"file"} <= set(summary["units"])


def test_the_live_display_never_grows_taller_than_the_terminal(plan):
    """At 80 x 24 a run of 80 trials: the display keeps the grid row and the latest trials that fit with the status
    line, and says how many it left out (before: every trial, the header repeated in the scrollback at each
    refresh, 1784 lines for a default run); on a file or pipe every trial is shown."""
    records = [record(k + 1, "grid" if k < 4 else "learn", 2.0 if k % 2 else 4.0) for k in range(80)]
    for terminal, height in ((True, 24), (False, 24), (True, 200)):
        console = Console(file=io.StringIO(), width=80, height=height, force_terminal=terminal, color_system=None,
                          record=True)
        view = CampaignView(console, plan, "ilcpmac run  runs/seed-bench", records, Clock())
        console.print(view)
        lines = console.export_text().rstrip("\n").splitlines()
        shown = [line for line in lines if re.match(r"^│ +\d+ ", line)]
        if terminal and height == 24:
            assert len(lines) <= 24
            assert any("left out to fit the terminal" in line for line in lines)
            assert shown[-1].split()[1] == "80"  # the latest trial is shown
        else:
            assert len(shown) == 76 and not any("left out" in line for line in lines)


def test_a_message_on_a_file_or_pipe_is_one_line_however_long(plan):
    console = Console(file=io.StringIO(), width=80, force_terminal=False)
    view = CampaignView(console, plan, "run", [], Clock())

    class Long:
        text = "guard: the ripple at 2 N m, 0.9 Hz grew twice in a row: reverted to the correction of trial 67, " \
               "learning gain halved to 0.5"

    view.message(Long())  # type: ignore[arg-type]
    assert console.file.getvalue() == Long.text + "\n"


def test_ctrl_c_in_a_run_names_the_folder_to_resume(tmp_path, write_config, monkeypatch):
    """Before: "a run directory can be continued with ilcpmac run --resume", which folder unsaid."""
    from ilcpmac.campaign.runner import CampaignRunner

    def interrupted(self):
        raise KeyboardInterrupt

    monkeypatch.setattr(CampaignRunner, "run", interrupted)
    out = tmp_path / "my run"
    done = CliRunner().invoke(main, ["run", str(write_config(SMALL_CAMPAIGN)), "--out", str(out)])
    assert done.exit_code == 130
    assert done.output.strip().splitlines()[-1] == f"error: interrupted; continue with ilcpmac run --resume '{out}'"


def test_the_torque_source_chosen_names_the_table_s_figures_from_then_on(plan):
    """With "auto" the campaign starts identified with "both" and chooses after the grid: the live table's
    figures are named by the choice (`TorqueSourceChosen`), not by the start's source."""
    from ilcpmac.campaign.events import TorqueSourceChosen
    from ilcpmac.core.torque_source import ChoiceReason, TorqueSource, TorqueSourceChoice

    out = io.StringIO()
    view = CampaignView(Console(file=out), plan, "run", [], Clock(), source="both")
    choice = TorqueSourceChoice(TorqueSource.SENSOR, True, ChoiceReason.CORRECTED, 0.001, 0.002, 0.0015, 0.05,
                                0.01, 0.03)
    view.message(TorqueSourceChosen(choice))
    assert view.source == "sensor" and "torque from the sensor (auto): the encoder needs a graduation correction" \
        in " ".join(out.getvalue().split())
