"""A body's 10 inertial parameters: names, packing, the parallel-axis theorem, validity.

φ_b = [m, hx, hy, hz, Ixx, Iyy, Izz, Ixy, Ixz, Iyz] with h = m·p_BoBcm_B the first moment and
I = I_BBo_B the rotational inertia about the body origin Bo, both expressed in the body frame B.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from pe_drake.config import check_finite
from pe_drake.exceptions import ConfigError, PeDrakeError

#: Number of inertial parameters per body, in the order of :data:`PARAMETER_NAMES`.
PARAMS_PER_BODY = 10
PARAMETER_NAMES = ("m", "hx", "hy", "hz", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")


class PhysicallyInvalidError(PeDrakeError, ValueError):
    """Inertial parameters that Drake refuses as a rigid body; ``bodies`` is {name: reason}."""

    def __init__(self, bodies: dict[str, str]):
        self.bodies = dict(bodies)
        names = ", ".join(self.bodies)
        first = next(iter(self.bodies.values()), "")
        super().__init__(
            f"the inertial parameters of {len(self.bodies)} body(ies) are not physically valid: "
            f"{names} (first: {first}); write a physically consistent estimate (method 'physical') "
            "instead")


def inertia_matrix(i6: np.ndarray) -> np.ndarray:
    """[Ixx, Iyy, Izz, Ixy, Ixz, Iyz] → the symmetric 3×3 matrix; shape (..., 6) → (..., 3, 3)."""
    i6 = np.asarray(i6, float)
    Ixx, Iyy, Izz, Ixy, Ixz, Iyz = np.moveaxis(i6, -1, 0)
    rows = [np.stack([Ixx, Ixy, Ixz], -1), np.stack([Ixy, Iyy, Iyz], -1), np.stack([Ixz, Iyz, Izz], -1)]
    return np.stack(rows, -2)


def inertia_vector(I: np.ndarray) -> np.ndarray:
    """The symmetric 3×3 matrix → [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]; shape (..., 3, 3) → (..., 6)."""
    I = np.asarray(I, float)
    return np.stack([I[..., 0, 0], I[..., 1, 1], I[..., 2, 2], I[..., 0, 1], I[..., 0, 2], I[..., 1, 2]], -1)


def parallel_axis(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    """m (|p|² 1 − p pᵀ), the inertia of a point mass m at p about the origin (parallel-axis
    theorem); m shape (...), p shape (..., 3) → (..., 3, 3)."""
    m, p = np.asarray(m, float), np.asarray(p, float)
    pp = np.einsum("...i,...i->...", p, p)
    return m[..., None, None] * (pp[..., None, None] * np.eye(3) - p[..., :, None] * p[..., None, :])


def phi_from_com(m: np.ndarray, p: np.ndarray, I_cm: np.ndarray) -> np.ndarray:
    """φ_b from mass, centre of mass p_BoBcm_B and inertia I_BBcm_B; (...), (..., 3),
    (..., 3, 3) → (..., 10)."""
    m = np.asarray(m, float)
    I_Bo = np.asarray(I_cm, float) + parallel_axis(m, p)
    return np.concatenate([m[..., None], m[..., None] * np.asarray(p, float), inertia_vector(I_Bo)], -1)


def central_inertia(phi_b: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """m [kg], p_BoBcm_B (3,) [m] and I_BBcm_B (3, 3) [kg·m²] of one body's 10 parameters.

    A massless body gives a zero centre of mass and its inertia about Bo.
    """
    phi_b = np.asarray(phi_b, float)
    m = float(phi_b[0])
    I_Bo = inertia_matrix(phi_b[4:10])
    if m == 0.0:
        return 0.0, np.zeros(3), I_Bo
    p = phi_b[1:4] / m
    return m, p, I_Bo - parallel_axis(m, p)


def principal_inertia(phi_b: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, float]:
    """(m, p, λ, R, r): mass, centre of mass, principal moments λ ≥ 0 and axes R of I_cm
    (I_cm = R diag(λ) Rᵀ), and the radius of gyration r = sqrt(tr I_cm / 2m)."""
    m, p, I_cm = central_inertia(phi_b)
    lam, R = np.linalg.eigh(I_cm)
    return m, p, np.maximum(lam, 0.0), R, math.sqrt(max(np.trace(I_cm), 0.0) / (2 * m))


def pseudo_inertia(phi_b: np.ndarray) -> np.ndarray:
    """J(φ_b) = [[½tr(I)·1 − I, h], [hᵀ, m]] (Wensing et al. 2017), shape (4, 4).

    J ⪰ 0 exactly when a non-negative mass density produces the body's mass, first moment
    and inertia about the origin (Drake's physical validity).
    """
    phi_b = np.asarray(phi_b, float)
    I = inertia_matrix(phi_b[4:10])
    J = np.zeros((4, 4))
    J[:3, :3] = 0.5 * np.trace(I) * np.eye(3) - I
    J[:3, 3] = J[3, :3] = phi_b[1:4]
    J[3, 3] = phi_b[0]
    return J


def pseudo_inertia_basis() -> list[np.ndarray]:
    """F_i with J(φ_b) = Σ_i φ_b,i F_i (J is linear in φ_b)."""
    return [pseudo_inertia(e) for e in np.eye(PARAMS_PER_BODY)]


def phi_from_pseudo_inertia(J: np.ndarray) -> np.ndarray:
    """The inverse of :func:`pseudo_inertia`: Σ = J[:3, :3] gives I = tr(Σ)·1 − Σ."""
    Sigma = J[:3, :3]
    I = np.trace(Sigma) * np.eye(3) - Sigma
    return np.concatenate([[J[3, 3]], J[:3, 3], inertia_vector(I)])


def spatial_inertia_to_phi(M) -> np.ndarray:
    """Drake SpatialInertia about Bo in B → the 10 parameters of :data:`PARAMETER_NAMES`."""
    m = M.get_mass()
    I = M.CalcRotationalInertia().CopyToFullMatrix3()
    return np.concatenate([[m], m * np.asarray(M.get_com()), inertia_vector(I)])


def phi_to_spatial_inertia(phi: np.ndarray, skip_validity_check: bool = True):
    """The 10 parameters → Drake SpatialInertia about Bo in B."""
    from pydrake.multibody.tree import SpatialInertia, UnitInertia  # lazy: keeps import light

    m = float(phi[0])
    if m == 0:
        if np.any(np.asarray(phi[1:]) != 0):
            raise ValueError("a massless body must have zero first moment and inertia")
        return SpatialInertia.Zero()  # Drake's default UnitInertia() is NaN, not zero
    p = np.asarray(phi[1:4]) / m
    Ixx, Iyy, Izz, Ixy, Ixz, Iyz = phi[4:10]
    G = UnitInertia(Ixx / m, Iyy / m, Izz / m, Ixy / m, Ixz / m, Iyz / m)
    return SpatialInertia(m, p, G, skip_validity_check)


def validity_problems(body_names: Sequence[str], phi: np.ndarray) -> dict[str, str]:
    """Bodies whose parameters (10·nb,) Drake does not accept, as {body: reason}.

    A body is valid when ``SpatialInertia(m, p, G, skip_validity_check=False)`` can be built,
    or when all its parameters are zero (a massless frame).
    """
    phi = np.asarray(phi, float)
    problems: dict[str, str] = {}
    if phi.shape != (PARAMS_PER_BODY * len(body_names),):
        raise ConfigError(f"phi has shape {phi.shape}, expected ({PARAMS_PER_BODY * len(body_names)},)")
    for b, name in enumerate(body_names):
        phi_b = phi[10 * b : 10 * b + 10]
        if not np.all(np.isfinite(phi_b)):
            problems[name] = "a parameter is NaN or infinite"
            continue
        if phi_b[0] == 0.0:
            if np.any(phi_b[1:] != 0.0):
                problems[name] = "zero mass with a non-zero first moment or inertia"
            continue
        if phi_b[0] < 0.0:
            problems[name] = f"negative mass {phi_b[0]:.6g} kg"
            continue
        try:
            M = phi_to_spatial_inertia(phi_b, skip_validity_check=True)
            if not M.IsPhysicallyValid():
                moments = np.linalg.eigvalsh(central_inertia(phi_b)[2])
                problems[name] = (
                    f"principal moments about the centre of mass {np.array2string(moments, precision=4)} "
                    "kg·m² are negative or violate the triangle inequality")
        except (RuntimeError, ValueError) as err:
            problems[name] = str(err).splitlines()[0]
    return problems


def check_physically_valid(body_names: Sequence[str], phi: np.ndarray) -> None:
    """Raises :class:`PhysicallyInvalidError` listing every invalid body."""
    problems = validity_problems(body_names, phi)
    if problems:
        raise PhysicallyInvalidError(problems)


def perturb_inertias(phi: np.ndarray, size: float, rng: int | np.random.Generator = 0,
                     max_tries: int = 100, body_names: tuple[str, ...] | None = None) -> np.ndarray:
    """Random, physically valid perturbation of every body's inertial parameters (10·nb,).

    Per body with mass m > 0, with U uniform in [-1, 1] drawn for each number: m' = m (1 + ε U);
    p' = p + ε U₃ max(|p|, r) (r the radius of gyration); principal moments λ' = λ (1 + ε U₃),
    redrawn until they satisfy the triangle inequality, axes rotated by ε U [rad] about a random
    axis. A thin rod (:func:`mass_on_a_line`) scales its second moments Σ_i = tr/2 − λ_i instead,
    which keeps a rod a rod.

    Args:
        size: ε, relative size in [0, 0.5].
        max_tries: redraws per body before giving up.
        body_names: the bodies' names, for the ConfigError of a body that cannot be made valid.
    """
    size = check_finite("inertia_perturbation", size, nonneg=True)
    if size > 0.5:
        raise ConfigError(f"inertia_perturbation must lie in [0, 0.5], got {size}")
    rng = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng
    phi = np.asarray(phi, float)
    out = phi.copy()
    if size == 0:
        return out
    for b in range(phi.size // 10):
        m = phi[10 * b]
        if m <= 0:
            continue
        rod = mass_on_a_line(phi[10 * b : 10 * b + 10])
        for _ in range(max_tries):
            new = _perturb_body(phi[10 * b : 10 * b + 10], size, rng, second_moments=rod)
            if new is not None and phi_to_spatial_inertia(new).IsPhysicallyValid():
                out[10 * b : 10 * b + 10] = new
                break
        else:
            name = f"body '{body_names[b]}'" if body_names is not None else f"body {b}"
            raise ConfigError(f"{name}: could not perturb its inertia into a physically valid "
                              f"one in {max_tries} tries; is the model's inertia valid?")
    return out


#: A body whose two smallest second moments of mass Σ_i = tr(I_cm)/2 − λ_i are below this
#: fraction of tr(I_cm)/2 holds its mass on a line (a rod: λ = (a, a, 0)), where relative draws
#: of λ almost never meet the triangle inequalities again.
ROD_TOLERANCE = 1e-3


def mass_on_a_line(phi_b: np.ndarray) -> bool:
    """Whether a body's mass lies (nearly) on a line, a thin rod (see :data:`ROD_TOLERANCE`)."""
    _, _, lam, _, _ = principal_inertia(phi_b)
    half_trace = 0.5 * float(lam.sum())
    return half_trace > 0 and float(np.sort(half_trace - lam)[1]) <= ROD_TOLERANCE * half_trace


def _perturb_body(phi_b: np.ndarray, eps: float, rng: np.random.Generator,
                  second_moments: bool = False) -> np.ndarray | None:
    """One draw of :func:`perturb_inertias` for one body, or None when it broke the triangle
    inequality; ``second_moments`` scales Σ = tr/2 − λ instead of λ."""
    m, p, lam, R, r_gyr = principal_inertia(phi_b)
    m2 = m * (1 + eps * rng.uniform(-1, 1))
    p2 = p + eps * rng.uniform(-1, 1, 3) * max(np.linalg.norm(p), r_gyr)
    if second_moments:
        sigma2 = np.maximum(0.5 * lam.sum() - lam, 0.0) * (1 + eps * rng.uniform(-1, 1, 3))
        lam2 = sigma2.sum() - sigma2  # λ_i = Σ_j + Σ_k
    else:
        lam2 = lam * (1 + eps * rng.uniform(-1, 1, 3))
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = eps * rng.uniform(-1, 1)
    if lam2.max() > lam2.sum() - lam2.max():  # triangle inequality
        return None
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    dR = np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K  # Rodrigues
    R2 = dR @ R
    return phi_from_com(m2, p2, R2 @ np.diag(lam2) @ R2.T)


#: What works on a model whose moving bodies all have zero mass (no ``<inertial>``).
NO_INERTIALS_NOTE = (
    "the model has no inertial parameters (every moving body's mass is 0): optimize, identify (ols, wls, "
    "physical) and diagnose work without them (identify finds them); simulate, the playback's centre of mass, "
    "excitation.torque_limits and payload identification need them: use the model.urdf of identify --method physical")
