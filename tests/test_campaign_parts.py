"""The campaign's parts on their own (issue 9): the plan, the one analysis per trial, the trial record,
the run directory's layout and the backend protocol of the guard (the layers' imports: .importlinter)."""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ilcpmac.backends.base import Backend
from ilcpmac.backends.guard import LimitGuard
from ilcpmac.campaign.events import CompensationBeatsNone
from ilcpmac.campaign.plan import CampaignPlan, records_at
from ilcpmac.campaign.record import MAX_REDUCTION_FACTOR, TrialRecord, records_of
from ilcpmac.campaign.rundir import RunDirError, RunFiles
from ilcpmac.campaign.validation import PointResult, fade_out, point_results, results_of
from ilcpmac.compensation import FadeOut
from ilcpmac.config import load_config
from ilcpmac.core.records import (
    MAX_SPEED_HZ,
    MAX_TORQUE_NM,
    BenchDescription,
    BenchLimits,
    SensorCalibration,
    TrialData,
    TrialRequest,
)
from ilcpmac.pipeline.analysis import TorqueSpectrum, TrialAnalysis
from ilcpmac.pipeline.pipeline import Pipeline
from ilcpmac.signals.harmonics import RippleFigures
from ilcpmac.stages.base import Identified

CPR = 256


def figures(scale: float) -> RippleFigures:
    return RippleFigures(*(scale * (k + 1) for k in range(8)))


# ---------------------------------------------------------------- the trial record


#: what a record may hold: set points within the bench's magnitudes, figures (the largest 8 x the scale) and factors
#: non-negative
torques, speeds = st.floats(-MAX_TORQUE_NM, MAX_TORQUE_NM), st.floats(-MAX_SPEED_HZ, MAX_SPEED_HZ)
scales, factors = st.floats(0.0, MAX_TORQUE_NM / 8), st.floats(0.0, MAX_REDUCTION_FACTOR)


@given(st.integers(1, 999), st.sampled_from(["grid", "baseline", "compensate", "learn", "validate"]), torques, speeds,
       st.none() | scales.map(figures), st.none() | scales.map(figures), st.none() | factors, st.none() | factors)
@settings(max_examples=50, deadline=None)
def test_a_trial_record_round_trips_through_its_json(index, role, torque, speed, measured, true, factor, factor_true):
    record = TrialRecord(index, "identify", role, torque, speed, measured, true, factor, factor_true)
    data = record.to_json()
    assert TrialRecord.from_json(data) == record
    assert ("ripple_pp_measured" in data) == (measured is not None)
    assert ("reduction_factor_true" in data) == (factor_true is not None)


def test_a_trial_record_writes_the_summary_keys_of_docs_campaign():
    record = TrialRecord(3, "learn", "learn", 1.0, 0.75, figures(1.0), figures(2.0), 10.0, 20.0)
    assert record.to_json() == {
        "index": 3, "phase": "learn", "role": "learn", "torque_setpoint": 1.0, "speed_setpoint": 0.75,
        "ripple_pp_true": 2.0, "ripple_rms_true": 4.0, "rest_rms_true": 6.0, "ripple_rms_repeatable_true": 8.0,
        "amp_1x_true_nm": 10.0, "amp_2x_true_nm": 12.0, "amp_cogging_true_nm": 14.0, "amp_rest_true_nm": 16.0,
        "ripple_pp_measured": 1.0, "ripple_rms_measured": 2.0, "rest_rms_measured": 3.0,
        "ripple_rms_repeatable_measured": 4.0, "amp_1x_measured_nm": 5.0, "amp_2x_measured_nm": 6.0,
        "amp_cogging_measured_nm": 7.0, "amp_rest_measured_nm": 8.0, "reduction_factor": 10.0,
        "reduction_factor_true": 20.0}
    assert TrialRecord.from_json(record.to_json()) == record


@pytest.mark.parametrize("key, value, message", [
    ("ripple_pp_true", 1e308, r"trials.2: ripple_pp_true is 1e\+308, not a number within \[0, 1e\+06\]"),
    ("amp_1x_measured_nm", -1.0, r"trials.2: amp_1x_measured_nm is -1.0, not a number within \[0, 100000\]"),
    ("speed_setpoint", True, r"trials.2: speed_setpoint is True, not a number"),
    ("reduction_factor", "10", r"trials.2: reduction_factor is '10', not a number"),
    ("index", 7, r"trials.2: index 7, not 3 \(the trials in the order they ran\)"),
    ("index", 2.5, r"trials.2: index is 2.5, not a trial's"),
])
def test_records_of_a_summary_refuse_what_no_run_writes(key, value, message):
    """Issue 34, item 12: a summary.json holding 1e308 crashed ``ilcpmac report`` in matplotlib."""
    trials = [TrialRecord(k, "learn", "learn", 1.0, 0.75, figures(1.0), figures(2.0), 10.0, 20.0).to_json()
              for k in (1, 2, 3)]
    assert [r.index for r in records_of({"trials": trials})] == [1, 2, 3]
    trials[2][key] = value
    with pytest.raises(ValueError, match=f"^{message}"):
        records_of({"trials": trials})


# ---------------------------------------------------------------- the plan


def done(index: int, role: str, torque: float, repeatable: float = 0.01, speed: float = 0.9) -> TrialRecord:
    phase = {"grid": "identify", "baseline": "identify", "learn": "learn"}.get(role, role)
    return TrialRecord(index, phase, role, torque, speed, dataclasses.replace(figures(1.0), rms_repeatable=repeatable))


@pytest.fixture
def stopping_plan(write_config):
    """The small campaign's plan with [campaign] patience 2: a point stops after 2 trials that do not improve."""
    from campaign_helpers import SMALL_CAMPAIGN, simulator_backend

    small = {**SMALL_CAMPAIGN, "campaign": {**SMALL_CAMPAIGN["campaign"], "patience": 2}}
    cfg = load_config(write_config(small))
    return CampaignPlan.build(cfg, simulator_backend(cfg).describe(), 7)


def test_the_plan_orders_grid_baselines_compensation_learning_then_validation_from_the_records_alone(
        stopping_plan):
    plan = stopping_plan
    records: list[TrialRecord] = []
    steps = []
    while (step := plan.next_step(records)) is not None:
        request = step.request
        steps.append((step.phase, step.role, request.torque_setpoint_nm))
        assert request.seed != 0
        assert step.role == "grid" or request.speed_setpoint_hz == 0.9
        records.append(done(len(records) + 1, step.role, request.torque_setpoint_nm, speed=request.speed_setpoint_hz))
    assert steps[:4] == [("identify", "grid", r.torque_setpoint_nm) for r in plan.grid]
    assert steps[4:8] == [("identify", "baseline", 2.0), ("identify", "baseline", 4.0),
                          ("compensate", "compensate", 2.0), ("compensate", "compensate", 4.0)]
    # a flat repeatable ripple stops improving: patience trials of learning at each point, in rounds
    patience = plan.config.campaign.patience
    assert steps[8:-2] == [("learn", "learn", 2.0), ("learn", "learn", 4.0)] * patience
    assert steps[-2:] == [("validate", "baseline", 3.0), ("validate", "validate", 3.0)]
    assert len(records_at(records, (2.0, 0.9), ("compensate", "learn"))) == patience + 1


def test_learning_goes_on_while_the_ripple_improves_up_to_learn_trials(plan):
    records = [done(i + 1, "grid", r.torque_setpoint_nm, speed=r.speed_setpoint_hz) for i, r in enumerate(plan.grid)]
    records += [done(5, "baseline", 2.0), done(6, "baseline", 4.0), done(7, "compensate", 2.0, 1.0),
                done(8, "compensate", 4.0, 1.0)]
    while (step := plan.next_step(records)) is not None and step.role == "learn":
        records.append(done(len(records) + 1, "learn", step.request.torque_setpoint_nm, 0.5 ** len(records)))
    for point in plan.learned:
        assert len(records_at(records, point, ("learn",))) == plan.config.campaign.learn_trials


def test_the_learning_phase_has_one_name_whatever_stage_learns(plan):
    """Issue 26, item 6: it was "ilc" in the records and the plot bands when the ilc stage ran, "learn" else."""
    records: list[TrialRecord] = []
    phases = set()
    while (step := plan.next_step(records)) is not None:
        phases.add(step.phase)
        request = step.request
        records.append(done(len(records) + 1, step.role, request.torque_setpoint_nm, speed=request.speed_setpoint_hz))
    assert "ilc" in plan.config.pipeline.stages and phases == {"identify", "compensate", "learn", "validate"}


def test_the_plan_ends_only_after_the_validation_and_bounds_every_trial_on_the_way(plan):
    """Every trial takes at least one off `most_remaining`, which counts the validation trials; the plan is over
    only when they have run, at the validation point, uncompensated then compensated."""
    c = plan.config.campaign
    assert plan.validated == [(3.0, 0.9)]
    assert plan.most_remaining([]) == len(plan.grid) + (2 + c.learn_trials) * len(plan.learned) + 2
    records: list[TrialRecord] = []
    while (step := plan.next_step(records)) is not None:
        left = plan.most_remaining(records)
        if step.phase == "validate":
            assert left == 2 - len(records_at(records, (3.0, 0.9), ("baseline", "validate")))
            assert (step.request.torque_setpoint_nm, step.request.speed_setpoint_hz) == (3.0, 0.9)
            assert step.request.revolutions == (plan.config.trial_revolutions((3.0, 0.9)) if step.role == "validate"
                                                else plan.config.campaign.baseline_revolutions)
            assert not step.request.feedforward_nm.any()
        records.append(done(len(records) + 1, step.role, step.request.torque_setpoint_nm,
                            speed=step.request.speed_setpoint_hz))
        assert 0 <= plan.most_remaining(records) <= left - 1
    assert [r.role for r in records[-2:]] == ["baseline", "validate"]
    assert plan.most_remaining(records) == 0
    assert plan.next_step(records[:-1]).role == "validate"


# ---------------------------------------------------------------- the validation


def point_trial(index: int, role: str, point: tuple[float, float], pp: float, true_pp: float | None = None,
                factor: float | None = None) -> TrialRecord:
    """A trial at ``point`` of measured peak-to-peak ripple ``pp`` (and true ``true_pp``)."""
    phase = {"baseline": "identify", "learn": "learn"}.get(role, role)
    true = None if true_pp is None else dataclasses.replace(figures(1.0), pp=true_pp)
    return TrialRecord(index, phase, role, *point, dataclasses.replace(figures(1.0), pp=pp), true, factor,
                       None if true_pp is None else factor)


def point_result(point: tuple[float, float], before_pp: float, after_pp: float, learned: bool = True) -> PointResult:
    return PointResult(point, learned, point_trial(1, "baseline", point, before_pp),
                       point_trial(2, "learn" if learned else "validate", point, after_pp))


def test_a_point_is_worse_when_its_measured_ripple_is_at_least_the_uncompensated_one():
    assert not point_result((1.0, 0.5), 1.0, 0.999).worse
    assert point_result((1.0, 0.5), 1.0, 1.0).worse
    assert point_result((1.0, 0.5), 1.0, 1.5, learned=False).worse


def test_the_conclusion_says_what_it_compared_and_its_least_reduction_with_the_point_of_it():
    """Issue 34, item 15: "the compensation beats none at every point" was said where the stage of
    docs/writing-a-stage.md had made its own harmonic 5x worse at every validation point: true of the measured
    peak-to-peak ripple (15x below, the other stages' work), which it did not say, nor of which trials."""
    results = [point_result((1.0, 0.5), 1.0, 0.05), point_result((1.0, 1.5), 1.0, 0.2),
               point_result((2.0, 0.75), 0.5, 0.1, learned=False), point_result((3.0, 0.5), 1.0, 0.0)]
    assert [r.reduction for r in results] == [20.0, 5.0, 5.0, math.inf]
    message = CompensationBeatsNone.of(results)
    assert (message.learned, message.validated, message.least_reduction, message.point) == (3, 1, 5.0, (1.0, 1.5))
    assert message.text == ("validate: the measured peak-to-peak ripple is below the uncompensated trial's at every "
                            "point, 5x at least (1 N m at 1.5 Hz; 3 learned points, their last trial, and 1 validated)")


def test_a_point_result_writes_the_validation_keys_of_summary_json():
    before = point_trial(7, "baseline", (2.0, 0.75), 0.02, 0.019)
    after = point_trial(8, "validate", (2.0, 0.75), 0.001, 0.0005, 20.0)
    assert PointResult((2.0, 0.75), False, before, after).to_json() == {
        "torque_setpoint": 2.0, "speed_setpoint": 0.75, "learned": False, "uncompensated_trial": 7,
        "compensated_trial": 8, "uncompensated_pp_measured": 0.02, "ripple_pp_measured": 0.001,
        "uncompensated_pp_true": 0.019, "ripple_pp_true": 0.0005, "reduction_factor": 20.0,
        "reduction_factor_true": 20.0, "worse_than_uncompensated": False}
    measured_only = PointResult((2.0, 0.75), True, point_trial(7, "baseline", (2.0, 0.75), 0.02),
                                point_trial(9, "learn", (2.0, 0.75), 0.03))
    assert measured_only.to_json() == {
        "torque_setpoint": 2.0, "speed_setpoint": 0.75, "learned": True, "uncompensated_trial": 7,
        "compensated_trial": 9, "uncompensated_pp_measured": 0.02, "ripple_pp_measured": 0.03,
        "worse_than_uncompensated": True}


def test_point_results_pair_each_points_baseline_with_its_last_trial_learned_points_first():
    learned = [(1.0, 0.5), (1.0, 1.5), (5.0, 0.5), (5.0, 1.5)]
    validated = [(3.0, 0.5), (3.0, 1.0)]
    records = [point_trial(1, "grid", (1.0, 0.5), 9.0)]
    for role, point, pp in [("baseline", (3.0, 0.5), 2.0), ("validate", (3.0, 0.5), 0.1),  # before any learned
                            ("baseline", (1.0, 0.5), 2.0), ("baseline", (1.0, 1.5), 3.0),
                            ("compensate", (1.0, 0.5), 0.5), ("compensate", (1.0, 1.5), 0.6),
                            ("learn", (1.0, 0.5), 0.2), ("learn", (1.0, 0.5), 0.1),
                            ("compensate", (5.0, 0.5), 0.4),  # no baseline: left out
                            ("baseline", (5.0, 1.5), 1.0),  # nothing after it: left out
                            ("baseline", (3.0, 1.0), 2.0)]:  # not validated yet: left out
        records.append(point_trial(len(records) + 1, role, point, pp))
    results = point_results(records, learned, validated)
    assert [(r.point, r.learned, r.before.index, r.after.index) for r in results] == [
        ((1.0, 0.5), True, 4, 9), ((1.0, 1.5), True, 5, 7), ((3.0, 0.5), False, 2, 3)]
    unidentified = [dataclasses.replace(r, measured=None) if r.index == 4 else r for r in records]
    assert [r.point for r in point_results(unidentified, learned, validated)] == [(1.0, 1.5), (3.0, 0.5)]
    assert point_results(records, [], []) == []


def test_point_results_read_back_from_summary_json_with_their_trials():
    records = [point_trial(1, "baseline", (1.0, 0.5), 2.0, 2.1), point_trial(2, "learn", (1.0, 0.5), 0.1, 0.09, 20.0),
               point_trial(3, "baseline", (2.0, 0.75), 1.0), point_trial(4, "validate", (2.0, 0.75), 0.2, None, 5.0)]
    results = point_results(records, [(1.0, 0.5)], [(2.0, 0.75)])
    summary = {"trials": [r.to_json() for r in records], "points": [r.to_json() for r in results]}
    assert results_of(summary) == results and results_of({}) == []
    summary["points"][1]["compensated_trial"] = 9
    with pytest.raises(ValueError, match="^compensated_trial 9 is not a trial of the summary$"):
        results_of(summary)


#: learned at 1 and 3 N m, validated at 2 N m between the learned speeds
LEARNED = [(t, s) for t in (1.0, 3.0) for s in (0.5, 1.0, 1.5)]
VALIDATED = [(2.0, 0.75), (2.0, 1.25)]


def results_worse_at(worse: set) -> list[PointResult]:
    return [point_result(p, 1.0, 2.0 if p in worse else 0.01, p in LEARNED) for p in LEARNED + VALIDATED]


@pytest.mark.parametrize("worse, fade", [
    (set(), FadeOut(math.inf, math.inf)),  # never fades
    ({(1.0, 1.5)}, FadeOut(1.25, 1.5)),  # the fastest speed, a learned point: from the next slower point speed
    ({(2.0, 1.25)}, FadeOut(1.0, 1.25)),  # a validation point
    ({(1.0, 1.0)}, FadeOut(0.75, 1.0)),  # a middle speed
    ({(3.0, 1.0), (2.0, 1.25), (1.0, 1.5)}, FadeOut(0.75, 1.0)),  # the slowest worse speed decides
    ({(3.0, 0.5)}, FadeOut(0.0, 0.0)),  # the slowest speed: it never applies
])
def test_the_fade_out_retires_the_compensation_from_the_slowest_speed_where_it_is_worse(worse, fade):
    assert fade_out(results_worse_at(worse)) == fade


@given(st.sets(st.sampled_from(LEARNED + VALIDATED)))
@settings(max_examples=50, deadline=None)
def test_the_fade_out_keeps_every_point_slower_than_a_worse_one_and_drops_every_worse_one(worse):
    fade = fade_out(results_worse_at(worse))
    slowest_worse = min((s for _, s in worse), default=math.inf)
    for torque, speed in LEARNED + VALIDATED:
        if (torque, speed) in worse:
            assert fade.factor(speed) == 0.0
        elif speed < slowest_worse:
            assert fade.factor(speed) == 1.0


# ---------------------------------------------------------------- the analysis


def uneven_trial(drift_nm_per_s: float) -> tuple[TrialData, np.ndarray]:
    """A trial of 6 revolutions whose speed varies (count not linear in time), with a ripple at harmonics
    3 and 8 and a torque drift linear in time; returns it and its ripple per count."""
    count = np.arange(6 * CPR, dtype=np.int64)
    theta = 2 * np.pi * count / CPR
    time_s = (count + 40.0 * np.sin(theta / 6)) / CPR  # one slow speed swing over the trial
    ripple = 0.02 * np.cos(3 * theta[:CPR]) + 0.01 * np.sin(8 * theta[:CPR] + 0.3)
    torque = 2.0 + ripple[count % CPR] + drift_nm_per_s * time_s
    return TrialData(2.0, 1.0, count, time_s, np.zeros((count.size, 3)), torque, torque_true_nm=torque), ripple


def test_the_analysis_removes_a_drift_linear_in_time_even_when_the_speed_varies():
    """A straight line against count (what the ripple figures fitted before) leaves 1.4 mN m of a
    0.3 N m drift in the ripple here, and 1.7e-3 of the mean torque in the rest; against time, 30x less."""
    trial, ripple = uneven_trial(0.05)
    spectrum = TorqueSpectrum.of(trial.count, trial.time_s, trial.torque_nm, CPR, 20)
    assert np.abs(spectrum.ripple_table() - ripple).max() < 1e-4
    f = spectrum.figures(2.0, 3, 8)
    assert f.amp_1x == pytest.approx(0.02, rel=1e-3) and f.amp_cogging == pytest.approx(0.01, rel=1e-3)
    assert f.pp == pytest.approx(np.ptp(ripple) / 2.0, rel=1e-3) and f.rest_rms < 1e-4


def test_the_joint_fit_and_the_ripple_figures_derive_from_one_analysis(small_model):
    from ilcpmac.backends.simulated import SimulatorBackend

    backend = SimulatorBackend(small_model, BenchLimits(30.0, 8.0, 1.5))
    description = backend.describe()
    cpr = description.motor.counts_per_rev
    ident = Identified(1.0, 1.0, np.ones(3), np.zeros(3), None, description.calibration)
    pipeline = Pipeline([], description, ident, None, 40)  # the frame needs no limits
    request = TrialRequest(2.0, 1.0, 3, np.zeros(cpr), np.zeros(cpr), description.calibration, seed=3)
    trial = dataclasses.replace(backend.run_trial(request), request=request)
    analysis = TrialAnalysis.of(trial, cpr, 40)
    frame = pipeline.frame(trial, spectrum=analysis.measured)
    np.testing.assert_array_equal(frame.torque_harmonics_nm, analysis.measured.harmonics_nm)
    np.testing.assert_allclose(pipeline.frame(trial).torque_harmonics_nm, analysis.measured.harmonics_nm)
    assert analysis.true is not None and analysis.true_mean_nm == pytest.approx(float(trial.torque_true_nm.mean()))


# ---------------------------------------------------------------- run directory, guard, layers


def test_the_run_files_own_the_layout(tmp_path):
    files = RunFiles(tmp_path)
    assert files.state(7) == tmp_path / "states" / "trial_007.json"
    assert files.existing_trial(2) == tmp_path / "trial_002.parquet"
    (tmp_path / "trial_002.csv").write_text("count\n")
    assert files.existing_trial(2) == tmp_path / "trial_002.csv"  # a run begun before Parquet
    with pytest.raises(RunDirError, match=r"no summary.json \(not a run directory of ilcpmac run\)"):
        files.read_summary()
    with pytest.raises(RunDirError, match=r"trial_003.json: missing \(trial 3 is not complete\)"):
        files.read_state(3)


class Closing:
    max_parallel_trials = 3

    def __init__(self) -> None:
        self.closed = False

    def describe(self):
        raise AssertionError("the guard answers describe itself")

    def run_trial(self, request):
        raise AssertionError("not called")

    def close(self) -> None:
        self.closed = True


def test_the_limit_guard_is_a_whole_backend():
    description = BenchDescription(None, np.zeros((CPR, 3)), SensorCalibration(np.ones(3), np.zeros(3), 1.0),
                                   BenchLimits(1.0, 1.0, 1.0))
    inner = Closing()
    guard = LimitGuard(inner, description, None)
    assert isinstance(guard, Backend)
    assert guard.max_parallel_trials == 3 and guard.describe() is description
    guard.close()
    assert inner.closed


def test_the_custom_stage_example_prints_typed_records(capsys):
    """examples/custom_stage.py's events read TrialRecord attributes (they indexed dicts once)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
    try:
        from custom_stage import Printer
    finally:
        sys.path.pop(0)
    figures = RippleFigures(*(0.001,) * len(dataclasses.fields(RippleFigures)))
    Printer().trial(TrialRecord(34, "ilc", "ilc", 3.0, 0.75, true=figures), [])
    assert capsys.readouterr().out == "trial 34 ilc        3 N m: true ripple   0.100 % pp\n"


def test_learning_runs_in_rounds_of_the_points_still_learning_as_next_step_gives_them(stopping_plan):
    """A round is the compensation trials, then one learning trial at every point still learning: the same
    requests and seeds as `next_step` one by one, and ``begun`` the records before the round, wherever in
    it the records stop (a resume). The point at 2 N m improves on and on; 4 N m stops after patience."""
    plan = stopping_plan
    c = plan.config.campaign

    def key(step):
        return step.role, step.request.seed, step.request.torque_setpoint_nm

    records = [done(i + 1, "grid", r.torque_setpoint_nm, speed=r.speed_setpoint_hz) for i, r in enumerate(plan.grid)]
    records += [done(5, "baseline", 2.0), done(6, "baseline", 4.0)]
    rounds = []
    while (step := plan.next_step(records)) is not None and step.role in ("compensate", "learn"):
        begun, steps = plan.learning_round(records)
        assert begun == len(records)
        rounds.append([s.request.torque_setpoint_nm for s in steps])
        for k, s in enumerate(steps):
            again, rest = plan.learning_round(records)
            assert again == begun
            assert [key(t) for t in rest] == [key(t) for t in steps[k:]]
            expected = plan.next_step(records)
            assert (expected.role, expected.request.seed, expected.request.torque_setpoint_nm) == \
                (s.role, s.request.seed, s.request.torque_setpoint_nm)
            repeatable = 0.5 ** len(records) if s.request.torque_setpoint_nm == 2.0 else 0.01
            records.append(done(len(records) + 1, s.role, s.request.torque_setpoint_nm, repeatable))
    assert rounds[0] == [2.0, 4.0]  # the compensation trials
    assert rounds[1:c.patience + 1] == [[2.0, 4.0]] * c.patience
    assert rounds[c.patience + 1:] == [[2.0]] * (c.learn_trials - c.patience)
    assert plan.learning_round(records) == (len(records), [])


def test_trials_that_neither_learn_nor_wait_for_learning_come_together_as_the_plan_gives_them(plan):
    """The grid alone (what follows waits for the identification), then the uncompensated trials at the
    learned points; the same requests and seeds as `next_step` one by one."""
    records: list[TrialRecord] = []
    batches = []
    while (step := plan.next_step(records)) is not None:
        batch = plan.independent_steps(records) if step.role in ("grid", "baseline", "validate") else [step]
        batches.append([s.role for s in batch])
        for s in batch:
            expected = plan.next_step(records)
            assert (expected.role, expected.request.seed, expected.request.torque_setpoint_nm) == \
                (s.role, s.request.seed, s.request.torque_setpoint_nm)
            records.append(done(len(records) + 1, s.role, s.request.torque_setpoint_nm,
                                speed=s.request.speed_setpoint_hz))
    assert batches[0] == ["grid"] * len(plan.grid)
    assert batches[1] == ["baseline"] * len(plan.learned)
    assert batches[-1] == ["baseline", "validate"] * len(plan.validated)


def test_the_plan_says_at_what_resolution_the_trials_record_and_what_that_holds_of_the_band():
    from ilcpmac.campaign.events import PlanStated

    plain = PlanStated({"identify": 15}, {"identify": 60.0})
    assert "recorded" not in plain.text
    text = PlanStated({"identify": 15}, {"identify": 60.0}, recorded=(4096, 2**20), harmonics=150).text
    assert "trials recorded at 4096 of the encoder's 1048576 counts per revolution (every 256th line)" in text
    assert f"harmonic 150 x {np.sinc(150 / 4096):.4f}" in text  # np.sinc(x) = sin(pi x) / (pi x)
