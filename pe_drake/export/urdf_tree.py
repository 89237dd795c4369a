"""A URDF written from pe_drake's plant, for a robot that has none of its own (an SDF robot).

URDF puts each joint's frame at its child link's frame, while Drake lets a joint's child frame M
sit anywhere on its child body C. So each URDF link is the joint frame M of its body (C for a
weld), its inertial re-expressed in M (exact), each ``<origin>`` its link's pose in the parent's
link at q = 0. No geometry.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.export.tree import number_text, robot_tree, vector_text
from pe_drake.multibody.inertia import phi_to_spatial_inertia, spatial_inertia_to_phi
from pe_drake.multibody.robot_model import PAYLOAD_BODY_NAME, RobotModel
from pe_drake.multibody.urdf import inertial_element, joint_dynamics

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


def _origin(parent: ET.Element, X: np.ndarray) -> None:
    from pydrake.math import RollPitchYaw, RotationMatrix  # lazy: pydrake is heavy

    rpy = RollPitchYaw(RotationMatrix(np.asarray(X, float)[:3, :3])).vector()
    ET.SubElement(parent, "origin", {"xyz": vector_text(np.asarray(X)[:3, 3]), "rpy": vector_text(rpy)})


def _inverse(X: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = X[:3, :3].T
    out[:3, 3] = -X[:3, :3].T @ X[:3, 3]
    return out


def _in_frame(phi_b: np.ndarray, X_CL: np.ndarray) -> np.ndarray:
    """A body's 10 parameters about C in C, re-expressed about L's origin in L."""
    from pydrake.math import RotationMatrix  # lazy: pydrake is heavy

    M = phi_to_spatial_inertia(phi_b).Shift(X_CL[:3, 3])  # about Lo, expressed in C
    return spatial_inertia_to_phi(M.ReExpress(RotationMatrix(X_CL[:3, :3]).inverse()))


def _link(robot_el: ET.Element, name: str, phi_b: np.ndarray) -> None:
    link = ET.SubElement(robot_el, "link", {"name": name})
    if phi_b[0] > 0:
        link.append(inertial_element(phi_b, "    "))


def _joint(robot_el: ET.Element, robot: Robot, name: str, kind: str, parent: str, child: str, X: np.ndarray,
           k: int = -1) -> None:
    joint = ET.SubElement(robot_el, "joint", {"name": name, "type": kind})
    ET.SubElement(joint, "parent", {"link": parent})
    ET.SubElement(joint, "child", {"link": child})
    _origin(joint, X)
    if k < 0:
        return
    ET.SubElement(joint, "axis", {"xyz": vector_text(robot.joints[k].axis_M)})
    drake_joint = robot.plant.GetJointByName(robot.joint_names[k])
    limits = {"lower": drake_joint.position_lower_limits()[0], "upper": drake_joint.position_upper_limits()[0],
              "effort": robot.limits.effort_max[k], "velocity": drake_joint.velocity_upper_limits()[0]}
    ET.SubElement(joint, "limit", {key: number_text(v) for key, v in limits.items() if np.isfinite(v)})


def urdf_from_tree(robot: Robot, model: RobotModel) -> str:
    """The URDF of the robot with ``model``, the payload a link ``PAYLOAD_BODY_NAME``."""
    root = ET.Element("robot", {"name": robot.name})
    ET.SubElement(root, "link", {"name": "world"})
    X_CL = {"world": np.eye(4)}  # each body's link frame L in its body frame C
    for body in robot_tree(robot, model):
        X_CL[body.name] = np.asarray(robot.joints[body.joint].X_CM, float) if body.joint >= 0 else np.eye(4)
        _link(root, body.name, _in_frame(body.phi, X_CL[body.name]))
        X_parent_link = _inverse(X_CL[body.parent]) @ body.X_PC @ X_CL[body.name]
        if body.joint >= 0:
            _joint(root, robot, robot.joint_names[body.joint], robot.joints[body.joint].kind, body.parent, body.name,
                   X_parent_link, body.joint)
        else:
            _joint(root, robot, body.weld_name, "fixed", body.parent, body.name, X_parent_link)
        if model.payload is not None and body.name == model.payload_link:
            _link(root, PAYLOAD_BODY_NAME, model.payload.phi)
            _joint(root, robot, f"{PAYLOAD_BODY_NAME}_weld", "fixed", body.name, PAYLOAD_BODY_NAME,
                   _inverse(X_CL[body.name]))
    ET.indent(root, "  ")
    text = '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
    joints = robot.joint_names
    return joint_dynamics(text, dict(zip(joints, map(float, model.viscous))),
                          {j: float(a) for j, a in zip(joints, model.armature) if a > 0},
                          dict(zip(joints, map(float, model.sliding_friction))))
