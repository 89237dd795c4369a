"""What the Meshcat playback draws around the robot: the config's environment (floor and boxes),
the CoM's ground projection with the feet's support area, and a camera framed on the motion
(Meshcat's default camera is fixed a few metres out: a 0.4 m arm would be a speck).
"""

from __future__ import annotations

import math
import re
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.exceptions import UnknownNameError
from pe_drake.excitation.constraints.environment import Box, floor_plane

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Meshcat path (under ``/drake``) of the environment layer.
ENVIRONMENT_PATH = "environment"
#: Meshcat paths (under ``/drake``) of the CoM's ground projection and the support area.
COM_PATH = "com_projection"
SUPPORT_PATH = "support_area"

_COM_RADIUS = 0.03  # [m] radius of the CoM ground marker (a flat disc)
_GROUND_OFFSET = 1e-3  # [m] above z = 0, so the markers do not flicker with the grid
_COM_RGBA = (0.9, 0.1, 0.1, 1.0)
_SUPPORT_RGBA = (0.1, 0.7, 0.2, 0.35)

_FLOOR_RGBA = (0.35, 0.35, 0.4, 0.15)
_BOX_RGBA = (0.2, 0.45, 0.9, 0.35)
_FLOOR_THICKNESS = 2e-3  # [m]; its top face 1 mm under the plane, so it does not flicker with the grid
_MIN_FLOOR_SIDE = 1.0  # [m]
_FOV_DEG = 75.0  # vertical field of view of Meshcat's default perspective camera (meshcat's viewer)
#: Direction from the target to the camera: in front, to the right and above (about 30°).
_VIEW_DIRECTION = np.array([1.0, 0.7, 0.85]) / np.linalg.norm([1.0, 0.7, 0.85])
_MIN_RADIUS = 0.05  # [m]: the smallest half-size framed (a point-sized extent)


def draw_environment(meshcat, robot: Robot, environment, extent: tuple[np.ndarray, np.ndarray]) -> dict[str, str]:
    """Draws the config's floor (for a fixed-base arm) and boxes, translucent; returns {object
    name: Meshcat path} drawn ("floor", "box:<name>"), or ConfigError for a malformed box.

    Args:
        environment: an :class:`~pe_drake.config.EnvironmentConfig`.
        extent: (lower, upper) corners of what the robot sweeps, each shape (3,) [m]: the
            floor square is centred under it and spans it.
    """
    from pydrake.geometry import Box as BoxShape  # lazy: pydrake is heavy
    from pydrake.geometry import Rgba
    from pydrake.math import RigidTransform, RotationMatrix

    meshcat.Delete(ENVIRONMENT_PATH)
    drawn: dict[str, str] = {}
    plane = floor_plane(robot, environment)
    lo, hi = (np.asarray(v, float) for v in extent)
    if plane is not None:
        normal, height = plane
        center = (lo + hi) / 2
        center = center - (center @ normal - height) * normal  # its projection on the plane
        side = max(_MIN_FLOOR_SIDE, 2.0 * float(np.max(hi - lo)))
        path = f"{ENVIRONMENT_PATH}/floor"
        meshcat.SetObject(path, BoxShape(side, side, _FLOOR_THICKNESS), Rgba(*_FLOOR_RGBA))
        R_WF = RotationMatrix.MakeFromOneVector(normal, 2)  # the square's z axis is the floor normal
        meshcat.SetTransform(path, RigidTransform(R_WF, center - (_FLOOR_THICKNESS / 2 + 1e-3) * normal))
        drawn["floor"] = f"/drake/{path}"
    for k, spec in enumerate(environment.boxes):
        box = Box.from_spec(spec, k)
        path = f"{ENVIRONMENT_PATH}/boxes/{_path_name(box.name, k)}"
        meshcat.SetObject(path, BoxShape(*box.size), Rgba(*_BOX_RGBA))
        meshcat.SetTransform(path, RigidTransform(box.center))
        drawn[f"box:{box.name}"] = f"/drake/{path}"
    return drawn


def motion_extent(robot: Robot, q: np.ndarray, max_samples: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) corners in world, each shape (3,) [m], of the axis-aligned box that body
    origins and capsules sweep over the postures q, shape (T, n), at ``max_samples`` frames."""
    plant = robot.plant
    context = plant.CreateDefaultContext()
    from pydrake.multibody.tree import BodyIndex  # lazy: pydrake is heavy

    bodies = [plant.get_body(BodyIndex(i)) for i in range(1, plant.num_bodies())]  # 0 is the world
    capsules = list(getattr(robot, "capsules", ()) or ())
    rows = np.unique(np.linspace(0, len(q) - 1, min(len(q), max_samples)).round().astype(int))
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for k in rows:
        plant.SetPositions(context, q[k])
        X_WB = {int(b.index()): plant.EvalBodyPoseInWorld(context, b).GetAsMatrix4() for b in bodies}
        points = [X[:3, 3] for X in X_WB.values()]
        for c in capsules:
            X = X_WB.get(int(c.body_index))
            if X is None:
                continue
            ends = (X[:3, :3] @ np.asarray(c.p_BS, float).T).T + X[:3, 3]
            points += [ends - c.radius, ends + c.radius]
        p = np.vstack(points)
        lo, hi = np.minimum(lo, p.min(axis=0)), np.maximum(hi, p.max(axis=0))
    return lo, hi


def camera_pose(extent: tuple[np.ndarray, np.ndarray], fill: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
    """(p_WC camera position, p_WT target), each shape (3,) [m], that fit the box ``extent``
    ((lower, upper) corners [m]) in Meshcat's view.

    The camera looks at the box's centre along a fixed direction from the nearest distance d at
    which every corner (a along the view, offsets u, v across it) is within ``fill`` of the half
    field of view: d = max over the corners of a + max(|u|, |v|) / (fill · tan(fov/2)) (the
    vertical angle binds: a browser window is wider than tall).
    """
    lo, hi = (np.asarray(v, float) for v in extent)
    target = (lo + hi) / 2
    half = np.maximum((hi - lo) / 2, _MIN_RADIUS)
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    back = _VIEW_DIRECTION  # from the target to the camera
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    across = np.maximum(np.abs(corners @ right), np.abs(corners @ up))
    distance = float(np.max(corners @ back + across / (fill * math.tan(math.radians(_FOV_DEG) / 2))))
    return target + distance * back, target


def frame_camera(meshcat, extent: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Points Meshcat's camera at ``extent`` (:func:`camera_pose`); returns (position, target)."""
    camera, target = camera_pose(extent)
    meshcat.SetCameraPose(camera, target)
    return camera, target


def _path_name(name: str, index: int) -> str:
    """A Meshcat path element from a box name ('/' separates path elements)."""
    clean = re.sub(r"[^A-Za-z0-9_.\-]+", "_", name).strip("_")
    return clean or f"box{index}"


def support_polygon(rob, plant, plant_context, q0: np.ndarray) -> np.ndarray:
    """Convex hull (x, y) of the support points in world at q0 (the area at t = 0), shape (m, 2)
    [m]."""
    points = rob.config.support_points or {}
    if not points:
        return np.zeros((0, 2))
    plant.SetPositions(plant_context, q0)
    p_W = []
    for link, p_L in points.items():
        if not plant.HasBodyNamed(link):
            raise UnknownNameError("link", link, rob.body_names_all, where="robot.support_points")
        X_WL = plant.EvalBodyPoseInWorld(plant_context, plant.GetBodyByName(link))
        p_W.append((X_WL.GetAsMatrix4() @ np.c_[np.asarray(p_L, float), np.ones(len(p_L))].T)[:3].T)
    return convex_hull_2d(np.concatenate(p_W)[:, :2])


def convex_hull_2d(points: np.ndarray) -> np.ndarray:
    """Convex hull of points, shape (N, 2) (Andrew's monotone chain): the corners
    counter-clockwise without repetition, shape (m, 2)."""
    pts = np.unique(np.asarray(points, float).reshape(-1, 2), axis=0)  # sorted by x, then y
    if len(pts) <= 2:
        return pts

    def half(seq):
        chain: list[np.ndarray] = []
        for p in seq:
            while len(chain) >= 2 and _cross(chain[-1] - chain[-2], p - chain[-2]) <= 0:
                chain.pop()
            chain.append(p)
        return chain[:-1]

    return np.array(half(pts) + half(pts[::-1]))


def _cross(a: np.ndarray, b: np.ndarray) -> float:
    """z of the cross product of two planar vectors."""
    return float(a[0] * b[1] - a[1] * b[0])


def draw_markers(meshcat, support: np.ndarray) -> None:
    """Draws the CoM's ground disc, and the support area's polygon and outline (3 corners up)."""
    from pydrake.geometry import Cylinder, Rgba  # lazy: pydrake is heavy

    meshcat.Delete(COM_PATH)
    meshcat.Delete(SUPPORT_PATH)
    meshcat.SetObject(f"{COM_PATH}/disc", Cylinder(_COM_RADIUS, 0.002), Rgba(*_COM_RGBA))
    if len(support) >= 3:
        m = len(support)
        vertices = np.c_[support, np.full(m, _GROUND_OFFSET / 2)].T
        faces = np.array([[0, k, k + 1] for k in range(1, m - 1)], np.int32).T
        meshcat.SetTriangleMesh(f"{SUPPORT_PATH}/area", np.asfortranarray(vertices),
                                np.asfortranarray(faces), Rgba(*_SUPPORT_RGBA))
        outline = np.c_[vertices, vertices[:, :1]]
        meshcat.SetLine(f"{SUPPORT_PATH}/outline", np.asfortranarray(outline), 2.0, Rgba(0.1, 0.5, 0.1, 1.0))


def com_marker_pose(xy: np.ndarray):
    """The pose of the CoM's ground disc over the point ``xy`` [m], just above the ground."""
    from pydrake.math import RigidTransform  # lazy: pydrake is heavy

    return RigidTransform([float(xy[0]), float(xy[1]), _GROUND_OFFSET])
