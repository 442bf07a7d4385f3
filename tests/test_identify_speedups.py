"""The identification's fast paths against the slow ones they replace: analytic derivatives against finite
differences, numpy spectra against scipy.signal, scipy.special quantiles against scipy.stats."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ilcpmac.core.current_loop import CurrentLoop, count_decay, lagged_phase, sample_decay
from ilcpmac.core.records import MotorInfo
from ilcpmac.core.torque_source import TorqueSource
from ilcpmac.identify.joint import _JointProblem, _lag_derivatives, _tall_product, harmonic_sets, time_shifted
from ilcpmac.identify.reduction import BenchTables, TrialTables, revolution_averages, trial_amplitudes
from ilcpmac.identify.sensor_gain import trial_response
from ilcpmac.identify.system_gain import chi2_quantile
from ilcpmac.signals.harmonics import not_a_knot_spline, uniform_time_resample

CPR = 256


def _count_periods(rng: np.random.Generator, n_trials: int, speed_hz: float = 2.0) -> np.ndarray:
    """Count periods with a speed ripple, s, shape (n_trials, CPR)."""
    theta = 2 * np.pi * np.arange(CPR) / CPR
    ripple = 1.0 + 0.1 * np.sin(3 * theta[None] + rng.uniform(0, 6, (n_trials, 1))) + 0.02 * rng.random((n_trials, CPR))
    return ripple / ripple.sum(axis=1, keepdims=True) / speed_hz


@pytest.mark.parametrize("continuous", [False, True])
@pytest.mark.parametrize("tau, delay", [(2e-3, 3e-4), (2e-3, -4e-4), (1.5e-3, 0.0), (5e-4, 3e-3), (0.0, 2e-4)])
def test_lag_derivatives_match_finite_differences(continuous, tau, delay):
    """d/dtau and d/dT_d of `lagged_phase` (staircase and continuous, either sign of the delay, no lag)."""
    rng = np.random.default_rng(3)
    dt = _count_periods(rng, 2, speed_hz=4.0)
    x = rng.standard_normal((2, CPR))
    decay = count_decay(dt, tau)
    d_tau, d_delay = np.empty(x.shape), np.empty(x.shape)
    _lag_derivatives(x, dt, tau, delay, decay, decay if continuous else sample_decay(dt, tau, delay), continuous,
                     d_tau, d_delay)

    def lag(t: float, d: float) -> np.ndarray:
        return lagged_phase(x, dt, t, d, continuous)

    step = 1e-7 * max(tau, 1e-3)
    expected_tau = ((lag(tau + step, delay) - lag(tau - step, delay)) / (2 * step) if tau > 0
                    else (lag(step, delay) - lag(0.0, delay)) / step)
    step = 1e-9
    expected_delay = ((lag(tau, delay + step) - lag(tau, delay - step)) / (2 * step) if delay != 0
                      else (lag(tau, step) - lag(tau, 0.0)) / step)  # T_d = 0: the derivative from above
    np.testing.assert_allclose(d_tau, expected_tau, atol=1e-6 * max(np.abs(expected_tau).max(), 1.0))
    np.testing.assert_allclose(d_delay, expected_delay, atol=1e-4 * max(np.abs(expected_delay).max(), 1.0))


@pytest.mark.parametrize("shift", [3e-4, -2e-4, 0.0])
def test_time_shift_slope_is_the_derivative_in_the_shift(shift):
    rng = np.random.default_rng(4)
    dt = _count_periods(rng, 2)
    tables = np.cos(2 * np.pi * 5 * np.arange(CPR) / CPR + rng.uniform(0, 6, (2, 1)))
    step = 1e-9
    # at a count instant (shift 0) the piecewise cubic has a kink: the slope is the one towards later instants
    before = shift - step if shift != 0 else shift
    expected = (time_shifted(tables, dt, shift + step) - time_shifted(tables, dt, before)) / (shift + step - before)
    np.testing.assert_allclose(time_shifted(tables, dt, shift, slope=True), expected,
                               atol=1e-4 * np.abs(expected).max())


def _tables(rng: np.random.Generator, source: str, symmetric: bool = False) -> BenchTables:
    """Three trials of random multisine references and torque on a 2-pole-pair motor (cogging order 12);
    ``symmetric``: back-EMFs that sum to zero (the common current offset not identified)."""
    theta = 2 * np.pi * np.arange(CPR) / CPR
    electrical = [2 * theta - 2 * np.pi * p / 3 for p in range(3)]
    backemf = np.column_stack([0.2 * np.sin(x) if symmetric else
                               (0.2 + 0.01 * p) * np.sin(x) + 0.02 * np.sin(3 * x + 0.3)
                               for p, x in enumerate(electrical)])
    trials = []
    for k, dt in enumerate(_count_periods(rng, 3)):
        reference = (1.0 + k) * (1 + 0.05 * np.cos(np.outer(theta, np.arange(1, 15)) + rng.uniform(0, 6, 14)).sum(1))
        i_ref = reference[:, None] * backemf / np.sum(backemf**2, axis=1, keepdims=True)
        torque = np.sum(backemf * i_ref, axis=1) + 0.01 * rng.standard_normal(CPR)
        speed = 2 * np.pi / (CPR * dt)
        extra = {} if source == "sensor" else dict(harmonic_variances_nm2=np.full(CPR // 2 + 1, 1e-6),
                                                   speed_table_rad_s=speed, viscous_nm_s=0.01)
        trials.append(TrialTables(1.0 + k, 2.0, 1.0 / dt.sum(), 2, np.arange(2), np.arange(2.0), np.zeros(2), torque,
                                  i_ref, dt, 1e-4, 1e-6, **extra))
    return BenchTables(MotorInfo(2, 12, CPR, 0.01, source == "sensor"), backemf, tuple(trials), ("a", "b", "c"), (),
                       TorqueSource(source))


@pytest.mark.parametrize("source, symmetric", [("sensor", False), ("encoder", False), ("sensor", True)])
def test_joint_jacobian_matches_finite_differences(source, symmetric):
    """The variable-projection Jacobian of the joint fit's residual and the fixed-x derivatives of the covariance,
    at a random point (every nonlinear parameter active), against central differences."""
    rng = np.random.default_rng(5)
    tables = _tables(rng, source, symmetric)
    problem = _JointProblem(tables, harmonic_sets(tables))
    assert problem.common_offset is not symmetric
    phi = np.array([*rng.uniform(3e-4, 1e-3, 3), 2e-5, 0.05, 2e-3, 4e-6])
    saturation = problem.saturation_column(phi, problem.solve(phi, None)[0])
    active = np.ones(7, bool)
    x, rest = problem.solve(phi, saturation)
    jacobian = problem.jacobian(phi, saturation, active)
    fixed, products = problem.sensitivities(phi, saturation, x, rest, active)
    for i, scale in enumerate([1e-3, 1e-3, 1e-3, 1e-4, 0.05, 1e-3, 1e-5]):
        step = 1e-5 * scale
        up, down = phi.copy(), phi.copy()
        up[i] += step
        down[i] -= step
        expected = (problem.solve(up, saturation)[1] - problem.solve(down, saturation)[1]) / (2 * step)
        size = max(np.linalg.norm(expected), 1e-300)
        assert np.linalg.norm(jacobian[:, i] - expected) <= 1e-5 * size + 1e-12, problem.sets.fit
        at_x = [y - d @ x for y, d in (problem.weighted(p, problem.design(p, saturation)) for p in (up, down))]
        expected = (at_x[0] - at_x[1]) / (2 * step)
        assert np.linalg.norm(fixed[:, i] - expected) <= 1e-5 * max(np.linalg.norm(expected), 1e-300) + 1e-12
        columns = [problem.weighted(p, problem.design(p, saturation))[1] for p in (up, down)]
        np.testing.assert_allclose(products[:, i], (columns[0] - columns[1]).T @ rest / (2 * step),
                                   atol=1e-5 * max(np.abs(products[:, i]).max(), 1e-300))
    if source == "encoder":  # no sensor: neither its high-pass nor its delay acts, and the fit leaves them out
        assert not jacobian[:, [4, 6]].any()
        assert not problem.identifiable[[4, 6]].any() and problem.identifiable.sum() == 5


def test_the_joint_problem_keeps_each_result_for_its_own_parameters():
    """The data and their slope in the torque's delay (computed together, the last shift kept) and the loop's
    derivatives (kept for the Gauss-Newton step) at one point after another equal a fresh problem's there."""
    tables = _tables(np.random.default_rng(10), "sensor")
    sets = harmonic_sets(tables)
    problem = _JointProblem(tables, sets)
    start = np.array([5e-4, 6e-4, 7e-4, 2e-5, 0.05, 2e-3, 4e-6])
    points = [start]
    for i, step in zip((0, 1, 2, 3, 5, 6), (1e-5, 1e-5, 1e-5, 3e-6, 1e-4, 2e-6)):
        point = start.copy()
        point[i] += step
        points += [point, start]
    for phi in points:
        fresh = _JointProblem(tables, sets)
        np.testing.assert_array_equal(problem.data_slope(phi), fresh.data_slope(phi))
        np.testing.assert_array_equal(problem.data(phi), fresh.data(phi))
        np.testing.assert_array_equal(problem.loop_derivatives(phi), fresh.loop_derivatives(phi))
    instants_table = np.stack([t.torque_table_nm for t in tables.trials])
    dt = np.stack([t.count_period_s for t in tables.trials])
    expected = trial_amplitudes(time_shifted(instants_table, dt, start[6], slope=True)[:, :, None],
                                problem.max_harmonic)[:, :, 0]
    np.testing.assert_array_equal(problem.data_slope(start), expected)


def test_the_loop_response_over_speeds_is_the_response_at_each_speed():
    """`CurrentLoop.response` at an array of speeds: the same numbers as one speed at a time, either sign of the
    delay."""
    h, speeds = np.arange(1, 40), np.array([0.5, 0.75, 1.3])
    for loop in (CurrentLoop(np.array([5e-4, 6e-4, 7e-4]), 2e-5), CurrentLoop(np.full(3, 8e-4), -1e-5),
                 CurrentLoop()):
        together = loop.response(h, speeds, CPR)
        assert together.shape == (3, h.size, 3)
        np.testing.assert_array_equal(together, np.stack([loop.response(h, f, CPR) for f in speeds]))


@pytest.mark.parametrize("first", [0, 5])
def test_revolution_averages_give_the_count_periods_of_a_rippling_speed(first):
    """Every count of three revolutions sampled, from a revolution's start (the index a revolution later
    taken directly) or not (searched): the speed ripple's count periods and the mean speed, as recorded."""
    rng = np.random.default_rng(11)
    dt = _count_periods(rng, 1, speed_hz=2.0)[0]
    count = first + np.arange(3 * CPR)
    time_s = np.concatenate([[0.0], np.cumsum(np.roll(np.tile(dt, 3), -first))[:-1]])
    speed_hz, i_ref, count_period_s = revolution_averages(count, time_s, np.ones((count.size, 3)), CPR)
    assert speed_hz == pytest.approx(2.0, rel=1e-12)
    np.testing.assert_allclose(count_period_s, dt, rtol=1e-9)
    np.testing.assert_array_equal(i_ref, np.ones((CPR, 3)))


def test_tall_product_is_the_matrix_product():
    rng = np.random.default_rng(6)
    tall, narrow = rng.standard_normal((500, 8)), rng.standard_normal((8, 7))
    np.testing.assert_allclose(_tall_product(tall, narrow), tall @ narrow, rtol=1e-13, atol=1e-13)
    np.testing.assert_array_equal(_tall_product(tall, np.eye(8)), tall)


def test_trial_response_equals_scipy_signal_csd_and_welch():
    from scipy import signal

    rng = np.random.default_rng(7)
    revolutions, H = 4, 10
    count = np.arange(revolutions * CPR)
    dt = np.tile(_count_periods(rng, 1)[0], revolutions)
    time = np.concatenate([[0.0], np.cumsum(dt)[:-1]])
    torque = np.sin(2 * np.pi * 3 * count / CPR) + 0.1 * rng.standard_normal(count.size)
    trial = TrialTables(1.0, 2.0, 2.0, revolutions, count, time, torque, np.zeros(CPR), np.ones((CPR, 3)), dt[:CPR],
                        1e-2, 1e-4)
    tables = BenchTables(MotorInfo(2, 12, CPR, 0.01), np.ones((CPR, 3)), (trial,), ("a",), ())
    response = trial_response(tables, 0, H)
    samples_per_rev = int(2 ** np.ceil(np.log2(4 * H + 4)))
    t, _, omega, resampled = uniform_time_resample(time, count, torque, CPR, samples_per_rev)
    options = dict(fs=1.0 / (t[1] - t[0]), window="boxcar", nperseg=samples_per_rev, noverlap=0, detrend=False)
    frequency, p_xy = signal.csd(omega, resampled, **options)
    p_xx, p_yy = signal.welch(omega, **options)[1], signal.welch(resampled, **options)[1]
    h = slice(1, H + 1)
    np.testing.assert_allclose(response.frequency_hz, frequency[h], rtol=1e-14)
    np.testing.assert_allclose(response.response, p_xy[h] / p_xx[h], rtol=1e-10)
    np.testing.assert_allclose(response.coherence, np.abs(p_xy[h]) ** 2 / (p_xx[h] * p_yy[h]), rtol=1e-10)
    assert response.revolutions == t.size // samples_per_rev


@pytest.mark.parametrize("n", [3, 4, 500])
def test_not_a_knot_spline_equals_scipy_cubic_spline(n):
    from scipy.interpolate import CubicSpline

    rng = np.random.default_rng(8)
    x = np.cumsum(1e-3 * (1 + 0.5 * rng.random(n)))
    y = np.stack([np.cumsum(rng.random(n)), rng.standard_normal(n)], axis=1)
    at = np.linspace(x[0] - 1e-3, x[-1] + 2e-3, 333)  # beyond the ends too
    value, slope = not_a_knot_spline(x, y, at)
    spline = CubicSpline(x, y)
    np.testing.assert_allclose(value, spline(at), rtol=1e-12, atol=1e-12 * np.abs(y).max())
    np.testing.assert_allclose(slope, spline(at, 1), rtol=1e-12, atol=1e-12 * np.abs(spline(at, 1)).max())


def test_quantiles_from_scipy_special_equal_scipy_stats():
    from scipy import special, stats

    for dof in (1.0, 2.5, 7.3, 100.0, 9517.3):
        for probability in (0.99, 0.999):
            assert chi2_quantile(probability, dof) == stats.chi2.ppf(probability, dof)
    for n in range(1, 60):  # encoder_torque's beta quantiles of the median of n
        k = (n + 1) // 2
        np.testing.assert_array_equal(special.betaincinv(k, n + 1 - k, [0.999, 0.5]),
                                      stats.beta.ppf([0.999, 0.5], k, n + 1 - k))


def test_identification_does_not_import_scipy_stats():
    """scipy.stats takes about 1 s to import: identifying a bench (the tests' small one) does without it."""
    script = textwrap.dedent("""
        import sys
        sys.path.insert(0, "tests")
        from identify_helpers import other_bench
        from ilcpmac.identify import identify_bench
        result = identify_bench(other_bench()[0])
        print(result.delta_epsilon is not None, "scipy.stats" in sys.modules)
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          cwd=Path(__file__).resolve().parents[1])
    assert done.stdout.split() == ["True", "False"], done.stderr


def test_trial_amplitudes_of_the_derivatives_are_linear():
    """The Jacobian transforms each derivative table alone (`_JointProblem.loop_derivatives`): the same
    amplitudes as a stack of them."""
    rng = np.random.default_rng(9)
    tables = rng.standard_normal((3, CPR, 4))
    stacked = trial_amplitudes(tables, 20)
    alone = np.concatenate([trial_amplitudes(tables[:, :, [j]], 20) for j in range(4)], axis=2)
    np.testing.assert_allclose(alone, stacked, rtol=1e-12, atol=1e-15)


@given(st.integers(0, 5000), st.lists(st.integers(1, 3), min_size=1, max_size=400), st.sampled_from([16, 64]))
@settings(max_examples=200, deadline=None)
def test_the_whole_revolutions_span_selects_what_the_per_sample_rule_selects(start, steps, counts_per_rev):
    """A sample is in a whole revolution when its revolution is covered from its first to its last count; for a
    strictly increasing count those samples are one contiguous run, which the slice selects without a copy."""
    from ilcpmac.signals.harmonics import whole_revolution_span

    count = start + np.concatenate([[0], np.cumsum(steps)])
    rev = count // counts_per_rev
    first = rev[0] + (count[0] > rev[0] * counts_per_rev)
    last = rev[-1] - (count[-1] < (rev[-1] + 1) * counts_per_rev - 1)
    expected = (rev >= first) & (rev <= last)
    span = whole_revolution_span(count, counts_per_rev)
    np.testing.assert_array_equal(np.arange(count.size)[span], np.flatnonzero(expected))
