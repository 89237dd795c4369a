"""STL reading, OBJ writing and the URDF visual rewrite of pe_drake.multibody.meshes."""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np
import pytest

from pe_drake.exceptions import DataError
from pe_drake.multibody.meshes import (
    CACHE_ENV,
    TriangleMesh,
    obj_text,
    read_stl,
    stl_to_obj,
    stl_visuals_to_obj,
)

# A tetrahedron, counter-clockwise seen from outside.
TETRA_V = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.2, 0.0], [0.0, 0.0, 0.3]])
TETRA_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def write_binary_stl(path: Path, corners: np.ndarray, header: bytes = b"solid but binary") -> Path:
    dtype = np.dtype([("normal", "<f4", (3,)), ("vertices", "<f4", (3, 3)), ("attribute", "<u2")])
    facets = np.zeros(len(corners), dtype)
    facets["vertices"] = corners
    path.write_bytes(header.ljust(80, b" ") + np.uint32(len(corners)).tobytes() + facets.tobytes())
    return path


def write_ascii_stl(path: Path, corners: np.ndarray) -> Path:
    lines = ["solid tetra"]
    for tri in corners:
        lines += ["  facet normal 0 0 0", "    outer loop"]
        lines += [f"      vertex {x:.9g} {y:.9g} {z:.9g}" for x, y, z in tri]
        lines += ["    endloop", "  endfacet"]
    path.write_text("\n".join(lines + ["endsolid tetra", ""]))
    return path


def triangles(mesh: TriangleMesh) -> set:
    """Each triangle as a rotation-normalized tuple of rounded corners (orientation kept)."""
    out = set()
    for face in mesh.faces:
        corners = [tuple(float(x) for x in np.round(mesh.vertices[i], 6)) for i in face]
        k = corners.index(min(corners))
        out.add(tuple(corners[k:] + corners[:k]))
    return out


def parse_obj(text: str) -> TriangleMesh:
    v = np.array([line.split()[1:] for line in text.splitlines() if line.startswith("v ")], float)
    f = np.array([line.split()[1:] for line in text.splitlines() if line.startswith("f ")], int) - 1
    return TriangleMesh(v, f)


@pytest.fixture
def cache(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv(CACHE_ENV, str(folder))
    return folder


def test_binary_stl_with_solid_header_is_read_as_binary(tmp_path):
    path = write_binary_stl(tmp_path / "t.stl", TETRA_V[TETRA_F])
    mesh = read_stl(path)
    assert mesh.vertices.shape == (4, 3) and mesh.faces.shape == (4, 3)
    assert triangles(mesh) == triangles(TriangleMesh(TETRA_V, TETRA_F))


def test_ascii_stl_equals_binary(tmp_path):
    corners = TETRA_V[TETRA_F]
    ascii_mesh = read_stl(write_ascii_stl(tmp_path / "a.stl", corners))
    binary_mesh = read_stl(write_binary_stl(tmp_path / "b.stl", corners))
    assert triangles(ascii_mesh) == triangles(binary_mesh)


def test_degenerate_triangles_are_dropped(tmp_path):
    corners = np.concatenate([TETRA_V[TETRA_F], TETRA_V[[[0, 0, 1]]]])
    assert read_stl(write_binary_stl(tmp_path / "d.stl", corners)).faces.shape == (4, 3)


def test_obj_round_trip_keeps_triangles_and_orientation(tmp_path):
    mesh = read_stl(write_binary_stl(tmp_path / "t.stl", TETRA_V[TETRA_F]))
    back = parse_obj(obj_text(mesh, "tetra"))
    assert triangles(back) == triangles(mesh)
    # Outward normals: the signed volume of a closed, outward-oriented mesh is positive.
    a, b, c = (back.vertices[back.faces[:, k]] for k in range(3))
    assert np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6 == pytest.approx(0.1 * 0.2 * 0.3 / 6)


@pytest.mark.parametrize(
    "content, message",
    [(b"", "not an STL file"), (b"\x00" * 83, "not an STL file"), (b"hello world" * 20, "not an STL")],
)
def test_malformed_stl_raises_data_error(tmp_path, content, message):
    path = tmp_path / "bad.stl"
    path.write_bytes(content)
    with pytest.raises(DataError, match=message) as err:
        read_stl(path)
    assert str(path) in str(err.value)


def test_missing_stl_raises_data_error(tmp_path):
    with pytest.raises(DataError, match="cannot read"):
        read_stl(tmp_path / "none.stl")


def test_stl_to_obj_converts_once(tmp_path, cache):
    stl = write_binary_stl(tmp_path / "part.stl", TETRA_V[TETRA_F])
    obj = stl_to_obj(stl)
    assert obj.parent.parent == cache and obj.name == "part.obj"
    stamp = obj.stat().st_mtime_ns
    time.sleep(0.01)
    assert stl_to_obj(stl) == obj and obj.stat().st_mtime_ns == stamp  # reused, not rewritten
    write_binary_stl(stl, TETRA_V[TETRA_F] * 2)  # changed content: a new cache entry
    assert stl_to_obj(stl) != obj
    assert not list(cache.rglob("*.tmp"))


URDF = """<robot name="r">
  <link name="a">
    <visual><geometry><mesh filename="../meshes/part.stl" scale="0.001 0.001 0.001"/></geometry></visual>
    <collision><geometry><mesh filename="../meshes/part.stl"/></geometry></collision>
  </link>
  <link name="b">
    <visual><geometry><mesh filename='package://my_pkg/meshes/part.STL'/></geometry></visual>
    <visual><geometry><mesh filename="../meshes/look.dae"/></geometry></visual>
    <visual><geometry><mesh filename="../meshes/missing.stl"/></geometry></visual>
  </link>
</robot>"""


def test_urdf_visuals_rewritten_collisions_untouched(tmp_path, cache):
    pkg = tmp_path / "src" / "robot"
    (pkg / "meshes").mkdir(parents=True)
    (pkg / "urdf").mkdir()
    (pkg / "package.xml").write_text("<package><name>my_pkg</name></package>")
    write_binary_stl(pkg / "meshes" / "part.stl", TETRA_V[TETRA_F])
    write_binary_stl(pkg / "meshes" / "part.STL", TETRA_V[TETRA_F])
    model = pkg / "urdf" / "r.urdf"
    text = URDF
    model.write_text(text)

    out = stl_visuals_to_obj(text, model)
    visuals = re.findall(r"<visual>.*?</visual>", out, re.S)
    names = [re.search(r"filename=[\"'](.*?)[\"']", v).group(1) for v in visuals]
    assert names[0].startswith("file://") and names[0].endswith("/part.obj")
    assert 'scale="0.001 0.001 0.001"' in visuals[0]
    assert names[1].startswith("file://") and names[1].endswith("/part.obj")
    assert names[2] == "../meshes/look.dae"  # not an STL
    assert names[3] == "../meshes/missing.stl"  # not found: left for Drake to report
    collision = re.search(r"<collision>.*?</collision>", out, re.S).group(0)
    assert 'filename="../meshes/part.stl"' in collision
    assert Path(names[0][len("file://") :]).is_file()


def test_g1_visuals_convert_and_parse(cache):
    """Every STL visual of G1 becomes an OBJ that Drake parses and Meshcat can draw."""
    from pydrake.geometry import Mesh, Role

    from pe_drake.multibody.registry import example_robot_data_dir
    from pe_drake.multibody.robot import load_robot

    urdf = example_robot_data_dir() / "robots/g1_description/urdf/g1_29dof_rev_1_0.urdf"
    text = urdf.read_text()
    start = time.perf_counter()
    out = stl_visuals_to_obj(text, urdf)
    first = time.perf_counter() - start
    start = time.perf_counter()
    assert stl_visuals_to_obj(text, urdf) == out
    again = time.perf_counter() - start
    visuals = re.findall(r"<visual\b.*?</visual>", out, re.S)
    assert visuals and all(".obj" in v and ".STL" not in v for v in visuals)
    assert out.count(".STL") == text.count(".STL") - len(visuals)  # collisions keep their STL
    objs = sorted(cache.rglob("*.obj"))
    print(
        f"\nG1: {len(visuals)} visuals, {len(objs)} OBJ files, "
        f"{sum(p.stat().st_size for p in objs) / 1e6:.1f} MB; convert {first:.2f} s, "
        f"cached {again:.3f} s"
    )

    # One mesh checked against its STL: same bounding box to the OBJ's 6 digits.
    pelvis = next(p for p in objs if p.name == "pelvis.obj")
    stl = read_stl(urdf.parent.parent / "meshes" / "pelvis.STL")
    obj = parse_obj(pelvis.read_text())
    assert obj.faces.shape == stl.faces.shape
    np.testing.assert_allclose(obj.vertices.min(0), stl.vertices.min(0), atol=1e-6)
    np.testing.assert_allclose(obj.vertices.max(0), stl.vertices.max(0), atol=1e-6)

    robot = load_robot("g1", obj_visuals=True)
    inspector = robot.scene_graph.model_inspector()
    shapes = [inspector.GetShape(g) for g in inspector.GetAllGeometryIds(Role.kIllustration)]
    meshes = [s for s in shapes if isinstance(s, Mesh)]
    assert len(meshes) == len(visuals)
    assert all(m.extension() == ".obj" for m in meshes)
