"""Excitation criteria of the stacked base regressor C and their gradients dc/dC (C's shape).

All use the singular values of C and ∂σ_i/∂C = u_i v_iᵀ (Eq. 16); docs/derivations.md §1 derives
each gradient and says when to use which:

- ``cond``: c = σ_max/σ_min (Eq. 5), the paper's criterion; dc/dC is Eq. (17).
- ``log_cond``: log σ_max − log σ_min: same minimizer, gradient of unit scale.
- ``soft_cond`` (default): (Σ σ_i^p)^(1/p) · (Σ σ_i^−p)^(1/p), p = :data:`SOFT_COND_POWER`, a
  smooth upper bound of cond (cond ≤ c ≤ b^(2/p)·cond) without cond's kink where σ_max or
  σ_min is repeated, which is where cond's minimizer sits.
- ``dopt``: −log det(CᵀC) = −2 Σ log σ_i (D-optimality).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import scipy.linalg

from pe_drake.config import CRITERIA

#: p of ``soft_cond``: large enough that only the singular values within a few percent of the
#: extremes weigh (σ_i/σ_max = 0.9 counts 0.9^32 ≈ 3 %), small enough to stay smooth.
SOFT_COND_POWER = 32


@dataclasses.dataclass(frozen=True)
class CriterionValue:
    """A criterion's value c, its gradient ``grad`` dc/dC (C's shape; dc/dalpha from
    :meth:`ExcitationProblem.evaluate`) and the singular values σ of C, descending."""

    value: float
    grad: np.ndarray
    singular_values: np.ndarray


def evaluate_criterion(C: np.ndarray, criterion: str = "cond", gradient: bool = True) -> CriterionValue:
    """The criterion of C, shape (m, b) with m ≥ b, and (optionally) dc/dC via Eqs. (16)–(17);
    value inf and gradient 0 when C is rank deficient."""
    m, b = C.shape
    s, Vt = singular_values_and_vectors(C, vectors=gradient)
    value = _value(s, criterion)
    if not gradient:
        return CriterionValue(value, np.zeros(0), s)
    if s[-1] <= 0 or not np.isfinite(value):
        return CriterionValue(np.inf, np.zeros_like(C), s)
    # Left singular vectors u_i = C v_i / σ_i (relative error ~ ε·cond: fine up to 1e10).
    v_max, v_min = Vt[0], Vt[-1]
    u_max, u_min = C @ v_max / s[0], C @ v_min / s[-1]
    # Both are rank 2, a u_max v_maxᵀ + c u_min v_minᵀ: one (m, 2) × (2, b) product.
    if criterion == "cond":
        # Eq. (17), transposed to C's shape.
        grad = np.column_stack([u_max, u_min]) @ np.vstack([v_max / s[-1], -(s[0] / s[-1] ** 2) * v_min])
    elif criterion == "log_cond":
        grad = np.column_stack([u_max, u_min]) @ np.vstack([v_max / s[0], -v_min / s[-1]])
    elif criterion == "soft_cond":
        # c = exp(log c): dc/dC = c Σ_i (∂log c/∂σ_i) u_i v_iᵀ (Eq. 16) over the σ_i that weigh.
        weight = _soft_cond_log_weights(s)
        keep = np.abs(weight) > 1e-15 * np.abs(weight).max()
        U = (C @ Vt[keep].T) / s[keep]
        grad = value * (U * weight[keep]) @ Vt[keep]
    elif criterion == "dopt":
        U = (C @ Vt.T) / s
        grad = -2.0 * (U / s) @ Vt
    else:
        raise ValueError(f"unknown criterion '{criterion}'; valid: {', '.join(CRITERIA)}")
    return CriterionValue(value, grad, s)


def singular_values_and_vectors(C: np.ndarray, vectors: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """σ (descending) and Vᵀ of C (None without ``vectors``).

    C = QR is backward stable, so the b×b factor R has C's singular values and right vectors:
    one QR (without Q) and a small SVD. (The Gram matrix CᵀC would square the conditioning.)
    """
    m, b = C.shape
    C = np.asarray(C, float)
    if m > 2 * b:
        # LAPACK's geqrf and gesdd called directly: scipy's and numpy's argument handling
        # was a noticeable share of a gradient.
        qr, _, _, info = _GEQRF(C)
        _check_lapack("geqrf", info)
        R = qr[:b]
        R[_strictly_lower(b)] = 0.0  # geqrf's reflectors; np.triu built its mask each call
    else:
        R = C
    if not vectors:
        return np.linalg.svd(R, compute_uv=False), None
    _, s, Vt, info = _GESDD(R, compute_uv=1, full_matrices=0)
    _check_lapack("gesdd", info)
    return s, Vt


_GEQRF, _GESDD = scipy.linalg.get_lapack_funcs(("geqrf", "gesdd"), (np.zeros((1, 1)),))


@functools.lru_cache(maxsize=8)
def _strictly_lower(b: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices below the diagonal of a b × b matrix."""
    return np.tril_indices(b, -1)


def _check_lapack(routine: str, info: int) -> None:
    """numpy's error for a LAPACK failure (an SVD that did not converge), as numpy.linalg raises it."""
    if info != 0:
        raise np.linalg.LinAlgError(f"LAPACK {routine} failed (info = {info})")


def _soft_cond_sums(s: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """σ_i/σ_max, σ_min/σ_i and the sums of their p-th powers (all ≤ 1: no overflow)."""
    top, bottom = s / s[0], s[-1] / s
    return top, bottom, float(np.sum(top**SOFT_COND_POWER)), float(np.sum(bottom**SOFT_COND_POWER))


def _soft_cond_log_weights(s: np.ndarray) -> np.ndarray:
    """∂ log(soft_cond)/∂σ_i."""
    p = SOFT_COND_POWER
    top, bottom, A, B = _soft_cond_sums(s)
    return top ** (p - 1) / (A * s[0]) - bottom ** (p + 1) / (B * s[-1])


def _value(s: np.ndarray, criterion: str) -> float:
    if s[-1] <= 0:
        return np.inf
    if criterion == "cond":
        return float(s[0] / s[-1])
    if criterion == "soft_cond":
        _, _, A, B = _soft_cond_sums(s)
        return float(s[0] / s[-1] * (A * B) ** (1.0 / SOFT_COND_POWER))
    if criterion == "log_cond":
        return float(np.log(s[0]) - np.log(s[-1]))
    if criterion == "dopt":
        return float(-2.0 * np.sum(np.log(s)))
    raise ValueError(f"unknown criterion '{criterion}'; valid: {', '.join(CRITERIA)}")
