"""The least-squares solutions of identification on folded rows: OLS and WLS.

- :func:`ordinary_fit`: Eq. (4), φ_B = W⁺ τ, with the residual's per-channel σ_c.
- :func:`weighted_fit`: weighted least squares with per-channel noise weights (Gautier 1997),
  the rows of channel c divided by σ_c, iterated until σ_c is the residual σ of the weighted
  fit itself (the maximum-likelihood estimate under independent Gaussian noise per channel):
  Gautier's one step from the OLS σ under-weights a joint the model fits much better than the
  others. The fixed point takes the residual for noise, so identify keeps the one step when
  friction and offsets would explain more than half of the OLS residual (``iterate=False``).

Both solve through QR then the SVD of R (:func:`solve_least_squares`) and give the sandwich
covariance of :func:`~pe_drake.identification.statistics.sandwich_from_grams`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pe_drake.exceptions import DataError
from pe_drake.identification.folded_rows import FoldedRows, RowBlocks, residual_series
from pe_drake.identification.statistics import sandwich_from_grams

#: The weights' fixed point is reached when no σ_c changes by more than this (relative).
WEIGHT_TOLERANCE = 1e-3
#: At most this many reweighted solves (the real Panda's converge in 12-20).
MAX_WEIGHT_ITERATIONS = 50
#: σ_c is kept above this fraction of the largest: a channel the model fits exactly (noiseless
#: data) would otherwise get an infinite weight.
MIN_RELATIVE_SIGMA = 1e-9


class LeastSquaresFit(NamedTuple):
    """One least-squares solution.

    Attributes:
        x: the fitted values, (p,) (base parameters, then drive terms).
        cov: their covariance, (WᵀW)⁻¹ (Σ_c τ_c s_c² W_cᵀW_c) (WᵀW)⁻¹ (weighted rows for WLS).
        cond: cond(W) of the regressor solved (the weighted one for WLS).
        noise_std: per-channel σ_c, (r,): OLS, its residual's; WLS, the σ_c whose weights 1/σ_c
            ``x`` was solved with.
        residual: the (weighted, for WLS) residual of every sample, (S, r).
        iterations: the weighted solves (0 for OLS, 1 for Gautier's one step).
    """

    x: np.ndarray
    cov: np.ndarray
    cond: float
    noise_std: np.ndarray
    residual: np.ndarray
    iterations: int = 0
    converged: bool = False


def solve_least_squares(W: np.ndarray, y: np.ndarray, *, min_ratio: float = 1e-12,
                        refusal: str = "the data does not excite every base parameter",
                        advice: str = "use an exciting trajectory (pe-drake optimize)",
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least squares through QR then the SVD of R: (x, (WᵀW)⁻¹, singular values of W).

    Raises:
        DataError: W is rank deficient, s_min ≤ ``min_ratio``·s_max ("{refusal} (cond(W) = …);
            {advice}").
    """
    b = W.shape[1]
    R = np.linalg.qr(np.column_stack([W, y]), mode="r")  # [W y] = Q [[R_W, z], [0, r]]
    U, s, Vt = np.linalg.svd(R[:b, :b])
    y = R[:b, b]
    if s[-1] <= s[0] * min_ratio:
        raise DataError(f"{refusal} (cond(W) = {s[0] / max(s[-1], 1e-300):.3g}); {advice}")
    x = Vt.T @ ((U.T @ y) / s)
    cov = (Vt.T / s**2) @ Vt
    return x, cov, s


def solve_normal_equations(G: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least squares from the Gram matrix G = WᵀW and g = Wᵀy, equilibrated: (x, G⁻¹) (the
    pseudo-inverse when G is singular)."""
    d = np.sqrt(np.maximum(np.diag(G), 1e-300))
    Gs = G / np.outer(d, d)
    try:
        Hinv = np.linalg.inv(Gs)
    except np.linalg.LinAlgError:
        Hinv = np.linalg.pinv(Gs)
    return (Hinv @ (g / d)) / d, Hinv / np.outer(d, d)


def compress_joint_rows(blocks) -> tuple[np.ndarray, int]:
    """Per joint j, the triangular factor R_j of [A_j  y_j] over blocks (A (s, n, p), y (s, n)),
    shape (n, p+1, p+1), and the total number of samples: ‖A_j x − y_j‖² = ‖R_j [x; −1]‖², so
    the weighted fits and the residuals need nothing else."""
    R, S = None, 0
    for A, y in blocks:
        S += A.shape[0]
        block = np.concatenate([A, y[..., None]], axis=-1).transpose(1, 0, 2)  # (n, s, p+1)
        if R is not None:
            block = np.concatenate([R, block], axis=1)
        R = np.linalg.qr(block, mode="r")
    return R, S


def lstsq_from_factors(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`solve_least_squares` of the stacked factors R (m, p+1) of [W y] with equilibrated
    columns: (x, (WᵀW)⁻¹); refuses a rank-deficient W (with the payload workflow's advice)."""
    p = R.shape[1] - 1
    scale = np.maximum(np.linalg.norm(R[:, :p], axis=0), 1e-300)
    x, cov, _ = solve_least_squares(
        R[:, :p] / scale, R[:, p], min_ratio=1e-10,
        refusal="the runs do not excite the payload and the nuisance terms (after column scaling)",
        advice="use a payload motion (optimize_payload_motion) and runs that move every joint")
    return x / scale, cov / np.outer(scale, scale)


def weighted_fit_from_factors(R_joint: np.ndarray, S: int, weighted: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OLS, per-joint σ_j from its residual, then Gautier's one WLS step with rows / σ_j
    (``weighted``; else OLS), from the per-joint factors R_joint (n, p+1, p+1) of S samples
    (:func:`compress_joint_rows`): (x, Cov(x), σ_j)."""
    n, _, p1 = R_joint.shape
    p = p1 - 1
    x, _ = lstsq_from_factors(R_joint.reshape(-1, p1))
    xm = np.append(x, -1.0)
    noise_std = np.sqrt(np.array([np.sum((Rj @ xm) ** 2) for Rj in R_joint]) / max(S - p / n, 1.0))
    w = 1.0 / np.maximum(noise_std, 1e-9 * max(float(noise_std.max()), 1e-12)) if weighted else np.ones(n)
    Rw = (R_joint * w[:, None, None]).reshape(-1, p1)
    x, cov = lstsq_from_factors(Rw)
    r = Rw @ np.append(x, -1.0)
    s2 = float(r @ r) / max(S * n - p, 1)  # ≈ 1 with the weights; keeps σ honest if not
    return x, cov * s2, noise_std


def channel_sigma(folded: FoldedRows, T: np.ndarray, x: np.ndarray) -> np.ndarray:
    """σ_c² = ‖ρ_c‖² / (S − p/r) of the unweighted residual, per channel, (r,)."""
    dof = max(folded.samples - T.shape[1] / folded.channels, 1.0)
    return np.sqrt(np.maximum(folded.residual_ss(T, x), 0.0) / dof)


def ordinary_fit(folded: FoldedRows, blocks: RowBlocks, T: np.ndarray) -> LeastSquaresFit:
    """Eq. (4): ordinary least squares on the columns ``T`` of the folded rows."""
    x, cov_unit, s = solve_least_squares(*folded.stacked(T))
    rho = residual_series(blocks, folded.samples, T, x)
    cov = sandwich_from_grams(folded.channel_grams(T), rho, cov_unit)
    return LeastSquaresFit(x, cov, float(s[0] / s[-1]), channel_sigma(folded, T, x), rho)


def weighted_fit(folded: FoldedRows, blocks: RowBlocks, T: np.ndarray, sigma: np.ndarray,
                 iterate: bool = True) -> LeastSquaresFit:
    """WLS with the weights 1/σ_c iterated from ``sigma`` (the OLS σ_c) to their fixed point
    (``iterate``), or Gautier's one step with the weights of ``sigma``."""
    floor = MIN_RELATIVE_SIGMA * max(float(np.max(sigma)), 1e-12)
    sigma = np.maximum(sigma, floor)
    solves = MAX_WEIGHT_ITERATIONS if iterate else 1
    iterations, converged = 0, False
    while True:
        iterations += 1
        x, cov_unit, s = solve_least_squares(*folded.stacked(T, 1.0 / sigma))
        new = np.maximum(channel_sigma(folded, T, x), floor)
        converged = iterate and bool(np.max(np.abs(new / sigma - 1.0)) < WEIGHT_TOLERANCE)
        if converged or iterations == solves:
            break
        sigma = new  # the next solve's; what is returned belongs to the weights x was solved with
    w = 1.0 / sigma
    rho = residual_series(blocks, folded.samples, T, x, w)
    cov = sandwich_from_grams(folded.channel_grams(T, w), rho, cov_unit)
    return LeastSquaresFit(x, cov, float(s[0] / s[-1]), sigma, rho, iterations, converged)
