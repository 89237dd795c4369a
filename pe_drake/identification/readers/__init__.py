"""Measured logs of every format read as one :class:`~pe_drake.identification.measurements.Measurement`.

:func:`read_log` dispatches by format (config ``data.format``, ``auto`` by default): ``rosbag``
(a ROS 2 bag folder, ``.db3`` or ``.mcap``), ``rtde`` (a UR RTDE CSV, recognised by its
``timestamp``/``actual_q_0`` columns), ``columns`` (any CSV through ``data.columns``) or
``pe_drake`` (pe_drake's own CSV, with ``current.<joint>`` columns instead of ``tau.<joint>``, or
motor-side). Then ``data.joint_map``'s signs and offsets are applied.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

from pe_drake.config import DATA_FORMATS, DataConfig
from pe_drake.exceptions import ConfigError
from pe_drake.identification.measurements import Measurement, read_measurement_csv
from pe_drake.identification.readers.columns import identity_columns, is_rtde, read_header, read_mapped_csv, rtde_columns
from pe_drake.identification.readers.joint_map import apply_signs
from pe_drake.identification.readers.motor_side import is_motor_side, read_motor_side_csv
from pe_drake.identification.readers.rosbag import is_bag, read_joint_state_bag
from pe_drake.multibody.transmission import robot_transmission

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

__all__ = ["detect_format", "read_log"]


def detect_format(path: str | Path, options: DataConfig) -> str:
    """The format of ``path``: ``options.format`` unless ``auto`` (module docstring)."""
    if options.format != "auto":
        return options.format
    if is_bag(path):
        return "rosbag"
    if options.columns:
        return "columns"
    columns, _ = read_header(path)
    return "rtde" if is_rtde(columns) else "pe_drake"


def read_log(path: str | Path, robot: Robot, options: DataConfig | None = None, **changes) -> Measurement:
    """Reads a measured log of ``robot``'s excited joints, whatever its format, as a raw
    :class:`Measurement` (joints in the robot's order).

    Args:
        options: how to read it (the config's ``data``).
        **changes: fields of ``options`` to override (``topic=``, ``format=``, ``effort=``).

    Raises:
        DataError: as the format's reader, naming the file, column/topic and row.
        ConfigError: an unknown format.
    """
    options = dataclasses.replace(options or DataConfig(), **{k: v for k, v in changes.items() if v is not None})
    joints = tuple(robot.joint_names)
    gains = dict(getattr(getattr(robot, "config", None), "drive_gains", {}) or {})
    fmt = detect_format(path, options)
    if fmt == "rosbag":
        m = read_joint_state_bag(path, joints, topic=options.topic, effort=options.effort,
                                 joint_map=options.joint_map, drive_gains=gains)
    elif fmt == "rtde":
        columns, _ = read_header(path)
        m = read_mapped_csv(path, joints, rtde_columns(joints, columns, str(path)), gains)
    elif fmt == "columns":
        m = read_mapped_csv(path, joints, options.columns, gains)
    elif fmt == "pe_drake":
        columns, _ = read_header(path)
        if is_motor_side(columns):
            m = read_motor_side_csv(path, joints, columns, gains, robot_transmission(robot))
        elif any(c.startswith("current.") for c in columns):
            m = read_mapped_csv(path, joints, identity_columns(columns, joints), gains)
        else:
            m = read_measurement_csv(path, joints, min_rows=30)
    else:
        raise ConfigError(f"data format '{fmt}' is not one of {', '.join(DATA_FORMATS)}")
    return apply_signs(m, options.joint_map)
