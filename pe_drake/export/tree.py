"""The robot's bodies as the exporters walk them: Drake's tree at q = 0 with the model's inertials
(URDF, xacro and SDF robots alike; locked joints are welds at their locked position)."""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from pe_drake.multibody.inertia import spatial_inertia_to_phi
from pe_drake.multibody.robot_model import RobotModel

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


class TreeBody(NamedTuple):
    """One body of the exported tree; poses at q = 0."""

    name: str
    parent: str  # "world" for the root
    X_PC: np.ndarray  # pose in the parent, (4, 4)
    X_WC: np.ndarray  # pose in the world, (4, 4)
    phi: np.ndarray  # 10 parameters about its origin (the model's if it moves, else the file's)
    joint: int  # index of its excited joint in ``robot.joint_names``, or -1 (a weld)
    weld_name: str  # the Drake joint that joins it to its parent


def robot_tree(robot: Robot, model: RobotModel) -> list[TreeBody]:
    """The bodies of ``robot``'s plant, parents before children."""
    plant = robot.plant
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, np.zeros(plant.num_positions()))
    children: dict[int, list] = {}
    for index in plant.GetJointIndices():
        joint = plant.get_joint(index)
        children.setdefault(int(joint.parent_body().index()), []).append(joint)
    moving = {name: model.phi[10 * b : 10 * b + 10] for b, name in enumerate(robot.body_names)}
    out: list[TreeBody] = []
    stack = [plant.world_body()]
    while stack:
        parent = stack.pop(0)
        for joint in children.get(int(parent.index()), []):
            child = joint.child_body()
            X_PC = plant.CalcRelativeTransform(context, parent.body_frame(), child.body_frame()).GetAsMatrix4()
            X_WC = plant.CalcRelativeTransform(context, plant.world_frame(), child.body_frame()).GetAsMatrix4()
            phi = moving.get(child.name())
            if phi is None:
                phi = spatial_inertia_to_phi(child.default_spatial_inertia())
            k = robot.joint_names.index(joint.name()) if joint.name() in robot.joint_names else -1
            out.append(TreeBody(child.name(), parent.name(), X_PC, X_WC, phi, k, joint.name()))
            stack.append(child)
    return out


def number_text(x: float) -> str:
    """A number as the exported files write it: every digit (repr), 0 as '0'."""
    return repr(float(x)) if x != 0 else "0"


def vector_text(x) -> str:
    """Numbers separated by spaces, each as :func:`number_text`."""
    return " ".join(number_text(v) for v in np.ravel(x))


def quaternion_wxyz(X: np.ndarray) -> np.ndarray:
    """The rotation of a pose (4, 4) as a unit quaternion [w, x, y, z]."""
    from pydrake.common.eigen_geometry import Quaternion  # lazy: pydrake is heavy
    from pydrake.math import RotationMatrix

    q: Quaternion = RotationMatrix(np.asarray(X, float)[:3, :3]).ToQuaternion()
    return np.asarray(q.wxyz(), float)
