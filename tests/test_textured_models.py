"""Issue 37, items 6 and 8: a material's ``<texture filename="package://…">`` (every Interbotix
arm) is resolved like a mesh, from the .xacro the user named (not from its expanded copy in
pe_drake's cache), in the expanded model and in an exported URDF."""

from __future__ import annotations

import numpy as np

from pe_drake.bench_models import png_1x1
from pe_drake.multibody.meshes import TriangleMesh, obj_text
from pe_drake.multibody.robot import load_robot
from pe_drake.multibody.urdf import urdf_with_inertias

INERTIAL = '<inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>'
URDF = f"""<?xml version="1.0"?>
<robot name="arm" xmlns:xacro="http://www.ros.org/wiki/xacro">
  <material name="skin"><texture filename="package://arm_description/meshes/skin.png"/></material>
  <link name="base">{INERTIAL}</link>
  <link name="l1">{INERTIAL}<visual><geometry><mesh filename="package://arm_description/meshes/l1.obj"/></geometry>
    <material name="skin"/></visual></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" velocity="1" effort="1"/></joint>
</robot>
"""


def _package(tmp_path, name: str):
    package = tmp_path / "ws" / "arm_description"
    (package / "meshes").mkdir(parents=True)
    (package / "urdf").mkdir()
    (package / "package.xml").write_text("<package><name>arm_description</name></package>")
    (package / "meshes" / "l1.obj").write_text(obj_text(TriangleMesh(np.eye(3), np.array([[0, 1, 2]]))))
    (package / "meshes" / "skin.png").write_bytes(png_1x1())
    path = package / "urdf" / name
    path.write_text(URDF)
    return path


def test_textured_xacro_loads_with_its_package_found_above_the_xacro(tmp_path, monkeypatch):
    monkeypatch.setenv("PE_DRAKE_MESH_CACHE", str(tmp_path / "cache"))
    robot = load_robot(str(_package(tmp_path, "arm.urdf.xacro")), obj_visuals=True)
    assert robot.joint_names == ("j1",)
    text = robot.model_path.read_text()
    assert "package://" not in text and (tmp_path / "ws" / "arm_description" / "meshes" / "skin.png").as_uri() in text


def test_exported_urdf_resolves_textures(tmp_path):
    source = _package(tmp_path, "arm.urdf")
    phi = np.array([1.0, 0, 0, 0, 0.01, 0.01, 0.01, 0, 0, 0])
    text = urdf_with_inertias(source, ["l1"], phi)
    assert "package://arm_description" not in text
    assert (tmp_path / "ws" / "arm_description" / "meshes" / "skin.png").as_uri() in text


def test_outputs_record_the_model_relative_to_their_folder(tmp_path, monkeypatch):
    """trajectory.json and report.json name the model relative to the output folder (no user
    name or folder layout of the author's machine), and ``view`` still finds it."""
    import json

    from pe_drake.cli import main
    from pe_drake.viewer import play_trajectory

    monkeypatch.setenv("PE_DRAKE_MESH_CACHE", str(tmp_path / "cache"))
    model = _package(tmp_path, "arm.urdf")
    (tmp_path / "c.yaml").write_text("solver:\n  max_iterations: 3\nexcitation:\n  collision_margin: -1\n")
    out = tmp_path / "runs" / "out"
    assert main(["optimize", "--robot", str(model), "--config", str(tmp_path / "c.yaml"), "--out", str(out),
                 "--no-html", "--allow-unchecked"]) in (0, 3)
    for name in ("trajectory.json", "report.json"):
        text = (out / name).read_text()
        assert str(tmp_path) not in text, name
    assert json.loads((out / "trajectory.json").read_text())["model"] == "../../ws/arm_description/urdf/arm.urdf"
    monkeypatch.chdir(tmp_path / "ws")  # another working folder: the path is the file's, not the shell's
    assert play_trajectory(out / "trajectory.json", html=tmp_path / "p.html", rate=5.0).num_frames > 0


def test_the_playback_holds_the_textured_link(tmp_path, monkeypatch):
    """The textured visual is sent to Meshcat (the playback drew no robot when a material had a
    texture): its set_object command is in the static HTML."""
    import base64
    import binascii
    import re

    from pydrake.geometry import Meshcat, MeshcatVisualizer, MeshcatVisualizerParams, Role

    monkeypatch.setenv("PE_DRAKE_MESH_CACHE", str(tmp_path / "cache"))
    meshcat = Meshcat()

    def hook(builder, plant, scene_graph):
        MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, MeshcatVisualizerParams(role=Role.kIllustration))

    robot = load_robot(str(_package(tmp_path, "arm.urdf.xacro")), obj_visuals=True, builder_hook=hook)
    robot.diagram.ForcedPublish(robot.diagram.CreateDefaultContext())
    paths = set()
    for chunk in re.findall(r"[A-Za-z0-9+/]{40,}={0,2}", meshcat.StaticHtml()):
        try:
            paths |= set(re.findall(rb"/drake/visualizer/[\w/]+", base64.b64decode(chunk + "=" * (-len(chunk) % 4))))
        except (binascii.Error, ValueError):
            continue
    assert b"/drake/visualizer/arm/l1/arm/Mesh" in paths, paths


def test_payload_urdf_of_a_textured_robot_is_written(tmp_path, monkeypatch):
    """identify --payload fitted, then exited 2 writing nothing: Drake could not read the
    texture's package:// back from the exported model_with_payload.urdf (issue 37, item 6)."""
    from pe_drake.identification.payload_formats import write_payload_urdf
    from pe_drake.multibody.payload import PayloadInertia

    monkeypatch.setenv("PE_DRAKE_MESH_CACHE", str(tmp_path / "cache"))
    robot = load_robot(str(_package(tmp_path, "arm.urdf")))
    payload = PayloadInertia(0.5, np.array([0.0, 0.0, 0.05]), np.diag([1e-3, 1e-3, 2e-3]))
    path = write_payload_urdf(tmp_path / "model_with_payload.urdf", robot, payload, "l1")
    assert "package://arm_description" not in path.read_text()


def test_trajectory_records_its_capsule_file_relative(tmp_path):
    import json
    from pathlib import Path

    from pe_drake.excitation.trajectory_file import load_trajectory, save_trajectory

    trajectory, _ = load_trajectory(Path(__file__).parent / "data" / "panda_optimized.json")
    capsules = tmp_path / "shared" / "caps.yaml"
    save_trajectory(tmp_path / "run" / "trajectory.json", load_robot("panda"), trajectory, capsules=str(capsules))
    data = json.loads((tmp_path / "run" / "trajectory.json").read_text())
    assert data["capsules"] == "../shared/caps.yaml" and str(tmp_path) not in json.dumps(data)
