"""Reverse laps (issue 13, item 1): imported as forward laps of the motor's mirror image, identified exactly.

A reverse lap of the motor M is a forward lap of its mirror M' in phi = -theta: K'_p(phi) = -K_p(-phi),
tau'_c(phi) = -tau_c(-phi), e'(phi) = -e(-phi), the torque negated, everything in time the same
(docs/bench-format.md, "Reverse laps"). The tests simulate M' forward (the simulator of M with its
position tables mirrored), write its trials as a real reverse-lap log of M (position -phi, decreasing;
torque -tau'), import and identify it, and compare with M's truth.
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import COUNTS_PER_REV, MAPPING_BENCH, PHASE_LOG, SEED_CONFIG, toml_text
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import ilcpmac.cli.import_  # noqa: F401  (registers the command on main)
from ilcpmac.bench.format import BENCH_FILE, Bench, convert_bench, read_bench, write_backemf_csv, write_bench
from ilcpmac.bench.importer import import_laps, import_log, import_logs, read_mapping, reverse_folder
from ilcpmac.campaign.grid import grid_requests
from ilcpmac.cli import main
from ilcpmac.config import load_config
from ilcpmac.core.errors import BenchFormatError
from ilcpmac.core.records import IdentificationResult, MethodEstimates, MotorInfo, TrialData, mirrored_table
from ilcpmac.core.torque_source import TorqueSource
from ilcpmac.identify import identify_bench
from ilcpmac.identify.mirror import MIRRORED_MESSAGE, in_mirror_coordinates, in_motor_coordinates
from ilcpmac.model.encoder import line_errors_counts
from ilcpmac.model.tables import backemf_table, cogging_table
from ilcpmac.signals.encoder_torque import encoder_error_summary
from ilcpmac.signals.harmonics import harmonic_amplitudes
from ilcpmac.sim.bench import truth_dict
from ilcpmac.sim.simulator import Simulator

HEADER = "t,theta,ia,ib,ic,tq"
#: rows per second of the logs
RATE_HZ = 2_000.0
#: bounds on the errors of delta eps, delta, eps (relative), alpha, beta (A, largest) and the cogging (RMS relative
#: to the true RMS) of the 4-trial grid below, forward and reverse alike: the issue's targets
#: (tests/identify_helpers.assert_targets) but delta eps 1 % and beta 20 mA: over grid seeds 1-5 the forward import
#: of this small grid gives up to 0.47 % and 10.2 mA, the reverse one up to 0.60 % and 15.7 mA
BOUNDS = {"delta_epsilon": 0.01, "delta": 0.015, "epsilon": 0.02, "alpha": 0.003, "beta": 0.02, "cogging": 0.03}


@pytest.fixture(scope="module")
def motors(tmp_path_factory) -> tuple[Simulator, Simulator, list]:
    """M (the small seed bench: 1024 counts, every error present; its cogging's phases 0.9 and 0.7 rad, so that
    the mirror moves every term) and its mirror M', and the grid's requests: 2 and 4 N m at 0.5 and 1 Hz,
    8 revolutions, multisine-excited."""
    folder = tmp_path_factory.mktemp("config")
    data = tomllib.loads(SEED_CONFIG.read_text())
    data["bench"]["counts_per_rev"] = COUNTS_PER_REV
    data["simulator"]["cogging"]["phases_rad"] = [0.9, 0.7]
    data["trials"].update(torque_setpoints_nm=[2.0, 4.0], speed_setpoints_hz=[0.5, 1.0], revolutions=8)
    (folder / "campaign.toml").write_text(toml_text(data))
    config = load_config(folder / "campaign.toml")
    simulator = Simulator(config.sampled_model(), config.grid.warmup_revolutions, config.recorded_counts_per_rev())
    requests = grid_requests(config, config.sampled_model().controller.calibration(), 3, 8)
    return simulator, simulator.mirrored(), requests


def log_rows(trial: TrialData, reverse: bool, shift_counts: int = 0) -> np.ndarray:
    """A trial as a drive logs it at RATE_HZ, from two rows before its first count to two past its last: time,
    position (rad), the current references and the torque, linearly interpolated between counts; ``reverse``:
    the trial is one of the mirror M', logged as the reverse lap of M it is (position -phi + shift, torque
    negated)."""
    t = trial.time_s[0] + np.arange(-2, int(np.ceil((trial.time_s[-1] - trial.time_s[0]) * RATE_HZ)) + 3) / RATE_HZ
    position = np.interp(t, trial.time_s, trial.count)
    for end, outside in ((0, t < trial.time_s[0]), (-1, t > trial.time_s[-1])):
        speed = 1.0 / abs(trial.time_s[end] - trial.time_s[1 if end == 0 else -2])
        position[outside] = trial.count[end] + (t[outside] - trial.time_s[end]) * speed
    sign = -1.0 if reverse else 1.0
    values = [np.interp(t, trial.time_s, v) for v in trial.i_ref_a.T]
    torque = sign * np.interp(t, trial.time_s, trial.torque_nm)
    return np.column_stack([t, (sign * position + shift_counts) * 2 * np.pi / COUNTS_PER_REV, *values, torque])


def write_log(path: Path, rows: np.ndarray) -> Path:
    np.savetxt(path, rows, delimiter=",", header=HEADER, comments="", fmt="%.12g")
    return path


def mapping_file(folder: Path, backemf: np.ndarray, extra: str = "") -> Path:
    folder.mkdir(exist_ok=True)
    write_backemf_csv(folder / "backemf.csv", backemf)
    path = folder / "map.toml"
    path.write_text(MAPPING_BENCH + PHASE_LOG + extra)
    return path


def test_the_mirror_of_a_table_is_the_mirror_motors_table(small_model):
    """K'_p(phi) = -K_p(-phi) is the back-EMF of [bench.backemf] with every phase phi_n negated and phases b and c
    swapped (the reversed phase sequence: another motor), and tau'_c the cogging with its phases negated."""
    w, emf, cogging = small_model.winding, small_model.backemf, small_model.cogging
    a = emf.asymmetry
    reversed_sequence = dataclasses.replace(emf, phases_rad=tuple(-p for p in emf.phases_rad),
                                            asymmetry=(a[0], a[2], a[1]))
    np.testing.assert_allclose(mirrored_table(backemf_table(w, emf, COUNTS_PER_REV)),
                               backemf_table(w, reversed_sequence, COUNTS_PER_REV)[:, [0, 2, 1]], rtol=0, atol=1e-12)
    negated = dataclasses.replace(cogging, phases_rad=tuple(-p for p in cogging.phases_rad))
    np.testing.assert_allclose(mirrored_table(cogging_table(w, cogging, COUNTS_PER_REV)),
                               cogging_table(w, negated, COUNTS_PER_REV), rtol=0, atol=1e-12)
    assert not np.allclose(mirrored_table(backemf_table(w, emf, COUNTS_PER_REV)), backemf_table(w, emf, COUNTS_PER_REV))


@given(arrays(np.float64, st.tuples(st.integers(1, 64), st.integers(1, 3)), elements=st.floats(-1e3, 1e3)))
def test_mirroring_twice_gives_the_table_back(table):
    mirrored = mirrored_table(table)
    np.testing.assert_array_equal(mirrored[0], -table[0])  # count 0 stays count 0
    np.testing.assert_array_equal(mirrored_table(mirrored), table)


def test_a_reverse_lap_imports_as_the_mirror_trial(tmp_path, motors):
    """A reverse-lap log of M is imported as the forward trial of M' it is: the same counts (one revolution on:
    the log's position is -phi + N), time stamps, currents and torque within the stated interpolation error,
    and the set point of M' from its data."""
    simulator, mirror, requests = motors
    trial = mirror.run_trial(dataclasses.replace(requests[0], revolutions=2))
    mapping = read_mapping(mapping_file(tmp_path, simulator.backemf_counts))
    rows = log_rows(trial, reverse=True, shift_counts=COUNTS_PER_REV)
    assert np.all(np.diff(rows[:, 1]) < 0)  # the position runs backwards throughout
    imported = import_log(write_log(tmp_path / "log.csv", rows), mapping)
    got, error = imported.trial, imported.error
    assert imported.reverse and imported.lines is None
    np.testing.assert_array_equal(got.count, trial.count - COUNTS_PER_REV)
    assert np.abs(got.time_s - trial.time_s).max() <= error.time_s
    assert np.abs(got.i_ref_a - trial.i_ref_a).max() <= error.current_a
    assert np.abs(got.torque_nm - trial.torque_nm).max() <= error.torque_nm
    assert got.torque_setpoint_nm == 2.0


def grid_logs(folder: Path, simulator: Simulator, requests: list, reverse: bool) -> list[str]:
    """The grid's trials of ``simulator`` written as logs (`log_rows`): reverse laps of M for its mirror."""
    folder.mkdir()
    return [str(write_log(folder / f"log{k}.csv", log_rows(trial, reverse)))
            for k, trial in enumerate(simulator.run_trials(requests))]


def errors(result: IdentificationResult, truth: dict) -> dict:
    """The result's errors against M's truth, in the units of BOUNDS."""
    true_cogging = np.asarray(truth["cogging"]["torque"])
    return {"delta_epsilon": abs(result.delta_epsilon / truth["total_system_gain"] - 1),
            "delta": abs(result.delta / truth["torque_sensor_gain"] - 1),
            "epsilon": abs(result.epsilon / truth["epsilon"] - 1),
            "alpha": np.abs(result.alpha - truth["alpha"]).max(), "beta": np.abs(result.beta - truth["beta"]).max(),
            "cogging": np.sqrt(np.mean((result.cogging_nm - true_cogging) ** 2) / np.mean(true_cogging**2))}


def test_reverse_laps_identify_the_motor_as_forward_laps_do(tmp_path, motors):
    """The grid of M' logged as reverse laps of M, imported by the command (only the reverse bench, mirrored) and
    identified: delta eps, delta, eps, alpha, beta and, mirrored back, the cogging against M's truth, within
    BOUNDS, as the same grid of M logged forward. Measured (2 kHz logs, grid seed 3): forward 0.22 % on delta eps,
    0.11 % on delta, 0.33 % on eps, alpha 0.0013, beta 10.2 mA, cogging 0.63 %; reverse 0.13 %, 0.13 %, 0.00 %,
    0.0015, 15.7 mA, 0.54 % (M' is another motor: other noise, and the current loop's lag and the sensor's
    dynamics meet mirrored tables, so the model's misfit differs)."""
    simulator, mirror, requests = motors
    truth = truth_dict(simulator, requests[0].calibration)
    mapping = mapping_file(tmp_path, simulator.backemf_counts)
    found = {}
    for name, sim, reverse in (("forward", simulator, False), ("reverse", mirror, True)):
        logs = grid_logs(tmp_path / name, sim, requests, reverse)
        out = tmp_path / f"{name}-bench"
        result = CliRunner().invoke(main, ["import", *logs, "--map", str(mapping), "--out", str(out)])
        assert result.exit_code == 0, result.output
        folder = reverse_folder(out) if reverse else out
        assert out.exists() != reverse and reverse_folder(out).exists() == reverse  # one bench, of its direction
        bench = read_bench(folder)
        assert bench.motor.mirrored == reverse
        np.testing.assert_allclose(bench.backemf_nm_per_a, sim.backemf_counts, rtol=0, atol=1e-12)
        found[name] = identify_bench(bench)
    assert MIRRORED_MESSAGE in found["reverse"].messages and MIRRORED_MESSAGE not in found["forward"].messages
    forward, reverse = errors(found["forward"], truth), errors(found["reverse"], truth)
    for key, bound in BOUNDS.items():
        assert forward[key] < bound and reverse[key] < bound, (key, forward[key], reverse[key])
    # the cogging as identified on M' is M''s: left unmirrored it would be wrong by far
    unmirrored = dataclasses.replace(found["reverse"], cogging_nm=mirrored_table(found["reverse"].cogging_nm))
    assert errors(unmirrored, truth)["cogging"] > 1.0
    np.testing.assert_allclose(found["reverse"].methods["report"].cogging_nm, truth["cogging"]["torque"], rtol=0,
                               atol=0.05 * np.abs(truth["cogging"]["torque"]).max())


def test_a_log_with_forward_and_reverse_laps_gives_both_benches(tmp_path, motors):
    """One log: a forward lap of M, then (the position turning) a reverse lap, M''s trial one revolution on: the
    forward lap in OUT, the reverse one mirrored in OUT-reverse, the output saying what went where."""
    simulator, mirror, requests = motors
    request = dataclasses.replace(requests[0], revolutions=3)
    forward_trial, mirror_trial = simulator.run_trial(request), mirror.run_trial(request)
    forward = log_rows(forward_trial, reverse=False)
    end = forward[-1, 1] * COUNTS_PER_REV / (2 * np.pi)
    # whole revolutions on (M's angles stay M's), the reverse lap starts above the turn ...
    shift = COUNTS_PER_REV * math.ceil((end + mirror_trial.count[0] + 1) / COUNTS_PER_REV)
    backward = log_rows(mirror_trial, reverse=True, shift_counts=shift)
    backward = backward[backward[:, 1] * COUNTS_PER_REV / (2 * np.pi) < end]  # ... and is logged from below it on
    backward[:, 0] += forward[-1, 0] + 1 / RATE_HZ - backward[0, 0]
    log = write_log(tmp_path / "log.csv", np.vstack([forward, backward]))
    mapping = mapping_file(tmp_path, simulator.backemf_counts)
    out = tmp_path / "bench"
    result = CliRunner().invoke(main, ["import", str(log), "--map", str(mapping), "--out", str(out)])
    assert result.exit_code == 0, result.output
    output = " ".join(result.output.split())
    turn = forward.shape[0] + 1  # the file line of the turning row: the forward lap's last
    assert re.search(rf"log.csv lines 2-{turn} -> trial_01.csv: \d+ counts, 2 N m at 0.4\d+ Hz", output), output
    assert re.search(rf"log.csv lines {turn}-{turn + backward.shape[0]} \(reverse, mirrored\) -> "
                     r"bench-reverse/trial_01.csv: \d+ counts, 2 N m", output), output
    assert "bench-reverse - reverse laps as forward laps of the motor's mirror image ([motor] mirrored = true" in output
    ahead, behind = read_bench(out), read_bench(reverse_folder(out))
    assert not ahead.motor.mirrored and behind.motor.mirrored
    assert np.all(np.isin(ahead.trials[0].count, forward_trial.count))
    assert np.all(np.isin(behind.trials[0].count, mirror_trial.count - shift))
    assert behind.trials[0].n_samples > COUNTS_PER_REV
    np.testing.assert_allclose(behind.backemf_nm_per_a, mirror.backemf_counts, rtol=0, atol=1e-12)


def test_the_mirrored_bench_round_trips_through_bench_toml(tmp_path, small_simulator, make_request, small_model):
    trial = small_simulator.run_trial(make_request(small_model, 2.0, 0.5))
    motor = MotorInfo(8, 48, COUNTS_PER_REV, 0.01056, mirrored=True)
    write_bench(tmp_path / "a", Bench(motor, small_simulator.backemf_counts, None, (trial,), ("trial_01.csv",)))
    assert "mirrored = true" in (tmp_path / "a" / BENCH_FILE).read_text()
    assert read_bench(tmp_path / "a").motor == motor
    assert convert_bench(tmp_path / "a", tmp_path / "b", ".parquet").motor == motor
    assert read_bench(tmp_path / "b").motor.mirrored
    toml = tmp_path / "b" / BENCH_FILE
    toml.write_text(toml.read_text().replace("mirrored = true", "mirrored = 1"))
    with pytest.raises(BenchFormatError, match=r"bench.toml: \[motor\] mirrored: expected true or false, got 1$"):
        read_bench(tmp_path / "b")


def test_in_motor_coordinates_mirrors_the_cogging_and_the_encoder_error():
    """An encoder of eccentricity A at phase p, mirrored (e'(phi) = -e(-phi)), has eccentricity A at phase -p: the
    result of M' (its tables and summary) comes back as M's, everything else as it was, with the message."""
    n = 256
    errors_m = line_errors_counts(n, 0.05, 0.7, 0.01, 3)
    cogging = np.sin(2 * np.pi * 12 * np.arange(n) / n + 0.4)
    mirror_errors = mirrored_table(errors_m)
    amplitude, _, phase, _ = encoder_error_summary(harmonic_amplitudes(mirror_errors))
    assert amplitude == pytest.approx(0.05, rel=0.05) and phase == pytest.approx(-0.7, abs=0.05)
    mirror = IdentificationResult(
        epsilon=0.9, alpha=np.array([0.9, 1.0, 1.1]), beta=np.array([0.1, 0.0, -0.1]),
        cogging_nm=mirrored_table(cogging),
        methods={"joint": MethodEstimates(epsilon=0.9, cogging_nm=mirrored_table(cogging)),
                 "report": MethodEstimates()},
        messages=("m",), encoder_error_counts=mirror_errors, encoder_error_std_counts=np.full(n, 0.002),
        encoder_eccentricity_counts=amplitude, encoder_eccentricity_phase_rad=phase)
    motor = in_motor_coordinates(mirror)
    np.testing.assert_array_equal(motor.cogging_nm, cogging)
    np.testing.assert_array_equal(motor.methods["joint"].cogging_nm, cogging)
    assert motor.methods["report"].cogging_nm is None
    np.testing.assert_array_equal(motor.encoder_error_counts, errors_m)
    np.testing.assert_array_equal(motor.encoder_error_std_counts, np.full(n, 0.002))
    assert motor.encoder_eccentricity_phase_rad == -phase
    assert motor.messages == ("m", MIRRORED_MESSAGE)
    assert (motor.epsilon, motor.alpha.tolist(), motor.beta.tolist()) == (0.9, [0.9, 1.0, 1.1], [0.1, 0.0, -0.1])
    at_pi = in_motor_coordinates(dataclasses.replace(mirror, encoder_eccentricity_phase_rad=math.pi))
    assert at_pi.encoder_eccentricity_phase_rad == math.pi  # within (-pi, pi]
    # the figures, drawn from the mirror's details, draw the result's tables in the mirror's coordinates
    np.testing.assert_array_equal(in_mirror_coordinates(motor, motor.cogging_nm), mirror.cogging_nm)
    np.testing.assert_array_equal(in_mirror_coordinates(mirror, mirror.cogging_nm), mirror.cogging_nm)


def test_a_mirrored_bench_without_torque_sensor_gives_the_motors_encoder_error(tmp_path):
    """The encoder path on reverse laps: the small sensorless bench of tests/test_identify_encoder.py (3 and 5 N m
    at 1 and 1.5 Hz, 6 revolutions; an encoder of eccentricity 0.05 counts at 0.7 rad and 0.01 counts per line)
    as M', identified on its encoder: eps, alpha, beta and the cogging within tests/test_importer.py's bounds for
    that bench forward, and the line errors, mirrored back, M's: nearer M's than M''s. Measured (grid seed 1):
    eps 0.04 %, the line errors off by 0.78 of their RMS (1.47-1.97 unmirrored over seeds 1-6, 0.41-0.83
    mirrored back), the eccentricity 0.0495 counts at 1.52 rad (-0.7 unmirrored; forward laps of M: 0.046 at
    0.21 rad): six revolutions leave the 1x error's phase uncertain."""
    data = tomllib.loads(SEED_CONFIG.read_text())
    data["bench"]["counts_per_rev"] = COUNTS_PER_REV
    data["trials"].update(torque_setpoints_nm=[3.0, 5.0], speed_setpoints_hz=[1.0, 1.5], revolutions=6)
    data["simulator"]["encoder"].update(eccentricity_counts=0.05, eccentricity_phase_rad=0.7, line_std_counts=0.01)
    data["simulator"]["cogging"]["phases_rad"] = [0.9, 0.7]
    (tmp_path / "campaign.toml").write_text(toml_text(data))
    config = load_config(tmp_path / "campaign.toml")
    simulator = Simulator(config.sampled_model(), config.grid.warmup_revolutions, config.recorded_counts_per_rev())
    requests = grid_requests(config, config.sampled_model().controller.calibration(), 1, 6)
    mirror = simulator.mirrored()
    trials = tuple(dataclasses.replace(t, torque_nm=None) for t in mirror.run_trials(requests))
    motor = MotorInfo(8, 48, COUNTS_PER_REV, 0.01056, torque_sensor=False, timer_resolution_s=1e-6, mirrored=True)
    result = identify_bench(Bench(motor, mirror.backemf_counts, requests[0].calibration, trials,
                                  tuple(f"trial_{i:02d}.csv" for i in range(1, 5))))
    truth = truth_dict(simulator, requests[0].calibration)
    assert result.torque_source is TorqueSource.ENCODER and MIRRORED_MESSAGE in result.messages
    assert abs(result.epsilon / truth["epsilon"] - 1) < 0.012
    assert np.abs(result.alpha - truth["alpha"]).max() < 0.002
    assert np.abs(result.beta - truth["beta"]).max() < 0.012
    true_cogging = np.asarray(truth["cogging"]["torque"])
    assert np.sqrt(np.mean((result.cogging_nm - true_cogging) ** 2) / np.mean(true_cogging**2)) < 0.012
    true_errors = np.asarray(truth["encoder_error"]["error_counts"])

    def rms(e: np.ndarray) -> float:
        return float(np.sqrt(np.mean(e**2)))

    assert rms(result.encoder_error_counts - true_errors) < 0.9 * rms(true_errors)
    assert rms(mirrored_table(result.encoder_error_counts) - true_errors) > 1.2 * rms(true_errors)
    assert result.encoder_eccentricity_counts == pytest.approx(0.05, rel=0.25)
    phase = result.encoder_eccentricity_phase_rad
    assert abs(phase - 0.7) < abs(phase + 0.7)  # M's phase, not M''s


def turning_log(path: Path, trial: TrialData, turn_counts: float) -> Path:
    """``trial`` logged forward, then turning back over ``turn_counts`` counts: its rows backwards in time."""
    forward = log_rows(trial, reverse=False)
    back = forward[-2:0:-1].copy()
    back[:, 0] = 2 * forward[-1, 0] - back[:, 0]
    back = back[back[:, 1] >= forward[-1, 1] - turn_counts * 2 * np.pi / COUNTS_PER_REV]
    return write_log(path, np.vstack([forward, back]))


@pytest.mark.parametrize(("turn_counts", "expected"), [
    (300.0, r"log.csv: lines \d+-\d+: a reverse lap of 0.29\d revolutions between turns of theta; in a log that "
            r"turns each lap must cover a whole revolution \(a position that dithers, or a partial lap: cut the "
            r"log\)$"),
    # the lap back holds the forward lap's currents at each angle: the motor generating, the mirror's torque < 0
    (3000.0, r"log.csv: lines (\d+)-\d+: the mean torque reference is -2 N m in the direction of motion: give the "
             r"log's operating point in \[\[points\]\] of \S*map.toml$"),
])
def test_a_log_that_turns_refused_in_one_line(tmp_path, small_simulator, make_request, small_model, turn_counts,
                                             expected):
    """A forward lap, then back over ``turn_counts``: a reverse lap shorter than a revolution refused naming its
    lines, and nothing written; a long one that generates refused as such. `import_log` (one log, one trial)
    refuses any log that turns, naming the line."""
    trial = small_simulator.run_trial(make_request(small_model, 2.0, 0.5))
    mapping = read_mapping(mapping_file(tmp_path, small_simulator.backemf_counts))
    log = turning_log(tmp_path / "log.csv", trial, turn_counts)
    with pytest.raises(BenchFormatError, match=expected) as e:
        import_logs([log], mapping, tmp_path / "bench")
    assert "\n" not in str(e.value)
    assert not (tmp_path / "bench").exists() and not (tmp_path / "bench-reverse").exists()
    if turn_counts > COUNTS_PER_REV:
        turn = re.search(expected, str(e.value)).group(1)
        with pytest.raises(BenchFormatError, match=rf"log.csv: line {turn}: theta turns \(2 laps; "
                                                   r"import_laps gives each\)$"):
            import_log(log, mapping)


def test_a_position_that_dithers_or_stands_still_refused(tmp_path, small_simulator, make_request, small_model):
    trial = small_simulator.run_trial(make_request(small_model, 2.0, 0.5))
    mapping = read_mapping(mapping_file(tmp_path, small_simulator.backemf_counts))
    rows = log_rows(trial, reverse=False)
    rows[:, 1] += np.random.default_rng(5).normal(0.0, 0.02, rows.shape[0])  # a noisy angle, 3 counts RMS
    with pytest.raises(BenchFormatError, match=r"log.csv: lines 2-\d+: a (forward|reverse) lap of 0.0\d+ revolutions "
                                               "between turns of theta"):
        import_laps(write_log(tmp_path / "log.csv", rows), mapping)
    rows[:, 1] = 1.0
    with pytest.raises(BenchFormatError, match=r"log.csv: theta never changes \(the motor did not turn\)$"):
        import_laps(write_log(tmp_path / "log.csv", rows), mapping)


def test_a_reverse_folder_that_exists_refused_before_writing(tmp_path, motors):
    """Forward and reverse logs into OUT when OUT-reverse holds a bench already: refused, and neither written."""
    simulator, mirror, requests = motors
    request = dataclasses.replace(requests[0], revolutions=2)
    logs = [write_log(tmp_path / "fwd.csv", log_rows(simulator.run_trial(request), reverse=False)),
            write_log(tmp_path / "rev.csv", log_rows(mirror.run_trial(request), reverse=True))]
    mapping = read_mapping(mapping_file(tmp_path, simulator.backemf_counts))
    (tmp_path / "bench-reverse").mkdir()
    (tmp_path / "bench-reverse" / BENCH_FILE).write_text("")
    with pytest.raises(BenchFormatError, match=r"bench-reverse: holds a bench.toml already \(refused: choose a new "
                                               r"folder\)$"):
        import_logs(logs, mapping, tmp_path / "bench")
    assert not (tmp_path / "bench").exists()
    assert reverse_folder(Path("a/b/")) == Path("a/b-reverse")
    assert reverse_folder(Path(".")) == Path.cwd().with_name(Path.cwd().name + "-reverse")
