"""Issue 37: robots nobody here had seen (a SCARA, an SDF with a prismatic joint, models without
inertials, capsule files with their margin): every stage runs, refuses with the fix, or says what
it left out."""

from __future__ import annotations

import json

import numpy as np

from pe_drake.cli import main
from pe_drake.excitation.constraints.collision import CollisionConstraint
from pe_drake.excitation.trajectory_file import load_motion
from pe_drake.multibody.registry import resolve_robot_config
from pe_drake.multibody.robot import Robot
from tests.unseen_robots import folding_arm


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
