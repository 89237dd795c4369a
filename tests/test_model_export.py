"""Model export: the URDF with identified inertials is what Drake reads back; invalid bodies are refused."""

from __future__ import annotations

import numpy as np
import pytest

from pe_drake.multibody.inertia import PhysicallyInvalidError, central_inertia, perturb_inertias, validity_problems
from pe_drake.multibody.robot_model import RobotModel
from pe_drake.multibody.urdf import urdf_with_inertias, verify_urdf_text
from tests.conftest import get_robot


def test_central_inertia_is_the_parallel_axis_theorem():
    m, c = 1.5, np.array([0.1, 0.02, -0.05])
    I_cm = np.diag([0.01, 0.02, 0.015])
    I_o = I_cm + m * (c @ c * np.eye(3) - np.outer(c, c))
    phi = np.concatenate([[m], m * c, [I_o[0, 0], I_o[1, 1], I_o[2, 2], I_o[0, 1], I_o[0, 2], I_o[1, 2]]])
    m2, c2, I2 = central_inertia(phi)
    assert m2 == m
    np.testing.assert_allclose(c2, c, atol=1e-15)
    np.testing.assert_allclose(I2, I_cm, atol=1e-15)


@pytest.mark.parametrize("name", ["panda", "ur5"])
def test_round_trip_through_drake(name, tmp_path):
    robot = get_robot(name)
    phi = perturb_inertias(robot.phi_model, 0.2, rng=4)
    path = tmp_path / "model.urdf"
    RobotModel(robot.joint_names, robot.body_names, phi).write_urdf(path, robot)  # verifies with Drake inside
    text = path.read_text()
    assert "identified inertial parameters" in text
    verify_urdf_text(text, robot.body_names, phi)
    with pytest.raises(Exception, match="does not reproduce"):
        verify_urdf_text(text, robot.body_names, perturb_inertias(phi, 0.2, rng=5))


def test_invalid_bodies_are_refused_and_nothing_is_written(tmp_path):
    robot = get_robot("panda")
    phi = robot.phi_model.copy()
    b = robot.body_names.index("panda_link4")
    phi[10 * b + 4] = -1.0  # negative Ixx
    phi[10 * robot.body_names.index("panda_link2")] = -2.0  # negative mass
    problems = validity_problems(robot.body_names, phi)
    assert set(problems) == {"panda_link4", "panda_link2"}
    assert "negative mass" in problems["panda_link2"]
    with pytest.raises(PhysicallyInvalidError, match="panda_link2"):
        RobotModel(robot.joint_names, robot.body_names, phi).write_urdf(tmp_path / "model.urdf", robot)
    assert not (tmp_path / "model.urdf").exists()
    with pytest.raises(Exception, match="URDF"):
        urdf_with_inertias(tmp_path / "robot.sdf", robot.body_names, robot.phi_model)
