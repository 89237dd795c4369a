"""Capsule files fitted automatically to a URDF's meshes (for robots that ship none).

Each link with a ``<collision>`` mesh (else its ``<visual>`` mesh) gets one capsule fitted
by :func:`pe_drake.multibody.capsules.fit_capsule` to the mesh vertices expressed in the link
frame (the element's ``<origin>`` and the mesh ``scale`` applied): the axis is the vertices'
principal axis, the radius covers 98 % of them and the segment is the shortest that contains
them. Links joined by a joint (adjacent) and links welded together are not checked against
each other: :func:`~pe_drake.multibody.capsules.register_capsules` filters those pairs.

Readers: STL (binary and ASCII) and OBJ (``v`` lines). DAE meshes are not read; a link with
only DAE meshes gets no capsule and is listed in :attr:`FittedCapsules.skipped`.
"""

from __future__ import annotations

import dataclasses
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from pe_drake.exceptions import ConfigError, DataError
from pe_drake.io_utils import atomic_write_text
from pe_drake.multibody.capsules import capsule_pairs, capsule_pose, fit_capsule, segment_closest_points
from pe_drake.multibody.meshes import read_stl, resolve_mesh_path
from pe_drake.multibody.model_files import loadable_model_path
from pe_drake.multibody.robot import Robot

#: Name of the fitted capsule file written to a command's output folder.
FITTED_CAPSULES_NAME = "fitted_capsules.yaml"
#: Self-collision margin used with fitted capsules when the config sets none [m].
FITTED_COLLISION_MARGIN = 0.01


@dataclasses.dataclass(frozen=True)
class FittedCapsules:
    """What :func:`fit_capsule_file` wrote.

    Attributes:
        path: the capsule file.
        links: links that got a capsule.
        skipped: {link: reason} for links with geometry but no capsule.
        ignored_pairs: pairs touching by design, (capsule, capsule, reason).
    """

    path: Path
    links: tuple[str, ...]
    skipped: dict[str, str]
    ignored_pairs: tuple = ()


def read_mesh_vertices(path: str | Path) -> np.ndarray:
    """Vertices of an STL or OBJ mesh, shape (V, 3) [file units].

    Raises:
        DataError: an unsupported format or an unreadable file, naming it.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".stl":
        return read_stl(path).vertices
    if suffix == ".obj":
        rows = []
        for line in path.read_text(errors="replace").splitlines():
            if line.startswith("v "):
                try:
                    rows.append([float(x) for x in line.split()[1:4]])
                except ValueError as err:
                    raise DataError(f"bad vertex line {line!r}", file=str(path)) from err
        if not rows:
            raise DataError("no vertices ('v x y z' lines)", file=str(path))
        return np.asarray(rows, float)
    raise DataError(f"mesh format '{suffix}' is not read for capsule fitting (STL and OBJ are)", file=str(path))


def _rotation_rpy(rpy) -> np.ndarray:
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx  # URDF: fixed-axis roll, pitch, yaw


def _numbers(text: str | None, count: int, default: float) -> list[float]:
    if not text:
        return [default] * count
    values = [float(x) for x in text.split()]
    return values if len(values) == count else values[:1] * count


def _link_points(link: ET.Element, model_path: Path) -> tuple[np.ndarray | None, list[str], str]:
    """Vertices of a link's collision (else visual) meshes in the link frame, the files used,
    and why none were used."""
    why = "no mesh geometry"
    for tag in ("collision", "visual"):
        points, files, reasons = [], [], []
        for element in link.findall(tag):
            mesh = element.find("geometry/mesh")
            if mesh is None:
                continue
            name = mesh.get("filename", "")
            path = resolve_mesh_path(name, model_path)
            if path is None:
                reasons.append(f"mesh '{name}' not found")
                continue
            try:
                v = read_mesh_vertices(path)
            except DataError as err:
                reasons.append(str(err))
                continue
            origin = element.find("origin")
            xyz = _numbers(origin.get("xyz") if origin is not None else None, 3, 0.0)
            rpy = _numbers(origin.get("rpy") if origin is not None else None, 3, 0.0)
            scale = np.asarray(_numbers(mesh.get("scale"), 3, 1.0))
            points.append((v * scale) @ _rotation_rpy(rpy).T + np.asarray(xyz))
            files.append(path.name)
        if points:
            return np.vstack(points), files, ""
        if reasons:
            why = "; ".join(reasons)
    return None, [], why


def fit_capsule_file(
    model_path: str | Path, out_path: str | Path, links: list[str] | None = None, cover: float = 0.98
) -> FittedCapsules:
    """Fits one capsule per link of a URDF to its meshes and writes a capsule file.

    Args:
        model_path: the URDF.
        out_path: the capsule file to write (YAML, format of pe_drake/multibody/capsules.py).
        links: only these links (default: every link with a mesh).
        cover: fraction of each mesh's vertices inside its capsule.

    Returns:
        A :class:`FittedCapsules`.

    Raises:
        ConfigError: not a URDF, unreadable XML, or no link with a readable mesh.
    """
    model_path = Path(model_path)
    if model_path.suffix.lower() != ".urdf":
        raise ConfigError(f"capsules can be fitted to URDF meshes only, not '{model_path.name}'; give robot.capsules")
    try:
        root = ET.parse(model_path).getroot()
    except (ET.ParseError, OSError) as err:
        raise ConfigError(f"cannot read '{model_path}' to fit capsules: {err}") from err
    lines = [
        f"# Capsules fitted automatically by pe_drake to the meshes of {model_path.name}: one per link,",
        "# axis = principal axis of the link's collision (else visual) mesh vertices, radius covering",
        f"# {cover:.0%} of them, shortest segment containing them (pe_drake.multibody.capsule_fitting).",
        "# Check them in `pe-drake view` and edit as needed; give the edited file as robot.capsules.",
        "capsules:",
    ]
    fitted, skipped = [], {}
    for link in root.findall("link"):
        name = link.get("name", "")
        if links is not None and name not in links:
            continue
        points, files, reason = _link_points(link, model_path)
        if points is None:
            if link.find("collision") is not None or link.find("visual") is not None:
                skipped[name] = reason
            continue
        if len(points) < 4:
            skipped[name] = "fewer than 4 vertices"
            continue
        p0, p1, r = fit_capsule(points, cover=cover)
        xyz, rpy, length = capsule_pose(p0, p1)
        length = max(length, 1e-3)  # a sphere-like link: Drake needs a positive length
        radial = _radial_distance(points, p0, p1)
        lines.append(f"  # {', '.join(files)}: worst vertex {max(radial.max() - r, 0.0) * 1e3:.0f} mm out")
        lines.append(
            f"  - {{name: {name}, link: {name}, radius: {r:.4f}, length: {length:.4f},\n"
            f"     xyz: [{xyz[0]:.4f}, {xyz[1]:.4f}, {xyz[2]:.4f}], rpy: [{rpy[0]:.4f}, {rpy[1]:.4f}, {rpy[2]:.4f}]}}"
        )
        fitted.append(name)
    if not fitted:
        raise ConfigError(
            f"no link of '{model_path}' has a readable STL/OBJ mesh to fit capsules to "
            f"({'; '.join(f'{k}: {v}' for k, v in skipped.items()) or 'no meshes'}); give robot.capsules"
        )
    atomic_write_text(out_path, "\n".join(lines) + "\n")
    return FittedCapsules(Path(out_path), tuple(fitted), skipped)


def _radial_distance(points: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    d = p1 - p0
    L2 = max(float(d @ d), 1e-300)
    s = np.clip((points - p0) @ d / L2, 0.0, 1.0)
    return np.linalg.norm(points - (p0 + s[:, None] * d), axis=1)


def ensure_capsules(config, folder: str | Path) -> FittedCapsules | None:
    """Fits capsules when a config needs them (self-collision, the floor, boxes) but names no
    capsule file: writes ``folder/fitted_capsules.yaml`` and points ``config.robot.capsules``
    at it; pairs touching by design are ignored (:func:`ignore_touching_pairs`), and
    self-collision is switched on at ``FITTED_COLLISION_MARGIN`` when the config leaves it
    off. Does nothing when the robot has a capsule file or nothing needs one.

    Args:
        config: a :class:`~pe_drake.config.Config` (changed in place).
        folder: where to write the fitted file.

    Returns:
        What was fitted, or None.

    Raises:
        ConfigError: the model is not a URDF with readable meshes.
    """
    robot, env = config.robot, config.environment
    needs = config.excitation.collision_margin >= 0 or bool(env.boxes) or (env.floor and not robot.support_points)
    if robot.capsules or not needs or not robot.model:
        return None
    model = resolve_mesh_path(robot.model, Path(robot.model))
    if model is None:
        raise ConfigError(f"cannot find the model '{robot.model}' to fit capsules to; give robot.capsules")
    model = loadable_model_path(model, robot.packages)  # xacro expanded, robot.packages resolved
    fitted = fit_capsule_file(model, Path(folder) / FITTED_CAPSULES_NAME)
    robot.capsules = str(fitted.path)
    if config.excitation.collision_margin < 0:
        config.excitation.collision_margin = FITTED_COLLISION_MARGIN
    ignored = ignore_touching_pairs(config, fitted.path, config.excitation.collision_margin)
    return dataclasses.replace(fitted, ignored_pairs=tuple(ignored))


def ignore_touching_pairs(config, path: Path, margin: float, samples: int = 200, share: float = 0.95) -> list:
    """Adds to a capsule file's ``ignored_pairs`` the pairs that touch by design: closer than
    ``margin`` at the nominal posture, or in ``share`` of random postures within the limits
    (as MoveIt's set-up assistant disables "default" and "always" colliding pairs). Pairs on
    adjacent or welded links are filtered anyway (:func:`register_capsules`).

    Returns:
        The pairs added, as [capsule, capsule, reason].
    """
    robot = Robot("fit", config.robot)
    pairs = capsule_pairs(robot.scene_graph, robot.capsules)
    if not pairs:
        return []
    rng = np.random.default_rng(0)
    lim = robot.limits
    q = np.vstack([robot.nominal_posture(), rng.uniform(lim.q_lower, lim.q_upper, (samples, robot.n))])
    d = _pair_distances(robot, pairs, q)  # (1 + samples, P)
    added = []
    for p, (a, b) in enumerate(pairs):
        nominal, always = d[0, p] < margin, np.mean(d[1:, p] < margin) >= share
        if nominal or always:
            reason = "closer than the margin at the nominal posture" if nominal else (
                f"closer than the margin in {np.mean(d[1:, p] < margin):.0%} of random postures")
            added.append([robot.capsules[a].name, robot.capsules[b].name, reason])
    if added:
        lines = ["ignored_pairs:", "  # touching by design (pe_drake.multibody.capsule_fitting.ignore_touching_pairs)"]
        lines += [f"  - [{a}, {b}]  # {why}" for a, b, why in added]
        path.write_text(path.read_text() + "\n".join(lines) + "\n")
    return added


def _pair_distances(robot, pairs, q: np.ndarray) -> np.ndarray:
    """Surface distance of capsule pairs at postures q (K, n), shape (K, P) [m]."""
    caps = robot.capsules
    X = robot.body_poses(q)  # (K, bodies, 4, 4)
    ends = np.stack([X[:, c.body_index, None, :3, :3] @ c.p_BS[..., None] for c in caps], axis=1)[..., 0]
    ends = ends + np.stack([X[:, c.body_index, None, :3, 3] for c in caps], axis=1)  # (K, C, 2, 3)
    ia, ib = np.array(pairs).T
    a0, a1, b0, b1 = ends[:, ia, 0], ends[:, ia, 1], ends[:, ib, 0], ends[:, ib, 1]
    s, t = segment_closest_points(a0, a1, b0, b1)
    gap = (a0 + s[..., None] * (a1 - a0)) - (b0 + t[..., None] * (b1 - b0))
    radii = np.array([caps[i].radius + caps[j].radius for i, j in pairs])
    return np.linalg.norm(gap, axis=-1) - radii
