"""Batched spatial-vector algebra in Drake's ordering [rotational; translational].

Every function works on arrays whose last axis has length 6 (or 6 × 10 for regressor
blocks) and broadcasts over the leading axes (samples, bodies, parameters). Motion vectors
m = [ω; v], force vectors f = [n; f]. See docs/derivations.md.
"""

from __future__ import annotations

import numpy as np


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b over the last axis (3,), broadcasting; faster than np.cross on small arrays."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    shape = np.broadcast_shapes(a.shape, b.shape)
    out = np.empty(shape)
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def rotate(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R @ v for rotations R (..., 3, 3) and vectors v (..., 3), broadcasting over the
    leading axes; 4–6× faster than einsum on thousands of small matrices."""
    out = R[..., 0] * v[..., 0, None]
    out += R[..., 1] * v[..., 1, None]
    out += R[..., 2] * v[..., 2, None]
    return out


def cross_motion(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a ×m b for motion vectors: [aω × bω; aω × bv + av × bω]."""
    aw, av, bw, bv = a[..., :3], a[..., 3:], b[..., :3], b[..., 3:]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., :3] = cross3(aw, bw)
    out[..., 3:] = cross3(aw, bv) + cross3(av, bw)
    return out


def cross_force(a: np.ndarray, f: np.ndarray) -> np.ndarray:
    """a ×* f for a motion a and a force f: [aω × n + av × f; aω × f]."""
    aw, av, n, ff = a[..., :3], a[..., 3:], f[..., :3], f[..., 3:]
    out = np.empty(np.broadcast_shapes(a.shape, f.shape))
    out[..., :3] = cross3(aw, n) + cross3(av, ff)
    out[..., 3:] = cross3(aw, ff)
    return out


def inertia_times(x: np.ndarray) -> np.ndarray:
    """Γ(x): the (6, 10) matrix with M(φ) x = Γ(x) φ for a body-frame spatial inertia M(φ).

    φ = [m, hx, hy, hz, Ixx, Iyy, Izz, Ixy, Ixz, Iyz] (pe_drake.multibody.robot.PARAMETER_NAMES) and
    M(φ) = [[I, [h]×], [-[h]×, m·1]], so M x = [I xω + h × xv; m xv - h × xω].

    Args:
        x: shape (..., 6).

    Returns:
        shape (..., 6, 10).
    """
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
    """Σ_k Γ(x_k)[:, k]: the inertia of unit parameter k applied to its own vector x_k.

    Args:
        x: shape (..., 10, 6), one motion vector per parameter.

    Returns:
        shape (..., 6).
    """
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
    """Net spatial force on a body as a linear map of its 10 parameters (body coordinates).

    F = M(φ) A + V ×* M(φ) V = [Γ(A) + crf(V) Γ(V)] φ, with V the spatial velocity and A the
    spatial (Featherstone) acceleration of the body, gravity included as a base acceleration.

    Args:
        V, A: shape (..., 6).

    Returns:
        shape (..., 6, 10).
    """
    G_V = inertia_times(V)
    return inertia_times(A) + np.moveaxis(cross_force(V[..., None, :], np.moveaxis(G_V, -1, -2)), -1, -2)


def skew(x: np.ndarray) -> np.ndarray:
    """[x]×, the (..., 3, 3) matrix with [x]× y = x × y."""
    out = np.zeros(x.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -x[..., 2], x[..., 1]
    out[..., 1, 0], out[..., 1, 2] = x[..., 2], -x[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -x[..., 1], x[..., 0]
    return out


# ---- 6 × 6 matrices: one batched matmul applies them to many vectors of the same body ----------


def force_transform_matrix(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """X* = [[R, [p]× R], [0, R]], (..., 6, 6): a force [n; f] at a body's origin in body
    coordinates (R = R_WB, p = p_WBo) to world coordinates at the world origin. Its transpose
    takes a world-origin motion vector to the body: [Rᵀ ω; Rᵀ (v − p × ω)]."""
    X = np.zeros(R.shape[:-2] + (6, 6))
    X[..., :3, :3] = R
    X[..., 3:, 3:] = R
    X[..., :3, 3:] = skew(p) @ R
    return X


def cross_force_matrix(a: np.ndarray) -> np.ndarray:
    """[a ×*] with [a ×*] f = :func:`cross_force` (a, f): [[ω×, v×], [0, ω×]], (..., 6, 6)."""
    X = np.zeros(a.shape[:-1] + (6, 6))
    W = skew(a[..., :3])
    X[..., :3, :3] = W
    X[..., 3:, 3:] = W
    X[..., :3, 3:] = skew(a[..., 3:])
    return X


def cross_motion_matrix(a: np.ndarray) -> np.ndarray:
    """[a ×m] with [a ×m] m = :func:`cross_motion` (a, m): [[ω×, 0], [v×, ω×]], (..., 6, 6)."""
    X = np.zeros(a.shape[:-1] + (6, 6))
    W = skew(a[..., :3])
    X[..., :3, :3] = W
    X[..., 3:, 3:] = W
    X[..., 3:, :3] = skew(a[..., 3:])
    return X


def summed_cross_force(a: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Σ_k a_k ×* f_k over the second-to-last axis, (..., K, 6) × (..., K, 6) → (..., 6).

    Σ_k x_k × y_k is the axial vector of M - Mᵀ with M = Σ_k x_k y_kᵀ, so the whole sum
    is one batched matmul M = aᵀ f (6 × 6) instead of K cross products.
    """
    M = a.swapaxes(-1, -2) @ f

    def axial(B):
        return np.stack([B[..., 1, 2] - B[..., 2, 1], B[..., 2, 0] - B[..., 0, 2], B[..., 0, 1] - B[..., 1, 0]], -1)

    out = np.empty(M.shape[:-2] + (6,))
    out[..., :3] = axial(M[..., :3, :3]) + axial(M[..., 3:, 3:])
    out[..., 3:] = axial(M[..., :3, 3:])
    return out
