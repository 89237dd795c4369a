"""The benchmarks run end to end and print their BENCH lines (issues 11, 38)."""

import re

import numpy as np
import pytest

from pe_drake.bench import bench_main as main


def test_bench_solve_prints_old_and_new_cpu_seconds_and_cond(capsys):
    """Issue 38: one BENCH line per robot with the old and the new formulation's CPU seconds
    and cond, from one run (a tiny budget keeps this a smoke test of the fields)."""
    assert main(["solve", "--robots", "ur5,two_arm_lift", "--max-iterations", "4"]) == 0
    out = capsys.readouterr().out
    lines = [row for row in out.splitlines() if row.startswith("BENCH ")]
    assert len(lines) == 2
    expected = {
        "robot", "n", "old_cpu_s", "new_cpu_s", "speedup", "old_solve_cpu_s", "new_solve_cpu_s", "old_cond",
        "new_cond", "cond_ratio",
        "old_iterations", "new_iterations", "old_valid", "new_valid",
    }
    for line, robot, n in zip(lines, ("ur5", "two_arm_lift"), (6, 10)):
        fields = dict(item.split("=", 1) for item in line.split()[1:])
        assert set(fields) == expected and fields["robot"] == robot and fields["n"] == str(n)
        assert float(fields["old_cpu_s"]) > 0 and float(fields["new_cpu_s"]) > 0
        assert float(fields["new_cond"]) > 1 and float(fields["old_cond"]) > 1
        assert float(fields["cond_ratio"]) == pytest.approx(float(fields["new_cond"]) / float(fields["old_cond"]), rel=1e-3)
    assert re.search(r"two_arm_lift +old .* CPU-s \(solve .*, quality report .*\)  cond", out)
    assert re.search(r"two_arm_lift +new .* CPU-s \(solve .*, quality report .*\)  cond", out)


def test_two_arm_lift_robot_loads_without_a_config(tmp_path):
    """The bench's 10-joint robot (a prismatic lift, a torso joint, two 4-joint arms) goes
    the default path: no config, capsules fitted to its shapes, the floor and self-collision
    checked, and its base parameters identifiable (the arms' joints all excited)."""
    from pe_drake.bench_solve import bench_config
    from pe_drake.excitation.constraints import constraints_from_config
    from pe_drake.excitation.problem import ExcitationProblem
    from pe_drake.multibody.robot import Robot

    config, name = bench_config("two_arm_lift", tmp_path)
    assert name == "two_arm_lift" and (tmp_path / "two_arm_lift.urdf").is_file() and config.robot.capsules
    robot = Robot(name, config.robot)
    assert robot.n == 10 and robot.joint_names[0] == "lift"
    # the lift's 0–0.4 m, with the safe defaults' margin for a model without a config
    assert 0.0 <= robot.limits.q_lower[0] < robot.limits.q_upper[0] <= 0.4
    assert [c.name for c in constraints_from_config(robot, config.excitation, config.environment)] == [
        "collision", "environment"
    ]
    problem = ExcitationProblem(robot, config.excitation)
    assert problem.num_variables == 21 * 10 and problem.base.count > 40
    assert np.isfinite(problem.value(problem.initial_guess(seed=0)))


def test_bench_payload_prints_its_errors(capsys):
    assert main(["payload", "--robot", "ur5", "--payloads", "1", "--seed", "3"]) == 0
    line = [row for row in capsys.readouterr().out.splitlines() if row.startswith("BENCH ")]
    fields = dict(item.split("=", 1) for item in line[0].split()[1:])
    assert fields["robot"] == "ur5" and float(fields["excitation_s"]) > 0
    assert float(fields["mass_percent"]) < 0.5 and float(fields["com_mm"]) < 1.0
