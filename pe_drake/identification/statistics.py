"""Standard deviations of least-squares estimates from filtered, hence correlated, samples.

Low-pass filtering and decimating a record well above its cut-off leaves neighbouring samples
correlated, so σ² (WᵀW)⁻¹ understates the variance by about the integrated autocorrelation time
τ_int of the residual (Sokal 1997). :func:`sandwich_from_grams` inflates each channel's
contribution by its own τ_int.
"""

from __future__ import annotations

import numpy as np


def integrated_autocorrelation(r: np.ndarray, max_lag_fraction: float = 0.1) -> np.ndarray:
    """τ_int = 1 + 2 Σ ρ_k per column of the residuals r (S, n), summed while ρ_k > 0 up to lag
    ``max_lag_fraction`` · S: the factor (n,), ≥ 1, by which correlation inflates a variance."""
    S = r.shape[0]
    out = np.ones(r.shape[1])
    max_lag = max(1, int(max_lag_fraction * S))
    for j in range(r.shape[1]):  # a channel at a time: an hour's transforms are 16 B per sample each
        x = r[:, j] - r[:, j].mean()
        f = np.fft.rfft(x, n=2 * S)
        ac = np.fft.irfft(f * np.conj(f))[: max_lag + 1]
        if ac[0] <= 0:
            continue
        rho = ac[1 : max_lag + 1] / ac[0]
        neg = np.flatnonzero(rho <= 0)
        stop = neg[0] if neg.size else len(rho)
        out[j] = 1.0 + 2.0 * float(np.sum(rho[:stop]))
    return np.clip(out, 1.0, S / 2.0)


def sandwich_from_grams(grams: np.ndarray, residual: np.ndarray, cov_unit: np.ndarray) -> np.ndarray:
    """Cov(x̂) = G⁻¹ (Σ_c τ_c s_c² W_cᵀ W_c) G⁻¹ of a least-squares fit, G⁻¹ = ``cov_unit``.

    Args:
        grams: each channel's W_cᵀW_c of the (possibly weighted) regressor, shape (r, p, p).
        residual: its residual y − W x̂, shape (S, r).
        cov_unit: (WᵀW)⁻¹, shape (p, p).

    Returns:
        shape (p, p): each channel c with its residual variance s_c² and correlation time τ_c.
    """
    S, r = residual.shape
    p = grams.shape[1]
    tau = integrated_autocorrelation(residual)
    s2 = np.sum(residual**2, axis=0) / max(S - p / r, 1.0)
    M = np.einsum("c,cij->ij", tau * s2, grams)
    return cov_unit @ M @ cov_unit
