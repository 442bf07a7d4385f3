"""KalmanEstimator against batch least squares (known answers), drift tracking, state round-trips."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ilcpmac.estimators import KalmanEstimator

N_STATE = 4
#: prior variance, vague next to the data (each block's information is 1e2 to 1e4): its weight in the
#: answer is ~1e-6. Far vaguer priors cost the covariance-form filter precision (1e8: ~1e-4 relative).
VAGUE_VARIANCE = 1e4


def random_covariance(rng: np.random.Generator, n: int, scale: float) -> np.ndarray:
    """A well-conditioned symmetric positive-definite matrix."""
    a = rng.standard_normal((n, n))
    return scale * (a @ a.T / n + 0.5 * np.eye(n))


def relative_error(x: np.ndarray, reference: np.ndarray) -> float:
    return float(np.linalg.norm(x - reference) / np.linalg.norm(reference))


def prior_rows(x0: np.ndarray, P0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The prior as whitened pseudo-equations (exactly what the filter starts from)."""
    w = np.linalg.cholesky(np.linalg.inv(P0)).T  # w.T w = P0^-1
    return w, w @ x0


def solve_stacked(rows: list[np.ndarray], rhs: list[np.ndarray]) -> np.ndarray:
    return np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)[0]


# ------------------------------------------------------------ zero process noise: batch least squares


def test_update_reproduces_batch_least_squares_with_full_covariances_and_non_identity_H():
    rng = np.random.default_rng(11)
    x_true = np.array([1.5, -2.0, 0.25, 4.0])
    x0 = np.zeros(N_STATE)
    P0 = np.eye(N_STATE) * VAGUE_VARIANCE
    kf = KalmanEstimator(x0, np.diag(P0), process_noise=0.0)
    w0, r0 = prior_rows(x0, P0)
    rows, rhs = [], []
    for m in (2, 3, 5, 1, 4):  # blocks of different sizes; the first ones alone cannot determine x
        H = rng.standard_normal((m, N_STATE))
        R = random_covariance(rng, m, 0.01)
        z = H @ x_true + np.linalg.cholesky(R) @ rng.standard_normal(m)
        kf.update(z, R, H)
        w = np.linalg.cholesky(np.linalg.inv(R)).T  # whiten: w.T w = R^-1
        rows.append(w @ H)
        rhs.append(w @ z)
    # batch LS on the stacked equations, the prior's pseudo-equations included
    batch = solve_stacked([w0] + rows, [r0] + rhs)
    assert relative_error(kf.x, batch) < 1e-9
    # the prior is vague: the answer is the data's alone to ~1e-6
    assert relative_error(kf.x, solve_stacked(rows, rhs)) < 1e-5
    # the posterior covariance is the batch one: (P0^-1 + sum H^T R^-1 H)^-1
    stacked = np.vstack([w0] + rows)
    batch_cov = np.linalg.inv(stacked.T @ stacked)
    np.testing.assert_allclose(kf.P, batch_cov, rtol=1e-7, atol=1e-9 * np.abs(batch_cov).max())
    # and the data were informative: the answer is near the truth, far from the prior
    assert np.abs(kf.x - x_true).max() < 0.5


def test_update_with_an_informative_prior_is_the_prior_plus_the_data():
    rng = np.random.default_rng(12)
    x0 = np.array([0.5, 0.5, -1.0, 2.0])
    P0 = random_covariance(rng, N_STATE, 0.2)
    kf = KalmanEstimator(x0, P0)
    w0, r0 = prior_rows(x0, P0)
    rows, rhs = [w0], [r0]
    for _ in range(3):
        H = rng.standard_normal((2, N_STATE))
        R = np.diag(rng.uniform(0.05, 0.2, 2))  # the filter takes a diagonal as a matrix
        z = rng.standard_normal(2)
        kf.update(z, R, H)
        w = np.diag(1.0 / np.sqrt(np.diag(R)))
        rows.append(w @ H)
        rhs.append(w @ z)
    assert relative_error(kf.x, solve_stacked(rows, rhs)) < 1e-9


def test_update_block_with_singular_information_reproduces_batch_least_squares():
    """Rank-deficient blocks, non-identity H: only the seen directions count, exactly as in batch LS."""
    rng = np.random.default_rng(13)
    n, k = N_STATE, 3  # state of 4, blocks of 3 measured quantities H x
    x_true = np.array([0.3, -1.2, 2.2, 0.7])
    kf = KalmanEstimator(np.zeros(n), np.full(n, VAGUE_VARIANCE))
    w0, r0 = prior_rows(np.zeros(n), np.eye(n) * VAGUE_VARIANCE)
    rows, rhs = [], []
    used = []
    for rank in (1, 2, 1, 2, 3, 2):
        H = rng.standard_normal((k, n))
        A = rng.standard_normal((rank, k)) * 10.0  # information A^T A of rank `rank`
        information = A.T @ A
        # the block's estimate of H x: exact in the seen directions (noise of covariance (A^T A)^+),
        # arbitrary in the unseen ones (they must not matter)
        noise = np.linalg.lstsq(A, rng.standard_normal(rank), rcond=None)[0]
        unseen = np.linalg.svd(A)[2][rank:].T @ rng.standard_normal(k - rank) * 1e3 if rank < k else 0.0
        estimate = H @ x_true + noise + unseen
        used.append(kf.update_block(estimate, information, H))
        rows.append(A @ H)  # whitened equations of the block: A estimate = A H x + unit noise
        rhs.append(A @ estimate)
    assert used == [1, 2, 1, 2, 3, 2]
    assert np.linalg.matrix_rank(np.vstack(rows)) == n  # together the blocks see every direction
    assert relative_error(kf.x, solve_stacked([w0] + rows, [r0] + rhs)) < 1e-9
    assert relative_error(kf.x, solve_stacked(rows, rhs)) < 1e-5
    assert np.abs(kf.x - x_true).max() < 0.2


def test_update_block_ignores_directions_below_the_relative_tolerance():
    """A direction 1e-14 weaker than the best one is numerically unseen: it must not drag the estimate."""
    kf = KalmanEstimator(np.zeros(2), np.full(2, 1.0))
    information = np.diag([1e6, 1e-8])
    assert kf.update_block(np.array([1.0, 1e9]), information) == 1
    assert kf.x[0] == pytest.approx(1e6 / (1e6 + 1.0), rel=1e-12)
    assert kf.x[1] == 0.0
    assert kf.P[1, 1] == pytest.approx(1.0, rel=1e-12)


def test_update_block_without_information_only_predicts():
    kf = KalmanEstimator(np.array([1.0, 2.0]), np.full(2, 0.5), process_noise=0.25)
    assert kf.update_block(np.array([10.0, 10.0]), np.zeros((2, 2))) == 0
    np.testing.assert_array_equal(kf.x, [1.0, 2.0])
    np.testing.assert_allclose(kf.P, np.diag([0.75, 0.75]), rtol=1e-15)


def test_update_block_equals_update_for_full_rank_information():
    rng = np.random.default_rng(14)
    information = random_covariance(rng, N_STATE, 50.0)
    H = rng.standard_normal((N_STATE, N_STATE))
    estimate = rng.standard_normal(N_STATE)
    a = KalmanEstimator(np.ones(N_STATE), np.full(N_STATE, 2.0), process_noise=0.01)
    b = KalmanEstimator(np.ones(N_STATE), np.full(N_STATE, 2.0), process_noise=0.01)
    assert a.update_block(estimate, information, H) == N_STATE
    b.update(estimate, np.linalg.inv(information), H)
    np.testing.assert_allclose(a.x, b.x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(a.P, b.P, rtol=1e-8, atol=1e-12)


# ------------------------------------------------------------ process noise: old data count less


def run_step_change(process_noise: float, seed: int = 21) -> tuple[np.ndarray, np.ndarray]:
    """Track a scalar that jumps from 1 to 2 after 30 of 60 trials; returns estimates and variances."""
    rng = np.random.default_rng(seed)
    kf = KalmanEstimator(np.zeros(1), np.full(1, 100.0), process_noise=process_noise)
    truth = np.r_[np.full(30, 1.0), np.full(30, 2.0)]
    estimates, variances = [], []
    for value in truth:
        kf.update(np.array([value + 0.1 * rng.standard_normal()]), np.array([[0.01]]))
        estimates.append(kf.x[0])
        variances.append(kf.P[0, 0])
    return np.array(estimates), np.array(variances)


def test_process_noise_tracks_a_step_change_that_zero_noise_averages_away():
    drifting, drifting_var = run_step_change(process_noise=0.01)
    frozen, frozen_var = run_step_change(process_noise=0.0)
    # both agree with the truth before the step
    assert abs(drifting[29] - 1.0) < 0.1
    assert abs(frozen[29] - 1.0) < 0.05
    # after it, only the filter with process noise follows: the other averages both halves (~1.5)
    assert np.all(np.abs(drifting[-10:] - 2.0) < 0.15)
    assert abs(frozen[-1] - 1.5) < 0.05
    # old data count less: the variance settles at a floor instead of falling as 1 / n
    assert drifting_var[-1] == pytest.approx(drifting_var[-20], rel=1e-6)
    assert drifting_var[-1] > 10 * frozen_var[-1]
    assert frozen_var[-1] == pytest.approx(0.01 / 60, rel=1e-3)


def test_process_noise_is_added_before_each_update():
    kf = KalmanEstimator(np.zeros(2), np.diag([1.0, 4.0]), process_noise=np.array([0.5, 0.0]))
    kf.update(np.array([1.0]), np.array([[1.0]]), np.array([[1.0, 0.0]]))
    # predicted variance of x_0 is 1.5; the gain is 1.5 / 2.5; x_1 is not observed and keeps 4
    assert kf.x[0] == pytest.approx(0.6, rel=1e-12)
    assert kf.P[0, 0] == pytest.approx(1.5 - 1.5**2 / 2.5, rel=1e-12)
    assert kf.P[1, 1] == pytest.approx(4.0, rel=1e-12)


# ------------------------------------------------------------ state and restore


def test_state_is_json_and_restore_round_trips_and_continues_identically():
    rng = np.random.default_rng(31)
    original = KalmanEstimator(rng.standard_normal(N_STATE), np.full(N_STATE, 3.0), process_noise=1e-3)
    for _ in range(3):
        original.update(rng.standard_normal(2), np.eye(2) * 0.1, rng.standard_normal((2, N_STATE)))
    state = json.loads(json.dumps(original.state()))
    copy = KalmanEstimator(np.zeros(N_STATE), np.ones(N_STATE), process_noise=1e-3)
    copy.restore(state)
    np.testing.assert_array_equal(copy.x, original.x)
    np.testing.assert_array_equal(copy.P, original.P)
    # and both go on the same way
    H, z = rng.standard_normal((3, N_STATE)), rng.standard_normal(3)
    original.update_block(z, np.diag([5.0, 1.0, 0.0]), H)
    copy.update_block(z, np.diag([5.0, 1.0, 0.0]), H)
    np.testing.assert_array_equal(copy.x, original.x)
    np.testing.assert_array_equal(copy.P, original.P)


def test_x_and_P_are_copies():
    kf = KalmanEstimator(np.zeros(2), np.ones(2))
    kf.x[0] = 5.0
    kf.P[0, 0] = 5.0
    assert kf.x[0] == 0.0 and kf.P[0, 0] == 1.0


def test_a_constraint_is_the_least_squares_answer_under_it_and_holds_through_later_updates():
    """Truth: the minimiser of (x - x^)' P^-1 (x - x^) with D x = d (the KKT system solved directly); after it D x
    has no variance, and a later measurement (no process noise) leaves D x at d."""
    rng = np.random.default_rng(12)
    n = 4
    root = rng.standard_normal((n, n))
    P0 = root @ root.T + n * np.eye(n)
    x0 = rng.standard_normal(n)
    kf = KalmanEstimator(x0, P0)
    kf.update(rng.standard_normal(2), np.diag([0.5, 2.0]), rng.standard_normal((2, n)))
    x, P = kf.x, kf.P
    D, d = rng.standard_normal(n), 0.7
    kkt = np.block([[np.linalg.inv(P), D[:, None]], [D[None, :], np.zeros((1, 1))]])
    expected = np.linalg.solve(kkt, np.concatenate([np.linalg.solve(P, x), [d]]))[:n]
    kf.constrain(D, d)
    np.testing.assert_allclose(kf.x, expected, rtol=1e-10, atol=1e-12)
    assert D @ kf.x == pytest.approx(d, abs=1e-12)
    assert D @ kf.P @ D == pytest.approx(0.0, abs=1e-9)
    kf.update(rng.standard_normal(3), np.eye(3), rng.standard_normal((3, n)))
    assert D @ kf.x == pytest.approx(d, abs=1e-8)
