"""The regressor equals Drake's inverse dynamics; its adjoint equals finite differences."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import get_robot, random_states

from pe_drake.multibody.inertia import PARAMETER_NAMES, phi_to_spatial_inertia
from pe_drake.multibody.regressor import RegressorModel

ROBOTS = ["panda", "ur5", "g1"]


@pytest.mark.parametrize("name", ROBOTS)
def test_regressor_times_model_parameters_is_drake_inverse_dynamics(name):
    robot = get_robot(name)
    model = RegressorModel(robot)
    q, v, vd = random_states(robot, 12, seed=1)
    Y = model(q, v, vd)
    assert Y.shape == (12, robot.n, 10 * robot.num_bodies)
    tau = robot.inverse_dynamics(q, v, vd)
    rel = np.abs(Y @ robot.phi_model - tau).max() / np.abs(tau).max()
    assert rel < 1e-9


@pytest.mark.parametrize("name", ["panda", "g1"])
def test_regressor_is_linear_in_arbitrary_parameters(name):
    """Y φ matches Drake for parameters other than the model's (set on a context)."""
    robot = get_robot(name)
    model = RegressorModel(robot)
    rng = np.random.default_rng(2)
    phi = robot.phi_model * (1 + 0.3 * rng.uniform(-1, 1, robot.phi_model.shape))
    ctx = robot.plant.CreateDefaultContext()
    for j, body_index in enumerate(robot.body_indices):
        body = robot.plant.get_body(robot.bodies[j].index())
        assert int(body.index()) == int(body_index)
        body.SetSpatialInertiaInBodyFrame(ctx, phi_to_spatial_inertia(phi[10 * j : 10 * j + 10]))
    q, v, vd = random_states(robot, 5, seed=3)
    from pydrake.multibody.tree import MultibodyForces

    tau = np.empty_like(q)
    forces = MultibodyForces(robot.plant)
    for t in range(5):
        robot.plant.SetPositions(ctx, q[t])
        robot.plant.SetVelocities(ctx, v[t])
        forces.SetZero()
        robot.plant.CalcForceElementsContribution(ctx, forces)
        tau[t] = robot.plant.CalcInverseDynamics(ctx, vd[t], forces) - v[t] * robot.joint_damping
    Y = model(q, v, vd)
    assert np.abs(Y @ phi - tau).max() / np.abs(tau).max() < 1e-9


def test_parameter_order_is_documented(panda):
    assert PARAMETER_NAMES == ("m", "hx", "hy", "hz", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
    assert panda.parameter_names[:2] == ("m.panda_link1", "hx.panda_link1")


def test_joint_axes_are_drake_jacobian_columns(g1):
    """S_i, the motion axes the adjoint differentiates, are Drake's Jacobian columns."""
    from pydrake.multibody.tree import JacobianWrtVariable

    model = RegressorModel(g1)
    q, v, vd = random_states(g1, 1, seed=4)
    kin = model.kinematics(q, v, vd)
    plant, ctx = g1.plant, g1.plant_context
    plant.SetPositions(ctx, q[0])
    for j in range(len(g1.body_indices)):
        body = plant.get_body(g1.bodies[j].index())
        # Spatial velocity Jacobian of the body-fixed point at the world origin.
        X_WB = plant.EvalBodyPoseInWorld(ctx, body)
        p_BoO_B = X_WB.inverse().translation()
        J = plant.CalcJacobianSpatialVelocity(
            ctx, JacobianWrtVariable.kV, body.body_frame(), p_BoO_B, plant.world_frame(), plant.world_frame()
        )
        expected = kin.S[0].T * model.moves[:, j][None, :]
        np.testing.assert_allclose(J, expected, atol=1e-12)


def _finite_difference(model, Z, q, v, vd, h=1e-6):
    out = []
    for k in range(3):
        g = np.zeros_like(q)
        for t in range(q.shape[0]):
            for i in range(q.shape[1]):
                xp = [q.copy(), v.copy(), vd.copy()]
                xm = [q.copy(), v.copy(), vd.copy()]
                xp[k][t, i] += h
                xm[k][t, i] -= h
                g[t, i] = (np.sum(Z * model(*xp)) - np.sum(Z * model(*xm))) / (2 * h)
        out.append(g)
    return out


@pytest.mark.parametrize("name", ROBOTS)
def test_adjoint_matches_central_differences(name):
    robot = get_robot(name)
    model = RegressorModel(robot)
    q, v, vd = random_states(robot, 3, seed=5)
    kin = model.kinematics(q, v, vd)
    Z = np.random.default_rng(6).normal(size=(3, robot.n, model.num_params))
    analytic = model.pullback(kin, Z)
    numeric = _finite_difference(model, Z, q, v, vd)
    for a, n, label in zip(analytic, numeric, ("q", "v", "vdot")):
        rel = np.abs(a - n).max() / np.abs(n).max()
        assert rel < 1e-6, f"d/d{label}: relative error {rel:.2e}"


def test_adjoint_of_prismatic_joint():
    """A prismatic joint (Panda finger unlocked) follows the same algebra."""
    from pe_drake.config import RobotConfig
    from pe_drake.multibody.robot import load_robot

    cfg = RobotConfig(
        model="package://example-robot-data/robots/panda_description/urdf/panda.urdf",
        joints=["panda_joint1", "panda_joint2", "panda_joint6", "panda_finger_joint1"],
        locked_positions={"panda_joint4": -1.5, "panda_finger_joint2": 0.01},
    )
    robot = load_robot(cfg)
    assert [j.kind for j in robot.joints][-1] == "prismatic"
    model = RegressorModel(robot)
    q, v, vd = random_states(robot, 3, seed=7)
    tau = robot.inverse_dynamics(q, v, vd)
    assert np.abs(model(q, v, vd) @ robot.phi_model - tau).max() / np.abs(tau).max() < 1e-9
    Z = np.random.default_rng(8).normal(size=(3, robot.n, model.num_params))
    analytic = model.pullback(model.kinematics(q, v, vd), Z)
    numeric = _finite_difference(model, Z, q, v, vd)
    for a, n in zip(analytic, numeric):
        assert np.abs(a - n).max() / np.abs(n).max() < 1e-6


@pytest.mark.parametrize("name", ["panda", "ur5", "g1"])
def test_batched_body_poses_equal_drake(name):
    robot = get_robot(name)
    model = RegressorModel(robot)
    assert model.batched_kinematics  # every built-in robot uses the batched path
    q, _, _ = random_states(robot, 30, seed=4)
    np.testing.assert_allclose(model.poses(q), model.drake_poses(q), atol=1e-12)
