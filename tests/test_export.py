"""Export (issue 35): the identified robot loaded in MuJoCo and Drake reproduces pe_drake's own
rigid + armature + viscous torque; frictionloss holds and lets go; feed-forward, gains and
randomization; ``validate --model model.xml``; the CLI face."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

from pe_drake.config import RobotConfig
from pe_drake.exceptions import ConfigError
from pe_drake.export.controller import effective_inertia, gains_table, sample_models
from pe_drake.export.drake_files import drake_check, sdf_text, urdf_export_text
from pe_drake.export.model_export import ExportOptions
from pe_drake.export.mjcf import PAYLOAD_BODY_NAME, mjcf_files
from pe_drake.export.model_source import IdentifiedSpread, random_states
from pe_drake.multibody.base_parameters import compute_base_parameters
from pe_drake.multibody.inertia import central_inertia, perturb_inertias, validity_problems
from pe_drake.multibody.payload import PayloadInertia
from pe_drake.multibody.robot import load_robot
from pe_drake.multibody.robot_model import RobotModel
from tests.conftest import get_robot

#: A robot of our own: revolute, prismatic (tilted), revolute, a massless frame; mounted tilted.
SLIDER_URDF = """<?xml version="1.0"?>
<robot name="slider">
  <link name="base"><inertial><mass value="2"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="turn" type="revolute"><parent link="base"/><child link="arm"/>
    <origin xyz="0 0 0.2" rpy="0 0 0"/><axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="50" velocity="3"/></joint>
  <link name="arm"><inertial><origin xyz="0.1 0.02 0.05" rpy="0.1 0.2 0.3"/><mass value="1.5"/>
    <inertia ixx="0.02" iyy="0.03" izz="0.025" ixy="0.001" ixz="0.002" iyz="-0.001"/></inertial></link>
  <joint name="slide" type="prismatic"><parent link="arm"/><child link="carriage"/>
    <origin xyz="0.3 0 0" rpy="0 1.2 0"/><axis xyz="1 0 0"/><limit lower="-0.2" upper="0.2" effort="200" velocity="1"/></joint>
  <link name="carriage"><inertial><origin xyz="0.01 0 -0.02" rpy="0 0 0"/><mass value="0.8"/>
    <inertia ixx="0.004" iyy="0.005" izz="0.006" ixy="0" ixz="0.0005" iyz="0"/></inertial></link>
  <joint name="tilt" type="revolute"><parent link="carriage"/><child link="tool"/>
    <origin xyz="0 0.1 0" rpy="0.3 0 0"/><axis xyz="0 1 0"/><limit lower="-1.5" upper="1.5" effort="20" velocity="4"/></joint>
  <link name="tool"><inertial><origin xyz="0.05 0.01 0.03" rpy="0.4 0 0.2"/><mass value="0.5"/>
    <inertia ixx="0.002" iyy="0.0025" izz="0.003" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="tool_frame_joint" type="fixed"><parent link="tool"/><child link="tool_frame"/>
    <origin xyz="0 0 0.1" rpy="0 0 0"/></joint>
  <link name="tool_frame"/>
</robot>
"""
MOUNT = {"base_position": [0.1, -0.2, 0.5], "base_quaternion_wxyz": [0.9238795325112867, 0.3826834323650898, 0, 0]}


@pytest.fixture(scope="module")
def slider(tmp_path_factory):
    path = tmp_path_factory.mktemp("slider") / "slider.urdf"
    path.write_text(SLIDER_URDF)
    return load_robot(RobotConfig(model=str(path), **MOUNT))


def identified_terms(robot, seed: int, payload_link: str = "") -> RobotModel:
    """A known truth: inertias ±10 %, friction, offsets and armature of real arms' size, a payload."""
    rng = np.random.default_rng(seed)
    n = robot.n
    phi = perturb_inertias(robot.phi_model, 0.1, rng, body_names=robot.body_names)
    drive = {"coulomb": rng.uniform(0.5, 3.0, n), "viscous": rng.uniform(0.2, 1.5, n),
             "offset": rng.uniform(-0.8, 0.8, n), "armature": rng.uniform(0.05, 0.4, n)}
    payload = PayloadInertia(0.8, np.array([0.01, 0.02, 0.1]), np.diag([1e-3, 2e-3, 1.5e-3])) if payload_link else None
    return RobotModel(robot.joint_names, robot.body_names, phi, drive, velocity_scale=0.01, payload=payload,
                      payload_link=payload_link)


def relative(a, b) -> float:
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


@pytest.mark.parametrize("name", ["panda", "slider"])
def test_mjcf_in_mujoco_reproduces_the_model_and_its_inertials(name, slider):
    mujoco = pytest.importorskip("mujoco")
    from pe_drake.export.mujoco_dynamics import load_mjcf, mujoco_torques

    robot = get_robot("panda") if name == "panda" else slider
    terms = identified_terms(robot, 3, "panda_link7" if name == "panda" else "tool")
    text, unheld = mjcf_files(robot, terms)[:2]
    assert any("offsets" in u for u in unheld) and any("frictionloss" in u for u in unheld)
    model = load_mjcf(text, text=True)
    q, v, vd = random_states(robot, 30, seed=5)  # held-out states, not those of the export's own check
    want = terms.torque(robot, q, v, vd, coulomb=False, offset=False)
    assert relative(mujoco_torques(model, robot.joint_names, q, v, vd), want) < 1e-6
    assert_mujoco_inertials(model, robot, terms)


def assert_mujoco_inertials(model, robot, terms: RobotModel) -> None:
    """MuJoCo's own reading of each body: mass, centre of mass, inertia about it (its principal
    axes turned back to the body frame) equal the model's."""
    import mujoco

    bodies = dict(zip(robot.body_names, terms.phi.reshape(-1, 10)))
    bodies[PAYLOAD_BODY_NAME] = terms.payload.phi
    for body, phi_b in bodies.items():
        if phi_b[0] <= 0:
            continue
        m, p, I = central_inertia(phi_b)
        got = model.body(body)
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, got.iquat)
        R = R.reshape(3, 3)
        assert got.mass[0] == pytest.approx(m, rel=1e-12)
        np.testing.assert_allclose(got.ipos, p, atol=1e-12)
        np.testing.assert_allclose(R @ np.diag(got.inertia) @ R.T, I, atol=1e-9 * np.abs(I).max())


def test_mujoco_reads_the_exported_urdf_inertials_as_written(slider):
    """An independent URDF parser (MuJoCo's) agrees with the model on every exported inertial."""
    mujoco = pytest.importorskip("mujoco")
    terms = identified_terms(slider, 14, "tool")
    # MuJoCo's URDF options: keep welded links as bodies, inertias as written
    text = urdf_export_text(slider, terms).replace(
        "</robot>", '<mujoco><compiler fusestatic="false" balanceinertia="false"/></mujoco></robot>')
    assert_mujoco_inertials(mujoco.MjModel.from_xml_string(text), slider, terms)


def test_frictionloss_holds_below_and_slides_above(slider):
    mujoco = pytest.importorskip("mujoco")
    from pe_drake.export.mujoco_dynamics import load_mjcf

    terms = identified_terms(slider, 4)
    model = load_mjcf(mjcf_files(slider, terms).text, text=True)
    model.opt.gravity[:] = 0.0
    k = slider.joint_names.index("tilt")

    def moved(share: float, friction: bool = True) -> float:
        data = mujoco.MjData(model)
        data.qfrc_applied[k] = share * terms.drive["coulomb"][k]
        flags = model.opt.disableflags
        if not friction:
            model.opt.disableflags = flags | int(mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS)
        for _ in range(250):  # 0.5 s
            mujoco.mj_step(model, data)
        model.opt.disableflags = flags
        return abs(float(data.qpos[k]))

    # MuJoCo's friction loss is a soft constraint: below it the joint creeps by a small fraction of
    # what the same torque does without friction; above it, the excess moves it like a free joint
    free = moved(0.5, friction=False)
    assert moved(0.5) < 0.02 * free, (moved(0.5), free)
    assert moved(2.0) > 0.5 * moved(1.0, friction=False), (moved(2.0), free)


@pytest.mark.parametrize("name", ["panda", "slider"])
def test_urdf_and_sdf_reloaded_in_drake_reproduce_the_model(name, slider):
    robot = get_robot("panda") if name == "panda" else slider
    terms = identified_terms(robot, 6, "panda_link7" if name == "panda" else "tool")
    for text, suffix in ((urdf_export_text(robot, terms), ".urdf"), (sdf_text(robot, terms), ".sdf")):
        assert drake_check(robot, terms, text, suffix, samples=30) < 1e-6
        assert "drake:rotor_inertia" in text
        # what the format cannot hold, in its own words, at the top of the file
        assert "not held: torque offsets" in text
        assert ("is written as <dynamics friction>" if suffix == ".urdf" else "so does pe_drake") in text


def test_an_sdf_robot_exports_sdf_and_urdf(slider, tmp_path):
    """An SDF robot whose joint frames are not its child links' frames (the slider written as
    SDFormat by the export; a URDF cannot say that): its URDF re-expresses each link in its
    joint frame, and Drake and MuJoCo read it back as the model."""
    mujoco = pytest.importorskip("mujoco")
    terms = identified_terms(slider, 7)
    path = tmp_path / "slider.sdf"
    path.write_text(sdf_text(slider, terms).replace(  # the tool's joint frame off its link frame
        "<child>tool</child>\n      <pose>0 0 0 0 0 0</pose>", "<child>tool</child>\n      <pose>0.02 0.03 -0.01 0.3 0.2 0.1</pose>"))
    robot = load_robot(RobotConfig(model=str(path), **MOUNT))
    assert robot.joint_names == slider.joint_names
    assert not np.allclose(robot.joints[2].X_CM, np.eye(4))
    again = identified_terms(robot, 8, "tool")
    assert drake_check(robot, again, sdf_text(robot, again), ".sdf") < 1e-6
    urdf = urdf_export_text(robot, again)
    assert drake_check(robot, again, urdf, ".urdf") < 1e-6
    from pe_drake.export.mujoco_dynamics import mujoco_torques

    q, v, vd = random_states(robot, 10, seed=2)
    model = mujoco.MjModel.from_xml_string(urdf.replace(
        "</robot>", '<mujoco><compiler fusestatic="false" balanceinertia="false"/></mujoco></robot>'))
    model.opt.gravity[:] = robot.plant.gravity_field().gravity_vector()
    # MuJoCo's own URDF reading of the rigid body (its URDF importer takes no rotor inertia or damping)
    rigid = dataclasses.replace(again, drive={**again.drive, "armature": 0 * again.drive["armature"],
                                              "viscous": 0 * again.drive["viscous"]})
    model.dof_damping[:] = 0.0
    want = rigid.torque(robot, q, v, vd, coulomb=False, offset=False)
    assert relative(mujoco_torques(model, robot.joint_names, q, v, vd), want) < 1e-6


def test_gains_use_the_mass_matrix_diagonal_plus_armature(slider, tmp_path):
    terms = identified_terms(slider, 9)
    q = random_states(slider, 5, seed=2)[0]
    J = effective_inertia(slider, terms, q)
    path = tmp_path / "slider.sdf"
    path.write_text(sdf_text(slider, terms))
    loaded = load_robot(dataclasses.replace(slider.config, model=str(path)))
    for s in range(q.shape[0]):
        loaded.plant.SetPositions(loaded.plant_context, q[s])
        M = loaded.plant.CalcMassMatrix(loaded.plant_context)  # rotor inertia included
        np.testing.assert_allclose(J[s], np.diag(M), rtol=1e-9)
    table = gains_table(slider, terms, q, bandwidth_hz=10.0, damping_ratio=0.7)
    omega = 2 * np.pi * 10.0
    for k, name in enumerate(slider.joint_names):
        assert table[name]["kp"] == pytest.approx(J[:, k].mean() * omega**2)
        assert table[name]["kd"] == pytest.approx(2 * 0.7 * J[:, k].mean() * omega)


def test_sampled_models_are_consistent_and_spread_as_sigma(slider):
    terms = identified_terms(slider, 10)
    # the slider's base parameters as one identification would report them: K of the regressor's base
    base = compute_base_parameters(slider)
    K = np.asarray(base.K, float)
    # 0.5 %: base parameters sharing a link inertia differ by less than that link's triangle margin
    sigma = 0.005 * np.abs(K @ terms.phi) + 1e-7
    drive_sigma = {t: 0.05 * terms.drive[t] for t in terms.drive}
    terms = dataclasses.replace(terms, sigma=drive_sigma)
    models = sample_models(slider, terms, IdentifiedSpread(K, sigma), 400, seed=1)
    for phi in models.phi:
        assert not validity_problems(slider.body_names, phi)
    spread = np.std(models.phi @ K.T, axis=0) / sigma
    assert models.projected == 0
    np.testing.assert_allclose(spread, 1.0, atol=0.15)  # 400 draws: the std's own error is 3.5 %
    np.testing.assert_allclose(np.std(models.drive["viscous"], axis=0) / drive_sigma["viscous"], 1.0, atol=0.15)


def test_options_and_model_files_are_checked(tmp_path):
    with pytest.raises(ConfigError, match="not one of mjcf, urdf, sdf, feedforward, gains"):
        ExportOptions("usd")
    with pytest.raises(ConfigError, match="bandwidth_hz"):
        ExportOptions("gains", bandwidth_hz=-1.0)
    missing = tmp_path / "nothing.json"
    code, _, err = run_cli("export", missing, "--robot", "panda", "--to", "sdf", "--out", tmp_path / "p.sdf")
    assert code == 2 and "does not exist" in err and str(missing) in err and not (tmp_path / "p.sdf").exists()
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"joints": ["a", "b"], "base_parameters": []}))
    code, _, err = run_cli("export", other, "--robot", "panda", "--to", "mjcf", "--out", tmp_path / "p.xml")
    assert code == 2 and "not the robot's: a, b" in err and not (tmp_path / "p.xml").exists()
    code, out, err = run_cli("export", "--robot", "panda", "--to", "gains", "--out", tmp_path / "g.yaml")
    assert code == 0 and "no randomization ranges" in (tmp_path / "g.yaml").read_text()  # the CAD model has no σ


REAL = Path(__file__).resolve().parents[2] / "shared" / "datasets" / "panda_gaz2019" / "excitation_1.csv"


def run_cli(*argv) -> tuple[int, str, str]:
    import contextlib
    import io

    from pe_drake.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


@pytest.mark.skipif(not REAL.is_file(), reason="the real Panda recording is not here")
def test_cli_export_then_validate_in_mujoco_and_drake_agree_on_the_real_run(tmp_path, slider):
    mujoco = pytest.importorskip("mujoco")
    results = {}
    for to, suffix in (("mjcf", ".xml"), ("urdf", ".urdf")):
        path = tmp_path / f"cad{suffix}"
        code, out, err = run_cli("export", "--robot", "panda", "--to", to, "--out", path)
        assert code == 0, err
        assert f"wrote {path}" in out and "vs the model (relative)" in out
        if to == "mjcf":  # the visuals: example-robot-data's COLLADA meshes converted to OBJ beside it
            assert len(list((tmp_path / "cad_meshes").glob("*.obj"))) == 10
            model = mujoco.MjModel.from_xml_path(str(path))
            assert model.nmesh == 11 and not list(tmp_path.glob(".cad_meshes*"))
        code, out, err = run_cli("validate", "--robot", "panda", "--model", path, "--data", REAL,
                                 "--window", "15,17", "--json", tmp_path / f"{to}.json")
        assert code == 0, err
        assert f"model: cad{suffix}, torques by " in out and "identified from" not in out
        results[to] = json.loads((tmp_path / f"{to}.json").read_text())["rms"]
    # the CAD Panda has damping and no friction: MuJoCo and Drake compute the same torques
    for joint, rms in results["urdf"].items():
        assert results["mjcf"][joint] == pytest.approx(rms, rel=1e-6)
    # another robot's MJCF: refused, naming the missing joints; nothing half-written
    other = tmp_path / "slider.xml"
    other.write_text(mjcf_files(slider, identified_terms(slider, 1)).text)
    code, _, err = run_cli("validate", "--robot", "panda", "--model", other, "--data", REAL, "--window", "15,16")
    assert code == 2 and "has no joint(s) panda_joint1" in err
    code, _, err = run_cli("export", "--robot", "panda", "--to", "mjcf", "--out", tmp_path / "x.urdf")
    assert code == 2 and not (tmp_path / "x.urdf").exists()


def test_simulator_torques_of_exported_files_hold_the_friction(slider, tmp_path):
    pytest.importorskip("mujoco")
    from pe_drake.export.simulator_validation import simulator_torques

    terms = identified_terms(slider, 11)
    q, v, vd = random_states(slider, 10, seed=4)
    want = terms.torque(slider, q, v, vd, coulomb=False, offset=False)
    c = terms.drive["coulomb"]
    for suffix, text, friction in ((".xml", mjcf_files(slider, terms).text, c * np.sign(v)),
                                   (".urdf", urdf_export_text(slider, terms), c * np.tanh(v / 0.01))):
        path = tmp_path / f"slider{suffix}"
        path.write_text(text)
        got, _ = simulator_torques(slider, path, q, v, vd)
        assert relative(got, want + friction) < 1e-6, suffix  # the URDF's friction read before its file goes


def simulated_fit(robot, truth: RobotModel, method: str, folder: Path, noise: float):
    """identified.json of ``method`` fitted on two periods of the optimized Panda trajectory
    simulated from ``truth`` with torque noise ``noise`` [N·m]: (its path, the trajectory, run),
    run(trajectory, seed, duration=None) a prepared simulated run of the truth."""
    from pe_drake.excitation.trajectory_file import load_trajectory
    from pe_drake.multibody.drive_columns import COULOMB_VELOCITY_SCALE
    from pe_drake.identification.estimators import identify
    from pe_drake.identification.intake import prepare_measurement
    from pe_drake.identification.identified_file import result_to_dict
    from pe_drake.simulation.synthetic import model_measurement
    from tests.test_identification import OPTIMIZED

    trajectory, _ = load_trajectory(OPTIMIZED)

    def run(traj, seed, duration=None):
        m = model_measurement(robot, traj, truth.phi, rate_hz=100, duration=duration, tau_noise_std=noise, seed=seed)
        d = truth.drive
        tau = m.tau + d["coulomb"] * np.tanh(m.v / COULOMB_VELOCITY_SCALE) + d["viscous"] * m.v + d["offset"] \
            + d["armature"] * m.vd
        return prepare_measurement(robot, m.replace(tau=tau), filtering=False, check_units=False)

    result = identify(robot, run(trajectory, 1, 2 * trajectory.period), method)
    path = folder / "identified.json"
    path.write_text(json.dumps(result_to_dict(result, robot)))
    return path, trajectory, run


@pytest.mark.parametrize("method", ["ols", "wls", "physical"])
def test_identified_models_reproduce_their_own_prediction_in_mujoco(method, tmp_path):
    """identified.json of each method through the one adapter. OLS/WLS files have base parameters
    only: the export projects them onto consistent links and reports how much that changes the
    held-out prediction; on data of a consistent truth (Panda, inertias ±10 %, friction, offsets,
    armature) the change is at the noise floor. A physical model is exported as it is: MuJoCo's
    torque plus offsets and Coulomb friction is pe_drake's own prediction of the held-out run."""
    pytest.importorskip("mujoco")
    from pe_drake.export.mujoco_dynamics import load_mjcf, mujoco_torques
    from pe_drake.export.model_source import exported_model, projection_change
    from pe_drake.identification.prediction import predict
    from pe_drake.identification.identified_file import load_identified
    from tests.test_identification import random_trajectory

    robot = get_robot("panda")
    truth = identified_terms(robot, 12)
    noise = 0.05  # [N·m]
    path, trajectory, run = simulated_fit(robot, truth, method, tmp_path, noise)
    terms = exported_model(robot, path)
    assert not validity_problems(robot.body_names, terms.phi)
    held = run(random_trajectory(robot, trajectory, 7), 5)
    change = projection_change(robot, path, terms, held)
    own = predict(robot, load_identified(path, robot), held)
    mj = load_mjcf(mjcf_files(robot, terms).text, text=True)
    mj = mujoco_torques(mj, robot.joint_names, held.q, held.v, held.vd)
    mj = mj + terms.drive["offset"] + terms.drive["coulomb"] * np.tanh(held.v / terms.velocity_scale)
    if method == "physical":
        assert change is None
        assert relative(mj, own) < 1e-6
    else:
        assert change is not None and np.all(change < noise), change
        assert np.all(np.sqrt(np.mean((mj - own) ** 2, axis=0)) < noise)


def test_mjcf_visuals_are_copied_beside_it_and_leave_the_inertials_alone(tmp_path):
    mujoco = pytest.importorskip("mujoco")
    from pe_drake.export import ExportOptions, export_model

    (tmp_path / "tetra.obj").write_text("v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    text = SLIDER_URDF.replace(
        '<link name="arm">', '<link name="arm"><visual><origin xyz="0.1 0 0" rpy="0 0 0.5"/>'
        '<geometry><box size="0.2 0.04 0.06"/></geometry></visual>').replace(
        '<link name="tool">', '<link name="tool"><visual><geometry><mesh filename="tetra.obj" scale="2 2 2"/>'
        '</geometry></visual>')
    (tmp_path / "slider.urdf").write_text(text)
    robot = load_robot(RobotConfig(model=str(tmp_path / "slider.urdf"), **MOUNT))
    result = export_model(robot, None, ExportOptions("mjcf", meshdir="slider_meshes"))
    out = tmp_path / "out" / "slider.xml"
    result.write(out.parent, name=out.name)
    model = mujoco.MjModel.from_xml_path(str(out))
    box = model.geom(model.body("arm").geomadr[0])
    np.testing.assert_allclose(box.size, [0.1, 0.02, 0.03])
    np.testing.assert_allclose(box.pos, [0.1, 0, 0], atol=1e-12)
    assert (tmp_path / "out" / "slider_meshes" / "tool_0.obj").read_text().startswith("v 0 0 0")
    # readable by others as a plain mkdir would make it, not mkdtemp's 0700
    mask = os.umask(0)
    os.umask(mask)
    assert (tmp_path / "out" / "slider_meshes").stat().st_mode & 0o777 == 0o777 & ~mask
    np.testing.assert_allclose(model.mesh_scale[0], [2, 2, 2])
    assert model.body("arm").mass[0] == pytest.approx(robot.phi_model[10 * robot.body_names.index("arm")])  # no geom mass
    with pytest.raises(ConfigError, match="must be a folder name"):
        ExportOptions("mjcf", meshdir="../elsewhere")


def test_a_diagnosed_model_exports_with_its_payload_as_a_body(tmp_path):
    """augmented_model.json through the one adapter: MuJoCo reproduces the diagnosis's own Drake
    plant (inertias, damping, rotor inertia, payload body, joint springs as MuJoCo's stiffness) and
    the file lists delay and pre-sliding."""
    mujoco = pytest.importorskip("mujoco")
    from pe_drake.export import ExportOptions, export_model
    from pe_drake.export.mujoco_dynamics import load_mjcf, mujoco_torques
    from pe_drake.multibody.drive_columns import coulomb_column
    from pe_drake.multibody.robot_model import RobotModel

    robot = get_robot("panda")
    t = identified_terms(robot, 13, "panda_link7")
    n = robot.n
    model = RobotModel(robot.joint_names, robot.body_names, t.phi, t.drive, velocity_scale=0.01, payload=t.payload,
                       payload_link="panda_link7", torque_delay=0.004, presliding=np.r_[0.3, np.zeros(n - 1)],
                       presliding_stiffness=np.r_[50.0, np.zeros(n - 1)], physical=True,
                       spring=np.r_[0.0, 0.0, 0.0, 0.26, 0.0, 0.05, 0.0])  # diagnose's joint_stiffness: MJCF stiffness
    path = tmp_path / "augmented_model.json"
    path.write_text(json.dumps(model.to_dict()))
    result = export_model(robot, path, ExportOptions("mjcf"))
    assert any("0.004 s" in u for u in result.unheld) and any("pre-sliding" in u for u in result.unheld)
    assert not any("spring" in u for u in result.unheld)
    assert "panda_joint4" not in next(u for u in result.unheld if "offsets" in u)  # its springref holds it
    assert result.model.payload.mass == pytest.approx(t.payload.mass)
    mj = load_mjcf(result.text, text=True)
    assert mj.body("pe_drake_payload").mass[0] == pytest.approx(t.payload.mass)
    q, v, vd = random_states(robot, 20, seed=8)
    # the model's own torque (rigid with payload, viscous, rotor inertia), Coulomb and offsets aside
    held = np.where(model.spring > 0, model.offset, 0.0)  # springref = -τ₀/k
    want = model.torque(robot, q, v, vd) - model.offset + held - model.coulomb * coulomb_column(v, model.velocity_scale)
    assert relative(mujoco_torques(mj, robot.joint_names, q, v, vd), want) < 1e-6
    assert mujoco.mj_id2name(mj, mujoco.mjtObj.mjOBJ_JOINT, 0) == robot.joint_names[0]
    urdf = export_model(robot, path, ExportOptions("urdf"))  # a URDF has no spring: listed
    assert any("joint springs" in u and "panda_joint4" in u for u in urdf.unheld)
    # pre-sliding friction leaves at its sliding level F_c with the Coulomb friction (joint 1: 0.3)
    sliding = model.coulomb + model.presliding
    assert mj.dof_frictionloss[0] == pytest.approx(sliding[0]) and sliding[0] == pytest.approx(model.coulomb[0] + 0.3)
    import xml.etree.ElementTree as ET

    joint1 = next(j for j in ET.fromstring(urdf.text).iter("joint") if j.get("name") == "panda_joint1")
    assert float(joint1.find("dynamics").get("friction")) == pytest.approx(sliding[0])
    feedforward = yaml.safe_load(export_model(robot, path, ExportOptions("feedforward")).text)
    assert feedforward["joints"]["panda_joint1"]["coulomb"] == pytest.approx(sliding[0])


def test_a_point_mass_is_given_the_smallest_inertia_mujoco_accepts(tmp_path):
    """Drake accepts a mass with no rotational inertia (a flange frame with a mass, so101's,
    TALOS's); MuJoCo refuses it: its principal moments are raised to 1e-12 kg·m², noted."""
    pytest.importorskip("mujoco")
    from pe_drake.export.mujoco_dynamics import load_mjcf, mujoco_torques

    path = tmp_path / "slider.urdf"
    path.write_text(SLIDER_URDF.replace('<link name="tool_frame"/>', '<link name="tool_frame"><inertial>'
                                        '<mass value="0.05"/><inertia ixx="0" iyy="0" izz="0" ixy="0" ixz="0" iyz="0"/>'
                                        '</inertial></link>'))
    robot = load_robot(RobotConfig(model=str(path), **MOUNT))
    terms = dataclasses.replace(identified_terms(robot, 15), phi=robot.phi_model)
    text, unheld = mjcf_files(robot, terms)[:2]
    assert any(u.startswith("tool_frame: principal moments 0, 0, 0") for u in unheld)
    q, v, vd = random_states(robot, 10, seed=3)
    got = mujoco_torques(load_mjcf(text, text=True), robot.joint_names, q, v, vd)
    assert relative(got, terms.torque(robot, q, v, vd, coulomb=False, offset=False)) < 1e-6


@pytest.mark.skipif(not REAL.is_file(), reason="the real Panda recording is not here")
def test_real_panda_in_mujoco_is_pe_drakes_validate_minus_what_mjcf_cannot_hold(tmp_path):
    """The shared real Panda run (identify on 0-14.445 s, validate on 14.95-20.495 s, diagnose's
    split): MuJoCo's held-out torques of the exported MJCF are pe_drake's own prediction minus the
    offsets and minus f_c·(tanh(v/v_s) − sign(v)), and the CAD MJCF is far worse."""
    pytest.importorskip("mujoco")
    from pe_drake.export import ExportOptions, export_model, exported_model, validate_exported
    from pe_drake.identification import (IdentifyOptions, TimeWindow, ValidateOptions, identify_model,
                                         load_identified, read_measurements, validate_model)
    from pe_drake.identification.drive_terms import filtered_coulomb
    from pe_drake.identification.intake import prepare_measurement

    robot = get_robot("panda")
    raw = read_measurements(robot, REAL)
    identify_model(robot, raw, IdentifyOptions(method="physical", window=TimeWindow.parse(",14.445"))).write(tmp_path)
    model = tmp_path / "identified.json"
    export_model(robot, model, ExportOptions("mjcf")).write(tmp_path, name="identified.xml")
    export_model(robot, None, ExportOptions("mjcf")).write(tmp_path, name="cad.xml")
    options = ValidateOptions(window=TimeWindow.parse("14.95,20.495"))
    own = validate_model(robot, load_identified(model, robot), raw, options)
    mj = validate_exported(robot, tmp_path / "identified.xml", raw, options)
    cad = validate_exported(robot, tmp_path / "cad.xml", raw, options)
    terms = exported_model(robot, model)
    data = prepare_measurement(robot, raw, window=options.window)
    shape = terms.drive["coulomb"] * (filtered_coulomb(raw, data, terms.velocity_scale) - filtered_coulomb(raw, data, 1e-6))
    np.testing.assert_allclose(mj.predicted, own.predicted - terms.drive["offset"] - shape, atol=1e-9)
    assert np.all(cad.rms > 2 * mj.rms)  # the CAD-vs-identified gap, in MuJoCo


def test_randomization_draws_from_the_identifications_covariance(tmp_path):
    """identified.json stores the base parameters' covariance; the sampled models are physically
    consistent and their base parameters spread as it says: σ and the correlations, which draws
    from σ alone lose. A WLS fit of a simulated Panda with 0.2 mN·m of torque noise: its σ is
    small against the bodies' margins, so projection is rarely needed and leaves the spread
    alone. An older file without the covariance still exports, drawing from σ and saying so."""
    from pe_drake.export import ExportOptions, export_model, exported_model, identified_spread

    robot = get_robot("panda")
    path, _, _ = simulated_fit(robot, identified_terms(robot, 12), "wls", tmp_path, 2e-4)
    model, spread = exported_model(robot, path), identified_spread(robot, path)
    assert spread.cov is not None and spread.cov.shape == (len(spread.names),) * 2 and not spread.note
    np.testing.assert_allclose(np.sqrt(np.diag(spread.cov)), spread.sigma, rtol=1e-9)
    count = 400
    models = sample_models(robot, model, spread, count, seed=1)
    for phi in models.phi:
        assert not validity_problems(robot.body_names, phi)
    assert models.projected < 0.2 * count, models.projected
    draws = models.phi @ spread.K.T
    # 400 draws: the std's own error is 3.5 %, a correlation's at most 5 % (0.15: 3 of them)
    np.testing.assert_allclose(np.std(draws, axis=0) / spread.sigma, 1.0, atol=0.15)
    rho = spread.cov / np.outer(spread.sigma, spread.sigma)
    strong = np.abs(rho - np.eye(len(rho))) > 0.5
    assert strong.any()  # the Panda's base parameters are correlated: what draws from σ alone lose
    np.testing.assert_allclose(np.corrcoef(draws.T)[strong], rho[strong], atol=0.15)

    old = json.loads(path.read_text())
    del old["base_parameter_covariance"]
    path.write_text(json.dumps(old))
    result = export_model(robot, path, ExportOptions("gains", samples=3))
    assert "no base_parameter_covariance" in result.figures["randomization"]
    assert "drawn independently from their σ" in result.text
    assert any("randomization" in line and "written before" in line for line in result.summary_lines())


def test_a_malformed_covariance_is_refused_naming_the_file(tmp_path):
    from pe_drake.exceptions import DataError
    from pe_drake.identification.identified_file import load_identified

    robot = get_robot("panda")
    path, _, _ = simulated_fit(robot, identified_terms(robot, 12), "ols", tmp_path, 0.05)
    d = json.loads(path.read_text())
    d["base_parameter_covariance"] = d["base_parameter_covariance"][:-1]
    path.write_text(json.dumps(d))
    with pytest.raises(DataError, match="base_parameter_covariance has shape") as err:
        load_identified(path, robot)
    assert str(path) in str(err.value)


def test_validation_of_a_model_file_does_not_call_it_identified():
    """`validate --model model.xml` printed "model identified from model.xml, torques by MuJoCo":
    a model file was not identified from a measurement; an identified.json still says what it was."""
    from pe_drake.identification.validate_model import ValidationReport

    def first_line(source):
        one = np.ones((2, 1))
        return ValidationReport("slider", source, "joint_torque", ("x",), np.arange(2.0), one, one,
                                np.zeros(1), np.zeros(1), 0.0, 2).summary_lines()[1]

    assert first_line("model.xml, torques by MuJoCo") == "model: model.xml, torques by MuJoCo; predicting joint_torque"
    assert first_line("joint_torque") == "model identified from joint_torque; predicting joint_torque"


def test_sdf_of_a_urdf_whose_weld_shares_its_links_name(tmp_path):
    """URDF lets a joint and a link share a name, SDFormat does not: example-robot-data's Z1 has a
    fixed joint and its child link both called gripperStator, and `export --to sdf` was refused
    ("Non-unique name[gripperStator]"). The weld is renamed; the excited joints keep their names."""
    path = tmp_path / "same_names.urdf"
    path.write_text(SLIDER_URDF.replace('joint name="tool_frame_joint"', 'joint name="tool_frame"'))
    robot = load_robot(RobotConfig(model=str(path), **MOUNT))
    terms = identified_terms(robot, 2)
    text = sdf_text(robot, terms)
    assert drake_check(robot, terms, text, ".sdf", samples=10) < 1e-6
    assert '<joint name="tool_frame_weld" type="fixed">' in text and '<link name="tool_frame">' in text
    assert all(f'<joint name="{j}"' in text for j in robot.joint_names)
