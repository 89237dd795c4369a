"""Capsule files, their registration in Drake, pair filtering, and the geometry helpers."""

import dataclasses
import itertools
import math

import numpy as np
import pytest

from pe_drake.exceptions import ConfigError, UnknownNameError
from pe_drake.multibody.capsules import (
    capsule_pairs,
    capsule_pose,
    fit_capsule,
    load_capsule_file,
    segment_closest_points,
)
from pe_drake.multibody.registry import resolve_robot_config
from pe_drake.multibody.robot import load_robot


def _names(robot, pairs):
    return {frozenset((robot.capsules[a].name, robot.capsules[b].name)) for a, b in pairs}


# ---- geometry helpers ---------------------------------------------------------------------
def test_segment_closest_points_match_brute_force():
    rng = np.random.default_rng(0)
    N = 300
    a0, a1, b0, b1 = (rng.normal(size=(N, 3)) for _ in range(4))
    b1[:40] = b0[:40] + 0.7 * (a1[:40] - a0[:40])  # parallel
    b0[40:60] = a0[40:60] + 0.3 * (a1[40:60] - a0[40:60])  # touching
    s, t = segment_closest_points(a0, a1, b0, b1)
    assert ((s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)).all()
    d = np.linalg.norm(a0 + s[:, None] * (a1 - a0) - b0 - t[:, None] * (b1 - b0), axis=1)
    g = np.linspace(0.0, 1.0, 201)
    for i in range(N):
        pa = a0[i] + g[:, None] * (a1[i] - a0[i])
        pb = b0[i] + g[:, None] * (b1[i] - b0[i])
        grid = np.min(np.linalg.norm(pa[:, None] - pb[None], axis=2))
        assert d[i] <= grid + 1e-12  # never worse than any grid pair
        assert grid - d[i] < 0.02  # and the grid gets close to it


def test_segment_closest_points_batched_shapes():
    rng = np.random.default_rng(1)
    a0, a1, b0, b1 = (rng.normal(size=(4, 5, 3)) for _ in range(4))
    s, t = segment_closest_points(a0, a1, b0, b1)
    s1, t1 = segment_closest_points(a0[2, 3], a1[2, 3], b0[2, 3], b1[2, 3])
    assert s.shape == t.shape == (4, 5)
    assert s[2, 3] == pytest.approx(float(s1)) and t[2, 3] == pytest.approx(float(t1))


def test_fit_capsule_recovers_a_sampled_capsule():
    rng = np.random.default_rng(2)
    u = np.array([1.0, 2.0, 2.0]) / 3.0
    p0, p1, r = np.array([0.1, 0.0, 0.0]), np.array([0.1, 0.0, 0.0]) + 0.3 * u, 0.05
    # points on the capsule surface
    t = rng.uniform(0, 1, 4000)
    direction = rng.normal(size=(4000, 3))
    direction -= np.outer(direction @ u, u)
    direction /= np.linalg.norm(direction, axis=1)[:, None]
    points = p0 + np.outer(t, p1 - p0) + r * direction
    q0, q1, radius = fit_capsule(points, cover=1.0)
    assert radius == pytest.approx(r, abs=1e-3)
    ends = sorted([q0, q1], key=lambda p: p @ u)
    assert np.allclose(ends[0], p0, atol=2e-3) and np.allclose(ends[1], p1, atol=2e-3)


@pytest.mark.parametrize("direction", [(0, 0, 1), (1, 0, 0), (0, 1, 0), (0, -1, 0), (1, 1, 0.3), (0, 0, -1)])
def test_capsule_pose_puts_the_axis_on_the_segment(direction):
    from pydrake.math import RollPitchYaw

    p0 = np.array([0.1, -0.2, 0.3])
    p1 = p0 + 0.25 * np.asarray(direction, float) / np.linalg.norm(direction)
    xyz, rpy, length = capsule_pose(p0, p1)
    z_G = RollPitchYaw(rpy).ToRotationMatrix().matrix()[:, 2]
    assert length == pytest.approx(0.25)
    assert np.allclose(xyz - 0.5 * length * z_G, p0) and np.allclose(xyz + 0.5 * length * z_G, p1)


# ---- built-in capsule files -----------------------------------------------------------------
def test_g1_capsules_and_filtered_pairs(g1):
    names = [c.name for c in g1.capsules]
    assert len(names) == 12 and len(set(names)) == 12
    pairs = _names(g1, capsule_pairs(g1.scene_graph, g1.capsules))
    static = ["torso_left", "torso_right", "head", "pelvis", "left_thigh", "right_thigh"]
    # One welded group (pelvis, torso, head, legs): none of its pairs is checked.
    for a, b in itertools.combinations(static, 2):
        assert frozenset((a, b)) not in pairs
    for side in ("left", "right"):
        assert frozenset((f"{side}_upper_arm", f"{side}_forearm")) not in pairs  # adjacent (elbow)
        assert frozenset((f"{side}_forearm", f"{side}_hand")) not in pairs  # ignored_pairs
        assert frozenset((f"{side}_upper_arm", f"{side}_hand")) in pairs
        assert frozenset((f"{side}_hand", "torso_left")) in pairs
        assert frozenset((f"{side}_upper_arm", f"torso_{side}")) in pairs
    assert frozenset(("left_hand", "right_hand")) in pairs
    assert len(pairs) == 6 * 6 + 3 * 3 + 2  # arm/static + left/right + upper arm/hand


def test_panda_capsules_and_filtered_pairs(panda):
    pairs = _names(panda, capsule_pairs(panda.scene_graph, panda.capsules))
    assert len(panda.capsules) == 16
    by_link = {}
    for c in panda.capsules:
        by_link.setdefault(c.link, []).append(c.name)
    # Same link, adjacent links, and link7 / hand (welded through link8) are filtered.
    for i in range(8):
        for j in (i, i + 1):
            for a in by_link[f"panda_link{i}"]:
                for b in by_link.get(f"panda_link{j}", []):
                    assert frozenset((a, b)) not in pairs
    assert frozenset(("link7", "hand")) not in pairs and frozenset(("link7", "fingers")) not in pairs
    assert frozenset(("link6_b", "hand")) not in pairs  # adjacent through joint 7
    assert frozenset(("link5_a", "link7")) not in pairs  # ignored_pairs
    assert frozenset(("hand", "link0")) in pairs and frozenset(("link5_a", "link3_a")) in pairs


@pytest.mark.parametrize("name", ["g1", "panda"])
def test_pairs_agree_with_drake_queries(name, g1, panda):
    """The unfiltered pairs are exactly those Drake's proximity queries report."""
    robot = {"g1": g1, "panda": panda}[name]
    qobj = robot.scene_graph.get_query_output_port().Eval(
        robot.scene_graph.GetMyContextFromRoot(robot.context)
    )
    by_id = {c.geometry_id: c.name for c in robot.capsules}
    reported = {
        frozenset((by_id[d.id_A], by_id[d.id_B]))
        for d in qobj.ComputeSignedDistancePairwiseClosestPoints(100.0)
    }
    assert reported == _names(robot, capsule_pairs(robot.scene_graph, robot.capsules))


def test_capsule_info_ends_match_pose(g1):
    from pydrake.multibody.tree import BodyIndex

    for c in g1.capsules:
        z_G, p_BGo = c.X_BG[:3, 2], c.X_BG[:3, 3]
        assert np.allclose(c.p_BS, [p_BGo - 0.5 * c.length * z_G, p_BGo + 0.5 * c.length * z_G])
        assert g1.plant.get_body(BodyIndex(c.body_index)).name() == c.link


# ---- error paths ------------------------------------------------------------------------------
_GOOD = {
    "name": "upper",
    "link": "panda_link3",
    "radius": 0.06,
    "length": 0.15,
    "xyz": [0.0, 0.0, -0.05],
    "rpy": [0.0, 0.0, 0.0],
}


def _write(tmp_path, capsules, ignored="[]", name="caps.yaml"):
    lines = ["capsules:" if capsules else "capsules: []"]
    for c in capsules:
        lines.append("  - {" + ", ".join(f"{k}: {v}" for k, v in c.items()) + "}")
    lines.append(f"ignored_pairs: {ignored}")
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def _panda_with(path):
    config = dataclasses.replace(resolve_robot_config("panda").robot, capsules=str(path))
    return load_robot(config)


def test_custom_capsule_file_registers(tmp_path):
    other = dict(_GOOD, name="hand", link="panda_hand", radius=0.05)
    robot = _panda_with(_write(tmp_path, [_GOOD, other]))
    assert [c.name for c in robot.capsules] == ["upper", "hand"]
    assert capsule_pairs(robot.scene_graph, robot.capsules) == ((0, 1),)


def test_unknown_link_lists_valid_links(tmp_path):
    with pytest.raises(UnknownNameError) as err:
        _panda_with(_write(tmp_path, [dict(_GOOD, link="panda_link33")]))
    assert err.value.name == "panda_link33" and "panda_link3" in err.value.choices
    assert "capsule 'upper'" in str(err.value) and "panda_hand" in str(err.value)


@pytest.mark.parametrize(
    "field, value",
    [
        ("radius", -0.01),
        ("radius", 0.0),
        ("radius", ".nan"),
        ("length", 0.0),
        ("length", -1),
        ("length", ".inf"),
    ],
)
def test_bad_radius_or_length_names_the_capsule(tmp_path, field, value):
    path = _write(tmp_path, [dict(_GOOD, **{field: value})])
    with pytest.raises(ConfigError, match=rf"capsule 'upper' \(link 'panda_link3'\): {field} must be"):
        load_capsule_file(path)
    with pytest.raises(ConfigError, match="capsule 'upper'"):
        _panda_with(path)


@pytest.mark.parametrize(
    "change, message",
    [
        ({"xyz": "[0.0, 0.1]"}, "xyz must be 3 finite numbers"),
        ({"rpy": "[0.0, .nan, 0.0]"}, "rpy must be 3 finite numbers"),
        ({"link": '""'}, "has no link"),
        ({"raduis": 0.1}, "does not match the capsule format"),
        ({"radius": "abc"}, "does not match the capsule format"),
    ],
)
def test_malformed_capsule_entries(tmp_path, change, message):
    with pytest.raises(ConfigError, match=message):
        load_capsule_file(_write(tmp_path, [dict(_GOOD, **change)]))


def test_duplicate_names_and_bad_ignored_pairs(tmp_path):
    with pytest.raises(ConfigError, match="capsule name 'upper' is used 2 times"):
        load_capsule_file(_write(tmp_path, [_GOOD, _GOOD]))
    with pytest.raises(ConfigError, match="must be two different names"):
        load_capsule_file(_write(tmp_path, [_GOOD], ignored="[[upper]]"))
    with pytest.raises(UnknownNameError) as err:
        _panda_with(_write(tmp_path, [_GOOD], ignored="[[upper, elbow]]"))
    assert err.value.name == "elbow" and "upper" in err.value.choices


def test_missing_or_empty_file(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_capsule_file(tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match="lists no capsules"):
        load_capsule_file(_write(tmp_path, []))


def test_default_names_and_link_names_in_ignored_pairs(tmp_path):
    a = {k: v for k, v in _GOOD.items() if k != "name"}
    b = dict(a, xyz=[0.0, 0.0, -0.15])
    hand = dict(a, link="panda_hand")
    data = load_capsule_file(_write(tmp_path, [a, b, hand]))
    assert [c.name for c in data.capsules] == ["panda_link3", "panda_link3_1", "panda_hand"]
    robot = _panda_with(_write(tmp_path, [a, b, hand], ignored="[[panda_link3, panda_hand]]"))
    assert capsule_pairs(robot.scene_graph, robot.capsules) == ()  # same link + ignored by link name


def test_register_after_finalize_is_refused(panda):
    from pe_drake.multibody.capsules import register_capsules

    with pytest.raises(ConfigError, match="before plant.Finalize"):
        register_capsules(panda.plant, panda.scene_graph, panda.config.capsules)


def test_fitted_radii_are_physical(g1, panda):
    for robot in (g1, panda):
        for c in robot.capsules:
            assert 0.02 < c.radius < 0.12 and 0 < c.length < 0.35 and math.isfinite(c.X_BG.sum())
