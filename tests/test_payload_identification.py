"""Payload identification accuracy (issue 24): random box payloads, a true arm that differs from
the URDF (inertias ±5 %, Coulomb and viscous friction on every joint), 0.03–0.05 N·m noise, an
8 s optimized payload motion (ramps included) and an unloaded run of the same motion sampled
at other instants. Inverse-dynamics data: no simulator."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pe_drake.excitation.payload_motion import optimize_payload_motion
from pe_drake.identification.payload import PayloadBox, PayloadOptions, identify_payload, payload_errors
from pe_drake.multibody.inertia import pseudo_inertia
from pe_drake.multibody.payload import PayloadInertia, box_inertia
from pe_drake.simulation.payload_synthetic import payload_run, random_box_payload, random_true_arm
from tests.conftest import get_robot

ROBOTS = {"panda": "panda_link8", "ur5": "tool0"}
_PLANS: dict = {}


def _plan(name):
    if name not in _PLANS:
        _PLANS[name] = optimize_payload_motion(get_robot(name), ROBOTS[name])
    return _PLANS[name]


def _runs(name, arm, payload, noise, seed, unloaded=True):
    robot, link, motion = get_robot(name), ROBOTS[name], _plan(name).motion
    loaded = payload_run(robot, motion, arm, link, payload, rate_hz=1000.0, noise_std=noise, seed=seed)
    # The unloaded run is not sample-aligned with the loaded one: another rate, another start.
    empty = payload_run(robot, motion, arm, link, None, rate_hz=800.0, t0=0.0004, noise_std=noise, seed=seed + 1)
    return [loaded], [empty] if unloaded else []


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_paired_runs_meet_the_accuracy_of_issue_24(name):
    robot = get_robot(name)
    assert _plan(name).motion.duration <= 15.0
    rng = np.random.default_rng({"panda": 2401, "ur5": 2402}[name])
    for trial in range(2):
        arm = random_true_arm(robot, rng)
        payload = random_box_payload(rng)
        noise = rng.uniform(0.03, 0.05)
        loaded, unloaded = _runs(name, arm, payload, noise, 100 * trial)
        result = identify_payload(robot, loaded, unloaded, ROBOTS[name])
        e = payload_errors(result, payload)
        msg = f"{name} trial {trial}: m {payload.mass:.3f} kg, {e}"
        assert e["mass_percent"] < 0.5, msg
        assert e["com_m"] < 1e-3, msg
        assert e["inertia_percent_of_max"] < 10.0, msg
        # Every error inside its reported 3σ band.
        assert e["mass_sigmas"] < 3 and e["com_sigmas"] < 3 and e["inertia_sigmas"] < 3, msg
        assert result.unloaded_runs == 1 and result.arm_correction is not None
        # The friction the true arm has is what the nuisance terms found.
        coulomb = np.array([result.drive[f"coulomb.{j}"] for j in robot.joint_names])
        np.testing.assert_allclose(coulomb, arm.coulomb, atol=0.02)


def test_without_unloaded_run_the_arm_model_errors_go_into_the_payload():
    """Loaded run alone: the payload's columns lie in the span of the arm's base columns, so the
    arm's 5 % inertia errors are read as payload (errors ≫ σ); with the arm exact it works."""
    name, robot = "panda", get_robot("panda")
    rng = np.random.default_rng(77)
    arm = random_true_arm(robot, rng)
    payload = random_box_payload(rng)
    loaded, _ = _runs(name, arm, payload, 0.04, 5, unloaded=False)
    biased = payload_errors(identify_payload(robot, loaded, [], ROBOTS[name]), payload)
    assert biased["mass_sigmas"] > 10 or biased["com_sigmas"] > 10, biased
    exact_arm = dataclasses.replace(arm, phi=robot.phi_model.copy(), physical=None)
    loaded, _ = _runs(name, exact_arm, payload, 0.04, 5, unloaded=False)
    e = payload_errors(identify_payload(robot, loaded, [], ROBOTS[name]), payload)
    assert e["mass_percent"] < 0.5 and e["com_m"] < 1e-3 and e["inertia_percent_of_max"] < 10, e


def test_physical_fit_keeps_a_thin_payload_valid_and_inside_its_box():
    """A thin rod has a nearly singular central inertia: noise puts the plain LS estimate outside
    J ⪰ 0; the SDP result is physically valid, and with the box, its mass is inside it."""
    name, robot, link = "ur5", get_robot("ur5"), "tool0"
    size = np.array([0.004, 0.004, 0.3])
    rod = PayloadInertia(0.4, np.array([0.0, 0.0, 0.15]), box_inertia(0.4, size))
    arm = random_true_arm(robot, np.random.default_rng(3))
    loaded, unloaded = _runs(name, arm, rod, 0.05, 9)
    plain = identify_payload(robot, loaded, unloaded, link, options=PayloadOptions(physical=False))
    phys = identify_payload(robot, loaded, unloaded, link)
    assert np.linalg.eigvalsh(pseudo_inertia(plain.phi)).min() < 0  # the case the SDP is for
    assert phys.constrained and np.linalg.eigvalsh(pseudo_inertia(phys.phi)).min() > -1e-9
    box = PayloadBox(center=(0.0, 0.0, 0.15), size=(0.01, 0.01, 0.3))
    boxed = identify_payload(robot, loaded, unloaded, link, options=PayloadOptions(box=box))
    assert np.all(np.abs(boxed.payload.com - [0, 0, 0.15]) <= np.array([0.005, 0.005, 0.15]) + 1e-7)
    assert abs(boxed.payload.mass - rod.mass) < 3 * boxed.mass_std + 1e-4
    d = boxed.to_dict()
    assert len(d["inertia_about_com"]) == 6 and len(d["com_std"]) == 3 and d["physically_valid"]
