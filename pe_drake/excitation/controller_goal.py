"""The optimized motion as a goal a ros2_control joint_trajectory_controller runs as it is.

The controller takes a ``FollowJointTrajectory`` goal (positions, velocities, accelerations per
point) and interpolates with quintics: 50 Hz waypoints reproduce the Fourier motion to far below
a micro-radian. Point k is the state at t_k = k / rate, with ``time_from_start`` = t_k + lead-in:
no point at 0, which the controller would not interpolate to (its first segment starts from the
robot's current state, which must be the motion's start at rest).

:func:`write_goal_yaml` writes it for ``ros2 action send_goal``, :func:`write_goal_bag` as an
MCAP bag for ``ros2 bag play``.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from pe_drake.exceptions import ConfigError, NotWithinLimitsError
from pe_drake.io_utils import atomic_write_text

#: Rate at which the jerk is checked [Hz].
JERK_CHECK_HZ = 1000.0


@dataclasses.dataclass(frozen=True)
class GoalOptions:
    """How the goal is written.

    Attributes:
        rate_hz: waypoint rate [Hz].
        lead_in_s: added to every ``time_from_start`` [s], > 0.
        joint_names: {URDF joint: the driver's name} for drivers whose names differ.
        jerk_limits: {URDF joint: limit} [rad/s³]; joints not listed are not checked.
    """

    rate_hz: float = 50.0
    lead_in_s: float = 1.0
    topic: str = "/joint_trajectory_controller/joint_trajectory"
    joint_names: Mapping[str, str] = dataclasses.field(default_factory=dict)
    jerk_limits: Mapping[str, float] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("rate_hz", "lead_in_s"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ConfigError(f"{name} must be a positive number, got {value!r}")

    @classmethod
    def from_config(cls, config) -> GoalOptions:
        """From a :class:`~pe_drake.config.Config` (sections ``controller`` and ``robot.jerk_limits``)."""
        c = config.controller
        return cls(c.goal_rate_hz, c.lead_in_s, c.topic, dict(c.joint_names), dict(config.robot.jerk_limits))


def check_jerk(motion, joint_names: Sequence[str], jerk_limits: Mapping[str, float]) -> np.ndarray:
    """Peak |jerk| per joint (central difference of the exact acceleration at ``JERK_CHECK_HZ``),
    shape (n,) [rad/s³]; NotWithinLimitsError for one above its limit."""
    t = motion.sample_times(JERK_CHECK_HZ)
    jerk = np.gradient(motion.evaluate(t)[2], 1.0 / JERK_CHECK_HZ, axis=0)
    peak = np.abs(jerk).max(axis=0)
    for j, name in enumerate(joint_names):
        limit = jerk_limits.get(name)
        if limit is not None and peak[j] > limit:
            k = int(np.argmax(np.abs(jerk[:, j])))
            err = NotWithinLimitsError(name, float(jerk[k, j]), -limit, limit, what=f"jerk [rad/s³] at t = {t[k]:.4g} s")
            err.args = (f"{err.args[0]} (robot.jerk_limits; the controller would refuse it): lower the amplitude "
                        "or the frequency, or lengthen the ramp",)
            raise err
    return peak


def goal_points(motion, rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t_k, q, v, vd) at ``rate_hz`` from 0 to the end of the motion (both at rest), t_k [s]."""
    count = int(math.ceil(motion.duration * rate_hz - 1e-9))
    t = np.append(np.arange(count) / rate_hz, motion.duration)
    t = np.unique(np.round(t, 12))
    return (t, *motion.evaluate(t))


def _names(joint_names: Sequence[str], options: GoalOptions) -> list[str]:
    unknown = [j for j in options.joint_names if j not in joint_names]
    if unknown:
        raise ConfigError(f"controller.joint_names names {', '.join(unknown)}, not excited joints: "
                          f"{', '.join(joint_names)}")
    return [options.joint_names.get(j, j) for j in joint_names]


def _stamp(seconds: float) -> tuple[int, int]:
    ns = int(round(seconds * 1e9))
    return ns // 10**9, ns % 10**9


def _g(x: float) -> str:
    return f"{x:.9g}" if x != 0 else "0.0"


def goal_yaml_text(motion, joint_names: Sequence[str], options: GoalOptions | None = None) -> str:
    """The text of ``trajectory_goal.yaml`` (module docstring), 9 significant digits."""
    options = options or GoalOptions()
    check_jerk(motion, joint_names, options.jerk_limits)
    t, q, v, vd = goal_points(motion, options.rate_hz)
    lines = ["trajectory:", "  joint_names: [" + ", ".join(_names(joint_names, options)) + "]", "  points:"]
    for k in range(len(t)):
        sec, nanosec = _stamp(t[k] + options.lead_in_s)
        lines += [
            "  - positions: [" + ", ".join(map(_g, q[k])) + "]",
            "    velocities: [" + ", ".join(map(_g, v[k])) + "]",
            "    accelerations: [" + ", ".join(map(_g, vd[k])) + "]",
            f"    time_from_start: {{sec: {sec}, nanosec: {nanosec}}}",
        ]
    return "\n".join(lines) + "\n"


def write_goal_yaml(path: str | Path, motion, joint_names: Sequence[str], options: GoalOptions | None = None) -> None:
    """Writes ``trajectory_goal.yaml``: ``ros2 action send_goal <controller>/follow_joint_trajectory
    control_msgs/action/FollowJointTrajectory "$(cat trajectory_goal.yaml)"``.

    Args:
        motion: the :class:`~pe_drake.excitation.ramp.RampedMotion` (at rest at both ends).
        joint_names: the URDF's excited joints, in the motion's order.

    Raises:
        NotWithinLimitsError, ConfigError: jerk above ``jerk_limits``; bad options or joints.
    """
    atomic_write_text(path, goal_yaml_text(motion, joint_names, options))


def write_goal_bag(path: str | Path, motion, joint_names: Sequence[str], options: GoalOptions | None = None) -> None:
    """Writes the goal's trajectory as one ``trajectory_msgs/msg/JointTrajectory`` on
    ``options.topic`` in an MCAP bag folder; raises as :func:`write_goal_yaml`, and ConfigError
    when ``path`` exists."""
    from rosbags.rosbag2 import StoragePlugin, Writer  # lazy: keeps `import pe_drake` light
    from rosbags.typesys import Stores, get_typestore

    options = options or GoalOptions()
    check_jerk(motion, joint_names, options.jerk_limits)
    t, q, v, vd = goal_points(motion, options.rate_hz)
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    Time, Duration = T["builtin_interfaces/msg/Time"], T["builtin_interfaces/msg/Duration"]
    Point = T["trajectory_msgs/msg/JointTrajectoryPoint"]
    points = [
        Point(positions=q[k], velocities=v[k], accelerations=vd[k], effort=np.empty(0),
              time_from_start=Duration(*_stamp(t[k] + options.lead_in_s)))
        for k in range(len(t))
    ]
    msg = T["trajectory_msgs/msg/JointTrajectory"](
        header=T["std_msgs/msg/Header"](stamp=Time(sec=0, nanosec=0), frame_id=""),
        joint_names=_names(joint_names, options), points=points)
    path = Path(path)
    if path.exists():
        raise ConfigError(f"bag '{path}' exists; remove it first")
    staging = Path(tempfile.mkdtemp(dir=path.parent if path.parent.exists() else None)) / path.name
    with Writer(staging, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection(options.topic, "trajectory_msgs/msg/JointTrajectory", typestore=ts)
        writer.write(conn, 1, ts.serialize_cdr(msg, "trajectory_msgs/msg/JointTrajectory"))
    shutil.move(str(staging), str(path))
    shutil.rmtree(staging.parent, ignore_errors=True)
