"""Issue 22: the exported controller goal, interpolated independently with quintics, is the motion."""

from __future__ import annotations

import py_compile
from pathlib import Path

import numpy as np
import pytest
import yaml

from pe_drake.exceptions import NotWithinLimitsError
from pe_drake.excitation.controller_goal import GoalOptions, write_goal_bag, write_goal_yaml
from pe_drake.excitation.fourier import FourierTrajectory
from pe_drake.excitation.ramp import RampedMotion
from pe_drake.excitation.trajectory_file import write_motion_csv

JOINTS = ("j1", "j2", "j3")


def _motion(seed: int = 1) -> RampedMotion:
    rng = np.random.default_rng(seed)
    k = np.arange(1, 5)
    path = FourierTrajectory(rng.normal(size=(3, 4)) * 0.3 / k, rng.normal(size=(3, 4)) * 0.3 / k,
                             rng.normal(size=3) * 0.1, 2 * np.pi / 5)
    return RampedMotion(path, 2, 1.5, 0.0)


def quintic_hermite(t0, t1, p0, v0, a0, p1, v1, a1, t):
    """The quintic with position, velocity and acceleration given at both ends (as ros2_control's)."""
    h = t1 - t0
    s = (t - t0) / h
    # Coefficients in s for p(s) with dp/ds = v·h, d²p/ds² = a·h².
    c0, c1, c2 = p0, v0 * h, 0.5 * a0 * h * h
    d = p1 - c0 - c1 - c2
    e = v1 * h - c1 - 2 * c2
    f = a1 * h * h - 2 * c2
    c3 = 10 * d - 4 * e + 0.5 * f
    c4 = -15 * d + 7 * e - f
    c5 = 6 * d - 3 * e + 0.5 * f
    return c0 + s * (c1 + s * (c2 + s * (c3 + s * (c4 + s * c5))))


def test_goal_interpolated_with_quintics_matches_the_csv(tmp_path):
    motion = _motion()
    goal, csv = tmp_path / "trajectory_goal.yaml", tmp_path / "trajectory.csv"
    write_goal_yaml(goal, motion, JOINTS, GoalOptions(joint_names={"j2": "driver_j2"}))
    write_motion_csv(csv, JOINTS, motion, 1000.0)
    trajectory = yaml.safe_load(goal.read_text())["trajectory"]
    assert trajectory["joint_names"] == ["j1", "driver_j2", "j3"]
    points = trajectory["points"]
    tp = np.array([p["time_from_start"]["sec"] + 1e-9 * p["time_from_start"]["nanosec"] for p in points]) - 1.0
    P, V, A = (np.array([p[k] for p in points]) for k in ("positions", "velocities", "accelerations"))
    assert tp[0] == pytest.approx(0.0) and points[0]["time_from_start"]["sec"] == 1  # lead-in: nothing at 0
    assert np.allclose(np.diff(tp)[:-1], 0.02)  # 50 Hz
    for k in (0, -1):  # at rest
        assert np.abs(V[k]).max() < 1e-9 and np.abs(A[k]).max() < 1e-9
    table = np.loadtxt(csv, delimiter=",", skiprows=1)
    t, q = table[:, 0], table[:, 1:4]
    t = t[t <= tp[-1]]
    seg = np.clip(np.searchsorted(tp, t, side="right") - 1, 0, len(tp) - 2)
    interp = quintic_hermite(tp[seg, None], tp[seg + 1, None], P[seg], V[seg], A[seg], P[seg + 1], V[seg + 1],
                             A[seg + 1], t[:, None])
    error = np.abs(interp - q[: len(t)]).max()
    print(f"quintic interpolation of the 50 Hz goal vs the 1 kHz CSV: {error:.3g} rad")
    assert error < 1e-6
    # every point holds the limits the motion holds (sampled densely)
    qd, vd_, ad = motion.evaluate(np.linspace(0, motion.duration, 20001))
    for X, ref in ((P, qd), (V, vd_), (A, ad)):
        assert np.all(X.max(axis=0) <= ref.max(axis=0) + 1e-8) and np.all(X.min(axis=0) >= ref.min(axis=0) - 1e-8)


def test_jerk_limit_is_checked_and_the_bag_holds_the_same_trajectory(tmp_path):
    motion = _motion()
    with pytest.raises(NotWithinLimitsError, match="joint 'j1': jerk"):
        write_goal_yaml(tmp_path / "g.yaml", motion, JOINTS, GoalOptions(jerk_limits={"j1": 0.01}))
    assert not (tmp_path / "g.yaml").exists()
    write_goal_yaml(tmp_path / "g.yaml", motion, JOINTS, GoalOptions(jerk_limits={"j1": 1e4}))
    bag = tmp_path / "goal_bag"
    write_goal_bag(bag, motion, JOINTS, GoalOptions(topic="/arm/joint_trajectory"))
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        (conn,) = reader.connections
        assert conn.topic == "/arm/joint_trajectory" and conn.msgtype == "trajectory_msgs/msg/JointTrajectory"
        (_, _, raw), = list(reader.messages())
        msg = reader.deserialize(raw, conn.msgtype)
    points = yaml.safe_load((tmp_path / "g.yaml").read_text())["trajectory"]["points"]
    assert len(msg.points) == len(points)
    np.testing.assert_allclose(msg.points[7].positions, points[7]["positions"], rtol=1e-8)


def test_the_hardware_example_compiles():
    py_compile.compile(str(Path(__file__).resolve().parents[1] / "examples" / "ur_rtde_replay.py"), doraise=True)


def test_panda_goal_points_hold_the_robot_limits(panda, tmp_path):
    from pe_drake.excitation.ramp import choose_ramp_duration
    from pe_drake.excitation.trajectory_file import load_trajectory

    path, _ = load_trajectory(Path(__file__).parent / "data" / "panda_optimized.json")
    motion, _ = choose_ramp_duration(path, panda.limits)  # as optimize builds it
    goal = tmp_path / "trajectory_goal.yaml"
    write_goal_yaml(goal, motion, panda.joint_names, GoalOptions(jerk_limits=dict.fromkeys(panda.joint_names, 3750.0)))
    points = yaml.safe_load(goal.read_text())["trajectory"]["points"]
    P, V, A = (np.array([p[k] for p in points]) for k in ("positions", "velocities", "accelerations"))
    lim = panda.limits
    assert np.all(P >= lim.q_lower) and np.all(P <= lim.q_upper)
    assert np.all(np.abs(V) <= lim.v_max) and np.all(np.abs(A) <= lim.vd_max + 1e-9)
    assert np.abs(V[[0, -1]]).max() < 1e-9 and np.abs(A[[0, -1]]).max() < 1e-9
    assert min(p["time_from_start"]["sec"] + p["time_from_start"]["nanosec"] for p in points) > 0
