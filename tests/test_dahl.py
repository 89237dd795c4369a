"""The Dahl pre-sliding friction state (issue 13): exact path integration and the Drake system."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from pe_drake.exceptions import ConfigError
from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.multibody.dahl import dahl_friction_system, dahl_state
from pe_drake.simulation.simulation import simulate
from pe_drake.simulation.truth import ControlTruth, make_truth
from tests.conftest import get_robot
from tests.test_diagnosis import TRAJECTORY


def _path(t):
    q = 0.05 * np.sin(2 * np.pi * 0.7 * t) + 0.02 * np.sin(2 * np.pi * 1.9 * t + 0.4)
    v = 0.05 * 2 * np.pi * 0.7 * np.cos(2 * np.pi * 0.7 * t) + 0.02 * 2 * np.pi * 1.9 * np.cos(2 * np.pi * 1.9 * t + 0.4)
    return q, v


def test_exact_integration_matches_the_ode():
    """z from the step formula equals the ODE dz/dt = (v − |v| z)/x_p integrated finely."""
    x_p = 0.02
    t = np.linspace(0.0, 3.0, 3001)
    q, _ = _path(t)
    z = dahl_state(q, x_p)

    def rhs(time, y):
        v = _path(np.array([time]))[1][0]
        return [(v - abs(v) * y[0]) / x_p]

    ode = solve_ivp(rhs, (0.0, 3.0), [0.0], t_eval=t, rtol=1e-9, atol=1e-11, max_step=1e-3)
    np.testing.assert_allclose(z, ode.y[0], atol=2e-4)
    # Sliding far from reversals: z → sgn v (the Coulomb limit, in sliding only); bounded by 1.
    assert np.max(np.abs(z)) <= 1.0
    assert np.min(z[np.argmax(q)]) > 0.9  # after a long positive stroke


def test_grid_and_joints_broadcast():
    t = np.linspace(0.0, 2.0, 501)
    q, _ = _path(t)
    Q = np.column_stack([q, -2 * q])
    grid = np.array([[0.01, 0.01], [0.04, 0.04]])
    z = dahl_state(Q, grid)
    assert z.shape == (501, 2, 2)
    np.testing.assert_allclose(z[:, 1, 0], dahl_state(q, 0.04))
    np.testing.assert_allclose(z[:, 0, 1], dahl_state(-2 * q, 0.01))
    # A larger pre-sliding displacement builds the force more slowly after the start.
    assert abs(z[20, 0, 0]) > abs(z[20, 1, 0])


def test_drake_system_derivative_and_output():
    pytest.importorskip("pydrake")
    system = dahl_friction_system(np.array([0.8, 0.0]), np.array([0.02, 0.05]))
    ctx = system.CreateDefaultContext()
    system.get_input_port(0).FixValue(ctx, [0.1, 0.2, 0.5, -0.3])
    ctx.SetContinuousState([0.25, -0.5])
    d = system.AllocateTimeDerivatives()
    system.CalcTimeDerivatives(ctx, d)
    np.testing.assert_allclose(d.CopyToVector(), [(0.5 - 0.5 * 0.25) / 0.02, (-0.3 - 0.3 * -0.5) / 0.05])
    np.testing.assert_allclose(system.get_output_port(0).Eval(ctx), [-0.8 * 0.25, 0.0])


def test_simulated_robot_carries_the_dahl_torque():
    """simulate: the recorded torque of a joint with pre-sliding friction is the effect-free
    one plus F_c·z(q) (the controller supplies the friction); the truth file names it."""
    robot = get_robot("panda")
    trajectory, _ = load_trajectory(TRAJECTORY)
    control = ControlTruth(rate_hz=500.0)
    fc, x_p = 0.5, 0.02
    effects = {"presliding_friction": {"panda_joint3": fc}, "presliding_stiffness": {"panda_joint3": fc / x_p}}
    with_dahl, truth = simulate(robot, trajectory, make_truth(robot, effects, control=control), 3.0)
    without, _ = simulate(robot, trajectory, make_truth(robot, control=control), 3.0)
    extra = with_dahl.tau[:, 2] - without.tau[:, 2]
    z = dahl_state(with_dahl.q[:, 2], x_p)
    assert np.sqrt(np.mean((extra - fc * z) ** 2)) < 0.03 * fc
    assert truth["effects"]["presliding_friction"]["values"]["panda_joint3"] == fc
    assert truth["effects"]["presliding_friction"]["stiffness"]["panda_joint3"] == pytest.approx(fc / x_p)


def test_presliding_friction_needs_a_stiffness():
    with pytest.raises(ConfigError, match=r"presliding_stiffness\['panda_joint2'\]"):
        make_truth(get_robot("panda"), {"presliding_friction": {"panda_joint2": 0.3}})
