"""All four quadrants (issue 38, item 4): the mirror's requests and the guard's check of them, the simulator's
reverse trials, the compensation of both directions, the configs that cannot run, and a small campaign in both
directions against the truth."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from campaign_helpers import SMALL_CAMPAIGN
from click.testing import CliRunner
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from ilcpmac.backends.base import BenchLimits
from ilcpmac.backends.simulated import SimulatorBackend
from ilcpmac.campaign.floors import _axis_weights
from ilcpmac.campaign.quadrants import (
    MirroredBackend,
    MirroredIdentification,
    at_calibration,
    both_directions,
    mirrored_description,
    run_quadrants,
)
from ilcpmac.cli import main
from ilcpmac.compensation import Compensation, FadeOut, read_position_table
from ilcpmac.config import FORWARD, REVERSE, load_config
from ilcpmac.core.errors import BenchFormatError, ConfigError, IlcpmacError
from ilcpmac.core.records import (
    MIRROR_COORDINATES,
    IdentificationResult,
    SensorCalibration,
    TrialRequest,
    mirrored_request,
    mirrored_table,
)
from ilcpmac.pipeline.safety import SafetyLimits, identified_truth, limit_violation
from ilcpmac.sim.bench import truth_dict
from ilcpmac.stages.base import Identified

CPR = 256
LIMITS = SafetyLimits(max_correction_nm=1.0, max_current_a=12.0, max_torque_nm=6.0, max_speed_hz=1.5,
                      max_scale_deviation=0.1, max_offset_deviation_a=0.5, max_torque_gain_deviation=0.1,
                      max_samples_per_trial=4 * CPR, max_trial_duration_s=8.0, warmup_revolutions=1,
                      from_config=True)
PROPERTY = settings(derandomize=True, deadline=None, database=None, max_examples=150,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
#: SMALL_CAMPAIGN in both directions on the load machine: -3 and 3 N m learned at -0.9 and 0.9 Hz, -2 and 2 N m
#: validated there
BOTH = {**SMALL_CAMPAIGN, "simulator.mechanics": {"load": "machine"},
        "campaign": {**SMALL_CAMPAIGN["campaign"], "learn_torques_nm": [-3.0, 3.0], "learn_speeds_hz": [-0.9, 0.9],
                     "validate_torques_nm": [-2.0, 2.0], "validate_speeds_hz": [-0.9, 0.9]}}


@pytest.fixture(scope="module")
def drive(small_model):
    """The seed drive at 256 counts, its simulator backend and its true sensors as identified."""
    model = dataclasses.replace(small_model, encoder=dataclasses.replace(small_model.encoder, counts_per_rev=CPR))
    backend = SimulatorBackend(model, BenchLimits(LIMITS.max_current_a, LIMITS.max_torque_nm, LIMITS.max_speed_hz))
    description = backend.describe()
    identified = Identified.from_result(truth_dict(backend.simulator, description.calibration),
                                        description.calibration)
    return backend, description, identified


def test_the_mirror_request_negates_the_set_points_and_mirrors_the_reference_and_is_its_own_inverse():
    rng = np.random.default_rng(1)
    cal = SensorCalibration([14.0, 14.0, 14.0], [0.0, 0.0, 0.0], 0.9)
    request = TrialRequest(2.5, 0.75, 3, rng.normal(0, 0.1, 64), rng.normal(0, 0.1, 64), cal, 7)
    mirror = mirrored_request(request)
    assert (mirror.torque_setpoint_nm, mirror.speed_setpoint_hz, mirror.revolutions, mirror.seed) == (-2.5, -0.75, 3, 7)
    c = np.arange(64)
    np.testing.assert_array_equal(mirror.torque_reference_nm(), -request.torque_reference_nm()[-c % 64])
    back = mirrored_request(mirror)
    for name in ("feedforward_nm", "excitation_nm"):
        np.testing.assert_array_equal(getattr(back, name), getattr(request, name))
    assert back.torque_setpoint_nm == request.torque_setpoint_nm and back.speed_setpoint_hz == 0.75


@PROPERTY
@given(torque=st.floats(-6.5, 6.5), speed=st.floats(0.3, 1.6), revolutions=st.integers(1, 4),
       table=arrays(np.float64, CPR, elements=st.floats(-1.0, 1.0)), size=st.floats(0.0, 1.1),
       scale=st.floats(0.88, 1.12), offset=st.floats(-0.6, 0.6), with_truth=st.booleans())
def test_the_guard_refuses_a_mirror_request_exactly_where_it_refuses_the_motor_request_it_becomes(
        drive, torque, speed, revolutions, table, size, scale, offset, with_truth):
    """The guard checks the mirror's request (`MirroredBackend` sits below it): every limit reads the same numbers
    there as in the motor's reverse request it becomes (its torque reference and currents at the mirrored counts,
    its speed's size), so one is refused exactly where the other would be. Checked against the motor's request at
    the speed's size (the guard takes only positive speeds)."""
    _, description, identified = drive
    base = description.calibration
    cal = SensorCalibration(base.current_scale * scale, base.current_offset + offset, base.torque_gain)
    mirror = TrialRequest(torque, speed, revolutions, size * table, np.zeros(CPR), cal, 3)
    motor = mirrored_request(mirror)
    motor = dataclasses.replace(motor, speed_setpoint_hz=-motor.speed_setpoint_hz)
    truth = identified_truth(identified) if with_truth else None
    theirs = limit_violation(mirror, mirrored_description(description), LIMITS, truth)
    ours = limit_violation(motor, description, LIMITS, truth)
    assert (theirs is None) == (ours is None), (theirs, ours)
    event("accepted" if ours is None else ours.split(" ")[0])


def test_a_reverse_trial_on_the_simulator_is_its_mirrors_forward_lap(drive):
    backend, description, _ = drive
    rng = np.random.default_rng(4)
    mirror = TrialRequest(2.0, 0.8, 3, rng.normal(0, 0.05, CPR), np.zeros(CPR), description.calibration, 11)
    through = MirroredBackend(backend).run_trial(mirror)
    direct = backend.simulator.mirrored().run_trial(mirror)
    for name in ("count", "time_s", "i_ref_a", "torque_nm", "torque_true_nm"):
        np.testing.assert_array_equal(getattr(through, name), getattr(direct, name))
    assert through.speed_setpoint_hz == 0.8 and np.all(np.diff(through.count) > 0)
    # the mirror's description is the motor's with its back-EMF mirrored, marked as reverse laps
    seen = MirroredBackend(backend).describe()
    np.testing.assert_array_equal(seen.backemf_nm_per_a, mirrored_table(description.backemf_nm_per_a))
    assert seen.motor.mirrored and not description.motor.mirrored


def test_the_mirror_refuses_a_backend_that_runs_no_reverse_trials_and_a_reverse_request(drive):
    backend, description, _ = drive

    class ForwardOnly:
        max_parallel_trials = 1

    with pytest.raises(IlcpmacError, match="runs no reverse trials"):
        MirroredBackend(ForwardOnly())  # type: ignore[arg-type]
    request = TrialRequest(1.0, -0.5, 3, np.zeros(CPR), np.zeros(CPR), description.calibration)
    with pytest.raises(IlcpmacError, match="forward trials only"):
        MirroredBackend(backend).run_trial(request)


NEVER = FadeOut(np.inf, np.inf)


def _record(speeds, seed: int, fade: FadeOut = NEVER, offset: float = 0.0) -> Compensation:
    tables = np.random.default_rng(seed).normal(0.0, 0.01, (2, len(speeds), 32))
    return Compensation(32, SensorCalibration([14.0, 14.1, 13.9], [offset, 0.0, 0.0], 0.9), np.array([-3.0, 3.0]),
                        np.array(speeds), tables, fade)


def test_both_directions_hold_the_reverse_tables_mirrored_back_at_negated_points():
    forward, reverse = _record([0.5, 1.0], 1, FadeOut(1.0, 2.0)), _record([0.5, 1.5], 2, FadeOut(3.0, 4.0))
    both = both_directions(forward, reverse)
    assert both.speeds_hz.tolist() == [-1.5, -0.5, 0.5, 1.0] and both.torques_nm.tolist() == [-3.0, 3.0]
    assert both.fade == FadeOut(1.0, 2.0)
    for i in range(2):  # the mirror's (T', S') at the motor's (-T', -S'): both axes reversed
        for k in range(2):
            np.testing.assert_array_equal(both.tables_nm[1 - i, 1 - k], mirrored_table(reverse.tables_nm[i, k]))
    np.testing.assert_array_equal(both.tables_nm[:, 2:], forward.tables_nm)
    alone = both_directions(None, reverse)
    assert alone.speeds_hz.tolist() == [-1.5, -0.5]
    with pytest.raises(IlcpmacError, match="different calibrations"):
        both_directions(forward, _record([0.5], 3, offset=0.1))
    with pytest.raises(IlcpmacError, match="different torques"):
        both_directions(forward, dataclasses.replace(reverse, torques_nm=np.array([-4.0, 3.0])))


def test_the_sensors_at_a_calibration_give_that_calibration_back(drive):
    _, description, identified = drive
    target = SensorCalibration([15.1, 13.2, 14.4], [0.3, -0.2, 0.1], description.calibration.torque_gain)
    result = IdentificationResult(delta_epsilon=0.5, delta=0.82, epsilon=0.6, alpha=np.ones(3), beta=np.zeros(3))
    held = at_calibration(result, target, description.calibration)
    truth = identified_truth(Identified.from_result(dataclasses.replace(held, cogging_nm=np.zeros(CPR)),
                                                    description.calibration))
    np.testing.assert_allclose(truth.current_scale, target.current_scale, rtol=1e-13)
    np.testing.assert_allclose(truth.current_offset, target.current_offset, rtol=1e-13, atol=1e-13)
    assert held.delta_epsilon == pytest.approx(held.delta * held.epsilon, rel=1e-15)


def test_the_floor_takes_the_same_points_at_minus_x_as_at_x_on_an_axis_through_zero():
    grid = np.array([-5.0, -3.0, -1.0, 1.0, 3.0, 5.0])
    np.testing.assert_array_equal(_axis_weights(grid, -2.0), _axis_weights(grid, 2.0)[::-1])
    assert np.flatnonzero(_axis_weights(grid, 2.0)).tolist() == [2, 3, 4]
    one_sign = np.array([1.0, 3.0, 5.0, 7.0])  # the grid's order, as before: 1, 3 and 5 at 4 N m
    assert np.flatnonzero(_axis_weights(one_sign, 4.0)).tolist() == [0, 1, 2]


def test_a_config_in_both_directions_splits_into_two_at_positive_speeds(write_config):
    config = load_config(write_config(BOTH))
    assert config.directions() == (FORWARD, REVERSE)
    forward, reverse = config.in_direction(FORWARD), config.in_direction(REVERSE)
    assert forward.learned_points() == [(-3.0, 0.9), (3.0, 0.9)]
    assert reverse.learned_points() == [(-3.0, 0.9), (3.0, 0.9)]  # the motor's (3, -0.9) is the mirror's (-3, 0.9)
    assert config.validation_points() == [(-2.0, -0.9), (-2.0, 0.9), (2.0, -0.9), (2.0, 0.9)]
    lengths = {**BOTH["campaign"], "learn_torques_nm": [-3.0, 1.0, 3.0], "learn_revolutions": [5, 7, 9]}
    reverse = load_config(write_config({**BOTH, "campaign": lengths})).in_direction(REVERSE)
    assert reverse.learned_torques_nm() == (-3.0, -1.0, 3.0) and reverse.campaign.learn_revolutions == (9, 7, 5)
    assert reverse.trial_revolutions((-3.0, 0.9)) == 9  # the motor's 3 N m


@pytest.mark.parametrize("changes, message", [
    ({"validate_speeds_hz": [-0.9, 0.9], "learn_speeds_hz": [0.9]},
     r"validate_speeds_hz: -0.9 Hz validates a direction \[campaign\] learn_speeds_hz learns nothing in"),
    ({"learn_speeds_hz": [-2.0, 0.9]}, r"learn_speeds_hz: -2 is beyond \[limits\] max_speed_hz 1.5"),
    ({"learn_speeds_hz": [0.0, 0.9]}, "learn_speeds_hz"),
])
def test_a_config_that_cannot_learn_in_reverse_is_refused_naming_the_key(write_config, changes, message):
    with pytest.raises(ConfigError, match=message):
        load_config(write_config({**BOTH, "campaign": {**BOTH["campaign"], **changes}}))


def test_a_reverse_point_that_generates_on_the_brake_is_refused_in_the_motors_signs(write_config):
    brake = {**BOTH, "simulator.mechanics": {"load": "brake"},
             "campaign": {**BOTH["campaign"], "learn_torques_nm": [1.0, 3.0], "validate_torques_nm": [2.0]}}
    with pytest.raises(ConfigError, match=r"1 N m at -0.9 Hz generates, which the eddy-current brake"):
        load_config(write_config(brake))


def test_a_campaign_in_both_directions_is_refused_by_run_and_by_a_forward_only_backend(write_config, tmp_path):
    import ilcpmac.campaign
    from ilcpmac.backends.registry import BackendSetup

    path = write_config(BOTH)
    with pytest.raises(ConfigError, match="learns in reverse: a campaign in both directions runs with ilcpmac run"):
        ilcpmac.campaign.run(path, out=tmp_path / "run")

    class ForwardOnly:
        """The simulator, without its reverse trials."""

        max_parallel_trials = 1

        def __init__(self) -> None:
            self.inner = SimulatorBackend.from_setup(BackendSetup(load_config(path), None))

        def describe(self):
            return self.inner.describe()

        def run_trial(self, request):
            raise AssertionError("no trial may run")

        def close(self) -> None:
            """Nothing to release."""

    with pytest.raises(ConfigError, match=r"learn_speeds_hz -0.9: the ForwardOnly backend runs no reverse trials"):
        run_quadrants(path, out=tmp_path / "run", backend=ForwardOnly())
    assert not (tmp_path / "run").exists()


@pytest.mark.slow
def test_a_campaign_in_both_directions_learns_and_validates_every_quadrant(write_config, tmp_path):
    """Truth first: the small campaign in both directions (``ilcpmac run``): every learned point within 1.5x its
    true floor and every validation point within 2x, in each direction (measured: forward 0.72-1.25x, reverse
    1.02-1.88x); the reverse learned at the forward's final calibration, so the record of both holds one; its
    reverse tables are the reverse run's mirrored back; a resumed run writes the same record; the reverse
    direction's identification is marked as the mirror's and refused as a position table; the report and the
    C export read the run."""
    path = write_config(BOTH)
    run = tmp_path / "run"
    done = CliRunner().invoke(main, ["run", str(path), "--out", str(run)], terminal_width=100)
    assert done.exit_code == 0, done.output
    assert "forward" in done.output and "reverse (as the mirror image's forward laps" in done.output
    assert done.output.startswith("plan of both directions: forward ")  # before the first trial
    assert f"next: ilcpmac report {run / 'forward'}" in done.output
    for direction in (FORWARD, REVERSE):
        summary = json.loads((run / direction / "summary.json").read_text())
        for p in summary["points"]:
            bound = 1.5 if p["learned"] else 2.0
            assert 0.0 < p["ripple_pp_true"] < bound * p["floor_pp_true"], (direction, p["torque_setpoint"])
    forward, reverse = (Compensation.read(run / d / "compensation.json") for d in (FORWARD, REVERSE))
    both = Compensation.read(run / "compensation.json")
    np.testing.assert_allclose(reverse.calibration.current_scale, forward.calibration.current_scale, rtol=1e-9)
    np.testing.assert_array_equal(both.feedforward_nm(3.0, -0.9), mirrored_table(reverse.tables_nm[0, 0]))
    np.testing.assert_array_equal(both.feedforward_nm(3.0, 0.9), forward.tables_nm[1, 0])
    result = json.loads((run / REVERSE / "summary.json").read_text())["identification"]
    assert MIRROR_COORDINATES in result["messages"]
    assert any(m.startswith("reverse grid identified on its own: delta eps") for m in result["messages"])
    (tmp_path / "reverse.json").write_text(json.dumps(result))
    with pytest.raises(BenchFormatError, match="in the mirror image's coordinates"):
        read_position_table(tmp_path / "reverse.json")
    before = (run / "compensation.json").read_bytes()
    again = CliRunner().invoke(main, ["run", "--resume", str(run)], terminal_width=100)
    assert again.exit_code == 0, again.output
    assert (run / "compensation.json").read_bytes() == before
    report = CliRunner().invoke(main, ["report", str(run)])
    assert report.exit_code == 0 and (run / REVERSE / "plots" / "report.html").exists(), report.output
    exported = CliRunner().invoke(main, ["export", str(run), "--format", "c", "--out", str(tmp_path / "c")])
    assert exported.exit_code == 0 and "|speed set point| at most 0.9 Hz" in exported.output, exported.output
    assert "Learned in both directions: a negative S turns in reverse" in (tmp_path / "c" /
                                                                           "ilcpmac_compensation.h").read_text()
    sub = CliRunner().invoke(main, ["run", "--resume", str(run / REVERSE)])
    assert sub.exit_code != 0 and "resume the run directory that holds it" in sub.output


def test_the_reverse_identification_without_a_forward_one_is_the_mirrors_own():
    """The mirrored bench folder identifies in the motor's coordinates (`in_motor_coordinates`); the reverse campaign
    learns in the mirror's: its own result mirrored back, said so."""
    from ilcpmac.identify.mirror import MIRRORED_MESSAGE

    def motors(bench, *, torque_source=None):
        return IdentificationResult(delta=0.8, epsilon=0.7, cogging_nm=np.arange(8.0), messages=(MIRRORED_MESSAGE,))

    result = MirroredIdentification(None, motors)(None)  # type: ignore[arg-type]
    np.testing.assert_array_equal(result.cogging_nm, mirrored_table(np.arange(8.0)))
    assert MIRRORED_MESSAGE not in result.messages and MIRROR_COORDINATES in result.messages


class Crash(Exception):
    """A killed process, as the backend sees it."""


@pytest.mark.slow
def test_a_campaign_in_both_directions_stopped_in_reverse_resumes_as_the_uninterrupted_one(write_config, tmp_path):
    """Killed within the reverse learning (the forward done), ``--resume`` of the run directory continues the
    reverse where it stopped, with the forward's identification and calibration, and writes every record byte for
    byte as the run that was never stopped."""
    from ilcpmac.backends.registry import BackendSetup

    path = write_config(BOTH)
    reference = run_quadrants(path, out=tmp_path / "reference")
    forward_trials = len(reference.directions[FORWARD].records)

    class Crashing:
        reverses = True
        max_parallel_trials = 1

        def __init__(self) -> None:
            self.inner, self.calls = SimulatorBackend.from_setup(BackendSetup(load_config(path), None)), 0

        def describe(self):
            return self.inner.describe()

        def run_trial(self, request):
            self.calls += 1
            if self.calls == forward_trials + 12:
                raise Crash(f"killed during call {self.calls}")
            return self.inner.run_trial(request)

        def close(self) -> None:
            """Nothing to release."""

    with pytest.raises(Crash):
        run_quadrants(path, out=tmp_path / "crashed", backend=Crashing())
    crashed = tmp_path / "crashed"
    assert not (crashed / "compensation.json").exists()
    for name, edit in (("campaign.toml", lambda t: t.replace("max_torque_nm = 8.0", "max_torque_nm = 80.0")),
                       ("quadrants.json", lambda t: t.replace('"seed": 2009', '"seed": 2010'))):
        text = (crashed / name).read_text()
        assert edit(text) != text
        (crashed / name).write_text(edit(text))
        with pytest.raises(ConfigError, match="not what .* began with"):
            run_quadrants(resume=crashed)
        (crashed / name).write_text(text)
    resumed = run_quadrants(resume=crashed)
    for name in ("compensation.json", "forward/compensation.json", "reverse/compensation.json",
                 "reverse/states/learned.json"):
        assert (tmp_path / "crashed" / name).read_bytes() == (tmp_path / "reference" / name).read_bytes(), name
    assert resumed.directions[REVERSE].summary["points"] == reference.directions[REVERSE].summary["points"]


@pytest.mark.slow
def test_the_api_runs_both_directions_and_load_run_names_their_folders(write_config, tmp_path):
    import ilcpmac.api as ilc

    path = write_config(BOTH)
    with pytest.raises(ConfigError, match="ilcpmac.api.run_quadrants"):
        ilc.run(path, out=tmp_path / "one")
    both = ilc.run_quadrants(path, out=tmp_path / "run")
    assert list(both.directions) == [FORWARD, REVERSE] and both.compensation_file == tmp_path / "run" / \
        "compensation.json"
    for results in both.directions.values():
        assert len(results.points) == 4 and all(p.ripple_pp_true_percent < 2 * p.floor_pp_true_percent
                                                for p in results.points)
    assert ilc.load_run(tmp_path / "run" / REVERSE).points == both.directions[REVERSE].points
    with pytest.raises(IlcpmacError, match=r"a campaign in both directions: load_run of .*forward and .*reverse"):
        ilc.load_run(tmp_path / "run")
    exported = ilc.export(both.compensation_file, "json", tmp_path / "out")
    assert Compensation.read(exported.files[0]).speeds_hz.tolist() == [-0.9, 0.9]


@pytest.mark.slow
def test_a_campaign_in_reverse_alone_learns_with_its_own_grid_in_the_mirrors_coordinates(write_config, tmp_path):
    """Only negative speeds: no forward campaign, so the reverse identifies its grid and learns with that, mirrored
    into its own coordinates (the bench folder says mirrored = true, whose identification reports in the motor's);
    every point within its bounds (measured 0.86-1.46x); the record holds negative speeds only."""
    reverse_only = {**BOTH, "campaign": {**BOTH["campaign"], "learn_speeds_hz": [-0.9], "validate_speeds_hz": [-0.9]}}
    result = run_quadrants(write_config(reverse_only), out=tmp_path / "run")
    assert list(result.directions) == [REVERSE] and not (tmp_path / "run" / FORWARD).exists()
    summary = result.directions[REVERSE].summary
    for p in summary["points"]:
        assert 0.0 < p["ripple_pp_true"] < (1.5 if p["learned"] else 2.0) * p["floor_pp_true"], p["torque_setpoint"]
    from ilcpmac.identify.mirror import MIRRORED_MESSAGE

    messages = summary["identification"]["messages"]
    assert MIRROR_COORDINATES in messages and MIRRORED_MESSAGE not in messages
    assert result.compensation.speeds_hz.tolist() == [-0.9] and result.compensation.torques_nm.tolist() == [-3.0, 3.0]
