"""Numerical base parameters: Y_B φ_B = Y φ, and the counts are right."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from conftest import get_robot, random_states

from pe_drake.multibody.base_parameters import compute_base_parameters, pivoted_qr_r
from pe_drake.multibody.regressor import RegressorModel


@pytest.mark.parametrize("name,count", [("panda", 43), ("ur5", 36), ("g1", 90)])
def test_base_parameter_count(name, count):
    """Panda: 43 (Gaz et al. 2019 report 43 for its 7 links); G1 arms: 90 (BUILD_NOTES.md)."""
    robot = get_robot(name)
    base = compute_base_parameters(robot)
    assert base.count == count


@pytest.mark.parametrize("name", ["panda", "ur5", "g1"])
def test_base_regressor_reproduces_torques(name):
    robot = get_robot(name)
    model = RegressorModel(robot)
    base = compute_base_parameters(robot, model=model)
    q, v, vd = random_states(robot, 20, seed=11)  # states not used to find the base
    Y = model(q, v, vd)
    tau = Y @ robot.phi_model
    tau_base = base.reduce(Y) @ base.base_values(robot.phi_model)
    assert np.abs(tau_base - tau).max() / np.abs(tau).max() < 1e-9
    # Y_B = Y X (Eq. 2)
    np.testing.assert_array_equal(Y @ base.X, base.reduce(Y))
    # Any φ: the torques depend on φ only through φ_B.
    phi = np.random.default_rng(12).normal(size=robot.phi_model.shape)
    assert np.allclose(Y @ phi, base.reduce(Y) @ base.base_values(phi), atol=1e-9 * np.abs(Y @ phi).max())


def test_base_regressor_has_full_column_rank(panda):
    model = RegressorModel(panda)
    base = compute_base_parameters(panda, model=model)
    q, v, vd = random_states(panda, 30, seed=13)
    YB = base.reduce(model(q, v, vd)).reshape(-1, base.count)
    assert np.linalg.matrix_rank(YB) == base.count


def test_base_names_are_compositions(panda):
    base = compute_base_parameters(panda)
    assert len(base.base_names) == base.count
    assert any("+" in n or " - " in n for n in base.base_names)
    # m.panda_link1 never moves a torque (its origin lies on joint 1's axis): not a base column.
    assert "m.panda_link1" not in base.base_names


def test_pivoted_qr_equals_lapack_without_ties():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(120, 30)) * rng.uniform(0.1, 10.0, 30)
    R, perm = pivoted_qr_r(A)
    _, R_lapack, perm_lapack = scipy.linalg.qr(A, mode="economic", pivoting=True)
    np.testing.assert_array_equal(perm, perm_lapack)
    np.testing.assert_allclose(np.abs(R), np.abs(R_lapack), atol=1e-12)
    Q = np.linalg.qr(A[:, perm])[0]
    np.testing.assert_allclose(Q @ R, A[:, perm], atol=1e-12)


def test_pivoted_qr_breaks_ties_by_column_order_not_rounding():
    rng = np.random.default_rng(1)
    B = rng.normal(size=(60, 4))
    B /= np.linalg.norm(B, axis=0)
    A = B[:, [0, 1, 0, 2, 3, 1]]  # columns 2 and 5 repeat 0 and 1: all six start at norm 1
    for noise in (0.0, 1e-15, -1e-15):
        _, perm = pivoted_qr_r(A * (1 + noise * np.arange(6)))  # last-bit changes of the norms
        assert perm[0] == 0
        assert set(perm[:4]) == {0, 1, 3, 4}


@pytest.mark.parametrize("name", ["panda", "g1"])
def test_base_parameters_do_not_move_with_rounding(name):
    """The same regressor with relative changes of 1e-15 (a different summation order) keeps
    the same base parameters; LAPACK's pivoting swapped 10 of G1's 90 on such a change."""
    robot = get_robot(name)
    model = RegressorModel(robot)
    base = compute_base_parameters(robot, model=model)

    class Rounded:
        num_params = model.num_params

        def __call__(self, q, v, vd):
            Y = model(q, v, vd)
            return Y * (1 + 1e-15 * np.random.default_rng(2).choice([-1.0, 1.0], size=Y.shape))

    again = compute_base_parameters(robot, model=Rounded())
    np.testing.assert_array_equal(again.independent, base.independent)
    np.testing.assert_allclose(again.K, base.K, atol=1e-8)
