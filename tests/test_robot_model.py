"""One model of the robot as built (issue 33): :class:`RobotModel` reads the files today's main
writes (identified.json of every method, augmented_model.json; fixtures in tests/data/robot_model
written by the code before this module, with its predictions) with the same predictions, round-
trips its own schema, and its Drake plant and URDF give the torque of :meth:`RobotModel.torque`."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from pe_drake.multibody.sensors import measurement_base_parameters
from pe_drake.multibody.payload import PayloadInertia
from pe_drake.multibody.robot import load_robot
from pe_drake.multibody.robot_model import RobotModel
from tests.conftest import get_robot, random_states

FIXTURES = Path(__file__).parent / "data" / "robot_model"
PREDICTIONS = json.loads((FIXTURES / "predictions.json").read_text())


def read(robot, name: str) -> RobotModel:
    d = json.loads((FIXTURES / f"{name}.json").read_text())
    base = measurement_base_parameters(robot, d.get("measurement", "joint_torque"))
    return RobotModel.from_dict(d, robot.body_names, base=base, phi_prior=robot.phi_model)


@pytest.mark.parametrize("name", ["identified_ols", "identified_wls", "identified_physical", "augmented_model"])
def test_old_files_load_with_the_same_predictions(name):
    robot = get_robot("panda")
    model = read(robot, name)
    q, v, vd = (np.array(PREDICTIONS[k]) for k in ("q", "v", "vd"))
    want = np.array(PREDICTIONS[name])
    np.testing.assert_allclose(model.torque(robot, q, v, vd), want, rtol=1e-9, atol=1e-8 * np.abs(want).max())
    assert model.physical == (name != "identified_ols" and name != "identified_wls")


def test_round_trip():
    robot = get_robot("panda")
    model = read(robot, "augmented_model")
    assert model.payload_link == "panda_link7" and model.torque_delay == 0.002 and model.holding_torque[-1] == 0.2
    written = json.loads((FIXTURES / "augmented_model.json").read_text())
    assert list(model.to_dict().items()) == list(written.items())  # the file today's diagnose writes, key order too
    again = RobotModel.from_dict(json.loads(json.dumps(model.to_dict())))
    for field in dataclasses.fields(RobotModel):
        a, b = getattr(model, field.name), getattr(again, field.name)
        if isinstance(a, dict):
            assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a), field.name
        elif isinstance(a, PayloadInertia):
            np.testing.assert_array_equal(a.phi, b.phi)
        else:
            assert np.array_equal(a, b), field.name
    identified = read(robot, "identified_wls")
    again = RobotModel.from_dict(json.loads(json.dumps(identified.to_dict())))
    for t in identified.sigma:
        np.testing.assert_array_equal(identified.sigma[t], again.sigma[t])


def test_bad_values_are_named():
    with pytest.raises(ValueError, match="unknown drive term.*gear.*valid: coulomb"):
        RobotModel(("a",), ("b",), np.zeros(10), {"gear": [1.0]})
    with pytest.raises(ValueError, match=r"drive\['viscous'\] must have one value per joint \(1\)"):
        RobotModel(("a",), ("b",), np.zeros(10), {"viscous": [1.0, 2.0]})


def test_plant_inverse_dynamics_is_the_model_torque():
    """Drake's plant (damping, DoorHinge, rotor inertia, payload body) + offsets = torque()."""
    robot = get_robot("panda")
    model = read(robot, "augmented_model")
    assert np.all(model.armature > 0) and np.all(model.viscous > 0)
    plant = model.plant(robot)
    q, v, vd = random_states(robot, 10, seed=2)
    got = plant.inverse_dynamics(q, v, vd, include_damping=True) + model.offset
    want = model.torque(robot, q, v, vd)
    np.testing.assert_allclose(got, want, atol=1e-9 * np.abs(want).max())
    # and the armature and viscous terms matter there
    bare = dataclasses.replace(model, drive={"coulomb": model.coulomb, "offset": model.offset})
    assert np.abs(bare.torque(robot, q, v, vd) - want).max() > 0.1


def test_urdf_writer_reproduces_the_rigid_torque(tmp_path):
    robot = get_robot("panda")
    model = read(robot, "augmented_model")
    path = tmp_path / "model.urdf"
    assert model.write_urdf(path, robot) < 1e-6
    loaded = load_robot(dataclasses.replace(robot.config, model=str(path), capsules=""))
    q, v, vd = random_states(robot, 10, seed=3)
    want = model.torque(robot, q, v, vd) - model.offset - model.coulomb * np.tanh(v / model.velocity_scale)
    np.testing.assert_allclose(loaded.inverse_dynamics(q, v, vd, include_damping=True), want,
                               atol=1e-8 * np.abs(want).max())
    assert "pe_drake_payload" in path.read_text()
    yaml = model.effects_yaml()
    assert "torque_delay: 0.002" in yaml and "presliding_stiffness: {panda_joint7: 300.0}" in yaml


def test_any_model_becomes_physically_consistent():
    """consistent_model (what the simulator and an exporter need): a WLS file's minimum-norm
    parameters are not physical; the consistent ones give the same joint torques."""
    from pe_drake.simulation.simulated_model import consistent_model

    robot = get_robot("panda")
    model = read(robot, "identified_wls")
    assert not model.physical
    physical = consistent_model(robot, model)
    assert physical.physical and consistent_model(robot, physical) is physical
    q, v, vd = random_states(robot, 20, seed=6)
    want = model.torque(robot, q, v, vd)
    assert np.abs(physical.torque(robot, q, v, vd) - want).max() < 1e-3 * np.abs(want).max()
