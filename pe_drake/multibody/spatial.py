"""Batched spatial-vector algebra in Drake's ordering [rotational; translational].

Every function works on arrays whose last axis has length 6 (or 6 × 10 for regressor
blocks) and broadcasts over the leading axes (samples, bodies, parameters). Motion vectors
m = [ω; v], force vectors f = [n; f]. See docs/derivations.md.
"""

from __future__ import annotations

import numpy as np

# ---- constant tensors -----------------------------------------------------------------------
# Every map here is linear or bilinear with coefficients 0 and ±1: one gather, multiply and
# matmul with a constant matrix beats numpy's per-call overhead of slice-by-slice formulas
# (issue 38). Each entry is the same sum of the same products as the explicit formula.


def _levi_civita() -> np.ndarray:
    eps = np.zeros((3, 3, 3))
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        eps[i, j, k], eps[i, k, j] = 1.0, -1.0
    return eps


def _spatial_cross_tensor(force: bool) -> np.ndarray:
    """E with (a × b)_i = Σ_jk E_ijk a_j b_k: a ×m b, or a ×* f when ``force``."""
    eps, E = _levi_civita(), np.zeros((6, 6, 6))
    E[:3, :3, :3] = eps
    if force:
        E[:3, 3:, 3:] = eps
        E[3:, :3, 3:] = eps
    else:
        E[3:, :3, 3:] = eps
        E[3:, 3:, :3] = eps
    return E


def _bilinear_terms(E: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(j, k, M) with out = (a[..., j] * b[..., k]) @ M: the non-zero terms of E, summed by M."""
    i, j, k = np.nonzero(E)
    M = np.zeros((len(i), E.shape[0]))
    M[np.arange(len(i)), i] = E[i, j, k]
    return j, k, M


_CROSS_LEFT, _CROSS_RIGHT = np.array([1, 2, 0, 2, 0, 1]), np.array([2, 0, 1, 1, 2, 0])
_MOTION_TENSOR, _FORCE_TENSOR = _spatial_cross_tensor(False), _spatial_cross_tensor(True)
_MOTION_A, _MOTION_B, _MOTION_SUM = _bilinear_terms(_MOTION_TENSOR)
_FORCE_A, _FORCE_B, _FORCE_SUM = _bilinear_terms(_FORCE_TENSOR)
#: [x]× = (x @ _SKEW) reshaped (3, 3): [x]×_ik = Σ_j ε_ijk x_j.
_SKEW = _levi_civita().transpose(1, 0, 2).reshape(3, 9)
#: [a ×*] as (a @ matrix) reshaped (6, 6).
_FORCE_MATRIX = _FORCE_TENSOR.transpose(1, 0, 2).reshape(6, 36)
#: Σ_k a_k ×* f_k = (aᵀ f) reshaped (36,) @ this: the force cross tensor contracted with M = aᵀ f.
_SUMMED_FORCE = _FORCE_TENSOR.transpose(0, 2, 1).reshape(6, 36).T


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b over the last axis (3,), broadcasting; faster than np.cross on small arrays."""
    x = a[..., _CROSS_LEFT] * b[..., _CROSS_RIGHT]
    return x[..., :3] - x[..., 3:]


def rotate(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R @ v for rotations R (..., 3, 3) and vectors v (..., 3), broadcasting; beats einsum."""
    out = R[..., 0] * v[..., 0, None]
    out += R[..., 1] * v[..., 1, None]
    out += R[..., 2] * v[..., 2, None]
    return out


def cross_motion(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a ×m b for motion vectors: [aω × bω; aω × bv + av × bω]."""
    return (a[..., _MOTION_A] * b[..., _MOTION_B]) @ _MOTION_SUM


def cross_force(a: np.ndarray, f: np.ndarray) -> np.ndarray:
    """a ×* f for a motion a and a force f: [aω × n + av × f; aω × f]."""
    return (a[..., _FORCE_A] * f[..., _FORCE_B]) @ _FORCE_SUM


def inertia_times(x: np.ndarray) -> np.ndarray:
    """Γ(x), (..., 6, 10): M(φ) x = Γ(x) φ for a body-frame spatial inertia M(φ), x (..., 6).

    M(φ) = [[I, [h]×], [-[h]×, m·1]], so M x = [I xω + h × xv; m xv - h × xω].
    """
    return (x @ _GAMMA).reshape(x.shape[:-1] + (6, 10))


def _inertia_times_formula(x: np.ndarray) -> np.ndarray:
    """Γ(x) entry by entry (builds :data:`_GAMMA` from unit vectors)."""
    xw, xv = x[..., :3], x[..., 3:]
    out = np.zeros(x.shape[:-1] + (6, 10))
    # h × xv = -[xv]× h
    out[..., 0:3, 1:4] = -skew(xv)
    # I xω with I = [[Ixx, Ixy, Ixz], [Ixy, Iyy, Iyz], [Ixz, Iyz, Izz]]
    w1, w2, w3 = xw[..., 0], xw[..., 1], xw[..., 2]
    out[..., 0, 4], out[..., 0, 7], out[..., 0, 8] = w1, w2, w3
    out[..., 1, 5], out[..., 1, 7], out[..., 1, 9] = w2, w1, w3
    out[..., 2, 6], out[..., 2, 8], out[..., 2, 9] = w3, w1, w2
    # m xv - h × xω = m xv + [xω]× h
    out[..., 3:6, 0] = xv
    out[..., 3:6, 1:4] = skew(xw)
    return out


def inertia_times_diagonal(x: np.ndarray) -> np.ndarray:
    """Σ_k Γ(x_k)[:, k], (..., 6): the inertia of unit parameter k on its own x_k (..., 10, 6)."""
    return x.reshape(x.shape[:-2] + (60,)) @ _GAMMA_DIAGONAL


def _inertia_times_diagonal_formula(x: np.ndarray) -> np.ndarray:
    """Σ_k Γ(x_k)[:, k] entry by entry (builds :data:`_GAMMA_DIAGONAL` from unit vectors)."""
    out = np.zeros(x.shape[:-2] + (6,))
    # m: [0; x_v]
    out[..., 3:] = x[..., 0, 3:]
    # h_c (c = x, y, z), with x_c = x[..., 1 + c, :]: [-(x_c,v × e_c); x_c,ω × e_c], using
    # a × e_x = (0, a_z, -a_y), a × e_y = (-a_z, 0, a_x), a × e_z = (a_y, -a_x, 0).
    hx, hy, hz = x[..., 1, :], x[..., 2, :], x[..., 3, :]
    out[..., 0] += hy[..., 5] - hz[..., 4]
    out[..., 1] += hz[..., 3] - hx[..., 5]
    out[..., 2] += hx[..., 4] - hy[..., 3]
    out[..., 3] += hz[..., 1] - hy[..., 2]
    out[..., 4] += hx[..., 2] - hz[..., 0]
    out[..., 5] += hy[..., 0] - hx[..., 1]
    # Ixx, Iyy, Izz, Ixy, Ixz, Iyz acting on the angular part.
    w = x[..., 4:10, :3]
    out[..., 0] += w[..., 0, 0] + w[..., 3, 1] + w[..., 4, 2]
    out[..., 1] += w[..., 1, 1] + w[..., 3, 0] + w[..., 5, 2]
    out[..., 2] += w[..., 2, 2] + w[..., 4, 0] + w[..., 5, 1]
    return out


def body_regressor(V: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Net spatial force on a body as a linear map of its 10 parameters, (..., 6, 10).

    F = M(φ) A + V ×* M(φ) V = [Γ(A) + crf(V) Γ(V)] φ, with V (..., 6) the spatial velocity and
    A the spatial acceleration of the body, gravity included as a base acceleration.
    """
    G_V = inertia_times(V)
    return inertia_times(A) + np.moveaxis(cross_force(V[..., None, :], np.moveaxis(G_V, -1, -2)), -1, -2)


def skew(x: np.ndarray) -> np.ndarray:
    """[x]×, the (..., 3, 3) matrix with [x]× y = x × y."""
    return (x @ _SKEW).reshape(x.shape[:-1] + (3, 3))


# ---- 6 × 6 matrices: one batched matmul applies them to many vectors of the same body ----------


def force_transform_matrix(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """X* = [[R, [p]× R], [0, R]], (..., 6, 6): a body-origin force [n; f] (R = R_WB, p = p_WBo)
    to the world origin. Its transpose takes a world-origin motion vector to the body."""
    X = np.zeros(R.shape[:-2] + (6, 6))
    X[..., :3, :3] = R
    X[..., 3:, 3:] = R
    X[..., :3, 3:] = skew(p) @ R
    return X


def cross_force_matrix(a: np.ndarray) -> np.ndarray:
    """[a ×*] with [a ×*] f = :func:`cross_force` (a, f): [[ω×, v×], [0, ω×]], (..., 6, 6)."""
    return (a @ _FORCE_MATRIX).reshape(a.shape[:-1] + (6, 6))


def summed_cross_force_of(fa: np.ndarray) -> np.ndarray:
    """Σ_k a_k ×* f_k from the 6 × 6 matrix fᵀ a = Σ_k f_k a_kᵀ, (..., 6, 6) → (..., 6)."""
    return fa.reshape(fa.shape[:-2] + (36,)) @ _SUMMED_FORCE


#: Γ(x) = (x @ _GAMMA) reshaped (6, 10); Σ_k Γ(x_k)[:, k] = x (60,) @ _GAMMA_DIAGONAL.
_GAMMA = _inertia_times_formula(np.eye(6)).reshape(6, 60)
_GAMMA_DIAGONAL = _inertia_times_diagonal_formula(np.eye(60).reshape(60, 10, 6))
