"""The physical fit of a small arm (issue 36/37): example-robot-data's SO-101 (links of
0.01-0.1 kg, rotor inertias of 0.002 kg·m²) with ±10 % inertial errors, friction, armature and
0.01 N·m torque noise. Its regressor had a rounding direction (1.3e-13 of the largest singular
value) just above the cut-off that chose the data term's minimizer, which then moved 1.5e9
prior magnitudes along it; stage 2's misfit budget became 4e8 instead of ~100, and the fit
came out 100x worse than WLS on every joint, with every armature at 0.0145 kg·m², and no word."""

from __future__ import annotations

import numpy as np
import pytest

from pe_drake.exceptions import ConfigError
from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.identification.estimators import PHYSICAL_WORSE_PERCENT, identify, physical_fit_excess
from pe_drake.identification.intake import prepare_measurement
from pe_drake.multibody.drive_columns import COULOMB_VELOCITY_SCALE
from pe_drake.multibody.inertia import perturb_inertias
from pe_drake.multibody.registry import example_robot_data_dir
from pe_drake.multibody.robot import load_robot
from pe_drake.simulation.synthetic import model_measurement
from tests.test_identification import DATA

ARMATURE = 0.002  # [kg·m²] every joint, as the newcomer's truth
VISCOUS = np.array([0.02, 0.02, 0.05, 0.02, 0.002, 0.002])  # [N·m·s/rad]
COULOMB = np.array([0.05, 0.12, 0.05, 0.05, 0.005, 0.005])  # [N·m]


@pytest.fixture(scope="module")
def so101():
    try:
        root = example_robot_data_dir()
    except ConfigError:
        pytest.skip("example-robot-data is not installed")
    path = root / "robots/so_arm_description/urdf/so101.urdf"
    if not path.is_file():
        pytest.skip("this example-robot-data has no SO-101")
    return load_robot(str(path))


def test_a_small_arms_physical_fit_is_as_good_as_wls(so101):
    """The newcomer's run, open loop: the trajectory optimized for the SO-101, 10 s at 1000 Hz,
    filtered as identify does."""
    robot = so101
    trajectory, _ = load_trajectory(DATA / "so101_optimized.json")
    truth = perturb_inertias(robot.phi_model, 0.1, np.random.default_rng(3))
    m = model_measurement(robot, trajectory, truth, rate_hz=1000, duration=10.0, tau_noise_std=0.01, seed=1)
    tau = m.tau + COULOMB * np.tanh(m.v / COULOMB_VELOCITY_SCALE) + VISCOUS * m.v + ARMATURE * m.vd
    data = prepare_measurement(robot, m.replace(tau=tau, v=None, vd=None))
    wls, physical = identify(robot, data, "wls"), identify(robot, data, "physical")
    # before: 20-23 times WLS's residual on every joint
    np.testing.assert_array_less(physical.residual_rms, 1.05 * wls.residual_rms)
    separable = [j for j in range(robot.n) if np.isfinite(physical.model.sigma["armature"][j])]
    assert separable, "no separable armature to check"
    np.testing.assert_allclose(physical.model.armature[separable], ARMATURE, atol=5e-4)  # before: 0.005-0.021
    # the friction as WLS's within 3 σ (both biased alike by tanh of the filtered v: identify's
    # filtered_coulomb is not used here); before: Coulomb 0.018-0.30 N·m for 0.005-0.12
    for term in ("coulomb", "viscous"):
        np.testing.assert_array_less(np.abs(physical.model.term(term) - wls.model.term(term)), 3 * wls.model.sigma[term])
    assert not any("least-squares (WLS)" in note for note in physical.physical_notes), physical.physical_notes


def test_a_physical_fit_far_above_least_squares_says_so():
    """The honest-figures rule: each channel more than PHYSICAL_WORSE_PERCENT above WLS is named."""
    notes = physical_fit_excess(("a", "b", "c"), np.array([0.1061, 0.00102, 0.0011]),
                                     np.array([0.0009, 0.001, 0.001]))
    assert [n.split(":")[0] for n in notes] == ["a", "c"] and PHYSICAL_WORSE_PERCENT < 10
    assert "11689 % above the least-squares (WLS) fit's 0.0009" in notes[0]
