"""Simulated measurements: the true robot's torque equals its inverse dynamics plus each effect."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pe_drake.exceptions import ConfigError, UnknownNameError
from pe_drake.excitation.fourier import FourierTrajectory
from pe_drake.excitation.trajectory_file import save_trajectory
from pe_drake.identification.measurements import read_measurement_csv
from pe_drake.multibody.inertia import perturb_inertias, phi_to_spatial_inertia
from pe_drake.multibody.robot import load_robot
from pe_drake.simulation.simulation import simulate, truth_path_for
from pe_drake.simulation.truth import ControlTruth, NoiseTruth, load_truth, make_truth

DURATION = 1.5  # [s]
SETTLED = 0.2  # [s] compare after the PD transient (the start is on the trajectory already)
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "truth_example.yaml"


@pytest.fixture(scope="module")
def robot():
    return load_robot("panda")


@pytest.fixture(scope="module")
def trajectory(robot):
    rng = np.random.default_rng(4)
    n, harmonics = robot.n, 3
    # The Panda's nominal posture is Franka's ready pose (joint 2 at -0.785), away from
    # q2 = 0 where joints 1 and 3 share an axis.
    q0 = robot.nominal_posture()
    return FourierTrajectory(
        rng.uniform(-0.12, 0.12, (n, harmonics)), rng.uniform(-0.12, 0.12, (n, harmonics)),
        q0, 2 * np.pi / 3.0,
    )


def _run(robot, trajectory, truth=None, duration=DURATION):
    return simulate(robot, trajectory, truth, duration)


@pytest.fixture(scope="module")
def baseline(robot, trajectory):
    return _run(robot, trajectory)


def _desired(trajectory, t):
    return trajectory.evaluate(t)


def _settled(m):
    return m.t >= SETTLED


def test_effect_free_torque_is_inverse_dynamics(robot, trajectory, baseline):
    m, truth = baseline
    assert m.num_samples == int(DURATION * 1000) + 1 and m.v is None and m.vd is None
    np.testing.assert_allclose(np.diff(m.t), 1e-3)
    q, v, vd = _desired(trajectory, m.t)
    assert np.abs(m.q - q).max() < 1e-4  # tracking converged from the first sample
    tau_id = robot.inverse_dynamics(q, v, vd)
    k = _settled(m)
    err = np.abs(m.tau[k] - tau_id[k])
    scale = np.abs(tau_id).max(axis=0)
    assert np.all(err.max(axis=0) < 2e-3 * scale + 5e-3), err.max(axis=0)
    for b, name in enumerate(robot.body_names):
        np.testing.assert_array_equal(truth["phi_true"][name], robot.phi_model[10 * b : 10 * b + 10])
    effects = {"viscous", "coulomb", "armature", "torque_offset", "torque_delay", "payload", "presliding_friction"}
    assert set(truth["effects"]) == effects


def test_viscous_friction_adds_b_v(robot, trajectory, baseline):
    truth = make_truth(robot, {"viscous": {"all": 0.3, "panda_joint7": 0.05}})
    m, d = _run(robot, trajectory, truth)
    b = np.array([0.3] * 6 + [0.05])
    assert d["effects"]["viscous"]["values"]["panda_joint7"] == 0.05
    _, v, _ = _desired(trajectory, m.t)
    k = _settled(m)
    diff = m.tau[k] - baseline[0].tau[k]
    # The controller leaves each effect to its feedback: the small tracking error it causes
    # moves the other joints' torques a little too.
    np.testing.assert_allclose(diff, b * v[k], atol=0.05 * np.abs(b * v).max())


def test_coulomb_friction_adds_smoothed_sign(robot, trajectory, baseline):
    # record_velocity: friction follows the actual velocity, not the desired one
    truth = make_truth(robot, {"coulomb": {"all": 0.8}, "coulomb_velocity_scale": 0.02}, record_velocity=True)
    m, _ = _run(robot, trajectory, truth)
    k = _settled(m)
    expected = 0.8 * np.tanh(m.v[k] / 0.02)
    error = np.abs(m.tau[k] - baseline[0].tau[k] - expected)
    # Away from velocity reversals (where the feedback needs ~10 ms to follow the jump)
    # the torque rises by f_c·sign(v).
    assert np.all(np.median(error, axis=0) < 0.05 * 0.8), np.median(error, axis=0)
    assert np.all(np.percentile(error, 90, axis=0) < 0.25 * 0.8)


def test_armature_adds_inertia_times_acceleration(robot, trajectory, baseline):
    truth = make_truth(robot, {"armature": {"panda_joint1": 0.4, "panda_joint6": 0.1}})
    m, _ = _run(robot, trajectory, truth)
    _, _, vd = _desired(trajectory, m.t)
    k = _settled(m)
    diff = m.tau[k] - baseline[0].tau[k]
    expected = np.zeros_like(diff)
    expected[:, 0], expected[:, 5] = 0.4 * vd[k, 0], 0.1 * vd[k, 5]
    np.testing.assert_allclose(diff, expected, atol=0.05 * np.abs(expected).max())


def test_offset_adds_a_constant(robot, trajectory, baseline):
    truth = make_truth(robot, {"torque_offset": {"panda_joint2": 1.5, "panda_joint5": -0.4}})
    m, d = _run(robot, trajectory, truth)
    k = _settled(m)
    diff = m.tau[k] - baseline[0].tau[k]
    expected = np.zeros(7)
    expected[1], expected[4] = 1.5, -0.4
    np.testing.assert_allclose(diff, np.broadcast_to(expected, diff.shape), atol=0.03)
    assert d["effects"]["torque_offset"]["values"]["panda_joint2"] == 1.5


def test_torque_is_true_dynamics_at_the_actual_motion(robot, trajectory):
    """Every effect at once: recorded tau = true rigid-body ID + friction + offset, evaluated
    at the simulated motion (v recorded without noise, vd by central differences)."""
    payload = {"link": "panda_link8", "mass": 0.5, "com": [0.0, 0.0, 0.05], "inertia": [4e-4, 4e-4, 2e-4, 0, 0, 0]}
    truth = make_truth(robot, {"viscous": {"all": 0.2}, "coulomb": {"all": 0.3}, "armature": {"all": 0.05},
                               "torque_offset": {"panda_joint4": -0.5}, "payload": payload},
                       seed=5, inertia_perturbation=0.1, record_velocity=True)
    m, _ = _run(robot, trajectory, truth)
    vd = np.gradient(m.v, m.t, axis=0)
    expected = truth.model.torque(robot, m.q, m.v, vd)  # rigid body with payload, rotor inertia, friction, offsets
    error = np.abs(m.tau - expected)[1:-1]  # np.gradient is one-sided at the ends
    assert np.all(np.median(error, axis=0) < 1e-3), np.median(error, axis=0)
    assert np.all(np.percentile(error, 95, axis=0) < 1e-2)


def test_payload_changes_torque_like_a_welded_body(robot, trajectory, baseline):
    payload = {"link": "panda_link7", "mass": 1.2, "com": [0.0, 0.02, 0.15], "inertia": [2e-3, 2e-3, 1e-3, 0, 0, 0]}
    truth = make_truth(robot, {"payload": payload}, record_velocity=True)
    m, d = _run(robot, trajectory, truth)

    def add_payload(plant, scene_graph):  # independent of pe_drake.simulation.simulation
        from pydrake.math import RigidTransform
        from pydrake.multibody.tree import RotationalInertia, SpatialInertia

        link = plant.GetBodyByName("panda_link7")
        M = SpatialInertia.MakeFromCentralInertia(1.2, [0.0, 0.02, 0.15], RotationalInertia(2e-3, 2e-3, 1e-3))
        body = plant.AddRigidBody("box", link.model_instance(), M)
        plant.WeldFrames(link.body_frame(), body.body_frame(), RigidTransform())

    loaded = load_robot("panda", before_finalize=add_payload)
    k = _settled(m)
    assert np.abs(m.tau[k] - baseline[0].tau[k]).max() > 1.0  # gravity of 1.2 kg at ~0.5 m
    q, v, vd = _desired(trajectory, m.t)
    np.testing.assert_allclose(m.tau[k], loaded.inverse_dynamics(q, v, vd)[k], atol=0.1)
    # Exactly, at the actual motion (the prior-model controller lags a little).
    tau_id = loaded.inverse_dynamics(m.q, m.v, np.gradient(m.v, m.t, axis=0))
    np.testing.assert_allclose(m.tau[1:-1], tau_id[1:-1], atol=5e-3)
    # truth.json lumps the payload into its link.
    b = robot.body_names.index("panda_link7")
    phi = np.asarray(d["phi_true"]["panda_link7"])
    assert phi[0] == pytest.approx(robot.phi_model[10 * b] + 1.2)


def test_perturbed_run_matches_true_parameters_of_truth_json(robot, trajectory, baseline):
    truth = make_truth(robot, inertia_perturbation=0.1, seed=7, record_velocity=True)
    m, d = _run(robot, trajectory, truth)
    check = load_robot("panda")
    for name, phi in d["phi_true"].items():
        if phi[0] > 0:
            body = check.plant.GetBodyByName(name)
            body.SetSpatialInertiaInBodyFrame(check.plant_context, phi_to_spatial_inertia(np.asarray(phi)))
    # The prior-model controller tracks with a small error: evaluate at the actual motion.
    vd = np.gradient(m.v, m.t, axis=0)
    tau_true = check.inverse_dynamics(m.q, m.v, vd)
    error = np.abs(m.tau - tau_true)[1:-1]
    assert np.all(np.max(error, axis=0) < 5e-3), np.max(error, axis=0)
    k = _settled(m)
    assert np.abs(m.tau[k] - baseline[0].tau[k]).max() > 0.1  # the perturbation shows


def test_controller_with_the_true_model_tracks_better(robot, trajectory):
    payload = {"link": "panda_link8", "mass": 1.0, "com": [0.0, 0.0, 0.05]}
    errors = {}
    for model in ("prior", "true"):
        truth = make_truth(robot, {"payload": payload}, inertia_perturbation=0.2, control=ControlTruth(model=model))
        _, d = _run(robot, trajectory, truth, duration=0.5)
        errors[model] = max(d["simulation"]["tracking_error_rms"].values())
    assert errors["true"] < 0.05 * errors["prior"], errors


def test_perturbation_is_valid_bounded_and_reproducible(robot):
    phi = robot.phi_model
    a = perturb_inertias(phi, 0.1, 3)
    np.testing.assert_array_equal(a, perturb_inertias(phi, 0.1, 3))
    assert not np.allclose(a, perturb_inertias(phi, 0.1, 4))
    np.testing.assert_array_equal(perturb_inertias(phi, 0.0, 3), phi)
    for b in range(robot.num_bodies):
        p0, p1 = phi[10 * b : 10 * b + 10], a[10 * b : 10 * b + 10]
        if p0[0] == 0:
            np.testing.assert_array_equal(p1, p0)  # massless frames untouched
            continue
        assert phi_to_spatial_inertia(p1).IsPhysicallyValid()
        assert abs(p1[0] / p0[0] - 1) <= 0.1 + 1e-12
        assert not np.allclose(p1, p0)
    with pytest.raises(ConfigError, match="inertia_perturbation"):
        perturb_inertias(phi, 0.7, 0)


def test_truth_seed_reproduces_parameters(robot):
    a, b = (make_truth(robot, inertia_perturbation=0.1, seed=11).model for _ in range(2))
    np.testing.assert_array_equal(a.phi, b.phi)


def test_delay_and_noise(robot, trajectory, baseline):
    truth = make_truth(robot, {"torque_delay": 0.004}, noise=NoiseTruth(encoder_counts_per_rev=2**16, tau_std=0.05),
                       record_velocity=True)
    m, d = _run(robot, trajectory, truth)
    m2, _ = _run(robot, trajectory, truth)
    np.testing.assert_array_equal(m.tau, m2.tau)  # noise reproducible from the seed
    step = 2 * np.pi / 2**16
    np.testing.assert_allclose(m.q / step, np.round(m.q / step), atol=1e-6)
    assert np.abs(m.q - baseline[0].q).max() <= step / 2 + 1e-12
    delayed = np.vstack([np.repeat(baseline[0].tau[:1], 4, axis=0), baseline[0].tau[:-4]])
    noise = m.tau - delayed
    assert np.std(noise) == pytest.approx(0.05, rel=0.05)
    assert abs(np.mean(noise)) < 0.01
    assert m.v is not None and d["noise"]["tau_std"] == 0.05


# ---- truth files and the command line ------------------------------------------------------


def _truth_file(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "truth.yaml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "text, match",
    [
        ("effects: {viscous: {all: -0.1}}", "non-negative"),
        ("effects: {coulomb: {panda_joint1: .nan}}", "finite"),
        ("effects: {armature: {all: .inf}}", "finite"),
        ("inertia_perturbation: 2.0", r"\[0, 0.5\]"),
        ("seed: -1", "seed"),
        ("bogus: 1", "bogus"),
        ("effects: {viscous: 0.1}", "truth file"),
        ("effects: {payload: {mass: 1.0}}", "no link"),
        ("effects: {payload: {link: panda_link7, mass: 0.0}}", "positive"),
        ("effects: {payload: {link: panda_link7, mass: 1.0, inertia: [1, 0.1, 0.1, 0, 0, 0]}}",
         "not physically valid"),
        ("control: {model: perfect}", "prior, true"),
        ("control: {rate_hz: 0}", "positive"),
        ("noise: {tau_std: -1}", "non-negative"),
        ("effects: {coulomb_velocity_scale: 0}", "positive"),
        ("integrator: euler_forward", "runge_kutta3"),
    ],
)
def test_bad_truth_file(tmp_path, robot, text, match):
    with pytest.raises(ConfigError, match=match):
        load_truth(_truth_file(tmp_path, text), robot)


def test_a_truth_in_code_is_checked_like_a_file(robot):
    """make_truth reads the effects section straight into the RobotModel, with the file's checks."""
    with pytest.raises(ConfigError, match="unknown effects key.*viscos"):
        make_truth(robot, {"viscos": {"all": 0.1}})
    with pytest.raises(ConfigError, match=r"effects.armature\['all'\].*non-negative"):
        make_truth(robot, {"armature": {"all": -0.1}})
    truth = make_truth(robot, {"coulomb": {"panda_joint2": 0.5}, "torque_delay": 0.002})
    assert truth.model.coulomb[1] == 0.5 and truth.model.torque_delay == 0.002
    assert truth.friction_set["coulomb"] == {"panda_joint2"} and not truth.friction_set["viscous"]


def test_missing_truth_file(tmp_path, robot):
    with pytest.raises(ConfigError, match="does not exist"):
        load_truth(tmp_path / "none.yaml", robot)


@pytest.mark.parametrize(
    "text, kind, listed",
    [
        ("effects: {viscous: {panda_joint9: 0.1}}", "joint", "panda_joint7, all"),
        ("effects: {payload: {link: gripper, mass: 1.0}}", "link", "panda_link7"),
    ],
)
def test_truth_names_checked_against_robot(tmp_path, robot, trajectory, text, kind, listed):
    path = _truth_file(tmp_path, text)
    with pytest.raises(UnknownNameError, match=listed) as err:
        load_truth(path, robot)
    assert err.value.kind == kind
    with pytest.raises(UnknownNameError, match=r"truth file '.*truth.yaml': unknown"):
        simulate(robot, trajectory, path, 0.1)


def test_simulate_run_names_the_truth_file_of_an_unknown_joint(tmp_path, robot):
    # a newcomer copies examples/truth_example.yaml for another robot: the refusal names the file
    from pe_drake.simulation import SimulateOptions, simulate_run

    path = _truth_file(tmp_path, "effects: {viscous: {joint9: 0.1}}")
    trajectory = Path(__file__).parent / "data" / "panda_optimized.json"
    with pytest.raises(UnknownNameError, match=r"truth file '.*truth.yaml': unknown joint 'joint9' in effects.viscous") as err:
        simulate_run(robot, trajectory, SimulateOptions(path))
    assert err.value.kind == "joint" and "panda_joint1" in err.value.choices


def test_example_truth_file_is_valid(robot):
    truth = load_truth(EXAMPLE, robot)
    assert truth.inertia_perturbation == pytest.approx(0.1)
    assert np.all(truth.model.viscous > 0) and np.all(truth.model.coulomb > 0)
    assert truth.model.viscous[6] == 0.03 and truth.model.coulomb[0] == 0.4


def test_command_writes_csv_and_truth(tmp_path, robot, trajectory, capsys):
    from pe_drake.cli import main

    save_trajectory(tmp_path / "trajectory.json", robot, trajectory)
    truth = _truth_file(tmp_path, "effects: {viscous: {all: 0.1}}\nnoise: {tau_std: 0.01}\n")
    out = tmp_path / "run" / "data.csv"
    code = main(["simulate", "--robot", "panda", "--trajectory", str(tmp_path / "trajectory.json"),
                 "--truth", str(truth), "--out", str(out), "--duration", "0.3"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "301 samples" in printed and "tracking error RMS" in printed
    m = read_measurement_csv(out, robot.joint_names)
    assert m.num_samples == 301
    data = json.loads(truth_path_for(out).read_text())
    assert truth_path_for(out).name == "data.truth.json"
    assert data["effects"]["viscous"]["values"]["panda_joint3"] == 0.1
    assert data["bodies"] == list(robot.body_names) and data["data_file"] == "data.csv"


def test_command_error_writes_nothing(tmp_path, robot, trajectory, capsys):
    from pe_drake.cli import main

    save_trajectory(tmp_path / "trajectory.json", robot, trajectory)
    truth = _truth_file(tmp_path, "effects: {coulomb: {joint_x: 0.1}}\n")
    out = tmp_path / "run" / "data.csv"
    code = main(["simulate", "--robot", "panda", "--trajectory", str(tmp_path / "trajectory.json"),
                 "--truth", str(truth), "--out", str(out), "--duration", "0.3"])
    assert code != 0
    printed = capsys.readouterr()
    err = printed.err
    assert "unknown joint 'joint_x'" in err and "panda_joint1" in err
    assert not out.exists() and not truth_path_for(out).exists()
    assert "simulating" not in printed.out  # refused before the work was announced


def test_command_refuses_trajectory_of_other_joints(tmp_path, robot, trajectory, capsys):
    from pe_drake.cli import main

    path = tmp_path / "trajectory.json"
    save_trajectory(path, robot, trajectory)
    data = json.loads(path.read_text())
    data["joints"] = list(reversed(data["joints"]))
    path.write_text(json.dumps(data))
    out = tmp_path / "data.csv"
    code = main(["simulate", "--robot", "panda", "--trajectory", str(path), "--truth", str(EXAMPLE),
                 "--out", str(out), "--duration", "0.3"])
    assert code == 2 and "differ from robot" in capsys.readouterr().err
    assert not out.exists()


def test_a_thin_rod_is_perturbed_into_a_rod_and_the_prior_covariance_ends():
    """example-robot-data's finger_edu has a link with Ixx = Iyy, Izz = 0 (a rod on its z
    axis): relative draws of its principal moments never met the triangle inequality again,
    so `simulate` refused the robot and `diagnose` looped for ever in its prior covariance."""
    from pe_drake.diagnosis.effects import prior_parameter_covariance
    from pe_drake.multibody.inertia import mass_on_a_line, principal_inertia
    from pe_drake.multibody.registry import example_robot_data_dir
    from pe_drake.multibody.robot import load_robot

    finger = load_robot(example_robot_data_dir() / "robots" / "finger_edu_description" / "robots" / "finger_edu.urdf")
    k = finger.body_names.index("finger_lower_link")
    rod = finger.phi_model[10 * k : 10 * k + 10]
    assert mass_on_a_line(rod) and not mass_on_a_line(finger.phi_model[10 * (k - 1) : 10 * k])
    phi = perturb_inertias(finger.phi_model, 0.1, 5)
    new = phi[10 * k : 10 * k + 10]
    assert phi_to_spatial_inertia(new).IsPhysicallyValid() and not np.allclose(new, rod)
    lam = np.sort(principal_inertia(new)[2])
    assert lam[0] < 1e-12 and abs(lam[1] / lam[2] - 1) < 1e-9  # still a rod
    S = prior_parameter_covariance(finger, 0.1, samples=500)
    assert np.all(np.isfinite(S)) and S[10 * k, 10 * k] > 0


def test_the_controller_feeds_forward_the_model_files_friction():
    """iCub's URDF gives every joint <dynamics damping="1">; the simulated robot has it, and the
    computed-torque law alone (kp·M on 0.4 g·m² wrists: 2.3 N·m/rad) let the wrists lag by
    0.2-0.4 rad, so the bench's run left the joint limits. The a-priori friction is fed forward."""
    from pe_drake.config import ExcitationConfig
    from pe_drake.excitation.problem import ExcitationProblem
    from pe_drake.multibody.registry import example_robot_data_dir, resolve_robot_config

    path = example_robot_data_dir() / "robots" / "icub_description" / "robots" / "icub_reduced.urdf"
    icub = load_robot(resolve_robot_config(str(path)))
    assert np.all(icub.joint_damping == 1.0)
    problem = ExcitationProblem(icub, ExcitationConfig(harmonics=3, rest_at_ends=True))
    trajectory = problem.trajectory(problem.initial_guess(seed=1, amplitude=0.2))
    _, info = simulate(icub, trajectory, None, duration=1.0)
    worst = max(info["simulation"]["tracking_error_rms"].values())
    assert worst < 0.005, worst  # [rad]; 0.2-0.4 rad before


def test_a_run_that_does_not_track_its_trajectory_is_flagged():
    from pe_drake.simulation.simulated_run import SimulatedRun

    sim = {"duration": 1.0, "rate_hz": 1000.0, "samples": 1001, "wall_time_s": 0.1,
           "tracking_error_rms": {"a": 0.001, "b": 0.15}}
    lines = SimulatedRun("r", "joint_torque", None, {"simulation": sim}).summary_lines()
    assert lines[-1].startswith("warning: b tracks its trajectory to 150 mrad RMS")
    assert "control.kp and control.kd in the truth file" in lines[-1]  # not the config: a newcomer looked there
    sim["tracking_error_rms"]["b"] = 0.005
    assert not any(line.startswith("warning") for line in SimulatedRun("r", "joint_torque", None,
                                                                        {"simulation": sim}).summary_lines())


def test_a_rotor_inertia_the_controller_lacks_is_named_as_the_tracking_errors_cause():
    # so101 (a hobby arm): 0.002 kg·m² of armature on 1e-5 kg·m² links lost the gripper by 545 mrad
    # with a prior-model controller; the warning blamed the friction
    from pe_drake.simulation.simulated_run import SimulatedRun

    sim = {"duration": 1.0, "rate_hz": 1000.0, "samples": 1001, "wall_time_s": 0.1,
           "tracking_error_rms": {"a": 0.001, "gripper": 0.545}}
    effects = {"armature": {"values": {"a": 0.002, "gripper": 0.002}}}
    truth = {"simulation": sim, "effects": effects, "control": {"model": "prior"}}
    cause = SimulatedRun("r", "joint_torque", None, truth).summary_lines()[-1]
    assert "armature (0.002 kg·m² on gripper) is not in the controller's model" in cause
    assert 'control.model: "true"' in cause and "friction" not in cause
    truth["control"] = {"model": "true"}  # the controller holds it: friction remains the suspect
    assert "friction is large" in SimulatedRun("r", "joint_torque", None, truth).summary_lines()[-1]


def test_simulate_says_which_joints_keep_the_model_files_friction():
    # a truth naming some joints leaves the others at the URDF's <dynamics> (the z1's 1 N·m):
    # simulated and identified, so the console says so (it was only in .truth.json)
    from pe_drake.simulation.simulated_run import SimulatedRun

    sim = {"duration": 1.0, "rate_hz": 1000.0, "samples": 1001, "wall_time_s": 0.1,
           "tracking_error_rms": {"j1": 1e-3, "j2": 1e-3}}
    effects = {"viscous": {"values": {"j1": 0.3, "j2": 1.0}, "source": {"j1": "truth", "j2": "model file"}},
               "coulomb": {"values": {"j1": 0.5, "j2": 0.0}, "source": {"j1": "truth", "j2": "model file"}}}
    lines = SimulatedRun("arm", "joint_torque", None, {"simulation": sim, "effects": effects}).summary_lines()
    kept = [line for line in lines if "of the model file kept" in line]
    assert kept == ["note: viscous friction of the model file kept where the truth does not set it: j2 1 N·m·s/rad"]
