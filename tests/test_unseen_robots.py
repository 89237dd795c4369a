"""Issue 37: robots nobody here had seen (a SCARA, an SDF with a prismatic joint, models without
inertials, capsule files with their margin): every stage runs, refuses with the fix, or says what
it left out."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pe_drake.cli import main
from pe_drake.identification.measurements import write_measurement_csv
from pe_drake.simulation.simulated_run import SimulatedRun
from pe_drake.simulation.payload_synthetic import payload_run, random_true_arm
from pe_drake.multibody.payload import PayloadInertia, box_inertia
from pe_drake.excitation.constraints.collision import CollisionConstraint
from pe_drake.excitation.trajectory_file import load_motion
from pe_drake.multibody.registry import resolve_robot_config
from pe_drake.multibody.robot import Robot
from pe_drake.multibody.base_parameters import compute_base_parameters
from pe_drake.bench_models import folding_arm, scara, vertical_lift, without_inertials


def test_payload_motion_keeps_the_capsule_files_margin_at_1khz(tmp_path, capsys):
    """Item 1: the capsule file's collision_margin applies in payload mode as in plain optimize."""
    urdf, capsules = folding_arm(tmp_path, margin=0.05)
    cfg = tmp_path / "arm.yaml"
    cfg.write_text(f"robot: {{model: {urdf}, capsules: {capsules}}}\n")
    out = tmp_path / "out"
    code = main(["optimize", "--robot", str(urdf), "--config", str(cfg), "--payload", "hand", "--out", str(out),
                 "--max-iterations", "25"])
    printed = capsys.readouterr().out
    assert code == 0
    assert "collision" in printed.split("constraints:")[1].splitlines()[0]
    report = json.loads((out / "report.json").read_text())
    assert report["margins_1khz"]["collision"] >= -1e-6
    # the written motion, ramps included, at 1 kHz against the file's margin
    robot = Robot("folding", resolve_robot_config(str(urdf), str(cfg)).robot)
    motion, _ = load_motion(out / "trajectory.json")
    q, v, vd = motion.evaluate(np.arange(0.0, motion.duration, 1e-3))
    assert CollisionConstraint(robot, 0.05).margins(q, v, vd).min() >= -1e-6


def test_payload_motion_fits_capsules_as_plain_optimize_does(tmp_path, capsys):
    """Item 1: a robot with collision geometry and no capsule file (exit 2 before: the floor check
    had no capsules) gets fitted capsules and the self-collision check."""
    urdf, _ = folding_arm(tmp_path, collision=True)
    out = tmp_path / "out"
    assert main(["optimize", "--robot", str(urdf), "--payload", "hand", "--out", str(out), "--max-iterations", "25"]) == 0
    printed = capsys.readouterr().out
    assert "fitted capsules" in printed and "collision" in printed.split("constraints:")[1].splitlines()[0]
    assert json.loads((out / "report.json").read_text())["margins_1khz"]["collision"] >= -1e-6


def _strict_json(path):
    """The file as JSON, refusing Infinity and NaN (not JSON)."""
    def refuse(name):
        raise AssertionError(f"{path}: {name} is not JSON")
    return json.loads(path.read_text(), parse_constant=refuse)


def test_payload_on_a_scara_names_what_no_motion_excites_and_fits_the_rest(tmp_path, capsys):
    """Item 2: all axes vertical: the payload's tilting inertias and CoM height never make a torque.
    optimize names them and excites the rest (cond finite, valid JSON); identify fits the rest."""
    urdf = scara(tmp_path)
    cfg = tmp_path / "scara.yaml"
    cfg.write_text("environment: {floor: false}\n")  # a SCARA on a table: nothing below its base moves
    motion_dir = tmp_path / "motion"
    assert main(["optimize", "--robot", str(urdf), "--config", str(cfg), "--payload", "tool", "--out", str(motion_dir),
                 "--max-iterations", "30"]) == 0
    printed = capsys.readouterr().out
    assert "not determined" in printed and "Ixx.tool" in printed and "hz.tool" in printed
    report = _strict_json(motion_dir / "report.json")
    assert np.isfinite(report["cond"]) and report["cond"] < 1e6
    assert report["expected"]["com_std"][2] is None and report["expected"]["mass_std"] > 0
    _strict_json(motion_dir / "trajectory.json")
    robot = Robot("scara", resolve_robot_config(str(urdf)).robot)
    motion, _ = load_motion(motion_dir / "trajectory.json")
    rng = np.random.default_rng(3)
    arm = random_true_arm(robot, rng)
    payload = PayloadInertia(0.8, np.array([0.01, -0.02, -0.03]), box_inertia(0.8, [0.05, 0.06, 0.04]))
    for name, load in (("loaded", payload), ("unloaded", None)):
        run = payload_run(robot, motion, arm, "tool", load, seed=len(name), noise_std=0.01)
        write_measurement_csv(tmp_path / f"{name}.csv", run.replace(v=None, vd=None))
    out = tmp_path / "out"
    assert main(["identify", "--robot", str(urdf), "--payload", "tool", "--data", str(tmp_path / "loaded.csv"),
                 "--unloaded", str(tmp_path / "unloaded.csv"), "--trajectory", str(motion_dir / "trajectory.json"),
                 "--flange", "tool", "--out", str(out)]) == 0
    d = _strict_json(out / "payload.json")
    assert abs(d["mass"] - 0.8) < 0.02 and np.allclose(d["com"][:2], payload.com[:2], atol=3e-3)
    assert set(d["not_determined"]) == {"hz.tool", "Ixx.tool", "Iyy.tool", "Ixy.tool", "Ixz.tool", "Iyz.tool"}
    assert d["com_std"][2] is None and d["com_std"][0] is not None


@pytest.fixture(scope="module")
def massless(tmp_path_factory):
    """A run of the folding arm (its inertials, viscous and Coulomb friction) and the same arm's
    model without any <inertial>, as a ROS-Industrial description ships: (model, truth model, csv)."""
    folder = tmp_path_factory.mktemp("massless")
    urdf, _ = folding_arm(folder, collision=True)
    cfg = folder / "small.yaml"
    cfg.write_text("excitation: {harmonics: 3, cost_samples: 24, constraint_samples: 96}\nsolver: {max_iterations: 40}\n")
    assert main(["optimize", "--robot", str(urdf), "--config", str(cfg), "--out", str(folder / "motion"), "--quiet",
                 "--no-html"]) == 0
    (folder / "truth.yaml").write_text("seed: 1\neffects: {viscous: {all: 0.2}, coulomb: {all: 0.5}}\n")
    assert main(["simulate", "--robot", str(urdf), "--trajectory", str(folder / "motion" / "trajectory.json"),
                 "--truth", str(folder / "truth.yaml"), "--out", str(folder / "run.csv")]) == 0
    return without_inertials(urdf, folder), urdf, folder / "run.csv"


def _base_values(model, phi_of):
    robot = Robot("ref", resolve_robot_config(str(model)).robot)
    base = compute_base_parameters(robot)
    return base.K @ Robot("other", resolve_robot_config(str(phi_of)).robot).phi_model


def test_diagnose_with_a_massless_model_exports_what_the_data_determine(massless, tmp_path, capsys):
    """Item 3: the augmented model fell back to the zero prior (every joint "unexplained" at the
    a-priori error); the exported augmented_model.urdf now carries the data's base parameters."""
    model, truth_model, csv = massless
    out = tmp_path / "diag"
    assert main(["diagnose", "--robot", str(model), "--data", str(csv), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    prior = [float(x) for x in printed.split("1. a-priori model, held-out RMS [N·m]:")[1].split("\n")[0].replace(",", "").split()[1::2]]
    augmented = [float(x) for x in printed.split("4. augmented Drake model, held-out RMS [N·m]:")[1].split("\n")[0].replace(",", "").split()[1::2]]
    assert max(augmented) < 0.05 * max(prior)
    exported, truth = _base_values(truth_model, out / "augmented_model.urdf"), _base_values(truth_model, truth_model)
    assert np.abs(exported - truth).max() < 0.02 * np.abs(truth).max()


def test_a_model_without_inertials_says_up_front_what_works(massless, tmp_path, capsys):
    """Item 5: accepted without a word, an empty quality line, no playback, tracebacks in simulate
    and identify --method physical; now a note up front, the playback drawn, clear refusals."""
    model, _, csv = massless
    cfg = tmp_path / "small.yaml"
    cfg.write_text("excitation: {harmonics: 2, cost_samples: 16, constraint_samples: 64}\nsolver: {max_iterations: 10}\n"
                   "parallel: {starts: 1}\n")
    assert main(["optimize", "--robot", str(model), "--config", str(cfg), "--out", str(tmp_path / "opt")]) == 0
    printed = capsys.readouterr().out
    assert "no inertial parameters" in printed.split("constraints:")[0]  # before any work
    assert "std (pe_drake's base parameters): not available" in printed
    assert (tmp_path / "opt" / "playback.html").exists() and "could not write the HTML playback" not in printed
    (tmp_path / "truth.yaml").write_text("effects: {viscous: {all: 0.1}}\n")
    code = main(["simulate", "--robot", str(model), "--trajectory", str(tmp_path / "opt" / "trajectory.json"),
                 "--truth", str(tmp_path / "truth.yaml"), "--out", str(tmp_path / "sim.csv")])
    assert code == 2 and "identify --method physical" in capsys.readouterr().err
    out = tmp_path / "ident"
    assert main(["identify", "--robot", str(model), "--data", str(csv), "--method", "physical", "--out", str(out)]) == 0
    fitted = Robot("fitted", resolve_robot_config(str(out / "model.urdf")).robot)
    assert np.all(fitted.phi_model[0::10] > 0)


def _lift_run(tmp_path, more_effects: str = "") -> tuple:
    """A vertical lift's short motion simulated with viscous and Coulomb friction (and
    ``more_effects``, YAML entries of ``effects``) into run.csv: (model, trajectory.json)."""
    urdf = vertical_lift(tmp_path)
    cfg = tmp_path / "small.yaml"
    cfg.write_text("excitation: {harmonics: 3, cost_samples: 24, constraint_samples: 96}\nsolver: {max_iterations: 30}\n"
                   "environment: {floor: false}\n")
    assert main(["optimize", "--robot", str(urdf), "--config", str(cfg), "--out", str(tmp_path / "m"), "--quiet",
                 "--no-html", "--allow-unchecked"]) in (0, 1)
    (tmp_path / "truth.yaml").write_text("effects: {viscous: {all: 3.0}, coulomb: {all: 4.0}"
                                         + (f", {more_effects}" if more_effects else "") + "}\n")
    trajectory = str(tmp_path / "m" / "trajectory.json")
    assert main(["simulate", "--robot", str(urdf), "--trajectory", trajectory, "--truth", str(tmp_path / "truth.yaml"),
                 "--out", str(tmp_path / "run.csv")]) == 0
    return urdf, trajectory


def test_a_force_offset_on_a_vertical_prismatic_joint_is_not_turned_into_a_negative_armature(tmp_path, capsys):
    """Item 4: on a vertical axis the offset's column 1 and the armature's z̈ span the carried mass's
    g + z̈: identify dropped the offset ("the joint never reverses") and reported an armature of
    −offset/g. The offset is kept, the armature goes into the carried mass, and the reason is said."""
    urdf, _ = _lift_run(tmp_path, "torque_offset: {lift: 5.0}")
    capsys.readouterr()
    assert main(["identify", "--robot", str(urdf), "--data", str(tmp_path / "run.csv"), "--out", str(tmp_path / "id")]) == 0
    printed = capsys.readouterr().out
    assert "armature[lift] left out" in printed and "vertical" in printed
    assert "offset[lift] left out" not in printed
    drive = json.loads((tmp_path / "id" / "identified.json").read_text())["drive_terms"]["joints"]["lift"]
    # the offset carries the carried mass's error × g (m·g and the offset are both constant; the
    # mass comes from z̈ alone, which the 4 Hz low-pass biases by ~2 %): 5.4 N measured here
    assert "armature" not in drive and abs(drive["offset"]["value"] - 5.0) < 0.5


def test_simulate_takes_coulomb_friction_on_a_prismatic_joint_and_its_own_drive_effects(tmp_path, capsys):
    """Item 7: simulate refused Coulomb friction on prismatic joints, including the
    drive_effects.yaml that identify writes, so the README's round trip failed on any lift."""
    urdf, trajectory = _lift_run(tmp_path)
    assert main(["identify", "--robot", str(urdf), "--data", str(tmp_path / "run.csv"), "--out", str(tmp_path / "id")]) == 0
    drive = json.loads((tmp_path / "id" / "identified.json").read_text())["drive_terms"]["joints"]["lift"]
    assert abs(drive["coulomb"]["value"] - 4.0) < 0.2  # simulated, and found again
    # the round trip of the README: the identified model and its drive_effects.yaml
    assert main(["simulate", "--robot", str(tmp_path / "id" / "model.urdf"), "--trajectory", trajectory,
                 "--truth", str(tmp_path / "id" / "drive_effects.yaml"), "--out", str(tmp_path / "again.csv")]) == 0


def test_diagnose_on_an_sdf_robot_says_that_no_urdf_is_written(tmp_path, capsys):
    """Item 7: an SDF robot got no augmented_model.urdf and no word about it."""
    sdf = scara(tmp_path, "sdf")
    cfg = tmp_path / "small.yaml"
    cfg.write_text("excitation: {harmonics: 3, cost_samples: 24, constraint_samples: 96}\nsolver: {max_iterations: 30}\n"
                   "environment: {floor: false}\n")
    assert main(["optimize", "--robot", str(sdf), "--config", str(cfg), "--out", str(tmp_path / "m"), "--quiet",
                 "--no-html"]) == 0
    (tmp_path / "truth.yaml").write_text("effects: {viscous: {all: 0.5}}\n")
    assert main(["simulate", "--robot", str(sdf), "--trajectory", str(tmp_path / "m" / "trajectory.json"),
                 "--truth", str(tmp_path / "truth.yaml"), "--out", str(tmp_path / "run.csv")]) == 0
    capsys.readouterr()
    assert main(["diagnose", "--robot", str(sdf), "--data", str(tmp_path / "run.csv"), "--out", str(tmp_path / "d")]) == 0
    out = capsys.readouterr().out
    assert "augmented_model.urdf not written" in out
    assert not (tmp_path / "d" / "augmented_model.urdf").exists() and (tmp_path / "d" / "augmented_model.json").exists()
    # item 9: the SCARA's quill is prismatic: its figures are forces, not N·m alone
    assert "1. a-priori model, held-out RMS [N·m; N for prismatic joints]:" in out, out


def test_effort_units_follow_the_joint_kinds():
    from pe_drake.multibody.joint_limits import effort_label

    assert effort_label(["revolute", "revolute"]) == "N·m"
    assert effort_label(["prismatic"]) == "N"
    assert effort_label(["prismatic", "revolute"]) == "N·m; N for prismatic joints"


def test_payload_messages_fit_the_robot(tmp_path, capsys):
    """Item 9: --flange was demanded on a robot without a known flange name (the payload link is
    known); "Franka setLoad" was printed for a non-Franka robot; without an unloaded run the ±
    looked like the payload's error; the tracking warning blamed friction for a payload."""
    urdf = scara(tmp_path)
    cfg = tmp_path / "scara.yaml"
    cfg.write_text("environment: {floor: false}\n")
    assert main(["optimize", "--robot", str(urdf), "--config", str(cfg), "--payload", "tool", "--out", str(tmp_path / "m"),
                 "--max-iterations", "20", "--quiet"]) == 0
    (tmp_path / "truth.yaml").write_text("effects: {payload: {link: tool, mass: 3.0, com: [0, 0, -0.05], "
                                         "inertia: [0.001, 0.001, 0.001, 0, 0, 0]}}\n")
    capsys.readouterr()
    assert main(["simulate", "--robot", str(urdf), "--trajectory", str(tmp_path / "m" / "trajectory.json"),
                 "--truth", str(tmp_path / "truth.yaml"), "--out", str(tmp_path / "run.csv")]) == 0
    printed = capsys.readouterr().out
    assert " mm" in printed.split("tracking error RMS")[1].split("\n")[0]  # the lift's error in mm
    sim = {"duration": 1.0, "rate_hz": 1000.0, "samples": 1001, "wall_time_s": 0.1, "tracking_error_rms": {"lift": 0.05}}
    lines = SimulatedRun("scara", "joint_torque", None, {"simulation": sim, "effects": {"payload": {"link": "tool", "mass": 3.0}}},
                         ("lift",)).summary_lines()
    assert "to 50 mm RMS" in lines[-1] and "payload (3 kg on tool)" in lines[-1] and "friction" not in lines[-1]
    assert main(["identify", "--robot", str(urdf), "--payload", "tool", "--data", str(tmp_path / "run.csv"),
                 "--out", str(tmp_path / "p")]) == 0
    printed = capsys.readouterr().out
    assert "setLoad" not in printed and "without them" in printed
    assert _strict_json(tmp_path / "p" / "payload.json")["vendor"]["flange"] == "tool"


def test_a_prismatic_position_in_mm_is_named_as_mm_not_degrees(tmp_path):
    """Item 9: a lift logged in mm was told "the column looks like degrees: multiply by π/180"."""
    from pe_drake.exceptions import DataError
    from pe_drake.identification.data_checks import check_positions

    robot = Robot("lift", resolve_robot_config(str(vertical_lift(tmp_path))).robot)
    with pytest.raises(DataError, match="looks like mm: divide by 1000"):
        check_positions(robot, np.array([[-100.0], [0.0], [120.0]]), "log.csv")


def _acrobot():
    from pydrake.common import FindResourceOrThrow

    return FindResourceOrThrow("drake/examples/acrobot/Acrobot.sdf")


def test_a_robot_hanging_below_its_base_is_told_the_floor_blocks(tmp_path, capsys):
    """Item 9: Drake's Acrobot hangs below its base: the start-posture refusal did not say that
    the floor is what blocks; a joint without limits was refused twice, after a stray "the floor
    is NOT checked"."""
    out = str(tmp_path / "o")
    assert main(["optimize", "--robot", _acrobot(), "--out", out]) == 2
    captured = capsys.readouterr()
    assert "NOT checked" not in captured.out + captured.err and captured.err.count("no finite position limits") == 1
    cfg = tmp_path / "acrobot.yaml"
    cfg.write_text("robot:\n  position_limits: {shoulder: [-3.0, 3.0], elbow: [-2.5, 2.5]}\n"
                   "  velocity_limits: {shoulder: 3.0, elbow: 3.0}\n")
    assert main(["optimize", "--robot", _acrobot(), "--config", str(cfg), "--out", out]) != 0
    err = capsys.readouterr().err
    assert "the floor blocks every one" in err and "floor: false" in err


def test_the_output_says_when_the_iteration_limit_ended_the_solve(tmp_path, capsys):
    """Item 10: optimize usually stopped at its iteration limit; the output says that the budget,
    not convergence, ended the solve, and what more iterations would do."""
    cfg = tmp_path / "small.yaml"
    cfg.write_text("excitation: {harmonics: 3, cost_samples: 24, constraint_samples: 96}\nenvironment: {floor: false}\n")
    main(["optimize", "--robot", str(vertical_lift(tmp_path)), "--config", str(cfg), "--out", str(tmp_path / "m"),
          "--max-iterations", "3", "--no-html", "--allow-unchecked"])
    printed = capsys.readouterr().out
    assert "stopped at its iteration limit (3) before converging" in printed and "--max-iterations" in printed


def test_the_bench_has_robots_of_these_kinds_and_they_load(tmp_path):
    """``python -m pe_drake.bench robots`` rows for an SDF with a prismatic joint, a model without
    inertials (identified from a run of its twin with them) and a dual-arm torso on a lift."""
    from pe_drake.bench_robots import select_robots

    entries = {e.name: e for e in select_robots("scara_sdf,folding_no_inertials,dual_arm_lift")}
    kinds = {}
    for name, entry in entries.items():
        folder = tmp_path / name
        folder.mkdir()
        robot = Robot(name, resolve_robot_config(str(entry.build(folder))).robot)
        kinds[name] = ({j.kind for j in robot.joints}, robot.model_path.suffix, float(robot.phi_model[0::10].sum()))
    assert "prismatic" in kinds["scara_sdf"][0] and kinds["scara_sdf"][1] == ".sdf"
    assert kinds["folding_no_inertials"][2] == 0.0 and entries["folding_no_inertials"].simulate_with is not None
    assert "prismatic" in kinds["dual_arm_lift"][0]


def test_payload_identification_on_an_sdf_robot_writes_payload_json(tmp_path, capsys):
    """Item 7: identify --payload on an SDF robot fitted the payload, then exited 2 writing nothing
    (model_with_payload.urdf needs a URDF); payload.json is written and the URDF said not to be."""
    sdf = scara(tmp_path, "sdf")
    cfg = tmp_path / "scara.yaml"
    cfg.write_text("environment: {floor: false}\n")
    assert main(["optimize", "--robot", str(sdf), "--config", str(cfg), "--payload", "tool", "--out", str(tmp_path / "m"),
                 "--max-iterations", "20", "--quiet"]) == 0
    robot = Robot("scara", resolve_robot_config(str(sdf)).robot)
    motion, _ = load_motion(tmp_path / "m" / "trajectory.json")
    payload = PayloadInertia(0.5, np.array([0.01, 0.0, -0.02]), box_inertia(0.5, [0.04, 0.04, 0.04]))
    run = payload_run(robot, motion, random_true_arm(robot, np.random.default_rng(1)), "tool", payload, seed=2)
    write_measurement_csv(tmp_path / "loaded.csv", run.replace(v=None, vd=None))
    capsys.readouterr()
    assert main(["identify", "--robot", str(sdf), "--payload", "tool", "--data", str(tmp_path / "loaded.csv"),
                 "--out", str(tmp_path / "p")]) == 0
    assert "model_with_payload.urdf not written" in capsys.readouterr().out
    assert abs(_strict_json(tmp_path / "p" / "payload.json")["mass"] - 0.5) < 0.05
    assert not (tmp_path / "p" / "model_with_payload.urdf").exists()


def test_the_floor_refusal_names_the_keys_that_raise_a_hanging_robot(tmp_path):
    """Newcomer pass (Alexander's lower body): the refusal said "robot.base_pose to raise its
    base", a key that does not exist, and raising the base alone keeps the floor at the base's
    plane; robot.base_position with environment.floor_height clears it."""
    from pe_drake.config import Config, EnvironmentConfig, RobotConfig
    from pe_drake.exceptions import InfeasibleError
    from pe_drake.excitation.nominal import choose_nominal_posture
    from pe_drake.multibody.capsule_fitting import fit_capsules

    limits = dict(position_limits={"shoulder": [-3.0, 3.0], "elbow": [-2.5, 2.5]},
                  velocity_limits={"shoulder": 3.0, "elbow": 3.0})
    raised = RobotConfig(model=_acrobot(), base_position=[0.0, 0.0, 5.0], **limits)
    config, _ = fit_capsules(Config(robot=raised), tmp_path / "fit")
    with pytest.raises(InfeasibleError, match="robot.base_position") as refusal:
        choose_nominal_posture(Robot("acrobot", config.robot), config.excitation, config.environment)
    assert "base_pose" not in str(refusal.value) and "environment.floor_height" in str(refusal.value)
    choose_nominal_posture(Robot("acrobot", config.robot), config.excitation, EnvironmentConfig(floor_height=0.0))


def test_the_export_hint_keeps_the_runs_config():
    """Newcomer pass (Alexander's lower body on a raised base): identify's hint dropped --config,
    and the export it suggested put the base back at the URDF's pose without a word."""
    from pe_drake.cli.common import export_hint

    hint = export_hint("out/identified.json", "robot.urdf", "rig.yaml")
    assert "--robot robot.urdf --config rig.yaml --to" in hint
    assert "--config" not in export_hint("out/identified.json", "panda")
