"""The payload-only excitation: the 10 columns as the problem's "base", its analytic gradient,
a short motion from and to rest, trajectory.json's payload_link, and expected σ that match the
σ the identification reports."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pe_drake.excitation.payload_motion import expected_payload_std, payload_excitation_config
from pe_drake.excitation.problem import ExcitationProblem
from pe_drake.identification.payload import identify_payload
from pe_drake.multibody.payload import link_columns, payload_base_parameters
from pe_drake.simulation.payload_synthetic import payload_run, random_true_arm
from tests.conftest import central_gradient, get_robot
from tests.test_payload_identification import ROBOTS, _plan


@pytest.mark.parametrize("criterion", ["soft_cond", "dopt", "cond"])
def test_payload_criterion_is_of_the_link_columns_and_its_gradient_is_right(criterion):
    robot = get_robot("ur5")
    config = payload_excitation_config(criterion=criterion)
    problem = ExcitationProblem(robot, config, base=payload_base_parameters(robot, "tool0"))
    alpha = problem.initial_guess(seed=4, amplitude=0.3)
    q, v, vd = problem.cost_basis.evaluate_alpha(alpha, robot.n)
    Y_L = problem.rows(q, v, vd)[..., link_columns(robot, "tool0")].reshape(-1, 10)  # noise-scaled rows
    np.testing.assert_allclose(problem.regressor_block(alpha), Y_L)
    grad = problem.evaluate(alpha).grad
    idx = np.random.default_rng(0).choice(alpha.size, 12, replace=False)
    fd = central_gradient(problem.value, alpha, idx, h=1e-6)
    np.testing.assert_allclose(grad[idx], fd, rtol=2e-4, atol=1e-6 * np.abs(grad).max())


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_payload_motion_is_short_at_rest_at_both_ends_and_recorded(name, tmp_path):
    robot, plan = get_robot(name), _plan(name)
    assert plan.result.success, plan.result.message
    assert plan.motion.duration <= 15.0 and plan.motion.ramp_duration > 0
    q, v, vd = plan.motion.evaluate(np.array([0.0, plan.motion.duration]))
    np.testing.assert_allclose(v, 0.0, atol=1e-9)
    np.testing.assert_allclose(vd, 0.0, atol=1e-9)
    t = plan.motion.sample_times(1000.0)
    q, v, vd = plan.motion.evaluate(t)
    lim = robot.limits
    assert np.all(q >= lim.q_lower - 1e-9) and np.all(q <= lim.q_upper + 1e-9)
    assert np.all(np.abs(v) <= lim.v_max + 1e-9) and np.all(np.abs(vd) <= lim.vd_max + 1e-6)
    plan.write(tmp_path, robot)
    data = json.loads((tmp_path / "trajectory.json").read_text())
    assert data["payload_link"] == ROBOTS[name]
    assert data["payload_expected_std"]["mass_std"] == pytest.approx(plan.expected.mass_std)
    assert data["motion_duration"] == pytest.approx(plan.motion.duration)


def test_expected_sigma_matches_the_identified_sigma():
    """The σ printed before the run (arm known, ×2 for the unloaded pairing) is the σ the fit
    reports afterwards (which also carries the arm correction and friction), within 30 %."""
    name = "ur5"
    robot, link, plan = get_robot(name), ROBOTS[name], _plan(name)
    nominal = plan.expected.nominal
    arm = random_true_arm(robot, np.random.default_rng(8))
    loaded = payload_run(robot, plan.motion, arm, link, nominal, noise_std=0.04, seed=1)
    empty = payload_run(robot, plan.motion, arm, link, None, noise_std=0.04, seed=2)
    result = identify_payload(robot, [loaded], [empty], link)
    expected = expected_payload_std(robot, link, plan.motion, noise_std=result.noise_std, nominal=result.payload)
    ratio = np.concatenate([[result.mass_std / expected.mass_std], result.com_std / expected.com_std,
                            result.inertia_about_com_std / expected.inertia_about_com_std])
    assert np.all((ratio > 0.7) & (ratio < 1.3)), ratio


def test_expected_sigma_names_nan_only_when_a_sigma_is_nan():
    """The expected-σ line ended in "(nan: not determined)" even when every σ was finite."""
    from pe_drake.excitation.payload_motion import PayloadStd
    from pe_drake.multibody.payload import PayloadInertia

    def line(inertia_std):
        std = PayloadStd(1e-4, np.full(3, 2e-5), np.asarray(inertia_std, float),
                         PayloadInertia(1.0, np.array([0.0, 0.0, 0.05]), np.eye(3) * 1e-3),
                         np.full(6, 0.05), True, 1000.0)
        return std.summary_lines()[1]

    assert "nan" not in line([4e-5] * 6)
    assert line([4e-5, 4e-5, np.nan, 1e-5, 1e-5, 1e-5]).endswith("(nan: not determined)")
