"""Loading a robot into Drake: excited joints, locked posture, limits, kinematic structure.

:func:`load_robot` turns a built-in name or a URDF/SDF path into a :class:`Robot`: a
MultibodyPlant whose positions are exactly the excited joints (every other joint welded), with
the root link welded to the world.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from functools import cached_property
from pathlib import Path

import numpy as np

from pe_drake.config import Config, RobotConfig, validate_config
from pe_drake.exceptions import ConfigError, InfeasibleError, UnknownNameError
from pe_drake.multibody.capsules import register_capsules
from pe_drake.multibody.excited_joints import (
    excited_joint_names,
    inboard_joint,
    joint_info,
    weld_locked_joints,
)
from pe_drake.multibody.inertia import NO_INERTIALS_NOTE, PARAMETER_NAMES, spatial_inertia_to_phi
from pe_drake.multibody.joint_limits import joint_unit, merge_limits, placeholder_velocity_notes, position_margins
from pe_drake.multibody.model_files import (
    check_world_joints,
    drake_model_text,
    finalize_plant,
    loadable_model_path,
    model_stem,
    parse_models,
)
from pe_drake.multibody.registry import resolve_model_path, resolve_robot_config, robot_display_name
from pe_drake.multibody.urdf_checks import urdf_joint_dynamics, urdf_joint_efforts


@dataclasses.dataclass(frozen=True)
class Limits:
    """Joint limits used by the optimizer, after config overrides and margins; each (n,)."""

    q_lower: np.ndarray  # [rad or m]
    q_upper: np.ndarray  # [rad or m]
    v_max: np.ndarray  # [rad/s or m/s]
    vd_max: np.ndarray  # [rad/s² or m/s²]
    effort_max: np.ndarray  # [N·m or N]


class Robot:
    """A Drake model with the excited joints free and every other joint welded.

    Attributes:
        name: built-in name or model file stem.
        plant: the finalized MultibodyPlant (continuous, q = excited joints).
        scene_graph: its SceneGraph (collision geometry is our capsules, if any).
        joint_names: excited joints, in the plant's position order.
        locked_positions: {joint: value} of every welded (non-excited) joint.
        body_names: bodies moved by at least one excited joint (the regressor's bodies).
        shared_kinematics: the kinematics model the sampled constraints share (None until
            :func:`~pe_drake.multibody.regressor.shared_model` makes it).
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
        self.shared_kinematics = None
        self.time_step = float(time_step)
        self._obj_visuals = obj_visuals
        self._before_finalize = before_finalize
        self._builder_hook = builder_hook
        self._build()

    # ---- construction -------------------------------------------------------------------
    def _build(self) -> None:
        """Parses the model, welds the locked joints and the root, and builds the plant."""
        from pydrake.multibody.plant import AddMultibodyPlantSceneGraph  # lazy: pydrake is heavy
        from pydrake.systems.framework import DiagramBuilder

        cfg = self.config
        model_path = loadable_model_path(resolve_model_path(cfg.model), cfg.packages, trust_xacro=cfg.trust_xacro)
        text, notes = drake_model_text(model_path, self._obj_visuals, cfg.packages)
        self.notes = list(cfg.notes) + notes
        self.limit_notes: list[str] = []
        builder = DiagramBuilder()
        plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=self.time_step)
        models = parse_models(plant, text, model_path, cfg.packages)
        self.model_path = model_path

        movable = [plant.get_joint(j) for m in models for j in plant.GetJointIndices(m)]
        movable = [j for j in movable if j.num_positions() == 1]
        check_world_joints(plant, models, model_path)
        excited = excited_joint_names(cfg, [j.name() for j in movable], model_path)
        self.locked_positions = weld_locked_joints(plant, movable, excited, cfg.locked_positions)
        self._weld_root(plant, models)
        self._scene_graph_builder_hook(plant, scene_graph)
        if self._before_finalize is not None:
            self._before_finalize(plant, scene_graph)
        finalize_plant(plant, model_path)
        self._build_diagram(builder, plant, scene_graph, excited)

        joints = [plant.GetJointByName(j) for j in excited]
        joints.sort(key=lambda j: j.position_start())
        self.joint_names = tuple(j.name() for j in joints)
        self.n = len(joints)
        self._joints = joints
        self._structure()
        self.limits = self._limits()
        if not np.any(self.phi_model[0::10] > 0):
            self.notes.append(NO_INERTIALS_NOTE)

    def _weld_root(self, plant, models) -> None:
        """Welds the root link to the world at the config's base pose.

        A weld of the root to the world in the model is replaced, so the base pose always is the
        root link's pose in the world.
        """
        from pydrake.common.eigen_geometry import Quaternion  # lazy: pydrake is heavy
        from pydrake.math import RigidTransform, RollPitchYaw

        cfg = self.config
        root = self._root_body(plant, models)
        wxyz = np.asarray(cfg.base_quaternion_wxyz, float)
        p_WR = np.asarray(cfg.base_position, float)
        pose = RigidTransform(Quaternion(wxyz / np.linalg.norm(wxyz)), p_WR)
        world = plant.world_body().index()
        for index in list(plant.GetJointIndices()):
            joint = plant.get_joint(index)
            if joint.parent_body().index() == world and joint.child_body().index() == root.index():
                X_WR = joint.frame_on_parent().GetFixedPoseInBodyFrame().multiply(
                    joint.frame_on_child().GetFixedPoseInBodyFrame().inverse())
                if not X_WR.IsNearlyEqualTo(pose, 1e-9):
                    xyz = " ".join(f"{v:.4g}" for v in X_WR.translation())
                    rpy = " ".join(f"{v:.4g}" for v in RollPitchYaw(X_WR.rotation()).vector())
                    self.notes.append(
                        f"the origin of the model's world joint '{joint.name()}' (xyz {xyz}, rpy {rpy}) is replaced by "
                        "robot.base_position / base_quaternion_wxyz, the pose of the root link in the world"
                    )
                plant.RemoveJoint(joint)  # a weld (check_world_joints refused movable ones)
        plant.WeldFrames(plant.world_frame(), root.body_frame(), pose)
        self.root_link = root.name()
        self.base_pose = pose

    def _build_diagram(self, builder, plant, scene_graph, excited: list[str]) -> None:
        """Checks that q is exactly the excited joints, then builds the diagram and contexts."""
        if plant.num_positions() != len(excited) or plant.num_velocities() != len(excited):
            raise ConfigError(
                f"after locking, the plant has {plant.num_positions()} positions but "
                f"{len(excited)} excited joints: is the root link '{self.root_link}' free?")
        if self._builder_hook is not None:  # e.g. Meshcat visualizers (pe_drake.viewer)
            self._builder_hook(builder, plant, scene_graph)
        self.diagram = builder.Build()
        self.plant = plant
        self.scene_graph = scene_graph
        self.context = self.diagram.CreateDefaultContext()
        self.plant_context = plant.GetMyMutableContextFromRoot(self.context)

    def _scene_graph_builder_hook(self, plant, scene_graph) -> None:
        """Registers extra geometry before Finalize (capsules; see constraints.collision)."""
        capsules = self.config.capsules
        self.capsules = register_capsules(plant, scene_graph, capsules) if capsules else ()

    def _root_body(self, plant, models):
        bodies = [plant.get_body(b) for m in models for b in plant.GetBodyIndices(m)]
        names = [b.name() for b in bodies]
        if self.config.root_link:
            if self.config.root_link not in names:
                raise UnknownNameError("link", self.config.root_link, names, where="robot.root_link")
            return plant.GetBodyByName(self.config.root_link)
        world = plant.world_body().index()
        joints = [plant.get_joint(j) for j in plant.GetJointIndices()]
        children = {j.child_body().index() for j in joints if j.parent_body().index() != world}
        return [b for b in bodies if b.index() not in children][0]

    def _structure(self) -> None:
        """Tree structure of the excited joints and of the bodies they move."""
        plant = self.plant
        index_of_joint = {j.index(): k for k, j in enumerate(self._joints)}

        # For each body, the nearest excited joint upstream (-1: welded to the world).
        def upstream_joint(body) -> int:
            while body.index() != plant.world_body().index():
                joint = inboard_joint(plant, body)
                if joint is None:
                    return -1
                if joint.index() in index_of_joint:
                    return index_of_joint[joint.index()]
                body = joint.parent_body()
            return -1

        from pydrake.multibody.tree import BodyIndex  # lazy: pydrake is heavy

        all_bodies = [plant.get_body(BodyIndex(b)) for b in range(plant.num_bodies())]
        self.body_names_all = tuple(b.name() for b in all_bodies)
        moving = [b for b in all_bodies if b.index() != 0 and upstream_joint(b) >= 0]
        self._bodies = moving
        self.body_names = tuple(b.name() for b in moving)
        self.body_indices = np.array([int(b.index()) for b in moving])
        self.joint_of_body = np.array([upstream_joint(b) for b in moving])

        n = self.n
        joint_parent = [upstream_joint(joint.parent_body()) for joint in self._joints]
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

        self.joints = tuple(joint_info(joint) for joint in self._joints)

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
        urdf_effort = urdf_joint_efforts(self.model_path)
        vd = np.full(self.n, float(cfg.default_acceleration_limit))
        for k, name in enumerate(self.joint_names):
            if not np.isfinite(effort[k]):
                effort[k] = urdf_effort.get(name, effort[k])
            lo[k], hi[k], v[k] = merge_limits(name, (lo[k], hi[k]), v[k], cfg, self.model_path.name)
            vd[k] = cfg.acceleration_limits.get(name, vd[k])
            effort[k] = min(effort[k], cfg.effort_limits.get(name, np.inf))
        margin, notes = position_margins(cfg, self.joint_names, [j.kind for j in self.joints], lo, hi)
        notes += placeholder_velocity_notes(cfg, self.joint_names, [j.kind for j in self.joints], v)
        self.limit_notes = notes  # the margins assumed: optimize and simulate print them
        lo, hi = lo + margin, hi - margin
        for k, name in enumerate(self.joint_names):
            if not np.isfinite(lo[k]) or not np.isfinite(hi[k]):
                raise ConfigError(
                    f"joint '{name}' has no finite position limits: set robot.position_limits['{name}'] "
                    f"[rad or m], or leave it out of robot.joints (a wheel, a continuous joint you do not "
                    f"want to excite; robot.locked_positions holds it)")
            if not np.isfinite(v[k]):
                raise ConfigError(
                    f"joint '{name}' has no velocity limit: set robot.velocity_limits['{name}']")
            if lo[k] >= hi[k]:
                fix = "reduce robot.position_margin" if margin[k] > 0 else (
                    f"give a real range in robot.position_limits['{name}']")
                raise InfeasibleError(
                    f"joint '{name}': position range [{lo[k]:.4g}, {hi[k]:.4g}] is empty after a "
                    f"margin of {margin[k]:g} {joint_unit(self.joints[k].kind)}; {fix}")
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
        """Number nb of bodies moved by the excited joints."""
        return len(self.body_names)

    @property
    def bodies(self) -> tuple:
        """The Drake bodies moved by the excited joints, in :attr:`body_names` order (read-only)."""
        return tuple(self._bodies)

    # ---- evaluation helpers ---------------------------------------------------------------
    def body_poses(self, q: np.ndarray) -> np.ndarray:
        """World poses X_WB of every plant body at positions q (T, n), shape (T, nb_all, 4, 4)."""
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

    @cached_property
    def joint_friction(self) -> np.ndarray:
        """Coulomb friction of each excited joint in the model file, shape (n,) [N·m or N].

        A URDF's ``<dynamics friction>``, which Drake's parser ignores; 0 for other formats.
        """
        table = urdf_joint_dynamics(self.model_path, "friction")
        return np.array([max(table.get(name, 0.0), 0.0) for name in self.joint_names], float)

    def inverse_dynamics(self, q: np.ndarray, v: np.ndarray, vd: np.ndarray,
                         include_damping: bool = False) -> np.ndarray:
        """Drake's inverse dynamics with gravity for (T, n) arrays, shape (T, n) [N·m or N].

        Args:
            include_damping: keep the model's joint damping (a friction term, not part of the
                rigid-body regressor); by default it is removed.
        """
        from pydrake.multibody.tree import MultibodyForces  # lazy: pydrake is heavy

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
        """Posture the optimizer starts from, shape (n,): ``nominal_positions``, else mid-range."""
        q = 0.5 * (self.limits.q_lower + self.limits.q_upper)
        for k, name in enumerate(self.joint_names):
            if name in self.config.nominal_positions:
                q[k] = self.config.nominal_positions[name]
        return q

    def __repr__(self) -> str:
        return f"Robot('{self.name}', {self.n} joints, {self.num_bodies} moving bodies)"


def load_robot(robot: str | Config | RobotConfig, config_file: str | Path | None = None,
               **options) -> Robot:
    """Loads a robot by built-in name, model path or config.

    Args:
        robot: ``"panda"``, ``"ur5"``, ``"g1"``, a URDF/SDF path, or a config object.
        config_file: optional YAML file overriding the defaults (see :class:`Config`).
        **options: passed to :class:`Robot`: ``time_step`` [s] (0: continuous plant),
            ``obj_visuals`` (convert STL visuals to OBJ for Meshcat), ``before_finalize``
            (callback ``f(plant, scene_graph)`` to add bodies, e.g. a payload),
            ``builder_hook`` (callback ``f(builder, plant, scene_graph)`` before the diagram is
            built, e.g. to add visualizers).

    Raises:
        UnknownNameError: unknown robot or joint name (the valid names are listed).
        NotWithinLimitsError: a locked position outside its joint's limits.
        ConfigError: missing file, bad value, or a model Drake cannot parse.
    """
    if isinstance(robot, Config):
        validate_config(robot)
        return Robot(model_stem(robot.robot.model), robot.robot, **options)
    if isinstance(robot, RobotConfig):
        validate_config(Config(robot=robot))
        return Robot(model_stem(robot.model), robot, **options)
    config = resolve_robot_config(robot, config_file)
    return Robot(robot_display_name(robot), config.robot, **options)
