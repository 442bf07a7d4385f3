"""The joint harmonic-domain fit: known coefficients, marginal (Schur) information, collinearity, Birge ratio."""

from __future__ import annotations

import numpy as np
import pytest

from ilcpmac.pipeline.regression import Regression

M = 60  # harmonics in the fit


def complex_normal(rng: np.random.Generator, shape, variance) -> np.ndarray:
    """Circular complex noise with E|n|^2 = variance (variance / 2 per real component)."""
    scale = np.sqrt(np.asarray(variance) / 2.0)
    return scale * (rng.standard_normal(shape) + 1j * rng.standard_normal(shape))


def design(rng: np.random.Generator) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
    """Three blocks of complex regressors, true real coefficients, per-harmonic variances."""
    blocks = {"a": complex_normal(rng, (M, 2), 1.0), "b": complex_normal(rng, (M, 3), 1.0),
              "c": complex_normal(rng, (M, 1), 1.0)}
    coefficients = np.array([1.0, -0.5, 2.0, 0.25, -1.5, 0.75])
    variance = rng.uniform(1e-4, 4e-3, M)  # very different noise per harmonic: the weights matter
    return blocks, coefficients, variance


def weighted_design(blocks: dict[str, np.ndarray], variance: np.ndarray) -> np.ndarray:
    """The real whitened design [Re X; Im X] * sqrt(2 / variance) the fit is defined by."""
    X = np.hstack(list(blocks.values()))
    w = np.sqrt(2.0 / np.concatenate([variance, variance]))
    return np.vstack([X.real, X.imag]) * w[:, None]


def slices(blocks: dict[str, np.ndarray]) -> dict[str, slice]:
    out, start = {}, 0
    for name, cols in blocks.items():
        out[name] = slice(start, start + cols.shape[1])
        start += cols.shape[1]
    return out


# ------------------------------------------------------------ known coefficients, known noise


def test_noise_free_data_give_the_coefficients_exactly():
    blocks, coefficients, variance = design(np.random.default_rng(1))
    y = np.hstack(list(blocks.values())) @ coefficients
    fit = Regression(y, variance, blocks)
    np.testing.assert_allclose(fit.coefficients, coefficients, rtol=1e-12, atol=1e-12)
    assert fit.birge_ratio == 1.0
    for name, s in slices(blocks).items():
        np.testing.assert_allclose(fit.block(name).estimate, coefficients[s], rtol=1e-12, atol=1e-12)


def test_estimates_scatter_as_their_information_says():
    """Monte Carlo: the errors are unbiased and their covariance is the inverse information."""
    rng = np.random.default_rng(2)
    blocks, coefficients, variance = design(rng)
    X = np.hstack(list(blocks.values()))
    full_info = weighted_design(blocks, variance).T @ weighted_design(blocks, variance)
    cov = np.linalg.inv(full_info)
    errors, chi2 = [], []
    for _ in range(400):
        fit = Regression(X @ coefficients + complex_normal(rng, M, variance), variance, blocks)
        errors.append(fit.coefficients - coefficients)
        # the whitened error, distributed as chi-square with 6 degrees of freedom
        chi2.append(errors[-1] @ full_info @ errors[-1])
    errors = np.array(errors)
    std = np.sqrt(np.diag(cov))
    assert np.all(np.abs(errors.mean(axis=0)) < 4 * std / np.sqrt(len(errors)))
    np.testing.assert_allclose(errors.std(axis=0), std, rtol=0.15)
    assert np.mean(chi2) == pytest.approx(6.0, rel=0.1)
    # a single fit is close to the truth in absolute terms too
    assert np.abs(errors[0]).max() < 5 * std.max()


def test_weights_follow_the_variance():
    """A harmonic with a huge variance (an outlier there) barely moves the estimate."""
    rng = np.random.default_rng(3)
    blocks, coefficients, variance = design(rng)
    X = np.hstack(list(blocks.values()))
    y = X @ coefficients
    y[7] += 50.0  # a wild value ...
    variance = variance.copy()
    variance[7] = 1e8  # ... that the fit is told to distrust
    fit = Regression(y, variance, blocks)
    np.testing.assert_allclose(fit.coefficients, coefficients, atol=1e-3)


# ------------------------------------------------------------ marginal information of a block


@pytest.mark.parametrize("name", ["a", "b", "c"])
def test_block_information_is_the_inverse_of_the_block_of_the_full_covariance(name):
    rng = np.random.default_rng(4)
    blocks, coefficients, variance = design(rng)
    y = np.hstack(list(blocks.values())) @ coefficients + complex_normal(rng, M, variance)
    fit = Regression(y, variance, blocks)
    A = weighted_design(blocks, variance)
    cov = np.linalg.inv(A.T @ A / fit.birge_ratio)
    s = slices(blocks)[name]
    block = fit.block(name)
    expected = np.linalg.inv(cov[s, s])
    np.testing.assert_allclose(block.information, expected, rtol=1e-8, atol=1e-10 * np.abs(expected).max())
    np.testing.assert_array_equal(block.information, block.information.T)
    np.testing.assert_allclose(block.estimate, fit.coefficients[s], rtol=0, atol=0)
    # marginal information is less than the conditional one (the block's own rows) whenever blocks overlap
    conditional = (A.T @ A / fit.birge_ratio)[s, s]
    assert np.all(np.linalg.eigvalsh(conditional - block.information) > -1e-9 * np.abs(conditional).max())
    assert np.trace(conditional - block.information) > 1e-6 * np.trace(conditional)


def test_a_single_block_has_the_full_information():
    rng = np.random.default_rng(5)
    blocks, coefficients, variance = design(rng)
    only = {"b": blocks["b"]}
    fit = Regression(only["b"] @ coefficients[2:5], variance, only)
    A = weighted_design(only, variance)
    np.testing.assert_allclose(fit.block("b").information, A.T @ A, rtol=1e-12)


# ------------------------------------------------------------ collinear blocks


def test_collinear_blocks_have_no_information_in_the_shared_direction():
    """Block b's first regressor is a multiple of a's first: neither block can tell its share there."""
    rng = np.random.default_rng(6)
    blocks, coefficients, variance = design(rng)
    blocks["b"] = blocks["b"].copy()
    blocks["b"][:, 0] = 2.0 * blocks["a"][:, 0]  # a real multiple (coefficients are real)
    X = np.hstack(list(blocks.values()))
    y = X @ coefficients + complex_normal(rng, M, variance)
    fit = Regression(y, variance, blocks)
    a, b = fit.block("a"), fit.block("b")
    for block, shared in ((a, np.array([1.0, 0.0])), (b, np.array([1.0, 0.0, 0.0]))):
        top = np.linalg.eigvalsh(block.information).max()
        # (near-)zero information in the shared direction ...
        assert shared @ block.information @ shared < 1e-9 * top
        # ... and full-strength information in the others
        eig = np.linalg.eigvalsh(block.information)
        assert np.sum(eig > 1e-6 * top) == block.information.shape[0] - 1
    # the other directions are still estimated correctly
    std = 1.0 / np.sqrt(b.information[1, 1] - b.information[1, 2] ** 2 / b.information[2, 2])
    assert abs(b.estimate[1] - coefficients[3]) < 5 * std
    # the identifiable combination a_0 + 2 b_0 is right; the split is the minimum-norm one
    combo = fit.coefficients[0] + 2.0 * fit.coefficients[2]
    assert combo == pytest.approx(coefficients[0] + 2.0 * coefficients[2], abs=0.05)
    assert fit.coefficients[2] == pytest.approx(2.0 * fit.coefficients[0], rel=1e-6)


def test_nearly_collinear_blocks_have_little_information_in_the_shared_direction():
    rng = np.random.default_rng(7)
    blocks, coefficients, variance = design(rng)
    blocks["c"] = blocks["a"][:, :1] + 1e-4 * complex_normal(rng, (M, 1), 1.0)
    y = np.hstack(list(blocks.values())) @ coefficients + complex_normal(rng, M, variance)
    fit = Regression(y, variance, blocks)
    alone = weighted_design({"c": blocks["c"]}, variance)
    # c's marginal information is ~1e-8 of what it would have alone
    assert fit.block("c").information[0, 0] < 1e-6 * (alone.T @ alone)[0, 0]


# ------------------------------------------------------------ Birge ratio


def test_birge_ratio_is_about_one_for_the_right_model():
    rng = np.random.default_rng(8)
    blocks, coefficients, variance = design(rng)
    X = np.hstack(list(blocks.values()))
    ratios = [Regression(X @ coefficients + complex_normal(rng, M, variance), variance, blocks).birge_ratio
              for _ in range(50)]
    assert all(r >= 1.0 for r in ratios)
    assert np.median(ratios) < 1.2


def test_birge_ratio_exceeds_one_for_a_wrong_model_and_deflates_the_information():
    rng = np.random.default_rng(9)
    blocks, coefficients, variance = design(rng)
    X = np.hstack(list(blocks.values()))
    missing = complex_normal(rng, M, 1.0) * 0.2  # a regressor the model lacks, 0.2 against noise of ~0.04
    y = X @ coefficients + missing + complex_normal(rng, M, variance)
    fit = Regression(y, variance, blocks)
    A = weighted_design(blocks, variance)
    b = np.concatenate([y.real, y.imag]) * np.sqrt(2.0 / np.concatenate([variance, variance]))
    residual = b - A @ np.linalg.lstsq(A, b, rcond=None)[0]
    expected = residual @ residual / (2 * M - A.shape[1])
    assert expected > 10.0
    assert fit.birge_ratio == pytest.approx(expected, rel=1e-9)
    s = slices(blocks)["a"]
    expected_info = np.linalg.inv(np.linalg.inv(A.T @ A / expected)[s, s])
    np.testing.assert_allclose(fit.block("a").information, expected_info, rtol=1e-8)


def test_no_blocks_is_a_fit_of_nothing():
    rng = np.random.default_rng(10)
    variance = np.full(M, 1e-3)
    fit = Regression(complex_normal(rng, M, variance), variance, {})
    assert fit.coefficients.shape == (0,)
    assert fit.birge_ratio >= 1.0
