"""Numerical base parameters: Y_B φ_B = Y φ, and the counts are right."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import scipy.linalg
from conftest import get_robot, random_states

from pe_drake.multibody.base_parameters import RANK_GAP_RATIO, compute_base_parameters, pivoted_qr_r
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.registry import example_robot_data_dir
from pe_drake.multibody.robot import load_robot

SO101 = "robots/so_arm_description/urdf/so101.urdf"


@pytest.mark.parametrize("name,count", [("panda", 43), ("ur5", 36), ("g1", 90)])
def test_base_parameter_count(name, count):
    """Panda: 43 (Gaz et al. 2019 report 43 for its 7 links); G1 arms: 90 (BUILD_NOTES.md)."""
    robot = get_robot(name)
    base = compute_base_parameters(robot)
    assert base.count == count
    assert base.dropped == () and base.rank_note is None  # no gap: the rank is the numerical one


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


def _exact_angles(text: str) -> str:
    """The URDF with 3.14159 and 1.5708 written as π and π/2 to double precision."""
    text = re.sub(r"(?<![\d.])3\.14159(?!\d)", repr(math.pi), text)
    return re.sub(r"(?<![\d.])1\.5708(?!\d)", repr(math.pi / 2), text)


def test_rounded_urdf_angles_keep_the_exact_count(tmp_path):
    """Issue 21: SO-101's URDF writes 1.5708 for π/2, which tilts the vertical pan axis by
    µrad; the first moments of the shoulder link then move the pan torque by 1e-6 of the
    rest, and a fixed tolerance kept them: 38 base parameters instead of 36."""
    shipped = example_robot_data_dir() / SO101
    exact = tmp_path / "so101_exact.urdf"
    exact.write_text(_exact_angles(shipped.read_text()))
    rounded, base = load_robot(str(shipped)), compute_base_parameters(load_robot(str(exact)))
    found = compute_base_parameters(rounded)
    assert base.count == 36 and base.dropped == ()
    assert found.count == base.count
    assert sorted(found.dropped) == ["hx.shoulder_link", "hy.shoulder_link"]
    assert max(found.dropped_size) < 1e-5 and found.rank_gap > 1e4
    assert "hx.shoulder_link" in found.rank_note and "gap" in found.rank_note
    # What the base leaves out is what the tilt adds: ~1e-6 of the torques.
    model = RegressorModel(rounded)
    q, v, vd = random_states(rounded, 20, seed=3)
    Y = model(q, v, vd)
    tau = Y @ rounded.phi_model
    error = found.reduce(Y) @ found.base_values(rounded.phi_model) - tau
    assert np.abs(error).max() < 1e-5 * np.abs(tau).max()
    YB = found.reduce(Y).reshape(-1, found.count)
    assert np.linalg.cond(YB / np.linalg.norm(YB, axis=0)) < 1e3  # 38 columns: ~1e6


def _synthetic_rows(sizes, extra=None):
    """Rows of independent random columns of the given norms (then zero columns), with
    column len(sizes) an exact combination of the first two; ``extra(W)`` edits them."""

    def rows(q, v, vd):
        T, n = q.shape
        p = len(get_robot("ur5").parameter_names)
        W = np.zeros((T * n, p))
        W[:, : len(sizes)] = np.random.default_rng(4).normal(size=(T * n, len(sizes))) * sizes / np.sqrt(T * n)
        W[:, len(sizes)] = W[:, 0] - 2 * W[:, 1]
        if extra is not None:
            extra(W)
        return W.reshape(T, n, p)

    return rows


def test_a_small_direction_without_a_gap_is_kept(ur5):
    """Size alone drops nothing: columns from 1 down to 1e-6 (smaller than the SO-101's dropped
    ones) in steps of √10 are all real, and kept."""
    sizes = 10.0 ** (-np.arange(13) / 2)
    base = compute_base_parameters(ur5, rows=_synthetic_rows(sizes))
    assert base.count == 13 and base.dropped == ()
    assert set(base.independent) == set(range(13))
    assert base.rank_gap < 30  # the largest step there is, far below the threshold
    # Without the gap test the rank is the same: only rounding separates kept from dependent.
    assert compute_base_parameters(ur5, rows=_synthetic_rows(sizes), gap_ratio=None).count == 13


def test_a_direction_below_a_gap_is_dropped_and_said(ur5):
    sizes = np.r_[np.ones(12), 1e-7]  # 12 real columns and one 1e-7 of them
    rows = _synthetic_rows(sizes)
    base = compute_base_parameters(ur5, rows=rows)
    names = ur5.parameter_names
    assert base.count == 12 and base.dropped == (names[12],)
    assert base.rank_gap > 1e6 and base.gap_ratio == RANK_GAP_RATIO
    assert names[12] in base.rank_note
    assert compute_base_parameters(ur5, rows=rows, gap_ratio=None).count == 13  # a fixed tolerance keeps it
    # The exact combination still composes: φ_B = K φ reproduces everything but the dropped column.
    W = rows(*random_states(ur5, 30, seed=1)).reshape(-1, len(names))
    phi = np.random.default_rng(5).normal(size=len(names))
    rest = W @ phi - W[:, 12] * phi[12]
    assert np.allclose(W[:, base.independent] @ base.base_values(phi), rest, atol=1e-6 * np.abs(rest).max())


def test_a_dropped_pivot_before_a_kept_one(ur5):
    """A tiny column (1e-6) pivots before a nearly dependent large one (5e-3 of its own norm
    left: the equilibrated order), yet only the tiny one lies below the gap: the kept columns
    are factored first again, and the tiny one is expressed by them."""

    def nearly_dependent(W):
        u = np.random.default_rng(7).normal(size=len(W))
        W[:, 14] = W[:, 2] + W[:, 3] + 5e-3 * np.linalg.norm(W[:, 2]) * u / np.linalg.norm(u)

    rows = _synthetic_rows(np.r_[np.ones(12), 1e-6], nearly_dependent)
    base = compute_base_parameters(ur5, rows=rows)
    names = ur5.parameter_names
    assert base.dropped == (names[12],)
    assert base.count == 13 and 14 in base.independent
    W = rows(*random_states(ur5, 30, seed=1)).reshape(-1, len(names))
    phi = np.random.default_rng(6).normal(size=len(names))
    rest = W @ phi - W[:, 12] * phi[12]
    assert np.allclose(W[:, base.independent] @ base.base_values(phi), rest, atol=1e-6 * np.abs(rest).max())


def test_a_coefficient_that_shows_as_one_is_written_as_a_sign():
    from pe_drake.multibody.base_parameters import composed_names

    K = np.array([[-0.99999999, -1.0000000001, 1.0], [1.0, 0.0825, 0.0], [0.0, -2.5, 1.0]])
    assert composed_names(K, ("a", "b", "c")) == ("-a - b + c", "a + 0.0825 b", "-2.5 b + c")
