"""Joint names, signs and offsets of a log mapped onto the robot's (config ``data.joint_map``)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pe_drake.config import JointMapConfig
from pe_drake.exceptions import ConfigError


def robot_name(logged: str, joint_map: JointMapConfig) -> str:
    """The URDF joint name of a logged joint name: prefix stripped, then renamed."""
    name = logged
    if joint_map.strip_prefix and name.startswith(joint_map.strip_prefix):
        name = name[len(joint_map.strip_prefix):]
    return joint_map.rename.get(name, name)


def check_joint_map(joint_map: JointMapConfig, joints: Sequence[str]) -> None:
    """Refuses sign/offset entries for joints the robot does not excite, listing the valid ones."""
    for table in ("sign", "offset"):
        for joint in getattr(joint_map, table):
            if joint not in joints:
                raise ConfigError(f"data.joint_map.{table} names '{joint}', not one of the robot's excited "
                                  f"joints: {', '.join(joints)}")


def apply_signs(measurement, joint_map: JointMapConfig):
    """q → sign·q + offset, and v, vd, tau multiplied by the sign, per joint (a new Measurement)."""
    joints = measurement.joints
    check_joint_map(joint_map, joints)
    if not joint_map.sign and not joint_map.offset:
        return measurement
    sign = np.array([float(joint_map.sign.get(j, 1.0)) for j in joints])
    offset = np.array([float(joint_map.offset.get(j, 0.0)) for j in joints])
    changes = {"q": measurement.q * sign + offset}
    for field in ("v", "vd", "tau"):
        value = getattr(measurement, field)
        if value is not None:
            changes[field] = value * sign
    return measurement.replace(**changes)
