"""Defaults for a legged robot given as a bare model file: excite the arms, stand on the feet.

A humanoid URDF without a config would be welded at its pelvis with its legs swinging through
the floor. :func:`standing_defaults` derives from the joint names and foot geometry what the
shipped G1 config does by hand: the arm joints excited (grippers and fingers locked), the rest
locked at zero, the lowest point of the feet at z = 0 and the sole corners as
``robot.support_points`` (Eq. 52), self-collision at the paper's 2 cm (Eq. 53).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from pe_drake.multibody.link_geometry import primitive_points, read_link_shapes, rotation_rpy
from pe_drake.multibody.collada_up_axis import oriented_vertices, up_axis_note
from pe_drake.multibody.meshes import resolve_mesh_path
from pe_drake.multibody.urdf_checks import urdf_tree

LEG = re.compile(r"hip|knee|ankle|leg|foot|toe", re.IGNORECASE)
ARM = re.compile(r"shoulder|elbow|wrist|arm", re.IGNORECASE)
HAND = re.compile(r"grip|finger|thumb|hand|index|pinky|palm|claw|jaw", re.IGNORECASE)
#: Self-collision margin of the arms against the trunk and each other (the paper's 2 cm) [m].
COLLISION_MARGIN = 0.02
#: Points within this height of a foot's lowest point are its sole [m].
SOLE_BAND = 0.005
#: The balance radius (Eq. 52) given to a humanoid without a config [m], widened to take in the
#: CoM of the starting posture.
BALANCE_RADIUS = 0.02


def _origin(element: ET.Element | None) -> np.ndarray:
    X = np.eye(4)
    if element is not None:
        X[:3, :3] = rotation_rpy([float(v) for v in element.get("rpy", "0 0 0").split()])
        X[:3, 3] = [float(v) for v in element.get("xyz", "0 0 0").split()]
    return X


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    X = np.eye(4)
    X[:3, :3] = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K  # Rodrigues
    return X


def _link_poses(joints: list[ET.Element], root: str, q: dict[str, float]) -> dict[str, np.ndarray]:
    """X_RL of every link with the revolute joints at ``q`` (others at zero), R the root link."""
    children: dict[str, list[ET.Element]] = {}
    for j in joints:
        children.setdefault(j.find("parent").get("link"), []).append(j)
    poses, stack = {root: np.eye(4)}, [root]
    while stack:
        parent = stack.pop()
        for j in children.get(parent, []):
            child = j.find("child").get("link")
            X = poses[parent] @ _origin(j.find("origin"))
            if j.get("name") in q and j.get("type") in ("revolute", "continuous"):
                axis = j.find("axis")
                xyz = axis.get("xyz", "1 0 0") if axis is not None else "1 0 0"
                X = X @ _axis_rotation(np.array([float(v) for v in xyz.split()]), q[j.get("name")])
            poses[child] = X
            stack.append(child)
    return poses


def _mid_range(joints: list[ET.Element], names: list[str]) -> dict[str, float]:
    """The mid-range posture of the named joints (where the optimizer starts)."""
    q = {}
    for j in joints:
        limit = j.find("limit")
        if j.get("name") in names and limit is not None and j.get("type") == "revolute":
            q[j.get("name")] = 0.5 * (float(limit.get("lower", 0)) + float(limit.get("upper", 0)))
    return q


def _centre_of_mass(tree: ET.Element, poses: dict[str, np.ndarray]) -> np.ndarray:
    """The whole robot's CoM in the root frame from the URDF inertials [m]."""
    total, moment = 0.0, np.zeros(3)
    for link in tree.findall("link"):
        inertial = link.find("inertial")
        mass = inertial.find("mass") if inertial is not None else None
        if mass is None or link.get("name") not in poses:
            continue
        m = float(mass.get("value", 0))
        p = poses[link.get("name")] @ np.r_[_origin(inertial.find("origin"))[:3, 3], 1.0]
        total, moment = total + m, moment + m * p[:3]
    return moment / max(total, 1e-12)


def _balance_radius(support: dict[str, list[list[float]]], poses: dict[str, np.ndarray], com: np.ndarray) -> float:
    """BALANCE_RADIUS around the support centre, widened to take in the starting CoM, but never
    past the feet's bounding box less 1 cm."""
    corners = np.array([(poses[link] @ np.r_[c, 1.0])[:3] for link, cs in support.items() for c in cs])
    centre = corners.mean(axis=0)
    half = np.minimum(centre[:2] - corners[:, :2].min(axis=0), corners[:, :2].max(axis=0) - centre[:2])
    cap = float(half.min()) - 0.01
    wanted = float(np.linalg.norm(com[:2] - centre[:2])) + BALANCE_RADIUS
    return round(max(BALANCE_RADIUS, min(wanted, cap)), 4)


def _feet(joints: list[ET.Element]) -> list[list[str]]:
    """The links of each foot: below a leg joint with no leg joint under it."""
    by_parent: dict[str, list[ET.Element]] = {}
    for j in joints:
        by_parent.setdefault(j.find("parent").get("link"), []).append(j)

    def below(link: str) -> list[ET.Element]:
        out = []
        for j in by_parent.get(link, []):
            out += [j] + below(j.find("child").get("link"))
        return out

    feet = []
    for j in joints:
        if j.get("type") == "fixed" or not LEG.search(j.get("name", "")):
            continue
        child = j.find("child").get("link")
        under = below(child)
        if any(k.get("type") != "fixed" and LEG.search(k.get("name", "")) for k in under):
            continue
        feet.append([child] + [k.find("child").get("link") for k in under if k.get("type") == "fixed"])
    return feet


def _shape_points(shapes, model_path: Path) -> np.ndarray:
    """Points of a link's collision shapes (its visuals when it has none), link frame."""
    chosen = [s for s in shapes if s.tag == "collision"] or [s for s in shapes if s.tag == "visual"]
    points = []
    for s in chosen:
        if s.kind != "mesh":
            points.append(primitive_points(s))
            continue
        path = resolve_mesh_path(s.filename, model_path)
        if path is not None:
            v = oriented_vertices(path, model_path) * s.scale  # a COLLADA mesh as the model means it
            points.append(v @ s.X_LG[:3, :3].T + s.X_LG[:3, 3])
    return np.vstack(points) if points else np.zeros((0, 3))


def _sole(points_R: np.ndarray, X_RL: np.ndarray, z0: float) -> list[list[float]]:
    """The four corners of the sole's bounding box (root frame x-y, height z0), in the link frame.

    Symmetric feet give symmetric points, centred under the middle of each sole."""
    sole = points_R[points_R[:, 2] <= z0 + SOLE_BAND]
    (x0, y0), (x1, y1) = sole[:, :2].min(axis=0), sole[:, :2].max(axis=0)
    X_LR = np.linalg.inv(X_RL)
    corners = [np.array([x, y, z0]) for x in (x0, x1) for y in (y0, y1)]
    return [[round(float(v), 5) for v in X_LR[:3, :3] @ c + X_LR[:3, 3]] for c in corners]


def standing_defaults(model_path: str | Path) -> dict | None:
    """The robot and excitation settings of a legged robot standing on its feet, or None.

    Returns:
        {"robot": {...}, "excitation": {...}} for :class:`~pe_drake.config.RobotConfig` and
        :class:`~pe_drake.config.ExcitationConfig`, or None for a model that is not a URDF of a
        legged robot with arms (fewer than two feet or two arm joints, or a welded root).
    """
    model_path = Path(model_path)
    if model_path.suffix.lower() != ".urdf":
        return None
    try:
        tree = urdf_tree(model_path.read_text())  # as Drake reads it (a DOCTYPE's entities not expanded)
    except (ET.ParseError, OSError, UnicodeDecodeError):
        return None  # the loader reports it
    joints = tree.findall("joint")
    children = {j.find("child").get("link") for j in joints}
    roots = [link.get("name") for link in tree.findall("link") if link.get("name") not in children]
    if len(roots) != 1 or roots[0] == "world":
        return None
    movable = [j.get("name", "") for j in joints if j.get("type") not in ("fixed", "floating", "planar")]
    arms = [n for n in movable if ARM.search(n) and not HAND.search(n) and not LEG.search(n)]
    feet = _feet(joints)
    if len(feet) < 2 or len(arms) < 2:
        return None
    poses, shapes = _link_poses(joints, roots[0], {}), read_link_shapes(model_path)
    points = {}
    for link in (link for foot in feet for link in foot):
        p = _shape_points(shapes.get(link, []), model_path)
        if len(p):
            points[link] = p @ poses[link][:3, :3].T + poses[link][:3, 3]
    if len({link for foot in feet for link in foot if link in points}) < 2:
        return None
    z0 = min(float(p[:, 2].min()) for p in points.values())
    support = {link: _sole(p, poses[link], z0) for link, p in points.items() if p[:, 2].min() <= z0 + SOLE_BAND}
    radius = _balance_radius(support, poses, _centre_of_mass(tree, _link_poses(joints, roots[0], _mid_range(joints, arms))))
    note = (
        f"a legged robot without a config: standing on {', '.join(support)} (root link '{roots[0]}' at "
        f"{-z0:.4g} m, legs straight), the {len(arms)} arm joints excited, the other {len(movable) - len(arms)} "
        f"joints locked at zero, CoM within {radius:g} m of the feet's centre, capsules {COLLISION_MARGIN:g} m "
        "apart; give a config (robot.joints, support_points, base_position) to choose otherwise")
    turned = up_axis_note(model_path)
    return {
        "robot": {"joints": arms, "base_position": [0.0, 0.0, -z0], "support_points": support,
                  "notes": [note] + ([turned] if turned else [])},
        "excitation": {"balance_radius": radius, "collision_margin": COLLISION_MARGIN},
    }
