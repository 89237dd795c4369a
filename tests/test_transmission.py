"""Transmissions (issue 36): gear ratios and a coupled wrist (a UR5 given a Stäubli TX40's
drivetrain: ratios 32 32 45 −48 45 32, motor 6 turning with joints 5 and 6), motor-side logs
read on the joint side, and the drive terms of each motor as joint-side columns."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pe_drake.config import TransmissionConfig
from pe_drake.exceptions import ConfigError, DataError, UnknownNameError
from pe_drake.identification.readers import read_log
from pe_drake.multibody.base_parameters import compute_base_parameters
from pe_drake.multibody.drive_columns import (
    TERMS,
    UNITS,
    DriveLayout,
    DriveTermOptions,
    drive_columns,
    drive_layout,
)
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.transmission import Transmission
from pe_drake.simulation.synthetic import model_measurement
from tests.conftest import get_robot
from tests.test_identification import optimized, random_trajectory  # noqa: F401  (a fixture)

RATIOS = [32.0, 32.0, 45.0, -48.0, 45.0, 32.0]
NOISE = 0.05  # [N·m]


def tx40(robot) -> Transmission:
    joints = robot.joint_names
    return Transmission.from_config(dict(zip(joints, RATIOS)), {joints[5]: {joints[4]: 32.0}}, joints)


class _Config:  # the robot.transmission a config gives
    def __init__(self, robot):
        self.transmission = TransmissionConfig(dict(zip(robot.joint_names, RATIOS)),
                                               {robot.joint_names[5]: {robot.joint_names[4]: 32.0}})
        self.drive_gains = {}


@dataclasses.dataclass
class _Robot:  # the robot with that config, for the reader
    joint_names: tuple
    n: int
    config: _Config


def test_r_and_its_errors():
    robot = get_robot("ur5")
    T = tx40(robot)
    assert T.R[5, 4] == 32 and T.R[5, 5] == 32 and T.R[3, 3] == -48 and T.coupled
    q = np.random.default_rng(0).normal(size=(5, 6))
    np.testing.assert_allclose(T.joint_positions(T.motor_positions(q)), q, atol=1e-12)
    tau_m = np.random.default_rng(1).normal(size=(5, 6))
    v = np.random.default_rng(2).normal(size=(5, 6))
    # power is the same on both sides
    np.testing.assert_allclose(np.sum(T.motor_positions(v) * tau_m, axis=1), np.sum(v * T.joint_torques(tau_m), axis=1))
    with pytest.raises(UnknownNameError, match="valid joints: shoulder_pan_joint"):
        Transmission.from_config({"joint_9": 2.0}, {}, robot.joint_names)
    with pytest.raises(ConfigError, match="ratios\\['elbow_joint'\\] must be a finite non-zero number"):
        Transmission.from_config({"elbow_joint": 0}, {}, robot.joint_names)
    with pytest.raises(ConfigError, match="names its own joint"):
        Transmission.from_config({}, {"elbow_joint": {"elbow_joint": 3.0}}, robot.joint_names)


def test_motor_side_log_is_read_on_the_joint_side(optimized, tmp_path):  # noqa: F811
    """θ_m = R q and τ_m = R⁻ᵀ τ written per motor read back as q and τ; a mixed file is refused."""
    robot = get_robot("ur5")
    T = tx40(robot)
    m = model_measurement(robot, random_trajectory(robot, optimized, seed=1), rate_hz=100, duration=3.0)
    header = ["t"] + [f"q_motor.{j}" for j in robot.joint_names] + [f"tau_motor.{j}" for j in robot.joint_names]
    table = np.column_stack([m.t, T.motor_positions(m.q), T.motor_torques(m.tau)])
    path = tmp_path / "motor.csv"
    np.savetxt(path, table, delimiter=",", header=",".join(header), comments="", fmt="%.12g")
    fake = _Robot(robot.joint_names, robot.n, _Config(robot))
    got = read_log(path, fake)
    np.testing.assert_allclose(got.q, m.q, atol=1e-9)
    np.testing.assert_allclose(got.tau, m.tau, rtol=1e-9, atol=1e-9)
    assert any("motor-side log converted" in note and "coupled" in note for note in got.notes)
    mixed = tmp_path / "mixed.csv"
    np.savetxt(mixed, np.column_stack([table, m.tau[:, :1]]), delimiter=",", comments="", fmt="%.12g",
               header=",".join(header + [f"tau.{robot.joint_names[0]}"]))
    with pytest.raises(DataError, match="mixes motor-side columns"):
        read_log(mixed, fake)


def motor_truth(n: int) -> dict[str, np.ndarray]:
    """Per motor, motor side: F_c [N·m], F_v [N·m·s/rad], offset [N·m], rotor inertia [kg·m²]."""
    rng = np.random.default_rng(4)
    return {"coulomb": rng.uniform(0.03, 0.1, n), "viscous": rng.uniform(1e-4, 4e-4, n),
            "offset": rng.uniform(-0.02, 0.02, n), "armature": rng.uniform(3e-5, 1e-4, n)}


MOTOR_TERMS = TERMS["all"]


def motor_drive_columns(v, vd, transmission):
    """Every motor's drive terms as joint-side columns, (S, n, 4n): column 4i + k is motor i's
    term k of MOTOR_TERMS."""
    cols = [(t, i) for i in range(len(transmission.joints)) for t in MOTOR_TERMS]
    layout = DriveLayout(tuple(t for t, _ in cols), tuple(i for _, i in cols), transmission.joints,
                         tuple(UNITS[t][0] for t, _ in cols), transmission=transmission)
    return drive_columns(v, vd, layout)


def coupled_run(robot, trajectory, T, truth, seed):
    m = model_measurement(robot, trajectory, rate_hz=100, duration=2 * trajectory.period, tau_noise_std=NOISE,
                          seed=seed)
    theta = np.column_stack([truth[t] for t in MOTOR_TERMS]).ravel()  # motor i's terms at 4i..4i+3
    return m.replace(tau=m.tau + motor_drive_columns(m.v, m.vd, T) @ theta), theta


def test_each_motors_terms_are_recovered_through_the_coupling(optimized):  # noqa: F811
    """Least squares on [Y_B | motor columns]: every motor's term within 3σ (the armatures that
    merge with base parameters left out), the other run at the noise floor; the per-joint drive
    columns, blind to the coupling, leave every joint far above it."""
    robot = get_robot("ur5")
    T = tx40(robot)
    truth = motor_truth(robot.n)
    base = compute_base_parameters(robot)
    model = RegressorModel(robot)
    runs = [coupled_run(robot, random_trajectory(robot, optimized, seed=s), T, truth, s) for s in (1, 7)]

    def rows(m, columns):
        Y = base.reduce(model(m.q, m.v, m.vd))
        return np.concatenate([Y, columns(m)], axis=2).reshape(-1, Y.shape[2] + columns(m).shape[2]), m.tau.ravel()

    def motor(m):
        return motor_drive_columns(m.v, m.vd, T)

    A, y = rows(runs[0][0], motor)
    b = base.count
    # an armature column inside span(Y_B) (the first motor's) is not identifiable: left out
    keep = list(range(b))
    for k in range(A.shape[1] - b):
        trial = keep + [b + k]
        if np.linalg.matrix_rank(A[:, trial] / np.linalg.norm(A[:, trial], axis=0), tol=1e-8) == len(trial):
            keep = trial
    x, *_ = np.linalg.lstsq(A[:, keep], y, rcond=None)
    cov = NOISE**2 * np.linalg.inv(A[:, keep].T @ A[:, keep])
    theta = runs[0][1]
    left_out = [k for k in range(len(theta)) if b + k not in keep]
    # the armatures of the motors of joints 1 and 2, which merge into base parameters as the
    # joints' own do (drive_layout)
    layout = drive_layout(robot, base, DriveTermOptions("all"))
    assert left_out == [4 * robot.joint_names.index(j) + 3 for j in layout.merged] == [3, 7], left_out
    for pos, col in enumerate(keep[b:], start=b):
        k = col - b
        sd = np.sqrt(cov[pos, pos])
        assert abs(x[pos] - theta[k]) < 3 * sd, (MOTOR_TERMS[k % 4], k // 4, x[pos], theta[k], sd)
    A2, y2 = rows(runs[1][0], motor)
    held = (y2 - A2[:, keep] @ x).reshape(-1, robot.n)
    assert np.all(np.sqrt(np.mean(held**2, axis=0)) < 1.1 * NOISE)
    # the same data with each joint's own friction, offset and armature (no coupling)
    def joint(m):
        return drive_columns(m.v, m.vd, layout)

    A, y = rows(runs[0][0], joint)
    x, *_ = np.linalg.lstsq(A, y, rcond=None)
    A2, y2 = rows(runs[1][0], joint)
    rms = np.sqrt(np.mean((y2 - A2 @ x).reshape(-1, robot.n) ** 2, axis=0))
    # joints 5 and 6 carry motor 6's terms, which no joint's own columns hold; the misfit
    # biases the shared rigid-body parameters, so every joint is far above the noise floor
    assert np.all(rms > 10 * NOISE), rms


def test_config_refuses_a_zero_ratio(tmp_path):
    from pe_drake.config import load_config

    path = tmp_path / "robot.yaml"
    path.write_text("robot:\n  transmission:\n    ratios: {joint_1: 0}\n    coupling: {joint_6: {joint_5: 32}}\n")
    with pytest.raises(ConfigError, match=r"robot.transmission.ratios\['joint_1'\] must not be 0"):
        load_config(path)
    path.write_text("robot:\n  transmission:\n    ratios: {joint_1: 32}\n    coupling: {joint_6: {joint_5: .nan}}\n")
    with pytest.raises(ConfigError, match=r"coupling\['joint_6'\]\['joint_5'\] must be a finite number"):
        load_config(path)


# ---- wired into identify and the robot model ----------------------------------------------------


def coupled_robot():
    """The UR5 with the TX40's drivetrain in its config (robot.transmission)."""
    from pe_drake.multibody.robot import load_robot

    ur5 = get_robot("ur5")
    joints = ur5.joint_names
    return load_robot(dataclasses.replace(ur5.config, transmission=TransmissionConfig(
        dict(zip(joints, RATIOS)), {joints[5]: {joints[4]: 32.0}})))


def true_model(robot):
    from pe_drake.multibody.robot_model import RobotModel
    from pe_drake.multibody.transmission import robot_transmission

    return RobotModel(robot.joint_names, robot.body_names, robot.phi_model, motor_truth(robot.n),
                      transmission=robot_transmission(robot))


def model_run(robot, truth, trajectory, seed):
    """The truth's torques along a trajectory (RobotModel.torque: the motors' terms through R), noisy."""
    m = model_measurement(robot, trajectory, rate_hz=100, duration=2 * trajectory.period)
    noise = np.random.default_rng(seed).normal(size=m.tau.shape) * NOISE
    return m.replace(tau=truth.torque(robot, m.q, m.v, m.vd) + noise)


def test_identify_fits_each_motor_through_the_coupling(optimized, tmp_path):  # noqa: F811
    """identify with robot.transmission: every motor term within 3σ of the truth, the held-out
    run at the noise floor, identified.json read back as the same model; without the
    transmission the same data leave joints far above it and the fit says why."""
    from pe_drake.identification.identified_file import load_identified
    from pe_drake.identification.identify_model import IdentifyOptions, identify_model
    from pe_drake.identification.validate_model import ValidateOptions, validate_model
    from pe_drake.multibody.robot_model import RobotModel

    robot = coupled_robot()
    truth = true_model(robot)
    train, held = (model_run(robot, truth, random_trajectory(robot, optimized, seed=s), s) for s in (1, 7))
    options = IdentifyOptions(filtering=False, rest="keep")
    fit = identify_model(robot, train, options)
    from pe_drake.identification.drive_terms import layout_values

    layout = fit.result.drive_layout
    assert layout.transmission is not None and set(layout.merged) == set(robot.joint_names[:2])
    for label, term, j, x, sd in zip(layout.labels, layout.terms, layout.joints,
                                     *layout_values(fit.result.model, layout)):
        assert abs(x - truth.term(term)[j]) < 3 * sd, (label, x, truth.term(term)[j], sd)
    assert not fit.result.coupling, fit.result.coupling
    assert any("motor wrist_3_joint" in line for line in fit.summary_lines())
    fit.write(tmp_path)
    model = load_identified(tmp_path / "identified.json", robot)
    report = validate_model(robot, model, held, ValidateOptions(filtering=False))
    assert np.all(report.rms < 1.1 * NOISE), report.rms
    # the file's model is the fit's: its torque through R equals the fit's prediction
    import json

    d = json.loads((tmp_path / "identified.json").read_text())
    assert "motors" in d["drive_terms"] and d["drive_terms"]["transmission"]["R"][5][4] == 32.0
    again = RobotModel.from_dict(d, robot.body_names, base=fit.result.base, phi_prior=robot.phi_model)
    assert again.transmission is not None
    np.testing.assert_allclose(again.torque(robot, held.q, held.v, held.vd), report.predicted, atol=1e-8)
    # without the transmission: per-joint terms, far above the noise floor and flagged
    plain = get_robot("ur5")
    blind = identify_model(plain, train, options)
    assert blind.result.drive_layout.transmission is None
    blind_report = validate_model(plain, load_identified(_written(blind, tmp_path / "blind"), plain), held,
                                  ValidateOptions(filtering=False))
    rms = blind_report.rms
    assert rms[4] > 5 * NOISE and rms[5] > 5 * NOISE, rms
    assert not report.coupling and "wrist_2_joint-wrist_3_joint" in blind_report.to_dict()["coupling_warnings"][0]
    warning = [w for w in blind.result.coupling if "coupled drive" in w]
    assert warning and "wrist_2_joint-wrist_3_joint" in warning[0], blind.result.coupling


def _written(fit, folder):
    fit.write(folder)
    return folder / "identified.json"


def test_robot_model_carries_the_transmission(tmp_path):
    """to_dict/from_dict keep R and the per-motor terms; per_joint_model and plant: the
    uncoupled motors exactly, the coupled motor's friction as a force, its inertia's diagonal."""
    from pe_drake.multibody.robot_model import RobotModel

    robot = coupled_robot()
    truth = true_model(robot)
    back = RobotModel.from_dict(truth.to_dict())
    np.testing.assert_array_equal(back.transmission.R, truth.transmission.R)
    rng = np.random.default_rng(3)
    q = rng.uniform(robot.limits.q_lower, robot.limits.q_upper, (5, robot.n))
    v, vd = rng.uniform(-1, 1, (5, robot.n)), rng.uniform(-3, 3, (5, robot.n))
    np.testing.assert_allclose(back.torque(robot, q, v, vd), truth.torque(robot, q, v, vd), atol=1e-12)
    # a file of before the transmissions loads without one
    old = truth.to_dict()
    del old["transmission"]
    assert RobotModel.from_dict(old).transmission is None
    notes = truth.plant_notes()
    assert len(notes) == 1 and "wrist_2_joint-wrist_3_joint" in notes[0]
    # Drake's plant (its DoorHinges in inverse_dynamics) minus the coupled motor's friction force
    # = torque() minus the offsets and the rotor inertia's off-diagonal entries (which Drake cannot hold)
    sim = truth.plant(robot)
    cross = truth.transmission.reflected(truth.armature)
    cross -= np.diag(np.diag(cross))
    joint = truth.per_joint_model()
    from pe_drake.multibody.model_plant import coupled_friction

    friction = coupled_friction(truth)
    for k in range(5):
        tau = sim.inverse_dynamics(q[k:k + 1], v[k:k + 1], vd[k:k + 1], include_damping=True)[0]
        want = truth.torque(robot, q[k], v[k], vd[k])[0] - joint.offset - cross @ vd[k]
        np.testing.assert_allclose(tau - friction(v[k]), want, atol=1e-9)
    # the diagram's forward dynamics (its rotor-coupling system) are exact: torque() of the
    # acceleration it gives is the applied torque, slow joints (Coulomb's tanh) included;
    # states near home, where no capsules touch (contact forces are no drive term)
    from pe_drake.multibody.model_plant import APPLIED_FORCE_PORT

    for _ in range(5):
        x = np.r_[rng.uniform(-0.5, 0.5, robot.n), rng.uniform(-1, 1, robot.n) * rng.choice([1, 0.01], robot.n)]
        u = rng.uniform(-5, 5, robot.n)
        sim.plant.SetPositionsAndVelocities(sim.plant_context, x)
        sim.diagram.GetInputPort(APPLIED_FORCE_PORT).FixValue(sim.context, u)
        a = sim.plant.get_generalized_acceleration_output_port().Eval(sim.plant_context)
        np.testing.assert_allclose(truth.torque(robot, x[:6], x[6:], a)[0] - joint.offset, u, atol=1e-9)


def test_a_per_motor_model_needs_its_transmission(optimized, tmp_path):  # noqa: F811
    """identified.json of a per-motor fit is refused for a robot without (or with another)
    transmission, naming the file; model.urdf's note says what a per-joint file leaves out."""
    from pe_drake.identification.identified_file import load_identified
    from pe_drake.identification.identify_model import IdentifyOptions, identify_model

    robot = coupled_robot()
    run = model_run(robot, true_model(robot), random_trajectory(robot, optimized, seed=1), 1)
    fit = identify_model(robot, run, IdentifyOptions(method="physical", filtering=False, rest="keep"))
    notes = []
    written = fit.write(tmp_path, progress=notes.append)
    assert str(tmp_path / "model.urdf") in written and "wrist_2_joint-wrist_3_joint" in notes[0], notes
    with pytest.raises(DataError, match="per motor through robot.transmission.*config gives none"):
        load_identified(tmp_path / "identified.json", get_robot("ur5"))


def test_diagnosis_prior_drive_torque_acts_per_motor(optimized):  # noqa: F811
    """diagnose --model of a per-motor fit: the prior's drive torque is Rᵀ τ_m(θ̇ = R q̇, θ̈ = R q̈),
    the coupled motor's Coulomb column the filtered tanh of its own velocity (written out here
    from the motors' side). Per joint (tanh of q̇_j alone) it had motor 6's friction with the
    wrong sign wherever q̇_5 + q̇_6 and q̇_6 differ in sign, and motor 4's (ratio −48) always:
    up to 4.1 N·m off on joints 4-6."""
    from pe_drake.diagnosis.options import DiagnosisConfig
    from pe_drake.diagnosis.prior import prior_drive_torque
    from pe_drake.diagnosis.record import prepare_record, split_segments
    from pe_drake.identification.identify_model import IdentifyOptions, identify_model

    robot = coupled_robot()
    truth = true_model(robot)
    run = model_run(robot, truth, random_trajectory(robot, optimized, seed=1), 1)
    prior = identify_model(robot, run, IdentifyOptions(filtering=False, rest="keep")).result
    layout = prior.drive_layout
    record = prepare_record(run, DiagnosisConfig())
    for seg in split_segments(record, DiagnosisConfig()):
        T = layout.transmission
        w, wd = T.motor_positions(record.v), T.motor_positions(seg.vd)
        wf = T.motor_positions(record.friction_v)  # the velocity inside tanh: not filtered at the torque cut-off
        coulomb = record.filtered(np.tanh(wf / (np.abs(np.diag(T.R)) * layout.velocity_scale)))[seg.idx]
        terms = {t: prior.model.term(t) for t in MOTOR_TERMS}  # per motor, motor side
        tau_m = (terms["coulomb"] * coulomb + terms["viscous"] * T.motor_positions(seg.v) + terms["offset"]
                 + terms["armature"] * wd)
        want = T.joint_torques(tau_m)
        got = prior_drive_torque(robot, prior, seg)
        np.testing.assert_allclose(got, want, atol=1e-9)
        # the case that matters: motor 6 turning against joint 6's own direction
        assert np.any(np.sign(w[seg.idx, 5]) != np.sign(record.v[seg.idx, 5]))
