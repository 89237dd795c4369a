"""Checks of a user's URDF text before Drake parses it, with messages that say what to change."""

from __future__ import annotations

import re
from pathlib import Path

from pe_drake.exceptions import ConfigError

#: URDF joint types pe_drake handles: 1-dof joints it can excite or lock, and welds.
SUPPORTED_JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed")

_JOINT = re.compile(r"<joint\b[^>]*>", re.S)
_ATTR = re.compile(r"""\b(name|type)\s*=\s*(["'])(.*?)\2""", re.S)


def check_joint_types(urdf_text: str, model_path: str | Path) -> None:
    """Refuses joints pe_drake cannot excite or lock (floating, planar, ball, ...).

    Raises:
        ConfigError: naming the joint, its type and what is supported.
    """
    # comments out, newlines kept (line numbers stay right): G1's URDF comments out a floating joint
    urdf_text = re.sub(r"<!--.*?-->", lambda m: "\n" * m.group(0).count("\n"), urdf_text, flags=re.S)
    for match in _JOINT.finditer(urdf_text):
        attrs = {m.group(1): m.group(3) for m in _ATTR.finditer(match.group(0))}
        kind = attrs.get("type", "")
        if kind and kind not in SUPPORTED_JOINT_TYPES:
            line = urdf_text.count("\n", 0, match.start()) + 1
            hint = (
                "For a floating base, delete that joint: the root link is then welded to the world at "
                "robot.base_position / base_quaternion_wxyz (as G1's pelvis is)"
                if kind == "floating"
                else "Replace it by 1-dof joints, or make it fixed to lock it"
            )
            raise ConfigError(
                f"'{Path(model_path).name}', line {line}: joint '{attrs.get('name', '?')}' has type '{kind}'; "
                f"pe_drake supports {', '.join(SUPPORTED_JOINT_TYPES)} joints (1-dof joints are excited or "
                f"locked, fixed ones welded). {hint}"
            )
