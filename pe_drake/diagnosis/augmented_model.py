"""The a-priori model with the diagnosed effects added: a
:class:`~pe_drake.multibody.robot_model.RobotModel` (:func:`augmented_model`), and its files.

The re-identified base parameters φ_B fix only K φ. The standard parameters written are the
a-priori ones moved as little as the a-priori uncertainty allows (the conditional mean of a
Gaussian prior):

    φ = φ_prior + Σ_φ Kᵀ (K Σ_φ Kᵀ)⁺ (φ_B - K φ_prior - K_L φ_payload)

so K (φ + φ_payload on link L) = φ_B; when that is not physically valid, a physically consistent
fit (pseudo-inertia ⪰ 0, Wensing et al. 2017), noted in the model. Files
(:func:`write_augmented_model`): ``augmented_model.urdf``, ``augmented_effects.yaml`` (what a
URDF cannot hold, in the TRUTH.yaml schema of ``pe-drake simulate``), ``augmented_model.json``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pe_drake.diagnosis.effects import EFFECT_TERMS, STIFFNESS
from pe_drake.identification.physical_fit import physical_fit
from pe_drake.io_utils import atomic_write_text
from pe_drake.multibody.inertia import (
    central_inertia,
    inertia_matrix,
    inertia_vector,
    phi_from_com,
    phi_from_pseudo_inertia,
    pseudo_inertia,
    validity_problems,
)
from pe_drake.multibody.payload import PayloadInertia
from pe_drake.multibody.robot_model import RobotModel

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: The augmented URDF's comment line and the effects file's header.
URDF_TITLE = "augmented by pe-drake diagnose: re-identified inertias, damping, rotor inertia, payload"
EFFECTS_HEADER = (
    "# Effects found by pe-drake diagnose that a URDF cannot hold (TRUTH.yaml schema):\n"
    "#   pe-drake simulate --robot augmented_model.urdf --truth augmented_effects.yaml ...\n"
    "# re-simulates the augmented model (viscous, coulomb and armature repeat the URDF's damping,\n"
    "# friction and rotor inertia; the payload and the inertias are in the URDF).\n")


def augmented_model(robot: Robot, base, phi_B: np.ndarray, Sigma_phi: np.ndarray, payload_phi: np.ndarray | None,
             effects: dict[str, tuple[Any, float]], velocity_scale: float,
             payload_link: str | None = None, cov_B: np.ndarray | None = None,
             time_delay: float = 0.0,
             presliding: dict[int, tuple[float, float]] | None = None,
             phi_prior: np.ndarray | None = None,
             phi_consistent: np.ndarray | None = None) -> RobotModel:
    """The :class:`~pe_drake.multibody.robot_model.RobotModel` of a diagnosis fit (module docstring).

    Args:
        phi_B: re-identified base parameters, (b,).
        Sigma_phi: a-priori covariance of the standard parameters, (10·nb, 10·nb).
        payload_phi: Δφ_L of a named payload about ``payload_link``'s origin (10,), or None.
        effects: {label: (Candidate, value)} of the named per-joint effects; a named friction
            adds to the model file's damping and friction.
        velocity_scale: v_s of the Coulomb friction [rad/s].
        cov_B: covariance of φ_B, (b, b): weighs the base parameters when a physically
            consistent fit is needed.
        time_delay: a named ``time_delay`` [s] (0: none).
        presliding: {joint index: (F_c [N·m], σ0 [N·m/rad])} of the named pre-sliding friction.
        phi_prior: the a-priori standard parameters (None: the robot's model file's).
        phi_consistent: physically consistent standard parameters with K φ = ``phi_B`` (the
            diagnosis's consistent fit): the model's, unless a payload body is split off them.
    """
    phi0 = robot.phi_model if phi_prior is None else np.asarray(phi_prior, float)
    n = robot.n
    drive = {"viscous": np.array(robot.joint_damping, float),
             "coulomb": np.array(robot.joint_friction, float),
             "armature": np.zeros(n), "offset": np.zeros(n)}
    holding, spring = np.zeros(n), np.zeros(n)
    for cand, value in effects.values():
        if cand.effect == "holding_torque":
            holding[cand.joint] = value
        elif cand.effect == STIFFNESS:
            spring[cand.joint] = value
        elif cand.effect in EFFECT_TERMS:  # a named friction adds to the model file's
            drive[EFFECT_TERMS[cand.effect]][cand.joint] += value
    notes = []
    phi_payload_full = np.zeros_like(robot.phi_model)
    link, mass, com, inertia = "", 0.0, np.zeros(3), np.zeros(6)
    if payload_phi is not None:
        if not payload_link:
            raise ValueError("payload_link is required with payload_phi")
        lead = robot.body_names.index(payload_link)
        phi_payload_full[10 * lead : 10 * lead + 10] = payload_phi
        m = float(payload_phi[0])
        if m > 0:
            _, p, I_cm = central_inertia(payload_phi)
            moments = np.linalg.eigvalsh(I_cm)
            valid = moments.min() >= 0 and 2 * moments.max() <= moments.sum() + 1e-12
            if not valid:  # keep the point mass; its inertia goes to the link via δ below
                I_cm = np.zeros((3, 3))
                notes.append("payload: the identified rotational inertia is not physically valid; "
                             "the payload body is a point mass, the rest goes to the link")
            link, mass, com = robot.body_names[lead], m, p
            inertia = inertia_vector(I_cm)
            phi_payload_full[10 * lead : 10 * lead + 10] = phi_from_com(m, p, I_cm)
        else:
            phi_payload_full[:] = 0.0
            notes.append(f"payload: negative mass {m:.3g} kg folded into {robot.body_names[lead]}'s "
                         "parameters (a body cannot have negative mass)")
    target = phi_B - base.K @ phi_payload_full
    phi = conditional_parameters(base.K, phi0, Sigma_phi, target)
    invalid = validity_problems(robot.body_names, phi)
    empty = not np.any(phi0[0::10] > 0)  # no inertials at all: only the data (issue 37)
    if phi_consistent is not None and not link:  # already the consistent fit of the data
        phi = np.asarray(phi_consistent, float)
    elif empty or invalid:
        H = np.linalg.pinv(cov_B) if cov_B is not None else np.eye(len(phi_B))
        phi = physical_parameters(base.K, phi0, Sigma_phi, target, H)
        phi, _ = physically_consistent(robot.body_names, phi)
        notes.append(
            "the a-priori model has no inertial parameters (every mass 0): the model holds the "
            "physically consistent fit of the re-identified base parameters nearest zero (what the "
            "data do not determine stays small)" if empty else
            "the parameters closest to the a-priori model are not physically valid for "
            + ", ".join(invalid) + "; the model holds a physically consistent fit of the base parameters "
            f"(largest base-parameter change {float(np.max(np.abs(base.K @ phi - target))):.3g})")
    fc, sigma0 = np.zeros(n), np.zeros(n)
    for j, (f, s0) in (presliding or {}).items():
        fc[j], sigma0[j] = f, s0
    payload = PayloadInertia(mass, np.asarray(com, float), inertia_matrix(inertia)) if link else None
    return RobotModel(tuple(robot.joint_names), tuple(robot.body_names), phi, drive,
                      velocity_scale=float(velocity_scale), payload=payload, payload_link=link,
                      torque_delay=float(time_delay), presliding=fc, presliding_stiffness=sigma0,
                      holding_torque=holding, notes=tuple(notes), spring=spring)


def conditional_parameters(K: np.ndarray, phi_prior: np.ndarray, Sigma_phi: np.ndarray,
                           phi_B: np.ndarray) -> np.ndarray:
    """φ closest to φ_prior in the Σ_φ⁻¹ metric with K φ = φ_B (module docstring).

    A small floor on Σ_φ's diagonal (1e-6 of the largest variance of the same kind — mass,
    first moment, inertia — of the same body) keeps K Σ_φ Kᵀ invertible for parameters the
    a-priori spread leaves at zero; massless bodies are not moved.
    """
    S = np.array(Sigma_phi, float)
    d = np.diag(S).copy()
    nb = len(phi_prior) // 10
    massive = np.repeat(phi_prior[0::10] > 0, 10)
    for b in range(nb):
        for kind in (slice(0, 1), slice(1, 4), slice(4, 10)):
            idx = np.arange(10 * b, 10 * b + 10)[kind]
            d[idx] = np.maximum(d[idx], 1e-6 * d[idx].max())
    d[~massive] = 0.0
    S[np.diag_indices_from(S)] = d
    S[~massive, :] = 0.0
    S[:, ~massive] = 0.0
    KS = K @ S
    M = KS @ K.T
    delta = KS.T @ np.linalg.lstsq(M, phi_B - K @ phi_prior, rcond=1e-12)[0]
    return phi_prior + delta


def physical_parameters(K: np.ndarray, phi_prior: np.ndarray, Sigma_phi: np.ndarray, phi_B: np.ndarray,
                        H: np.ndarray) -> np.ndarray:
    """Physically consistent φ (p,) whose base parameters match φ_B (b,) as well as possible.

    min (Kφ - φ_B)ᵀ H (Kφ - φ_B) + the a-priori pull  s.t.  J(φ_b) ⪰ ε·m_b·1: the
    identification's SDP (:func:`pe_drake.identification.physical_fit.physical_fit`) with
    LᵀL = H (the information matrix of φ_B, (b, b)), the variables scaled by the a-priori
    standard deviations, so the pull toward φ_prior is measured in them. Massless bodies stay
    massless.

    Raises:
        NoSolutionFound: the solver failed.
    """
    nb = len(phi_prior) // 10
    active = [b for b in range(nb) if phi_prior[10 * b] > 0]
    d = np.sqrt(np.maximum(np.diag(Sigma_phi), 0.0))
    for b in active:
        for kind in (slice(0, 1), slice(1, 4), slice(4, 10)):
            idx = np.arange(10 * b, 10 * b + 10)[kind]
            d[idx] = np.maximum(d[idx], 1e-3 * max(d[idx].max(), 1e-12))
    w, V = np.linalg.eigh(0.5 * (H + H.T))
    L = (V * np.sqrt(np.maximum(w, 0.0))).T  # LᵀL = H
    names = [f"body{b}" for b in range(nb)]
    # H is the information matrix of φ_B, so the misfit is a χ²: the pull toward the prior may
    # raise it by 1 (a one-σ move), the augmented model's torque stays the fit's.
    fit = physical_fit(L @ K, L @ phi_B, np.asarray(phi_prior, float), names, base_K=K, scale=d if active else None,
                       chi2_tolerance=1.0)
    return fit.phi


def physically_consistent(body_names, phi: np.ndarray, margin: float = 1e-9) -> tuple[np.ndarray, list[str]]:
    """Projects invalid bodies onto physically consistent ones: the negative eigenvalues of the
    pseudo-inertia (Wensing, Kim, Slotine 2017) raised to ``margin`` × its largest one.

    Returns:
        (φ, names of the projected bodies).
    """
    phi = np.array(phi, float)
    problems = validity_problems(body_names, phi)
    projected = []
    for b, name in enumerate(body_names):
        if name not in problems:
            continue
        J = pseudo_inertia(phi[10 * b : 10 * b + 10])
        w, V = np.linalg.eigh(J)
        w = np.maximum(w, margin * max(w.max(), 1e-12))
        J = (V * w) @ V.T
        phi[10 * b : 10 * b + 10] = phi_from_pseudo_inertia(J)
        projected.append(name)
    return phi, projected


def write_augmented_model(folder: str | Path, robot: Robot, model: RobotModel) -> list[Path]:
    """Writes the augmented model's files into ``folder`` (module docstring); a robot not loaded
    from a URDF gets only the YAML and JSON files. Returns the paths written.

    Raises:
        ConfigError: the written URDF does not reproduce the model (Drake's inverse dynamics).
    """
    folder = Path(folder)
    written = []
    data = model.to_dict()
    if Path(robot.model_path).suffix.lower() == ".urdf":
        path = folder / "augmented_model.urdf"
        data["urdf_check_max_abs_torque"] = model.write_urdf(path, robot, URDF_TITLE)
        written.append(path)

    else:
        data["urdf"] = f"not written: '{Path(robot.model_path).name}' is not a URDF"
    atomic_write_text(folder / "augmented_effects.yaml", model.effects_yaml(EFFECTS_HEADER))
    atomic_write_text(folder / "augmented_model.json", json.dumps(data, indent=2) + "\n")
    return [*written, folder / "augmented_effects.yaml", folder / "augmented_model.json"]
