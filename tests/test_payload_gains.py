"""Drive gains from a payload of known mass (Gautier & Briot): random gains, currents logged
instead of torques, a true arm unlike its URDF, one loaded and one unloaded run of the Panda's
arm exciting motion; inverse-dynamics data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pe_drake.exceptions import ConfigError
from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.identification.payload_gains import identify_drive_gains
from pe_drake.simulation.payload_synthetic import payload_run, random_box_payload, random_true_arm
from tests.conftest import get_robot

TRAJECTORY = Path(__file__).resolve().parent / "data" / "panda_optimized.json"


def test_gains_scaled_by_the_known_mass_are_recovered_within_their_sigma():
    robot, link = get_robot("panda"), "panda_link8"
    trajectory, _ = load_trajectory(TRAJECTORY)
    rng = np.random.default_rng(2406)
    arm, payload = random_true_arm(robot, rng), random_box_payload(rng)
    k = rng.uniform(0.5, 5.0, robot.n)  # [N·m/A]
    loaded = payload_run(robot, trajectory, arm, link, payload, noise_std=0.04, seed=1)
    empty = payload_run(robot, trajectory, arm, link, None, noise_std=0.04, seed=2, t0=3e-4)
    loaded, empty = loaded.replace(tau=loaded.tau / k), empty.replace(tau=empty.tau / k)  # currents
    result = identify_drive_gains(robot, [loaded], [empty], link, payload.mass)
    error = result.gains - k
    assert np.all(np.abs(error) < 0.005 * k), 100 * error / k
    assert np.all(np.abs(error) < 3 * result.gains_std), error / result.gains_std
    assert result.not_separable == ()
    assert np.linalg.norm(result.payload.com - payload.com) < 1e-3
    strict = identify_drive_gains(robot, [loaded], [empty], link, payload.mass, max_sigma_percent=0.01)
    assert set(strict.not_separable) == {j for j, s in zip(robot.joint_names, result.sigma_percent) if s > 0.01}
    assert set(result.to_dict()["gains"]) == set(robot.joint_names)
    with pytest.raises(ConfigError, match="known payload mass"):
        identify_drive_gains(robot, [loaded], [empty], link, 0.0)
