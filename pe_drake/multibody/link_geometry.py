"""The collision and visual shapes of a URDF's or SDF's links, in each link's frame.

:func:`read_link_shapes` lists, per link, every ``<collision>`` and ``<visual>`` element as a
:class:`Shape` (a mesh, or a cylinder, sphere, box or capsule); nothing is loaded here. SDF: a
shape's ``<pose>`` is taken in the link frame, and ``model://`` URIs are read as ``package://``.
"""

from __future__ import annotations

import dataclasses
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from pe_drake.exceptions import ConfigError
from pe_drake.multibody.urdf_checks import urdf_tree


@dataclasses.dataclass(frozen=True)
class Shape:
    """One collision or visual shape of a link."""

    link: str
    tag: str  # "collision" or "visual"
    kind: str  # "mesh", "cylinder", "sphere", "box" or "capsule"
    X_LG: np.ndarray  # pose of the shape's frame G in the link frame L, (4, 4) [m]
    # cylinder/capsule (radius, length), sphere (radius,), box (x, y, z) edges [m]; mesh: ()
    size: tuple[float, ...] = ()
    filename: str = ""  # a mesh's file name or URI as written
    scale: np.ndarray = dataclasses.field(default_factory=lambda: np.ones(3))

    def describe(self) -> str:
        """A short label: the mesh file name, or the primitive with its size."""
        if self.kind == "mesh":
            return f"mesh '{self.filename}'"
        return f"{self.kind}({', '.join(f'{s:g}' for s in self.size)})"


def rotation_rpy(rpy) -> np.ndarray:
    """R = Rz(yaw)·Ry(pitch)·Rx(roll), the URDF/SDF fixed-axis roll-pitch-yaw, shape (3, 3)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _transform(xyz, rpy) -> np.ndarray:
    X = np.eye(4)
    X[:3, :3] = rotation_rpy(rpy)
    X[:3, 3] = xyz
    return X


def _numbers(text: str | None, count: int, default: float) -> list[float]:
    if not text or not text.split():
        return [default] * count
    values = [float(x) for x in text.split()]
    return values if len(values) == count else values[:1] * count


def read_link_shapes(model_path: str | Path) -> dict[str, list[Shape]]:
    """The shapes of every link of a URDF or SDF file, {link: shapes} in file order.

    ConfigError for another format, unreadable XML, or a size that is not a number."""
    model_path = Path(model_path)
    suffix = model_path.suffix.lower()
    if suffix not in (".urdf", ".sdf"):
        raise ConfigError(f"link shapes are read from URDF and SDF files, not '{model_path.name}'")
    try:
        # a URDF as Drake reads it (its DOCTYPE's entities not expanded); SDF as XML
        root = urdf_tree(model_path.read_text()) if suffix == ".urdf" else ET.parse(model_path).getroot()
    except (ET.ParseError, OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"cannot read '{model_path}' to fit capsules: {err}") from err
    reader = _urdf_shape if suffix == ".urdf" else _sdf_shape
    out: dict[str, list[Shape]] = {}
    for link in root.findall("link") if suffix == ".urdf" else root.iter("link"):
        name = link.get("name", "")
        shapes = out.setdefault(name, [])
        for tag in ("collision", "visual"):
            for element in link.findall(tag):
                try:
                    shape = reader(name, tag, element)
                except ValueError as err:
                    raise ConfigError(f"'{model_path}': link '{name}': bad <{tag}> geometry: {err}") from err
                if shape is not None:
                    shapes.append(shape)
    return out


def _urdf_shape(link: str, tag: str, element: ET.Element) -> Shape | None:
    origin = element.find("origin")
    X = _transform(
        _numbers(origin.get("xyz") if origin is not None else None, 3, 0.0),
        _numbers(origin.get("rpy") if origin is not None else None, 3, 0.0),
    )
    return _shape(link, tag, X, element.find("geometry"), lambda g, key: g.get(key))  # URDF: attributes


def _sdf_shape(link: str, tag: str, element: ET.Element) -> Shape | None:
    pose = _numbers(element.findtext("pose"), 6, 0.0)
    return _shape(link, tag, _transform(pose[:3], pose[3:]), element.find("geometry"),
                  lambda g, key: g.findtext(key))  # SDFormat: child elements


def _shape(link: str, tag: str, X, geometry: ET.Element | None, value) -> Shape | None:
    """The :class:`Shape` of a ``<geometry>`` element (None: none or of another kind); ``value(g,
    key)`` reads a shape's ``filename``/``uri``, ``scale``, ``radius``, ``length`` or ``size``."""
    if geometry is None or len(geometry) == 0:
        return None
    g = geometry[0]

    def size(key: str) -> float:
        text = value(g, key)
        if text is None:  # float(None) is a TypeError: the caller names link and file for a ValueError
            raise ValueError(f"<{g.tag}> has no {key}")
        return float(text)

    if g.tag == "mesh":
        uri = (value(g, "filename") or value(g, "uri") or "").strip()
        if uri.startswith("model://"):
            uri = "package://" + uri[len("model://") :]
        return Shape(link, tag, "mesh", X, filename=uri, scale=np.asarray(_numbers(value(g, "scale"), 3, 1.0)))
    if g.tag in ("cylinder", "capsule"):
        return Shape(link, tag, g.tag, X, (size("radius"), size("length")))
    if g.tag == "sphere":
        return Shape(link, tag, "sphere", X, (size("radius"),))
    if g.tag == "box":
        return Shape(link, tag, "box", X, tuple(_numbers(value(g, "size"), 3, 0.0)))
    return None


def primitive_segment(shape: Shape) -> tuple[np.ndarray, np.ndarray, float]:
    """(p0, p1, radius) [m] of the smallest capsule along the primitive's own axis that encloses
    it, in the link frame.

    A cylinder or capsule keeps its radius, axis and length; a sphere is a zero-length capsule;
    a box becomes the capsule along its longest edge whose end circles hold its corners.
    """
    R, p = shape.X_LG[:3, :3], shape.X_LG[:3, 3]
    if shape.kind in ("cylinder", "capsule"):
        r, length = shape.size
        axis, half = R[:, 2], 0.5 * length
    elif shape.kind == "sphere":
        r, axis, half = shape.size[0], R[:, 2], 0.0
    elif shape.kind == "box":
        size = np.abs(np.asarray(shape.size, float))
        k = int(np.argmax(size))
        others = np.delete(size, k)
        r, axis, half = 0.5 * float(np.hypot(*others)), R[:, k], 0.5 * size[k]
    else:
        raise ValueError(f"not a primitive: {shape.kind}")
    return p - half * axis, p + half * axis, float(r)


def primitive_points(shape: Shape, count: int = 16) -> np.ndarray:
    """Points holding the primitive's extremes (box corners, cylinder rims, sphere poles and
    equator), in the link frame, shape (N, 3) [m]."""
    R, p = shape.X_LG[:3, :3], shape.X_LG[:3, 3]
    a = np.linspace(0.0, 2 * np.pi, count, endpoint=False)
    ring = np.c_[np.cos(a), np.sin(a), np.zeros_like(a)]
    if shape.kind == "box":
        h = 0.5 * np.abs(np.asarray(shape.size, float))
        local = np.array([[x, y, z] for x in (-h[0], h[0]) for y in (-h[1], h[1]) for z in (-h[2], h[2])])
    elif shape.kind == "sphere":
        r = shape.size[0]
        local = r * np.vstack([ring, ring[:, [0, 2, 1]], ring[:, [2, 0, 1]]])
    else:  # cylinder, capsule
        r, length = shape.size
        cap = r if shape.kind == "capsule" else 0.0
        local = np.vstack([r * ring + [0, 0, -0.5 * length], r * ring + [0, 0, 0.5 * length]])
        local = np.vstack([local, [[0, 0, -0.5 * length - cap], [0, 0, 0.5 * length + cap]]])
    return local @ R.T + p
