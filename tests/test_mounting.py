"""Mounting (issue 21): the base pose of the config places a URDF that already welds to a
``world`` link, gravity acts accordingly, and the floor is the mounting plane."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from pe_drake.config import Config, EnvironmentConfig, ExcitationConfig
from pe_drake.excitation.constraints.environment import environment_from_config
from pe_drake.multibody.registry import builtin_config
from pe_drake.multibody.robot import load_robot

CEILING = ([0.2, -0.1, 2.5], [0.0, 1.0, 0.0, 0.0])  # upside down, 2.5 m up
WALL = ([0.0, 1.0, 1.2], [np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0])  # base z along -y


def mounted(position, quaternion_wxyz):
    cfg = builtin_config("ur5").robot
    return load_robot(dataclasses.replace(cfg, base_position=list(position), base_quaternion_wxyz=list(quaternion_wxyz)))


def rotation_wxyz(q) -> np.ndarray:
    w, x, y, z = np.asarray(q, float) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def gravity_torques(upright, q: np.ndarray, g: np.ndarray) -> np.ndarray:
    """τ_g(q) = Σ_b J_b(q)ᵀ m_b (−g), from the upright plant's centre-of-mass Jacobians
    (not its gravity field): the torque that holds the robot still under gravity g."""
    from pydrake.multibody.tree import JacobianWrtVariable

    plant, ctx = upright.plant, upright.plant.CreateDefaultContext()
    plant.SetPositions(ctx, q)
    world = plant.world_frame()
    tau = np.zeros(upright.n)
    for body in upright.bodies:
        m = body.default_mass()
        J = plant.CalcJacobianTranslationalVelocity(
            ctx, JacobianWrtVariable.kV, body.body_frame(), body.default_com().reshape(3, 1), world, world
        )
        tau += J.T @ (-m * g)
    return tau


@pytest.mark.parametrize("mount", [CEILING, WALL], ids=["ceiling", "wall"])
def test_mount_changes_gravity_torques(mount):
    upright = load_robot("ur5")
    robot = mounted(*mount)
    R_WB = rotation_wxyz(mount[1])
    g_W = np.array([0.0, 0.0, -9.81])
    rng = np.random.default_rng(3)
    q = rng.uniform(-2.0, 2.0, (5, robot.n))
    zeros = np.zeros_like(q)
    tau = robot.inverse_dynamics(q, zeros, zeros)
    want = np.array([gravity_torques(upright, qk, R_WB.T @ g_W) for qk in q])  # gravity in the base frame
    np.testing.assert_allclose(tau, want, atol=1e-9 * np.abs(want).max())
    # and not the upright robot's torques
    assert np.abs(tau - upright.inverse_dynamics(q, zeros, zeros)).max() > 1.0
    X = robot.body_poses(q[:1])[0, robot.plant.GetBodyByName(robot.root_link).index()]
    assert any("world_joint" in note for note in robot.notes) and not upright.notes
    np.testing.assert_allclose(X[:3, :3], R_WB, atol=1e-12)
    np.testing.assert_allclose(X[:3, 3], mount[0], atol=1e-12)


def test_upright_gravity_reference_matches_drake():
    upright = load_robot("ur5")
    q = np.random.default_rng(1).uniform(-2, 2, (3, upright.n))
    want = np.array([gravity_torques(upright, qk, np.array([0, 0, -9.81])) for qk in q])
    np.testing.assert_allclose(upright.inverse_dynamics(q, 0 * q, 0 * q), want, atol=1e-9)


def test_ceiling_floor_is_the_ceiling():
    """The floor is the mounting plane: a ceiling-mounted arm keeps below it."""
    robot = mounted(*CEILING)
    env = environment_from_config(robot, ExcitationConfig(collision_margin=0.005), EnvironmentConfig())
    np.testing.assert_allclose(env.floor_normal, [0, 0, -1], atol=1e-12)
    q = robot.nominal_posture()
    p = env.ends(q[None], jacobian=False)[0]  # (1, C, 2, 3)
    d = env.clearances(q[None])[0][0]
    for row, (c, e) in enumerate(env.floor_ends):
        np.testing.assert_allclose(d[row], CEILING[0][2] - p[0, c, e, 2] - env.capsules[c].radius, atol=1e-12)
    assert d.min() > 0.005  # the upright nominal posture, upside down: below the ceiling
    # the gradient of the tilted plane: finite differences
    _, g = env.clearances(q[None], derivatives=True)
    h = 1e-6
    for k in range(robot.n):
        e = np.zeros(robot.n)
        e[k] = h
        fd = (env.clearances((q + e)[None])[0] - env.clearances((q - e)[None])[0]) / (2 * h)
        np.testing.assert_allclose(g[0, :, k], fd[0], atol=1e-6)


def test_wall_floor_offset_along_the_base_axis():
    robot = mounted(*WALL)
    env = environment_from_config(robot, ExcitationConfig(), EnvironmentConfig(floor_height=WALL[0][2] + 0.1))
    n = rotation_wxyz(WALL[1])[:, 2]
    np.testing.assert_allclose(env.floor_normal, n, atol=1e-12)
    np.testing.assert_allclose(env.floor_height, n @ WALL[0] + 0.1, atol=1e-12)


def test_trajectory_file_records_the_mount(tmp_path):
    from pe_drake.cli import main

    cfg = tmp_path / "ceiling.yaml"
    cfg.write_text(
        "robot:\n  base_position: [0.2, -0.1, 2.5]\n  base_quaternion_wxyz: [0, 1, 0, 0]\n"
        "excitation:\n  harmonics: 2\n  cost_samples: 20\n  constraint_samples: 40\n"
    )
    out = tmp_path / "out"
    # 20 iterations: after 3 the hanging UR5 was still at its start's soft_cond (7e5, far from
    # the 344 it had evaluated), which is no result and writes no trajectory (issue 38)
    code = main(["optimize", "--robot", "ur5", "--config", str(cfg), "--out", str(out), "--max-iterations", "20",
                 "--quiet", "--csv-rate", "10"])
    assert code in (0, 1)
    data = json.loads((out / "trajectory.json").read_text())
    assert data["base_pose"]["position"] == pytest.approx([0.2, -0.1, 2.5])
    assert data["base_pose"]["quaternion_wxyz"] == pytest.approx([0, 1, 0, 0])
    ceiling = dataclasses.replace(builtin_config("ur5").robot, base_position=[0.2, -0.1, 2.5], base_quaternion_wxyz=[0, 1, 0, 0])
    robot = load_robot(Config(robot=ceiling))
    # the playback replays the robot's own plant: the root hangs upside down
    X = robot.body_poses(np.zeros((1, robot.n)))[0, robot.plant.GetBodyByName(robot.root_link).index()]
    assert X[2, 2] == pytest.approx(-1.0)
