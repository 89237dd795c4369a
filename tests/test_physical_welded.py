"""The physical fit on a known truth (issue 36): a UR10 with 20 parts welded to its wrist and
±30 % inertial errors, noise-free: the rigid group is one body of the fit, and the fit converges
(it failed on the pull toward the a-priori model and left the upper arm at 113 kg for a 12.1 kg
truth; the welded parts went to 2e-5 kg, each on its bound)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from pe_drake.identification.estimators import identify
from pe_drake.identification.intake import prepare_measurement
from pe_drake.simulation.synthetic import model_measurement
from pe_drake.identification.welded import merge_welded
from pe_drake.multibody.inertia import perturb_inertias
from pe_drake.multibody.registry import example_robot_data_dir
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.robot import load_robot
from tests.conftest import random_states
from tests.test_identification import optimized, random_trajectory  # noqa: F401  (a fixture)

PARTS = 20


@pytest.fixture(scope="module")
def ur10_with_parts(tmp_path_factory):
    """example-robot-data's UR10 (meshes left out) with PARTS bodies of 0.05 kg welded to wrist_3_link."""
    text = (example_robot_data_dir() / "robots/ur_description/urdf/ur10_robot.urdf").read_text()
    text = re.sub(r"<(collision|visual)\b.*?</\1>", "", text, flags=re.S)
    parts = "".join(
        f'  <link name="part_{k}"><inertial><origin xyz="0 0 0"/><mass value="0.05"/>'
        '<inertia ixx="1e-5" ixy="0" ixz="0" iyy="1e-5" iyz="0" izz="1e-5"/></inertial></link>\n'
        f'  <joint name="part_{k}_weld" type="fixed"><parent link="wrist_3_link"/><child link="part_{k}"/>'
        f'<origin xyz="{0.02 * np.cos(k)} {0.02 * np.sin(k)} {0.01 * k}" rpy="0 0 {0.3 * k}"/></joint>\n'
        for k in range(PARTS))
    path = tmp_path_factory.mktemp("ur10") / "ur10_parts.urdf"
    path.write_text(text.replace("</robot>", parts + "</robot>"))
    return load_robot(str(path))


def test_a_welded_body_is_the_carrier_moved_by_a_fixed_map(ur10_with_parts):
    """Each part's regressor columns are the carrier's times L (the weld's map of parameters),
    so only the group's sum is identifiable."""
    robot = ur10_with_parts
    groups = merge_welded(robot, robot.phi_model)
    carrier = robot.body_names.index("wrist_3_link")
    assert list(groups.members) == [carrier] and len(groups.members[carrier]) == PARTS
    Y = RegressorModel(robot)(*random_states(robot, 20, seed=3))
    for member, L in groups.members[carrier][:5]:
        np.testing.assert_allclose(Y[..., 10 * member : 10 * member + 10],
                                   Y[..., 10 * carrier : 10 * carrier + 10] @ L, atol=1e-10)


@pytest.mark.parametrize("seed", [0, 1])
def test_noise_free_physical_fit_converges_with_the_group_merged(ur10_with_parts, optimized, seed):  # noqa: F811
    robot = ur10_with_parts
    rng = np.random.default_rng(seed)
    truth = perturb_inertias(robot.phi_model, 0.3, rng)
    trajectory = random_trajectory(robot, optimized, seed=1)
    data = prepare_measurement(robot, model_measurement(robot, trajectory, truth, rate_hz=100,
                                                        duration=2 * trajectory.period), filtering=False)
    result = identify(robot, data, "physical")
    notes = result.physical_notes
    assert not any("solver failed" in n for n in notes), notes
    assert not any(n.startswith("part_") for n in notes), notes  # no part emptied onto its bound
    assert any(n.startswith(f"wrist_3_link and the {PARTS} bodies welded to it") for n in notes), notes
    want = result.base.base_values(truth)
    # measured 1.4e-3 and 1.6e-3: the pull toward the a-priori model within Δχ² of 1e-6 RMS
    assert np.max(np.abs(result.phi_B - want) / np.maximum(np.abs(want), 1e-3)) < 1e-2
    upper = robot.body_names.index("upper_arm_link")
    assert result.phi[10 * upper] == pytest.approx(truth[10 * upper], rel=0.1)  # was 113 kg for 12.1
    wrist = [robot.body_names.index("wrist_3_link")] + [robot.body_names.index(f"part_{k}") for k in range(PARTS)]
    group_mass = sum(result.phi[10 * b] for b in wrist)
    assert all(result.phi[10 * b] >= 0 for b in wrist) and group_mass > 0


def test_identify_help_says_the_physical_fit_is_weighted(capsys):
    from pe_drake.cli import main

    with pytest.raises(SystemExit):
        main(["identify", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "physical (every link physically consistent, each rigid group of welded links one body; weighted" in text


def test_a_single_welded_body_is_named_in_the_singular():
    """The Z1's link06 is welded to its gripper stator: the fit's note said 'the 1 bodies'."""
    from pe_drake.identification.welded import WeldedGroups

    body = np.array([1.0, 0.0, 0.0, 0.05, 0.01, 0.01, 0.01, 0.0, 0.0, 0.0])  # 1 kg, CoM 5 cm up
    groups = WeldedGroups(kept=(0,), members={0: [(1, np.eye(10))]})
    assert groups.names(["stator", "link06"]) == ["stator (with its 1 welded body)"]
    _, notes = groups.split(2 * body, np.concatenate([body, body]), ["stator", "link06"])
    assert notes and notes[0].startswith("stator and the 1 body welded to it (link06) fitted as one body"), notes
