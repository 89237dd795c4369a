"""A robot part that could not be checked for collision makes the run 'not valid for hardware'
(exit 1, listed in report.json's ``unchecked``) unless ``--allow-unchecked`` is given."""

from __future__ import annotations

import json

import pytest

from pe_drake.cli import main

URDF = """<?xml version="1.0"?>
<robot name="two_link">
  <link name="base"><inertial><mass value="2"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.05"/><geometry><cylinder radius="0.05" length="0.1"/></geometry></collision></link>
  <link name="upper"><inertial><origin xyz="0 0 0.15"/><mass value="1"/>
      <inertia ixx="0.01" iyy="0.01" izz="0.002" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.15"/><geometry><cylinder radius="0.03" length="0.3"/></geometry></collision></link>
  <link name="lower"><inertial><origin xyz="0.1 0 0"/><mass value="0.5"/>
      <inertia ixx="0.001" iyy="0.004" izz="0.004" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0.1 0 0" rpy="0 1.5707963267948966 0"/>
      <geometry><cylinder radius="0.02" length="0.2"/></geometry></collision></link>
  <link name="hand"><inertial><origin xyz="0.03 0 0"/><mass value="0.2"/>
      <inertia ixx="0.0002" iyy="0.0002" izz="0.0002" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><geometry><mesh filename="meshes/missing.stl"/></geometry></collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="upper"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-2" upper="2" velocity="2" effort="20"/></joint>
  <joint name="j2" type="revolute"><parent link="upper"/><child link="lower"/><origin xyz="0 0 0.3"/>
    <axis xyz="0 1 0"/><limit lower="-1.5" upper="1.5" velocity="2" effort="20"/></joint>
  <joint name="j3" type="revolute"><parent link="lower"/><child link="hand"/><origin xyz="0.2 0 0"/>
    <axis xyz="1 0 0"/><limit lower="-2" upper="2" velocity="2" effort="5"/></joint>
</robot>
"""


@pytest.fixture
def robot_with_unreadable_mesh(tmp_path):
    (tmp_path / "meshes").mkdir()
    path = tmp_path / "two_link.urdf"
    path.write_text(URDF)
    return path


def _run(robot, out, *extra):
    return main(["optimize", "--robot", str(robot), "--max-iterations", "20", "--no-html", "--quiet",
                 "--out", str(out), *extra])


def test_unreadable_mesh_is_not_valid_for_hardware(robot_with_unreadable_mesh, tmp_path, capsys):
    out = tmp_path / "out"
    assert _run(robot_with_unreadable_mesh, out) == 1
    assert "not valid for hardware" in capsys.readouterr().err
    report = json.loads((out / "report.json").read_text())
    assert any("missing.stl" in line for line in report["unchecked"]), report["unchecked"]
    assert not (out / "trajectory.csv").exists()


def test_allow_unchecked_writes_the_motion_and_keeps_the_list(robot_with_unreadable_mesh, tmp_path):
    out = tmp_path / "out"
    rc = _run(robot_with_unreadable_mesh, out, "--allow-unchecked")
    report = json.loads((out / "report.json").read_text())
    assert report["unchecked"] and report["not_valid_for_hardware"] is None
    assert rc == (0 if report["success"] else 1)
    assert (out / "trajectory.csv").exists() == report["success"]
    if report["success"]:  # the controller's goal, as YAML and as an MCAP bag, beside the CSV
        from rosbags.rosbag2 import Reader

        assert "time_from_start" in (out / "trajectory_goal.yaml").read_text()
        with Reader(out / "trajectory_goal_bag") as reader:
            assert [c.msgtype for c in reader.connections] == ["trajectory_msgs/msg/JointTrajectory"]
        assert main(["optimize", "--robot", str(robot_with_unreadable_mesh), "--max-iterations", "20", "--no-html",
                     "--quiet", "--out", str(out)]) == 1  # a refused rerun on the same folder
        assert not (out / "trajectory_goal_bag").exists() and not (out / "trajectory.csv").exists()
