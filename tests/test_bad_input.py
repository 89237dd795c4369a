"""Issue 10: every bad input gets a clear error, exit 2, and nothing written."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pe_drake.cli import main

DATA = Path(__file__).parent / "data"
TRAJ = str(DATA / "panda_optimized.json")


@pytest.mark.parametrize("text, message", [
    ("excitation: {harmonics: 3\n", "line 2, column 1: YAML syntax error"),
    ("excitation:\n  - harmonics: 3\n", "line 2, key 'excitation': expected a mapping"),
    ("excitation:\n  harmonics: three\n", "line 2, key 'excitation.harmonics': expected an integer, got 'three'"),
    ("robot: [1, 2]\n", "line 1, key 'robot': expected a mapping"),
    ("- a\n- b\n", "key '(top level)': expected a mapping"),
    ("excitation:\n  harmonics: 3\n  omeg: 2\n", "line 3, key 'excitation.omeg': unknown key"),
    ("excitation:\n  cost_samples: 1\n", "cost_samples = 1 gives 7 rows of joint_torque for 43 base parameters"),
    ("excitation:\n  omega: 1.0e6\n", "gives a period of 6.283e-06 s"),
    ("robot:\n  nominal_positions: {elbow: 0.3}\n", "unknown joint 'elbow' in robot.nominal_positions"),
    ("excitation:\n  constraint_samples: 3\n", "constraint_samples = 3 is too few for 5 harmonics"),
    ("excitation:\n  seed: -1\n", "excitation.seed must be an integer from 0"),
    ("excitation:\n  periods: 0\n", "excitation.periods must be an integer from 1"),
    ("environment:\n  boxes: [{center: [0, 0], size: [1, 1, 1]}]\n", "environment.boxes[0].center must be 3"),
    ("environment:\n  floor: maybe\n", "key 'environment.floor': expected true or false"),
])
def test_bad_config_files(tmp_path, capsys, text, message):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text(text)
    out = tmp_path / "out"
    assert main(["optimize", "--robot", "panda", "--config", str(cfg), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert message in err, err
    assert not out.exists()


@pytest.mark.parametrize("argv, message", [
    (["optimize", "--robot", "panda", "--out", "{file}"], "exists and is a file; give a folder"),
    (["optimize", "--robot", "panda", "--out", "/proc/pe_drake_test/out"], "cannot write in the folder '/proc'"),
    (["optimize", "--robot", "panda", "--out", "{tmp}/o", "--seed", "-1"], "--seed must be an integer from 0"),
    (["optimize", "--robot", "panda", "--out", "{tmp}/o", "--csv-rate", "1e6"], "--csv-rate must be from 1 to 10000 Hz"),
    (["optimize", "--robot", "panda", "--out", "{tmp}/o", "--periods", "0"], "--periods must be an integer from 1"),
    (["optimize", "--robot", "panda", "--out", "{tmp}/o", "--periods", "1000", "--csv-rate", "10000"],
     "trajectory.csv would hold up to 1e+08 rows"),
    (["optimize", "--robot", "panda", "--out", "{tmp}/o", "--prior", "{bad_json}"], "'omega' = 0"),
    (["view", TRAJ, "--html", "{tmp}"], "--html '{tmp}' is a folder"),
    (["simulate", "--robot", "panda", "--trajectory", TRAJ, "--truth", "t.yaml", "--out", "{tmp}"], "is a folder"),
    (["validate", "--robot", "panda", "--model", "m.json", "--data", "d.csv", "--json", "{tmp}"], "--json '{tmp}' is a folder"),
    (["validate", "--robot", "panda", "--model", "m.json", "--data", "d.csv", "--plot", "{tmp}/p.txt"], "must end in .png"),
    (["identify", "--robot", "panda", "--data", "d.csv", "--out", "{file}"], "exists and is a file"),
    (["diagnose", "--robot", "panda", "--data", "d.csv", "--out", "/proc/pe_drake_test"], "cannot write in the folder"),
])
def test_output_paths_and_arguments_are_checked_before_any_work(tmp_path, capsys, argv, message):
    afile = tmp_path / "afile"
    afile.write_text("user data\n")
    bad = tmp_path / "bad.json"
    data = json.loads(Path(TRAJ).read_text())
    data["omega"] = 0
    bad.write_text(json.dumps(data))
    fill = {"{file}": str(afile), "{tmp}": str(tmp_path), "{bad_json}": str(bad)}

    def sub(a):
        for k, v in fill.items():
            a = a.replace(k, v)
        return a

    assert main([sub(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert sub(message) in err, err
    assert afile.read_text() == "user data\n"
    assert not (tmp_path / "o").exists()


def test_reused_out_gets_its_own_stale_outputs_removed_only(tmp_path):
    from pe_drake.output_paths import OPTIMIZE_OUTPUTS, remove_stale_outputs

    for name in OPTIMIZE_OUTPUTS + ("notes.txt", "my.csv"):
        (tmp_path / name).write_text("old")
    removed = remove_stale_outputs(tmp_path, OPTIMIZE_OUTPUTS, ["report.json"])
    assert set(removed) == set(OPTIMIZE_OUTPUTS) - {"report.json"}
    assert (tmp_path / "notes.txt").exists() and (tmp_path / "my.csv").exists()
    assert (tmp_path / "report.json").exists()


@pytest.mark.slow
def test_failed_optimize_leaves_no_stale_trajectory(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    for name in ("trajectory.json", "playback.html", "notes.txt"):
        (out / name).write_text("old")
    cfg = tmp_path / "c.yaml"
    cfg.write_text("excitation: {harmonics: 3, cost_samples: 24, constraint_samples: 96}\nsolver: {max_iterations: 1}\n")
    code = main(["optimize", "--robot", "panda", "--config", str(cfg), "--out", str(out), "--quiet", "--no-html"])
    names = {p.name for p in out.iterdir()}
    assert "notes.txt" in names and "playback.html" not in names  # --no-html: the old playback is gone
    if code == 1:
        assert "trajectory.json" not in names
    else:
        assert json.loads((out / "trajectory.json").read_text())["periods"] == 1


def test_one_joint_check_names_the_file_the_missing_and_extra_joints_and_the_robots():
    from types import SimpleNamespace

    from pe_drake.exceptions import ConfigError, DataError, JointMismatchError, check_joints

    robot = SimpleNamespace(name="arm", joint_names=("j1", "j2", "j3"))
    check_joints(robot, ["j1", "j2", "j3"])
    check_joints(robot, ["j3", "j1", "j2"], any_order=True)
    with pytest.raises(JointMismatchError) as err:
        check_joints(robot, ["j1", "j2", "x9"], file="log.csv")
    text = str(err.value)
    assert "log.csv" in text and "missing: j3" in text and "not the robot's: x9" in text and "j1, j2, j3" in text
    assert "robot 'arm': its excited joints are j1, j2, j3" in text and "''s" not in text  # was "robot 'arm''s"
    assert isinstance(err.value, DataError) and isinstance(err.value, ConfigError)
    assert err.value.missing == ("j3",) and err.value.extra == ("x9",)
    with pytest.raises(JointMismatchError, match="another order"):
        check_joints(robot, ["j3", "j1", "j2"])
    with pytest.raises(JointMismatchError):
        check_joints(robot, ["j1", "j1", "j2", "j3"], any_order=True)


def test_a_config_exciting_fewer_built_in_joints_drops_the_built_in_entries_of_the_others(tmp_path):
    """Newcomer pass: README's config example (4 of the Panda's joints) was refused for
    'panda_joint5' in robot.acceleration_limits, an entry of models/panda.yaml the user never
    wrote; an entry the user writes for a locked joint is still refused."""
    from pe_drake.exceptions import UnknownNameError
    from pe_drake.multibody.registry import resolve_robot_config
    from pe_drake.multibody.robot import Robot

    four = ("robot:\n  joints: [panda_joint1, panda_joint2, panda_joint3, panda_joint4]\n"
            "  locked_positions: {panda_joint5: 0.0, panda_joint6: 1.57, panda_joint7: 0.78}\n")
    cfg = tmp_path / "four.yaml"
    cfg.write_text(four + "  acceleration_limits: {panda_joint1: 5.0}\n")
    config = resolve_robot_config("panda", cfg)
    assert config.robot.acceleration_limits == {"panda_joint1": 5.0, "panda_joint2": 7.5, "panda_joint3": 10.0,
                                                "panda_joint4": 12.5}
    assert set(config.robot.nominal_positions) <= set(config.robot.joints)
    assert list(Robot("panda", config.robot).joint_names) == config.robot.joints
    cfg.write_text(four + "  acceleration_limits: {panda_joint5: 5.0}\n")
    with pytest.raises(UnknownNameError, match="'panda_joint5' in robot.acceleration_limits"):
        Robot("panda", resolve_robot_config("panda", cfg).robot)
