"""The campaign's parts on their own (issue 9): the plan, the one analysis per trial, the trial record,
the run directory's layout, the backend protocol of the guard and the layers' imports."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ilcpmac.backends.base import Backend
from ilcpmac.campaign.plan import records_at
from ilcpmac.campaign.record import TrialRecord, records_of
from ilcpmac.campaign.rundir import RunDirError, RunFiles
from ilcpmac.pipeline.analysis import TorqueSpectrum, TrialAnalysis
from ilcpmac.pipeline.pipeline import Pipeline
from ilcpmac.pipeline.safety import LimitGuard
from ilcpmac.records import BenchDescription, BenchLimits, SensorCalibration, TrialData, TrialRequest
from ilcpmac.signals.harmonics import RippleFigures
from ilcpmac.stages.base import Identified

CPR = 256


def figures(scale: float) -> RippleFigures:
    return RippleFigures(*(scale * (k + 1) for k in range(8)))


# ---------------------------------------------------------------- the trial record


finite = st.floats(-1e6, 1e6, allow_nan=False)


@given(st.integers(1, 999), st.sampled_from(["grid", "baseline", "compensate", "ilc"]), finite, finite,
       st.none() | finite.map(figures), st.none() | finite.map(figures), st.none() | finite, st.none() | finite)
@settings(max_examples=50, deadline=None)
def test_a_trial_record_round_trips_through_its_json(index, role, torque, speed, measured, true, factor, factor_true):
    record = TrialRecord(index, "identify", role, torque, speed, measured, true, factor, factor_true)
    data = record.to_json()
    assert TrialRecord.from_json(data) == record
    assert ("ripple_pp_measured" in data) == (measured is not None)
    assert ("reduction_factor_true" in data) == (factor_true is not None)


def test_a_trial_record_writes_the_summary_keys_of_docs_campaign():
    record = TrialRecord(3, "ilc", "ilc", 1.0, 0.75, figures(1.0), figures(2.0), 10.0, 20.0)
    assert record.to_json() == {
        "index": 3, "phase": "ilc", "role": "ilc", "torque_setpoint": 1.0, "speed_setpoint": 0.75,
        "ripple_pp_true": 2.0, "ripple_rms_true": 4.0, "rest_rms_true": 6.0, "ripple_rms_repeatable_true": 8.0,
        "amp_1x_true_nm": 10.0, "amp_2x_true_nm": 12.0, "amp_cogging_true_nm": 14.0, "amp_rest_true_nm": 16.0,
        "ripple_pp_measured": 1.0, "ripple_rms_measured": 2.0, "rest_rms_measured": 3.0,
        "ripple_rms_repeatable_measured": 4.0, "amp_1x_measured_nm": 5.0, "amp_2x_measured_nm": 6.0,
        "amp_cogging_measured_nm": 7.0, "amp_rest_measured_nm": 8.0, "reduction_factor": 10.0,
        "reduction_factor_true": 20.0}
    assert records_of({"trials": [record.to_json()]}) == [record]


# ---------------------------------------------------------------- the plan


def done(index: int, role: str, torque: float, repeatable: float = 0.01) -> TrialRecord:
    phase = {"grid": "identify", "baseline": "identify"}.get(role, role)
    return TrialRecord(index, phase, role, torque, 0.75, dataclasses.replace(figures(1.0), rms_repeatable=repeatable))


def test_the_plan_orders_grid_baselines_compensation_then_ilc_from_the_records_alone(plan):
    records: list[TrialRecord] = []
    roles = []
    while (step := plan.next_step(records)) is not None:
        roles.append((step.role, step.request.torque_setpoint_nm))
        assert step.request.seed != 0
        records.append(done(len(records) + 1, step.role, step.request.torque_setpoint_nm))
    assert roles[:4] == [("grid", r.torque_setpoint_nm) for r in plan.grid]
    assert roles[4:8] == [("baseline", 2.0), ("baseline", 4.0), ("compensate", 2.0), ("compensate", 4.0)]
    # a flat repeatable ripple stops improving: patience trials of ILC at each set point, in turn
    patience = plan.config.campaign.patience
    assert roles[8:] == [("ilc", 2.0)] * patience + [("ilc", 4.0)] * patience
    assert len(records_at(records, 2.0, ("compensate", "ilc"))) == patience + 1


def test_ilc_goes_on_while_the_ripple_improves_up_to_ilc_trials(plan):
    records = [done(i + 1, "grid", r.torque_setpoint_nm) for i, r in enumerate(plan.grid)]
    records += [done(5, "baseline", 2.0), done(6, "baseline", 4.0), done(7, "compensate", 2.0, 1.0),
                done(8, "compensate", 4.0, 1.0)]
    while (step := plan.next_step(records)) is not None and step.request.torque_setpoint_nm == 2.0:
        records.append(done(len(records) + 1, "ilc", 2.0, 0.5 ** len(records)))
    assert len(records_at(records, 2.0, ("ilc",))) == plan.config.campaign.ilc_trials


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


@pytest.mark.parametrize("module, absent", [
    ("ilcpmac.records", "ilcpmac.backends"),
    ("ilcpmac.stages.base", "ilcpmac.backends"),
    ("ilcpmac.sim.grid", "ilcpmac.backends"),
])
def test_lower_layers_do_not_import_upper_ones(module, absent):
    code = (f"import sys, {module}; bad = [m for m in sys.modules if m.startswith({absent!r})]; "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)


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
