"""The TRUTH.yaml schema of a simulated run: what the true robot has beyond the a-priori model.

``pe-drake simulate --truth TRUTH.yaml`` (:mod:`pe_drake.simulation.simulation`) builds
the true robot from these dataclasses: perturbed inertias, friction, armature, torque offsets
and delay, a payload, sensor noise and the tracking controller. :func:`load_truth` reads a
file onto :class:`Truth` with Drake's ``yaml_load_typed`` (unknown keys refused) and
:func:`validate_truth` checks every number and, given a robot, every joint and link name.
The sign convention of the effects is in the simulation module's docstring.
"""
# No ``from __future__ import annotations`` here: yaml_load_typed reads the dataclass field
# types at run time and cannot resolve string annotations.

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.config import check_finite
from pe_drake.yaml_check import load_yaml_typed
from pe_drake.exceptions import ConfigError, UnknownNameError
from pe_drake.multibody.inertia import inertia_matrix
from pe_drake.multibody.payload import PayloadInertia
from pe_drake.multibody.payload import payload_spatial_inertia
from pe_drake.multibody.robot_model import COULOMB_VELOCITY_SCALE
from pe_drake.multibody.wrench import WRENCH_COLUMNS

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Key of a per-joint table that sets every joint not listed by name.
ALL_JOINTS = "all"
CONTROL_MODELS = ("prior", "true")


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
    Joints absent from a table get 0, except for the friction the model file already has
    (``viscous``, ``coulomb``): that is part of the a-priori model and is kept.

    Attributes:
        viscous: viscous friction f_v [N·m·s/rad] (Drake joint damping). A joint this table
            sets (by name or ``all``) has this value instead of the model file's
            ``<dynamics damping>``; a joint it does not set keeps the model file's.
        coulomb: Coulomb friction f_c [N·m], smoothed as f_c·tanh(v/v_s) (revolute joints);
            like ``viscous``, it replaces the model file's ``<dynamics friction>`` where set.
        coulomb_velocity_scale: v_s [rad/s].
        armature: reflected rotor inertia I_a [kg·m²], adds I_a·vd.
        torque_offset: constant torque o [N·m] the actuator must supply (sign convention:
            :mod:`pe_drake.simulation.simulation`).
        torque_delay: recorded torque lags the positions by this [s] (negative: leads).
        payload: see :class:`PayloadTruth`.
        presliding_friction: Dahl friction level F_c [N·m] (:mod:`pe_drake.multibody.dahl`,
            a Drake system with one state per joint).
        presliding_stiffness: its stiffness at rest σ0 [N·m/rad]; the pre-sliding
            displacement is F_c/σ0. Needed for every joint with ``presliding_friction``.
    """

    viscous: dict[str, float] = dataclasses.field(default_factory=dict)
    coulomb: dict[str, float] = dataclasses.field(default_factory=dict)
    coulomb_velocity_scale: float = COULOMB_VELOCITY_SCALE
    armature: dict[str, float] = dataclasses.field(default_factory=dict)
    torque_offset: dict[str, float] = dataclasses.field(default_factory=dict)
    torque_delay: float = 0.0
    payload: PayloadTruth = dataclasses.field(default_factory=PayloadTruth)
    presliding_friction: dict[str, float] = dataclasses.field(default_factory=dict)
    presliding_stiffness: dict[str, float] = dataclasses.field(default_factory=dict)


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
        inertia_perturbation: relative size ε in [0, 0.5] (:func:`pe_drake.multibody.inertia.perturb_inertias`).
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
    path = Path(path)
    truth = load_yaml_typed(path, Truth, Truth(), "truth")
    try:
        return validate_truth(truth)
    except ConfigError as err:
        raise ConfigError(f"truth file '{path}': {err}") from err


_JOINT_TABLES = {  # field: (unit, non-negative)
    "viscous": ("N·m·s/rad", True),
    "coulomb": ("N·m", True),
    "armature": ("kg·m²", True),
    "torque_offset": ("N·m", False),
    "presliding_friction": ("N·m", True),
    "presliding_stiffness": ("N·m/rad", True),
}


def validate_truth(truth: Truth, robot: "Robot | None" = None) -> Truth:
    """Checks a :class:`Truth`; with a robot, also its joint and link names.

    Raises:
        ConfigError: naming the field and the bad value.
        UnknownNameError: a joint or link the robot does not have (valid names listed).
    """
    _check_run(truth)
    _check_effects(truth.effects)
    _check_noise_and_control(truth.noise, truth.control)
    if robot is not None:
        _check_names(truth.effects, robot)
    return truth


def _check_run(truth: Truth) -> None:
    """Seed, inertial perturbation and integrator."""
    if isinstance(truth.seed, bool) or not isinstance(truth.seed, int) or truth.seed < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {truth.seed!r}")
    eps = check_finite("inertia_perturbation", truth.inertia_perturbation, nonneg=True)
    if eps > 0.5:
        raise ConfigError(f"inertia_perturbation must lie in [0, 0.5] (relative), got {eps}")
    check_finite("integration_accuracy", truth.integration_accuracy, positive=True)
    if truth.integration_accuracy > 1e-2:
        raise ConfigError(f"integration_accuracy must be at most 1e-2, got {truth.integration_accuracy}")
    from pydrake.systems.analysis import GetIntegrationSchemes  # lazy: pydrake stays out of `import pe_drake`

    if truth.integrator not in GetIntegrationSchemes():
        raise ConfigError(
            f"integrator '{truth.integrator}' is not one of Drake's schemes: "
            f"{', '.join(GetIntegrationSchemes())}"
        )


def _check_effects(e: EffectsTruth) -> None:
    """Per-joint tables, Coulomb scale, delay and payload (robot-independent)."""
    for field, (unit, nonneg) in _JOINT_TABLES.items():
        table = getattr(e, field)
        for joint, value in table.items():
            check_finite(f"effects.{field}['{joint}'] [{unit}]", value, nonneg=nonneg)
    check_finite("effects.coulomb_velocity_scale [rad/s]", e.coulomb_velocity_scale, positive=True)
    check_finite("effects.torque_delay [s]", e.torque_delay)
    p = e.payload
    if len(p.com) != 3:
        raise ConfigError(f"effects.payload.com must have 3 numbers [m], got {p.com}")
    if len(p.inertia) != 6:
        raise ConfigError(
            f"effects.payload.inertia must be [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] [kg·m²], got {p.inertia}"
        )
    for k, value in enumerate(list(p.com) + list(p.inertia)):
        check_finite("effects.payload.com" if k < 3 else "effects.payload.inertia", value)
    check_finite("effects.payload.mass [kg]", p.mass, nonneg=True)
    if p.link and p.mass <= 0:
        raise ConfigError(f"effects.payload.mass must be positive for a payload on '{p.link}', got {p.mass}")
    if not p.link and (p.mass != 0 or any(p.inertia)):
        raise ConfigError("effects.payload has a mass or inertia but no link: set effects.payload.link")
    if p.link:  # raises when not physically valid
        payload_spatial_inertia(PayloadInertia(float(p.mass), np.asarray(p.com, float), inertia_matrix(p.inertia)))


def _check_noise_and_control(n: NoiseTruth, c: ControlTruth) -> None:
    counts = n.encoder_counts_per_rev
    if isinstance(counts, bool) or not isinstance(counts, int) or counts < 0:
        raise ConfigError(f"noise.encoder_counts_per_rev must be a non-negative integer, got {counts!r}")
    for name in ("q_std", "v_std", "tau_std", "force_std", "moment_std"):
        check_finite(f"noise.{name}", getattr(n, name), nonneg=True)
    if len(n.wrench_offset) not in (0, 6):
        raise ConfigError(
            f"noise.wrench_offset must be [fx, fy, fz, mx, my, mz] [N, N·m] (or empty), got {n.wrench_offset!r}"
        )
    for k, value in enumerate(n.wrench_offset):
        check_finite(f"noise.wrench_offset[{k}] ({WRENCH_COLUMNS[k]})", value)
    rate = check_finite("control.rate_hz [Hz]", c.rate_hz, positive=True)
    if rate > 1e5:
        raise ConfigError(f"control.rate_hz must be at most 100 kHz, got {rate}")
    check_finite("control.kp [1/s²]", c.kp, nonneg=True)
    check_finite("control.kd [1/s]", c.kd, nonneg=True)
    if c.model not in CONTROL_MODELS:
        raise ConfigError(f"control.model '{c.model}' is not one of {', '.join(CONTROL_MODELS)}")


def _check_names(e: EffectsTruth, robot: "Robot") -> None:
    """Joint and link names against the robot."""
    for field in _JOINT_TABLES:
        for joint in getattr(e, field):
            if joint != ALL_JOINTS and joint not in robot.joint_names:
                raise UnknownNameError(
                    "joint", joint, (*robot.joint_names, ALL_JOINTS), where=f"effects.{field}"
                )
    p = e.payload
    if p.link and p.link not in robot.body_names:
        raise UnknownNameError("link", p.link, robot.body_names, where="effects.payload.link")
    fc = per_joint_values(e.presliding_friction, robot.joint_names)
    sigma0 = per_joint_values(e.presliding_stiffness, robot.joint_names)
    for k, name in enumerate(robot.joint_names):
        if fc[k] > 0 and not sigma0[k] > 0:
            raise ConfigError(
                f"effects.presliding_friction['{name}'] = {fc[k]:g} N·m needs a positive "
                f"effects.presliding_stiffness['{name}'] [N·m/rad] (σ0 of the Dahl model)"
            )



def per_joint_values(table: dict[str, float], joints: tuple[str, ...]) -> np.ndarray:
    """Per-joint table (with the ``all`` key) → values in joint order, shape (n,)."""
    default = float(table.get(ALL_JOINTS, 0.0))
    return np.array([float(table.get(j, default)) for j in joints])
