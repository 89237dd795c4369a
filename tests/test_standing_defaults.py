# ruff: noqa: E501 (URDF text on one line per link)
"""A legged robot given without a config stands on its feet with its arms excited (TALOS,
Romeo, iCub: welded at the pelvis with every joint excited, their legs went through the
floor and no posture cleared)."""

import numpy as np
import pytest

from pe_drake.multibody.registry import example_robot_data_dir, resolve_robot_config
from pe_drake.multibody.standing_defaults import standing_defaults

_I = '<inertial><mass value="{m}"/><origin xyz="{c}"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>'
_J = '<joint name="{n}" type="revolute"><parent link="{p}"/><child link="{c}"/><origin xyz="{o}"/><axis xyz="0 1 0"/><limit lower="-1" upper="{u}" effort="50" velocity="3"/></joint>'


def _humanoid() -> str:
    links = ['<link name="pelvis">' + _I.format(m=10, c="0 0 0.1") + "</link>"]
    joints = []
    for side, y in (("left", 0.1), ("right", -0.1)):
        links += [f'<link name="{side}_thigh">' + _I.format(m=3, c="0 0 -0.2") + "</link>",
                  f'<link name="{side}_shin">' + _I.format(m=2, c="0 0 -0.2") + "</link>",
                  f'<link name="{side}_foot">' + _I.format(m=1, c="0.03 0 -0.03")
                  + '<collision><origin xyz="0.03 0 -0.03"/><geometry><box size="0.2 0.08 0.04"/></geometry></collision></link>',
                  f'<link name="{side}_upper_arm">' + _I.format(m=1, c="0 0 -0.1") + "</link>",
                  f'<link name="{side}_forearm">' + _I.format(m=1, c="0 0 -0.1") + "</link>",
                  f'<link name="{side}_hand">' + _I.format(m=0.3, c="0 0 -0.03") + "</link>"]
        joints += [_J.format(n=f"{side}_hip_pitch", p="pelvis", c=f"{side}_thigh", o=f"0 {y} 0", u=1),
                   _J.format(n=f"{side}_knee", p=f"{side}_thigh", c=f"{side}_shin", o="0 0 -0.4", u=1),
                   _J.format(n=f"{side}_ankle_pitch", p=f"{side}_shin", c=f"{side}_foot", o="0 0 -0.4", u=1),
                   _J.format(n=f"{side}_shoulder_pitch", p="pelvis", c=f"{side}_upper_arm", o=f"0 {2 * y} 0.4", u=1),
                   _J.format(n=f"{side}_elbow", p=f"{side}_upper_arm", c=f"{side}_forearm", o="0 0 -0.25", u=1),
                   _J.format(n=f"{side}_hand_joint", p=f"{side}_forearm", c=f"{side}_hand", o="0 0 -0.25", u=1)]
    return '<robot name="walker">' + "".join(links + joints) + "</robot>"


def test_a_humanoid_stands_on_its_soles_with_its_arms_excited(tmp_path):
    path = tmp_path / "walker.urdf"
    path.write_text(_humanoid())
    d = standing_defaults(path)
    r = d["robot"]
    assert sorted(r["joints"]) == ["left_elbow", "left_shoulder_pitch", "right_elbow", "right_shoulder_pitch"]
    assert r["base_position"] == pytest.approx([0, 0, 0.8 + 0.05])  # shins, ankle, sole 5 cm below it
    assert set(r["support_points"]) == {"left_foot", "right_foot"}
    left = np.array(r["support_points"]["left_foot"])
    np.testing.assert_allclose(sorted(left[:, 0]), [-0.07, -0.07, 0.13, 0.13], atol=1e-9)  # the box's sole corners
    np.testing.assert_allclose(left[:, 2], -0.05, atol=1e-9)
    # mirror-symmetric robot: mirror-symmetric points
    right = np.array(r["support_points"]["right_foot"])
    np.testing.assert_allclose(sorted(map(tuple, left * [1, -1, 1])), sorted(map(tuple, right)), atol=1e-9)
    assert d["excitation"]["balance_radius"] >= 0.02 and d["excitation"]["collision_margin"] == 0.02
    config = resolve_robot_config(str(path))  # the CLI's door
    assert config.robot.support_points == r["support_points"] and config.excitation.balance_radius > 0
    assert "standing on left_foot, right_foot" in config.robot.notes[0]


def test_the_balance_radius_takes_in_the_starting_com(tmp_path):
    """TALOS stands with its CoM 59 mm in front of its feet's centre: a 2 cm radius about the
    centre refused its own starting posture."""
    path = tmp_path / "walker.urdf"
    path.write_text(_humanoid().replace('<link name="pelvis"><inertial><mass value="10"/><origin xyz="0 0 0.1"/>',
                                        '<link name="pelvis"><inertial><mass value="10"/><origin xyz="0.05 0 0.1"/>'))
    d = standing_defaults(path)
    # CoM x = (10·0.05 + 2·1·0.03) / 26.6 kg = 21 mm; the soles' centre is at x = 30 mm: 9 mm off,
    # so the radius is 2 cm + 9 mm (the feet's box, ±10 cm in x less 1 cm, does not cap it)
    assert d["excitation"]["balance_radius"] == pytest.approx(0.02 + 0.03 - 0.56 / 26.6, abs=1e-4)


def test_an_arm_is_not_a_humanoid(tmp_path):
    assert standing_defaults(example_robot_data_dir() / "robots/panda_description/urdf/panda.urdf") is None
    path = tmp_path / "walker.urdf"
    path.write_text(_humanoid().replace("<robot name=\"walker\">", '<robot name="walker"><link name="world"/><joint name="w" type="fixed"><parent link="world"/><child link="pelvis"/></joint>'))
    assert standing_defaults(path) is None  # welded to a world link: mounted, not standing


def test_g1_defaults_match_the_shipped_config():
    """The shipped G1 config was written by hand; the defaults derive the same set-up."""
    g1 = resolve_robot_config("g1")
    d = standing_defaults(example_robot_data_dir() / "robots/g1_description/urdf/g1_29dof_rev_1_0.urdf")
    assert sorted(d["robot"]["joints"]) == sorted(g1.robot.joints)
    assert d["robot"]["base_position"][2] == pytest.approx(g1.robot.base_position[2], abs=1e-3)
    assert set(d["robot"]["support_points"]) == set(g1.robot.support_points)


def test_icubs_y_up_meshes_are_turned_and_it_stands_balanced():
    """iCub's 56 COLLADA meshes say Y_UP and are drawn for tools that honour it: as written, its
    thighs lay horizontal and its feet pointed sideways, overlapping, so the support centre sat
    31 mm to one side and the nominal posture was "out of balance" before any solve. TIAGo's
    Y_UP meshes fit their links only as written (the ROS convention), and stay so."""
    from pe_drake.excitation.constraints.balance import BalanceConstraint
    from pe_drake.multibody.collada_up_axis import honors_up_axis, link_points_inside, to_z_up
    from pe_drake.multibody.robot import load_robot

    robots = example_robot_data_dir() / "robots"
    icub = robots / "icub_description" / "robots" / "icub_reduced.urdf"
    tiago = robots / "tiago_description" / "robots" / "tiago_no_hand.urdf"
    assert honors_up_axis(str(icub)) and not honors_up_axis(str(tiago))
    raw, turned, points = link_points_inside(str(icub))
    assert turned > raw + 0.2 * points
    assert np.allclose(to_z_up(np.array([[1.0, 2.0, 3.0]]), "Y_UP"), [[1.0, -3.0, 2.0]])
    d = standing_defaults(icub)
    assert any("<up_axis>" in n for n in d["robot"]["notes"])
    config = resolve_robot_config(str(icub))
    robot = load_robot(config)
    balance = BalanceConstraint(robot, config.excitation.balance_radius)
    assert abs(balance.p_WSc[1]) < 1e-3  # the feet are mirror images: the support centre is on the mid-plane
    balance.check_posture(robot.nominal_posture()[None, :])  # raised "out of balance at sample 0" before


def test_the_playback_draws_icubs_dae_visuals_turned_and_tiagos_as_written(tmp_path, monkeypatch):
    """Meshcat draws a DAE as written: for a model whose meshes are turned (iCub) the viewer's
    model text names turned OBJ copies; TIAGo's DAE visuals are left for Meshcat as they are."""
    from pe_drake.multibody.collada_up_axis import to_z_up, turned_dae_visuals
    from pe_drake.multibody.meshes import read_dae_triangles, read_mesh_vertices

    monkeypatch.setenv("PE_DRAKE_MESH_CACHE", str(tmp_path))
    robots = example_robot_data_dir() / "robots"
    icub = robots / "icub_description" / "robots" / "icub_reduced.urdf"
    tiago = robots / "tiago_description" / "robots" / "tiago_no_hand.urdf"
    text = turned_dae_visuals(icub.read_text(), icub)
    import re

    visuals = re.findall(r"<visual\b.*?</visual>", text, re.S)
    assert visuals and not any(".dae" in v for v in visuals) and any(".turned.obj" in v for v in visuals)
    assert "icub_simple_collision_r_foot.dae" in text  # collisions are not the viewer's
    turned = sorted(tmp_path.rglob("*.turned.obj"))
    assert turned
    foot = next(p for p in turned if p.name == "icub_r_foot.turned.obj")
    dae = robots / "icub_description" / "meshes" / "upmc" / "visual" / "icub_r_foot.dae"
    assert np.allclose(np.sort(read_mesh_vertices(foot), axis=0),
                       np.sort(to_z_up(read_dae_triangles(dae).vertices, "Y_UP"), axis=0), atol=1e-6)
    assert turned_dae_visuals(tiago.read_text(), tiago) == tiago.read_text()
