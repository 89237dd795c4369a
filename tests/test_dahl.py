"""The Dahl pre-sliding friction state (issue 13): exact path integration and the Drake system."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from pe_drake.identification.dahl import dahl_friction_system, dahl_state


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
    # Sliding far from reversals: z → sgn v (the Coulomb limit); bounded by 1.
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
