"""The weighted least squares of identify: weights 1/σ_c at their fixed point."""

from __future__ import annotations

import numpy as np

from pe_drake.identification.folded_rows import fold_rows
from pe_drake.identification.least_squares import (
    WEIGHT_TOLERANCE,
    channel_sigma,
    ordinary_fit,
    solve_least_squares,
    weighted_fit,
)

SIGMA = np.array([0.01, 0.1, 1.0])  # one channel 100× quieter than another


def _problem(seed=0, samples=3000, sigma=SIGMA):
    """Three channels sharing 4 parameters, each with one of its own; noise σ_c per channel."""
    rng = np.random.default_rng(seed)
    r, shared = len(sigma), 4
    F = np.zeros((samples, r, shared + r))
    F[:, :, :shared] = rng.normal(size=(samples, r, shared))
    for c in range(r):
        F[:, c, shared + c] = rng.normal(size=samples)
    x_true = rng.normal(size=shared + r)
    y = F @ x_true + rng.normal(size=(samples, r)) * sigma

    def blocks():
        for s in range(0, samples, 1000):
            k = slice(s, min(s + 1000, samples))
            yield k, F[k], y[k]

    return blocks, F, y, x_true


def test_weights_reach_their_fixed_point_and_the_noise_of_each_channel():
    blocks, F, y, _ = _problem()
    folded = fold_rows(blocks)
    T = np.eye(F.shape[2])
    ols = ordinary_fit(folded, blocks, T)
    fit = weighted_fit(folded, blocks, T, ols.noise_std)
    assert 1 < fit.iterations < 20
    # the fixed point: σ_c is the residual σ of the fit the weights 1/σ_c give
    np.testing.assert_allclose(channel_sigma(folded, T, fit.x), fit.noise_std, rtol=2 * WEIGHT_TOLERANCE)
    np.testing.assert_allclose(fit.noise_std, SIGMA, rtol=0.05)
    # the OLS σ of the quiet channel is inflated by the loud one's errors in the shared parameters
    assert ols.noise_std[0] > 1.3 * fit.noise_std[0]  # measured 1.42


def test_reweighted_estimate_is_the_one_with_the_true_weights():
    blocks, F, y, x_true = _problem(seed=3)
    folded = fold_rows(blocks)
    T = np.eye(F.shape[2])
    ols = ordinary_fit(folded, blocks, T)
    fit = weighted_fit(folded, blocks, T, ols.noise_std)
    w = 1.0 / SIGMA
    x_gls, cov_gls, _ = solve_least_squares((F * w[None, :, None]).reshape(-1, F.shape[2]), (y * w).ravel())
    sd = np.sqrt(np.diag(cov_gls))
    assert np.max(np.abs(fit.x - x_gls) / sd) < 0.1  # within a tenth of a standard deviation
    assert np.max(np.abs(fit.x - x_true) / sd) < 4.5
    np.testing.assert_allclose(np.sqrt(np.diag(fit.cov)), sd, rtol=0.25)  # sandwich ≈ the true covariance
    # one WLS step from the OLS σ is farther from the estimate with the true weights
    x_one, _, _ = solve_least_squares(*folded.stacked(T, 1.0 / ols.noise_std))
    assert np.max(np.abs(x_one - x_gls) / sd) > 2 * np.max(np.abs(fit.x - x_gls) / sd)


def test_noiseless_channel_keeps_a_finite_weight():
    blocks, F, y, x_true = _problem(sigma=np.array([0.0, 0.1, 1.0]))
    folded = fold_rows(blocks)
    T = np.eye(F.shape[2])
    fit = weighted_fit(folded, blocks, T, ordinary_fit(folded, blocks, T).noise_std)
    assert np.all(np.isfinite(fit.x)) and np.all(fit.noise_std > 0)
    # the exact channel fixes the shared parameters and its own; the noisy ones keep their noise
    assert np.max(np.abs(fit.x[:5] - x_true[:5])) < 1e-9
    assert fit.iterations <= 3  # measured 3


def test_one_step_is_gautiers_wls_with_the_ols_weights():
    blocks, F, y, _ = _problem(seed=5)
    folded = fold_rows(blocks)
    T = np.eye(F.shape[2])
    ols = ordinary_fit(folded, blocks, T)
    fit = weighted_fit(folded, blocks, T, ols.noise_std, iterate=False)
    x_one, _, _ = solve_least_squares(*folded.stacked(T, 1.0 / ols.noise_std))
    np.testing.assert_allclose(fit.x, x_one, rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(fit.noise_std, ols.noise_std)  # the σ of the weights used
    assert fit.iterations == 1 and not fit.converged


def test_weights_out_of_solves_are_reported_and_consistent(monkeypatch):
    import pe_drake.identification.least_squares as least_squares

    monkeypatch.setattr(least_squares, "MAX_WEIGHT_ITERATIONS", 3)
    monkeypatch.setattr(least_squares, "WEIGHT_TOLERANCE", 1e-15)  # never met: the solves run out
    blocks, F, y, _ = _problem(seed=6)
    folded = fold_rows(blocks)
    T = np.eye(F.shape[2])
    fit = weighted_fit(folded, blocks, T, ordinary_fit(folded, blocks, T).noise_std)
    assert fit.iterations == 3 and not fit.converged
    x, _, _ = solve_least_squares(*folded.stacked(T, 1.0 / fit.noise_std))
    np.testing.assert_allclose(fit.x, x, rtol=1e-12, atol=1e-14)  # x belongs to the σ returned
