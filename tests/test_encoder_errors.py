"""Encoder graduation errors (issue 12): the line model, and where the simulator's samples then fall."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import COUNTS_PER_REV
from hypothesis import given
from hypothesis import strategies as st
from scipy.interpolate import CubicSpline

from ilcpmac.cli import main
from ilcpmac.config import load_config
from ilcpmac.core.errors import ConfigError, SimulationError
from ilcpmac.core.records import TrialData
from ilcpmac.model.encoder import line_errors_counts, line_errors_problem
from ilcpmac.model.motor import MotorModel
from ilcpmac.signals.harmonics import harmonic_amplitudes, synchronous_average
from ilcpmac.sim.simulator import Simulator

ENCODER_KEYS = ("eccentricity_counts", "eccentricity_phase_rad", "line_std_counts", "line_seed")


# ------------------------------------------------ the line model


@pytest.mark.parametrize("seed", [0, 7])
def test_a_perfect_encoder_has_no_error(seed):
    np.testing.assert_array_equal(line_errors_counts(COUNTS_PER_REV, 0.0, 1.3, 0.0, seed), np.zeros(COUNTS_PER_REV))


@given(counts_per_rev=st.integers(4, 4096), eccentricity=st.floats(0.0, 0.49),
       phase=st.floats(-2 * math.pi, 2 * math.pi), line_std=st.floats(0.0, 0.25), seed=st.integers(0, 2**63 - 1))
def test_errors_have_mean_zero_and_are_fixed_by_their_seed(counts_per_rev, eccentricity, phase, line_std, seed):
    errors = line_errors_counts(counts_per_rev, eccentricity, phase, line_std, seed)
    assert errors.shape == (counts_per_rev,)
    assert abs(errors.mean()) < 1e-15
    np.testing.assert_array_equal(errors, line_errors_counts(counts_per_rev, eccentricity, phase, line_std, seed))


@pytest.mark.parametrize("counts_per_rev, eccentricity, phase", [(1024, 0.3, 0.0), (4096, 0.05, -1.2), (7, 0.4, 2.0)])
def test_eccentricity_is_the_sinusoid_exactly(counts_per_rev, eccentricity, phase):
    line = np.arange(counts_per_rev)
    np.testing.assert_allclose(line_errors_counts(counts_per_rev, eccentricity, phase, 0.0, 3),
                               eccentricity * np.sin(2 * np.pi * line / counts_per_rev + phase), rtol=0, atol=1e-15)


def test_random_lines_are_seeded_normal_draws_less_their_mean():
    draws = np.random.default_rng(11).standard_normal(COUNTS_PER_REV)
    errors = line_errors_counts(COUNTS_PER_REV, 0.0, 0.0, 0.1, 11)
    np.testing.assert_allclose(errors, 0.1 * (draws - draws.mean()), rtol=0, atol=1e-16)
    assert errors.std() == pytest.approx(0.1, rel=0.05)
    assert not np.array_equal(errors, line_errors_counts(COUNTS_PER_REV, 0.0, 0.0, 0.1, 12))


@pytest.mark.parametrize("errors, message", [
    (np.zeros(COUNTS_PER_REV - 1), r"line errors must be 1024 real numbers, got shape \(1023,\)"),
    (np.zeros(COUNTS_PER_REV, complex), r"got shape \(1024,\) of complex128"),
    (np.full(COUNTS_PER_REV, np.nan), r"NaN or infinite"),
    (np.full(COUNTS_PER_REV, -np.inf), r"NaN or infinite"),
    (np.where(np.arange(COUNTS_PER_REV) == 9, 0.5, 0.0), r"line 9 errs by 0.5 counts, not within 0.5"),
    (np.where(np.arange(COUNTS_PER_REV) == 3, -1e300, 0.0), r"line 3 errs by -1e\+300 counts"),
])
def test_errors_the_lines_cannot_have(errors, message):
    assert re.search(message, line_errors_problem(errors, COUNTS_PER_REV))


def test_errors_within_half_a_count_are_fine():
    assert line_errors_problem(np.full(COUNTS_PER_REV, 0.4999), COUNTS_PER_REV) is None


# ------------------------------------------------ the config keys


def test_defaults_are_a_perfect_encoder_bit_identical_to_keys_given_as_zero(write_config, make_request):
    given = load_config(write_config({"bench": {"counts_per_rev": COUNTS_PER_REV}}, name="given.toml")).model
    left_out = load_config(write_config({"bench": {"counts_per_rev": COUNTS_PER_REV}}, name="left_out.toml",
                                        drop=[f"simulator.encoder.{key}" for key in ENCODER_KEYS])).model
    assert given == left_out
    assert (left_out.encoder.eccentricity_counts, left_out.encoder.line_std_counts) == (0.0, 0.0)
    a, b = Simulator(given), Simulator(left_out)
    # the lines sit exactly on the integers: the kernel's count is the one it computed before line errors
    np.testing.assert_array_equal(b.lines_counts, np.arange(-1.0, COUNTS_PER_REV + 2))
    request = make_request(given, 2.0, 0.5)
    assert_trials_identical(a.run_trial(request), b.run_trial(request))


@pytest.mark.parametrize("values, message", [
    ({"eccentricity_counts": math.nan}, r"eccentricity_counts: expected a finite number, got nan"),
    ({"eccentricity_counts": math.inf}, r"eccentricity_counts: expected a finite number, got inf"),
    ({"eccentricity_counts": 0.5}, r"eccentricity_counts: invalid value 0.5 .*within \[0, 0.5\)"),
    ({"eccentricity_counts": -0.1}, r"eccentricity_counts: invalid value -0.1"),
    ({"eccentricity_counts": 1e300}, r"eccentricity_counts: invalid value 1e\+300"),
    ({"eccentricity_counts": "0.1"}, r"eccentricity_counts: expected a finite number, got '0.1'"),
    ({"eccentricity_phase_rad": 7.0}, r"eccentricity_phase_rad: invalid value 7.0"),
    ({"line_std_counts": math.nan}, r"line_std_counts: expected a finite number, got nan"),
    ({"line_std_counts": 0.3}, r"line_std_counts: invalid value 0.3 .*within \[0, 0.25\]"),
    ({"line_seed": -1}, r"line_seed: invalid value -1"),
    ({"line_seed": 2**64}, r"line_seed: invalid value 18446744073709551616"),
    ({"line_seed": 1.5}, r"line_seed: expected an integer, got 1.5"),
    ({"eccentricity": 0.1}, r"unknown key 'eccentricity' \(known: timer_resolution_s, eccentricity_counts, "),
])
def test_hostile_encoder_keys_are_one_line_config_errors(write_config, values, message):
    with pytest.raises(ConfigError) as error:
        load_config(write_config({"simulator.encoder": values}))
    assert "\n" not in str(error.value)
    assert re.search(r"\[simulator\.encoder\] " + message, str(error.value)), str(error.value)


#: an eccentricity and random lines each within range, whose sum leaves half a count
TOO_FAR = {"eccentricity_counts": 0.45, "line_std_counts": 0.25}


def test_lines_drawn_beyond_half_a_count_are_a_config_error_naming_the_keys(write_config, tmp_path):
    """Each key within its range, the lines they draw together beyond half a count: refused when the config is
    read (one line naming the file and keys, no folder made), and by the simulator itself if built around it."""
    config = write_config({"bench": {"counts_per_rev": COUNTS_PER_REV}, "simulator.encoder": TOO_FAR})
    with pytest.raises(ConfigError, match=r"campaign.toml: \[simulator.encoder\] eccentricity_counts, line_std_counts, "
                                          r"line_seed: line \d+ errs by -?1\.\d+ counts, not within 0.5"):
        load_config(config)
    result = CliRunner().invoke(main, ["simulate", str(config), "--out", str(tmp_path / "bench")])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert [line for line in result.stderr.splitlines() if line.startswith("error:")] == \
        [line for line in result.stderr.strip().splitlines()]
    assert not (tmp_path / "bench").exists()
    good = load_config(write_config({"bench": {"counts_per_rev": COUNTS_PER_REV}})).model
    bad = dataclasses.replace(good, encoder=dataclasses.replace(good.encoder, **TOO_FAR))
    with pytest.raises(SimulationError, match=r"^model \[encoder\] eccentricity_counts, line_std_counts, line_seed: "):
        Simulator(bad)


# ------------------------------------------------ where the samples fall


def assert_trials_identical(a: TrialData, b: TrialData) -> None:
    for f in dataclasses.fields(TrialData):
        if f.name != "request":
            np.testing.assert_array_equal(getattr(a, f.name), getattr(b, f.name), err_msg=f.name)


@pytest.fixture(scope="module")
def steady_model(ideal_model: MotorModel) -> MotorModel:
    """The ideal drive on a flywheel of 10^4 kg m^2: its speed varies by less than 1e-6 over a trial."""
    return dataclasses.replace(ideal_model, mechanics=dataclasses.replace(ideal_model.mechanics, inertia_kgm2=1e4))


def with_lines(model: MotorModel, **encoder) -> MotorModel:
    return dataclasses.replace(model, encoder=dataclasses.replace(model.encoder, **encoder))


@pytest.fixture(scope="module")
def perfect_trials(steady_model, make_request) -> dict[float, TrialData]:
    """The steady drive with a perfect encoder, by speed set point, Hz."""
    simulator = Simulator(steady_model)
    return {speed: simulator.run_trial(make_request(steady_model, 2.0, speed)) for speed in (0.5, 1.0)}


def deviation_from_uniform_s(trial: TrialData, late_s: np.ndarray) -> np.ndarray:
    """What is left of the time stamps less ``late_s`` once a smooth run (a parabola against count) is removed."""
    left = trial.time_s - late_s
    return left - np.polynomial.Polynomial.fit(trial.count, left, 2)(trial.count)


#: encoders with errors: [simulator.encoder] keys
ENCODERS = [
    {"eccentricity_counts": 0.3, "eccentricity_phase_rad": math.pi / 2},   # line 0 late: crossed after the wrap
    {"eccentricity_counts": 0.3, "eccentricity_phase_rad": -math.pi / 2},  # line 0 early: crossed before it
    {"eccentricity_counts": 0.1, "eccentricity_phase_rad": 0.4, "line_std_counts": 0.1, "line_seed": 5},
]


@pytest.mark.parametrize("encoder", ENCODERS)
def test_each_sample_comes_when_its_line_is_crossed(steady_model, perfect_trials, make_request, encoder):
    """Count c is stamped e_c / (counts_per_rev f) late against a uniform run, within the 1 us timer's 0.5 us."""
    model = with_lines(steady_model, **encoder)
    trial = Simulator(model).run_trial(make_request(model, 2.0, 0.5))
    np.testing.assert_array_equal(trial.count, np.arange(2 * COUNTS_PER_REV))  # every line, in order
    errors = model.encoder.line_errors_counts()[trial.count % COUNTS_PER_REV]
    speed_hz = trial.speed_true_rad_s / (2 * np.pi)
    np.testing.assert_array_less(np.abs(deviation_from_uniform_s(trial, errors / (COUNTS_PER_REV * speed_hz))),
                                 0.6e-6)
    # without the lines' errors the run is not uniform: they are as large as they should be
    assert np.abs(deviation_from_uniform_s(trial, 0.0)).max() > 0.8 * np.abs(errors).max() / (COUNTS_PER_REV * 0.5)
    # a perfect encoder's run is uniform
    np.testing.assert_array_less(np.abs(deviation_from_uniform_s(perfect_trials[0.5], 0.0)), 0.6e-6)
    # the controller reads the measured count: the reference of line c is sampled with line c
    np.testing.assert_array_equal(trial.i_ref_a, perfect_trials[0.5].i_ref_a)


@pytest.mark.parametrize("encoder", ENCODERS)
def test_each_sample_holds_the_state_at_its_line(ideal_model, small_model, make_request, encoder):
    """The recorded speed is the speed at the line's true angle, where cogging makes it vary 19 % pp."""
    cogged = dataclasses.replace(ideal_model, cogging=small_model.cogging)
    perfect = Simulator(cogged).run_trial(make_request(cogged, 2.0, 0.5))
    speed_at = CubicSpline(perfect.count, perfect.speed_true_rad_s)
    model = with_lines(cogged, **encoder)
    trial = Simulator(model).run_trial(make_request(model, 2.0, 0.5))
    line_counts = trial.count + model.encoder.line_errors_counts()[trial.count % COUNTS_PER_REV]
    inner = slice(1, -1)  # the spline extrapolates beyond the first and last count
    # within 0.25 %: samples a step after the crossing, the torque of commutation on the measured count;
    # 1 % when a line crossed early is seen only at its nominal position
    np.testing.assert_array_less(np.abs(trial.speed_true_rad_s - speed_at(line_counts))[inner], 0.0025 * np.pi)
    assert np.abs(trial.speed_true_rad_s - perfect.speed_true_rad_s).max() > 0.005 * np.pi  # and it matters


def apparent_speed_harmonics(trial: TrialData) -> np.ndarray:
    """Harmonics 0 and 1 of the apparent speed (one count over the time between two samples), rad / s."""
    apparent = 2 * np.pi / COUNTS_PER_REV / np.diff(trial.time_s)
    return harmonic_amplitudes(synchronous_average(trial.count[:-1], apparent, COUNTS_PER_REV), 1)


def test_eccentricity_ripples_the_apparent_speed_once_per_revolution(steady_model, perfect_trials, make_request):
    """E 2 pi / counts_per_rev relative at any speed (first order), so growing with speed in rad / s."""
    eccentricity = 0.3
    model = with_lines(steady_model, eccentricity_counts=eccentricity)
    simulator = Simulator(model)
    step_rad = 2 * np.pi / COUNTS_PER_REV
    # count c's interval spans e_(c+1) - e_c = E step cos(theta_c + step / 2) more: the apparent speed dips
    expected = -eccentricity * step_rad * np.exp(0.5j * step_rad)
    absolute = {}
    for speed_hz, perfect in perfect_trials.items():
        mean, ripple = apparent_speed_harmonics(simulator.run_trial(make_request(model, 2.0, speed_hz)))
        assert abs(ripple / mean - expected) < 0.02 * abs(expected), speed_hz
        assert mean.real == pytest.approx(2 * np.pi * speed_hz, rel=1e-3)
        absolute[speed_hz] = abs(ripple)
        perfect_mean, perfect_ripple = apparent_speed_harmonics(perfect)
        assert abs(perfect_ripple / perfect_mean) < 0.01 * abs(expected)
    assert absolute[1.0] / absolute[0.5] == pytest.approx(2.0, rel=0.02)
