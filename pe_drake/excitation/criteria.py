"""Excitation criteria of the stacked base regressor C and their gradients dc/dC.

All three use the singular values of C and their derivative ∂σ_i/∂C = u_i v_iᵀ (Eq. 16):

- ``cond``: c = σ_max/σ_min (Eq. 5); dc/dC is Eq. (17). The paper's criterion.
- ``log_cond``: log σ_max − log σ_min. Same minimizer as cond, but its gradient has the
  scale of 1 instead of cond, so quasi-Newton steps behave when cond is large (>1e3),
  e.g. at a poor initial point; prefer it when cond starts above ~1e4.
- ``dopt``: −log det(CᵀC) = −2 Σ log σ_i (D-optimality): maximizes the information in all
  directions, not only the worst one; smoother (no kink when σ_min is repeated) and it
  rewards large motion, so it saturates the limits. Prefer it when the goal is low parameter
  variance overall rather than a well-balanced C.

Gradients are returned with the shape of C.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.linalg


@dataclasses.dataclass(frozen=True)
class CriterionValue:
    """A criterion's value, gradient, and the singular values it came from.

    Attributes:
        value: c.
        grad: dc/dC, same shape as C.
        singular_values: σ of C, descending.
    """

    value: float
    grad: np.ndarray
    singular_values: np.ndarray


def evaluate_criterion(C: np.ndarray, criterion: str = "cond", gradient: bool = True) -> CriterionValue:
    """The criterion of C and (optionally) its gradient via Eqs. (16)–(17).

    Args:
        C: the stacked base regressor, shape (m, b) with m ≥ b.
        criterion: "cond", "log_cond" or "dopt".
        gradient: compute dc/dC.

    Returns:
        A :class:`CriterionValue` (value inf/gradient 0 when C is rank deficient).
    """
    m, b = C.shape
    s, Vt = _singular_values_and_vectors(C, vectors=gradient)
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
    elif criterion == "dopt":
        U = (C @ Vt.T) / s
        grad = -2.0 * (U / s) @ Vt
    else:
        raise ValueError(f"unknown criterion '{criterion}'; valid: cond, log_cond, dopt")
    return CriterionValue(value, grad, s)


def _singular_values_and_vectors(C: np.ndarray, vectors: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """σ (descending) and Vᵀ of C.

    C = QR is backward stable, so the b×b factor R has C's singular values and right
    vectors: one QR (without Q) and a small SVD, ~25 % cheaper than the SVD of a tall C.
    (The Gram matrix CᵀC would be cheaper still but squares the conditioning: its σ_min
    carries a relative error ε·cond², enough to spoil finite-difference checks of cond.)
    """
    m, b = C.shape
    R = scipy.linalg.qr(C, mode="r", check_finite=False)[0][:b] if m > 2 * b else C
    if not vectors:
        return np.linalg.svd(R, compute_uv=False), None
    _, s, Vt = np.linalg.svd(R, full_matrices=False)
    return s, Vt


def _value(s: np.ndarray, criterion: str) -> float:
    if s[-1] <= 0:
        return np.inf
    if criterion == "cond":
        return float(s[0] / s[-1])
    if criterion == "log_cond":
        return float(np.log(s[0]) - np.log(s[-1]))
    if criterion == "dopt":
        return float(-2.0 * np.sum(np.log(s)))
    raise ValueError(f"unknown criterion '{criterion}'; valid: cond, log_cond, dopt")
