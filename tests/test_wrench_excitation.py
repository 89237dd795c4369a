"""Excitation for the ground wrench (issue 14): the criterion's analytic gradient and scaling."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import get_robot, sampled_gradient_error

from pe_drake.config import ExcitationConfig
from pe_drake.config_sections import NoiseStdConfig
from pe_drake.exceptions import ConfigError
from pe_drake.excitation.problem import ExcitationProblem

DATA = Path(__file__).parent / "data"
PAPER = ExcitationConfig(harmonics=10, omega=math.pi / 4, cost_samples=40, criterion="cond")


@pytest.mark.parametrize("measurement, criterion", [("base_wrench", "cond"), ("both", "cond"), ("base_wrench", "log_cond")])
def test_wrench_criterion_gradient_matches_central_differences(measurement, criterion):
    config = dataclasses.replace(PAPER, measurement=measurement, criterion=criterion)
    problem = ExcitationProblem(get_robot("g1"), config)
    assert problem.base.count == 96
    if criterion == "cond":  # a realistic start: no nearly unobservable direction in C
        assert 100 < problem.value(problem.initial_guess(seed=1, amplitude=0.3)) < 1e5
    alpha = problem.initial_guess(seed=1, amplitude=0.3)
    rel, _, _ = sampled_gradient_error(problem, alpha, 20, np.random.default_rng(0))
    assert rel < 1e-6, f"relative error {rel:.2e}"


def test_wrench_cond_does_not_depend_on_units():
    """Moments in N·mm with their noise in N·mm: the same C up to a row scaling, the same cond."""
    g1 = get_robot("g1")
    base_config = dataclasses.replace(PAPER, measurement="base_wrench")
    problem = ExcitationProblem(g1, base_config)
    alpha = problem.initial_guess(seed=2, amplitude=0.3)
    noise = NoiseStdConfig(force=0.5, moment=0.05)
    mm = NoiseStdConfig(force=0.5, moment=50.0)
    a = ExcitationProblem(g1, dataclasses.replace(base_config, noise_std=noise), base=problem.base)
    b = ExcitationProblem(g1, dataclasses.replace(base_config, noise_std=mm), base=problem.base)
    C_a, C_b = a.stacked(alpha), b.stacked(alpha)
    # A moment in N·mm is 1000× the N·m value; its noise too: b's moment rows are a's / 1000.
    assert np.allclose(C_b.reshape(-1, 6, problem.base.count)[:, 3:] * 1000, C_a.reshape(-1, 6, problem.base.count)[:, 3:])
    # ... which is what noise-weighting removes: the data of b in N·mm gives a's C.
    C_b_mm = C_b.reshape(-1, 6, problem.base.count).copy()
    C_b_mm[:, 3:] *= 1000.0
    assert a.value(alpha) == pytest.approx(np.linalg.cond(C_b_mm.reshape(-1, problem.base.count)), rel=1e-9)


def test_joint_torque_measurement_is_today_behaviour():
    g1 = get_robot("g1")
    default = ExcitationProblem(g1, PAPER)
    alpha = default.initial_guess(seed=3, amplitude=0.3)
    assert default.base.count == 90
    assert np.array_equal(default.stacked(alpha), ExcitationProblem(g1, PAPER, base=default.base).stacked(alpha))


def test_too_few_cost_samples_for_the_wrench_is_refused():
    config = dataclasses.replace(PAPER, measurement="base_wrench", cost_samples=12)
    message = "cost_samples = 12 gives 72 rows of base_wrench for 96 base parameters: use at least 16"
    with pytest.raises(ConfigError, match=message):
        ExcitationProblem(get_robot("g1"), config)


def test_wrench_optimized_motion_is_better_conditioned_on_the_wrench_rows():
    """tests/data/g1_base_wrench_optimized.json (``optimize --robot g1 --measurement base_wrench``,
    150 IPOPT iterations, balance and capsules as in the paper) against the joint-torque-optimized
    motion of the same start and random motions that keep balance and collision."""
    from pe_drake.excitation.baseline import generate_candidates
    from pe_drake.excitation.trajectory_file import load_trajectory
    from pe_drake.multibody.registry import builtin_config

    g1 = get_robot("g1")
    excitation = dataclasses.replace(builtin_config("g1").excitation, measurement="base_wrench", criterion="cond")
    problem = ExcitationProblem(g1, excitation)
    conds = {}
    for name in ("base_wrench", "joint_torque"):
        trajectory, _ = load_trajectory(DATA / f"g1_{name}_optimized.json")
        conds[name] = problem.value(trajectory.alpha)
    randoms = generate_candidates(g1, excitation, 3, seed=5, amplitude=0.1).candidates
    conds["random"] = min(c.cond for c in randoms)
    assert conds["base_wrench"] < 60  # 50.9 when written
    assert 3 * conds["base_wrench"] < conds["joint_torque"]  # 978
    assert 3 * conds["base_wrench"] < conds["random"]


def test_base_parameters_of_other_rows_are_refused():
    """A pool or caller passing the joint-torque base to a wrench problem would select the
    wrong columns of C silently."""
    g1 = get_robot("g1")
    torque_base = ExcitationProblem(g1, PAPER).base
    with pytest.raises(ConfigError, match="base parameters given are those of the joint_torque rows"):
        ExcitationProblem(g1, dataclasses.replace(PAPER, measurement="base_wrench"), base=torque_base)
