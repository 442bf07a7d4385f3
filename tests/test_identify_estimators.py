"""Each estimator against data with an exact known answer."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from ilcpmac.core.current_loop import CurrentLoop, lagged
from ilcpmac.core.records import MotorInfo, SensorCalibration
from ilcpmac.identify import corrected_calibration
from ilcpmac.identify.decoupling import cogging_band, decouple
from ilcpmac.identify.joint import time_shifted
from ilcpmac.identify.reduction import BenchTables, TrialTables, trial_amplitudes
from ilcpmac.identify.sensor_gain import TrialResponse, fit_inertia
from ilcpmac.identify.system_gain import excluded_harmonics
from ilcpmac.pipeline.analysis import TorqueSpectrum
from ilcpmac.signals.harmonics import (
    harmonic_amplitudes,
    linear_trend,
    revolution_harmonics,
    revolution_table,
    slow_trend,
    synchronous_table,
    table_from_amplitudes,
)

CPR = 512


def test_lag_recursion_matches_its_constant_speed_response():
    """The count recursion (staircase through a first-order lag) equals its z-domain response."""
    speed_hz, h = 0.8, 37
    theta = 2 * np.pi * np.arange(CPR) / CPR
    x = np.repeat(np.cos(h * theta + 0.3)[None, :, None], 3, axis=2)
    dt = np.full((1, CPR), 1.0 / (CPR * speed_hz))
    for delay in (0.0, 40e-6, -20e-6):
        loop = CurrentLoop(np.array([5e-4, 1e-3, 2e-3]), delay)
        amplitude = trial_amplitudes(lagged(x, dt, loop), h)[0, h]
        expected = loop.response(np.array([h]), speed_hz, CPR)[0] * np.exp(0.3j)
        np.testing.assert_allclose(amplitude, expected, rtol=1e-9, atol=1e-12)


def test_continuous_lag_is_a_first_order_lag():
    """A smooth input (here 100 counts per period) through the linear-between-counts recursion."""
    speed_hz, h = 1.0, 5
    theta = 2 * np.pi * np.arange(CPR) / CPR
    x = np.repeat(np.sin(h * theta)[None, :, None], 3, axis=2)
    dt = np.full((1, CPR), 1.0 / (CPR * speed_hz))
    tau = 5e-3
    amplitude = trial_amplitudes(lagged(x, dt, CurrentLoop(np.full(3, tau), 0.0), continuous=True), h)[0, h, 0]
    w = 2 * np.pi * h * speed_hz
    assert amplitude == pytest.approx(-1j / (1 + 1j * w * tau), rel=1e-3)


def test_ideal_loop_returns_the_references():
    x = np.random.default_rng(0).standard_normal((2, CPR, 3))
    np.testing.assert_array_equal(lagged(x, np.full((2, CPR), 1e-3), CurrentLoop()), x)


def test_time_shift_of_a_sine_with_speed_ripple():
    period = 1.0 + 0.3 * np.sin(2 * np.pi * 3 * np.arange(CPR) / CPR)
    dt = (period / period.sum())[None, :]
    t = np.concatenate([[0.0], np.cumsum(dt[0])[:-1]])
    signal = lambda time: np.cos(2 * np.pi * 5 * time)  # noqa: E731
    for shift in (3e-4, -5e-4):
        np.testing.assert_allclose(time_shifted(signal(t)[None], dt, shift)[0], signal(t + shift), atol=1e-6)


def test_slow_trend_recovers_a_drift_beside_periodic_content():
    revolutions = 5
    count = np.arange(revolutions * CPR)
    time = count * 1e-3
    periodic = np.sin(2 * np.pi * 3 * count / CPR) + 0.2 * np.cos(2 * np.pi * 7 * count / CPR)
    drift = 0.4 * (time - time.mean())
    noise = 0.01 * np.random.default_rng(1).standard_normal(count.size)
    trend, variance = slow_trend(count, time, periodic + drift + noise, CPR, 2)
    np.testing.assert_allclose(trend - trend.mean(), drift - drift.mean(), atol=2e-3)
    assert variance == pytest.approx(1e-4, rel=0.1)


def test_synchronous_table_fills_unsampled_counts():
    count = np.concatenate([np.arange(0, CPR, 2), np.arange(CPR, 2 * CPR, 2)])  # odd counts never sampled
    values = np.cos(2 * np.pi * count / CPR)
    table = synchronous_table(count, values, CPR)
    np.testing.assert_allclose(table, np.cos(2 * np.pi * np.arange(CPR) / CPR), atol=1e-4)


def _skipping_trial(skipped: list[int], revolutions: int = 3, cpr: int = 64):
    """Counts over whole revolutions with ``skipped`` counts (indices into them) left out, and two torques."""
    count = np.delete(np.arange(5 * cpr, (5 + revolutions) * cpr), skipped)
    rng = np.random.default_rng(len(skipped))
    time_s = count * 1e-3 + 1e-5 * rng.standard_normal(count.size)
    theta = 2 * np.pi * count / cpr
    torques = [2.0 + 0.3 * time_s + np.sin(3 * theta) + 0.1 * rng.standard_normal(count.size),
               1.0 + 0.5 * np.cos(5 * theta + 0.2) + 0.01 * rng.standard_normal(count.size)]
    return count, time_s, torques, cpr


@given(st.lists(st.integers(0, 3 * 64 - 1).filter(lambda i: 0 < i % 64 < 63), max_size=20, unique=True))
def test_revolution_table_holds_the_samples_and_interpolates_skipped_counts(skipped):
    """A ramp in position is linear between any two sampled counts of a revolution (the first and last count
    of each are kept: no wrap-around): the fill reproduces it, and the samples stay where they are."""
    count, _, _, cpr = _skipping_trial(skipped)
    ramp = np.stack([count % cpr, -2.0 * (count % cpr)]).astype(float)
    table = revolution_table(count, ramp, cpr)
    assert table.shape == (2, 3, cpr)
    expected = np.arange(cpr) * np.array([1.0, -2.0])[:, None, None]
    np.testing.assert_allclose(table, np.broadcast_to(expected, table.shape), atol=1e-12)
    assert np.shares_memory(table, ramp) == (not skipped)


@pytest.mark.parametrize("skipped", [[], [7, 8, 9, 100]])
def test_spectra_of_a_stack_equal_each_spectrum_alone(skipped):
    """One pass over both torques (shared mask, table and FFT) gives what one pass per torque gives, bit for bit."""
    count, time_s, torques, cpr = _skipping_trial(skipped)
    together = TorqueSpectrum.of_each(count, time_s, torques, cpr, 12)
    for spectrum, torque in zip(together, torques):
        alone = TorqueSpectrum.of(count, time_s, torque, cpr, 12)
        np.testing.assert_array_equal(spectrum.harmonics_nm, alone.harmonics_nm)
        np.testing.assert_array_equal(spectrum.variance_nm2, alone.variance_nm2)
        assert spectrum.rest_rms_nm == alone.rest_rms_nm
        # and what the definitions give sample by sample: detrend, average per revolution, subtract
        detrended = torque - linear_trend(time_s, torque)
        harmonics, variance = revolution_harmonics(count, detrended, cpr, 12)
        np.testing.assert_allclose(spectrum.harmonics_nm, harmonics, rtol=0, atol=1e-12)
        rest = detrended - spectrum.ripple_table()[count % cpr]
        assert spectrum.rest_rms_nm == pytest.approx(np.std(rest), rel=1e-12)
    assert together[0].harmonics_nm[3] == pytest.approx(-1j, abs=0.05)  # sin(3 theta)
    assert together[1].harmonics_nm[5] == pytest.approx(0.5 * np.exp(0.2j), abs=0.01)


def test_linear_trend_of_a_stack_is_each_line_s_trend():
    x = np.linspace(0.0, 2.0, 101)
    lines = np.stack([3.0 + 0.5 * x, -1.0 - 2.0 * x + np.sin(7 * x)])
    trend = linear_trend(x, lines)
    np.testing.assert_array_equal(trend, np.stack([linear_trend(x, line) for line in lines]))
    np.testing.assert_allclose(trend[0], lines[0], atol=1e-12)


def test_harmonic_amplitudes_along_any_axis():
    table = np.random.default_rng(5).standard_normal((4, 32, 3))
    along_counts = harmonic_amplitudes(np.moveaxis(table, 1, 0), 9)
    np.testing.assert_array_equal(harmonic_amplitudes(table, 9, axis=1), np.moveaxis(along_counts, 0, 1))
    np.testing.assert_array_equal(harmonic_amplitudes(table[..., 0], None, axis=-1),
                                  harmonic_amplitudes(table[..., 0].T).T)


@pytest.mark.parametrize("start", [0, 3 * CPR, 5])
def test_synchronous_table_of_whole_revolutions_is_the_per_count_mean(start):
    """Whole revolutions sampled at every count (averaged as revolutions) or not from a revolution's start
    (summed per count): the same numbers as summing per count."""
    count = np.arange(start, start + 3 * CPR)
    values = np.random.default_rng(start).standard_normal((count.size, 2))
    hits = np.bincount(count % CPR, minlength=CPR)[:, None]
    expected = np.stack([np.bincount(count % CPR, weights=v, minlength=CPR) for v in values.T], axis=1) / hits
    np.testing.assert_array_equal(synchronous_table(count, values, CPR), expected)
    np.testing.assert_array_equal(synchronous_table(count, values[:, 1], CPR), expected[:, 1])


def test_excluded_harmonics_are_multiples_of_pole_pairs_and_cogging_order():
    h = np.arange(1, 50)
    excluded = excluded_harmonics(h, 8, 48)
    assert set(h[excluded]) == {8, 16, 24, 32, 40, 48}


def test_decoupling_recovers_alpha_and_beta_exactly():
    """Noise-free eq. (1.3) data: the pseudo-inverse (eq. 1.12) returns alpha* and beta* (eq. 1.11)."""
    rng = np.random.default_rng(2)
    theta = 2 * np.pi * np.arange(CPR) / CPR
    # a third harmonic makes the common offset of the three phases observable
    electrical = [4 * theta - 2 * np.pi * p / 3 for p in range(3)]
    backemf = np.column_stack([0.2 * np.sin(x) + 0.02 * np.sin(3 * x) for x in electrical])
    delta, epsilon = 0.9, 0.7
    alpha, beta = np.array([0.95, 1.0, 1.05]), np.array([0.2, -0.1, 0.05])
    cogging = 0.05 * np.sin(48 * theta)  # order lcm(48, 8); the columns reach harmonic 34
    trials = []
    for torque in (1.0, 2.0):
        reference = torque * (1 + 0.02 * np.cos(np.outer(theta, np.arange(1, 11)) + rng.uniform(0, 6, 10)).sum(1))
        i_ref = reference[:, None] * backemf / np.sum(backemf**2, axis=1, keepdims=True)
        measured = delta * (np.sum(backemf * (epsilon * alpha * i_ref + beta), axis=1) + cogging)
        trials.append(TrialTables(torque, 1.0, 1.0, 2, np.arange(2), np.arange(2.0), np.zeros(2), measured, i_ref,
                                  np.full(CPR, 1e-3), 1e-4, 1e-8))
    tables = BenchTables(MotorInfo(4, 48, CPR, 0.01), backemf, tuple(trials), ("a", "b"), ())
    result = decouple(tables, delta * epsilon)
    np.testing.assert_allclose(result.alpha(), alpha, atol=1e-5)
    np.testing.assert_allclose(result.beta_star_mean() / delta, beta, atol=1e-5)
    np.testing.assert_allclose(result.mean_cogging_nm() / delta, cogging, atol=1e-5)


def test_cogging_band_keeps_only_multiples_of_the_order():
    theta = 2 * np.pi * np.arange(CPR) / CPR
    table = np.sin(24 * theta) + np.cos(48 * theta) + np.sin(20 * theta)
    np.testing.assert_allclose(cogging_band(table, 24), np.sin(24 * theta) + np.cos(48 * theta), atol=1e-12)


def test_table_from_amplitudes_builds_the_cosines():
    theta = 2 * np.pi * np.arange(CPR) / CPR
    amplitudes = np.zeros(11, complex)
    amplitudes[[0, 3, 10]] = 0.25, 0.5 - 0.2j, 1.0
    np.testing.assert_allclose(table_from_amplitudes(amplitudes, CPR),
                               0.25 + 0.5 * np.cos(3 * theta) + 0.2 * np.sin(3 * theta) + np.cos(10 * theta),
                               atol=1e-12)


@pytest.mark.parametrize("n_points", [7, 8, 64, 65])
def test_table_from_amplitudes_inverts_harmonic_amplitudes(n_points):
    """Mean, every harmonic and the Nyquist one, for even and odd lengths, one or more columns."""
    table = np.random.default_rng(n_points).standard_normal((n_points, 3))
    np.testing.assert_allclose(table_from_amplitudes(harmonic_amplitudes(table), n_points), table, atol=1e-12)
    np.testing.assert_allclose(table_from_amplitudes(harmonic_amplitudes(table[:, 0]), n_points), table[:, 0],
                               atol=1e-12)


def test_inertia_fit_recovers_j_and_b():
    """An exact response J s + b with unit-ish coherence gives J and b back."""
    frequency = np.arange(1, 100) * 0.7
    response = 0.3 + 2j * np.pi * frequency * 0.0123
    j, j_std, b = fit_inertia(TrialResponse(frequency, response, np.full(frequency.size, 0.99), 8))
    assert j == pytest.approx(0.0123, rel=1e-12)
    assert b == pytest.approx(0.3, rel=1e-12)
    assert j_std > 0


def test_corrected_calibration_inverts_eqs_1_4_to_1_7():
    start = SensorCalibration([14.0, 14.0, 14.0], [1.0, 0.0, -1.0], 0.9)
    epsilon, alpha, beta, delta = 0.7, np.array([0.9, 1.0, 1.1]), np.array([0.5, -0.2, 0.1]), 0.8
    fixed = corrected_calibration(start, epsilon, alpha, beta, delta)
    # the true sensor: G*_s^-1 G_s = eps alpha and beta = G_s (o_s - o*_s)
    np.testing.assert_allclose(start.current_scale / fixed.current_scale, epsilon * alpha)
    np.testing.assert_allclose((fixed.current_offset - start.current_offset) / fixed.current_scale, beta)
    assert fixed.torque_gain == pytest.approx(delta * start.torque_gain)
