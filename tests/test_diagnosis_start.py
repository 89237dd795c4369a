"""diagnose starts from identify (issue 36): its starting fit is identify's (WLS with drive
terms) on the diagnosis's training part, and a joint whose augmented model is worse on the
held-out part than that fit is named, with the reason, in the output and in diagnosis.json."""

from __future__ import annotations

import numpy as np
import pytest

from pe_drake.diagnosis.options import DiagnosisConfig
from pe_drake.diagnosis.workflow import diagnose
from pe_drake.simulation.synthetic import model_measurement
from tests.conftest import get_robot
from tests.test_identification import optimized  # noqa: F401  (a fixture)

NOISE = 0.05  # [N·m]
ARMATURE = -0.15  # [kg·m²] on joint 4: a term a least-squares fit holds and a physical model cannot


@pytest.fixture(scope="module")
def negative_armature(optimized):  # noqa: F811
    """The model file's torques plus a negative armature on joint 4, white noise, the
    diagnosis with the last 30 % held out."""
    robot = get_robot("panda")
    m = model_measurement(robot, optimized, rate_hz=200, tau_noise_std=NOISE, seed=0)
    v = np.gradient(m.q, m.t, axis=0)
    tau = m.tau.copy()
    tau[:, 3] += ARMATURE * np.gradient(v[:, 3], m.t)
    lines: list[str] = []
    result = diagnose(robot, m.replace(tau=tau), config=DiagnosisConfig(holdout_fraction=0.3), progress=lines.append)
    return robot, result, lines


def test_the_starting_fit_is_identifys_and_finds_the_negative_armature(negative_armature):
    _, result, lines = negative_armature
    start = result.to_json_dict()["starting_fit"]
    assert start["weights_converged"] and start["weight_iterations"] >= 1
    # identify's default drive terms: Coulomb, viscous, offset on every joint, the separable armatures
    terms = start["drive_terms"]
    assert {f"torque_offset[panda_joint{k}]" for k in range(1, 8)} <= set(terms)
    assert terms["armature[panda_joint4]"] == pytest.approx(ARMATURE, rel=0.1)
    assert any(line.startswith("2. starting fit (identify's") for line in lines)


def test_a_joint_worse_than_the_starting_fit_is_named_with_its_reason(negative_armature):
    """The physical augmented model cannot hold armature < 0: joint 4 is worse than the
    starting fit, and the output and diagnosis.json say so and why."""
    _, result, lines = negative_armature
    worse = {w["channel"]: w for w in result.to_json_dict()["worse_than_references"]["worse"] if w["reference"] == "start"}
    assert worse["panda_joint4"]["percent_worse"] > 5
    reason = worse["panda_joint4"]["reason"]
    assert "armature[panda_joint4] = -0.1" in reason and "below its physical bound" in reason
    assert all(w["reason"] for w in worse.values())
    assert any(line.startswith("warning: panda_joint4: held-out RMS") and "worse than the starting fit" in line
               for line in lines)
