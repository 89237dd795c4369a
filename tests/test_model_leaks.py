"""No file outside a model's folder and packages reaches playback.html, whatever spelling the
model uses for it (issue 34): XML character references, a mesh's own references (OBJ mtllib,
glTF uri), a package:// path climbing out of its package, an SDF <uri>, a material texture, the
meshes of an expanded xacro. Each case draws the model in Meshcat and looks for the canary in
the static HTML: raw, URL-decoded and base64-decoded."""

from __future__ import annotations

import base64
import binascii
import json
import os
import re
import subprocess
import sys
import urllib.parse
from pathlib import Path

import numpy as np
import pytest

from pe_drake.multibody.meshes import TriangleMesh, obj_text
from pe_drake.multibody.robot import load_robot

ROOT = Path(__file__).resolve().parents[1]
CANARY = "CANARY-5e1f-not-for-html"
INERTIAL = '<inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>'
TRIANGLE = obj_text(TriangleMesh(np.eye(3), np.array([[0, 1, 2]])))


def _urdf(visual: str, material: str = "") -> str:
    return f"""<?xml version="1.0"?>
<robot name="r">
  {material}
  <link name="base">{INERTIAL}</link>
  <link name="l1">{INERTIAL}<visual><geometry>{visual}</geometry>{'<material name="m"/>' if material else ''}</visual></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" velocity="1" effort="1"/></joint>
</robot>
"""


def _sdf(uri: str) -> str:
    return f"""<?xml version="1.0"?>
<sdf version="1.7"><model name="r">
  <link name="base"><inertial><mass>1</mass></inertial></link>
  <link name="l1"><inertial><mass>1</mass></inertial>
    <visual name="v"><geometry><mesh><uri>{uri}</uri></mesh></geometry></visual></link>
  <joint name="j1" type="revolute"><parent>base</parent><child>l1</child>
    <axis><xyz>0 0 1</xyz><limit><lower>-1</lower><upper>1</upper><effort>1</effort><velocity>1</velocity></limit></axis></joint>
</model></sdf>
"""


@pytest.fixture
def layout(tmp_path):
    secret = tmp_path / "secret"
    secret.mkdir()
    (secret / "id_rsa").write_text(CANARY)
    (secret / "cad.obj").write_text(f"# {CANARY}\n{TRIANGLE}")
    (secret / "leak.png").write_bytes(b"\x89PNG\r\n\x1a\n" + CANARY.encode())
    model = tmp_path / "arm"
    (model / "meshes").mkdir(parents=True)
    (model / "package.xml").write_text("<package><name>arm</name></package>")
    (model / "meshes" / "good.obj").write_text(TRIANGLE)
    return tmp_path, model, secret


def _html(model_path) -> str:
    from pydrake.geometry import Meshcat, MeshcatVisualizer, MeshcatVisualizerParams, Role

    meshcat = Meshcat()

    def hook(builder, plant, scene_graph):
        MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, MeshcatVisualizerParams(role=Role.kIllustration))

    robot = load_robot(str(model_path), obj_visuals=True, builder_hook=hook)
    context = robot.diagram.CreateDefaultContext()
    robot.diagram.ForcedPublish(context)
    return meshcat.StaticHtml()


def _assert_no_canary(html: str) -> None:
    assert CANARY not in html
    assert CANARY not in urllib.parse.unquote(html)
    for chunk in re.findall(r"[A-Za-z0-9+/]{24,}={0,2}", html):
        try:
            decoded = base64.b64decode(chunk + "=" * (-len(chunk) % 4))
        except (binascii.Error, ValueError):
            continue
        assert CANARY.encode() not in decoded


def _write(model, name: str, text: str):
    path = model / name
    path.write_text(text)
    return path


CASES = {
    "character reference in file://": lambda m, s: _write(m, "r.urdf", _urdf(
        f'<mesh filename="file://{s}/cad&#46;obj"/>')),
    "hex character references in a relative name": lambda m, s: _write(m, "r.urdf", _urdf(
        '<mesh filename="&#x2e;&#x2e;/secret/cad.obj"/>')),
    "obj mtllib": lambda m, s: (
        _write(m / "meshes", "lib.obj", f"mtllib ../../secret/id_rsa\n{TRIANGLE}"),
        _write(m, "r.urdf", _urdf('<mesh filename="meshes/lib.obj"/>')))[1],
    "obj mtllib map_Kd": lambda m, s: (
        _write(m / "meshes", "lib.mtl", "newmtl a\nKd 1 1 1\nmap_Kd ../../secret/leak.png\n"),
        _write(m / "meshes", "lib.obj", f"mtllib lib.mtl\nusemtl a\n{TRIANGLE}"),
        _write(m, "r.urdf", _urdf('<mesh filename="meshes/lib.obj"/>')))[2],
    "gltf buffer uri": lambda m, s: (
        _write(m / "meshes", "g.gltf", json.dumps({"asset": {"version": "2.0"}, "buffers": [
            {"uri": "../../secret/id_rsa", "byteLength": len(CANARY)}]})),
        _write(m, "r.urdf", _urdf('<mesh filename="meshes/g.gltf"/>')))[1],
    "package path climbing out": lambda m, s: _write(m, "r.urdf", _urdf(
        '<mesh filename="package://arm/../secret/cad.obj"/>')),
    "percent-encoded file uri": lambda m, s: _write(m, "r.urdf", _urdf(
        f'<mesh filename="file://{s}/cad%2Eobj"/>')),
    "percent-encoded package climb": lambda m, s: _write(m, "r.urdf", _urdf(
        '<mesh filename="package://arm/%2E%2E/secret/cad.obj"/>')),
    "file uri with a host": lambda m, s: _write(m, "r.urdf", _urdf(
        f'<mesh filename="file://localhost{s}/cad.obj"/>')),
    "upper-case scheme": lambda m, s: _write(m, "r.urdf", _urdf(
        f'<mesh filename="FILE://{s}/cad.obj"/>')),
    "decoy attribute": lambda m, s: _write(m, "r.urdf", _urdf(
        f'<mesh data-filename="meshes/good.obj" filename="file://{s}/cad.obj"/>')),
    "closing tag with a space": lambda m, s: _write(m, "r.urdf", _urdf(
        f'<mesh filename="{s}/cad.obj"/>').replace("</visual>", "</visual >")),
    "sdf uri": lambda m, s: _write(m, "r.sdf", _sdf(f"file://{s}/cad.obj")),
    "texture": lambda m, s: _write(m, "r.urdf", _urdf(
        '<mesh filename="meshes/good.obj"/>',
        '<material name="m"><texture filename="../secret/leak.png"/></material>')),
    "expanded xacro": lambda m, s: _write(m, "r.urdf.xacro", _urdf(
        '<mesh filename="../secret/cad.obj"/>').replace('<robot name="r">',
        '<robot name="r" xmlns:xacro="http://www.ros.org/wiki/xacro">')),
}


@pytest.mark.parametrize("case", CASES)
def test_no_canary_in_playback(layout, case, monkeypatch):
    tmp, model, secret = layout
    monkeypatch.setenv("PE_DRAKE_MESH_CACHE", str(tmp / "cache"))
    path = CASES[case](model, secret)
    try:
        html = _html(path)
    except Exception as err:  # a refusal is fine too, if it does not quote the canary
        assert CANARY not in str(err)
        return
    _assert_no_canary(html)


def test_sdf_with_relative_mesh_uri_loads(layout):
    _, model, _ = layout
    robot = load_robot(str(_write(model, "r.sdf", _sdf("meshes/good.obj"))), obj_visuals=True)
    assert robot.joint_names == ("j1",)


BOUNDED = """
import resource, sys, time
resource.setrlimit(resource.RLIMIT_AS, (2**30, 2**30))  # 1 GB: /dev/zero read whole would exceed it
from pydrake.geometry import Meshcat, MeshcatVisualizer, MeshcatVisualizerParams, Role
from pe_drake.multibody.robot import load_robot
start = time.perf_counter()
meshcat = Meshcat()
hook = lambda builder, plant, sg: MeshcatVisualizer.AddToBuilder(builder, sg, meshcat, MeshcatVisualizerParams(role=Role.kIllustration))
robot = load_robot(sys.argv[1], obj_visuals=True, builder_hook=hook)
robot.diagram.ForcedPublish(robot.diagram.CreateDefaultContext())  # Meshcat reads what the meshes name here
meshcat.StaticHtml()
print("\\n".join(robot.notes))
print(f"seconds {time.perf_counter() - start:.2f}")
"""

HANGS = {
    "obj mtllib fifo": lambda m, s: (
        _write(m / "meshes", "lib.obj", f"mtllib pipe.mtl\n{TRIANGLE}"), os.mkfifo(m / "meshes" / "pipe.mtl"),
        _write(m, "r.urdf", _urdf('<mesh filename="meshes/lib.obj"/>')))[2],
    "gltf uri dev zero": lambda m, s: (
        os.symlink("/dev/zero", m / "meshes" / "zero.bin"),
        _write(m / "meshes", "g.gltf", json.dumps({"asset": {"version": "2.0"}, "buffers": [
            {"uri": "zero.bin", "byteLength": 2**40}]})),
        _write(m, "r.urdf", _urdf('<mesh filename="meshes/g.gltf"/>')))[2],
    "sdf uri fifo": lambda m, s: (
        os.mkfifo(m / "meshes" / "pipe.obj"), _write(m, "r.sdf", _sdf("meshes/pipe.obj")))[1],
    "texture fifo": lambda m, s: (
        os.mkfifo(m / "meshes" / "pipe.png"),
        _write(m, "r.urdf", _urdf('<mesh filename="meshes/good.obj"/>',
                                  '<material name="m"><texture filename="meshes/pipe.png"/></material>')))[1],
}


@pytest.mark.parametrize("case", HANGS)
def test_pipes_and_devices_named_by_a_model_end_quickly(layout, case, monkeypatch):
    """Each case runs in a child limited to 1 GB and 30 s: a hang or a read of /dev/zero fails
    the test instead of the suite."""
    tmp, model, secret = layout
    path = HANGS[case](model, secret)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PE_DRAKE_MESH_CACHE": str(tmp / "cache")}
    done = subprocess.run([sys.executable, "-c", BOUNDED, str(path)], capture_output=True, text=True, timeout=30,
                          env=env, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    assert re.search("not a regular file|is not a .* file: only", done.stdout), done.stdout
    print(case, done.stdout.splitlines()[-1])


def test_mjcf_and_sdf_include_naming_outside_files_are_refused(layout):
    from pe_drake.exceptions import ConfigError
    from pe_drake.multibody.model_files import drake_model_text

    _, model, secret = layout
    mjcf = _write(model, "r.xml", f"""<mujoco><compiler meshdir="meshes"/>
  <asset><mesh name="a" file="good.obj"/><mesh name="b" file="{secret}/cad.obj"/></asset></mujoco>""")
    with pytest.raises(ConfigError, match="outside the model's folder"):
        drake_model_text(mjcf, obj_visuals=True)
    sdf = _write(model, "inc.sdf", f'<sdf version="1.7"><include><uri>file://{secret}/x.sdf</uri></include></sdf>')
    with pytest.raises(ConfigError, match="<include>s another model"):
        drake_model_text(sdf, obj_visuals=True)


def test_capsule_fitting_names_a_pipe_or_an_oversize_mesh(layout, monkeypatch):
    """An oversize or unreadable mesh was reported as "file not found"."""
    from pe_drake.multibody.capsule_fitting import CapsuleFittingError, fit_capsule_file

    tmp, model, _ = layout
    os.mkfifo(model / "meshes" / "pipe.stl")
    (model / "meshes" / "big.obj").write_text(TRIANGLE * 2000)
    monkeypatch.setenv("PE_DRAKE_MAX_MESH_MB", "0.01")
    for name, says in (("pipe.stl", "not a regular file"), ("big.obj", "over the 0.01 MB limit")):
        path = _write(model, "r.urdf", _urdf(f'<mesh filename="meshes/{name}"/>'))
        with pytest.raises(CapsuleFittingError) as err:
            fit_capsule_file(path, tmp / "caps.yaml")
        assert says in str(err.value.unchecked), err.value.unchecked


def test_a_collada_file_with_entities_is_not_parsed(tmp_path):
    from pe_drake.exceptions import DataError
    from pe_drake.multibody.meshes import read_dae_vertices

    (tmp_path / "x.dae").write_text('<?xml version="1.0"?><!DOCTYPE c [<!ENTITY s SYSTEM "file:///etc/passwd">]>'
                                    '<COLLADA><library_geometries>&s;</library_geometries></COLLADA>')
    with pytest.raises(DataError, match="declares XML entities"):
        read_dae_vertices(tmp_path / "x.dae")
