"""The identified robot as MuJoCo's MJCF: one ``<body>`` per Drake body with its identified
inertial, the excited joints with their drive terms, the base at its mount pose.

Each excited joint is a ``hinge`` or ``slide`` with MuJoCo's ``armature``, ``damping`` and
``frictionloss`` f_c: a constraint that holds a joint at rest below f_c, not f_c·tanh(v/v_s); the
two agree when sliding (|v| ≫ v_s). What MJCF cannot hold is listed in a comment at the top.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from pe_drake.export.mjcf_meshes import add_visuals
from pe_drake.export.tree import number_text, quaternion_wxyz, robot_tree, vector_text
from pe_drake.multibody.inertia import central_inertia
from pe_drake.multibody.robot_model import PAYLOAD_BODY_NAME, RobotModel

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Smallest principal moment of inertia of a body with mass written to an MJCF [kg·m²].
MIN_PRINCIPAL_MOMENT = 1e-12


def _inertial(parent: ET.Element, phi_b: np.ndarray) -> str:
    """``<inertial>`` of a body's 10 parameters; none for a massless frame (mass 0 as in Drake).

    MuJoCo refuses a mass whose inertia has a zero principal moment (a point mass, a rod: valid
    in Drake); those moments are raised to :data:`MIN_PRINCIPAL_MOMENT` and a note returned.
    """
    m, p, I = central_inertia(phi_b)
    if m <= 0:
        return ""
    attributes = {"pos": vector_text(p), "mass": number_text(m)}
    lam, R = np.linalg.eigh(0.5 * (I + I.T))
    floor = max(MIN_PRINCIPAL_MOMENT, 1e-9 * float(lam.max()))
    if lam.min() > floor:
        attributes["fullinertia"] = vector_text([I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]])
        ET.SubElement(parent, "inertial", attributes)
        return ""
    if np.linalg.det(R) < 0:
        R[:, 0] = -R[:, 0]
    attributes.update(quat=vector_text(quaternion_wxyz(np.block([[R, np.zeros((3, 1))], [np.zeros((1, 3)), 1.0]]))),
                      diaginertia=vector_text(np.maximum(lam, floor)))
    ET.SubElement(parent, "inertial", attributes)
    return (f"{parent.get('name')}: principal moments {', '.join(f'{x:.3g}' for x in lam)} kg·m² raised to "
            f"at least {floor:.3g} (MuJoCo refuses a zero principal moment)")


def _joint(body_el: ET.Element, robot: Robot, model: RobotModel, k: int) -> None:
    """The ``<joint>`` of excited joint k in its child body: frame, axis, limits, drive terms."""
    info, joint = robot.joints[k], robot.plant.GetJointByName(robot.joint_names[k])
    X_CM = np.asarray(info.X_CM, float)
    attributes = {
        "name": info.name, "type": "hinge" if info.kind == "revolute" else "slide",
        "pos": vector_text(X_CM[:3, 3]), "axis": vector_text(X_CM[:3, :3] @ np.asarray(info.axis_M, float)),
        "armature": number_text(model.armature[k]), "damping": number_text(model.viscous[k]),
        "frictionloss": number_text(model.sliding_friction[k]),
    }
    if model.spring[k] > 0:  # diagnose's joint_stiffness k·q + offset τ₀ = k (q - springref): MuJoCo's spring
        attributes.update(stiffness=number_text(model.spring[k]), springref=number_text(-model.offset[k] / model.spring[k]))
    lo, hi = joint.position_lower_limits()[0], joint.position_upper_limits()[0]
    attributes["limited"] = "true" if np.isfinite(lo) and np.isfinite(hi) else "false"
    if attributes["limited"] == "true":
        attributes["range"] = vector_text([lo, hi])
    effort = robot.limits.effort_max[k]
    if np.isfinite(effort):
        attributes.update(actuatorfrclimited="true", actuatorfrcrange=vector_text([-effort, effort]))
    ET.SubElement(body_el, "joint", attributes)


def _bodies(robot: Robot, model: RobotModel, worldbody: ET.Element, notes: list[str]) -> dict[str, ET.Element]:
    """The bodies, nested as Drake's tree, each posed in its parent at q = 0: {name: element}
    (what was adjusted is appended to ``notes``)."""
    elements = {"world": worldbody}
    for body in robot_tree(robot, model):
        X = body.X_PC
        body_el = ET.SubElement(elements[body.parent], "body", {
            "name": body.name, "pos": vector_text(X[:3, 3]), "quat": vector_text(quaternion_wxyz(X))})
        elements[body.name] = body_el
        notes.append(_inertial(body_el, body.phi))
        if body.joint >= 0:
            _joint(body_el, robot, model, body.joint)
        if model.payload is not None and body.name == model.payload_link:
            payload_el = ET.SubElement(body_el, "body", {"name": PAYLOAD_BODY_NAME, "pos": "0 0 0"})
            notes.append(_inertial(payload_el, model.payload.phi))
    del elements["world"]
    return elements


#: How each format holds f_c·tanh(v/v_s), or why it does not.
_COULOMB = {
    "mjcf": "is written as MuJoCo's frictionloss f_c: a constraint that holds the joint at rest below f_c and "
            "equals f_c*sign(v) once it slides; the two differ for |v| below a few v_s",
    "urdf": "is written as <dynamics friction>: Drake ignores it, pe_drake reads it back as f_c*tanh(v/0.01)",
    "sdf": "is written as <dynamics><friction>: Drake ignores it, and so does pe_drake in an SDFormat file",
}


#: Formats written with a joint spring (MJCF ``stiffness``/``springref``). A URDF has none; an
#: SDFormat ``spring_stiffness`` is a RevoluteSpring in Drake, but a plant with one refuses the
#: RemoveJoint by which pe_drake locks joints, so the SDF lists the springs as not held.
SPRING_FORMATS = ("mjcf",)


def spring_held_offsets(model: RobotModel, fmt: str) -> np.ndarray:
    """The torque offsets a format holds, (n,): in MJCF those of joints with a spring, as its
    reference angle (k·q + τ₀ = k (q − q_ref), q_ref = −τ₀/k)."""
    return np.where(model.spring > 0, model.offset, 0.0) if fmt in SPRING_FORMATS else np.zeros(len(model.joints))


def unheld_terms(robot: Robot, model: RobotModel, fmt: str = "mjcf") -> list[str]:
    """What a format (mjcf, urdf, sdf) cannot hold of the model, one sentence each."""
    joints = robot.joint_names
    out = []
    offsets = model.offset - spring_held_offsets(model, fmt)
    if np.any(offsets != 0):
        out.append("torque offsets (add them to the control: the format has no constant joint torque): "
                   + ", ".join(f"{j} {x:.4g}" for j, x in zip(joints, offsets) if x != 0))
    if np.any(model.sliding_friction > 0) and fmt in _COULOMB:
        out.append(f"Coulomb friction f_c*tanh(v/v_s), v_s = {model.velocity_scale:g} rad/s, {_COULOMB[fmt]}")
    if model.torque_delay:
        out.append(f"the torque delay of {model.torque_delay:.4g} s")
    if np.any(model.presliding > 0):
        out.append("pre-sliding (Dahl) friction F_c, written as its sliding level with the Coulomb friction; "
                   "its transition over x_p = F_c/σ0 after a reversal is not held: " + ", ".join(
            f"{j} {x:.4g}" for j, x in zip(joints, model.presliding) if x > 0))
    if np.any(model.spring > 0) and fmt not in SPRING_FORMATS:  # diagnose's joint_stiffness
        out.append("joint springs k·q [N·m/rad] (add them to the control): " + ", ".join(
            f"{j} {x:.4g}" for j, x in zip(joints, model.spring) if x > 0))
    return out


class MJCFFiles(NamedTuple):
    """An MJCF (``text``), what it cannot hold (``unheld``), the {file name: content} of its mesh
    folder (``meshes``) and the visuals left out (``notes``), from :func:`mjcf_files`."""

    text: str
    unheld: list[str]
    meshes: dict[str, bytes]
    notes: list[str]


def mjcf_files(robot: Robot, model: RobotModel, meshdir: str | None = None,
               source: str = "") -> MJCFFiles:
    """The MJCF of the robot with ``model``, and with ``meshdir`` (a folder name beside the
    file) its visuals (:mod:`pe_drake.export.mjcf_meshes`); ``source`` names the model file."""
    unheld = unheld_terms(robot, model)
    root = ET.Element("mujoco", {"model": robot.name})
    compiler = ET.SubElement(root, "compiler", {"angle": "radian", "inertiafromgeom": "false", "autolimits": "true"})
    gravity = robot.plant.gravity_field().gravity_vector()
    ET.SubElement(root, "option", {"gravity": vector_text(gravity), "integrator": "implicitfast"})
    asset = ET.SubElement(root, "asset")
    worldbody = ET.SubElement(root, "worldbody")
    adjusted: list[str] = []
    bodies = _bodies(robot, model, worldbody, adjusted)
    unheld = unheld + [n for n in adjusted if n]
    meshes, notes = {}, []
    if meshdir is not None:
        compiler.set("meshdir", meshdir)
        meshes, notes = add_visuals(robot, bodies, asset)
    if not len(asset):
        root.remove(asset)
    actuator = ET.SubElement(root, "actuator")
    for k, joint in enumerate(robot.joint_names):
        attributes = {"name": joint, "joint": joint, "gear": "1"}
        effort = robot.limits.effort_max[k]
        if np.isfinite(effort):
            attributes.update(ctrllimited="true", ctrlrange=vector_text([-effort, effort]))
        ET.SubElement(actuator, "motor", attributes)
    ET.indent(root, "  ")
    lines = [f"MJCF of robot '{robot.name}' written by pe-drake export",
             f"model: {source or 'the robot model file (CAD)'}"]
    lines += [f"note: {n}" for n in model.notes]
    lines += [f"not held by MJCF: {n}" for n in unheld]
    lines += [f"note: {n}" for n in notes]
    if meshdir is None:
        lines.append("no geometry: inertials are explicit (inertiafromgeom false); add visuals from the robot's model")
    comment = "\n".join("  " + line.replace("--", "- -") for line in lines)
    return MJCFFiles(f"<!--\n{comment}\n-->\n" + ET.tostring(root, encoding="unicode") + "\n", unheld, meshes, notes)
