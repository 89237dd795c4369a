"""The identified robot for a controller and a training config: friction feed-forward
τ_f = f_c·tanh(v/v_s) + b·v + τ_0, PD gains k_p = J·ω², k_d = 2·ζ·J·ω from the effective inertia
J_i(q) = M_ii(q) + armature_i, and randomization ranges and models drawn from the
identification's σ (mapped onto the standard parameters by δφ = W Kᵀ (K W Kᵀ)⁺ δ).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.diagnosis.augmented_model import physically_consistent
from pe_drake.export.model_source import IdentifiedSpread
from pe_drake.multibody.drive_columns import coulomb_column
from pe_drake.multibody.inertia import central_inertia, validity_problems
from pe_drake.multibody.robot_model import DRIVE_TERMS, RobotModel

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


def _dump(data) -> str:
    import yaml  # lazy: only the YAML exports need it

    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=120, allow_unicode=True)


def _unit(robot: Robot, k: int) -> tuple[str, str]:
    """(force unit, velocity unit) of joint k."""
    return ("N", "m/s") if robot.joints[k].kind == "prismatic" else ("N·m", "rad/s")


def feedforward_yaml(robot: Robot, model: RobotModel, check: dict | None = None, source: str = "") -> str:
    """The friction and offset feed-forward per joint as YAML, with ``check`` figures of it on a
    held-out run; ``source`` names the model file ("": the robot's own model)."""
    joints = {}
    for k, name in enumerate(robot.joint_names):
        force, speed = _unit(robot, k)
        # a pre-sliding friction enters at its sliding level (RobotModel.sliding_friction)
        c, b, o = (float(x[k]) for x in (model.sliding_friction, model.viscous, model.offset))
        joints[name] = {
            "coulomb": c, "viscous": b, "offset": o, "units": f"{force}, {force}/({speed}), {force}",
            # firmware tables with separate signs: the identified model is symmetric
            "table": {"coulomb_pos": c + o, "coulomb_neg": c - o, "viscous_pos": b, "viscous_neg": b,
                      "velocity_threshold": model.velocity_scale},
        }
    data = {
        "robot": robot.name, "model": source or "CAD",
        "formula": "tau_friction = coulomb * tanh(v / velocity_scale) + viscous * v + offset",
        "velocity_scale": model.velocity_scale,
        "sign": "the log's: a positive torque drives the joint in its positive direction",
        "joints": joints,
        "ur_friction_model": ("UR's FrictionModelParameters (ur_msgs) take scale factors in [0, 1] of UR's own "
                              "viscous and Coulomb model, not values: set them to 0 and add this feed-forward "
                              "to the direct torque command"),
    }
    if check:
        data["check"] = check
    header = ("# Friction feed-forward of the identified model (pe-drake export --to feedforward).\n"
              "# Add gravity (and the rigid-body torque) from the exported URDF/MJCF; table.coulomb_pos/neg hold the\n"
              "# offset: friction table form tau = +coulomb_pos (v > threshold), -coulomb_neg (v < -threshold).\n")
    return header + _dump(data)


def friction_torque(model: RobotModel, v: np.ndarray, coulomb: np.ndarray | None = None) -> np.ndarray:
    """The feed-forward's friction and offset torque at velocities v (S, n), shape (S, n).

    ``coulomb``: the Coulomb columns, default tanh(v/v_s)."""
    column = coulomb_column(v, model.velocity_scale) if coulomb is None else coulomb
    return model.sliding_friction * column + model.viscous * v + model.offset


def effective_inertia(robot: Robot, model: RobotModel, q: np.ndarray) -> np.ndarray:
    """J_i(q) = M_ii(q) + armature_i at postures q (S, n), shape (S, n) [kg·m² or kg]."""
    q = np.atleast_2d(q)
    zero = np.zeros_like(q)
    rest = model.torque(robot, q, zero, zero, coulomb=False, offset=False)  # gravity alone
    J = np.empty_like(q)
    for i in range(robot.n):
        unit = zero.copy()
        unit[:, i] = 1.0
        J[:, i] = model.torque(robot, q, zero, unit, coulomb=False, offset=False)[:, i] - rest[:, i]
    return J


def gains_table(robot: Robot, model: RobotModel, q: np.ndarray, bandwidth_hz: float, damping_ratio: float) -> dict:
    """Per joint the effective inertia over the postures q (min, mean, max) and the PD gains
    k_p = J·ω², k_d = 2·ζ·J·ω of the mean J (ω = 2π·bandwidth)."""
    J = effective_inertia(robot, model, q)
    omega = 2 * np.pi * bandwidth_hz
    out = {}
    for k, name in enumerate(robot.joint_names):
        j = float(np.mean(J[:, k]))
        out[name] = {"effective_inertia": {"min": float(J[:, k].min()), "mean": j, "max": float(J[:, k].max())},
                     "armature": float(model.armature[k]),
                     "kp": j * omega**2, "kd": 2 * damping_ratio * j * omega}
    return out


@dataclasses.dataclass(frozen=True, eq=False)
class SampledModels:
    """Models drawn from the identification's σ: ``phi`` (count, 10·nb), physically consistent;
    ``drive`` {term: (count, n)}; ``projected`` samples with a body projected."""

    phi: np.ndarray
    drive: dict[str, np.ndarray]
    projected: int


def drive_spread(model: RobotModel, term: str) -> np.ndarray:
    """σ per joint of a drive term, shape (n,), 0 where the model has none (not randomized)."""
    return np.nan_to_num(model.sigma.get(term, np.zeros(len(model.joints))), nan=0.0)


def sample_models(robot: Robot, model: RobotModel, spread: IdentifiedSpread, count: int, seed: int = 0) -> SampledModels:
    """``count`` models drawn from the identification's σ ``spread`` (module docstring)."""
    rng = np.random.default_rng(seed)
    K = spread.K
    root = _covariance_root(spread)
    # each parameter weighed by its size, floored at 1e-3 of its body's largest: a massless frame
    # (a flange welded to its link) stays massless, the draw goes to the bodies that carry it
    per_body = np.abs(model.phi).reshape(-1, 10)
    scale = (per_body + 1e-3 * per_body.max(axis=1, keepdims=True)).ravel()
    W = scale**2
    KW = K * W
    lift = KW.T @ np.linalg.pinv(KW @ K.T)  # δφ = W Kᵀ (K W Kᵀ)⁺ δ
    phi = np.empty((count, model.phi.size))
    projected = 0
    for s in range(count):
        sample = model.phi + lift @ (root @ rng.standard_normal(root.shape[1]))
        if validity_problems(robot.body_names, sample):
            sample, _ = physically_consistent(robot.body_names, sample)
            projected += 1
        phi[s] = sample
    drive = {}
    for term in DRIVE_TERMS:
        draw = model.term(term) + drive_spread(model, term) * rng.standard_normal((count, robot.n))
        drive[term] = draw if term == "offset" else np.maximum(draw, 0.0)
    return SampledModels(phi, drive, projected)


def _covariance_root(spread: IdentifiedSpread) -> np.ndarray:
    """L with L Lᵀ = Σ_B, (p, p) (diag σ without a covariance; a σ not finite is not drawn)."""
    sigma = np.where(np.isfinite(spread.sigma), spread.sigma, 0.0)
    if spread.cov is None:
        return np.diag(sigma)
    # eigh, not Cholesky: a covariance of nearly dependent parameters is only semi-definite
    lam, V = np.linalg.eigh(0.5 * (spread.cov + spread.cov.T))
    return V * np.sqrt(np.maximum(lam, 0.0))


def _body_record(phi_b: np.ndarray) -> dict:
    m, p, I = central_inertia(phi_b)
    return {"mass": m, "com": [float(x) for x in p],
            "inertia_about_com": [float(I[0, 0]), float(I[1, 1]), float(I[2, 2]), float(I[0, 1]), float(I[0, 2]),
                                  float(I[1, 2])]}


def randomization(robot: Robot, model: RobotModel, spread: IdentifiedSpread | None, k: float, count: int,
                  seed: int = 0, source: str = "") -> dict:
    """Ranges value ± k·σ per drive term and base parameter, and ``count`` sampled models.

    Without ``spread`` (a CAD or diagnosed model, named by ``source``) only a note."""
    if spread is None:
        return {"note": f"no σ in '{source or 'the CAD model'}': no randomization ranges"}
    drive = {}
    for j, name in enumerate(robot.joint_names):
        drive[name] = {}
        for t in DRIVE_TERMS:
            value, s = model.term(t)[j], drive_spread(model, t)[j]
            low = value - k * s if t == "offset" else max(value - k * s, 0.0)
            drive[name][t] = [float(low), float(value + k * s)]
    base_value = spread.K @ model.phi
    base = {name: [float(v - k * s), float(v + k * s)]
            for name, v, s in zip(spread.names, base_value, spread.sigma) if np.isfinite(s)}
    out = {"k": k, "drive_terms": drive, "base_parameters": base,
           "base_draws": spread.note or "from the identification's covariance of the base parameters"}
    if count > 0:
        models = sample_models(robot, model, spread, count, seed)
        # a projected draw is pulled back to the consistent set: the spread is then below σ
        out["samples_projected_onto_consistent"] = models.projected
        out["samples"] = [
            {"bodies": {b: _body_record(models.phi[s, 10 * i : 10 * i + 10]) for i, b in enumerate(robot.body_names)},
             "joints": {j: {"armature": float(models.drive["armature"][s, i]),
                            "damping": float(models.drive["viscous"][s, i]),
                            "frictionloss": float(models.drive["coulomb"][s, i]),
                            "offset": float(models.drive["offset"][s, i])}
                        for i, j in enumerate(robot.joint_names)}}
            for s in range(count)]
    return out


def gains_yaml(robot: Robot, model: RobotModel, spread: IdentifiedSpread | None, q: np.ndarray, *, bandwidth_hz: float,
               damping_ratio: float, sigma_k: float, samples: int, seed: int = 0, source: str = "") -> str:
    """The gains, effective inertias and randomization ranges as YAML (module docstring)."""
    data = {
        "robot": robot.name, "model": source or "CAD",
        "formula": "kp = J * omega^2, kd = 2 * zeta * J * omega, J = mean over the postures of M_ii(q) + armature",
        "bandwidth_hz": bandwidth_hz, "damping_ratio": damping_ratio, "postures": int(np.atleast_2d(q).shape[0]),
        "joints": gains_table(robot, model, q, bandwidth_hz, damping_ratio),
        "randomization": randomization(robot, model, spread, sigma_k, samples, seed, source),
    }
    header = ("# PD gains from the identified effective inertia and randomization ranges from σ\n"
              "# (pe-drake export --to gains). Units: kg·m², N·m/rad, N·m·s/rad (kg, N/m, N·s/m: prismatic).\n")
    return header + _dump(data)
