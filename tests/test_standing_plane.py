# ruff: noqa: E501 (URDF text on one line per link)
"""A robot on a pedestal stands on it: the floor goes under the pedestal, not through the root
link (Baxter's root link is its torso, and the mounting plane cut its arms' workspace in half)."""

import numpy as np
import pytest

from pe_drake.excitation.constraints.environment import environment_from_config
from pe_drake.multibody.capsule_fitting import fit_capsules
from pe_drake.multibody.registry import resolve_robot_config
from pe_drake.multibody.robot import Robot

_INERTIAL = '<inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>'


def _urdf(pedestal: bool) -> str:
    base = ('<collision><origin xyz="0 0 -0.4"/><geometry><cylinder radius="0.1" length="0.8"/></geometry></collision>'
            if pedestal else '<collision><origin xyz="0 0 0.02"/><geometry><cylinder radius="0.08" length="0.04"/></geometry></collision>')
    return f"""<robot name="stand">
  <link name="torso">{base}</link>
  <link name="arm">{_INERTIAL}<collision><origin xyz="0.15 0 0"/><geometry><box size="0.3 0.04 0.04"/></geometry></collision></link>
  <joint name="j1" type="revolute"><parent link="torso"/><child link="arm"/><origin xyz="0 0 0.1"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="10" velocity="2"/></joint>
</robot>
"""


def _environment(tmp_path, pedestal: bool):
    path = tmp_path / "stand.urdf"
    path.write_text(_urdf(pedestal))
    config = resolve_robot_config(str(path), None)
    config, _ = fit_capsules(config, tmp_path)
    robot = Robot("stand", config.robot)
    return robot, environment_from_config(robot, config.excitation, config.environment)


def test_floor_goes_under_the_pedestal(tmp_path):
    """Fails on the old code: the floor was the plane z = 0 through the torso, 0.2 m above the
    arm's lowest point, so the robot's only posture was refused."""
    robot, env = _environment(tmp_path, pedestal=True)
    assert env.floor_height == pytest.approx(-0.8 - 0.1, abs=2e-3)
    env.check_posture(np.full((1, robot.n), 1.5))  # the arm hangs 0.2 m below the torso: allowed


def test_a_base_without_pedestal_keeps_the_mounting_plane(tmp_path):
    robot, env = _environment(tmp_path, pedestal=False)
    assert env.floor_height == pytest.approx(0.0)
    with pytest.raises(Exception, match="floor"):
        env.check_posture(np.full((1, robot.n), 1.5))  # the arm hangs below its mounting plane
