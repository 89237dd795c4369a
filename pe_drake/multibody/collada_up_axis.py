"""Which way is up in a robot's COLLADA meshes: as written, or turned by their ``<up_axis>``.

ROS tools ignore a ``.dae`` file's ``<up_axis>``, while Assimp-based tools turn a ``Y_UP`` mesh
(iCub's meshes are drawn for that). So the choice is made per model (:func:`honors_up_axis`):
the way that puts more of the links' own points inside their meshes' bounding boxes wins.
"""

from __future__ import annotations

import functools
import hashlib
import re
from pathlib import Path

import numpy as np

from pe_drake.multibody.link_geometry import read_link_shapes
from pe_drake.multibody.meshes import (TriangleMesh, default_cache_dir, read_dae_triangles,
                                       read_mesh_vertices, resolve_mesh_path, rewrite_visual_meshes,
                                       write_obj)
from pe_drake.multibody.urdf_checks import urdf_tree

#: Slack of a mesh's bounding box when counting the link points it holds [m].
BOX_MARGIN = 0.01
#: Turning the meshes must hold this many more link points than not turning them, and this
#: share of them more; otherwise the model keeps the ROS convention.
MIN_GAIN_POINTS = 3
MIN_GAIN_SHARE = 0.2

_UP_AXIS = re.compile(rb"<up_axis>\s*([XYZ]_UP)\s*</up_axis>")


def up_axis(path: str | Path) -> str:
    """The ``<up_axis>`` of a COLLADA file ("X_UP", "Y_UP" or "Z_UP"; COLLADA's default Y_UP)."""
    with open(path, "rb") as f:
        head = f.read(8192)  # the tag is in <asset>, at the top
    match = _UP_AXIS.search(head)
    return match.group(1).decode() if match else "Y_UP"


def to_z_up(vertices: np.ndarray, axis: str) -> np.ndarray:
    """Vertices (V, 3) of a mesh whose up axis is ``axis``, turned so that it points along z
    (Y_UP: (x, y, z) → (x, −z, y); X_UP: → (−z, y, x))."""
    v = np.asarray(vertices, float)
    if axis == "Y_UP":
        return np.column_stack([v[:, 0], -v[:, 2], v[:, 1]])
    if axis == "X_UP":
        return np.column_stack([-v[:, 2], v[:, 1], v[:, 0]])
    return v


def oriented_vertices(path: str | Path, model_path: str | Path) -> np.ndarray:
    """A mesh's vertices (V, 3) the way ``model_path`` means them (see :func:`honors_up_axis`)."""
    v = read_mesh_vertices(path)
    if Path(path).suffix.lower() == ".dae" and honors_up_axis(str(model_path)):
        return to_z_up(v, up_axis(path))
    return v


@functools.lru_cache(maxsize=32)
def honors_up_axis(model_path: str) -> bool:
    """Whether this model's COLLADA meshes are meant turned by their ``<up_axis>``."""
    raw, turned, points = link_points_inside(model_path)
    return turned >= raw + max(MIN_GAIN_POINTS, MIN_GAIN_SHARE * points)


def up_axis_note(model_path: str | Path) -> str | None:
    """The line saying that the meshes are read turned, or None when they are read as written."""
    if not honors_up_axis(str(model_path)):
        return None
    raw, turned, points = link_points_inside(str(model_path))
    return (f"COLLADA meshes read turned by their <up_axis>: their links' centres of mass and joints lie inside "
            f"them ({turned} of {points} points; {raw} as written)")


@functools.lru_cache(maxsize=32)
def link_points_inside(model_path: str) -> tuple[int, int, int]:
    """(link points inside the Y_UP/X_UP COLLADA meshes as written, turned, points counted).

    Per link its first collision (else visual) such mesh, in the link frame."""
    path = Path(model_path)
    if path.suffix.lower() != ".urdf":
        return 0, 0, 0
    try:
        tree = urdf_tree(path.read_text())
        shapes = read_link_shapes(path)
    except Exception:  # noqa: BLE001 (the loader reports a bad model; here it only means "no choice")
        return 0, 0, 0
    own: dict[str, list[np.ndarray]] = {}
    for joint in tree.findall("joint"):
        if joint.find("parent") is not None:
            own.setdefault(joint.find("parent").get("link"), []).append(_xyz(joint.find("origin")))
    for link in tree.findall("link"):
        if link.find("inertial") is not None:
            own.setdefault(link.get("name"), []).append(_xyz(link.find("inertial").find("origin")))
    raw = turned = points = 0
    for name, link_shapes in shapes.items():
        found = _first_mesh_with_up_axis(link_shapes, path)
        if found is None or not own.get(name):
            continue
        mesh, shape, axis = found
        try:
            v = read_mesh_vertices(mesh) * shape.scale
        except Exception:  # noqa: BLE001 (an unreadable mesh is reported where it is used)
            continue
        raw += _inside(v, shape, own[name])
        turned += _inside(to_z_up(v, axis), shape, own[name])
        points += len(own[name])
    return raw, turned, points


def _first_mesh_with_up_axis(link_shapes, model_path: Path):
    """(file, shape, axis) of a link's first DAE mesh that says Y_UP or X_UP, or None."""
    chosen = [s for s in link_shapes if s.tag == "collision"] or [s for s in link_shapes if s.tag == "visual"]
    for s in chosen:
        if s.kind == "mesh" and s.filename.lower().endswith(".dae"):
            mesh = resolve_mesh_path(s.filename, model_path)
            if mesh is not None and (axis := up_axis(mesh)) != "Z_UP":
                return mesh, s, axis
    return None


def _inside(vertices: np.ndarray, shape, points: list[np.ndarray]) -> int:
    w = vertices @ shape.X_LG[:3, :3].T + shape.X_LG[:3, 3]
    lo, hi = w.min(axis=0) - BOX_MARGIN, w.max(axis=0) + BOX_MARGIN
    return sum(bool(np.all(p >= lo) and np.all(p <= hi)) for p in points)


def _xyz(origin) -> np.ndarray:
    return np.array([float(x) for x in origin.get("xyz", "0 0 0").split()]) if origin is not None else np.zeros(3)


def turned_dae_visuals(urdf_text: str, model_path: str | Path, packages: dict | None = None,
                       cache_dir: str | Path | None = None) -> str:
    """The URDF text with its ``<visual>`` DAE meshes replaced by turned OBJ copies (cached by
    content) when :func:`honors_up_axis`; else the text unchanged."""
    if not honors_up_axis(str(model_path)):
        return urdf_text

    def convert(source: Path) -> Path:
        data = source.read_bytes()
        digest = hashlib.blake2b(data, digest_size=8).hexdigest()
        target = Path(cache_dir or default_cache_dir()) / digest / f"{source.stem}.turned.obj"
        if not target.is_file():
            mesh = read_dae_triangles(source)
            write_obj(target, TriangleMesh(to_z_up(mesh.vertices, up_axis(source)), mesh.faces),
                      comment=f"converted by pe_drake from {source.name}, turned by its <up_axis>")
        return target

    return rewrite_visual_meshes(urdf_text, model_path, ".dae", convert, packages)
