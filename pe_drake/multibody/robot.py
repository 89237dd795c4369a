"""Loading a robot into Drake: excited joints, locked posture, limits, kinematic structure.

:func:`load_robot` turns a built-in name (``panda``, ``ur5``, ``g1``) or a URDF/SDF path into
a :class:`Robot`: a MultibodyPlant whose generalized positions are exactly the excited joints
(every other joint is welded at its locked position), with the root link welded to the world,
the joint limits the optimizer uses, and the tree structure the regressor needs.
"""

from __future__ import annotations

import dataclasses
import logging
import re
import sys
import sysconfig
from collections.abc import Callable
from functools import cached_property
from pathlib import Path

import numpy as np

from pe_drake.config import Config, RobotConfig, load_config, validate_config
from pe_drake.exceptions import (
    ConfigError,
    InfeasibleError,
    NotWithinLimitsError,
    UnknownNameError,
)
from pe_drake.multibody.inertia import PARAMETER_NAMES, spatial_inertia_to_phi
from pe_drake.multibody.urdf_checks import check_joint_types

_MODELS_PACKAGE = "pe_drake.models"


def builtin_robots() -> tuple[str, ...]:
    """Names of the built-in robot configs (``models/<name>.yaml``)."""
    # A robot config has a top-level "robot:" section; capsule and truth files do not.
    return tuple(
        sorted(
            p.stem
            for p in _models_dir().glob("*.yaml")
            if re.search(r"^robot:", p.read_text(), flags=re.M)
        )
    )


def _models_dir() -> Path:
    from importlib.resources import files

    return Path(str(files(_MODELS_PACKAGE)))


def example_robot_data_dir() -> Path:
    """The ``share/example-robot-data`` folder of the installed ``example-robot-data`` wheel.

    Raises:
        ConfigError: when the package is not installed.
    """
    roots = [sysconfig.get_paths()["purelib"], *sys.path]
    for root in roots:
        candidate = Path(root) / "cmeel.prefix" / "share" / "example-robot-data"
        if candidate.is_dir():
            return candidate
    raise ConfigError(
        "the robot models of 'example-robot-data' are not installed: pip install example-robot-data"
    )


def builtin_config(name: str) -> Config:
    """The config of a built-in robot.

    Raises:
        UnknownNameError: listing the built-in names.
    """
    path = _models_dir() / f"{name}.yaml"
    if not path.is_file():
        raise UnknownNameError("robot", name, builtin_robots())
    return load_config(path)


def resolve_robot_config(robot: str, config_file: str | Path | None = None) -> Config:
    """Config for a robot given by built-in name or model path, with a user file on top.

    Args:
        robot: built-in name, or a URDF/SDF path.
        config_file: optional YAML file whose keys override the defaults.

    Raises:
        UnknownNameError: an unknown built-in name that is not a file either.
        ConfigError: a missing model file or a bad config.
    """
    if robot in builtin_robots():
        base = builtin_config(robot)
    else:
        path = Path(robot)
        if path.suffix.lower() not in (".urdf", ".sdf", ".xml"):
            raise UnknownNameError("robot", robot, builtin_robots() + ("<path to .urdf/.sdf>",))
        if not path.is_file():
            raise ConfigError(f"robot model file '{robot}' does not exist")
        base = Config(robot=RobotConfig(model=str(path.resolve())))
    if config_file is not None:
        return load_config(config_file, base=base)
    return validate_config(base)


@dataclasses.dataclass(frozen=True)
class JointInfo:
    """One excited joint.

    Attributes:
        name: joint name.
        kind: "revolute" or "prismatic".
        child_body: index (into ``Robot.body_names_all``) of the joint's child body.
        X_CM: pose of the joint's child frame M in the child body frame C, (4, 4).
        axis_M: unit joint axis in M, (3,).
    """

    name: str
    kind: str
    child_body: int
    X_CM: np.ndarray
    axis_M: np.ndarray


@dataclasses.dataclass(frozen=True)
class Limits:
    """Joint limits used by the optimizer, after config overrides and margins.

    All arrays have shape (n,), in the robot's joint order. Units: rad (m), rad/s, rad/s²,
    N·m (N).
    """

    q_lower: np.ndarray
    q_upper: np.ndarray
    v_max: np.ndarray
    vd_max: np.ndarray
    effort_max: np.ndarray


class Robot:
    """A Drake model with the excited joints free and every other joint welded.

    Attributes:
        name: built-in name or model file stem.
        config: the :class:`RobotConfig` it was built from.
        plant: the finalized MultibodyPlant (continuous, q = excited joints).
        scene_graph: its SceneGraph (collision geometry is our capsules, if any).
        diagram: plant + scene graph.
        joint_names: excited joints, in the plant's position order.
        limits: the :class:`Limits` the optimizer uses.
        locked_positions: {joint: value} of every welded (non-excited) joint.
        body_names: bodies moved by at least one excited joint (the regressor's bodies).
    """

    def __init__(
        self,
        name: str,
        config: RobotConfig,
        *,
        time_step: float = 0.0,
        obj_visuals: bool = False,
        before_finalize: Callable | None = None,
        builder_hook: Callable | None = None,
    ):
        self.name = name
        self.config = config
        self.time_step = float(time_step)
        self._obj_visuals = obj_visuals
        self._before_finalize = before_finalize
        self._builder_hook = builder_hook
        self._build()

    # ---- construction -------------------------------------------------------------------
    def _build(self) -> None:
        from pydrake.math import RigidTransform, RollPitchYaw
        from pydrake.multibody.parsing import Parser
        from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
        from pydrake.multibody.tree import PrismaticJoint, RevoluteJoint
        from pydrake.systems.framework import DiagramBuilder

        cfg = self.config
        model_path = _resolve_model_path(cfg.model)
        text = model_path.read_text()
        if model_path.suffix.lower() == ".urdf":
            check_joint_types(text, model_path)  # floating/ball joints: name them
            # Drake cannot build convex hulls of STL/DAE collision meshes (DRAKE_NOTES.md);
            # collision is our own capsules. Mimic tags would couple joints we may lock.
            text = re.sub(r"<collision\b.*?</collision>", "", text, flags=re.S)
            text = re.sub(r"<mimic\b[^>]*/>", "", text)
            from pe_drake.multibody.meshes import absolute_mesh_paths

            text = absolute_mesh_paths(text, model_path)  # parsed from a string below
            if self._obj_visuals:
                from pe_drake.multibody.meshes import stl_visuals_to_obj

                text = stl_visuals_to_obj(text, model_path)

        builder = DiagramBuilder()
        plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=self.time_step)
        parser = Parser(plant)
        try:
            parser.package_map().Add("example-robot-data", str(example_robot_data_dir()))
        except ConfigError:
            pass
        try:  # user models may ship a package.xml next to them
            parser.package_map().PopulateFromFolder(str(model_path.parent))
        except Exception:
            pass
        drake_logger = logging.getLogger("drake")
        level = drake_logger.level
        drake_logger.setLevel(logging.ERROR)  # unsupported ROS tags (gazebo, transmission)
        try:
            models = parser.AddModelsFromString(text, model_path.suffix.lstrip(".").lower())
        except Exception as err:  # Drake raises RuntimeError with its parser message
            raise ConfigError(f"Drake could not parse '{model_path}': {err}") from err
        finally:
            drake_logger.setLevel(level)
        self.model_path = model_path

        movable = [
            plant.get_joint(j)
            for m in models
            for j in plant.GetJointIndices(m)
            if plant.get_joint(j).num_positions() == 1
        ]
        movable_names = [j.name() for j in movable]
        excited = list(cfg.joints) if cfg.joints else list(movable_names)
        for j in excited:
            if j not in movable_names:
                raise UnknownNameError("joint", j, movable_names, where=str(model_path.name))
        if len(set(excited)) != len(excited):
            raise ConfigError(f"robot.joints lists a joint twice: {excited}")
        for j in cfg.locked_positions:
            if j not in movable_names:
                raise UnknownNameError("joint", j, movable_names, where="robot.locked_positions")
            if j in excited:
                raise ConfigError(f"joint '{j}' is both excited and in robot.locked_positions")
        for table in ("position_limits", "velocity_limits", "acceleration_limits", "effort_limits", "nominal_positions"):
            for j in getattr(cfg, table):
                if j not in excited:
                    raise UnknownNameError("joint", j, excited, where=f"robot.{table} (excited joints)")

        # Weld every non-excited joint at its locked position.
        locked: dict[str, float] = {}
        for joint in movable:
            if joint.name() in excited:
                continue
            lo, hi = joint.position_lower_limits()[0], joint.position_upper_limits()[0]
            value = cfg.locked_positions.get(joint.name(), float(np.clip(0.0, lo, hi)))
            if not lo - 1e-9 <= value <= hi + 1e-9:
                raise NotWithinLimitsError(joint.name(), value, lo, hi, what="locked position")
            locked[joint.name()] = float(value)
            if isinstance(joint, RevoluteJoint):
                from pydrake.common.eigen_geometry import AngleAxis

                X_FM = RigidTransform(AngleAxis(value, joint.revolute_axis()), np.zeros(3))
            elif isinstance(joint, PrismaticJoint):
                X_FM = RigidTransform(joint.translation_axis() * value)
            else:
                raise ConfigError(f"cannot lock joint '{joint.name()}' of type {joint.type_name()}")
            frame_F, frame_M = joint.frame_on_parent(), joint.frame_on_child()
            for actuator_index in plant.GetJointActuatorIndices():
                if plant.get_joint_actuator(actuator_index).joint().index() == joint.index():
                    plant.RemoveJointActuator(plant.get_joint_actuator(actuator_index))
            plant.RemoveJoint(joint)
            plant.WeldFrames(frame_F, frame_M, X_FM)
        self.locked_positions = locked

        # Weld the root link to the world.
        root = self._root_body(plant, models)
        pose = RigidTransform(
            _quaternion(cfg.base_quaternion_wxyz), np.asarray(cfg.base_position, float)
        )
        if not plant.GetBodiesWeldedTo(plant.world_body()).__contains__(root):
            plant.WeldFrames(plant.world_frame(), root.body_frame(), pose)
        self.root_link = root.name()
        self.base_pose = pose
        self._scene_graph_builder_hook(plant, scene_graph)
        if self._before_finalize is not None:
            self._before_finalize(plant, scene_graph)
        plant.Finalize()
        del RollPitchYaw

        if plant.num_positions() != len(excited) or plant.num_velocities() != len(excited):
            raise ConfigError(
                f"after locking, the plant has {plant.num_positions()} positions but "
                f"{len(excited)} excited joints: is the root link '{self.root_link}' free?"
            )
        if self._builder_hook is not None:  # e.g. Meshcat visualizers (pe_drake.viewer)
            self._builder_hook(builder, plant, scene_graph)
        self.diagram = builder.Build()
        self.plant = plant
        self.scene_graph = scene_graph
        self.context = self.diagram.CreateDefaultContext()
        self.plant_context = plant.GetMyMutableContextFromRoot(self.context)

        joints = [plant.GetJointByName(j) for j in excited]
        joints.sort(key=lambda j: j.position_start())
        self.joint_names = tuple(j.name() for j in joints)
        self.n = len(joints)
        self._joints = joints
        self._structure()
        self.limits = self._limits()

    def _scene_graph_builder_hook(self, plant, scene_graph) -> None:
        """Registers extra geometry before Finalize (capsules; see constraints.collision)."""
        if self.config.capsules:
            from pe_drake.multibody.capsules import register_capsules

            self.capsules = register_capsules(plant, scene_graph, self.config.capsules)
        else:
            self.capsules = ()

    def _root_body(self, plant, models):
        bodies = [plant.get_body(b) for m in models for b in plant.GetBodyIndices(m)]
        names = [b.name() for b in bodies]
        if self.config.root_link:
            if self.config.root_link not in names:
                raise UnknownNameError("link", self.config.root_link, names, where="robot.root_link")
            return plant.GetBodyByName(self.config.root_link)
        children = set()
        for j in plant.GetJointIndices():
            joint = plant.get_joint(j)
            if joint.parent_body().index() != plant.world_body().index():
                children.add(joint.child_body().index())
        roots = [b for b in bodies if b.index() not in children]
        return roots[0]

    def _structure(self) -> None:
        """Tree structure of the excited joints and of the bodies they move."""
        plant = self.plant
        index_of_joint = {j.index(): k for k, j in enumerate(self._joints)}

        # For each body, the nearest excited joint upstream (-1: welded to the world).
        def upstream_joint(body) -> int:
            while body.index() != plant.world_body().index():
                joint = _inboard_joint(plant, body)
                if joint is None:
                    return -1
                if joint.index() in index_of_joint:
                    return index_of_joint[joint.index()]
                body = joint.parent_body()
            return -1

        from pydrake.multibody.tree import BodyIndex

        all_bodies = [plant.get_body(BodyIndex(b)) for b in range(plant.num_bodies())]
        self.body_names_all = tuple(b.name() for b in all_bodies)
        moving = [b for b in all_bodies if b.index() != 0 and upstream_joint(b) >= 0]
        self._bodies = moving
        self.body_names = tuple(b.name() for b in moving)
        self.body_indices = np.array([int(b.index()) for b in moving])
        self.joint_of_body = np.array([upstream_joint(b) for b in moving])

        n = self.n
        joint_parent = np.full(n, -1)
        for k, joint in enumerate(self._joints):
            joint_parent[k] = upstream_joint(joint.parent_body()) if joint.parent_body().index() != 0 else -1
        self.joint_parent = joint_parent
        # anc[l, i]: joint l is a strict ancestor of joint i.
        anc = np.zeros((n, n), bool)
        for i in range(n):
            p = joint_parent[i]
            while p >= 0:
                anc[p, i] = True
                p = joint_parent[p]
        self.joint_strict_ancestors = anc
        # moves[i, j]: joint i moves body j.
        moves = np.zeros((n, len(moving)), bool)
        for j, k in enumerate(self.joint_of_body):
            moves[k, j] = True
            moves[anc[:, k], j] = True
        self.joint_moves_body = moves

        infos = []
        for joint in self._joints:
            X_CM = joint.frame_on_child().GetFixedPoseInBodyFrame().GetAsMatrix4()
            if joint.type_name() == "revolute":
                kind, axis = "revolute", np.asarray(joint.revolute_axis(), float)
            elif joint.type_name() == "prismatic":
                kind, axis = "prismatic", np.asarray(joint.translation_axis(), float)
            else:
                raise ConfigError(
                    f"joint '{joint.name()}' is a {joint.type_name()} joint; only revolute and "
                    "prismatic joints can be excited"
                )
            infos.append(
                JointInfo(joint.name(), kind, int(joint.child_body().index()), X_CM, axis / np.linalg.norm(axis))
            )
        self.joints = tuple(infos)

    def _limits(self) -> Limits:
        cfg = self.config
        lo = np.array([j.position_lower_limits()[0] for j in self._joints], float)
        hi = np.array([j.position_upper_limits()[0] for j in self._joints], float)
        v = np.array([j.velocity_upper_limits()[0] for j in self._joints], float)
        effort = np.full(self.n, np.inf)
        for a in self.plant.GetJointActuatorIndices():
            actuator = self.plant.get_joint_actuator(a)
            if actuator.joint().name() in self.joint_names:
                effort[self.joint_names.index(actuator.joint().name())] = actuator.effort_limit()
        urdf_effort = _urdf_effort_limits(self.model_path)
        for k, name in enumerate(self.joint_names):
            if not np.isfinite(effort[k]) and name in urdf_effort:
                effort[k] = urdf_effort[name]
        vd = np.full(self.n, float(cfg.default_acceleration_limit))
        for k, name in enumerate(self.joint_names):
            lo[k], hi[k], v[k] = merge_limits(name, (lo[k], hi[k]), v[k], cfg, self.model_path.name)
            vd[k] = cfg.acceleration_limits.get(name, vd[k])
            effort[k] = min(effort[k], cfg.effort_limits.get(name, np.inf))
        lo = lo + cfg.position_margin
        hi = hi - cfg.position_margin
        for k, name in enumerate(self.joint_names):
            if not np.isfinite(lo[k]) or not np.isfinite(hi[k]):
                raise ConfigError(
                    f"joint '{name}' has no finite position limits: set robot.position_limits['{name}']"
                )
            if not np.isfinite(v[k]):
                raise ConfigError(
                    f"joint '{name}' has no velocity limit: set robot.velocity_limits['{name}']"
                )
            if lo[k] >= hi[k]:
                fix = (
                    "reduce robot.position_margin"
                    if cfg.position_margin > 0
                    else f"give a real range in robot.position_limits['{name}']"
                )
                raise InfeasibleError(
                    f"joint '{name}': position range [{lo[k]:.4g}, {hi[k]:.4g}] is empty after a "
                    f"margin of {cfg.position_margin} rad; {fix}"
                )
        return Limits(lo, hi, v * cfg.velocity_scale, vd * cfg.acceleration_scale, effort * cfg.effort_scale)

    # ---- parameters ---------------------------------------------------------------------
    @cached_property
    def phi_model(self) -> np.ndarray:
        """A-priori inertial parameters, shape (10·nb,), order of :data:`PARAMETER_NAMES`."""
        return np.concatenate([spatial_inertia_to_phi(b.default_spatial_inertia()) for b in self._bodies])

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names ``<param>.<body>`` of the 10·nb standard parameters."""
        return tuple(f"{p}.{b}" for b in self.body_names for p in PARAMETER_NAMES)

    @property
    def num_bodies(self) -> int:
        return len(self.body_names)

    # ---- evaluation helpers ---------------------------------------------------------------
    def body_poses(self, q: np.ndarray) -> np.ndarray:
        """World poses of every plant body at each configuration.

        Args:
            q: positions, shape (T, n).

        Returns:
            X_WB, shape (T, num_bodies_all, 4, 4).
        """
        plant, ctx = self.plant, self.plant_context
        port = plant.get_body_poses_output_port()
        q = np.atleast_2d(q)
        out = np.empty((q.shape[0], plant.num_bodies(), 4, 4))
        for t in range(q.shape[0]):
            plant.SetPositions(ctx, q[t])
            poses = port.Eval(ctx)
            for b, X in enumerate(poses):
                out[t, b] = X.GetAsMatrix4()
        return out

    @cached_property
    def joint_damping(self) -> np.ndarray:
        """Viscous damping of each excited joint in the model, shape (n,) [N·m·s/rad]."""
        return np.array([j.default_damping_vector()[0] for j in self._joints], float)

    def inverse_dynamics(
        self, q: np.ndarray, v: np.ndarray, vd: np.ndarray, include_damping: bool = False
    ) -> np.ndarray:
        """Drake's inverse dynamics with gravity, shape (T, n) [N·m or N].

        Args:
            q, v, vd: each (T, n).
            include_damping: keep the model's joint damping (a friction term, not part of the
                rigid-body regressor); by default it is removed.
        """
        from pydrake.multibody.tree import MultibodyForces

        plant, ctx = self.plant, self.plant_context
        q, v, vd = np.atleast_2d(q), np.atleast_2d(v), np.atleast_2d(vd)
        tau = np.empty_like(q)
        forces = MultibodyForces(plant)
        for t in range(q.shape[0]):
            plant.SetPositions(ctx, q[t])
            plant.SetVelocities(ctx, v[t])
            forces.SetZero()
            plant.CalcForceElementsContribution(ctx, forces)
            tau[t] = plant.CalcInverseDynamics(ctx, vd[t], forces)
        if not include_damping:
            tau -= v * self.joint_damping  # Drake's damping force is -d·v
        return tau

    def nominal_posture(self) -> np.ndarray:
        """Posture the optimizer starts from, shape (n,) [rad or m]: ``nominal_positions``
        of the config where given, else mid-range."""
        q = 0.5 * (self.limits.q_lower + self.limits.q_upper)
        for k, name in enumerate(self.joint_names):
            if name in self.config.nominal_positions:
                q[k] = self.config.nominal_positions[name]
        return q

    def __repr__(self) -> str:
        return f"Robot('{self.name}', {self.n} joints, {self.num_bodies} moving bodies)"


def merge_limits(name: str, model_range, model_velocity: float, cfg, model_file: str = "the model"):
    """A joint's position range and velocity limit from the model file and the config.

    A zero-width model range (lower == upper, a placeholder as in example-robot-data's
    double pendulum) or a zero velocity limit is replaced by the config's value; a real
    model limit can only be tightened, and a wider config value is refused.

    Returns:
        (lower, upper, velocity) [rad or m, rad/s or m/s].

    Raises:
        ConfigError: the config widens a real model limit (naming both values).
    """
    lo, hi = float(model_range[0]), float(model_range[1])
    v = float(model_velocity)
    if name in cfg.position_limits:
        c_lo, c_hi = (float(x) for x in cfg.position_limits[name])
        if hi - lo > 0 and (c_lo < lo - 1e-12 or c_hi > hi + 1e-12):
            raise ConfigError(
                f"robot.position_limits['{name}'] = [{c_lo:g}, {c_hi:g}] is wider than the limits "
                f"[{lo:g}, {hi:g}] in {model_file}; a config can only tighten a real model limit "
                "(it replaces zero-width placeholders)"
            )
        lo, hi = c_lo, c_hi
    if name in cfg.velocity_limits:
        c_v = float(cfg.velocity_limits[name])
        if v > 0 and c_v > v + 1e-12:
            raise ConfigError(
                f"robot.velocity_limits['{name}'] = {c_v:g} is above the limit {v:g} in {model_file}; "
                "a config can only tighten a real model limit (it replaces zero placeholders)"
            )
        v = c_v
    elif v == 0:
        v = np.inf  # a placeholder: refused below as "no velocity limit" unless the config gives one
    return lo, hi, v


def _urdf_effort_limits(path: Path) -> dict[str, float]:
    """{joint: effort} from a URDF's <limit effort=...> (Drake keeps them only with actuators)."""
    if path.suffix.lower() != ".urdf":
        return {}
    import xml.etree.ElementTree as ET

    out = {}
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError:
        return {}
    for joint in root.iter("joint"):
        limit = joint.find("limit")
        if limit is not None and limit.get("effort") and float(limit.get("effort")) > 0:
            out[joint.get("name")] = float(limit.get("effort"))
    return out


def _inboard_joint(plant, body):
    for j in plant.GetJointIndices():
        joint = plant.get_joint(j)
        if joint.child_body().index() == body.index():
            return joint
    return None


def _quaternion(wxyz):
    from pydrake.common.eigen_geometry import Quaternion

    q = np.asarray(wxyz, float)
    return Quaternion(q / np.linalg.norm(q))


def _resolve_model_path(model: str) -> Path:
    if not model:
        raise ConfigError("robot.model is empty: give a URDF/SDF path or a built-in robot name")
    prefix = "package://example-robot-data/"
    if model.startswith(prefix):
        path = example_robot_data_dir() / model[len(prefix):]
    else:
        path = Path(model)
    if not path.is_file():
        raise ConfigError(f"robot model file '{path}' does not exist")
    return path


def load_robot(
    robot: str | Config | RobotConfig, config_file: str | Path | None = None, **options
) -> Robot:
    """Loads a robot by built-in name, model path or config.

    Args:
        robot: ``"panda"``, ``"ur5"``, ``"g1"``, a URDF/SDF path, or a config object.
        config_file: optional YAML file overriding the defaults (see :class:`Config`).
        **options: passed to :class:`Robot`: ``time_step`` [s] (0: continuous plant),
            ``obj_visuals`` (convert STL visuals to OBJ for Meshcat), ``before_finalize``
            (callback ``f(plant, scene_graph)`` to add bodies, e.g. a payload),
            ``builder_hook`` (callback ``f(builder, plant, scene_graph)`` after Finalize and
            before the diagram is built, e.g. to add visualizers).

    Returns:
        The :class:`Robot`.

    Raises:
        UnknownNameError: unknown robot or joint name (the valid names are listed).
        NotWithinLimitsError: a locked position outside its joint's limits.
        ConfigError: missing file, bad value, or a model Drake cannot parse.
    """
    if isinstance(robot, Config):
        validate_config(robot)
        return Robot(Path(robot.robot.model).stem, robot.robot, **options)
    if isinstance(robot, RobotConfig):
        validate_config(Config(robot=robot))
        return Robot(Path(robot.model).stem, robot, **options)
    config = resolve_robot_config(robot, config_file)
    name = robot if robot in builtin_robots() else Path(robot).stem
    return Robot(name, config.robot, **options)
