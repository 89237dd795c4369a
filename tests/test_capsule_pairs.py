# ruff: noqa: E501 (URDF text on one line per link)
"""Fitted capsules keep non-neighbours checked, name the pairs they ignore and treat left and
right alike (issue 21: TALOS's 0.25 m torso capsule swallowed the arm links beside it)."""

import dataclasses

import numpy as np
import pytest

from pe_drake.excitation.constraints.collision import CollisionConstraint
from pe_drake.multibody.capsule_fitting import fit_capsules, mirror_name
from pe_drake.multibody.capsules import capsule_pairs, joints_apart
from pe_drake.multibody.registry import example_robot_data_dir, resolve_robot_config
from pe_drake.multibody.robot import Robot

_I = '<inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>'
_J = '<joint name="{n}" type="revolute"><parent link="{p}"/><child link="{c}"/><origin xyz="{o}"/><axis xyz="1 0 0"/><limit lower="-1" upper="1" effort="50" velocity="3"/></joint>'
_CYL = '<collision><origin xyz="{o}" rpy="1.5708 0 0"/><geometry><cylinder radius="0.03" length="{L}"/></geometry></collision>'


def _fat_torso_robot(tmp_path):
    """A 0.3 m ball of a torso with two 3-link arms; each hand reaches back to 3 cm inside the
    ball at the zero (mid-range) posture, three joints away from it."""
    links = ['<link name="world"/>', '<link name="torso">' + _I + '<collision><geometry><sphere radius="0.3"/></geometry></collision></link>']
    joints = ['<joint name="w" type="fixed"><parent link="world"/><child link="torso"/></joint>']
    for side, s in (("left", 1), ("right", -1)):
        links += [f'<link name="{side}_shoulder">' + _I + _CYL.format(o="0 0 0", L=0.02) + "</link>",
                  f'<link name="{side}_upper">' + _I + _CYL.format(o="0 0 0", L=0.02) + "</link>",
                  f'<link name="{side}_hand">' + _I + _CYL.format(o=f"0 {-s * 0.17} 0", L=0.06) + "</link>"]
        joints += [_J.format(n=f"{side}_j1", p="torso", c=f"{side}_shoulder", o=f"0 {s * 0.4} 0"),
                   _J.format(n=f"{side}_j2", p=f"{side}_shoulder", c=f"{side}_upper", o=f"0 {s * 0.05} 0"),
                   _J.format(n=f"{side}_j3", p=f"{side}_upper", c=f"{side}_hand", o=f"0 {s * 0.05} 0")]
    path = tmp_path / "fat.urdf"
    path.write_text('<robot name="fat">' + "".join(links + joints) + "</robot>")
    config = resolve_robot_config(str(path))
    return dataclasses.replace(config, excitation=dataclasses.replace(config.excitation, collision_margin=0.02))


def _checked(config):
    robot = Robot("check", config.robot)
    return robot, {frozenset((robot.capsules[a].name, robot.capsules[b].name)) for a, b in capsule_pairs(robot.scene_graph, robot.capsules)}


def test_a_capsule_too_fat_for_links_three_joints_away_is_shrunk_not_ignored(tmp_path):
    config, fitted = fit_capsules(_fat_torso_robot(tmp_path), tmp_path)
    # the hand's segment ends 0.5 - 0.17 - 0.03 = 0.30 m from the ball's centre, its surface 3 cm
    # inside the ball: clearing the 2 cm margin (+1 mm) takes the ball from 0.30 to 0.249 m
    robot, checked = _checked(config)
    for side in ("left", "right"):
        assert frozenset(("torso", f"{side}_hand")) in checked  # old code: ignored "by design"
    assert set(fitted.shrunk) == {"torso"}
    before, after = fitted.shrunk["torso"]
    assert before == pytest.approx(0.3) and after == pytest.approx(0.249, abs=2e-4)
    torso = next(c for c in robot.capsules if c.name == "torso")
    assert torso.radius == pytest.approx(after, abs=1e-4)  # written to the file
    assert not any("torso" in p[:2] and "hand" in " ".join(p[:2]) for p in fitted.ignored_pairs)
    assert "shrunk" in fitted.pairs_summary() and "torso 0.300 ->" in fitted.pairs_summary()
    CollisionConstraint(robot, 0.02).check_posture(robot.nominal_posture())  # the start posture is clear


def test_joints_apart_counts_joints_between_links(tmp_path):
    robot = Robot("fat", _fat_torso_robot(tmp_path).robot)
    names = ["torso", "left_shoulder", "left_upper", "left_hand", "right_hand"]
    index = [robot.plant.GetBodyByName(n).index() for n in names]
    hops = joints_apart(robot.plant, [int(i) for i in index])
    assert hops[0].tolist() == [0, 1, 2, 3, 3] and hops[3, 4] == 6


def test_mirror_names():
    assert mirror_name("arm_left_4_link") == "arm_right_4_link" and mirror_name("RightHand") == "LeftHand"
    assert mirror_name("l_forearm") == "r_forearm" and mirror_name("torso_2_link") == "torso_2_link"


@pytest.fixture(scope="module")
def talos(tmp_path_factory):
    model = example_robot_data_dir() / "robots/talos_data/robots/talos_reduced.urdf"
    if not model.exists():
        pytest.skip("example-robot-data without TALOS")
    config = resolve_robot_config(str(model))
    config, fitted = fit_capsules(config, tmp_path_factory.mktemp("talos"))
    return config, fitted, *_checked(config)


def test_talos_torso_capsule_is_its_own_mirror_image_and_the_arms_mirror_each_other(talos):
    _, _, robot, _ = talos
    caps = {c.name: c for c in robot.capsules}
    mirror = np.diag([1.0, -1.0, 1.0])
    torso = caps["torso_2_link"]
    ends = torso.p_BS @ mirror
    # the same segment, either way round (old code: 12 mm off the plane and leaning 12°)
    assert min(np.abs(ends - torso.p_BS).max(), np.abs(ends[::-1] - torso.p_BS).max()) < 1e-4
    for k in range(1, 8):
        left, right = caps[f"arm_left_{k}_link"], caps[f"arm_right_{k}_link"]
        assert left.radius == pytest.approx(right.radius, abs=1e-4)
        mirrored = left.p_BS @ mirror
        assert min(np.abs(mirrored - right.p_BS).max(), np.abs(mirrored[::-1] - right.p_BS).max()) < 2e-4


def test_talos_both_forearms_are_checked_against_the_torso_and_the_ignored_pairs_are_symmetric(talos):
    _, fitted, _, checked = talos
    for side in ("left", "right"):
        for k in (3, 4, 5, 6, 7):
            assert frozenset(("torso_2_link", f"arm_{side}_{k}_link")) in checked
    ignored = {frozenset(p[:2]) for p in fitted.ignored_pairs}
    assert ignored and ignored == {frozenset(mirror_name(n) for n in p) for p in ignored}
    summary = fitted.pairs_summary()
    assert summary.startswith(f"{len(ignored)} pair(s) touching by design ignored: ")
    assert "torso_2_link/arm_left_2_link" in summary and "more (full list: report.json 'ignored_pairs')" in summary
    records = fitted.ignored_records()
    assert len(records) == len(ignored) and all(set(r) == {"pair", "reason"} for r in records)


def _swinging_robot(tmp_path, left_range: float, right_range: float):
    """Per side, a ball on a post and a ball swung past it on a 0.3 m crank, two joints from the
    post: they are within the 2 cm margin while |crank| < 0.97 rad, not at the nominal ±1 rad."""
    links = ['<link name="world"/>', '<link name="base">' + _I + "</link>"]
    joints = ['<joint name="w" type="fixed"><parent link="world"/><child link="base"/></joint>']
    ball = '<collision><geometry><sphere radius="0.13"/></geometry></collision>'
    for side, s, rng in (("left", 1, left_range), ("right", -1, right_range)):
        links += [f'<link name="{side}_post">' + _I + ball + "</link>", f'<link name="{side}_crank">' + _I + "</link>",
                  f'<link name="{side}_ball">' + _I + ball + "</link>"]
        joints += [f'<joint name="{side}_weld" type="fixed"><parent link="base"/><child link="{side}_post"/><origin xyz="0.3 {s} 0"/></joint>',
                   f'<joint name="{side}_j1" type="revolute"><parent link="base"/><child link="{side}_crank"/><origin xyz="0 {s} 0"/><axis xyz="0 0 1"/><limit lower="{-rng}" upper="{rng}" effort="50" velocity="3"/></joint>',
                   f'<joint name="{side}_j2" type="revolute"><parent link="{side}_crank"/><child link="{side}_ball"/><origin xyz="0.3 0 0"/><axis xyz="0 0 1"/><limit lower="-0.01" upper="0.01" effort="50" velocity="3"/></joint>']
    path = tmp_path / "swing.urdf"
    path.write_text('<robot name="swing">' + "".join(links + joints) + "</robot>")
    config = resolve_robot_config(str(path))
    return dataclasses.replace(
        config, robot=dataclasses.replace(config.robot, nominal_positions={"left_j1": 1.0, "right_j1": -1.0}),
        excitation=dataclasses.replace(config.excitation, collision_margin=0.02))


def test_a_pair_touching_in_random_postures_on_one_side_only_stays_checked(tmp_path):
    """The left crank's ±1 rad range touches in 97 % of random postures, the right's ±2 rad in
    49 %: ignoring the left pair alone checked the right arm and not the left (issue 21)."""
    config, fitted = fit_capsules(_swinging_robot(tmp_path, 1.0, 2.0), tmp_path / "a")
    _, checked = _checked(config)
    assert {frozenset(("left_post", "left_ball")), frozenset(("right_post", "right_ball"))} <= checked
    assert not fitted.ignored_pairs
    # both sides alike (±1 rad): both pairs touch by design
    config, fitted = fit_capsules(_swinging_robot(tmp_path, 1.0, 1.0), tmp_path / "b")
    assert sorted(tuple(p[:2]) for p in fitted.ignored_pairs) == [("left_post", "left_ball"), ("right_post", "right_ball")]
    assert all(p[2].endswith("of random postures") for p in fitted.ignored_pairs)
