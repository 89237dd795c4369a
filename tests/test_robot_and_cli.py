"""Robot loading, configuration errors and the optimize CLI."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from pe_drake.cli import main
from pe_drake.config import Config, ExcitationConfig, RobotConfig
from pe_drake.exceptions import ConfigError, InfeasibleError, NotWithinLimitsError, UnknownNameError
from pe_drake.excitation.fourier import FourierBasis, FourierTrajectory, sample_times
from pe_drake.multibody.registry import builtin_robots
from pe_drake.multibody.robot import load_robot

PANDA_URDF = "package://example-robot-data/robots/panda_description/urdf/panda.urdf"


def test_builtin_robots_and_their_structure(panda, ur5, g1):
    assert builtin_robots() == ("g1", "panda", "ur5")
    assert (panda.n, ur5.n, g1.n) == (7, 6, 14)
    assert panda.plant.num_positions() == 7  # fingers welded
    # G1: soles at z ≈ 0 with every leg joint at zero (pelvis welded at 0.7919 m).
    ctx = g1.plant.CreateDefaultContext()
    foot = g1.plant.GetBodyByName("left_ankle_roll_link")
    z = g1.plant.EvalBodyPoseInWorld(ctx, foot).translation()[2] - 0.03 - 0.005  # sphere centre - radius
    assert abs(z) < 0.01
    assert all(name.startswith(("left_", "right_")) for name in g1.joint_names)


def test_limits_come_from_model_and_config(panda):
    lim = panda.limits
    # URDF: joint 1 in [-2.8973, 2.8973], 2.175 rad/s; config margin 0.05, velocity scale 0.8.
    assert lim.q_lower[0] == pytest.approx(-2.8973 + 0.05)
    assert lim.v_max[0] == pytest.approx(0.8 * 2.175)
    assert lim.vd_max[0] == pytest.approx(0.8 * 15.0)
    assert lim.effort_max[0] == pytest.approx(87.0)


def test_user_urdf_with_custom_joints_and_posture():
    cfg = RobotConfig(model=PANDA_URDF, joints=["panda_joint2", "panda_joint4"], locked_positions={"panda_joint1": 0.3})
    robot = load_robot(cfg)
    assert robot.joint_names == ("panda_joint2", "panda_joint4")
    assert robot.locked_positions["panda_joint1"] == 0.3
    assert robot.locked_positions["panda_joint3"] == 0.0


def test_unknown_joint_lists_valid_names():
    with pytest.raises(UnknownNameError, match="panda_joint1"):
        load_robot(RobotConfig(model=PANDA_URDF, joints=["elbow"]))


def test_unknown_robot_lists_builtins():
    with pytest.raises(UnknownNameError, match="panda"):
        load_robot("pandaa")


def test_an_example_robot_data_name_points_to_its_model_file(tmp_path, capsys):
    """`--robot z1` (README: pe_drake was tried on example-robot-data's robots) is not built in:
    the refusal gives the model file to pass instead, and that path then loads."""
    from pe_drake.multibody.registry import example_robot_data_dir

    z1 = example_robot_data_dir() / "robots" / "z1_description" / "urdf" / "z1.urdf"
    assert main(["optimize", "--robot", "z1", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "unknown robot 'z1'" in err and str(z1) in err and not (tmp_path / "o").exists()
    assert len(load_robot(str(z1)).joint_names) == 7
    with pytest.raises(UnknownNameError) as unknown:  # no look-alike: the built-ins and a path only
        load_robot("no_such_robot")
    assert unknown.value.choices[-1] == "<path to .urdf/.sdf/.urdf.xacro>"


def test_locked_posture_outside_limits():
    with pytest.raises(NotWithinLimitsError, match="panda_joint4"):
        load_robot(RobotConfig(model=PANDA_URDF, joints=["panda_joint1"], locked_positions={"panda_joint4": 1.0}))


def test_margin_that_empties_the_range():
    with pytest.raises(InfeasibleError, match="position_margin"):
        load_robot(RobotConfig(model=PANDA_URDF, joints=["panda_joint6"], position_margin=2.0))


@pytest.mark.parametrize(
    "bad",
    [
        Config(excitation=ExcitationConfig(omega=float("nan"))),
        Config(excitation=ExcitationConfig(harmonics=0)),
        Config(excitation=ExcitationConfig(criterion="trace")),
        Config(robot=RobotConfig(model=PANDA_URDF, velocity_scale=0.0)),
        Config(robot=RobotConfig(model=PANDA_URDF, acceleration_limits={"panda_joint1": -1.0})),
    ],
)
def test_bad_numbers_are_refused(bad):
    from pe_drake.config import validate_config

    with pytest.raises(ConfigError):
        validate_config(bad)


def test_fourier_derivatives_and_pullback():
    rng = np.random.default_rng(0)
    traj = FourierTrajectory(rng.normal(size=(2, 3)), rng.normal(size=(2, 3)), rng.normal(size=2), 0.7)
    t = np.linspace(0, 5, 7)
    q, v, vd = traj.evaluate(t)
    h = 1e-6
    qp, vp, _ = traj.evaluate(t + h)
    qm, vm, _ = traj.evaluate(t - h)
    np.testing.assert_allclose((qp - qm) / (2 * h), v, atol=1e-6)
    np.testing.assert_allclose((vp - vm) / (2 * h), vd, atol=1e-6)
    np.testing.assert_allclose(traj.evaluate(np.array([traj.period]))[0], traj.evaluate(np.zeros(1))[0], atol=1e-12)
    # Pullback is the transpose of the linear map (Eq. 49).
    basis = FourierBasis(3, 0.7, t)
    alpha = traj.alpha
    bars = [rng.normal(size=q.shape) for _ in range(3)]
    lhs = sum(np.sum(b * x) for b, x in zip(bars, basis.evaluate_alpha(alpha, 2)))
    rhs = basis.pullback(*bars) @ alpha
    assert lhs == pytest.approx(rhs)
    assert sample_times(8.0, 40)[1] == pytest.approx(0.2)


def test_cli_optimize_writes_everything(tmp_path):
    cfg = tmp_path / "small.yaml"
    cfg.write_text("excitation: {harmonics: 3, cost_samples: 24, constraint_samples: 96}\nsolver: {max_iterations: 60}\n")
    out = tmp_path / "out"
    code = main(["optimize", "--robot", "panda", "--config", str(cfg), "--out", str(out), "--quiet", "--csv-rate", "50"])
    assert code == 0
    data = json.loads((out / "trajectory.json").read_text())
    for key in ("robot", "joints", "omega", "harmonics", "a", "b", "q0", "duration", "locked_positions", "base_pose", "cond"):
        assert key in data
    assert data["duration"] == pytest.approx(2 * math.pi / data["omega"])
    report = json.loads((out / "report.json").read_text())
    assert report["success"] and min(report["margins_1khz"].values()) >= 0
    header = (out / "trajectory.csv").read_text().splitlines()[0].split(",")
    assert header[0] == "t" and "q.panda_joint1" in header and "vdot.panda_joint7" in header
    assert (out / "trajectory.png").stat().st_size > 10_000
    assert (out / "playback.html").exists()
    # What `view` draws: the run's capsules and environment, recorded; the playback shows them.
    assert Path(data["capsules"]).name == "panda_capsules.yaml"
    assert data["environment"] == {"floor": True, "floor_height": None, "boxes": []}
    from tests.test_viewer import html_commands

    commands = html_commands(out / "playback.html")
    drawn = {c["path"] for c in commands if c["type"] == "set_object"}
    assert "/drake/environment/floor" in drawn and any(p.startswith("/drake/capsules/panda/panda_link4/") for p in drawn)
    assert any(c["type"] == "set_target" for c in commands)  # the camera is framed on the arm
    # Eq. (50) exactly, from the JSON alone.
    a, b, q0, w = np.array(data["a"]), np.array(data["b"]), np.array(data["q0"]), data["omega"]
    t = 1.234
    k = np.arange(1, data["harmonics"] + 1)
    q = (a * np.sin(k * w * t)).sum(1) + (b * np.cos(k * w * t)).sum(1) + q0
    from pe_drake.excitation.trajectory_file import load_trajectory

    np.testing.assert_allclose(load_trajectory(out / "trajectory.json")[0].evaluate(np.array([t]))[0][0], q)


@pytest.mark.parametrize(
    "argv,message",
    [
        (["optimize", "--robot", "nope", "--out", "X"], "unknown robot"),
        (["optimize", "--robot", "panda", "--config", "missing.yaml", "--out", "X"], "does not exist"),
        (["optimize", "--robot", "/no/such/robot.urdf", "--out", "X"], "does not exist"),
    ],
)
def test_cli_errors_exit_nonzero_and_write_nothing(tmp_path, capsys, argv, message):
    argv = [a if a != "X" else str(tmp_path / "out") for a in argv]
    assert main(argv) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_cli_bad_config_value(tmp_path, capsys):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("excitation: {omega: -1.0}\n")
    assert main(["optimize", "--robot", "panda", "--config", str(cfg), "--out", str(tmp_path / "o")]) == 2
    assert "excitation.omega must be positive" in capsys.readouterr().err
    cfg.write_text("excitation: {omeg: 1.0}\n")
    assert main(["optimize", "--robot", "panda", "--config", str(cfg), "--out", str(tmp_path / "o")]) == 2
    assert "omeg" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_optimize_loads_no_identification_or_diagnosis_module(tmp_path):
    """Issue 33: the stage packages export lazily, so `pe-drake optimize` (run whole, in a fresh
    interpreter) imports neither the identification nor the diagnosis stage."""
    import os
    import subprocess
    import sys

    cfg = tmp_path / "small.yaml"
    cfg.write_text("excitation: {harmonics: 3, cost_samples: 24, constraint_samples: 96}\nsolver: {max_iterations: 30}\n")
    script = (
        "import sys\nfrom pe_drake.cli import main\n"
        f"code = main(['optimize', '--robot', 'panda', '--config', {str(cfg)!r}, '--out', {str(tmp_path / 'o')!r}, "
        "'--quiet', '--csv-rate', '50'])\n"
        "print(code, [m for m in sys.modules if m.startswith(('pe_drake.identification', 'pe_drake.diagnosis'))])\n"
    )
    root = str(Path(__file__).resolve().parent.parent)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, cwd=root,
                         env={**os.environ, "PYTHONPATH": root})
    assert run.stdout.strip().splitlines()[-1] == "0 []", run.stdout + run.stderr


def test_python_m_pe_drake_cli_runs_the_command_line(tmp_path):
    """`python -m pe_drake.cli` works from a checkout (no console script on PATH): it needs a
    __main__.py, and passes the exit code of a refused input through (2, one-line message)."""
    import os
    import subprocess
    import sys

    root = str(Path(__file__).resolve().parent.parent)
    env = {**os.environ, "PYTHONPATH": root}
    shown = subprocess.run([sys.executable, "-m", "pe_drake.cli", "--help"], capture_output=True, text=True,
                           timeout=120, cwd=tmp_path, env=env)
    assert shown.returncode == 0, shown.stderr
    assert "optimize" in shown.stdout and "identify" in shown.stdout
    refused = subprocess.run([sys.executable, "-m", "pe_drake.cli", "optimize", "--robot", "no_such_robot",
                              "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=300,
                             cwd=tmp_path, env=env)
    assert refused.returncode == 2, refused.stdout + refused.stderr
    assert "no_such_robot" in refused.stderr and "Traceback" not in refused.stderr
