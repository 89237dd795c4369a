"""The identified robot for Drake and ROS: URDF and SDFormat with inertials, joint friction and
rotor inertia, checked by loading them back in Drake. Drake ignores the Coulomb ``friction``;
offsets, a delay and pre-sliding have no place in either format (the file's comment says so).
"""

from __future__ import annotations

import dataclasses
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.exceptions import ConfigError
from pe_drake.export.mjcf import unheld_terms
from pe_drake.export.model_source import random_states
from pe_drake.export.tree import number_text, robot_tree
from pe_drake.export.urdf_tree import urdf_from_tree
from pe_drake.multibody.inertia import central_inertia
from pe_drake.multibody.robot import load_robot
from pe_drake.multibody.robot_model import PAYLOAD_BODY_NAME, RobotModel

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

DRAKE_NAMESPACE = "http://drake.mit.edu"


def urdf_export_text(robot: Robot, model: RobotModel, source: str = "") -> str:
    """The robot's URDF with the model's inertials, joint dynamics and payload link, headed by a
    comment naming ``source`` ("": the robot's own model) and what the URDF cannot hold."""
    if Path(robot.model_path).suffix.lower() == ".urdf":
        text = model.urdf_text(robot)
    else:  # an SDF robot: no URDF of its own to edit
        text = urdf_from_tree(robot, model)
    return text.replace("<robot", _comment(robot, model, source, "URDF", "urdf") + "<robot", 1)


def _comment(robot: Robot, model: RobotModel, source: str, kind: str, fmt: str) -> str:
    """The file's opening comment: what it is, from which model, what it cannot hold."""
    notes = [f"{kind} of robot '{robot.name}' written by pe-drake export; model: {source or 'CAD'}"]
    notes += [f"note: {n}" for n in model.notes]
    notes += [f"not held: {n}" for n in unheld_terms(robot, model, fmt)]
    return "<!--\n" + "\n".join("  " + n.replace("--", "- -") for n in notes) + "\n-->\n"


def _pose_text(X: np.ndarray) -> str:
    from pydrake.math import RollPitchYaw, RotationMatrix  # lazy: pydrake is heavy

    rpy = RollPitchYaw(RotationMatrix(np.asarray(X, float)[:3, :3])).vector()
    return " ".join(number_text(x) for x in [*np.asarray(X)[:3, 3], *rpy])


def _sdf_inertial(link: ET.Element, phi_b: np.ndarray) -> None:
    m, p, I = central_inertia(phi_b)
    inertial = ET.SubElement(link, "inertial")
    ET.SubElement(inertial, "pose").text = " ".join(number_text(x) for x in [*p, 0, 0, 0])
    ET.SubElement(inertial, "mass").text = number_text(m)
    inertia = ET.SubElement(inertial, "inertia")
    for tag, (r, c) in (("ixx", (0, 0)), ("ixy", (0, 1)), ("ixz", (0, 2)), ("iyy", (1, 1)), ("iyz", (1, 2)),
                        ("izz", (2, 2))):
        ET.SubElement(inertia, tag).text = number_text(I[r, c])


def _sdf_joint(sdf_model: ET.Element, robot: Robot, model: RobotModel, parent: str, child: str, k: int) -> None:
    info, joint = robot.joints[k], robot.plant.GetJointByName(robot.joint_names[k])
    el = ET.SubElement(sdf_model, "joint", {"name": info.name, "type": info.kind})
    ET.SubElement(el, "parent").text = parent
    ET.SubElement(el, "child").text = child
    ET.SubElement(el, "pose").text = _pose_text(info.X_CM)  # relative to the child link
    axis = ET.SubElement(el, "axis")
    ET.SubElement(axis, "xyz").text = " ".join(number_text(x) for x in info.axis_M)
    limit = ET.SubElement(axis, "limit")
    effort = robot.limits.effort_max[k]
    for tag, value in (("lower", joint.position_lower_limits()[0]), ("upper", joint.position_upper_limits()[0]),
                       ("effort", effort if np.isfinite(effort) else -1.0),  # -1: no limit
                       ("velocity", joint.velocity_upper_limits()[0])):
        if np.isfinite(value):
            ET.SubElement(limit, tag).text = number_text(value)
    dynamics = ET.SubElement(axis, "dynamics")
    ET.SubElement(dynamics, "damping").text = number_text(model.viscous[k])
    ET.SubElement(dynamics, "friction").text = number_text(model.sliding_friction[k])
    ET.SubElement(el, f"{{{DRAKE_NAMESPACE}}}rotor_inertia").text = number_text(model.armature[k])
    ET.SubElement(el, f"{{{DRAKE_NAMESPACE}}}gear_ratio").text = "1"


def _free_name(name: str, taken: set[str]) -> str:
    """``name``, or ``name_weld``, ``name_weld_2``, ... when taken; added to ``taken``."""
    free, k = name, 1
    while free in taken:
        free = f"{name}_weld" + (f"_{k}" if k > 1 else "")
        k += 1
    taken.add(free)
    return free


def sdf_text(robot: Robot, model: RobotModel, source: str = "") -> str:
    """The SDFormat model of the robot with ``model`` from its plant (links at q = 0, locked joints
    as welds, no geometry); ``source`` names the model file."""
    ET.register_namespace("drake", DRAKE_NAMESPACE)
    root = ET.Element("sdf", {"version": "1.9"})
    sdf_model = ET.SubElement(root, "model", {"name": robot.name})
    tree = robot_tree(robot, model)
    # SDFormat gives a model's links and joints one namespace; URDF does not (example-robot-data's
    # Z1 has a fixed joint and its child link both named gripperStator): a weld's name is free
    taken = {body.name for body in tree} | {PAYLOAD_BODY_NAME, f"{PAYLOAD_BODY_NAME}_weld"}
    taken |= {robot.joint_names[body.joint] for body in tree if body.joint >= 0}
    for body in tree:
        link = ET.SubElement(sdf_model, "link", {"name": body.name})
        ET.SubElement(link, "pose").text = _pose_text(body.X_WC)
        _sdf_inertial(link, body.phi)
        if body.joint >= 0:
            _sdf_joint(sdf_model, robot, model, body.parent, body.name, body.joint)
        else:
            weld = ET.SubElement(sdf_model, "joint", {"name": _free_name(body.weld_name, taken), "type": "fixed"})
            ET.SubElement(weld, "parent").text = body.parent
            ET.SubElement(weld, "child").text = body.name
        if model.payload is not None and body.name == model.payload_link:
            payload = ET.SubElement(sdf_model, "link", {"name": PAYLOAD_BODY_NAME})
            ET.SubElement(payload, "pose").text = _pose_text(body.X_WC)
            _sdf_inertial(payload, model.payload.phi)
            weld = ET.SubElement(sdf_model, "joint", {"name": f"{PAYLOAD_BODY_NAME}_weld", "type": "fixed"})
            ET.SubElement(weld, "parent").text = body.name
            ET.SubElement(weld, "child").text = PAYLOAD_BODY_NAME
    ET.indent(root, "  ")
    head = '<?xml version="1.0"?>\n' + _comment(robot, model, source, "SDFormat", "sdf")
    return head + ET.tostring(root, encoding="unicode") + "\n"


def reloaded_robot(robot: Robot, text: str, suffix: str):
    """``robot`` with its model replaced by the exported text (a temporary file), loaded by
    pe_drake (SDFormat: its locked joints are welds of the file already)."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"{robot.name}{suffix}"
        path.write_text(text)
        changes = {"model": str(path), "capsules": ""}
        if suffix == ".sdf":
            changes["locked_positions"] = {}
        loaded = load_robot(dataclasses.replace(robot.config, **changes))
        loaded.joint_friction  # noqa: B018 - read from the file (a cached property) before it is removed
        return loaded


def drake_check(robot: Robot, model: RobotModel, text: str, suffix: str, samples: int = 20,
                tolerance: float = 1e-6) -> float:
    """Largest relative difference between Drake's inverse dynamics of the exported file and
    pe_drake's rigid + armature + viscous torque of the model, on random states; ConfigError when
    Drake refuses the file or they differ by more than ``tolerance``."""
    try:
        loaded = reloaded_robot(robot, text, suffix)
    except ConfigError as err:
        raise ConfigError(f"Drake refuses the exported {suffix} file: {err}") from err
    if loaded.joint_names != robot.joint_names:
        raise ConfigError(f"the exported file has joints {loaded.joint_names}, expected {robot.joint_names}")
    q, v, vd = random_states(robot, samples)
    want = model.torque(robot, q, v, vd, coulomb=False, offset=False)
    got = loaded.inverse_dynamics(q, v, vd, include_damping=True)
    error = float(np.max(np.abs(got - want)) / max(float(np.max(np.abs(want))), 1e-12))
    if not error <= tolerance:
        raise ConfigError(f"the exported {suffix} file does not reproduce the model in Drake: torques differ by "
                          f"{error:.3g} relative (tolerance {tolerance:g})")
    return error

