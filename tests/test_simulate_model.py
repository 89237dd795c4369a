"""``pe-drake simulate --model FILE`` (issue 23): the simulated robot is an identified model
(identified.json with drive terms, or the diagnosis's augmented_model.json), so identifying the
simulated run gives that model back; a file that is not a model is refused before any work."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pe_drake.cli import main as cli
from pe_drake.identification.estimators import identify
from pe_drake.identification.identified_file import load_identified, result_to_dict
from pe_drake.simulation.simulated_model import load_simulation_model
from pe_drake.simulation.simulation import truth_path_for
from tests.conftest import get_robot, random_states
from tests.test_drive_terms import drive_truth, with_drive
from tests.test_identification import OPTIMIZED




@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    """identified.json of a WLS fit (base parameters only, drive terms) of a Panda with known friction."""
    from pe_drake.excitation.trajectory_file import load_trajectory

    robot = get_robot("panda")
    trajectory, _ = load_trajectory(OPTIMIZED)
    result = identify(robot, with_drive(robot, trajectory, drive_truth(robot, seed=3), duration=trajectory.period), "wls")
    path = tmp_path_factory.mktemp("model") / "identified.json"
    path.write_text(json.dumps(result_to_dict(result, robot)))
    return path


def predicted(robot, model, q, v, vd):
    from pe_drake.identification.prediction import predict
    from pe_drake.identification.measurements import Measurement

    return predict(robot, model, Measurement(np.arange(len(q), dtype=float), q, np.zeros_like(q), v, vd, robot.joint_names))


def test_simulate_with_model_is_identified_back(model_file, tmp_path, capsys):
    robot = get_robot("panda")
    out = tmp_path / "run.csv"
    # The truth comes on top of the model: noise, and a controller that knows the model's rotor
    # inertia (the URDF's prior lacks it: joint 7's 0.33 kg·m² against 0.01 tracked 80 mrad off).
    truth = tmp_path / "truth.yaml"
    truth.write_text("noise: {tau_std: 0.02}\ncontrol: {model: 'true'}\n")
    assert cli(["simulate", "--robot", "panda", "--trajectory", str(OPTIMIZED), "--model", str(model_file),
                "--truth", str(truth), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"the robot is the model of '{model_file}'" in printed
    record = json.loads(truth_path_for(out).read_text())
    model = load_identified(model_file, robot)
    sim = load_simulation_model(model_file, robot)
    np.testing.assert_allclose(list(record["simulated_model"]["drive_terms"]["coulomb"].values()), sim.coulomb)
    np.testing.assert_allclose(list(record["effects"]["coulomb"]["values"].values()), sim.coulomb)
    assert record["noise"]["tau_std"] == 0.02
    assert cli(["identify", "--robot", "panda", "--data", str(out), "--method", "wls", "--trajectory", str(OPTIMIZED),
                "--out", str(tmp_path / "again")]) == 0
    again = load_identified(tmp_path / "again" / "identified.json", robot)
    for term in ("coulomb", "viscous", "offset"):  # measured: within 1.1 σ
        for j in range(robot.n):
            got, want, sd = again.model.term(term)[j], model.model.term(term)[j], again.model.sigma[term][j]
            assert abs(got - want) < 3 * sd, (term, j, got, want, sd)
    # measured: 1 % low (a few σ) on joints 3-7, whose armature the model can separate
    np.testing.assert_allclose(again.model.armature[2:], model.model.armature[2:], rtol=0.03)
    q, v, vd = random_states(robot, 50, seed=1)
    v = np.sign(v) * np.maximum(np.abs(v), 0.2)  # away from the tanh's knee, where the fits need not agree
    want, got = predicted(robot, model, q, v, vd), predicted(robot, again, q, v, vd)
    rms = np.sqrt(np.mean((got - want) ** 2, axis=0))
    assert np.all(rms < 0.05 * np.sqrt(np.mean(want**2, axis=0)) + 0.05), rms


def augmented_model_file(tmp_path, robot):
    """An augmented_model.json with friction, armature, offsets, a payload on link 7, a torque
    delay and pre-sliding friction on the last joint."""
    from pe_drake.multibody.inertia import inertia_matrix
    from pe_drake.multibody.payload import PayloadInertia
    from pe_drake.multibody.robot_model import RobotModel

    n = robot.n
    rng = np.random.default_rng(0)
    presliding, stiffness = np.zeros(n), np.zeros(n)
    presliding[-1], stiffness[-1] = 0.3, 300.0
    drive = {"viscous": rng.uniform(0, 1, n), "coulomb": rng.uniform(0, 2, n), "armature": rng.uniform(0, 0.3, n),
             "offset": rng.uniform(-1, 1, n)}
    link = "panda_link7" if "panda_link7" in robot.body_names else robot.body_names[-1]
    payload = PayloadInertia(0.8, np.array([0.0, 0.01, 0.05]), inertia_matrix(np.array([1e-3, 1e-3, 2e-3, 0, 0, 0])))
    model = RobotModel(tuple(robot.joint_names), tuple(robot.body_names), robot.phi_model.copy(), drive,
                       payload=payload, payload_link=link, torque_delay=0.002, presliding=presliding,
                       presliding_stiffness=stiffness)
    path = tmp_path / "augmented_model.json"
    path.write_text(json.dumps(model.to_dict()))
    return path, model


def test_simulate_with_the_diagnosis_augmented_model(tmp_path, capsys):
    """Without --truth: the simulated robot has the model's parameters (payload lumped into its
    link), drive terms, torque delay and pre-sliding friction, and no noise."""
    from pe_drake.identification.measurements import read_measurement_csv

    robot = get_robot("panda")
    path, model = augmented_model_file(tmp_path, robot)
    out = tmp_path / "run.csv"
    assert cli(["simulate", "--robot", "panda", "--trajectory", str(OPTIMIZED), "--model", str(path),
                "--out", str(out), "--duration", "0.5"]) == 0
    record = json.loads(truth_path_for(out).read_text())
    loaded = load_identified(path, robot)
    b = robot.body_names.index("panda_link7")
    np.testing.assert_allclose(record["phi_true"]["panda_link7"], loaded.phi_total[10 * b : 10 * b + 10])
    assert record["phi_true"]["panda_link7"][0] == pytest.approx(robot.phi_model[10 * b] + 0.8)
    for field, values in (("viscous", model.viscous), ("coulomb", model.coulomb), ("armature", model.armature),
                          ("torque_offset", model.offset)):
        np.testing.assert_allclose(list(record["effects"][field]["values"].values()), values, err_msg=field)
    assert record["noise"]["tau_std"] == 0.0
    assert record["effects"]["torque_delay"]["value"] == 0.002  # validate leaves these two out
    last = robot.joint_names[-1]
    assert record["effects"]["presliding_friction"]["values"][last] == 0.3
    assert record["effects"]["presliding_friction"]["stiffness"][last] == 300.0
    run = read_measurement_csv(out, robot.joint_names)
    assert run.num_samples == 501


def test_simulate_refuses_a_file_that_is_not_a_model(tmp_path, capsys):
    """A trajectory.json, another robot's model, or no --truth and no --model: exit 2, nothing written."""
    out = tmp_path / "run.csv"
    base = ["simulate", "--robot", "panda", "--trajectory", str(OPTIMIZED), "--out", str(out), "--duration", "0.2"]
    assert cli([*base, "--model", str(OPTIMIZED)]) == 2
    err = capsys.readouterr().err
    assert "not an identified.json" in err and str(OPTIMIZED) in err
    ur5 = get_robot("ur5")
    other, _ = augmented_model_file(tmp_path, ur5)
    assert cli([*base, "--model", str(other)]) == 2
    err = capsys.readouterr().err
    assert "shoulder_pan_joint" in err and "panda_joint1" in err and str(other) in err
    assert cli(base) == 2
    assert "--truth" in capsys.readouterr().err
    assert not out.exists() and not truth_path_for(out).exists()


def test_a_truth_adds_its_effects_to_the_model(tmp_path):
    from pe_drake.exceptions import ConfigError
    from pe_drake.simulation.truth import make_truth

    robot = get_robot("panda")
    path, model = augmented_model_file(tmp_path, robot)
    sim = load_simulation_model(path, robot)
    true = make_truth(robot, {"viscous": {"all": 0.1}, "torque_delay": 0.001}, model=sim).model
    np.testing.assert_allclose(true.viscous, model.viscous + 0.1)
    assert true.torque_delay == pytest.approx(0.003)
    with pytest.raises(ConfigError, match="coulomb_velocity_scale 0.05 rad/s of the truth file differs"):
        make_truth(robot, {"coulomb": {"all": 1.0}, "coulomb_velocity_scale": 0.05}, model=sim)
    with pytest.raises(ConfigError, match="both the truth file and the model"):
        make_truth(robot, {"presliding_friction": {"all": 0.1}, "presliding_stiffness": {"all": 100.0}}, model=sim)


def test_simulated_parameters_are_valid_and_reproduce_the_model(model_file):
    """A WLS fit's base parameters become physically valid links that reproduce them within
    their σ (merged armatures as rotor inertia); a physical fit is simulated as it is, its
    merged armatures added to the rotor inertias."""
    from pe_drake.excitation.trajectory_file import load_trajectory
    from pe_drake.multibody.inertia import validity_problems

    robot = get_robot("panda")
    wls = load_identified(model_file, robot)
    sim = load_simulation_model(model_file, robot)
    assert not validity_problems(robot.body_names, sim.phi) and not sim.notes
    q, v, vd = random_states(robot, 40, seed=4)
    from pe_drake.multibody.regressor import RegressorModel

    simulated = RegressorModel(robot)(q, v, vd) @ sim.phi + sim.armature * vd + sim.viscous * v + sim.offset
    simulated += sim.coulomb * np.tanh(v / sim.velocity_scale)
    want = predicted(robot, wls, q, v, vd)
    err = np.max(np.abs(simulated - want))
    print(f"simulated vs file model: max |Δτ| {err:.3g} N·m of max |τ| {np.max(np.abs(want)):.3g} N·m")
    assert err < 1e-3 * np.max(np.abs(want)), err  # measured 0.0027 of 73.8 N·m
    trajectory, _ = load_trajectory(OPTIMIZED)
    physical = identify(robot, with_drive(robot, trajectory, drive_truth(robot, seed=3), duration=trajectory.period),
                        "physical")
    path = model_file.parent / "physical" / "identified.json"
    path.parent.mkdir(exist_ok=True)
    path.write_text(json.dumps(result_to_dict(physical, robot)))
    sim = load_simulation_model(path, robot)
    np.testing.assert_array_equal(sim.phi, physical.phi)
    for name in physical.drive_layout.merged:
        j = robot.joint_names.index(name)
        assert sim.armature[j] == pytest.approx(physical.model.armature[j])
