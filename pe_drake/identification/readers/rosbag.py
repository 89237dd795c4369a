"""ROS 2 bags (``.db3``/``.mcap``, ``sensor_msgs/msg/JointState``) read with ``rosbags``.

Joints are matched by name, never by index: every message carries its own ``name`` order,
and a gripper may publish its own joints on the same topic. Time is ``header.stamp``; a bag
whose stamps are zero falls back to the receive time (with a note). Messages that do not hold
every excited joint (a gripper's, a partial one) and repeated stamps are dropped, with notes.
Empty ``velocity``/``effort`` arrays are common: velocities then come from differentiation;
efforts are required (``torque`` [N·m] or ``current`` [A] with ``robot.drive_gains``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from pe_drake.config import JointMapConfig
from pe_drake.exceptions import DataError
from pe_drake.limits import input_file_problem
from pe_drake.identification.measurements import Measurement
from pe_drake.identification.readers.bag_limits import check_compressed_bag, check_mcap_chunks, check_message_size
from pe_drake.identification.readers.currents import torque_from_current
from pe_drake.identification.readers.joint_map import robot_name

JOINT_STATE = "sensor_msgs/msg/JointState"
BAG_SUFFIXES = (".db3", ".mcap")


def is_bag(path: str | Path) -> bool:
    """A bag folder (with metadata.yaml) or a ``.db3``/``.mcap`` file."""
    path = Path(path)
    return (path.is_dir() and (path / "metadata.yaml").is_file()) or path.suffix in BAG_SUFFIXES


def _pick_topic(connections, topic: str, file: str) -> list:
    states = sorted({c.topic for c in connections if c.msgtype == JOINT_STATE})
    listing = ", ".join(f"{c.topic} ({c.msgtype})" for c in connections) or "none"
    if topic:
        chosen = [c for c in connections if c.topic == topic]
        if not chosen or chosen[0].msgtype != JOINT_STATE:
            raise DataError(f"topic '{topic}' is not a {JOINT_STATE} topic of the bag; its topics: {listing}",
                            file=file)
        return chosen
    if not states:
        raise DataError(f"the bag has no {JOINT_STATE} topic; its topics: {listing}", file=file)
    if len(states) > 1:
        raise DataError(f"the bag has {len(states)} {JOINT_STATE} topics ({', '.join(states)}): pick one with "
                        "--topic (config data.topic)", file=file)
    return [c for c in connections if c.topic == states[0]]


def _check_unique_names(names: list[str], mine: list[tuple[int, int]], index: int, topic: str, file: str) -> None:
    """Refuses a message naming an excited joint twice: which copy is the joint's is unknown."""
    if len({c for _, c in mine}) < len(mine):
        twice = sorted({names[i] for i, _ in mine if sum(names[k] == names[i] for k, _ in mine) > 1})
        raise DataError(f"message {index} on '{topic}' names joint(s) {', '.join(repr(n) for n in twice)} more than "
                        f"once (names: {', '.join(names)}); each joint must appear once per message", file=file)


def _collect(reader, connections, joints: Sequence[str], joint_map: JointMapConfig, file: str):
    """Per complete message: stamp [ns], receive time [ns], q, v (or None), effort (or None)."""
    index = {j: k for k, j in enumerate(joints)}
    rows, seen, partial, other = [], set(), 0, 0
    for count, (conn, received, raw) in enumerate(reader.messages(connections=connections)):
        check_message_size(raw, count, conn.topic, file)
        msg = reader.deserialize(raw, conn.msgtype)
        names = [robot_name(n, joint_map) for n in msg.name]
        seen.update(msg.name)
        cols = [index.get(n, -1) for n in names]
        mine = [(i, c) for i, c in enumerate(cols) if c >= 0]
        _check_unique_names(names, mine, count, conn.topic, file)
        if len(mine) < len(joints) or len(msg.position) < len(names):
            partial += bool(mine)
            other += not mine
            continue
        src = np.array([i for i, _ in mine])
        dst = np.array([c for _, c in mine])
        values = []
        for field in ("position", "velocity", "effort"):
            array = np.asarray(getattr(msg, field), float)
            if len(array) == len(names):
                out = np.full(len(joints), np.nan)  # every column is written: mine covers each joint once
                out[dst] = array[src]
                values.append(out)
            else:
                values.append(None)
        stamp = int(msg.header.stamp.sec) * 10**9 + int(msg.header.stamp.nanosec)
        rows.append((stamp, int(received), *values))
    return rows, seen, partial, other


def read_joint_state_bag(path: str | Path, joints: Sequence[str], *, topic: str = "",
                         effort: str = "torque", joint_map: JointMapConfig | None = None,
                         drive_gains: Mapping[str, float] | None = None) -> Measurement:
    """Reads the JointState messages of a bag (module docstring) as a raw :class:`Measurement`.

    Args:
        path: a bag folder (``metadata.yaml``; split bags are read in order) or its ``.db3`` /
            ``.mcap`` file.
        topic: the JointState topic; empty: the only one.
        effort: ``torque`` [N·m] or ``current`` [A].
        joint_map: logged names → URDF names (signs and offsets are applied by the caller).
        drive_gains: {joint: k [N·m/A]} for ``effort="current"``.

    Returns:
        t [s] from the first kept sample, q, tau, v (None unless every kept message has it).

    Raises:
        DataError: not a bag, no/ambiguous JointState topic, a joint never published (the
            names seen are listed), no efforts, too few messages, currents without gains.
    """
    from rosbags.highlevel import AnyReader  # lazy: keeps `import pe_drake` light
    from rosbags.typesys import Stores, get_typestore

    path, file = Path(path), str(path)
    joint_map = joint_map or JointMapConfig()
    problem = input_file_problem(path)
    if problem and not path.is_dir():  # a ROS 2 bag is a folder
        raise DataError(f"the bag {problem}", file=file)
    check_mcap_chunks(path)  # before rosbags inflates a chunk whole
    if path.is_dir() and (path / "metadata.yaml").is_file():
        check_compressed_bag(path)  # and a compressed message or storage file
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            connections = _pick_topic(reader.connections, topic, file)
            rows, seen, partial, other = _collect(reader, connections, joints, joint_map, file)
    except DataError:
        raise
    except Exception as err:  # rosbags raises its own error types for corrupt or foreign files
        raise DataError(f"cannot read the bag: {err}", file=file) from err
    if not rows:
        missing = [j for j in joints if j not in {robot_name(n, joint_map) for n in seen}]
        raise DataError(
            f"no message holds every excited joint; never published: {', '.join(missing)}; names on the topic: "
            f"{', '.join(sorted(seen)) or 'none'} (map them with data.joint_map: strip_prefix, rename)", file=file)
    return _to_measurement(rows, joints, effort, drive_gains or {}, file, partial, other)


def _check_finite(field: str, values: np.ndarray | None, joints, stamps: np.ndarray, file: str) -> None:
    """Refuses a NaN or infinite value, naming the message's stamp and the joint."""
    if values is None or np.isfinite(values).all():
        return
    row, col = np.argwhere(~np.isfinite(values))[0]
    count = int((~np.isfinite(values)).sum())
    raise DataError(f"{field} of joint '{joints[col]}' is {values[row, col]} in the message stamped "
                    f"{stamps[row] * 1e-9:.9f} s (message {row + 1} of {len(values)} in time order; {count} such "
                    "value(s)): the JointState holds no number there", file=file)


def _to_measurement(rows, joints, effort: str, gains, file: str, partial: int, other: int) -> Measurement:
    notes = []
    if partial or other:
        notes.append(f"{partial + other} message(s) without every excited joint dropped "
                     f"({other} with none of them, e.g. a gripper's; {partial} partial)")
    with_effort = [r for r in rows if r[4] is not None]
    if not with_effort:
        raise DataError("the JointState messages have empty effort arrays: no torques to identify from", file=file)
    if len(with_effort) < len(rows):
        notes.append(f"{len(rows) - len(with_effort)} message(s) with an empty effort array dropped")
    rows = with_effort
    stamps = np.array([r[0] for r in rows], np.int64)
    if np.any(stamps == 0):
        stamps = np.array([r[1] for r in rows], np.int64)
        notes.append("header.stamp is zero: the bag's receive times are used instead")
    order = np.argsort(stamps, kind="stable")
    stamps = stamps[order]
    keep = np.concatenate([[True], np.diff(stamps) > 0])
    if not keep.all():
        notes.append(f"{int((~keep).sum())} message(s) with a repeated stamp dropped (the first is kept)")
    order = order[keep]
    if len(order) < 30:
        raise DataError(f"only {len(order)} usable JointState messages; at least 30 are needed", file=file)
    q = np.array([rows[k][2] for k in order])
    tau = np.array([rows[k][4] for k in order])
    v = np.array([rows[k][3] for k in order]) if all(rows[k][3] is not None for k in order) else None
    for field, values in (("position", q), ("effort", tau), ("velocity", v)):
        _check_finite(field, values, joints, stamps[keep], file)
    if effort == "current":
        tau = torque_from_current(tau, joints, gains, file, "effort read as motor current, --effort current")
        notes.append("effort read as motor current [A] and multiplied by robot.drive_gains")
    t = (stamps[keep] - stamps[keep][0]) * 1e-9
    return Measurement(t, q, tau, v, None, tuple(joints), file, notes=tuple(notes))
