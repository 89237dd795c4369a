"""The solver's harmonic coordinates (excitation/scaling.py) and the stall rule (excitation/stall.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pe_drake.config import ExcitationConfig, SolverConfig
from pe_drake.excitation.constraints.torque import TorqueConstraint
from pe_drake.excitation.problem import ExcitationProblem
from pe_drake.excitation.program import build_excitation_program
from pe_drake.excitation.scaling import ScaledResult, harmonic_scale, scaled_copy
from pe_drake.excitation.solve import check_margins, solve_excitation
from pe_drake.excitation.stall import StallRule

CONFIG = ExcitationConfig(harmonics=3, omega=2 * math.pi / 8, cost_samples=24, constraint_samples=48, rest_at_ends=True)


def _program(panda, **kw):
    problem = ExcitationProblem(panda, CONFIG)
    program = build_excitation_program(problem, [TorqueConstraint(panda)], **{"scaling": "harmonic", **kw})
    # a Drake constraint a user adds on alpha: it must reach the solver too
    program.prog.AddLinearConstraint(np.ones((1, 2)), [-0.3], [0.3], program.alpha[:2])
    return problem, program


def test_harmonic_scale_is_the_amplitude_the_limits_allow_each_harmonic():
    """d_jk = min(half range, v_max/(kω), vdot_max/(kω)²) / the same for k = 1; 1 for q0 and
    for a joint without finite limits."""
    from types import SimpleNamespace

    limits = SimpleNamespace(
        q_lower=np.array([-1.0, -np.inf]), q_upper=np.array([1.0, np.inf]),
        v_max=np.array([2.0, np.inf]), vd_max=np.array([4.0, np.inf]),
    )
    d = harmonic_scale(3, 1.0, limits)
    # joint 0: k = 1: min(1, 2, 4) = 1; k = 2: min(1, 1, 1) = 1; k = 3: min(1, 2/3, 4/9) = 4/9
    expected_a = [1.0, 1.0, 4 / 9, 1.0, 1.0, 1.0]
    np.testing.assert_allclose(d, expected_a + expected_a + [1.0, 1.0])


def _autodiff_jacobian(evaluator, beta):
    from pydrake.autodiffutils import ExtractGradient, InitializeAutoDiff

    y = evaluator.Eval(InitializeAutoDiff(beta).ravel())
    return ExtractGradient(np.atleast_1d(y))


def test_every_scaled_binding_is_the_original_at_d_beta_with_the_chain_rule(panda):
    """Values equal the original's at alpha = d·beta; Jacobians match central differences in
    beta (our own evaluators take the double path with a hand-written chain rule; Drake's
    linear rows and the user's constraint are rebound too)."""
    problem, program = _program(panda)
    d = program.variable_scale
    scaled = scaled_copy(program.prog, program.alpha, d, program.own_evaluators())
    assert len(scaled.prog.GetAllCosts()) == len(program.prog.GetAllCosts())
    assert len(scaled.prog.GetAllConstraints()) == len(program.prog.GetAllConstraints())
    index = {v.get_id(): i for i, v in enumerate(scaled.beta)}
    alpha = problem.initial_guess(seed=3)
    beta = alpha / d
    originals = list(program.prog.GetAllCosts()) + list(program.prog.GetAllConstraints())
    copies = list(scaled.prog.GetAllCosts()) + list(scaled.prog.GetAllConstraints())
    for original, copy in zip(originals, copies):
        idx = [index[v.get_id()] for v in copy.variables()]
        b = beta[idx]
        expected = np.atleast_1d(original.evaluator().Eval(alpha[idx]))
        np.testing.assert_allclose(np.atleast_1d(copy.evaluator().Eval(b)), expected, rtol=1e-12, atol=1e-12)
        J = _autodiff_jacobian(copy.evaluator(), b)
        # the chain rule: ∂/∂beta = ∂/∂alpha · d (to rounding: d·(alpha/d) is not alpha bit for bit)
        np.testing.assert_allclose(J, _autodiff_jacobian(original.evaluator(), alpha[idx]) * d[idx], rtol=1e-8,
                                   atol=1e-10 * max(1.0, np.abs(J).max()))
        if copy.evaluator().get_description().startswith("joint limits"):
            continue  # a window row is a maximum over time, with kinks: test_limit_windows.py checks it
        # and against central differences in beta
        h = 1e-6
        ev = copy.evaluator()
        numeric = np.stack(
            [(np.atleast_1d(ev.Eval(b + h * e)) - np.atleast_1d(ev.Eval(b - h * e))) / (2 * h) for e in np.eye(len(b))], axis=1
        )
        np.testing.assert_allclose(J, numeric, rtol=1e-5, atol=1e-6 * max(1.0, np.abs(numeric).max()))


def test_scaled_result_answers_in_alpha(panda):
    from pydrake.solvers import IpoptSolver

    problem, program = _program(panda)
    d = program.variable_scale
    scaled = scaled_copy(program.prog, program.alpha, d, program.own_evaluators())
    x0 = problem.initial_guess(seed=0)
    raw = IpoptSolver().Solve(scaled.prog, x0 / d)
    result = ScaledResult(raw, scaled)
    beta = raw.GetSolution(scaled.beta)
    np.testing.assert_allclose(result.GetSolution(program.alpha), d * beta)
    assert result.GetSolution(program.alpha[4]) == pytest.approx(d[4] * beta[4])
    assert result.is_success() == raw.is_success()


def test_scaled_and_unscaled_solves_both_give_valid_motions(panda):
    """Both coordinates end inside every limit at 1 kHz, at rest at the ends, with the user's
    constraint held."""
    for scaling in ("harmonic", "none"):
        problem, program = _program(panda, scaling=scaling, stall=None)
        result = solve_excitation(program, SolverConfig(max_iterations=60), problem.initial_guess(seed=1))
        assert result.success, result.message
        assert min(check_margins(problem, result.x, program.constraints).values()) >= -1e-6
        assert abs(result.x[0] + result.x[1]) <= 0.3 + 1e-6
        _, v, vd = problem.trajectory(result.x).evaluate(np.array([0.0, problem.period]))
        assert np.abs(v).max() < 1e-6 and np.abs(vd).max() < 1e-6


def test_unknown_scaling_is_refused(panda):
    from pe_drake.exceptions import ConfigError

    with pytest.raises(ConfigError, match="harmonic, none"):
        build_excitation_program(ExcitationProblem(panda, CONFIG), scaling="diagonal")


def test_stall_rule():
    rule = StallRule(window=3, improvement=0.1, min_evaluations=5)
    inf = math.inf
    assert not rule.stalled([inf, inf, 10.0, 10.0])  # too few evaluations
    assert not rule.stalled([inf, inf, 10.0, 10.0, 10.0])  # inf three evaluations ago
    assert rule.stalled([10.0, 10.0, 10.0, 9.5, 9.5])  # 5 % in 3 evaluations
    assert not rule.stalled([10.0, 10.0, 10.0, 8.5, 8.5])  # 15 %
    # a logarithmic criterion: log(10) − log(9.5) = 0.051 < −log(0.9) = 0.105
    logs = list(np.log([10.0, 10.0, 10.0, 9.5, 9.5]))
    assert rule.stalled(logs, logarithmic=True)
    assert not rule.stalled(list(np.log([10.0, 10.0, 10.0, 8.5, 8.5])), logarithmic=True)
    for bad in ({"window": 0}, {"min_evaluations": 1.5}, {"improvement": 1.0}, {"window": True}):
        with pytest.raises(ValueError):
            StallRule(**bad)


def test_a_stalled_solve_returns_a_valid_motion_and_says_so(panda):
    """A rule that fires early: the solve ends with status kStalled, a valid motion (every
    limit at 1 kHz, at rest at the ends) and an iteration count from IPOPT's log."""
    problem = ExcitationProblem(panda, CONFIG)
    program = build_excitation_program(
        problem, [TorqueConstraint(panda)], stall=StallRule(window=5, improvement=0.5, min_evaluations=20)
    )
    result = solve_excitation(program, SolverConfig(max_iterations=200), problem.initial_guess(seed=2))
    assert result.status == "kStalled", result.message
    assert "stalled" in result.message
    assert result.success and not result.converged, result.message
    assert min(result.margins.values()) >= -1e-6
    assert result.nit is not None and 0 < result.nit < 200
    assert result.nfev >= 20


def test_nlopt_runs_without_the_stall_rule(panda):
    """NLopt's callbacks swallow exceptions: the rule is off there and the solve ends as NLopt
    ends it."""
    config = ExcitationConfig(harmonics=3, omega=2 * math.pi / 8, cost_samples=24, constraint_samples=48)
    problem = ExcitationProblem(panda, config)
    program = build_excitation_program(problem, stall=StallRule(window=2, improvement=0.9, min_evaluations=3))
    options = SolverConfig(name="nlopt", algorithm="LD_SLSQP", max_iterations=30)
    result = solve_excitation(program, options, problem.initial_guess(seed=0))
    assert result.status != "kStalled"
    assert result.nfev > 3


def test_own_evaluators_take_the_double_path(panda):
    """pe_drake's cost, window rows and sampled rows are found by identity and rebound without
    AutoDiff arithmetic; only other evaluators go through Drake's Eval at d·beta."""
    problem, program = _program(panda)
    scaled = scaled_copy(program.prog, program.alpha, program.variable_scale, program.own_evaluators())
    assert scaled.rebound.count("own") == len(program.own_evaluators()) == 1 + problem.n + 1
    # the rest at the ends and the user's row are linear: rebound as A·d
    assert scaled.rebound.count("linear") == 2 and "eval" not in scaled.rebound
