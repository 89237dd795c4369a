"""The library of candidate effects that a rigid-body model can miss, each with a physical name.

Per-joint effects are linear in their value θ, so each is one column c(q, v, v̇) appended to
the base-parameter regressor (τ = Y_B φ_B + Σ_k θ_k c_k):

=====================  ====================  =================  ==================  ==========
effect                 column c_j             unit (revolute)    unit (prismatic)    sign of θ
=====================  ====================  =================  ==================  ==========
``coulomb_friction``   tanh(v_j / v_s)        N·m                N                   θ ≥ 0
``viscous_friction``   v_j                    N·m·s/rad          N·s/m               θ ≥ 0
``armature``           v̇_j                   kg·m²              kg                  θ ≥ 0
``torque_offset``      1                      N·m                N                   any
``joint_stiffness``    q_j                    N·m/rad            N/m                 θ ≥ 0
=====================  ====================  =================  ==================  ==========

τ is the torque the actuator applies (:mod:`pe_drake.multibody.robot_model`), so a resistive
load adds to it; the caller filters the columns in parallel with the torque (Gautier 1997).
:func:`separability` tells whether any motion separates an effect from the rigid-body terms (an
armature on a first, vertical joint is one base parameter with that link's inertia).
``payload`` is not a column but a pattern in the re-identified base parameters,
Δφ_B = φ_B - K φ_prior ≈ K_L Δφ_L (Eq. 2), localized on one link (:func:`fit_payload`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.exceptions import UnknownNameError
from pe_drake.multibody.drive_columns import COULOMB_VELOCITY_SCALE, NONNEGATIVE, UNITS, term_values
from pe_drake.multibody.inertia import mass_on_a_line, phi_from_com, principal_inertia
from pe_drake.multibody.payload import link_columns
from pe_drake.multibody.regressor import RegressorModel

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Per-joint effects of the library, in the order they are listed in reports.
JOINT_EFFECTS = ("coulomb_friction", "viscous_friction", "armature", "torque_offset", "joint_stiffness")

#: Default relative a-priori uncertainty of every inertial parameter (CAD-level accuracy).
PRIOR_RELATIVE_UNCERTAINTY = 0.10

#: The drive term (:mod:`pe_drake.multibody.drive_columns`) of each per-joint effect.
EFFECT_TERMS = {"coulomb_friction": "coulomb", "viscous_friction": "viscous", "armature": "armature",
                "torque_offset": "offset"}
#: A spring at the joint (cables, a balancer): k·q_j, k ≥ 0, its rest angle held by the joint's
#: torque offset. Not a drive term of ``identify``.
STIFFNESS = "joint_stiffness"
STIFFNESS_UNITS = ("N·m/rad", "N/m")

#: The signal against which each effect's residual is plotted (the regime that exposes it).
EXPOSING_REGIME = {"coulomb_friction": "v", "viscous_friction": "v", "armature": "vd",
                   "torque_offset": "t", "joint_stiffness": "q", "payload": "q",
                   "time_delay": "dtau", "presliding_friction": "v", "holding_torque": "v"}


@dataclasses.dataclass(frozen=True)
class Candidate:
    """One per-joint effect of the library on one joint.

    Attributes:
        nonnegative: a physically meaningful value is ≥ ``lower`` (friction, armature).
        lower: that bound: 0, or for friction minus the model file's value on the joint (the
            value is what the model file lacks, the total d + θ must be ≥ 0).
    """

    effect: str
    joint: int
    joint_name: str
    unit: str
    nonnegative: bool
    lower: float = 0.0

    @property
    def label(self) -> str:
        return f"{self.effect}[{self.joint_name}]"


def joint_candidates(robot: Robot, effects: Sequence[str] = JOINT_EFFECTS) -> list[Candidate]:
    """Every per-joint effect on every joint (Coulomb friction on revolute joints only); a
    friction's ``lower`` is minus the model file's."""
    out = []
    model_file = {"viscous_friction": robot.joint_damping, "coulomb_friction": robot.joint_friction}
    for effect in effects:
        if effect not in JOINT_EFFECTS:
            raise UnknownNameError("effect", effect, JOINT_EFFECTS)
        for j, info in enumerate(robot.joints):
            if effect == "coulomb_friction" and info.kind != "revolute":
                continue  # the augmented Drake model holds Coulomb friction as a revolute DoorHinge
            units = STIFFNESS_UNITS if effect == STIFFNESS else UNITS[EFFECT_TERMS[effect]]
            lower = -float(model_file[effect][j]) if effect in model_file else 0.0
            nonnegative = effect == STIFFNESS or EFFECT_TERMS[effect] in NONNEGATIVE
            out.append(Candidate(effect, j, info.name, units[0 if info.kind == "revolute" else 1], nonnegative, lower))
    return out


def effect_column(effect: str, q: np.ndarray, v: np.ndarray, vd: np.ndarray, joint: int,
                  velocity_scale: float = COULOMB_VELOCITY_SCALE) -> np.ndarray:
    """The torque per unit value of one effect on ``joint``, (T,), from q, v, vd (T, n)."""
    if effect == STIFFNESS:
        return np.asarray(q, float)[:, joint].copy()
    if effect not in EFFECT_TERMS:
        raise ValueError(f"unknown effect '{effect}'")
    return term_values(EFFECT_TERMS[effect], v[:, [joint]], vd[:, [joint]], velocity_scale)[:, 0].copy()


@dataclasses.dataclass(frozen=True)
class Separability:
    """How far a candidate's column lies from the span of the base regressor.

    Attributes:
        residual: ‖(I - P_B) c‖ / ‖c‖ over random states (0: inside span(Y_B)).
        merged_with: when not separable, the base parameters the column is made of
            {name: coefficient}.
    """

    candidate: Candidate
    residual: float
    separable: bool
    merged_with: dict[str, float]


def separability(robot: Robot, base, candidates: Sequence[Candidate], *, model=None, samples: int = 200,
                 seed: int = 1, tolerance: float = 1e-6) -> list[Separability]:
    """Whether any motion can tell each candidate apart from the rigid-body terms, on random
    states within the robot's limits (``tolerance``: the relative residual inside span(Y_B))."""
    model = model or RegressorModel(robot)
    rng = np.random.default_rng(seed)
    lo, hi = robot.limits.q_lower, robot.limits.q_upper
    q = rng.uniform(lo, hi, (samples, robot.n))
    v = rng.uniform(-1, 1, (samples, robot.n)) * np.minimum(robot.limits.v_max, 3.0)
    vd = rng.uniform(-1, 1, (samples, robot.n)) * np.minimum(robot.limits.vd_max, 10.0)
    Y_B = base.reduce(model(q, v, vd)).reshape(-1, base.count)
    # Scale columns so the projection is not dominated by units.
    scale = np.linalg.norm(Y_B, axis=0)
    scale[scale == 0] = 1.0
    A = Y_B / scale
    out = []
    for c in candidates:
        col = np.zeros((samples, robot.n))
        col[:, c.joint] = effect_column(c.effect, q, v, vd, c.joint, velocity_scale=1.0)
        col = col.ravel()
        beta, *_ = np.linalg.lstsq(A, col, rcond=None)
        residual = float(np.linalg.norm(col - A @ beta) / max(np.linalg.norm(col), 1e-300))
        separable = residual > tolerance
        merged = {}
        if not separable:
            coef = beta / scale
            for k in np.flatnonzero(np.abs(coef) > 1e-6 * np.abs(coef).max()):
                merged[base.base_names[k]] = float(coef[k])
        out.append(Separability(c, residual, separable, merged))
    return out


def prior_parameter_covariance(robot: Robot, relative: float = PRIOR_RELATIVE_UNCERTAINTY, *,
                               samples: int = 400, seed: int = 0) -> np.ndarray:
    """Covariance Σ_φ (10·nb, 10·nb), block diagonal, of the standard parameters of an a-priori
    model accurate to ``relative`` ε in (0, 0.5], the perturbation of
    :func:`pe_drake.multibody.inertia.perturb_inertias`; each body's block from ``samples``
    draws (the map to the parameters about the body origin is not linear)."""
    rng = np.random.default_rng(seed)
    phi = np.asarray(robot.phi_model, float)
    nb = phi.size // 10
    Sigma = np.zeros((phi.size, phi.size))
    for b in range(nb):
        phi_b = phi[10 * b : 10 * b + 10]
        if phi_b[0] <= 0:
            continue
        d = _perturbation_draws(phi_b, relative, samples, rng) - phi_b
        Sigma[10 * b : 10 * b + 10, 10 * b : 10 * b + 10] = d.T @ d / samples
    return Sigma


def _perturbation_draws(phi_b: np.ndarray, eps: float, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` perturbed copies of one body's parameters, shape (count, 10) (vectorized
    form of the perturbation of :func:`pe_drake.multibody.inertia.perturb_inertias`)."""
    m, p, lam, R, r_gyr = principal_inertia(phi_b)
    if mass_on_a_line(phi_b):  # a rod: scale its second moments Σ = tr/2 − λ instead (never invalid)
        sigma = np.maximum(0.5 * lam.sum() - lam, 0.0) * (1 + eps * rng.uniform(-1, 1, (count, 3)))
        lam2 = sigma.sum(axis=1, keepdims=True) - sigma
    else:
        lam2 = np.empty((0, 3))
        while lam2.shape[0] < count:  # redraw principal moments that break the triangle inequality
            x = lam * (1 + eps * rng.uniform(-1, 1, (2 * count, 3)))
            lam2 = np.concatenate([lam2, x[x.max(axis=1) <= x.sum(axis=1) - x.max(axis=1)]])
        lam2 = lam2[:count]
    m2 = m * (1 + eps * rng.uniform(-1, 1, count))
    p2 = p + eps * rng.uniform(-1, 1, (count, 3)) * max(np.linalg.norm(p), r_gyr)
    axis = rng.normal(size=(count, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = eps * rng.uniform(-1, 1, count)
    Kx = np.zeros((count, 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2], Kx[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    Kx -= np.transpose(Kx, (0, 2, 1))
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    dR = np.eye(3) + s * Kx + (1 - c) * Kx @ Kx  # Rodrigues
    R2 = dR @ R
    return phi_from_com(m2, p2, np.einsum("kij,kj,klj->kil", R2, lam2, R2))


def payload_groups(robot: Robot, base) -> list[tuple[int, int, tuple[str, ...]]]:
    """Link groups (the bodies rigidly attached to one joint's child link) whose added mass is
    separable in K from the link's other 9 parameters.

    Returns:
        [(joint index, body index of the child link, names of the group's bodies)].
    """
    out = []
    K = base.K
    for j in range(robot.n):
        bodies = [b for b in range(robot.num_bodies) if robot.joint_of_body[b] == j]
        if not bodies:
            continue
        child = robot.joints[j].child_body
        lead = next((b for b in bodies if int(robot.body_indices[b]) == child), bodies[0])
        K_L = K[:, link_columns(robot, lead)]
        rank = np.linalg.matrix_rank(K_L, 1e-9)
        if rank == 0 or np.linalg.matrix_rank(K_L[:, 1:], 1e-9) == rank:
            continue
        out.append((j, lead, tuple(robot.body_names[b] for b in bodies)))
    return out


def fit_payload(delta_B: np.ndarray, C: np.ndarray, K_L: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Generalized least squares Δφ_B ≈ K_L x with covariance C (Eq. 2 restricted to a link).

    Args:
        delta_B: Δφ_B, shape (b,).
        C: its covariance under "no payload" (a-priori uncertainty + estimation), (b, b).
        K_L: the link's columns of K, (b, 10).

    Returns:
        (x (10,), its covariance (10, 10) (pseudo-inverse where K_L is rank deficient), the χ²
        of the residual).
    """
    L = _whitener(C)
    A = L @ K_L
    y = L @ delta_B
    cov = np.linalg.pinv(A.T @ A, rcond=1e-10)

    x = cov @ A.T @ y
    r = y - A @ x
    return x, cov, float(r @ r)


def chi2(delta_B: np.ndarray, C: np.ndarray) -> float:
    """Δφ_Bᵀ C⁻¹ Δφ_B."""
    y = _whitener(C) @ delta_B
    return float(y @ y)


def _whitener(C: np.ndarray) -> np.ndarray:
    """W with Wᵀ W = C⁻¹ (eigen-decomposition; directions of zero variance get a floor)."""
    w, V = np.linalg.eigh(0.5 * (C + C.T))
    floor = max(w.max(), 1e-300) * 1e-12
    return (V / np.sqrt(np.maximum(w, floor))).T


def chi2_quantile(p: float, dof: int) -> float:
    """Quantile of the χ² distribution (scipy.special, lighter to import than scipy.stats)."""
    from scipy.special import chdtri

    return float(chdtri(max(int(dof), 1), 1.0 - p))
