"""Simulated measurements: a perturbed "true" robot tracking a trajectory in Drake.

``pe-drake simulate --robot ROBOT --trajectory DIR/trajectory.json --truth TRUTH.yaml
--out data.csv`` writes what a real robot would log (q and the actuator torque, at the control
rate, in the format of :mod:`pe_drake.identification.measurements`) and, beside it, ``data.truth.json`` with
every true value (inertial parameters, effects, noise) so tests can check what identification
recovers.

The true robot is the a-priori model with:

- inertial parameters perturbed per body (:func:`perturb_inertias`), each body kept
  physically valid;
- viscous friction as Drake joint damping (it *replaces* the model file's damping, so an
  effect-free truth has none);
- Coulomb friction ``-f_c·tanh(v/v_s)`` as a Drake ``DoorHinge`` force element (its dynamic
  friction term is exactly this; spring, catch and static terms are zero), so it is part of
  the continuous dynamics the integrator sees rather than a sampled input;
- armature (reflected rotor inertia) as the rotor inertia of a Drake ``JointActuator``
  (gear ratio 1), added when the joint has none;
- constant torque offsets as a constant generalized force on the joint;
- a payload body welded to a link.

**Sign convention of the recorded torque.** ``tau`` is the torque the actuator applies. The
effects are resistive loads the actuator must overcome, so once tracking has converged::

    tau(t) = ID_rb(q, v, vd) + viscous·v + coulomb·tanh(v/v_s) + armature·vd + offset

with ``ID_rb`` the true rigid-body inverse dynamics (payload and perturbed inertias included).
An offset o is thus a constant torque -o acting on the joint (a spring or cable preload);
identification with ``tau = Y·phi + f_v·v + f_c·sign(v) + o`` recovers it with its sign.
The controller's command tau_k is held over [t_k, t_k + h), so it matches the motion half a
sample later; the log records the torque averaged over the sample period centred on t_k,
(tau_{k-1} + tau_k)/2, what a torque sensor with a one-sample averaging window reads. That
keeps effect-free data free of any timing offset (the raw command is available with
``record_command: true``). A torque delay d then shifts the recorded torque:
``tau_recorded(t) = tau(t - d)`` (positive d: the torque log lags the positions), and noise
is added last.

Control: computed torque at ``control.rate_hz`` with zero-order hold, ``tau = M(q)(vd_d +
kp·(q_d - q) + kd·(v_d - v)) + c(q, v) - tau_g(q)`` evaluated with the a-priori rigid-body
model (``control.model: prior``, what a real controller has) or the true one (``true``), on
the true state (noise only affects the log). The controller runs between
``Simulator.AdvanceTo`` calls and holds its torque on the plant's applied-generalized-force
input. The plant is continuous (Drake's error-controlled RK3 by default, Radau3 on request):
the stiff tanh of Coulomb friction would need a much smaller time step in a discrete plant.
"""
# No ``from __future__ import annotations`` here: yaml_load_typed reads the dataclass field
# types at run time and cannot resolve string annotations.

import dataclasses
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from pe_drake.exceptions import ConfigError, DataError, PeDrakeError, UnknownNameError
from pe_drake.excitation.fourier import FourierTrajectory
from pe_drake.identification.measurements import Measurement
from pe_drake.multibody.inertia import (
    PARAMETER_NAMES,
    phi_from_com,
    phi_to_spatial_inertia,
    principal_inertia,
    spatial_inertia_to_phi,
)
from pe_drake.multibody.sensors import MeasurementType
from pe_drake.multibody.wrench import WRENCH_COLUMNS, weld_reaction

#: Key of a per-joint table that sets every joint not listed by name.
ALL_JOINTS = "all"
CONTROL_MODELS = ("prior", "true")
PAYLOAD_BODY_NAME = "pe_drake_payload"


class SimulationError(PeDrakeError):
    """The simulation diverged (NaN or infinite state)."""


# ---- TRUTH.yaml schema -----------------------------------------------------------------------


@dataclasses.dataclass
class PayloadTruth:
    """A rigid payload welded to a link.

    Attributes:
        link: link it is welded to (a body moved by the excited joints); empty: no payload.
        mass: [kg], > 0 when ``link`` is set.
        com: centre of mass in the link frame, p_LoPcm_L [m].
        inertia: rotational inertia about its centre of mass in the link axes, I_PPcm_L, as
            [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] [kg·m²]; zeros give a point mass.
    """

    link: str = ""
    mass: float = 0.0
    com: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    inertia: list[float] = dataclasses.field(default_factory=lambda: [0.0] * 6)


@dataclasses.dataclass
class EffectsTruth:
    """Effects of the true robot beyond its rigid-body dynamics.

    Per-joint tables map a joint name to a value; the key ``all`` sets every joint not named.
    Joints absent from a table get 0.

    Attributes:
        viscous: viscous friction f_v [N·m·s/rad] (Drake joint damping; replaces the model
            file's damping).
        coulomb: Coulomb friction f_c [N·m], smoothed as f_c·tanh(v/v_s) (revolute joints).
        coulomb_velocity_scale: v_s [rad/s].
        armature: reflected rotor inertia I_a [kg·m²], adds I_a·vd.
        torque_offset: constant torque o [N·m] the actuator must supply (module docstring).
        torque_delay: recorded torque lags the positions by this [s] (negative: leads).
        payload: see :class:`PayloadTruth`.
    """

    viscous: dict[str, float] = dataclasses.field(default_factory=dict)
    coulomb: dict[str, float] = dataclasses.field(default_factory=dict)
    coulomb_velocity_scale: float = 0.01
    armature: dict[str, float] = dataclasses.field(default_factory=dict)
    torque_offset: dict[str, float] = dataclasses.field(default_factory=dict)
    torque_delay: float = 0.0
    payload: PayloadTruth = dataclasses.field(default_factory=PayloadTruth)


@dataclasses.dataclass
class NoiseTruth:
    """Sensor imperfections of the log (the controller sees the true state).

    Attributes:
        encoder_counts_per_rev: q of revolute joints quantized to 2π/counts [rad]; 0: none.
        q_std: white noise on q [rad].
        v_std: white noise on v [rad/s] (only with ``record_velocity``).
        tau_std: white noise on tau [N·m].
        force_std: white noise on the ground wrench's force [N] (``wrench.f*`` columns).
        moment_std: white noise on the ground wrench's moment [N·m] (``wrench.m*``).
        wrench_offset: constant offset of the force/torque sensor, [fx, fy, fz, mx, my, mz]
            [N, N·m]; empty means none. Its fz, mx, my cannot be told from the total mass and
            horizontal centre of mass of the moving bodies (:mod:`pe_drake.identification.channels`).
    """

    encoder_counts_per_rev: int = 0
    q_std: float = 0.0
    v_std: float = 0.0
    tau_std: float = 0.0
    force_std: float = 0.0
    moment_std: float = 0.0
    wrench_offset: list[float] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class ControlTruth:
    """The tracking controller (computed torque + PD, zero-order hold).

    Attributes:
        rate_hz: control and logging rate [Hz].
        kp: position gain [1/s²] (multiplies the model's mass matrix).
        kd: velocity gain [1/s].
        model: "prior" (a-priori rigid-body model, realistic) or "true" (true rigid-body
            model incl. payload and armature; friction is still left to the feedback).
    """

    rate_hz: float = 1000.0
    kp: float = 6400.0
    kd: float = 160.0
    model: str = "prior"


@dataclasses.dataclass
class Truth:
    """A whole TRUTH.yaml.

    Attributes:
        seed: seeds the inertial perturbation and, independently, the noise.
        inertia_perturbation: relative size ε in [0, 0.5] (:func:`perturb_inertias`).
        effects: see :class:`EffectsTruth`.
        noise: see :class:`NoiseTruth`.
        control: see :class:`ControlTruth`.
        record_velocity: also write ``v.<joint>`` columns (true v + noise.v_std).
        record_command: write the raw command tau_k (held over [t_k, t_k + h), so it leads the
            positions by half a sample) instead of the centred average (tau_{k-1} + tau_k)/2.
        integration_accuracy: relative accuracy of Drake's error-controlled integrator.
        integrator: Drake integration scheme (``GetIntegrationSchemes()``): "runge_kutta3"
            (fastest for arms), or "radau3" when light joints with Coulomb friction make the
            dynamics stiff (G1 wrists, 4e-4 kg·m²: 4× faster than runge_kutta3).
    """

    seed: int = 0
    inertia_perturbation: float = 0.0
    effects: EffectsTruth = dataclasses.field(default_factory=EffectsTruth)
    noise: NoiseTruth = dataclasses.field(default_factory=NoiseTruth)
    control: ControlTruth = dataclasses.field(default_factory=ControlTruth)
    record_velocity: bool = False
    record_command: bool = False
    integration_accuracy: float = 1e-4
    integrator: str = "runge_kutta3"


def load_truth(path: str | Path) -> Truth:
    """Reads a TRUTH.yaml onto :class:`Truth` (robot-independent checks included).

    Raises:
        ConfigError: missing file, unknown key, wrong type or bad value (the field is named).
    """
    from pydrake.common.yaml import yaml_load_typed

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"truth file '{path}' does not exist")
    try:
        truth = yaml_load_typed(schema=Truth, filename=str(path), defaults=Truth())
    except (RuntimeError, ValueError, TypeError, AttributeError) as err:
        raise ConfigError(f"truth file '{path}': {err}") from err
    try:
        return validate_truth(truth)
    except ConfigError as err:
        raise ConfigError(f"truth file '{path}': {err}") from err


def _finite(name: str, value: Any, *, nonneg: bool = False, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise ConfigError(f"{name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ConfigError(f"{name} must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise ConfigError(f"{name} must be positive, got {value!r}")
    if nonneg and value < 0:
        raise ConfigError(f"{name} must be non-negative, got {value!r}")
    return float(value)


_JOINT_TABLES = {  # field: (unit, non-negative)
    "viscous": ("N·m·s/rad", True),
    "coulomb": ("N·m", True),
    "armature": ("kg·m²", True),
    "torque_offset": ("N·m", False),
}


def validate_truth(truth: Truth, robot=None) -> Truth:
    """Checks a :class:`Truth`; with a robot, also its joint and link names.

    Raises:
        ConfigError: naming the field and the bad value.
        UnknownNameError: a joint or link the robot does not have (valid names listed).
    """
    if isinstance(truth.seed, bool) or not isinstance(truth.seed, int) or truth.seed < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {truth.seed!r}")
    eps = _finite("inertia_perturbation", truth.inertia_perturbation, nonneg=True)
    if eps > 0.5:
        raise ConfigError(f"inertia_perturbation must lie in [0, 0.5] (relative), got {eps}")
    _finite("integration_accuracy", truth.integration_accuracy, positive=True)
    if truth.integration_accuracy > 1e-2:
        raise ConfigError(f"integration_accuracy must be at most 1e-2, got {truth.integration_accuracy}")
    from pydrake.systems.analysis import GetIntegrationSchemes

    if truth.integrator not in GetIntegrationSchemes():
        raise ConfigError(
            f"integrator '{truth.integrator}' is not one of Drake's schemes: "
            f"{', '.join(GetIntegrationSchemes())}"
        )
    e = truth.effects
    for field, (unit, nonneg) in _JOINT_TABLES.items():
        table = getattr(e, field)
        for joint, value in table.items():
            _finite(f"effects.{field}['{joint}'] [{unit}]", value, nonneg=nonneg)
    _finite("effects.coulomb_velocity_scale [rad/s]", e.coulomb_velocity_scale, positive=True)
    _finite("effects.torque_delay [s]", e.torque_delay)
    p = e.payload
    if len(p.com) != 3:
        raise ConfigError(f"effects.payload.com must have 3 numbers [m], got {p.com}")
    if len(p.inertia) != 6:
        raise ConfigError(
            f"effects.payload.inertia must be [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] [kg·m²], got {p.inertia}"
        )
    for k, value in enumerate(list(p.com) + list(p.inertia)):
        _finite("effects.payload.com" if k < 3 else "effects.payload.inertia", value)
    _finite("effects.payload.mass [kg]", p.mass, nonneg=True)
    if p.link and p.mass <= 0:
        raise ConfigError(f"effects.payload.mass must be positive for a payload on '{p.link}', got {p.mass}")
    if not p.link and (p.mass != 0 or any(p.inertia)):
        raise ConfigError("effects.payload has a mass or inertia but no link: set effects.payload.link")
    if p.link:
        _payload_spatial_inertia(p)  # raises when not physically valid
    n = truth.noise
    if (
        isinstance(n.encoder_counts_per_rev, bool)
        or not isinstance(n.encoder_counts_per_rev, int)
        or n.encoder_counts_per_rev < 0
    ):
        raise ConfigError(
            f"noise.encoder_counts_per_rev must be a non-negative integer, got {n.encoder_counts_per_rev!r}"
        )
    for name in ("q_std", "v_std", "tau_std", "force_std", "moment_std"):
        _finite(f"noise.{name}", getattr(n, name), nonneg=True)
    if len(n.wrench_offset) not in (0, 6):
        raise ConfigError(
            f"noise.wrench_offset must be [fx, fy, fz, mx, my, mz] [N, N·m] (or empty), got {n.wrench_offset!r}"
        )
    for k, value in enumerate(n.wrench_offset):
        _finite(f"noise.wrench_offset[{k}] ({WRENCH_COLUMNS[k]})", value)
    c = truth.control
    rate = _finite("control.rate_hz [Hz]", c.rate_hz, positive=True)
    if rate > 1e5:
        raise ConfigError(f"control.rate_hz must be at most 100 kHz, got {rate}")
    _finite("control.kp [1/s²]", c.kp, nonneg=True)
    _finite("control.kd [1/s]", c.kd, nonneg=True)
    if c.model not in CONTROL_MODELS:
        raise ConfigError(f"control.model '{c.model}' is not one of {', '.join(CONTROL_MODELS)}")
    if robot is not None:
        for field in _JOINT_TABLES:
            for joint in getattr(e, field):
                if joint != ALL_JOINTS and joint not in robot.joint_names:
                    raise UnknownNameError(
                        "joint", joint, (*robot.joint_names, ALL_JOINTS), where=f"effects.{field}"
                    )
        if p.link and p.link not in robot.body_names:
            raise UnknownNameError("link", p.link, robot.body_names, where="effects.payload.link")
        coulomb = _per_joint(e.coulomb, robot.joint_names)
        for k, info in enumerate(robot.joints):
            if coulomb[k] > 0 and info.kind != "revolute":
                raise ConfigError(
                    f"effects.coulomb['{info.name}']: Coulomb friction is simulated on revolute "
                    f"joints only; '{info.name}' is {info.kind}"
                )
    return truth


def _per_joint(table: dict[str, float], joints: tuple[str, ...]) -> np.ndarray:
    """Per-joint table (with the ``all`` key) → values in joint order, shape (n,)."""
    default = float(table.get(ALL_JOINTS, 0.0))
    return np.array([float(table.get(j, default)) for j in joints])


def _payload_spatial_inertia(p: PayloadTruth):
    from pydrake.multibody.tree import RotationalInertia, SpatialInertia

    Ixx, Iyy, Izz, Ixy, Ixz, Iyz = (float(x) for x in p.inertia)
    I_PPcm = RotationalInertia(Ixx, Iyy, Izz, Ixy, Ixz, Iyz)
    if not I_PPcm.CouldBePhysicallyValid():
        raise ConfigError(
            f"effects.payload.inertia {list(p.inertia)} is not physically valid (moments must be "
            "non-negative and satisfy the triangle inequality)"
        )
    try:
        return SpatialInertia.MakeFromCentralInertia(float(p.mass), np.asarray(p.com, float), I_PPcm)
    except RuntimeError as err:
        raise ConfigError(f"effects.payload is not physically valid: {err}") from err


# ---- inertial perturbation -------------------------------------------------------------------


def perturb_inertias(
    phi: np.ndarray, size: float, rng: int | np.random.Generator = 0, max_tries: int = 100
) -> np.ndarray:
    """Random, physically valid perturbation of every body's inertial parameters.

    Per body with mass m > 0 (massless frames are left alone), with U uniform in [-1, 1]
    drawn independently for each number:

    - m' = m (1 + ε U);
    - centre of mass p' = p + ε U₃ max(|p|, r), r = √(tr I_cm / 2m) the radius of gyration;
    - principal moments of the central inertia λ' = λ (1 + ε U₃), redrawn until they satisfy
      the triangle inequality; principal axes rotated by an angle ε U [rad] about a random
      axis;
    - rebuilt about the body origin (parallel-axis theorem) and checked with Drake's
      ``SpatialInertia.IsPhysicallyValid``.

    Args:
        phi: parameters, shape (10·nb,) in :data:`pe_drake.multibody.robot.PARAMETER_NAMES` order.
        size: ε, relative size in [0, 0.5].
        rng: seed or numpy Generator.
        max_tries: redraws per body before giving up.

    Returns:
        Perturbed parameters, shape (10·nb,); equal to phi when size is 0.

    Raises:
        ConfigError: a bad size, or a body whose inertia cannot be made valid (an invalid
            a-priori inertia).
    """
    size = _finite("inertia_perturbation", size, nonneg=True)
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
        for _ in range(max_tries):
            new = _perturb_body(phi[10 * b : 10 * b + 10], size, rng)
            if new is not None and phi_to_spatial_inertia(new).IsPhysicallyValid():
                out[10 * b : 10 * b + 10] = new
                break
        else:
            raise ConfigError(
                f"body {b}: could not perturb its inertia into a physically valid one in "
                f"{max_tries} tries; is the model's inertia valid?"
            )
    return out


def _perturb_body(phi_b: np.ndarray, eps: float, rng: np.random.Generator) -> np.ndarray | None:
    m, p, lam, R, r_gyr = principal_inertia(phi_b)
    m2 = m * (1 + eps * rng.uniform(-1, 1))
    p2 = p + eps * rng.uniform(-1, 1, 3) * max(np.linalg.norm(p), r_gyr)
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


# ---- the true robot --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class TrueRobot:
    """The simulated robot and the true values it was built with.

    Attributes:
        robot: the :class:`~pe_drake.multibody.robot.Robot` (continuous plant) with every effect.
        phi: true parameters of the a-priori robot's bodies, payload lumped into its link,
            shape (10·nb,).
        phi_bodies: true parameters of the bodies alone (without payload), (10·nb,).
        phi_payload: payload parameters about the link origin in the link frame, (10,).
        viscous, coulomb, armature, torque_offset: per joint, shape (n,).
        model_damping: the model file's joint damping (replaced by ``viscous``), (n,).
    """

    robot: Any
    phi: np.ndarray
    phi_bodies: np.ndarray
    phi_payload: np.ndarray
    viscous: np.ndarray
    coulomb: np.ndarray
    armature: np.ndarray
    torque_offset: np.ndarray
    model_damping: np.ndarray


def build_true_robot(robot, truth: Truth) -> TrueRobot:
    """Builds the true robot of a truth on top of an a-priori robot.

    Args:
        robot: the a-priori :class:`~pe_drake.multibody.robot.Robot` (its config is reloaded; bodies
            added by its own ``before_finalize`` are not carried over).
        truth: a validated :class:`Truth`.

    Raises:
        ConfigError, UnknownNameError: from :func:`validate_truth`.
    """
    from pydrake.math import RigidTransform
    from pydrake.multibody.tree import DoorHinge, DoorHingeConfig

    from pe_drake.multibody.robot import load_robot

    validate_truth(truth, robot)
    joints = robot.joint_names
    e = truth.effects
    viscous = _per_joint(e.viscous, joints)
    coulomb = _per_joint(e.coulomb, joints)
    armature = _per_joint(e.armature, joints)
    offset = _per_joint(e.torque_offset, joints)
    model_damping = np.array(
        [robot.plant.GetJointByName(j).default_damping_vector()[0] for j in joints], float
    )
    payload_M = _payload_spatial_inertia(e.payload) if e.payload.link else None

    def before_finalize(plant, scene_graph):
        for k, name in enumerate(joints):
            joint = plant.GetJointByName(name)
            joint.set_default_damping_vector([viscous[k]])
            if coulomb[k] > 0:
                config = DoorHingeConfig()
                config.spring_constant = 0.0
                config.catch_torque = 0.0
                config.static_friction_torque = 0.0
                config.viscous_friction = 0.0
                config.dynamic_friction_torque = float(coulomb[k])
                config.motion_threshold = float(e.coulomb_velocity_scale)
                plant.AddForceElement(DoorHinge(joint, config))
            if armature[k] > 0:
                actuators = [
                    plant.get_joint_actuator(a)
                    for a in plant.GetJointActuatorIndices()
                    if plant.get_joint_actuator(a).joint().index() == joint.index()
                ]
                if actuators:
                    gear = actuators[0].default_gear_ratio() or 1.0
                    actuators[0].set_default_rotor_inertia(float(armature[k]) / gear**2)
                else:
                    actuator = plant.AddJointActuator(f"pe_drake_armature_{name}", joint)
                    actuator.set_default_gear_ratio(1.0)
                    actuator.set_default_rotor_inertia(float(armature[k]))
        if payload_M is not None:
            link = plant.GetBodyByName(e.payload.link)
            body = plant.AddRigidBody(PAYLOAD_BODY_NAME, link.model_instance(), payload_M)
            plant.WeldFrames(link.body_frame(), body.body_frame(), RigidTransform())

    seeds = np.random.SeedSequence(truth.seed).spawn(2)
    rng = np.random.default_rng(seeds[0])
    phi_bodies = perturb_inertias(robot.phi_model, truth.inertia_perturbation, rng)
    true = load_robot(robot.config, time_step=0.0, before_finalize=before_finalize)
    for b, name in enumerate(robot.body_names):
        phi_b = phi_bodies[10 * b : 10 * b + 10]
        if phi_b[0] <= 0:  # massless frames are not perturbed; keep the model's value
            continue
        body = true.plant.GetBodyByName(name)
        body.SetSpatialInertiaInBodyFrame(true.plant_context, phi_to_spatial_inertia(phi_b))
    phi = phi_bodies.copy()
    phi_payload = np.zeros(10)
    if payload_M is not None:
        phi_payload = spatial_inertia_to_phi(payload_M)
        b = robot.body_names.index(e.payload.link)
        phi[10 * b : 10 * b + 10] += phi_payload
    return TrueRobot(true, phi, phi_bodies, phi_payload, viscous, coulomb, armature, offset, model_damping)


# ---- simulation ------------------------------------------------------------------------------


def rigid_body_torque(plant, context, q: np.ndarray, v: np.ndarray, vd: np.ndarray) -> np.ndarray:
    """M(q)·vd + c(q, v) - tau_g(q) of a plant (rotor inertia included, no damping or other
    force elements), batched.

    Args:
        plant, context: a MultibodyPlant and its context (positions are overwritten).
        q, v, vd: each (T, n) or (n,).

    Returns:
        Torques, shape (T, n) [N·m or N].
    """
    from pydrake.multibody.tree import MultibodyForces

    q, v, vd = np.atleast_2d(q), np.atleast_2d(v), np.atleast_2d(vd)
    forces = MultibodyForces(plant)
    out = np.empty_like(q, dtype=float)
    for k in range(q.shape[0]):
        plant.SetPositions(context, q[k])
        plant.SetVelocities(context, v[k])
        tau_g = plant.CalcGravityGeneralizedForces(context)
        out[k] = plant.CalcInverseDynamics(context, vd[k], forces) - tau_g
    return out


def simulate(
    robot_or_name,
    trajectory: FourierTrajectory,
    truth: "Truth | str | Path",
    duration: float | None = None,
    measurement: str = "joint_torque",
) -> tuple[Measurement, dict[str, Any]]:
    """Simulates a run of the true robot tracking a trajectory; returns what it logs.

    Args:
        robot_or_name: the a-priori :class:`~pe_drake.multibody.robot.Robot` or a built-in name.
        trajectory: the trajectory to track (joints in the robot's order).
        truth: a :class:`Truth` or the path of a TRUTH.yaml.
        duration: simulated time [s]; default one period of the trajectory.
        measurement: what the robot records: "joint_torque" (tau), "base_wrench" (the ground
            wrench only: a robot without joint-torque sensors) or "both". The ground wrench
            is Drake's reaction at the root link's weld, plus ``noise.force_std`` /
            ``moment_std`` and the constant ``noise.wrench_offset``.

    Returns:
        The :class:`~pe_drake.identification.measurements.Measurement` (t, q, tau and/or the
        wrench at ``control.rate_hz``; v when ``record_velocity``) and the JSON-ready truth
        dict (true parameters per body, effects with units, noise, control, tracking error,
        wall time).

    Raises:
        ConfigError: a bad truth or duration.
        UnknownNameError: a truth names a joint or link the robot does not have.
        DataError: a trajectory for a different number of joints.
    """
    from pydrake.multibody.tree import MultibodyForces
    from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator

    from pe_drake.multibody.robot import Robot, load_robot

    robot = robot_or_name if isinstance(robot_or_name, Robot) else load_robot(robot_or_name)
    if not isinstance(truth, Truth):
        truth = load_truth(truth)
    sensors = MeasurementType(measurement)
    if trajectory.num_joints != robot.n:
        raise DataError(
            f"the trajectory has {trajectory.num_joints} joints, robot '{robot.name}' has {robot.n} "
            f"excited joints ({', '.join(robot.joint_names)})"
        )
    duration = trajectory.period if duration is None else duration
    duration = _finite("duration [s]", duration, positive=True)
    delay = truth.effects.torque_delay
    if abs(delay) >= duration:
        raise ConfigError(f"effects.torque_delay {delay} s is not shorter than the duration {duration} s")

    true = build_true_robot(robot, truth)
    plant, ctx = true.robot.plant, true.robot.plant_context
    if truth.control.model == "prior":
        ctl_plant, ctl_ctx = robot.plant, robot.plant.CreateDefaultContext()
    else:
        ctl_plant, ctl_ctx = plant, plant.CreateDefaultContext()
        for b in robot.body_names:  # the default context lacks the perturbed inertias
            body = plant.GetBodyByName(b)
            body.SetSpatialInertiaInBodyFrame(ctl_ctx, body.CalcSpatialInertiaInBodyFrame(ctx))
    forces = MultibodyForces(ctl_plant)
    rate = truth.control.rate_hz
    h = 1.0 / rate
    count = int(math.floor(duration * rate + 1e-9)) + 1
    t = np.arange(count) * h
    q_d, v_d, vd_d = trajectory.evaluate(t)
    kp, kd = truth.control.kp, truth.control.kd

    plant.SetPositions(ctx, q_d[0])
    plant.SetVelocities(ctx, v_d[0])
    port = plant.get_applied_generalized_force_input_port()
    port.FixValue(ctx, np.zeros(robot.n))
    simulator = Simulator(true.robot.diagram, true.robot.context)
    integrator = ResetIntegratorFromFlags(simulator, truth.integrator, h)
    if not integrator.get_fixed_step_mode():  # fixed-step schemes step at 1 / rate_hz
        integrator.set_target_accuracy(truth.integration_accuracy)
    simulator.Initialize()

    n = robot.n
    q_log = np.empty((count, n))
    v_log = np.empty((count, n))
    tau_log = np.empty((count, n))
    wall = time.perf_counter()
    for k in range(count):
        q = plant.GetPositions(ctx)
        v = plant.GetVelocities(ctx)
        a_ref = vd_d[k] + kp * (q_d[k] - q) + kd * (v_d[k] - v)
        ctl_plant.SetPositions(ctl_ctx, q)
        ctl_plant.SetVelocities(ctl_ctx, v)
        tau_g = ctl_plant.CalcGravityGeneralizedForces(ctl_ctx)
        tau = ctl_plant.CalcInverseDynamics(ctl_ctx, a_ref, forces) - tau_g
        q_log[k], v_log[k], tau_log[k] = q, v, tau
        if k + 1 < count:
            # The offset is a constant load the actuator must overcome (module docstring).
            port.FixValue(ctx, tau - true.torque_offset)
            simulator.AdvanceTo(t[k + 1])
            if not np.isfinite(plant.GetPositionsAndVelocities(ctx)).all():
                raise SimulationError(
                    f"the simulated state became NaN/inf at t = {t[k + 1]:.4g} s; check the truth "
                    "file's values (gains, friction, payload) and the model's inertias"
                )
    wall = time.perf_counter() - wall

    tracking_rms = np.sqrt(np.mean((q_log - q_d) ** 2, axis=0))
    rng = np.random.default_rng(np.random.SeedSequence(truth.seed).spawn(2)[1])
    if truth.record_command:
        tau_rec = tau_log
    else:
        # Torque averaged over the sample period centred on t_k: the command tau_k is held over
        # [t_k, t_k+h), so on its own it leads the positions by h/2 (see the module docstring).
        tau_rec = tau_log.copy()
        tau_rec[1:] = 0.5 * (tau_log[:-1] + tau_log[1:])
    if delay != 0:
        tau_rec = np.column_stack([np.interp(t - delay, t, tau_rec[:, j]) for j in range(n)])
    noise = truth.noise
    q_rec = q_log.copy()
    if noise.encoder_counts_per_rev > 0:
        step = 2 * math.pi / noise.encoder_counts_per_rev
        revolute = np.array([info.kind == "revolute" for info in robot.joints])
        q_rec[:, revolute] = np.round(q_rec[:, revolute] / step) * step
    if noise.q_std > 0:
        q_rec = q_rec + rng.normal(0.0, noise.q_std, q_rec.shape)
    if noise.tau_std > 0:
        tau_rec = tau_rec + rng.normal(0.0, noise.tau_std, tau_rec.shape)
    v_rec = None
    if truth.record_velocity:
        v_rec = v_log + (rng.normal(0.0, noise.v_std, v_log.shape) if noise.v_std > 0 else 0.0)
    wrench = None
    if sensors.wrench:
        # The reaction under the command held after t_k (and, centred, the one before it).
        applied = tau_log - true.torque_offset
        wrench = weld_reaction(true.robot, q_log, v_log, applied, centred=not truth.record_command)
        wrench = wrench + _wrench_noise(truth, wrench.shape)
    data = Measurement(
        t, q_rec, tau_rec if sensors.torques else None, v_rec, None, robot.joint_names, "", wrench=wrench
    )

    truth_dict = _truth_dict(robot, truth, true, duration, count, tracking_rms, wall, PARAMETER_NAMES)
    truth_dict["measurement"] = sensors.kind
    return data, truth_dict


def _wrench_noise(truth: Truth, shape: tuple[int, int]) -> np.ndarray:
    """Force/torque sensor noise and offset, (T, 6), from its own random stream (the other
    streams, and so earlier simulated files, stay as they were)."""
    noise = truth.noise
    rng = np.random.default_rng(np.random.SeedSequence(truth.seed).spawn(3)[2])
    std = np.repeat([noise.force_std, noise.moment_std], 3)
    offset = np.asarray(noise.wrench_offset, float) if noise.wrench_offset else np.zeros(6)
    return offset + rng.normal(size=shape) * std


def _truth_dict(robot, truth, true, duration, count, tracking_rms, wall, parameter_names) -> dict[str, Any]:
    joints = list(robot.joint_names)
    bodies = robot.body_names

    def per_joint(values):
        return {j: float(x) for j, x in zip(joints, values)}

    e = truth.effects
    return {
        "robot": robot.name,
        "joints": joints,
        "bodies": list(robot.body_names),
        "parameter_names": list(parameter_names),
        "parameters_frame": "about the body origin, in the body frame; payload lumped into its link",
        "phi_true": {b: true.phi[10 * i : 10 * i + 10].tolist() for i, b in enumerate(bodies)},
        "phi_model": {b: robot.phi_model[10 * i : 10 * i + 10].tolist() for i, b in enumerate(bodies)},
        "seed": truth.seed,
        "inertia_perturbation": truth.inertia_perturbation,
        "torque_equation": (
            "tau_recorded(t) = [ID_rigid_body_true(q, v, vd) + viscous*v + coulomb*tanh(v/"
            "coulomb_velocity_scale) + armature*vd + torque_offset](t - torque_delay) + noise"
        ),
        "effects": {
            "viscous": {"unit": "N·m·s/rad", "values": per_joint(true.viscous),
                        "model_file_damping": per_joint(true.model_damping),
                        "note": "replaces the model file's joint damping"},
            "coulomb": {"unit": "N·m", "values": per_joint(true.coulomb),
                        "velocity_scale": e.coulomb_velocity_scale, "velocity_scale_unit": "rad/s",
                        "model": "coulomb * tanh(v / velocity_scale)"},
            "armature": {"unit": "kg·m²", "values": per_joint(true.armature)},
            "torque_offset": {"unit": "N·m", "values": per_joint(true.torque_offset),
                              "convention": "added to the recorded torque (a constant load -offset "
                                            "acts on the joint)"},
            "torque_delay": {"unit": "s", "value": e.torque_delay,
                             "convention": "tau_recorded(t) = tau(t - delay)"},
            "payload": {
                "link": e.payload.link, "mass": e.payload.mass, "com": list(e.payload.com),
                "inertia_about_com": list(e.payload.inertia),
                "phi_about_link_origin": true.phi_payload.tolist(),
                "units": "kg, m, kg·m²",
            },
        },
        "noise": {**dataclasses.asdict(truth.noise),
                  "units": {"q_std": "rad", "v_std": "rad/s", "tau_std": "N·m", "force_std": "N",
                            "moment_std": "N·m", "wrench_offset": "N, N·m"}},
        "wrench_equation": (
            "wrench_recorded = reaction of the root link's weld on the robot (force; moment about the "
            "world origin; world frame) + wrench_offset + noise"
        ),
        "control": {**dataclasses.asdict(truth.control), "law": "computed torque + PD, zero-order hold",
                    "units": {"rate_hz": "Hz", "kp": "1/s²", "kd": "1/s"}},
        "record_velocity": truth.record_velocity,
        "torque_recorded": "command tau_k" if truth.record_command else "(tau_{k-1} + tau_k) / 2",
        "simulation": {
            "duration": duration, "samples": count, "rate_hz": truth.control.rate_hz,
            "integrator": truth.integrator, "accuracy": truth.integration_accuracy,
            "tracking_error_rms": per_joint(tracking_rms), "tracking_error_unit": "rad",
            "wall_time_s": wall,
        },
    }


def truth_path_for(out: str | Path) -> Path:
    """``<out stem>.truth.json`` beside the output CSV."""
    out = Path(out)
    return out.parent / f"{out.stem}.truth.json"


