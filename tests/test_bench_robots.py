"""``python -m pe_drake.bench robots`` (issue 21): one row per robot with the table's columns, the
whole chain run on a small arm, and a robot that cannot load gets its reason, not a crash."""

from __future__ import annotations

import pytest

from pe_drake.bench import bench_main as main
from pe_drake.bench_robots import (
    COLUMNS, ROBOTS, BenchOptions, BenchRobot, caps_yaml, hidden_friction, select_robots, short_reason,
)
from pe_drake.multibody.registry import example_robot_data_dir
from pe_drake.multibody.robot import load_robot
from pe_drake.simulation.truth import load_truth


def _table(output: str) -> tuple[list[str], list[str]]:
    lines = output.strip().splitlines()
    header = next(k for k, line in enumerate(lines) if line.startswith("robot "))
    rows = [line for line in lines[header + 1:] if not line.startswith(("BENCH ", "seconds per stage"))]
    return lines[header].split(), rows


def test_a_small_arm_runs_every_stage_and_a_broken_model_gets_its_reason(tmp_path, capsys):
    if not (example_robot_data_dir() / "robots/ur_description/urdf/ur3_robot.urdf").is_file():
        pytest.skip("example-robot-data has no UR3")
    broken = tmp_path / "broken_arm.urdf"
    broken.write_text("<robot name='broken_arm'><link name='a'/>")  # not closed
    code = main(["robots", "--robots", f"ur3,{broken}", "--max-iterations", "10", "--harmonics", "2"])
    assert code == 0
    out = capsys.readouterr().out
    header, rows = _table(out)
    assert header[:3] == ["robot", "loads", "mount"] and "capsules" in header and "cond" in header
    assert len(rows) == 2, out
    ur3, bad = rows
    assert ur3.startswith("ur3 ") and "yes (6 joints)" in ur3 and "upright (base_link)" in ur3
    assert "mesh" in ur3 and ("yes: coulomb" in ur3 or "no: coulomb" in ur3), ur3  # diagnose ran
    assert bad.startswith("broken_arm ") and ("config failed" in bad or "load failed" in bad), bad
    assert "broken_arm.urdf" in bad  # the reason names the file
    assert "BENCH robots=2 loaded=1" in out


def test_unknown_names_are_refused_naming_the_known_ones():
    with pytest.raises(ValueError, match="unknown robot 'nao'.*so101.*talos"):
        select_robots("so101,nao")
    assert [r.name for r in select_robots("")] == [r.name for r in ROBOTS]


def test_the_named_robots_are_in_the_bench():
    names = {r.name for r in ROBOTS}
    assert {"kinova", "so101", "z1", "ur3", "ur5", "ur10", "xarm7", "panda_fingers", "tiago_arm", "talos",
            "romeo", "icub"} <= names
    assert len(COLUMNS) == 9
    # issue 37's kinds, built in the run's folder: an SDF with a prismatic joint, a model without
    # inertials, a dual-arm on a lift, a textured xacro in its description package
    assert {"scara_sdf", "folding_no_inertials", "dual_arm_lift", "textured_xacro"} <= names


def test_the_textured_xacro_loads_from_its_package_with_its_texture(tmp_path):
    from pe_drake.bench_models import textured_xacro

    robot = load_robot(str(textured_xacro(tmp_path)))
    text = robot.model_path.read_text()
    assert robot.joint_names == ("j1", "j2", "j3")
    assert "package://" not in text and (tmp_path / "ws/arm_description/meshes/skin.png").as_uri() in text


def test_the_caps_go_into_the_config_a_user_would_write():
    text = caps_yaml(BenchRobot("x", "x.urdf", "robot:\n  joints: [a]\n"), BenchOptions(max_iterations=7))
    assert "joints: [a]" in text and "max_iterations: 7" in text and "starts: 1" in text and "periods: 1" in text


def test_the_hidden_friction_is_a_truth_the_simulation_takes(tmp_path):
    """Failed on the first bench run: Coulomb friction on the Panda's prismatic fingers was
    refused by simulate; since issue 37 simulate carries it, and every joint gets it."""
    robot = load_robot(str(example_robot_data_dir() / "robots/panda_description/urdf/panda.urdf"))
    path = tmp_path / "TRUTH.yaml"
    path.write_text(hidden_friction(robot, 0))
    truth = load_truth(path, robot)
    assert truth.friction_set["viscous"] == truth.friction_set["coulomb"] == set(robot.joint_names)
    assert truth.model.coulomb[0] == pytest.approx(0.02 * 87.0)  # 2 % of its effort limit
    assert truth.integrator == "radau3"


def test_reasons_are_one_short_line():
    assert short_reason(ValueError("a\n  b")) == "a b"
    assert len(short_reason("x" * 500)) == 90
    assert short_reason("file '/tmp/a/b/run.csv': bad") == "file 'run.csv': bad"
