"""The a-priori model with the diagnosed effects added, in Drake and as files.

In Drake (:func:`build_augmented_robot`, on :func:`pe_drake.identification.simulation.build_true_robot`):
viscous friction is the joint damping, Coulomb friction a ``DoorHinge`` force element
(f_c·tanh(v/v_s)), armature the rotor inertia of a joint actuator (gear ratio 1), a payload a
body welded to its link; the rigid-body parameters are the re-identified ones. Torque offsets
are a constant generalized force added to the inverse dynamics (:func:`augmented_torque`): a
Drake system feeding the applied-generalized-force port does the same in a simulation.

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

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from pe_drake.exceptions import ConfigError
from pe_drake.identification.physical_fit import physical_fit
from pe_drake.identification.simulation import build_true_robot
from pe_drake.identification.truth import EffectsTruth, PayloadTruth, Truth
from pe_drake.io_utils import atomic_write_text
from pe_drake.multibody.inertia import (
    PARAMETER_NAMES,
    central_inertia,
    inertia_matrix,
    inertia_vector,
    phi_from_com,
    phi_from_pseudo_inertia,
    phi_to_spatial_inertia,
    pseudo_inertia,
    validity_problems,
)
from pe_drake.multibody.packages import found_packages
from pe_drake.multibody.robot import load_robot
from pe_drake.multibody.urdf import joint_dynamics, urdf_with_inertias

PAYLOAD_LINK = "pe_drake_payload"


@dataclasses.dataclass(frozen=True, eq=False)
class AugmentedModel:
    """Rigid-body parameters and effects of the augmented model.

    Attributes:
        joints: excited joints, length n.
        body_names: the robot's moving bodies, length nb.
        phi: their inertial parameters, shape (10·nb,) (payload not included).
        viscous: joint damping [N·m·s/rad], (n,): the total, the model file's damping plus the
            named viscous friction.
        coulomb: Coulomb friction [N·m], (n,): the total, the model file's ``<dynamics
            friction>`` plus the named Coulomb friction.
        coulomb_velocity_scale: v_s [rad/s].
        armature: rotor inertia [kg·m²], (n,).
        torque_offset: [N·m], (n,), added to the torque the actuator applies.
        payload_link: link carrying the payload body ("" for none).
        payload_mass: [kg].
        payload_com: centre of mass in the link frame [m], (3,).
        payload_inertia: about its centre of mass, link axes, [Ixx, Iyy, Izz, Ixy, Ixz, Iyz].
        notes: what was adjusted (physical projection, payload folded into the link).
        time_delay: the torque log lags the positions by this [s] (``time_delay``): the model
            predicts the recorded torque at t from the motion at t − time_delay.
        presliding, presliding_stiffness: Dahl friction F_c [N·m] and σ0 [N·m/rad] per joint
            (empty or 0: none); a Drake system in the simulator, not in the URDF.
        holding_torque: H [N·m] per joint of a named ``holding_torque`` (the friction a
            stopped joint holds, H·z with z the Dahl state, :mod:`pe_drake.diagnosis.holding`;
            empty or 0: none). Recorded for the user; validate and simulate do not apply it
            (they say so).
    """

    joints: tuple[str, ...]
    body_names: tuple[str, ...]
    phi: np.ndarray
    viscous: np.ndarray
    coulomb: np.ndarray
    coulomb_velocity_scale: float
    armature: np.ndarray
    torque_offset: np.ndarray
    payload_link: str = ""
    payload_mass: float = 0.0
    payload_com: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    payload_inertia: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(6))
    notes: tuple[str, ...] = ()
    time_delay: float = 0.0
    presliding: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    presliding_stiffness: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    holding_torque: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))

    @classmethod
    def from_fit(cls, robot, base, phi_B: np.ndarray, Sigma_phi: np.ndarray, payload_phi: np.ndarray | None,
                 effects: dict[str, tuple[Any, float]], velocity_scale: float,
                 payload_link: str | None = None, cov_B: np.ndarray | None = None,
                 time_delay: float = 0.0,
                 presliding: dict[int, tuple[float, float]] | None = None,
                 phi_prior: np.ndarray | None = None,
                 friction_start: tuple[np.ndarray, np.ndarray] | None = None) -> AugmentedModel:
        """The model of a diagnosis fit.

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
        """
        phi0 = robot.phi_model if phi_prior is None else np.asarray(phi_prior, float)
        n = robot.n
        start = (robot.joint_damping, robot.joint_friction) if friction_start is None else friction_start
        viscous, coulomb = np.array(start[0], float), np.array(start[1], float)
        armature, offset, holding = np.zeros(n), np.zeros(n), np.zeros(n)
        for cand, value in effects.values():
            j = cand.joint
            if cand.effect == "viscous_friction":
                viscous[j] += value
            elif cand.effect == "coulomb_friction":
                coulomb[j] += value
            elif cand.effect == "armature":
                armature[j] = value
            elif cand.effect == "torque_offset":
                offset[j] = value
            elif cand.effect == "holding_torque":
                holding[j] = value
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
        if invalid:
            H = np.linalg.pinv(cov_B) if cov_B is not None else np.eye(len(phi_B))
            phi = physical_parameters(base.K, phi0, Sigma_phi, target, H)
            phi, projected = physically_consistent(robot.body_names, phi)
            notes.append(
                "the parameters closest to the a-priori model are not physically valid for "
                + ", ".join(invalid) + "; the model holds a physically consistent fit of the base parameters "
                f"(largest base-parameter change {float(np.max(np.abs(base.K @ phi - target))):.3g})")
        return cls(tuple(robot.joint_names), tuple(robot.body_names), phi, viscous, coulomb,
                   float(velocity_scale), armature, offset, link, mass, np.asarray(com, float),
                   np.asarray(inertia, float), tuple(notes), float(time_delay),
                   *_presliding_arrays(presliding or {}, n), holding_torque=holding)

    def truth(self):
        """The :class:`~pe_drake.identification.simulation.Truth` that builds this model's effects."""
        payload = PayloadTruth()
        if self.payload_link:
            payload = PayloadTruth(self.payload_link, float(self.payload_mass),
                                   [float(x) for x in self.payload_com], [float(x) for x in self.payload_inertia])
        effects = EffectsTruth(
            viscous={j: float(x) for j, x in zip(self.joints, self.viscous)},
            # every joint: a joint left out would keep the model file's friction in the simulator
            coulomb={j: float(x) for j, x in zip(self.joints, self.coulomb)},
            coulomb_velocity_scale=float(self.coulomb_velocity_scale),
            armature={j: float(x) for j, x in zip(self.joints, self.armature) if x > 0},
            torque_offset={j: float(x) for j, x in zip(self.joints, self.torque_offset) if x != 0},
            torque_delay=float(self.time_delay),
            presliding_friction={j: float(x) for j, x in zip(self.joints, self.presliding) if x > 0},
            presliding_stiffness={j: float(s) for j, x, s in zip(self.joints, self.presliding,
                                                                 self.presliding_stiffness) if x > 0},
            payload=payload,
        )
        return Truth(effects=effects)

    def as_dict(self) -> dict[str, Any]:
        def per_joint(x):
            return {j: float(v) for j, v in zip(self.joints, x)}

        return {
            "joints": list(self.joints),
            "parameter_names": list(PARAMETER_NAMES),
            "phi": {b: self.phi[10 * k : 10 * k + 10].tolist() for k, b in enumerate(self.body_names)},
            "phi_frame": "about each body origin, in the body frame [kg, kg·m, kg·m²]",
            "viscous": per_joint(self.viscous), "viscous_unit": "N·m·s/rad",
            "coulomb": per_joint(self.coulomb), "coulomb_unit": "N·m",
            "coulomb_velocity_scale": self.coulomb_velocity_scale,
            "armature": per_joint(self.armature), "armature_unit": "kg·m²",
            "torque_offset": per_joint(self.torque_offset), "torque_offset_unit": "N·m",
            "payload": {"link": self.payload_link, "mass": self.payload_mass, "com": self.payload_com.tolist(),
                        "inertia_about_com": self.payload_inertia.tolist()} if self.payload_link else None,
            "time_delay": self.time_delay, "time_delay_unit": "s",
            "presliding_friction": per_joint(self.presliding), "presliding_stiffness": per_joint(self.presliding_stiffness),
            "presliding_units": "N·m, N·m/rad (Dahl model)",
            "holding_torque": per_joint(self.holding_torque) if self.holding_torque.size else {},
            "holding_torque_unit": "N·m (the friction a stopped joint holds: H·z, z the Dahl state; not applied "
                                   "by validate or simulate)",
            "torque_equation": "tau_recorded(t) = [ID(q, v, vd) + viscous*v + coulomb*tanh(v/v_s) + armature*vd "
                               "+ offset](t - time_delay)",
            "notes": list(self.notes),
        }


def _presliding_arrays(presliding: dict[int, tuple[float, float]], n: int) -> tuple[np.ndarray, np.ndarray]:
    fc, sigma0 = np.zeros(n), np.zeros(n)
    for j, (f, s) in presliding.items():
        fc[j], sigma0[j] = f, s
    return fc, sigma0


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
    fit = physical_fit(L @ K, L @ phi_B, np.asarray(phi_prior, float), names, base_K=K, scale=d,
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


# ---- Drake ----------------------------------------------------------------------------------


def build_augmented_robot(robot, model: AugmentedModel):
    """The augmented model as a Drake plant (a :class:`~pe_drake.identification.simulation.TrueRobot` whose
    context holds the re-identified inertias).

    Raises:
        ConfigError: an effect value the simulator's schema refuses (named in the message).
    """
    true = build_true_robot(robot, model.truth())
    plant, ctx = true.robot.plant, true.robot.plant_context
    for b, name in enumerate(model.body_names):
        phi_b = model.phi[10 * b : 10 * b + 10]
        if phi_b[0] <= 0 and not np.any(phi_b):
            continue
        plant.GetBodyByName(name).SetSpatialInertiaInBodyFrame(ctx, phi_to_spatial_inertia(phi_b))
    return true


def augmented_torque(true, model: AugmentedModel, q: np.ndarray, v: np.ndarray, vd: np.ndarray) -> np.ndarray:
    """Torque the augmented model needs along a motion: Drake's inverse dynamics with its force
    elements (gravity, damping, Coulomb ``DoorHinge``), rotor inertia and payload, plus the
    offsets. Shape (T, n) [N·m]."""
    q, v, vd = (np.atleast_2d(np.asarray(x, float)) for x in (q, v, vd))
    return true.robot.inverse_dynamics(q, v, vd, include_damping=True) + model.torque_offset


# ---- files ----------------------------------------------------------------------------------


def augmented_urdf_text(robot, model: AugmentedModel) -> str:
    """The robot's URDF with the augmented inertials, damping, rotor inertias and payload link.

    Raises:
        ConfigError: the robot was not loaded from a URDF.
        PhysicallyInvalidError: an invalid body (cannot happen after :func:`physically_consistent`).
    """
    text = urdf_with_inertias(robot.model_path, model.body_names, model.phi)
    text = joint_dynamics(text, dict(zip(model.joints, map(float, model.viscous))),
                          {j: float(a) for j, a in zip(model.joints, model.armature) if a > 0},
                          dict(zip(model.joints, map(float, model.coulomb))))
    extra = []
    if model.payload_link:
        phi_p = phi_from_com(model.payload_mass, model.payload_com, inertia_matrix(model.payload_inertia))
        m, p, I = central_inertia(phi_p)
        extra.append(
            f'  <link name="{PAYLOAD_LINK}">\n    <inertial>\n'
            f'      <origin xyz="{_num(p[0])} {_num(p[1])} {_num(p[2])}" rpy="0 0 0"/>\n'
            f'      <mass value="{_num(m)}"/>\n'
            f'      <inertia ixx="{_num(I[0, 0])}" ixy="{_num(I[0, 1])}" ixz="{_num(I[0, 2])}" iyy="{_num(I[1, 1])}" '
            f'iyz="{_num(I[1, 2])}" izz="{_num(I[2, 2])}"/>\n    </inertial>\n  </link>\n'
            f'  <joint name="{PAYLOAD_LINK}_weld" type="fixed">\n'
            f'    <parent link="{model.payload_link}"/>\n    <child link="{PAYLOAD_LINK}"/>\n'
            '    <origin xyz="0 0 0" rpy="0 0 0"/>\n  </joint>\n')
    if extra:
        head, sep, tail = text.rpartition("</robot>")
        text = head + "".join(extra) + sep + tail
    return text.replace("with identified inertial parameters (pe_drake)",
                        "augmented by pe-drake diagnose: re-identified inertias, damping, rotor inertia, payload")


def _num(x) -> str:
    return repr(float(x))


def effects_yaml_text(model: AugmentedModel) -> str:
    """The effects a URDF cannot hold, as a TRUTH.yaml for ``pe-drake simulate``."""
    def table(x, every: bool = False):
        items = {j: float(v) for j, v in zip(model.joints, x) if every or v != 0}
        return "{" + ", ".join(f"{j}: {v!r}" for j, v in items.items()) + "}"

    return (
        "# Effects found by pe-drake diagnose that a URDF cannot hold (TRUTH.yaml schema):\n"
        "#   pe-drake simulate --robot augmented_model.urdf --truth augmented_effects.yaml ...\n"
        "# re-simulates the augmented model (viscous, coulomb and armature repeat the URDF's damping,\n"
        "# friction and rotor inertia; the payload and the inertias are in the URDF).\n"
        "effects:\n"
        # every joint's friction: the simulator keeps the model file's where a joint is left out
        f"  viscous: {table(model.viscous, True)}            # [N·m·s/rad]\n"
        f"  coulomb: {table(model.coulomb, True)}            # [N·m], f_c·tanh(v / v_s)\n"
        f"  coulomb_velocity_scale: {model.coulomb_velocity_scale!r}   # v_s [rad/s]\n"
        f"  armature: {table(model.armature)}          # [kg·m²]\n"
        f"  torque_offset: {table(model.torque_offset)}   # [N·m]\n"
        f"  torque_delay: {float(model.time_delay)!r}   # [s], the torque log lags the positions (time_delay)\n"
        f"  presliding_friction: {table(model.presliding)}   # Dahl F_c [N·m]\n"
        f"  presliding_stiffness: {table(model.presliding_stiffness)}   # Dahl σ0 [N·m/rad]\n"
    )


def write_augmented_model(folder: str | Path, robot, model: AugmentedModel, *, verify: bool = True) -> list[Path]:
    """Writes the augmented model's files into ``folder`` (module docstring).

    With ``verify``, the URDF is loaded back with :func:`~pe_drake.multibody.robot.load_robot` and its
    inverse dynamics compared with :func:`build_augmented_robot` (Coulomb and offsets aside).

    Returns:
        The paths written. A robot not loaded from a URDF gets only the YAML and JSON files.

    Raises:
        ConfigError: the written URDF does not reproduce the model.
    """
    folder = Path(folder)
    written = []
    data = model.as_dict()
    if Path(robot.model_path).suffix.lower() == ".urdf":
        path = folder / "augmented_model.urdf"
        atomic_write_text(path, augmented_urdf_text(robot, model))
        if verify:
            data["urdf_check_max_abs_torque"] = verify_augmented_urdf(path, robot, model)
        written.append(path)
    else:
        data["urdf"] = f"not written: '{Path(robot.model_path).name}' is not a URDF"
    atomic_write_text(folder / "augmented_effects.yaml", effects_yaml_text(model))
    atomic_write_text(folder / "augmented_model.json", json.dumps(data, indent=2) + "\n")
    return [*written, folder / "augmented_effects.yaml", folder / "augmented_model.json"]


def verify_augmented_urdf(path: Path, robot, model: AugmentedModel, samples: int = 20,
                          tolerance: float = 1e-6) -> float:
    """Max |τ_urdf - τ_model| over random states [N·m] (raises above ``tolerance`` relative)."""
    # the file sits in an output (or staging) folder: its package:// URIs resolve as the input
    # model's did, not by the upward search from its own folder
    packages = {**robot.config.packages, **found_packages(Path(path).read_text(), robot.model_path, robot.config.packages)}
    config = dataclasses.replace(robot.config, model=str(Path(path).resolve()), capsules="", packages=packages)
    loaded = load_robot(config)
    rng = np.random.default_rng(0)
    q = rng.uniform(robot.limits.q_lower, robot.limits.q_upper, (samples, robot.n))
    v = rng.uniform(-1, 1, (samples, robot.n))
    vd = rng.uniform(-3, 3, (samples, robot.n))
    true = build_augmented_robot(robot, model)
    want = augmented_torque(true, model, q, v, vd) - model.torque_offset
    want -= model.coulomb * np.tanh(v / model.coulomb_velocity_scale)
    got = loaded.inverse_dynamics(q, v, vd, include_damping=True)
    err = float(np.max(np.abs(got - want)))
    scale = max(float(np.max(np.abs(want))), 1.0)
    if not math.isfinite(err) or err > tolerance * scale:
        raise ConfigError(f"the augmented URDF '{path}' does not reproduce the augmented model: torques "
                          f"differ by up to {err:.3g} N·m")
    return err
