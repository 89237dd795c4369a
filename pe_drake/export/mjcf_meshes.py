"""The robot's visuals in an MJCF: its illustration geometry as MuJoCo geoms, meshes copied into a
folder beside the file.

Each mesh is checked again by the read policy (:mod:`pe_drake.multibody.mesh_policy`): STL and OBJ
files are copied, COLLADA converted to OBJ as its vertices are written (the ROS convention), other
formats left out with a note. Geoms are visual only (``contype``/``conaffinity`` 0, group 1).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from typing import TYPE_CHECKING

from pe_drake.exceptions import DataError
from pe_drake.export.tree import vector_text
from pe_drake.multibody.mesh_policy import mesh_file_refusal
from pe_drake.multibody.meshes import obj_text, read_dae_triangles

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Mesh formats MuJoCo reads as they are.
COPIED_SUFFIXES = (".stl", ".obj")


def _mesh_bytes(path: Path) -> tuple[bytes | None, str, str]:
    """(content, suffix written, note) of one mesh file: copied, converted or refused."""
    refusal = mesh_file_refusal(path)
    if refusal:
        return None, "", f"visual left out: {refusal}"
    suffix = path.suffix.lower()
    if suffix in COPIED_SUFFIXES:
        return path.read_bytes(), suffix, ""
    if suffix == ".dae":
        try:
            return obj_text(read_dae_triangles(path), f"{path.name} (pe-drake export)").encode(), ".obj", ""
        except DataError as err:
            return None, "", f"visual left out: {err}"
    return None, "", f"visual left out: MuJoCo does not read '{path.name}' ({suffix}) and pe_drake does not convert it"


def _primitive(shape) -> tuple[str, list[float]] | None:
    """(MuJoCo geom type, size) of a Drake primitive shape, or None."""
    kind = type(shape).__name__
    if kind == "Box":
        return "box", [shape.width() / 2, shape.depth() / 2, shape.height() / 2]
    if kind == "Sphere":
        return "sphere", [shape.radius()]
    if kind in ("Cylinder", "Capsule"):
        return kind.lower(), [shape.radius(), shape.length() / 2]
    return None


def add_visuals(robot: Robot, bodies: dict[str, ET.Element], asset: ET.Element) -> tuple[dict[str, bytes], list[str]]:
    """Adds the robot's visual geoms to the MJCF ``bodies`` {name: element} and meshes to ``asset``;
    returns ({file name: content} of the mesh folder, notes on what was left out)."""
    from pydrake.geometry import Role  # lazy: pydrake is heavy

    plant, inspector = robot.plant, robot.scene_graph.model_inspector()
    files: dict[str, bytes] = {}
    notes: list[str] = []
    converted: dict[str, str] = {}  # source path -> file name (a mesh used twice is written once)
    for name, element in bodies.items():
        frame = plant.GetBodyFrameIdIfExists(plant.GetBodyByName(name).index())
        if frame is None:
            continue
        for k, geometry in enumerate(inspector.GetGeometries(frame, Role.kIllustration)):
            shape, X = inspector.GetShape(geometry), inspector.GetPoseInFrame(geometry)
            attributes = {"pos": vector_text(X.translation()), "quat": vector_text(X.rotation().ToQuaternion().wxyz()),
                          "contype": "0", "conaffinity": "0", "group": "1"}
            primitive = _primitive(shape)
            if primitive is not None:
                attributes.update(type=primitive[0], size=vector_text(primitive[1]))
            elif type(shape).__name__ in ("Mesh", "Convex"):
                source = Path(shape.source().path())
                if str(source) not in converted:
                    content, suffix, note = _mesh_bytes(source)
                    if content is None:
                        notes.append(f"{name}: {note}")
                        continue
                    converted[str(source)] = f"{name}_{k}{suffix}"
                    files[converted[str(source)]] = content
                mesh_name = f"{name}_{k}"  # one asset per geom: each has its own scale
                ET.SubElement(asset, "mesh", {"name": mesh_name, "file": converted[str(source)],
                                              "scale": vector_text(shape.scale3())})
                attributes.update(type="mesh", mesh=mesh_name)
            else:
                notes.append(f"{name}: a visual {type(shape).__name__} is left out")
                continue
            ET.SubElement(element, "geom", attributes)
    return files, notes
