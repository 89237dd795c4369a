"""Shared fixtures: robots (built once per session) and seeded random states."""

from __future__ import annotations

import logging

import numpy as np
import pytest


@pytest.fixture(scope="session", autouse=True)
def _single_threaded_blas():
    """Small matrices: BLAS threads only add contention (pe_drake.threads)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield


@pytest.fixture(scope="session", autouse=True)
def _quiet_drake():
    import pydrake.common  # noqa: F401  (pydrake resets the logger level at import)

    logging.getLogger("drake").setLevel(logging.ERROR)


_ROBOTS: dict = {}


def get_robot(name: str):
    """A built-in robot, loaded once per test session."""
    from pe_drake.multibody.robot import load_robot

    if name not in _ROBOTS:
        _ROBOTS[name] = load_robot(name)
    return _ROBOTS[name]


@pytest.fixture(scope="session")
def panda():
    return get_robot("panda")


@pytest.fixture(scope="session")
def ur5():
    return get_robot("ur5")


@pytest.fixture(scope="session")
def g1():
    return get_robot("g1")


def central_gradient(f, x, idx, h=1e-6) -> np.ndarray:
    """Central differences of the scalar f at x along the coordinates idx."""
    out = []
    for i in idx:
        e = np.zeros_like(x)
        e[i] = h
        out.append((f(x + e) - f(x - e)) / (2 * h))
    return np.array(out)


def sampled_gradient_error(problem, alpha, count, rng):
    """The analytic gradient of ``problem`` at ``alpha`` against central differences along
    ``count`` coordinates drawn by ``rng``: (relative error, coordinates, numeric gradient)."""
    grad = problem.evaluate(alpha).grad
    idx = rng.choice(len(alpha), count, replace=False)
    numeric = central_gradient(problem.value, alpha, idx)
    return np.linalg.norm(grad[idx] - numeric) / np.linalg.norm(numeric), idx, numeric


def random_postures(robot, count: int, seed: int) -> np.ndarray:
    """``count`` postures drawn uniformly within the joint limits, shape (count, n)."""
    rng = np.random.default_rng(seed)
    return rng.uniform(robot.limits.q_lower, robot.limits.q_upper, (count, robot.n))


def random_states(robot, count: int, seed: int = 0):
    """q within limits, v and vdot of a few rad/s, each (count, n)."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(robot.limits.q_lower, robot.limits.q_upper, (count, robot.n))
    v = rng.uniform(-2, 2, (count, robot.n))
    vd = rng.uniform(-5, 5, (count, robot.n))
    return q, v, vd


@pytest.fixture(scope="session")
def diagnosis_trajectory():
    """The optimized Panda trajectory the diagnosis tests simulate (tests/data)."""
    from pathlib import Path

    from pe_drake.excitation.trajectory_file import load_trajectory

    return load_trajectory(Path(__file__).parent / "data" / "diagnosis_panda_trajectory.json")[0]


def ground_wrench(robot, phi, q, v, vd) -> np.ndarray:
    """The ground wrench a model φ predicts, (S, 6) [N, N·m], static bodies included."""
    from pe_drake.multibody.regressor import RegressorModel
    from pe_drake.multibody.wrench import static_wrench

    model = RegressorModel(robot)
    out = np.empty((q.shape[0], 6))
    for s in range(0, q.shape[0], 2000):  # bounded memory: (2000, 6, 10·nb) at a time
        k = slice(s, min(s + 2000, q.shape[0]))
        out[k] = model.wrench_regressor(model.kinematics(q[k], v[k], vd[k])) @ phi
    return out + static_wrench(robot)
