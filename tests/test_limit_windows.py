"""Joint limits as window-maximum rows (issue 11) and the exchange step for sampled constraints."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pe_drake.config import ExcitationConfig, SolverConfig
from pe_drake.exceptions import ConfigError
from pe_drake.excitation.constraints.base import SampledConstraint, SampledValues
from pe_drake.excitation.exchange import add_violated_samples, violated_instants
from pe_drake.excitation.limit_windows import WindowMaxRows, joint_window_rows, trig_rows
from pe_drake.excitation.problem import ExcitationProblem
from pe_drake.excitation.program import build_excitation_program
from pe_drake.excitation.solve import check_margins, solve_excitation
from tests.conftest import central_gradient


def _rows(N=5, windows=10, period=10.0, seed=0):
    """Window rows of q, v, vdot (both sides) of one joint with unit scale and zero bound."""
    omega = 2 * math.pi / period
    order, sign, w = np.meshgrid(np.arange(3), [1.0, -1.0], np.arange(windows), indexing="ij")
    order, sign, w = order.ravel(), sign.ravel(), w.ravel()
    width = period / windows
    rows = WindowMaxRows(
        np.arange(1, N + 1) * omega, order, sign, np.ones(len(order)), np.zeros(len(order)), w * width, (w + 1) * width
    )
    a = np.random.default_rng(seed).normal(size=2 * N + 1) / np.r_[np.arange(1, N + 1), np.arange(1, N + 1), 1.0]
    return rows, a, omega


def _assert_matches_central_differences(rows, a, J):
    fd = central_gradient(lambda x: rows.values_and_jacobian(x)[0], a, range(len(a))).T
    assert np.allclose(J, fd, atol=1e-6 * max(1.0, np.abs(J).max()))


def test_trig_rows_are_the_time_derivatives():
    k_omega = np.arange(1, 4) * 0.7
    t = np.linspace(0.0, 5.0, 7)
    a = np.random.default_rng(1).normal(size=7)
    h = 1e-5
    for order in range(4):
        fd = (trig_rows(k_omega, t + h, order) @ a - trig_rows(k_omega, t - h, order) @ a) / (2 * h)
        assert np.allclose(trig_rows(k_omega, t, order + 1) @ a, fd, atol=1e-6)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_window_rows_equal_the_maximum_over_every_instant(seed):
    rows, a, _ = _rows(seed=seed)
    g, _ = rows.values_and_jacobian(a)
    for r in range(rows.num_rows):
        t = np.linspace(rows.start[r], rows.stop[r], 20001)
        dense = np.max(rows.gain[r] * (trig_rows(rows.k_omega, t, rows.order[r]) @ a))
        # never below the window's maximum (the limit holds at every instant), and above it
        # only by what the dense sampling misses (~x''·(2.5e-5 s)²/2)
        assert dense - 1e-9 <= g[r] <= dense + 1e-7, (r, g[r], dense)


@pytest.mark.parametrize("seed", [0, 3])
def test_window_rows_jacobian_matches_central_differences(seed):
    rows, a, _ = _rows(seed=seed)
    _, J = rows.values_and_jacobian(a)
    _assert_matches_central_differences(rows, a, J)


def test_joint_window_rows_bound_the_limits(panda):
    config = ExcitationConfig(harmonics=3, cost_samples=24, constraint_samples=48)
    problem = ExcitationProblem(panda, config)
    x = problem.initial_guess(seed=0)
    for j in range(problem.n):
        rows, idx = joint_window_rows(problem, j, 6, backoff=0.0)
        g, _ = rows.values_and_jacobian(x[idx])
        # The start is inside the limits, and each row's sign is right: the q rows of the
        # upper side measure (q_max - q_upper)/scale, those of the lower side (q_lower - q_min)/scale.
        assert np.all(g < 0)
        t = np.linspace(0.0, problem.period, 4001)
        q = problem.trajectory(x).evaluate(t)[0][:, j]
        upper = rows.order == 0
        scale = rows.gain[upper & (rows.gain > 0)][0] ** -1
        lim = panda.limits
        assert np.max(g[upper & (rows.gain > 0)]) == pytest.approx((q.max() - lim.q_upper[j]) / scale, abs=1e-6)
        assert np.max(g[upper & (rows.gain < 0)]) == pytest.approx((lim.q_lower[j] - q.min()) / scale, abs=1e-6)


def test_unknown_limit_formulation_and_bad_stride_are_refused(panda):
    problem = ExcitationProblem(panda, ExcitationConfig(harmonics=2, constraint_samples=48))
    with pytest.raises(ConfigError, match="windows, sampled"):
        build_excitation_program(problem, limits="exact")
    with pytest.raises(ConfigError, match="sample_stride"):
        build_excitation_program(problem, sample_stride=5)


def test_violated_instants_are_local_minima_below_tolerance():
    margin = np.array([0.3, -0.1, -0.2, -0.1, 0.2, 0.1, 0.2, -1e-9, 0.5])
    assert violated_instants(margin, 1e-6).tolist() == [2]
    # periodic: the minimum at the end wraps around to the start
    assert violated_instants(np.array([-0.1, 0.2, 0.3, -0.3]), 1e-6).tolist() == [3]


class _Band(SampledConstraint):
    """|q_0(t) − centre| ≤ radius as two one-sided rows, so its samples are grouped like
    balance and collision."""

    name = "band"

    def __init__(self, n, centre, radius):
        super().__init__(["q0 above", "q0 below"], [-np.inf, -np.inf], [radius, radius])
        self.n, self.centre = n, centre

    def evaluate(self, q, v, vd, derivatives=True):
        d = q[:, 0] - self.centre
        d_q = np.zeros((len(q), 2, self.n))
        d_q[:, 0, 0], d_q[:, 1, 0] = 1.0, -1.0
        return SampledValues(value=np.stack([d, -d], axis=1), d_q=d_q)


def _band_program(panda):
    # Only 8 samples of the band (K = 16, stride 2): the optimizer pushes joint 0 against the
    # band at the samples and through it in between.
    config = ExcitationConfig(harmonics=2, omega=2 * math.pi / 8, cost_samples=16, constraint_samples=16)
    problem = ExcitationProblem(panda, config)
    x0 = problem.initial_guess(seed=0)
    q, _, _ = problem.trajectory(x0).evaluate(np.linspace(0, problem.period, 801))
    band = _Band(problem.n, x0[-problem.n], 1.05 * np.abs(q[:, 0] - x0[-problem.n]).max())
    # The scenario is the path of IPOPT in alpha itself without the stall rule (the former
    # default): the exchange mechanism is what these tests check, not the formulation.
    program = build_excitation_program(problem, [band], limits="windows", sample_stride=2, scaling="none", stall=None)
    return problem, program, x0


def test_exchange_rounds_add_the_violated_instants(panda):
    """The exchange step by hand: solve, add the instants violated at 1 kHz, solve again from
    there. Each added row sits where the band was crossed, and the crossing shrinks round
    after round (these short solves stop at their iteration limit, so it need not vanish)."""
    problem, program, x = _band_program(panda)
    margins = []
    for _ in range(4):
        result = solve_excitation(program, SolverConfig(max_iterations=100), x, exchange=False)
        x = result.raw.GetSolution(program.alpha)
        margins.append(check_margins(problem, x, program.constraints)["band"])
        before = len(program.exchange_evaluators)
        added = add_violated_samples(program, x)
        if added == 0:
            break
        # each added row sits at an instant where the band is violated at x
        for ev in program.exchange_evaluators[before:]:
            g, _ = ev.values_and_jacobian(x)
            assert np.all(g.reshape(-1, 2).max(axis=1) > ev.constraint.upper[0])
    assert margins[0] < -1e-6  # the 8 grouped samples alone let the band be crossed
    assert margins[-1] > 0.5 * margins[0], margins


def test_solve_runs_the_exchange_step_within_its_budget(panda):
    """solve_excitation adds the violated instants itself (a loop that stopped adding them
    would leave ``exchange_samples`` at 0) and never exceeds the iteration budget."""
    problem, program, x0 = _band_program(panda)
    result = solve_excitation(program, SolverConfig(max_iterations=150), x0)
    assert result.exchange_samples > 0 and result.solves >= 2
    assert len(program.exchange_bindings) >= 1
    assert result.nit <= 150
    _, program, x0 = _band_program(panda)
    without = solve_excitation(program, SolverConfig(max_iterations=150), x0, exchange=False)
    assert without.exchange_samples == 0 and without.solves == 1


def test_add_violated_samples_adds_nothing_at_a_valid_point(panda):
    problem, program, x0 = _band_program(panda)
    assert add_violated_samples(program, x0) == 0
    assert program.exchange_bindings == []


def test_shrink_into_limits_scales_an_overshooting_motion_back(panda):
    from pe_drake.excitation.solve import shrink_into_limits

    problem = ExcitationProblem(panda, ExcitationConfig(harmonics=3, cost_samples=24, constraint_samples=48))
    x = problem.initial_guess(seed=0)
    big = x.copy()
    big[: -problem.n] *= 50.0  # far over the velocity and acceleration limits
    assert min(check_margins(problem, big).values()) < 0
    shrunk = shrink_into_limits(problem, big)
    margins = check_margins(problem, shrunk)
    assert min(margins.values()) >= 0 and min(margins.values()) < 1e-6  # on a limit, not inside
    assert np.array_equal(shrunk[-problem.n :], x[-problem.n :])
    assert np.allclose(shrunk[: -problem.n] / big[: -problem.n], shrunk[0] / big[0])
    # a valid motion is left as it is
    assert np.array_equal(shrink_into_limits(problem, x), x)
