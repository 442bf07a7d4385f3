"""The torque ripple from the encoder's time stamps against synthetic trials with a known truth.

Crossing times come from the mechanics J omega domega/dtheta = tau(theta) - b omega in the position
domain: the exact periodic steady state (any b, `_steady_trial`) or, for b = 0, the closed form of
omega^2 with a constant net torque that makes the speed drift (`_drifting_trial`).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from ilcpmac.core.current_loop import CurrentLoop
from ilcpmac.signals.encoder_torque import (
    EncoderTorqueSpectrum,
    count_speeds,
    encoder_error_table,
    quantisation_variance_nm2,
    separate_encoder_error,
    staircase_bias,
    without_encoder_error,
    without_staircase,
)
from ilcpmac.signals.harmonics import harmonic_amplitudes, table_from_amplitudes

CPR = 1024
J_KGM2 = 0.01056
Q_S = 1e-6
H = 60
#: the true torque ripple, N m per harmonic
TAU_NM = {8: 0.005, 16: 0.003j, 48: 0.004 * np.exp(0.5j)}


def _truth(size: int = H + 1) -> np.ndarray:
    tau = np.zeros(size, complex)
    for h, c in TAU_NM.items():
        tau[h] = c
    return tau


def _steady_trial(speed_hz: float, viscous_nm_s: float, revolutions: int = 8, line_errors=None,
                  start: int = 0, extra: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Exact crossing times of counts start..start + revolutions N + extra in the periodic steady state.

    omega = Omega + w(theta): (j h J Omega + b) w_h = tau_h - J (w w')_h, iterated to convergence on a
    fine grid; t(phi) = integral of 1 / omega, summed as a Fourier series at the lines' true angles.
    """
    m = 8 * CPR
    h = np.arange(m // 2 + 1)
    tau = _truth(h.size)
    omega = 2.0 * np.pi * speed_hz
    gain = 1j * h * J_KGM2 * omega + viscous_nm_s
    gain[0] = 1.0
    w_h = np.zeros(h.size, complex)
    for _ in range(100):
        w, dw = table_from_amplitudes(w_h, m), table_from_amplitudes(1j * h * w_h, m)
        new = (tau - J_KGM2 * harmonic_amplitudes(w * dw)) / gain
        new[0] = 0.0
        converged = np.max(np.abs(new - w_h)) < 1e-16 * omega
        w_h = new
        if converged:
            break
    u_h = harmonic_amplitudes(1.0 / (omega + table_from_amplitudes(w_h, m)))
    hs = np.nonzero(np.abs(u_h) > 1e-22)[0][1:]
    e = np.zeros(CPR) if line_errors is None else line_errors
    phi = (np.arange(CPR) + e) * 2.0 * np.pi / CPR
    t_line = u_h[0].real * phi + (u_h[hs] / (1j * hs) * (np.exp(1j * np.outer(phi, hs)) - 1.0)).real.sum(axis=1)
    n = np.arange(start, start + revolutions * CPR + extra + 1)
    return n, (n // CPR) * u_h[0].real * 2.0 * np.pi + t_line[n % CPR]


def _drifting_trial(speed_hz: float, net_torque_nm: float, revolutions: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """b = 0: omega^2 = Omega^2 + (2 / J) (net theta + integral of the ripple); t by 8-point Gauss-Legendre."""
    n = np.arange(revolutions * CPR + 1)
    angle = n * 2.0 * np.pi / CPR
    x, weight = np.polynomial.legendre.leggauss(8)
    half = np.diff(angle) / 2.0
    theta = (angle[1:] - half)[:, None] + half[:, None] * x
    omega2 = (2.0 * np.pi * speed_hz) ** 2 + 2.0 / J_KGM2 * (net_torque_nm * theta + sum(
        (c / (1j * h) * (np.exp(1j * h * theta) - 1.0)).real for h, c in TAU_NM.items()))
    return n, np.concatenate([[0.0], np.cumsum(half * (weight / np.sqrt(omega2)).sum(axis=1))])


def _z2(estimate: np.ndarray, variance: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """|error|^2 / E|error|^2 over harmonics 1.. (exponential with mean 1 for a circular complex error)."""
    return np.abs(estimate[1:] - truth[1:]) ** 2 / variance[1:]


def test_count_speeds_gives_a_gap_its_mean_speed_and_drops_the_last_sample():
    count = np.array([5, 6, 9, 10])
    time_s = np.array([0.0, 1.0, 2.5, 3.5])
    c, mid, speed = count_speeds(count, time_s, 8)
    delta = 2.0 * np.pi / 8
    np.testing.assert_array_equal(c, [5, 6, 7, 8, 9])
    np.testing.assert_allclose(mid, [0.5, 1.25, 1.75, 2.25, 3.0])
    np.testing.assert_allclose(speed, [delta, 2 * delta, 2 * delta, 2 * delta, delta])


@given(st.lists(st.integers(1, 4), min_size=1, max_size=40), st.integers(0, 2**32 - 1))
def test_count_speeds_conserve_the_time(gaps, seed):
    count = np.concatenate([[3], 3 + np.cumsum(gaps)])
    time_s = np.concatenate([[0.0], np.cumsum(np.random.default_rng(seed).uniform(0.1, 1.0, len(gaps)))])
    c, mid, speed = count_speeds(count, time_s, 16)
    assert np.sum(2.0 * np.pi / 16 / speed) == pytest.approx(time_s[-1], rel=1e-12)
    assert np.all(np.diff(mid) > 0) and time_s[0] < mid[0] and mid[-1] < time_s[-1]


def test_a_pure_speed_harmonic_has_its_amplitude_and_phase():
    """u = u0 (1 + a cos(h theta + p)) exactly: 1 / (1 + a cos x) has harmonic 1 of -2 rho / sqrt(1 - a^2).

    At h = 10 of 64 counts the half-count shift is 0.49 rad and the interval's averaging 4 %.
    """
    cpr, h, a, p, u0 = 64, 10, 0.02, 0.7, 1.0 / (2.0 * np.pi)
    n = np.arange(5 * cpr + 1)
    theta = 2.0 * np.pi * n / cpr
    time_s = u0 * (theta + a / h * (np.sin(h * theta + p) - np.sin(p)))
    spectrum = EncoderTorqueSpectrum.of(n, time_s, cpr, 20, J_KGM2, 0.0)
    rho = (1.0 - np.sqrt(1.0 - a**2)) / a
    expected = -2.0 * rho / np.sqrt(1.0 - a**2) / u0 * np.exp(1j * p)
    assert spectrum.speed_harmonics_rad_s[h] == pytest.approx(expected, rel=1e-9)
    assert spectrum.speed_harmonics_rad_s[0] == pytest.approx(1.0 / (u0 * np.sqrt(1.0 - a**2)), rel=1e-12)


def test_exact_stamps_give_the_torque_exactly():
    n, t = _steady_trial(1.0, 0.3, start=100, extra=300)
    spectrum = EncoderTorqueSpectrum.of(n, t, CPR, H, J_KGM2, 0.0, 0.3)
    np.testing.assert_allclose(spectrum.harmonics_nm[1:], _truth()[1:], atol=1e-12)
    assert spectrum.revolutions == 7
    assert spectrum.harmonics_nm[0].real == pytest.approx(0.3 * 2.0 * np.pi, rel=1e-6)


def test_torque_is_recovered_within_its_predicted_std():
    """Stamps with independent errors uniform in +-q/2, viscous b = 1 N m / Omega, partial revolutions at both ends."""
    z2 = []
    for seed in range(6):
        rng = np.random.default_rng(seed)
        speed_hz = 0.5 + rng.random()
        viscous = 1.0 / (2.0 * np.pi * speed_hz)
        n, t = _steady_trial(speed_hz, viscous, start=int(rng.integers(CPR)), extra=int(rng.integers(CPR)))
        spectrum = EncoderTorqueSpectrum.of(n, t + rng.uniform(-Q_S / 2, Q_S / 2, t.size), CPR, H, J_KGM2, Q_S,
                                            viscous)
        z2.append(_z2(spectrum.harmonics_nm, spectrum.quantisation_variance_nm2, _truth()))
    z2 = np.array(z2)
    assert 0.7 < z2.mean() < 1.4
    assert z2.max() < 20.0


def test_noise_model_matches_the_scatter_over_30_seeds_and_a_drift_does_not_leak():
    """Stamps rounded to q (as the simulator's) at a random timer phase; the speed drifts by 0.25 % over the trial.

    The revolution scatter is compared above h = 20: below, each revolution's harmonic also carries the
    errors of its first and last stamps, which cancel in the average (the scatter over-states there).
    """
    errors, scatter = [], []
    for seed in range(30):
        rng = np.random.default_rng(seed)
        n, t = _drifting_trial(1.0 + 0.01 * rng.random(), 2e-5)
        stamps = np.round((t + rng.random()) / Q_S) * Q_S
        spectrum = EncoderTorqueSpectrum.of(n, stamps, CPR, H, J_KGM2, Q_S)
        errors.append(_z2(spectrum.harmonics_nm, spectrum.quantisation_variance_nm2, _truth()))
        scatter.append(spectrum.variance_nm2[21:] / spectrum.quantisation_variance_nm2[21:])
    errors = np.array(errors)
    assert 0.7 < errors.mean() < 1.3
    assert np.all((0.5 < errors.mean(axis=0)) & (errors.mean(axis=0) < 2.0))
    assert 0.7 < np.mean(scatter) < 1.3


def test_skipped_counts_are_handled():
    rng = np.random.default_rng(3)
    n, t = _steady_trial(1.0, 0.0)
    keep = np.ones(n.size, bool)
    keep[rng.choice(np.arange(1, n.size - 1), n.size // 50, replace=False)] = False
    stamps = t + rng.uniform(-Q_S / 2, Q_S / 2, t.size)
    spectrum = EncoderTorqueSpectrum.of(n[keep], stamps[keep], CPR, H, J_KGM2, Q_S)
    assert spectrum.revolutions == 8
    z2 = _z2(spectrum.harmonics_nm, spectrum.quantisation_variance_nm2, _truth())
    assert z2.mean() < 2.0 and z2.max() < 20.0


def _line_errors(white_counts: float, seed: int = 5) -> np.ndarray:
    """Eccentricity-like and a few higher harmonics, plus an independent error per line."""
    e_h = np.zeros(CPR // 2 + 1, complex)
    e_h[[1, 2, 16, 48]] = [0.05, 0.02j, 0.01, 0.005 * np.exp(1j)]
    e = table_from_amplitudes(e_h, CPR) + white_counts * np.random.default_rng(seed).standard_normal(CPR)
    return e - e.mean()


def test_encoder_error_and_torque_are_separated_over_three_speeds():
    """One pass recovers e_h within 10 %; a second, on the stamps corrected for it, tau_h within its std."""
    rng = np.random.default_rng(11)
    e = _line_errors(0.005)
    e_true = harmonic_amplitudes(e)
    trials = []
    for speed_hz in (0.5, 1.0, 1.5):
        viscous = 1.0 / (2.0 * np.pi * speed_hz)
        n, t = _steady_trial(speed_hz, viscous, line_errors=e)
        trials.append((n, t + rng.uniform(-Q_S / 2, Q_S / 2, t.size), viscous))
    full = CPR // 2 - 1

    first = separate_encoder_error([EncoderTorqueSpectrum.of(n, t, CPR, full, J_KGM2, Q_S, b) for n, t, b in trials])
    for h in (1, 2, 16, 48):
        assert abs(first.encoder_error_counts[h] - e_true[h]) < 0.1 * abs(e_true[h])
    assert abs(first.torque_nm[16] - TAU_NM[16]) < 0.01 * abs(TAU_NM[16])

    known = encoder_error_table(first.encoder_error_counts, CPR)
    second = separate_encoder_error([EncoderTorqueSpectrum.of(n, t, CPR, full, J_KGM2, Q_S, b,
                                                              line_errors_counts=known) for n, t, b in trials])
    e_estimate = first.encoder_error_counts + second.encoder_error_counts
    for h in (1, 2, 16, 48):
        assert abs(e_estimate[h] - e_true[h]) < 0.01 * abs(e_true[h])
    z2 = _z2(second.torque_nm[: H + 1], second.torque_variance_nm2[: H + 1], _truth())
    assert np.all(z2[[7, 15, 47]] < 9.0)
    assert z2.mean() < 2.0


def test_a_known_encoder_error_is_corrected():
    """In the spectrum to first order (the error falls 100-fold), in the stamps to within the quantisation."""
    rng = np.random.default_rng(2)
    e = _line_errors(0.0)
    n, t = _steady_trial(1.5, 0.0, line_errors=e)
    stamps = t + rng.uniform(-Q_S / 2, Q_S / 2, t.size)
    apparent = EncoderTorqueSpectrum.of(n, stamps, CPR, H, J_KGM2, Q_S)
    corrected = without_encoder_error(apparent, harmonic_amplitudes(e))
    before = np.abs(apparent.harmonics_nm - _truth())[1:]
    after = np.abs(corrected.harmonics_nm - _truth())[1:]
    assert before[15] > 0.01 and after[15] < before[15] / 100
    exact = EncoderTorqueSpectrum.of(n, stamps, CPR, H, J_KGM2, Q_S, line_errors_counts=e)
    z2 = _z2(exact.harmonics_nm, exact.quantisation_variance_nm2, _truth())
    assert z2.mean() < 2.0 and z2.max() < 20.0


def test_encoder_error_table_inverts_the_harmonics():
    e = _line_errors(0.0)
    e_h = harmonic_amplitudes(e)
    e_h[0] = 5.0
    np.testing.assert_allclose(encoder_error_table(e_h, CPR), e, atol=1e-15)


def test_the_floor_closed_form_holds_on_the_seed_bench():
    """std(tau_h) = J h^2 Omega^3 q / sqrt(3 R N_c) for N h^2 Delta^2 >> 2 and small h Delta."""
    h = np.array([8, 16, 48, 96, 150])
    for speed_hz in (0.5, 1.5):
        std = np.sqrt(quantisation_variance_nm2(h, 4096, 1e-6, J_KGM2, speed_hz, 64))
        omega = 2.0 * np.pi * speed_hz
        np.testing.assert_allclose(std, J_KGM2 * h**2 * omega**3 * 1e-6 / np.sqrt(3 * 64 * 4096), rtol=0.03)


def _lagged_staircase(h: int, cpr: int, tau_s: float, delay_steps: int, count_s: float, steps: int = 64
                      ) -> tuple[complex, complex]:
    """S and M of eq. (5) by brute force: x_c = e^{j h c 2 pi / cpr} held over each count, switched T_d =
    ``delay_steps`` sub-steps after the line, through exp(-t / tau) stepped exactly over ``steps`` sub-steps a
    count, for 12 revolutions; the last revolution's sample at each line and exact mean over each count, over x_c."""
    step_s = count_s / steps
    decay = np.exp(-step_s / tau_s)
    n = 12 * cpr * steps
    target = np.exp(2j * np.pi * h * ((np.arange(n) - delay_steps) // steps) / cpr)
    level = np.empty(n + 1, complex)
    level[0] = 0.0
    for k in range(n):
        level[k + 1] = target[k] + (level[k] - target[k]) * decay
    area = target * step_s + (level[:-1] - target) * tau_s * (1.0 - decay)
    lines = np.arange(n - cpr * steps, n, steps)
    x = np.exp(2j * np.pi * h * (lines // steps) / cpr)
    mean = area[lines[:, None] + np.arange(steps)].sum(axis=1) / count_s
    return np.mean(level[lines] / x), np.mean(mean / x)


@pytest.mark.parametrize("delay_steps", [0, 5, -3])
def test_the_staircase_bias_is_the_count_mean_less_the_line_sample_of_a_lagged_staircase(delay_steps):
    """eq. (5) against a staircase stepped exactly through the lag, T_d = 0, 5/64 and -3/64 of a count; and its
    first-order form j h Delta dt / (12 tau) for dt << tau, T_d = 0."""
    cpr, speed_hz, tau_s = 32, 2.0, 0.02
    count_s = 1.0 / (cpr * speed_hz)
    loop = CurrentLoop(np.full(3, tau_s), delay_steps * count_s / 64)
    for h in (1, 3, 7):
        sample, mean = _lagged_staircase(h, cpr, tau_s, delay_steps, count_s)
        nu = 2.0 * np.pi * h / cpr
        expected = mean / (np.exp(0.5j * nu) * np.sinc(h / cpr)) - sample
        np.testing.assert_allclose(staircase_bias([h], cpr, speed_hz, loop), np.full((1, 3), expected), atol=1e-12)
        assert loop.response([h], speed_hz, cpr)[0, 0] == pytest.approx(sample, abs=1e-12)
    slow = CurrentLoop(np.full(3, 1.0), 0.0)
    first_order = 1j * 3 * (2.0 * np.pi / 4096) * (1.0 / (4096 * 0.5)) / 12.0
    assert staircase_bias([3], 4096, 0.5, slow)[0, 0] == pytest.approx(first_order, rel=0.01)
    np.testing.assert_array_equal(staircase_bias([0, 5], cpr, speed_hz, CurrentLoop()), np.zeros((2, 3)))


def test_without_staircase_takes_the_phases_mean_bias_times_the_reference_out():
    n, t = _steady_trial(1.0, 0.0, revolutions=2)
    spectrum = EncoderTorqueSpectrum.of(n, t, CPR, H, J_KGM2, Q_S)
    loop = CurrentLoop([1e-3, 2e-3, 3e-3], 1e-5)
    reference = 2.0 + 0.3 * np.cos(48 * 2.0 * np.pi * np.arange(CPR) / CPR + 0.4)
    epsilon_alpha = np.array([0.9, 1.0, 1.2])
    corrected = without_staircase(spectrum, reference, epsilon_alpha, loop)
    bias = staircase_bias([48], CPR, spectrum.mean_speed_hz, loop)[0]
    change = spectrum.harmonics_nm - corrected.harmonics_nm
    assert change[48] == pytest.approx(np.mean(epsilon_alpha * bias) * 0.3 * np.exp(0.4j), rel=1e-9)
    assert np.max(np.abs(np.delete(change, 48))) < 1e-15
    np.testing.assert_array_equal(corrected.variance_nm2, spectrum.variance_nm2)
    with pytest.raises(ValueError, match=f"reference_nm must hold {CPR} finite values"):
        without_staircase(spectrum, reference[:-1], epsilon_alpha, loop)


@pytest.mark.parametrize("change, message", [
    ({"count": np.array([0, 1, 1, 2])}, "count must be strictly increasing"),
    ({"time_s": np.array([0.0, 1.0, 1.0, 2.0])}, "time_s must be strictly increasing"),
    ({"count": np.arange(4.0)}, "count must hold integers"),
    ({"max_harmonic": 32}, "max_harmonic must be an integer"),
    ({"inertia_kgm2": 0.0}, "inertia_kgm2 must be finite and > 0"),
    ({}, "at least 2 whole revolutions"),
])
def test_bad_input_is_refused_on_one_line(change, message):
    args = {"count": np.arange(4), "time_s": np.arange(4.0), "counts_per_rev": 64, "max_harmonic": 8,
            "inertia_kgm2": 0.01, "timer_resolution_s": 1e-6} | change
    with pytest.raises(ValueError, match=message) as error:
        EncoderTorqueSpectrum.of(**args)
    assert "\n" not in str(error.value)


def test_separation_needs_distinct_speeds():
    n, t = _steady_trial(1.0, 0.0, revolutions=2)
    spectrum = EncoderTorqueSpectrum.of(n, t, CPR, 8, J_KGM2, Q_S)
    with pytest.raises(ValueError, match="2 or more speeds"):
        separate_encoder_error([spectrum])
    with pytest.raises(ValueError, match="distinct speeds"):
        separate_encoder_error([spectrum, spectrum])
