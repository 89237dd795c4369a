"""The excited joints of a robot and the locked rest: the config's joint names checked, every
other 1-dof joint welded at its locked position, and what the regressor needs of each joint."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from pe_drake.config import RobotConfig
from pe_drake.exceptions import ConfigError, NotWithinLimitsError, UnknownNameError


@dataclasses.dataclass(frozen=True)
class JointInfo:
    """One excited joint."""

    name: str
    kind: str  # "revolute" or "prismatic"
    child_body: int  # index into ``Robot.body_names_all`` of the child body C
    X_CM: np.ndarray  # pose of the joint's child frame M in C, (4, 4)
    axis_M: np.ndarray  # unit joint axis in M, (3,)


def joint_info(joint) -> JointInfo:
    """The :class:`JointInfo` of an excited Drake joint (ConfigError unless revolute/prismatic)."""
    X_CM = joint.frame_on_child().GetFixedPoseInBodyFrame().GetAsMatrix4()
    if joint.type_name() == "revolute":
        kind, axis = "revolute", np.asarray(joint.revolute_axis(), float)
    elif joint.type_name() == "prismatic":
        kind, axis = "prismatic", np.asarray(joint.translation_axis(), float)
    else:
        raise ConfigError(f"joint '{joint.name()}' is a {joint.type_name()} joint; only revolute "
                          "and prismatic joints can be excited")
    return JointInfo(joint.name(), kind, int(joint.child_body().index()), X_CM, axis / np.linalg.norm(axis))


def inboard_joint(plant, body):
    for j in plant.GetJointIndices():
        joint = plant.get_joint(j)
        if joint.child_body().index() == body.index():
            return joint
    return None


#: The ``robot`` tables keyed by excited joint name.
PER_JOINT_TABLES = ("position_limits", "velocity_limits", "acceleration_limits", "effort_limits", "nominal_positions")


def excited_joint_names(cfg: RobotConfig, movable_names: list[str], model_path: Path) -> list[str]:
    """The excited joints (default: every 1-dof joint), every joint name of the config checked.

    Raises:
        UnknownNameError: a joint the model (or the excited set) does not have.
        ConfigError: a joint listed twice, or both excited and locked.
    """
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
    for table in PER_JOINT_TABLES:
        for j in getattr(cfg, table):
            if j not in excited:
                raise UnknownNameError("joint", j, excited, where=f"robot.{table} (excited joints)")
    return excited


def weld_locked_joints(plant, movable: list, excited: list[str], positions: dict[str, float]) -> dict[str, float]:
    """Welds every non-excited joint at its locked position (default: 0 clipped to its limits);
    returns {joint: locked position} [rad or m].

    Raises:
        NotWithinLimitsError: a locked position outside the joint's limits.
        ConfigError: a joint type that cannot be locked.
    """
    from pydrake.common.eigen_geometry import AngleAxis  # lazy: pydrake is heavy
    from pydrake.math import RigidTransform
    from pydrake.multibody.tree import PrismaticJoint, RevoluteJoint

    locked: dict[str, float] = {}
    for joint in movable:
        if joint.name() in excited:
            continue
        lo, hi = joint.position_lower_limits()[0], joint.position_upper_limits()[0]
        value = positions.get(joint.name(), float(np.clip(0.0, lo, hi)))
        if not lo - 1e-9 <= value <= hi + 1e-9:
            raise NotWithinLimitsError(joint.name(), value, lo, hi, what="locked position")
        locked[joint.name()] = float(value)
        if isinstance(joint, RevoluteJoint):
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
    return locked
