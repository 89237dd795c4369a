"""Issue 37: robots nobody here had seen (a SCARA, an SDF with a prismatic joint, models without
inertials, capsule files with their margin): every stage runs, refuses with the fix, or says what
it left out."""

from __future__ import annotations

import json

import numpy as np

from pe_drake.cli import main
from pe_drake.identification.measurements import write_measurement_csv
from pe_drake.identification.payload_synthetic import payload_run, random_true_arm
from pe_drake.multibody.payload import PayloadInertia, box_inertia
from pe_drake.excitation.constraints.collision import CollisionConstraint
from pe_drake.excitation.trajectory_file import load_motion
from pe_drake.multibody.registry import resolve_robot_config
from pe_drake.multibody.robot import Robot
from tests.unseen_robots import folding_arm, scara


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
