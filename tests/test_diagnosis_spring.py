"""A spring at a joint (``joint_stiffness``, torque k·q): the diagnosis names it, the augmented
model holds it (a Drake RevoluteSpring) and ``validate`` applies it; a spring is what the real
Panda's negative WLS armatures stood in for (issue 36, BUILD_NOTES)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from pe_drake.diagnosis.options import DiagnosisConfig
from pe_drake.diagnosis.workflow import diagnose
from pe_drake.identification.identified_file import read_augmented_model
from pe_drake.identification.measurements import Measurement
from pe_drake.identification.prediction import predict
from pe_drake.multibody.robot_model import RobotModel
from pe_drake.simulation.synthetic import model_measurement
from tests.conftest import get_robot
from tests.test_identification import optimized  # noqa: F401  (a fixture)

NOISE = 0.05  # [N·m]
SPRING = 1.5  # [N·m/rad] on joint 4


@pytest.fixture(scope="module")
def spring(optimized):  # noqa: F811
    """The model file's torques plus a spring k·q on joint 4 and white noise, the diagnosis with
    the last 30 % held out."""
    robot = get_robot("panda")
    m = model_measurement(robot, optimized, rate_hz=200, tau_noise_std=NOISE, seed=0)
    tau = m.tau.copy()
    tau[:, 3] += SPRING * m.q[:, 3]
    result = diagnose(robot, m.replace(tau=tau), options=DiagnosisConfig(holdout_fraction=0.3))
    return robot, result


def test_a_hidden_spring_is_named_alone_with_its_value(spring):
    robot, result = spring
    found = {(e.effect, e.joint or e.link): e for e in result.effects}
    assert set(found) == {("joint_stiffness", "panda_joint4")}, found
    assert found[("joint_stiffness", "panda_joint4")].value == pytest.approx(SPRING, rel=0.05)
    assert found[("joint_stiffness", "panda_joint4")].unit == "N·m/rad"
    # the augmented Drake model holds it: the held-out residual at the noise (filtered) level
    assert result.augmented.spring[3] == pytest.approx(found[("joint_stiffness", "panda_joint4")].value)
    assert np.all(result.rms_after < 3 * NOISE)
    assert np.max(result.drake_check) < 0.01


def test_validate_applies_the_spring_of_augmented_model_json(spring, tmp_path):
    """augmented_model.json → validate's prediction includes k·q (was dropped: 0.1 N·m on the
    real Panda's joint 6)."""
    robot, result = spring
    d = json.loads(json.dumps(result.augmented.to_dict()))
    assert d["joint_stiffness"]["panda_joint4"] == pytest.approx(result.augmented.spring[3])
    model = read_augmented_model(d, robot)
    seg = result.held_out
    data = Measurement(seg.t, seg.q, seg.tau, seg.v, seg.vd, robot.joint_names, "")
    with_spring = predict(robot, model, data)
    without = predict(robot, dataclasses.replace(model, spring=np.zeros(robot.n)), data)
    np.testing.assert_allclose(with_spring - without, seg.q * result.augmented.spring, atol=1e-12)


def test_the_drake_spring_gives_plus_k_q_in_inverse_dynamics():
    """RobotModel.plant's RevoluteSpring (Drake applies −k q) and RobotModel.torque (+k q, the
    actuator's torque) agree."""
    robot = get_robot("panda")
    k = np.array([0.0, 0.0, 0.5, 2.0, 0.0, 0.1, 0.0])
    model = RobotModel.from_robot(robot)
    sprung = RobotModel(model.joints, model.bodies, model.phi, model.drive, spring=k)
    rng = np.random.default_rng(0)
    q = rng.uniform(robot.limits.q_lower, robot.limits.q_upper, (5, robot.n))
    v, vd = rng.normal(size=(2, 5, robot.n))
    drake = sprung.plant(robot).inverse_dynamics(q, v, vd, include_damping=True)
    np.testing.assert_allclose(drake - model.plant(robot).inverse_dynamics(q, v, vd, include_damping=True), q * k,
                               atol=1e-9)
    np.testing.assert_allclose(sprung.torque(robot, q, v, vd, coulomb=False) - model.torque(robot, q, v, vd, coulomb=False),
                               q * k, atol=1e-9)
    assert RobotModel.from_dict(sprung.to_dict(), robot.body_names).spring == pytest.approx(k)
