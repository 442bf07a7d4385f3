"""The campaign of ``ilcpmac run``: phases, ripple falling, persistence, resume, the guard.

These tests inject an identification built from the simulator's truth, so that
they test the campaign and not the estimators (those are tested against known
truth in tests/test_identify_*.py); tests/test_live_table.py and
tests/test_backends.py run the whole command with the real identification.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from campaign_helpers import SMALL_CAMPAIGN, Quiet, run_campaign, simulator_backend

from ilcpmac.backends.simulated import SimulatorBackend
from ilcpmac.bench.format import read_bench
from ilcpmac.campaign.events import CompensationWorse, GuardEvent
from ilcpmac.campaign.rundir import RunDir, RunDirError, trial_file
from ilcpmac.config import load_config
from ilcpmac.core.records import TrialData, TrialRequest

SUMMARY_KEYS = {"index", "phase", "torque_setpoint", "speed_setpoint", "ripple_pp_measured",
                "ripple_rms_measured", "ripple_pp_true", "ripple_rms_true"}


@pytest.fixture
def campaign_config(write_config):
    return load_config(write_config(SMALL_CAMPAIGN))


class Crash(RuntimeError):
    pass


class CrashingBackend:
    """Runs trials until the Nth call, then fails like a killed process would."""

    def __init__(self, backend: SimulatorBackend, fail_on_call: int) -> None:
        self.backend, self.fail_on_call, self.calls = backend, fail_on_call, 0
        self.max_parallel_trials = 1

    def describe(self):
        return self.backend.describe()

    def run_trial(self, request: TrialRequest) -> TrialData:
        self.calls += 1
        if self.calls == self.fail_on_call:
            raise Crash(f"killed during call {self.calls}")
        return self.backend.run_trial(request)


def test_campaign_phases_ripple_falls_and_run_dir_is_a_bench_folder(campaign_config, tmp_path):
    summary = run_campaign(campaign_config, tmp_path / "run")
    records = summary["trials"]
    roles = [r["role"] for r in records]
    assert roles[:4] == ["grid"] * 4
    assert roles[4:6] == ["baseline"] * 2 and roles[6:8] == ["compensate"] * 2
    assert set(roles[8:-2]) == {"learn"} and 2 <= roles.count("learn") <= 8
    assert roles[-2:] == ["baseline", "validate"]
    assert [r["phase"] for r in records[:6]] == ["identify"] * 6
    assert {r["phase"] for r in records[8:-2]} == {"learn"}  # one name, whatever stage learns
    assert [r["phase"] for r in records[-2:]] == ["validate"] * 2
    assert [(r["torque_setpoint"], r["speed_setpoint"]) for r in records[-2:]] == [(3.0, 0.9)] * 2
    for r in records:
        assert SUMMARY_KEYS <= set(r)
    final = summary["final"]
    assert final["reduction_factor_true"] > 20
    assert final["ripple_pp_true"] < 0.02
    bench = read_bench(tmp_path / "run")
    assert len(bench.trials) == len(records)
    assert [t.torque_setpoint_nm for t in bench.trials] == [r["torque_setpoint"] for r in records]
    states = sorted((tmp_path / "run" / "states").glob("trial_*.json"))
    assert len(states) == len(records)
    last = json.loads(states[-1].read_text())
    assert set(last["pipeline"]) == {"current-sensor", "cogging", "ilc", "mean-torque"}
    assert json.loads((tmp_path / "run" / "summary.json").read_text()) == summary
    (validated,) = summary["validation"]
    assert (validated["torque_setpoint"], validated["speed_setpoint"]) == (3.0, 0.9)
    assert validated["reduction_factor_true"] > 20 and not validated["worse_than_uncompensated"]
    assert summary["compensation"] == {"file": "compensation.json", "fade_full_hz": None, "fade_zero_hz": None}
    assert summary["complete"] is True
    # issue 34, item 17: resumed once ended, it says there is nothing to do and changes no file (it rewrote them)
    files = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in (tmp_path / "run").rglob("*") if p.is_file()
             and not p.name.startswith(".lock")}
    events = Quiet()
    assert run_campaign(campaign_config, tmp_path / "run", resume=True, events=events) == summary
    run = tmp_path / "run"
    assert [m.text for m in events.messages] == [f"resume: {len(records)} trials already complete in {run}",
                                                 f"the run in {run} had ended: nothing to do, no file changed"]
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in files} == files


# in the parallel grid; within the compensation round; at the start of and within a learning round, whose
# requests the resumed run must shape from the pipeline as it stood when the round began
@pytest.mark.parametrize("fail_on_call", [3, 8, 9, 10])
def test_resume_after_a_crash_ends_as_an_uninterruptedrun_campaign(campaign_config, tmp_path, fail_on_call):
    reference = run_campaign(campaign_config, tmp_path / "reference")
    crashed = tmp_path / "crashed"
    with pytest.raises(Crash):
        run_campaign(campaign_config, crashed, CrashingBackend(simulator_backend(campaign_config), fail_on_call))
    listed = read_bench(crashed).trials
    assert len(listed) == fail_on_call - 1  # every finished trial committed, nothing of the failed one
    assert sorted(p.name for p in crashed.glob("trial_*")) == [trial_file(i) for i in range(1, fail_on_call)]
    resumed = run_campaign(campaign_config, crashed, resume=True)
    assert resumed == reference
    assert_same_learning(crashed, tmp_path / "reference")


def test_a_campaign_with_the_mean_torque_stage_resumes_exactly(write_config, tmp_path):
    """The mean-torque stage's state (each set point's last speed) is saved with every trial: a crash within a
    learning round and a resume end as the uninterrupted run, the stage's constant feed-forward in the
    compensation's tables (their mean), and every point's stated mean torque its set point's."""
    config = load_config(write_config({**SMALL_CAMPAIGN, "pipeline": {
        "stages": ["current-sensor", "cogging", "ilc", "mean-torque"]}}))
    reference = run_campaign(config, tmp_path / "reference")
    crashed = tmp_path / "crashed"
    with pytest.raises(Crash):
        run_campaign(config, crashed, CrashingBackend(simulator_backend(config), 9))
    assert run_campaign(config, crashed, resume=True) == reference
    assert_same_learning(crashed, tmp_path / "reference")
    tables = np.array(json.loads((tmp_path / "reference" / "compensation.json").read_text())["tables_nm"])
    assert np.all(tables.mean(axis=-1) > 0)  # what the loop and the sensors lose of the mean, put back
    for p in reference["points"]:
        assert p["mean_torque_nm"] == pytest.approx(p["torque_setpoint"], rel=1e-6)


def assert_same_learning(run: Path, reference: Path) -> None:
    """What ``run`` learned, and what the report draws of it, is byte for byte ``reference``'s."""
    for name in ("compensation.json", "states/learned.json"):
        assert (run / name).read_bytes() == (reference / name).read_bytes(), name


def test_leftovers_of_an_uncommitted_trial_are_removed_on_resume(campaign_config, tmp_path):
    run_campaign(dataclasses.replace(campaign_config, campaign=dataclasses.replace(campaign_config.campaign,
                                                                           learn_trials=1)), tmp_path / "run")
    run = tmp_path / "run"
    n = len(read_bench(run).trials)
    (run / trial_file(n + 1)).write_bytes(b"PAR1")  # half a trial, never listed
    (run / "states" / f"trial_{n + 1:03d}.json.tmp").write_text("{")
    RunDir.resume(run, simulator_backend(campaign_config).describe())
    assert not (run / trial_file(n + 1)).exists()
    assert not (run / "states" / f"trial_{n + 1:03d}.json.tmp").exists()


def test_an_existing_run_directory_is_not_overwritten(campaign_config, tmp_path):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "keep.txt").write_text("data")
    with pytest.raises(RunDirError, match="exists and is not empty.*--resume"):
        run_campaign(campaign_config, tmp_path / "run")
    assert (tmp_path / "run" / "keep.txt").read_text() == "data"


class GrowingRipple:
    """Adds a ripple at harmonic 20 that grows with every ILC-phase trial (something the ILC
    cannot follow), so that the measured ripple grows twice in a row."""

    def __init__(self, backend: SimulatorBackend) -> None:
        self.backend, self.n = backend, 0
        self.max_parallel_trials = 1

    def describe(self):
        return self.backend.describe()

    def run_trial(self, request: TrialRequest) -> TrialData:
        trial = self.backend.run_trial(request)
        if np.any(request.excitation_nm) or not np.any(request.feedforward_nm):
            return trial
        self.n += 1
        theta = 2 * np.pi * trial.count / 1024
        extra = 0.05 * self.n**2 * np.cos(20 * theta + self.n)
        return dataclasses.replace(trial, torque_nm=trial.torque_nm + extra)


def test_guard_reverts_and_halves_the_gain_when_the_ripple_grows_twice(campaign_config, tmp_path):
    events = Quiet()
    cfg = dataclasses.replace(campaign_config, campaign=dataclasses.replace(
        campaign_config.campaign, learn_torques_nm=(2.0,), learn_trials=4, patience=4, validate_torques_nm=()))
    summary = run_campaign(cfg, tmp_path / "run", GrowingRipple(simulator_backend(cfg)), events=events)
    guard = [m for m in events.messages if isinstance(m, GuardEvent)]
    assert guard and guard[0].text.startswith("guard: ") and "halved the learning gain to 0.5" in guard[0].text
    states = [json.loads(p.read_text()) for p in sorted((tmp_path / "run" / "states").glob("trial_*.json"))]
    events_saved = [s["guard"] for s in states if s["guard"]]
    assert events_saved[0] == guard[0].to_json() and events_saved[0]["learning_gain"] == 0.5
    best = events_saved[0]["reverted_to_trial"]
    reverted = next(s for s in states if s["guard"])
    assert reverted["pipeline"] == states[best - 1]["pipeline"]
    assert summary["trials"][-1]["role"] == "learn"


def test_a_campaign_runs_through_an_installed_plugin_stage(write_config, tmp_path):
    """The example plugin (plugins/ilcpmac-harmonic-canceller, installed by the test command) is named
    in a config like a built-in and cancels the seed bench's disturbance at orders 20, 36 and 100."""
    changes = dict(SMALL_CAMPAIGN)
    changes["pipeline"] = {"stages": ["current-sensor", "cogging", "harmonic-canceller"]}
    changes["stages"] = {"harmonic-canceller": {"orders": [20, 36, 100]}}
    changes["campaign"] = dict(SMALL_CAMPAIGN["campaign"], learn_torques_nm=[3.0], learn_trials=3,
                               validate_torques_nm=[2.0])
    cfg = load_config(write_config(changes, drop=["stages.ilc"]))
    summary = run_campaign(cfg, tmp_path / "run")
    run = tmp_path / "run"
    states = [json.loads(p.read_text()) for p in sorted((run / "states").glob("trial_*.json"))]
    assert set(states[-1]["pipeline"]) == {"current-sensor", "cogging", "harmonic-canceller"}
    bench = read_bench(run)
    trials, counts = bench.trials, bench.motor.counts_per_rev
    roles = [r["role"] for r in summary["trials"]]
    before = trials[roles.index("compensate")]  # the canceller has learned nothing yet
    after = trials[len(roles) - 3]  # the last learning trial
    for order, amplitude in zip((20, 36, 100), (0.012, 0.01, 0.006)):
        assert _true_amplitude(before, order, counts) > 0.5 * amplitude
        assert _true_amplitude(after, order, counts) < 0.2 * _true_amplitude(before, order, counts)


def _true_amplitude(trial: TrialData, order: int, counts_per_rev: int) -> float:
    from ilcpmac.signals.harmonics import harmonic_amplitudes, synchronous_average

    return float(abs(harmonic_amplitudes(synchronous_average(trial.count, trial.torque_true_nm,
                                                             counts_per_rev))[order]))


def test_a_campaign_stops_with_a_clear_error_when_the_identification_lacks_an_estimate(campaign_config, tmp_path):
    from campaign_helpers import truth_json

    from ilcpmac.campaign.runner import CampaignRunner
    from ilcpmac.core.errors import IdentificationError
    from ilcpmac.core.records import IdentificationResult

    sim = simulator_backend(campaign_config)
    answer = truth_json(sim)
    answer.update(alpha=None, messages=["alpha: coherence too low"])

    class Lacking:
        def __call__(self, bench):
            return IdentificationResult.from_json(answer)

    run_dir = RunDir.create(tmp_path / "run", sim.describe(), campaign_config.path.read_text())
    with pytest.raises(IdentificationError, match="needs alpha.*coherence too low"):
        CampaignRunner(campaign_config, sim, run_dir, 7, Lacking(), Quiet()).run()
    assert len(read_bench(tmp_path / "run").trials) == 4  # the grid is kept for a later --resume


# ---------------------------------------------------------------- the limits (issue 8)


@pytest.mark.parametrize("changes, bench_current_a, message", [
    ({"limits": {"max_current_a": 0.001}}, 30.0,
     r"\[trials\] set point 2 N m at 0.6 Hz, revolutions 3, with its \[excitation\] multisine \(fraction 0.05 .*\): "
     r"current reference .* A in phase . at count \d+ exceeds 0.001 A \(\[limits\] max_current_a or the bench's\)"),
    ({}, 5.0, r"\[trials\] set point 2 N m at 0.6 Hz.*: current reference .* exceeds 5 A \(\[limits\] max_current_a "
              r"or the bench's\)"),
    ({"limits": {"max_torque_nm": 2.0}}, 30.0,
     r"\[trials\] set point 2 N m at 0.6 Hz.*: torque reference 2.\d+ N m at count \d+ .* exceeds 2 N m "
     r"\(\[limits\] max_torque_nm or the bench's\)"),
    ({"campaign": {"learn_speeds_hz": (3.0,)}}, 30.0,
     r"\[campaign\] learn_torques_nm 2 N m at learn_speeds_hz 3 Hz, learn_revolutions 6: speed set "
     r"point 3 Hz exceeds 1.5 Hz \(\[limits\] max_speed_hz or the bench's\)"),
    ({"grid": {"torque_setpoints_nm": (2.0,)}, "campaign": {"learn_torques_nm": (4.0,), "validate_torques_nm": ()},
      "limits": {"max_current_a": 14.0}}, 30.0,
     r"\[campaign\] learn_torques_nm 4 N m .*: with a calibration at the edge of the trust region "
     r"\(\[limits\] max_scale_deviation, max_offset_deviation_a\): flowing current .* exceeds 14 A"),
    ({"limits": {"max_trial_duration_s": 7.5}}, 30.0,
     r"\[campaign\] learn_torques_nm 2 N m .*: the trial lasts 7.778 s \(1 warm-up and 6 revolutions at "
     r"0.9 Hz\), beyond 7.5 s \(\[limits\] max_trial_duration_s\)"),
], ids=["config-current", "bench-current", "torque", "speed-3-hz", "trust-region", "duration"])
def test_a_plan_beyond_the_limits_fails_before_any_trial(campaign_config, tmp_path, changes, bench_current_a,
                                                          message):
    """Issue 8: the grid ran (up to 18 A) whatever [limits] said; now the whole plan is checked first.
    (The configs are changed in memory: the checks must hold whatever the config reader lets through.)"""
    from campaign_helpers import Recording, TruthIdentification

    from ilcpmac.backends.base import BenchLimits
    from ilcpmac.campaign.runner import CampaignRunner
    from ilcpmac.core.errors import ConfigError

    cfg = dataclasses.replace(campaign_config, **{table: dataclasses.replace(getattr(campaign_config, table), **values)
                                                  for table, values in changes.items()})
    sim = SimulatorBackend(cfg.model, BenchLimits(bench_current_a, 8.0, 1.5), cfg.grid.warmup_revolutions)
    recording = Recording(sim)
    run_dir = RunDir.create(tmp_path / "run", sim.describe(), cfg.path.read_text())
    with pytest.raises(ConfigError, match=message):
        CampaignRunner(cfg, recording, run_dir, 7, TruthIdentification(sim), Quiet()).run()
    run_dir.close()
    assert recording.requests == []


class TenfoldScale:
    """A stage that multiplies the calibration's current scales by 10 (issue 8: 92.9 A against 30 A)."""

    name = "tenfold"

    def __init__(self, setup) -> None:
        pass

    def columns(self, trial):
        return None

    def shape(self, request: TrialRequest) -> TrialRequest:
        cal = request.calibration
        return request.with_changes(calibration=dataclasses.replace(cal, current_scale=10 * cal.current_scale))

    def learn(self, trial, frame) -> None:
        pass

    def state(self) -> dict:
        return {}

    def restore(self, state: dict) -> None:
        pass


@pytest.mark.slow
def test_every_request_of_a_campaign_obeys_the_limits_whatever_a_stage_asks(write_config, tmp_path):
    from campaign_helpers import Recording

    from ilcpmac.model.tables import current_references

    changes = {**SMALL_CAMPAIGN, "pipeline": {"stages": ["current-sensor", "tenfold", "cogging", "ilc"]},
               "campaign": {**SMALL_CAMPAIGN["campaign"], "learn_trials": 1}, "limits": {"max_current_a": 20.0}}
    cfg = load_config(write_config(changes))
    sim = simulator_backend(cfg)
    recording, events = Recording(sim), Quiet()
    summary = run_campaign(cfg, tmp_path / "run", recording, events=events, extra_stages={"tenfold": TenfoldScale})
    clipped = [m.text for m in events.messages
               if m.text.startswith("limits: stage 'tenfold' set a calibration outside")]
    learning = sum(r["role"] in ("compensate", "learn") for r in summary["trials"])
    assert learning > 0 and len(clipped) == learning + 2  # and once per learned point for the compensation
    assert "current scale of phase a deviates +900 % from the identified sensors" in clipped[0]
    backemf = sim.describe().backemf_nm_per_a
    assert len(read_bench(tmp_path / "run").trials) == len(recording.requests)
    for request in recording.requests:
        truth = sim.simulator.truth(request.calibration)
        i_ref = current_references(request.torque_reference_nm(), backemf)
        assert np.abs(truth.epsilon * truth.alpha * i_ref + truth.beta_a).max() <= 20.0 * (1 + 1e-6)
    # the simulated true current within the limit plus the tolerance tests/test_limits_property.py justifies
    assert max(np.abs(t.i_true_a).max() for t in recording.trials) <= 20.25


def test_a_trials_saved_state_holds_the_calibration_it_ran_with(campaign_config, tmp_path):
    """The state recorded the unshaped request's calibration (the bench's) for every trial; it is the one
    the current-sensor stage set, which the stage's state after the last trial before the trial's round (the
    compensation trials, then one learning trial per point) announces."""
    summary = run_campaign(campaign_config, tmp_path / "run")
    states = [json.loads(p.read_text()) for p in sorted((tmp_path / "run" / "states").glob("trial_*.json"))]
    trials = summary["trials"]
    first = next(i for i, r in enumerate(trials) if r["role"] == "compensate")
    begun, seen = first - 1, set()
    for i in range(first, first + 4):
        point = (trials[i]["role"], trials[i]["torque_setpoint"])
        if point in seen or trials[i]["role"] != trials[i - 1]["role"]:
            begun, seen = i - 1, set()
        seen.add(point)
        ran = states[i]["request"]["calibration"]
        assert ran == {key: states[begun]["pipeline"]["current-sensor"][key] for key in ran}
        assert ran["current_scale"] != states[0]["request"]["calibration"]["current_scale"]
    assert begun == first + 1  # the first learning round began after the two compensation trials


def test_the_exported_compensation_replayed_gives_the_campaigns_validation_figures(campaign_config, tmp_path):
    """Issue 11: export the run's compensation, load it back in a pipeline whose only stage replays it, run the
    validation points on the simulator: the same trials (the same seeds) and the same figures as the campaign's."""
    from click.testing import CliRunner

    from ilcpmac.bench.format import as_recorded
    from ilcpmac.campaign.plan import CampaignPlan
    from ilcpmac.cli import main
    from ilcpmac.core.seeds import trial_seed
    from ilcpmac.pipeline.analysis import TrialAnalysis
    from ilcpmac.stages.base import Identified, StageSetup
    from ilcpmac.stages.registry import build_stages

    run = tmp_path / "run"
    summary = run_campaign(campaign_config, run)
    out = CliRunner().invoke(main, ["export", str(run), "--format", "json", "--out", str(tmp_path / "fw")])
    assert out.exit_code == 0, out.output
    sim = simulator_backend(campaign_config)
    description = sim.describe()
    identified = Identified.from_result(summary["identification"], description.calibration)
    (replay,) = build_stages(["replay"], {"replay": StageSetup(description, identified, 100,
                                                                {"file": str(tmp_path / "fw" / "compensation.json")})})
    plan = CampaignPlan.build(campaign_config, description, 7)
    motor = description.motor
    assert summary["validation"]
    for point in summary["validation"]:
        index = point["compensated_trial"]
        request = replay.shape(plan.base_request((point["torque_setpoint"], point["speed_setpoint"]),
                                                 trial_seed(7, index)))
        trial = as_recorded(dataclasses.replace(sim.run_trial(request), request=request), motor.counts_per_rev)
        np.testing.assert_array_equal(trial.torque_nm, read_bench(run).trials[index - 1].torque_nm)
        analysis = TrialAnalysis.of(trial, motor.counts_per_rev, campaign_config.campaign.ripple_harmonics)
        true = analysis.true.figures(analysis.true_mean_nm, motor.pole_pairs, motor.cogging_order)
        assert true.pp == point["ripple_pp_true"]


def test_resume_after_a_crash_in_the_parallel_validation_ends_as_an_uninterrupted_run(campaign_config, tmp_path):
    """The validation's trials run at once (neither learns); a crash among them loses none that finished
    before it, and the resumed run ends as the uninterrupted one."""
    reference = run_campaign(campaign_config, tmp_path / "reference")
    total = len(reference["trials"])
    assert [r["role"] for r in reference["trials"][-2:]] == ["baseline", "validate"]
    crashed = tmp_path / "crashed"
    with pytest.raises(Crash):
        run_campaign(campaign_config, crashed, CrashingBackend(simulator_backend(campaign_config), total))
    assert len(read_bench(crashed).trials) in (total - 2, total - 1)
    assert run_campaign(campaign_config, crashed, resume=True) == reference
    assert_same_learning(crashed, tmp_path / "reference")


class WorseWhenFast:
    """A bench on which the compensation goes wrong above 0.8 Hz: a compensated trial there gets a ripple at
    harmonic 20 larger than the uncompensated ripple (what the compensation cannot have learned)."""

    def __init__(self, backend: SimulatorBackend) -> None:
        self.backend = backend
        self.max_parallel_trials = 1

    def describe(self):
        return self.backend.describe()

    def run_trial(self, request: TrialRequest) -> TrialData:
        trial = self.backend.run_trial(request)
        if request.speed_setpoint_hz < 0.8 or not np.any(request.feedforward_nm) or np.any(request.excitation_nm):
            return trial
        theta = 2 * np.pi * trial.count / 1024
        return dataclasses.replace(trial, torque_nm=trial.torque_nm + 6.0 * np.cos(20 * theta))


def test_where_the_compensation_is_worse_than_none_it_fades_out_and_the_campaign_says_so(write_config, tmp_path):
    """Issue 11: learned at 0.6 Hz, validated at 0.6 and 0.9 Hz; at 0.9 Hz the compensated trial is worse than
    the uncompensated one, so compensation.json fades the feed-forward out from 0.6 Hz to 0.9 Hz."""
    from ilcpmac.compensation import Compensation

    cfg = load_config(write_config({**SMALL_CAMPAIGN, "campaign": {
        **SMALL_CAMPAIGN["campaign"], "learn_speeds_hz": [0.6], "learn_trials": 2, "validate_speeds_hz": [0.6, 0.9]}}))
    events = Quiet()
    summary = run_campaign(cfg, tmp_path / "run", WorseWhenFast(simulator_backend(cfg)), events=events)
    worse = {(v["torque_setpoint"], v["speed_setpoint"]): v["worse_than_uncompensated"] for v in summary["validation"]}
    assert worse == {(3.0, 0.6): False, (3.0, 0.9): True}
    assert summary["compensation"] == {"file": "compensation.json", "fade_full_hz": 0.6, "fade_zero_hz": 0.9}
    fade = Compensation.read(tmp_path / "run" / "compensation.json").fade
    assert (fade.factor(0.6), fade.factor(0.75), fade.factor(0.9)) == (1.0, 0.5, 0.0)
    (said,) = [m.text for m in events.messages if isinstance(m, CompensationWorse)]
    assert "WORSE than none at 3 N m at 0.9 Hz" in said and "fades it out from 0.6 Hz to 0.9 Hz" in said
