"""Balance constraint (Eq. 52): support centre, CoM offset, Jacobian, checks and errors."""

import dataclasses

import numpy as np
import pytest

from pe_drake.exceptions import ConfigError, InfeasibleError, UnknownNameError
from pe_drake.excitation.constraints.balance import BalanceConstraint, OutOfBalanceError, support_center
from pe_drake.multibody.registry import resolve_robot_config
from pe_drake.multibody.robot import load_robot
from tests.conftest import random_postures


def test_support_center_is_the_centroid_of_the_contact_points(g1):
    plant = g1.plant
    context = plant.CreateDefaultContext()
    points = []
    for link, pts in g1.config.support_points.items():
        X_WB = plant.EvalBodyPoseInWorld(context, plant.GetBodyByName(link))
        points += [X_WB.multiply(np.asarray(p, float)) for p in pts]
    assert len(points) == 8
    assert np.allclose(support_center(g1), np.mean(points, axis=0))
    assert np.allclose(support_center(g1)[:2], [0.035, 0.0], atol=1e-3)  # between the feet


def test_com_includes_every_body(g1):
    """Drake's CoM equals the mass-weighted mean over all bodies, locked ones included."""
    constraint = BalanceConstraint(g1)
    q = random_postures(g1, 3, seed=4)
    plant = g1.plant
    context = plant.CreateDefaultContext()
    for k in range(len(q)):
        plant.SetPositions(context, q[k])
        mass, moment = 0.0, np.zeros(3)
        for name in g1.body_names_all[1:]:
            body = plant.GetBodyByName(name)
            m = body.default_mass()
            moment += m * plant.EvalBodyPoseInWorld(context, body).multiply(body.default_com())
            mass += m
        expected = moment[:2] / mass - constraint.p_WSc[:2]
        assert np.allclose(constraint.com_offset(q[k])[0], expected, atol=1e-12)
    assert mass > 30.0  # legs, torso and head count, not just the 16 moving arm bodies


def test_jacobian_matches_finite_differences(g1):
    constraint = BalanceConstraint(g1)
    q = random_postures(g1, 15, seed=11)
    values = constraint.evaluate(q, None, None)
    h = 1e-6
    fd = np.empty_like(values.d_q)
    for j in range(g1.n):
        dq = np.zeros(g1.n)
        dq[j] = h
        plus = constraint.evaluate(q + dq, None, None, derivatives=False).value
        minus = constraint.evaluate(q - dq, None, None, derivatives=False).value
        fd[:, :, j] = (plus - minus) / (2 * h)
    assert np.abs(values.d_q - fd).max() < 1e-9  # seen: 7e-12 m/rad
    assert np.abs(values.d_q).max() > 1e-3


def test_value_is_the_smoothed_distance(g1):
    constraint = BalanceConstraint(g1, radius=0.01, smoothing=1e-4)
    q = random_postures(g1, 5, seed=2)
    e = constraint.com_offset(q)
    values = constraint.evaluate(q, None, None, derivatives=False)
    assert values.value.shape == (5, 1) and values.d_q.shape == (5, 1, 0) and values.d_v is None
    assert np.allclose(values.value[:, 0], np.sqrt((e**2).sum(axis=1) + 1e-8))
    assert np.allclose(constraint.margins(q, None, None)[:, 0], 0.01 - np.linalg.norm(e, axis=1))
    assert constraint.upper[0] == 0.01 and constraint.lower[0] == -np.inf


def test_g1_zero_posture_leans_back_and_nominal_is_centred(g1):
    constraint = BalanceConstraint(g1, radius=0.01)
    behind = constraint.com_offset(np.zeros(g1.n))[0]
    assert behind[0] == pytest.approx(-0.0147, abs=5e-4) and abs(behind[1]) < 5e-4
    centred = constraint.com_offset(g1.nominal_posture())[0]
    assert np.linalg.norm(centred) < 1e-3
    constraint.check_posture(g1.nominal_posture())  # does not raise
    with pytest.raises(OutOfBalanceError):
        constraint.check_posture(np.zeros(g1.n))


def test_out_of_balance_posture_is_reported_in_mm(g1):
    constraint = BalanceConstraint(g1, radius=0.01)
    q = np.tile(g1.nominal_posture(), (8, 1))
    q[5, [0, 7]] = 0.6  # both arms swung back
    t = 0.02 * np.arange(8)
    with pytest.raises(OutOfBalanceError) as err:
        constraint.check_posture(q, t)
    e = err.value
    assert isinstance(e, InfeasibleError)
    assert e.sample == 5 and e.time == pytest.approx(0.1) and e.violations == 1
    assert e.offset[0] < -0.03 and e.distance > e.radius == 0.01
    assert f"{e.distance * 1e3:.1f} mm from the support centre" in str(e)
    assert "sample 5 (t = 0.100 s)" in str(e) and "10.0 mm" in str(e)


def test_errors(g1):
    panda = load_robot("panda")
    with pytest.raises(ConfigError, match="no support points"):
        BalanceConstraint(panda)
    for radius in (0.0, -0.01, float("nan")):
        with pytest.raises(ConfigError, match="radius"):
            BalanceConstraint(g1, radius=radius)
    with pytest.raises(ConfigError, match="must exceed the smoothing"):
        BalanceConstraint(g1, radius=1e-5)
    with pytest.raises(ConfigError, match=r"shape \(K, 14\)"):
        BalanceConstraint(g1).evaluate(np.zeros((2, 3)), None, None)

    base = resolve_robot_config("panda").robot
    moving = dataclasses.replace(base, support_points={"panda_link7": [[0.0, 0.0, 0.0]]})
    with pytest.raises(ConfigError, match="moved by the excited joint"):
        BalanceConstraint(load_robot(moving))
    unknown = dataclasses.replace(base, support_points={"left_foot": [[0.0, 0.0, 0.0]]})
    with pytest.raises(UnknownNameError) as err:
        BalanceConstraint(load_robot(unknown))
    assert "panda_link0" in err.value.choices


def test_static_support_on_a_fixed_base():
    """A welded link works as support (here Panda's base): offset of the arm's CoM."""
    config = dataclasses.replace(
        resolve_robot_config("panda").robot, support_points={"panda_link0": [[0.0, 0.0, 0.0]]}
    )
    robot = load_robot(config)
    constraint = BalanceConstraint(robot, radius=0.5)
    assert np.allclose(constraint.p_WSc, 0.0)
    constraint.check_posture(robot.nominal_posture())


def test_batched_com_and_jacobian_equal_drakes(g1):
    """The batched CoM and CoM Jacobian (issue 11) against Drake's per-sample queries."""
    constraint = BalanceConstraint(g1)
    q = random_postures(g1, 12, seed=21)
    p, J = constraint.com(q, jacobian=True)
    p_drake, J_drake = constraint.drake_com(q, jacobian=True)
    assert np.abs(p - p_drake).max() < 1e-13
    assert np.abs(J - J_drake).max() < 1e-13
    assert np.abs(J).max() > 1e-2  # the arms do move the CoM
