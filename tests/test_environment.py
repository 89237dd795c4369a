"""Floor and box obstacles (pe_drake.excitation.constraints.environment)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import random_postures, random_states

from pe_drake.exceptions import ConfigError, InfeasibleError
from pe_drake.excitation.constraints.balance import BalanceConstraint
from pe_drake.excitation.constraints.collision import CollisionConstraint
from pe_drake.excitation.constraints.environment import (
    Box,
    EnvironmentConstraint,
    box_signed_distance,
    segment_box_distance,
)
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.robot import load_robot


def test_box_signed_distance_values_and_gradient():
    c, h = np.zeros(3), np.array([0.5, 1.0, 2.0])
    sd, n = box_signed_distance(np.array([[1.5, 0, 0], [0, 0, 0], [0, 0.9, 0], [1.5, 2.0, 0]]), c, h)
    np.testing.assert_allclose(sd, [1.0, -0.5, -0.1, np.sqrt(2)])
    rng = np.random.default_rng(0)
    p = rng.uniform(-3, 3, (50, 3))
    sd, n = box_signed_distance(p, c, h)
    eps = 1e-7
    fd = np.stack([(box_signed_distance(p + eps * e, c, h)[0] - box_signed_distance(p - eps * e, c, h)[0]) / (2 * eps)
                   for e in np.eye(3)], axis=1)
    np.testing.assert_allclose(fd, n, atol=1e-6)


def test_segment_box_distance_against_dense_sampling():
    rng = np.random.default_rng(1)
    c, h = np.array([0.2, -0.1, 0.3]), np.array([0.3, 0.2, 0.1])
    p0, p1 = rng.uniform(-1, 1, (200, 3)), rng.uniform(-1, 1, (200, 3))
    d, s, _ = segment_box_distance(p0, p1, c, h)
    grid = np.linspace(0, 1, 20001)
    pts = p0[:, None] + grid[None, :, None] * (p1 - p0)[:, None]
    dense = box_signed_distance(pts, c, h)[0].min(axis=1)
    assert np.all(d <= dense + 1e-12) and np.all(d >= dense - 2e-4)  # grid step 5e-5 × slope <= 3.5


@pytest.fixture(scope="module")
def panda_env(panda):
    boxes = [Box(np.array([0.5, 0.0, 0.2]), np.array([0.3, 0.6, 0.4]), "table")]
    return EnvironmentConstraint(panda, 0.01, floor_height=0.0, boxes=boxes, aggregate=False)


def test_panda_rows_skip_capsules_that_cannot_move_up_or_down(panda_env):
    names = {label.split(".")[0] for label in panda_env.row_labels if label.endswith("/floor")}
    assert "link0" not in names  # the base is welded to the world
    assert "link1_a" not in names  # joint 1 turns about the vertical axis: its height is fixed
    assert "link7" in names or any(n.startswith("link7") for n in names)


@pytest.mark.parametrize("aggregate", [False, True])
@pytest.mark.parametrize("with_box", [True, False])  # floor alone: its rows take only ∂z/∂q
def test_jacobian_matches_central_differences(panda, aggregate, with_box):
    boxes = [Box(np.array([0.5, 0.0, 0.2]), np.array([0.3, 0.6, 0.4]), "table")] if with_box else []
    c = EnvironmentConstraint(panda, 0.01, floor_height=0.0, boxes=boxes, aggregate=aggregate, smoothing=0.05)
    q, v, vd = random_states(panda, 5, seed=3)
    out = c.evaluate(q, v, vd)
    eps = 1e-6
    for j in range(panda.n):
        dq = np.zeros_like(q)
        dq[:, j] = eps
        fd = (c.evaluate(q + dq, v, vd, False).value - c.evaluate(q - dq, v, vd, False).value) / (2 * eps)
        np.testing.assert_allclose(out.d_q[:, :, j], fd, atol=1e-6, rtol=1e-5)
    assert np.abs(out.d_q).max() > 0.01


def test_floor_rows_are_end_heights_minus_radius(panda):
    c = EnvironmentConstraint(panda, 0.0, floor_height=0.1, aggregate=False)
    q = panda.nominal_posture()[None]
    d = c.clearances(q)[0][0]
    poses = panda.body_poses(q)[0]  # indexed by Drake body index
    for r, (k, e) in enumerate(c.floor_ends):
        cap = c.capsules[k]
        X = poses[cap.body_index]
        z = (cap.p_BS[e] @ X[:3, :3].T + X[:3, 3])[2]
        assert d[r] == pytest.approx(z - cap.radius - 0.1, abs=1e-12)


def test_posture_below_the_floor_is_refused(panda):
    c = EnvironmentConstraint(panda, 0.01, floor_height=1.5)
    with pytest.raises(InfeasibleError, match="floor"):
        c.check_posture(panda.nominal_posture())


@pytest.mark.parametrize("spec, match", [
    ({"center": [0, 0], "size": [1, 1, 1]}, "center"),
    ({"center": [0, 0, 0], "size": [1, -1, 1]}, "size"),
    ({"center": "a", "size": [1, 1, 1]}, "center"),
    ({"center": [0, 0, float("nan")], "size": [1, 1, 1]}, "center"),
])
def test_bad_boxes_are_refused(spec, match):
    with pytest.raises(ConfigError, match=match):
        Box.from_spec(spec, 2)


def test_batched_capsule_ends_and_jacobians_equal_drakes(panda_env, panda):
    """The batched ends and their Jacobians (issue 11) against Drake's per-sample queries."""
    q = random_postures(panda, 10, seed=5)
    p, J = panda_env.ends(q, jacobian=True)
    p_drake, J_drake = panda_env.drake_ends(q, jacobian=True)
    assert np.abs(p - p_drake).max() < 1e-13
    assert np.abs(J - J_drake).max() < 1e-13
    assert np.abs(J).max() > 0.1


@pytest.mark.parametrize("robot_name", ["panda", "g1"])
def test_constraints_on_drakes_per_sample_queries_equal_the_batched_ones(robot_name):
    """The fallback for joint types the batched forward kinematics does not handle: the
    balance, collision and floor constraints on Drake's per-sample queries (a robot whose
    shared kinematics model is not batched) give the batched values and Jacobians."""
    batched_robot, drake_robot = load_robot(robot_name), load_robot(robot_name)
    drake_robot.shared_kinematics = RegressorModel(drake_robot, batched=False, keep_last_poses=True)
    constraints = []
    for robot in (batched_robot, drake_robot):
        made = [CollisionConstraint(robot, 0.01)]
        if robot_name == "panda":
            boxes = [Box(np.array([0.5, 0.0, 0.2]), np.array([0.3, 0.6, 0.4]), "table")]
            made.append(EnvironmentConstraint(robot, 0.01, floor_height=0.0, boxes=boxes, aggregate=False))
        else:
            made.append(BalanceConstraint(robot, 0.05))
        constraints.append(made)
    assert not drake_robot.shared_kinematics.batched_kinematics
    q = random_postures(batched_robot, 6, seed=9)
    for fast, slow in zip(*constraints):
        a, b = fast.evaluate(q, q, q), slow.evaluate(q, q, q)
        np.testing.assert_allclose(a.value, b.value, atol=1e-12)
        np.testing.assert_allclose(a.d_q, b.d_q, atol=1e-11)
        assert np.abs(a.d_q).max() > 1e-3


def test_capsules_only_on_fixed_links_are_refused_with_a_reason(panda):
    """A model whose capsules all sit on links no excited joint moves (example-robot-data's
    simple_humanoid) raised an IndexError inside the floor rows."""
    import copy

    moving = {int(b) for b in panda.body_indices}
    robot = copy.copy(panda)
    robot.capsules = tuple(c for c in panda.capsules if c.body_index not in moving)
    assert robot.capsules  # the base's capsule
    with pytest.raises(ConfigError, match="none of its 1 collision capsule"):
        EnvironmentConstraint(robot, 0.01, floor_height=0.0)
