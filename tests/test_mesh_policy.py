"""A model cannot make pe_drake read files that are not its meshes: visuals naming a file outside
the model's folder and packages, a non-mesh file, a symlink out of the folder, a named pipe or
/dev/zero are dropped with a note naming the path and the rule (Meshcat would embed them whole
in playback.html, a pipe would hang the run)."""

from __future__ import annotations

import os

import numpy as np
import pytest

from pe_drake.multibody.mesh_policy import mesh_file_refusal
from pe_drake.multibody.meshes import TriangleMesh, write_obj
from pe_drake.multibody.model_files import drake_model_text

LINK = """  <link name="{name}"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/>
    </inertial><visual><geometry><mesh filename="{mesh}"/></geometry></visual></link>
"""


def _urdf(meshes: list[str]) -> str:
    links = "".join(LINK.format(name=f"l{k}", mesh=m) for k, m in enumerate(meshes))
    joints = "".join(
        f'  <joint name="j{k}" type="revolute"><parent link="l{k - 1}"/><child link="l{k}"/><axis xyz="0 0 1"/>'
        f'<limit lower="-1" upper="1" velocity="1" effort="1"/></joint>\n' for k in range(1, len(meshes)))
    return f'<?xml version="1.0"?>\n<robot name="r">\n{links}{joints}</robot>\n'


@pytest.fixture
def hostile(tmp_path):
    secret = tmp_path / "secret"
    secret.mkdir()
    (secret / "id_rsa").write_text("SECRET-KEY-MARKER")
    write_obj(secret / "outside.obj", TriangleMesh(np.eye(3), np.array([[0, 1, 2]])))
    model = tmp_path / "robot"
    (model / "meshes").mkdir(parents=True)
    write_obj(model / "meshes" / "good.obj", TriangleMesh(np.eye(3), np.array([[0, 1, 2]])))
    os.symlink(secret / "outside.obj", model / "meshes" / "link_out.obj")
    os.mkfifo(model / "meshes" / "pipe.stl")
    os.symlink("/dev/zero", model / "meshes" / "zero.stl")
    bad = ["../secret/id_rsa", f"file://{secret / 'id_rsa'}", str(secret / "outside.obj"),
           "meshes/link_out.obj", "meshes/pipe.stl", "meshes/zero.stl"]
    path = model / "robot.urdf"
    path.write_text(_urdf(["meshes/good.obj", *bad]))
    return path, bad


def test_hostile_visuals_are_dropped_with_a_reason(hostile):
    path, bad = hostile
    text, notes = drake_model_text(path, obj_visuals=True)
    dropped = [n for n in notes if n.startswith("visual dropped")]
    assert len(dropped) == len(bad), notes
    for reason in ("not a mesh file", "outside the model's folder", "not a regular file"):
        assert any(reason in n for n in dropped), (reason, dropped)
    assert "good.obj" in text
    for name in ("id_rsa", "outside.obj", "link_out.obj", "pipe.stl", "zero.stl"):
        assert name not in text


def test_file_checks_refuse_pipes_devices_and_non_meshes(tmp_path):
    os.mkfifo(tmp_path / "p.stl")
    (tmp_path / "notes.txt").write_text("x")
    assert "regular file" in mesh_file_refusal(tmp_path / "p.stl")
    assert "not a mesh file" in mesh_file_refusal(tmp_path / "notes.txt")
    assert "regular file" in mesh_file_refusal("/dev/zero") or "not a mesh file" in mesh_file_refusal("/dev/zero")
