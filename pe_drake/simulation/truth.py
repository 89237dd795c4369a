"""A simulated run's truth: the robot as built (a :class:`~pe_drake.multibody.robot_model.RobotModel`
around the a-priori or an identified model), sensor noise and the tracking controller.

:func:`load_truth` checks a TRUTH.yaml's shape and types against :data:`TRUTH_KEYS` (file, line
and key named); :func:`make_truth` reads its ``effects`` into the true model, every number and
name checked against the robot. The effects' sign convention is the simulation module's.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pe_drake import limits
from pe_drake.config import check_choice, check_finite
from pe_drake.exceptions import ConfigError, UnknownNameError, shorten
from pe_drake.multibody.inertia import inertia_matrix, perturb_inertias
from pe_drake.multibody.payload import PayloadInertia, payload_spatial_inertia
from pe_drake.multibody.robot_model import COULOMB_VELOCITY_SCALE, FILE_KEYS, RobotModel
from pe_drake.multibody.transmission import robot_transmission
from pe_drake.multibody.wrench import WRENCH_COLUMNS
from pe_drake.yaml_check import check_yaml_file

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Key of a per-joint table that sets every joint not listed by name.
ALL_JOINTS = "all"
CONTROL_MODELS = ("prior", "true")


@dataclasses.dataclass
class NoiseTruth:
    """Sensor imperfections of the log (the controller sees the true state); white noise std."""

    encoder_counts_per_rev: int = 0  # q of revolute joints quantized to 2π/counts; 0: none
    q_std: float = 0.0  # [rad]
    v_std: float = 0.0  # [rad/s] (only with record_velocity)
    tau_std: float = 0.0  # [N·m]
    force_std: float = 0.0  # [N] of the ground wrench's force (wrench.f* columns)
    moment_std: float = 0.0  # [N·m] of the ground wrench's moment (wrench.m*)
    # constant force/torque sensor offset [fx, fy, fz, mx, my, mz] [N, N·m]; empty: none
    wrench_offset: list[float] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class ControlTruth:
    """The tracking controller (computed torque + PD, zero-order hold)."""

    rate_hz: float = 1000.0  # control and logging rate [Hz]
    kp: float = 6400.0  # position gain [1/s²] (times the model's mass matrix)
    kd: float = 160.0  # velocity gain [1/s]
    # the rigid-body model: "prior" (a-priori, realistic) or "true" (payload and armature
    # included; friction is still left to the feedback)
    model: str = "prior"


_JOINT_TABLES = {  # effects table: (unit, non-negative)
    "viscous": ("N·m·s/rad", True), "coulomb": ("N·m", True), "armature": ("kg·m²", True),
    "torque_offset": ("N·m", False), "presliding_friction": ("N·m", True),
    "presliding_stiffness": ("N·m/rad", True),
}
#: The TRUTH.yaml ``effects`` section (key: type; :func:`make_truth` says what each is).
EFFECT_KEYS = {**{k: dict[str, float] for k in _JOINT_TABLES}, "coulomb_velocity_scale": float,
               "torque_delay": float, "payload": {"link": str, "mass": float, "com": list[float], "inertia": list[float]}}
#: A whole TRUTH.yaml (key: type): :class:`Truth`'s attributes with ``effects`` for ``model``.
TRUTH_KEYS = {"seed": int, "inertia_perturbation": float, "effects": EFFECT_KEYS, "noise": NoiseTruth,
              "control": ControlTruth, "record_velocity": bool, "record_command": bool,
              "integration_accuracy": float, "integrator": str}


@dataclasses.dataclass(frozen=True, eq=False)
class Truth:
    """A simulated run's truth: the robot as built, noise and control (a whole TRUTH.yaml)."""

    model: RobotModel  # the true robot (:func:`make_truth`)
    noise: NoiseTruth = dataclasses.field(default_factory=NoiseTruth)
    control: ControlTruth = dataclasses.field(default_factory=ControlTruth)
    seed: int = 0  # seeds the inertial perturbation and, independently, the noise
    inertia_perturbation: float = 0.0  # relative size ε in [0, 0.5] of the perturbation in model
    record_velocity: bool = False  # also write v.<joint> columns (true v + noise.v_std)
    # the raw command tau_k instead of the centred (tau_{k-1} + tau_k)/2 (simulation module)
    record_command: bool = False
    integration_accuracy: float = 1e-4
    # a Drake scheme: "runge_kutta3" (fastest for arms), "radau3" when light joints with Coulomb
    # friction make the dynamics stiff
    integrator: str = "runge_kutta3"
    # {"viscous" | "coulomb": joints whose friction the truth sets}; the others keep the model
    # file's (every joint around an identified model)
    friction_set: Mapping[str, frozenset[str]] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        seed, n, c = self.seed, self.noise, self.control
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")
        eps = check_finite("inertia_perturbation", self.inertia_perturbation, nonneg=True)
        if eps > 0.5:
            raise ConfigError(f"inertia_perturbation must lie in [0, 0.5] (relative), got {eps}")
        check_finite("integration_accuracy", self.integration_accuracy, positive=True)
        if self.integration_accuracy > 1e-2:
            raise ConfigError(f"integration_accuracy must be at most 1e-2, got {self.integration_accuracy}")
        from pydrake.systems.analysis import GetIntegrationSchemes  # lazy: pydrake is heavy

        if self.integrator not in GetIntegrationSchemes():
            raise ConfigError(f"integrator '{self.integrator}' is not one of Drake's schemes: "
                              f"{', '.join(GetIntegrationSchemes())}")
        counts = n.encoder_counts_per_rev
        if isinstance(counts, bool) or not isinstance(counts, int) or counts < 0:
            raise ConfigError("noise.encoder_counts_per_rev must be a non-negative integer, "
                              f"got {counts!r}")
        for name in ("q_std", "v_std", "tau_std", "force_std", "moment_std"):
            check_finite(f"noise.{name}", getattr(n, name), nonneg=True)
        if len(n.wrench_offset) not in (0, 6):
            raise ConfigError("noise.wrench_offset must be [fx, fy, fz, mx, my, mz] [N, N·m] "
                              f"(or empty), got {n.wrench_offset!r}")
        for k, value in enumerate(n.wrench_offset):
            check_finite(f"noise.wrench_offset[{k}] ({WRENCH_COLUMNS[k]})", value)
        rate = check_finite("control.rate_hz [Hz]", c.rate_hz, positive=True)
        if rate > 1e5:
            raise ConfigError(f"control.rate_hz must be at most 100 kHz, got {rate}")
        check_finite("control.kp [1/s²]", c.kp, nonneg=True)
        check_finite("control.kd [1/s]", c.kd, nonneg=True)
        check_choice("control.model", c.model, CONTROL_MODELS)


def load_truth(path: str | Path, robot: Robot) -> Truth:
    """Reads a TRUTH.yaml for ``robot``; ConfigError (file and key named) or UnknownNameError."""
    return make_truth(robot, where=f"truth file '{path}'", **read_truth_file(path))


def read_truth_file(path: str | Path) -> dict[str, Any]:
    """A TRUTH.yaml's keys as :func:`make_truth`'s arguments, the numbers not checked yet
    (ConfigError naming file, line and key)."""
    from pydrake.common.yaml import yaml_load  # lazy, like every pydrake import

    path = Path(path)
    problem = limits.input_file_problem(path)
    if problem:
        raise ConfigError(f"truth file '{path}' {problem}")
    check_yaml_file(path, TRUTH_KEYS, "truth")  # syntax and shape, naming the line and the key
    return _typed(yaml_load(filename=str(path)) or {}, TRUTH_KEYS, f"truth file '{path}'", "")


def _typed(value: Any, schema: Any, where: str, key: str) -> Any:
    """``value`` (checked by :func:`~pe_drake.yaml_check.check_yaml_file`) as ``schema``'s types,
    converted as Drake's ``yaml_load_typed`` does (int → float, a number's text → number)."""
    if isinstance(schema, dict) or dataclasses.is_dataclass(schema):
        fields = schema if isinstance(schema, dict) else typing.get_type_hints(schema)
        out = {k: _typed(v, fields[k], where, f"{key}.{k}" if key else k) for k, v in value.items()}
        return out if isinstance(schema, dict) else schema(**out)
    origin, args = typing.get_origin(schema), typing.get_args(schema)
    if origin is list:
        return [_typed(x, args[0], where, key) for x in value or []]
    if origin is dict:
        return {str(k): _typed(v, args[1], where, f"{key}['{k}']") for k, v in value.items()}
    if schema in (float, int) and type(value) in (int, float, str) and not isinstance(value, bool):
        return schema(value)
    if type(value) is schema:
        return value
    raise ConfigError(f"{where} does not match the truth format: key '{key}' expects {schema.__name__}, got "
                      f"{type(value).__name__} {shorten(repr(value))}")


def make_truth(robot: Robot, effects: Mapping[str, Any] | None = None, *, model: RobotModel | None = None,
               where: str = "", **run: Any) -> Truth:
    """The truth of ``robot``: the robot as built from an ``effects`` section, noise and control.

    The true model is ``model`` (default: the a-priori robot with its model file's friction)
    with the effects, its bodies' parameters perturbed and the payload welded. The truth's
    friction replaces the model file's on the joints it sets; on an identified ``model`` the
    truth's per-joint effects and delay add to the model's. With a transmission the truth's
    viscous, coulomb, armature and torque_offset are per motor and the model file's joint
    friction is not simulated (``identify`` fits the motors' terms as the whole friction).

    Args:
        effects: a TRUTH.yaml ``effects`` section as data (keys and units in
            examples/truth_example.yaml); a per-joint table's ``all`` sets every joint not named.
        where: what to name in errors (the file).
        run: the other :class:`Truth` attributes (``seed``, ``noise``, ``control``, ...).

    Raises:
        ConfigError: a bad value (key, joint and value named); Coulomb friction of another v_s
            than the model's, or pre-sliding friction where the model has its own.
        UnknownNameError: a joint or link the robot does not have (valid names listed).
    """
    try:
        # the run's keys checked before the perturbation draws from the seed
        truth = Truth(model or RobotModel(robot.joint_names, robot.body_names, robot.phi_model), **run)
        e = _effects(effects or {})
        _check_names(e, robot)
        true, friction_set = _as_built(robot, e, model, truth.seed, truth.inertia_perturbation)
    except ConfigError as err:  # UnknownNameError too: its type and fields kept, the file named
        if where:
            err.args = (f"{where}: {err}",)
        raise
    return dataclasses.replace(truth, model=true, friction_set=friction_set)


def _effects(data: Mapping[str, Any]) -> dict[str, Any]:
    """An effects section with every key (:data:`EFFECT_KEYS`), checked without the robot."""
    unknown = sorted(set(data) - set(EFFECT_KEYS)) + sorted(set(data.get("payload") or {}) - set(EFFECT_KEYS["payload"]))
    if unknown:
        raise ConfigError(f"unknown effects key(s) {', '.join(unknown)}; valid keys: {', '.join(EFFECT_KEYS)}, "
                          f"payload.{{{', '.join(EFFECT_KEYS['payload'])}}}")
    e = {**{k: {} for k in _JOINT_TABLES}, "coulomb_velocity_scale": COULOMB_VELOCITY_SCALE, "torque_delay": 0.0,
         **data, "payload": {"link": "", "mass": 0.0, "com": [0.0] * 3, "inertia": [0.0] * 6, **(data.get("payload") or {})}}
    for field, (unit, nonneg) in _JOINT_TABLES.items():
        if not isinstance(e[field], Mapping):
            raise ConfigError(f"effects.{field} must map joint names to values [{unit}], got {shorten(repr(e[field]))}")
        for joint, value in e[field].items():
            check_finite(f"effects.{field}['{joint}'] [{unit}]", value, nonneg=nonneg)
    check_finite("effects.coulomb_velocity_scale [rad/s]", e["coulomb_velocity_scale"], positive=True)
    check_finite("effects.torque_delay [s]", e["torque_delay"])
    p = e["payload"]
    if len(p["com"]) != 3:
        raise ConfigError(f"effects.payload.com must have 3 numbers [m], got {p['com']}")
    if len(p["inertia"]) != 6:
        raise ConfigError(f"effects.payload.inertia must be [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] [kg·m²], got {p['inertia']}")
    for k, value in enumerate(list(p["com"]) + list(p["inertia"])):
        check_finite("effects.payload.com" if k < 3 else "effects.payload.inertia", value)
    check_finite("effects.payload.mass [kg]", p["mass"], nonneg=True)
    if p["link"] and p["mass"] <= 0:
        raise ConfigError(f"effects.payload.mass must be positive for a payload on '{p['link']}', got {p['mass']}")
    if not p["link"] and (p["mass"] != 0 or any(p["inertia"])):
        raise ConfigError("effects.payload has a mass or inertia but no link: set effects.payload.link")
    if p["link"]:  # raises when not physically valid
        payload_spatial_inertia(_payload(p))
    return e


def _payload(p: Mapping[str, Any]) -> PayloadInertia:
    return PayloadInertia(float(p["mass"]), np.asarray(p["com"], float), inertia_matrix(p["inertia"]))


def _check_names(e: Mapping[str, Any], robot: Robot) -> None:
    """Joint and link names of an effects section against the robot."""
    for field in _JOINT_TABLES:
        for joint in e[field]:
            if joint != ALL_JOINTS and joint not in robot.joint_names:
                raise UnknownNameError("joint", joint, (*robot.joint_names, ALL_JOINTS), where=f"effects.{field}")
    link = e["payload"]["link"]
    if link and link not in robot.body_names:
        raise UnknownNameError("link", link, robot.body_names, where="effects.payload.link")
    fc = per_joint_values(e["presliding_friction"], robot.joint_names)
    sigma0 = per_joint_values(e["presliding_stiffness"], robot.joint_names)
    for k, name in enumerate(robot.joint_names):
        if fc[k] > 0 and not sigma0[k] > 0:
            raise ConfigError(f"effects.presliding_friction['{name}'] = {fc[k]:g} N·m needs a "
                              f"positive effects.presliding_stiffness['{name}'] [N·m/rad] (σ0 of "
                              "the Dahl model)")


def _as_built(robot: Robot, e: Mapping[str, Any], model: RobotModel | None, seed: int,
              eps: float) -> tuple[RobotModel, dict[str, frozenset[str]]]:
    """The true model of a checked effects section and the joints whose friction it sets."""
    joints = robot.joint_names
    # the truth's tables are named as the model file's (RobotModel's FILE_KEYS)
    tables = {t: per_joint_values(e[field], joints) for t, field in FILE_KEYS.items()}
    fc, sigma0 = per_joint_values(e["presliding_friction"], joints), per_joint_values(e["presliding_stiffness"], joints)
    transmission = robot_transmission(robot) if model is None else model.transmission
    transmission = None if transmission is None or transmission.identity else transmission
    v_s, delay = float(e["coulomb_velocity_scale"]), float(e["torque_delay"])
    friction_set = {k: frozenset(joints if model is not None or ALL_JOINTS in e[k] else set(e[k]) & set(joints))
                    for k in ("viscous", "coulomb")}
    if model is None and transmission is None:  # the truth's friction where it sets a joint, else the model file's
        tables["viscous"], tables["coulomb"] = (
            per_joint_values(t, joints) if ALL_JOINTS in t else np.array([float(t.get(j, m)) for j, m in zip(joints, x)])
            for t, x in ((e["viscous"], robot.joint_damping), (e["coulomb"], robot.joint_friction)))
    phi = robot.phi_model  # with a transmission, the model file's joint friction is not the motors'
    if model is not None:
        _check_model_truth(model, tables["coulomb"], fc, v_s)
        tables = {t: x + model.term(t) for t, x in tables.items()}
        if np.any(model.presliding > 0):
            fc, sigma0 = model.presliding, model.presliding_stiffness
        phi, v_s, delay = model.phi_total, model.velocity_scale, e["torque_delay"] + model.torque_delay
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(2)[0])
    phi = perturb_inertias(np.asarray(phi, float), eps, rng, body_names=robot.body_names)
    p = e["payload"]
    true = RobotModel(joints, robot.body_names, phi, tables, velocity_scale=v_s,
                      payload=_payload(p) if p["link"] else None, payload_link=p["link"],
                      torque_delay=float(delay), presliding=fc, presliding_stiffness=sigma0,
                      notes=model.notes if model is not None else (), transmission=transmission)
    return true, friction_set


def _check_model_truth(model: RobotModel, coulomb: np.ndarray, presliding: np.ndarray, v_s: float) -> None:
    """One tanh(v/v_s) and one Dahl model per joint are simulated (:func:`make_truth`)."""
    if np.any(coulomb > 0) and not math.isclose(v_s, model.velocity_scale, rel_tol=1e-12):
        raise ConfigError(f"effects.coulomb_velocity_scale {v_s:g} rad/s of the truth file differs from the model's "
                          f"{model.velocity_scale:g} rad/s: one tanh(v/v_s) is simulated; remove the truth's coulomb "
                          "or set the model's v_s")
    if np.any(model.presliding > 0) and np.any(presliding > 0):
        raise ConfigError("both the truth file and the model have pre-sliding friction: one Dahl model per joint is "
                          "simulated; remove the truth's presliding_*")


def per_joint_values(table: Mapping[str, float], joints: tuple[str, ...]) -> np.ndarray:
    """Per-joint table (with the ``all`` key) → values in joint order, shape (n,)."""
    default = float(table.get(ALL_JOINTS, 0.0))
    return np.array([float(table.get(j, default)) for j in joints])
