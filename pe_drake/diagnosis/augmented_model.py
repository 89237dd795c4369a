"""The a-priori model with the diagnosed effects added: a
:class:`~pe_drake.multibody.robot_model.RobotModel` (:func:`augmented_model`), whose ``plant`` is
the model in Drake and whose writers give the files.

The re-identified base parameters φ_B fix only K φ. The standard parameters written are the
a-priori ones moved as little as the a-priori uncertainty allows (the conditional mean of a
Gaussian prior, Σ_φ from :func:`pe_drake.diagnosis.effects.prior_parameter_covariance`):

    φ = φ_prior + Σ_φ Kᵀ (K Σ_φ Kᵀ)⁺ (φ_B - K φ_prior - K_L φ_payload)

so K (φ + φ_payload on link L) = φ_B. A body whose result is not physically valid is projected
onto the nearest physically consistent one (its 4×4 pseudo-inertia made positive
semidefinite, Wensing et al. 2017); that is noted in the model, as the torque then differs
slightly from the fit.

Files (:func:`write_augmented_model`): ``augmented_model.urdf`` (new inertials, joint
damping, ``drake:rotor_inertia`` in a transmission, the payload link; loadable with Drake and
by ``load_robot``), ``augmented_effects.yaml`` (Coulomb friction and offsets, which a URDF
cannot hold, in the TRUTH.yaml schema of ``pe-drake simulate``) and ``augmented_model.json``
(everything, machine-readable).
"""

from __future__ import annotations

import json
import math
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
             friction_start: tuple[np.ndarray, np.ndarray] | None = None,
             phi_consistent: np.ndarray | None = None) -> RobotModel:
    """The :class:`~pe_drake.multibody.robot_model.RobotModel` of a diagnosis fit (module docstring).

    Args:
        robot: the a-priori robot.
        base: its base parameters.
        phi_B: re-identified base parameters, (b,).
        Sigma_phi: a-priori covariance of the standard parameters, (10·nb, 10·nb).
        payload_phi: Δφ_L of a named payload about its link's origin (10,), or None.
        effects: {label: (Candidate, value)} of the named per-joint effects. A named
            viscous or Coulomb friction is what the model file lacks: it adds to the model
            file's damping and friction (the a-priori model the diagnosis starts from).
        velocity_scale: v_s of the Coulomb friction [rad/s].
        payload_link: the link whose frame ``payload_phi`` is expressed in.
        cov_B: covariance of φ_B, (b, b): weighs the base parameters when the conditional
            parameters are not physically valid and a physically consistent fit is needed.
        time_delay: a named ``time_delay`` [s] (0: none).
        presliding: {joint index: (F_c [N·m], σ0 [N·m/rad])} of the named pre-sliding friction.
        phi_prior: the a-priori standard parameters the closest ones are sought from
            (None: the robot's model file's; ``diagnose --model``: the earlier model's).
        friction_start: (viscous, Coulomb) per joint a named friction adds to (default the
            model file's, which the workflow always passes, also with an earlier model).
        phi_consistent: physically consistent standard parameters with K φ = ``phi_B`` (the
            diagnosis's consistent fit): the model's, unless a payload body is split off them.
    """
    phi0 = robot.phi_model if phi_prior is None else np.asarray(phi_prior, float)
    n = robot.n
    start = (robot.joint_damping, robot.joint_friction) if friction_start is None else friction_start
    drive = {"viscous": np.array(start[0], float), "coulomb": np.array(start[1], float), "armature": np.zeros(n),
             "offset": np.zeros(n)}
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
    if phi_consistent is not None and not link:  # already the consistent fit of the data
        phi = np.asarray(phi_consistent, float)
    elif not np.any(phi0[0::10] > 0):  # no inertials at all: nothing to move, only the data (issue 37)
        H = np.linalg.pinv(cov_B) if cov_B is not None else np.eye(len(phi_B))
        phi = physical_parameters(base.K, phi0, Sigma_phi, target, H)
        phi, _ = physically_consistent(robot.body_names, phi)
        notes.append("the a-priori model has no inertial parameters (every mass 0): the model holds the "
                     "physically consistent fit of the re-identified base parameters nearest zero (what the "
                     "data do not determine stays small)")
    elif invalid:
        H = np.linalg.pinv(cov_B) if cov_B is not None else np.eye(len(phi_B))
        phi = physical_parameters(base.K, phi0, Sigma_phi, target, H)
        phi, projected = physically_consistent(robot.body_names, phi)
        notes.append(
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
                        H: np.ndarray, *, prior_weight: float = 1e-6, margin: float = 1e-7) -> np.ndarray:
    """Physically consistent φ whose base parameters match φ_B as well as possible.

    min (Kφ - φ_B)ᵀ H (Kφ - φ_B) + the a-priori pull  s.t.  J(φ_b) ⪰ ``margin``·m_b·1: the
    identification's SDP (:func:`pe_drake.identification.physical_fit.physical_fit`, one
    implementation for both stages) with the data term ‖L K φ − L φ_B‖², LᵀL = H, and the
    variables scaled by the a-priori standard deviations D (floored as in
    :func:`conditional_parameters`), so the pull toward φ_prior in the directions K does not
    see is measured in a-priori standard deviations. Massless bodies stay massless.

    Args:
        K: φ_B = K φ, (b, p).
        phi_prior: a-priori parameters, (p,).
        Sigma_phi: their covariance, (p, p).
        phi_B: base parameters to match, (b,).
        H: weight of the base-parameter mismatch (the information matrix of φ_B), (b, b).

    Returns:
        φ, (p,).

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
                       prior_weight=prior_weight, margin=margin, chi2_tolerance=1.0)
    return fit.phi


def physically_consistent(body_names, phi: np.ndarray, margin: float = 1e-9) -> tuple[np.ndarray, list[str]]:
    """Projects invalid bodies onto physically consistent ones (pseudo-inertia ⪰ 0).

    The pseudo-inertia J = [[½ tr(I)·1 - I, h], [hᵀ, m]] of a body is positive semidefinite
    exactly when the body is physically consistent (Wensing, Kim, Slotine 2017); its negative
    eigenvalues are raised to ``margin`` × its largest one (the nearest PSD matrix in the
    Frobenius norm, made strictly valid).

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


# ---- files ----------------------------------------------------------------------------------


def write_augmented_model(folder: str | Path, robot: Robot, model: RobotModel, *, verify: bool = True) -> list[Path]:
    """Writes the augmented model's files into ``folder`` (module docstring).

    The URDF is checked by :meth:`~pe_drake.multibody.robot_model.RobotModel.write_urdf`
    (Drake's inverse dynamics of the file against the model's, Coulomb and offsets aside).

    Returns:
        The paths written. A robot not loaded from a URDF gets only the YAML and JSON files.

    Raises:
        ConfigError: the written URDF does not reproduce the model.
    """
    folder = Path(folder)
    written = []
    data = model.to_dict()
    if Path(robot.model_path).suffix.lower() == ".urdf":
        path = folder / "augmented_model.urdf"
        err = model.write_urdf(path, robot, URDF_TITLE, tolerance=1e-6 if verify else math.inf)
        if verify:
            data["urdf_check_max_abs_torque"] = err
        written.append(path)
    else:
        data["urdf"] = f"not written: '{Path(robot.model_path).name}' is not a URDF"
    atomic_write_text(folder / "augmented_effects.yaml", model.effects_yaml(EFFECTS_HEADER))
    atomic_write_text(folder / "augmented_model.json", json.dumps(data, indent=2) + "\n")
    return [*written, folder / "augmented_effects.yaml", folder / "augmented_model.json"]
