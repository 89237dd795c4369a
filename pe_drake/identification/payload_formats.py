"""An identified payload in the formats robot controllers take, in the vendor's flange frame.

The payload is identified in its link's frame L; controllers want it in their flange frame F
(``panda_link8`` for a Franka, ``tool0`` for a UR; any link rigidly attached to L). With X_LF the
flange's pose in L, p_FoPcm_F = R_FL (p_LoPcm_L − p_LoFo_L) and I_F = R_FL I_L R_LF (about the
centre of mass).

- Franka (libfranka ``Robot::setLoad(load_mass, F_x_Cload, load_inertia)``): mass [kg], the
  centre of mass in F [m], the 3×3 inertia about it in F's axes, column-major [kg·m²].
- UR (URScript): ``set_target_payload(m, [cx, cy, cz], [Ixx, Iyy, Izz, Ixy, Ixz, Iyz])`` (about
  the centre of mass, axes of ``tool0``) and the older ``set_payload(m, [cx, cy, cz])``.
- KUKA (KRL ``LOAD_DATA``): M [kg]; CM X, Y, Z [mm] in the flange frame; A, B, C [deg], the
  principal axes as Z-Y'-X'' angles (R = Rz(A) Ry(B) Rx(C)); J X, Y, Z [kg·m²] the principal
  moments.
- URDF: the robot's model with a link ``pe_drake_payload`` welded to L, its inertial the
  payload (verified by parsing it back with Drake).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pe_drake.exceptions import ConfigError
from pe_drake.io_utils import atomic_write_text
from pe_drake.multibody.payload import PayloadInertia, link_position
from pe_drake.multibody.urdf import urdf_text_phi, urdf_with_inertias

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Known vendor flange links, tried in order when no flange is given.
DEFAULT_FLANGES = ("panda_link8", "tool0", "flange", "iiwa_link_ee", "link_ee")
#: Name of the payload link in the exported URDF.
PAYLOAD_LINK_NAME = "pe_drake_payload"


def default_flange(robot: Robot) -> str:
    """The robot's known flange link (``panda_link8``, ``tool0``, ...).

    Raises:
        ConfigError: none of :data:`DEFAULT_FLANGES` is a body of the robot.
    """
    for name in DEFAULT_FLANGES:
        if name in robot.body_names:
            return name
    raise ConfigError(f"robot '{robot.name}' has none of the known flange links {', '.join(DEFAULT_FLANGES)}: "
                      f"give the flange link (--flange); moving links: {', '.join(robot.body_names)}")


def flange_pose_in_link(robot: Robot, link: str, flange: str) -> np.ndarray:
    """X_LF, the flange's pose in the payload link's frame, (4, 4).

    Raises:
        UnknownNameError: an unknown link.
        ConfigError: the flange is not rigidly attached to the link.
    """
    a, b = link_position(robot, link), link_position(robot, flange)
    if robot.joint_of_body[a] != robot.joint_of_body[b]:
        raise ConfigError(f"flange '{flange}' is not rigidly attached to the payload link '{link}' (a joint "
                          "moves between them): choose a flange on the same rigid group")
    X = robot.body_poses(robot.nominal_posture()[None, :])[0]
    X_WL, X_WF = X[robot.body_indices[a]], X[robot.body_indices[b]]
    return np.linalg.inv(X_WL) @ X_WF


def payload_in_flange(robot: Robot, payload: PayloadInertia, link: str, flange: str | None = None) -> PayloadInertia:
    """The payload (in ``link``'s frame) expressed in the flange frame (default :func:`default_flange`)."""
    flange = flange or default_flange(robot)
    return payload.in_frame(flange_pose_in_link(robot, link, flange))


def franka_load(p: PayloadInertia) -> dict[str, Any]:
    """libfranka ``setLoad`` arguments: ``load_mass``, ``F_x_Cload`` (3), ``load_inertia``
    (9, column-major)."""
    return {"load_mass": p.mass, "F_x_Cload": p.com.tolist(),
            "load_inertia": np.asarray(p.inertia_about_com).flatten(order="F").tolist()}


def ur_script(p: PayloadInertia, digits: int = 6) -> dict[str, str]:
    """URScript lines: ``set_target_payload`` (mass, CoG, inertia) and ``set_payload`` (mass, CoG)."""
    def fmt(v):
        return "[" + ", ".join(f"{x:.{digits}g}" for x in v) + "]"

    return {"set_target_payload": f"set_target_payload({p.mass:.{digits}g}, {fmt(p.com)}, {fmt(p.inertia_vector)})",
            "set_payload": f"set_payload({p.mass:.{digits}g}, {fmt(p.com)})"}


def kuka_angles(R: np.ndarray) -> np.ndarray:
    """KUKA A, B, C [deg] of a rotation: R = Rz(A) Ry(B) Rx(C)."""
    B = math.asin(float(np.clip(-R[2, 0], -1.0, 1.0)))
    if abs(math.cos(B)) > 1e-9:
        A, C = math.atan2(R[1, 0], R[0, 0]), math.atan2(R[2, 1], R[2, 2])
    else:  # gimbal lock: C = 0
        A, C = math.atan2(-R[0, 1], R[1, 1]), 0.0
    return np.degrees([A, B, C])


def kuka_load_data(p: PayloadInertia, index: int = 1) -> dict[str, Any]:
    """KUKA LOAD_DATA: ``M``, ``X``/``Y``/``Z`` [mm], ``A``/``B``/``C`` [deg] of the principal
    axes, ``JX``/``JY``/``JZ`` [kg·m²], and the KRL line ``LOAD_DATA[index]={...}``."""
    lam, R = p.principal()
    A, B, C = kuka_angles(R)
    x, y, z = 1000.0 * p.com
    d = {"M": p.mass, "X": x, "Y": y, "Z": z, "A": A, "B": B, "C": C, "JX": lam[0], "JY": lam[1], "JZ": lam[2]}
    d["krl"] = (f"LOAD_DATA[{index}]={{M {p.mass:.4f},CM {{X {x:.3f},Y {y:.3f},Z {z:.3f},A {A:.3f},B {B:.3f},"
                f"C {C:.3f}}},J {{X {lam[0]:.6f},Y {lam[1]:.6f},Z {lam[2]:.6f}}}}}")
    return d


def vendor_formats(robot: Robot, payload: PayloadInertia, link: str, flange: str | None = None) -> dict[str, Any]:
    """Every format above for the payload on ``link``, in the flange frame (the payload link's own
    when none is given and the robot has none of :data:`DEFAULT_FLANGES`: issue 37)."""
    known = [name for name in DEFAULT_FLANGES if name in robot.body_names]
    flange = flange or (known[0] if known else link)
    p = payload_in_flange(robot, payload, link, flange)
    return {"flange": flange, "mass": p.mass, "com_in_flange": p.com.tolist(),
            "inertia_about_com_in_flange": p.inertia_vector.tolist(),
            "franka": franka_load(p), "ur": ur_script(p), "kuka": kuka_load_data(p)}


def urdf_with_payload(robot: Robot, payload: PayloadInertia, link: str, arm_phi: np.ndarray | None = None) -> str:
    """The robot's URDF (with the arm's parameters ``arm_phi`` if given) plus a link
    :data:`PAYLOAD_LINK_NAME` welded to ``link`` carrying the payload (in ``link``'s frame).

    Raises:
        ConfigError: a model that is not a URDF or already has the payload link.
    """
    phi = robot.phi_model if arm_phi is None else np.asarray(arm_phi, float)
    text = urdf_with_inertias(robot.model_path, robot.body_names, phi, check=False)
    body, sep, rest = text.partition("\n<robot")
    root = ET.fromstring("<robot" + rest if sep else text)
    if any(e.get("name") == PAYLOAD_LINK_NAME for e in root.iter("link")):
        raise ConfigError(f"the model already has a link '{PAYLOAD_LINK_NAME}'")
    new = ET.SubElement(root, "link", {"name": PAYLOAD_LINK_NAME})
    inertial = ET.SubElement(new, "inertial")
    ET.SubElement(inertial, "origin", {"xyz": " ".join(repr(float(x)) for x in payload.com), "rpy": "0 0 0"})
    ET.SubElement(inertial, "mass", {"value": repr(float(payload.mass))})
    I = np.asarray(payload.inertia_about_com, float)
    entries = {"ixx": (0, 0), "ixy": (0, 1), "ixz": (0, 2), "iyy": (1, 1), "iyz": (1, 2),
               "izz": (2, 2)}
    ET.SubElement(inertial, "inertia", {k: repr(float(I[i, j])) for k, (i, j) in entries.items()})
    joint = ET.SubElement(root, "joint", {"name": PAYLOAD_LINK_NAME + "_joint", "type": "fixed"})
    ET.SubElement(joint, "parent", {"link": link})
    ET.SubElement(joint, "child", {"link": PAYLOAD_LINK_NAME})
    ET.SubElement(joint, "origin", {"xyz": "0 0 0", "rpy": "0 0 0"})
    ET.indent(root)
    return (body + "\n" if sep else "") + ET.tostring(root, encoding="unicode") + "\n"


def write_payload_urdf(path: str | Path, robot: Robot, payload: PayloadInertia, link: str,
                       arm_phi: np.ndarray | None = None) -> Path:
    """Writes :func:`urdf_with_payload` after Drake has read the payload link back unchanged.

    Raises:
        ConfigError: Drake refuses the text or reads another inertia.
    """
    text = urdf_with_payload(robot, payload, link, arm_phi)
    got = urdf_text_phi(text, [PAYLOAD_LINK_NAME])
    if not np.allclose(got, payload.phi, rtol=1e-9, atol=1e-12 * max(payload.mass, 1.0)):
        raise ConfigError(f"the exported payload link reads back as {got.tolist()}, expected {payload.phi.tolist()}")
    path = Path(path)
    atomic_write_text(path, text)
    return path
