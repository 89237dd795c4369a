"""Checks of a user's URDF text before Drake parses it, with messages that say what to change,
and the joint attributes Drake's parser does not keep (effort limits, ``<dynamics friction>``)."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from pe_drake.exceptions import ConfigError

#: URDF joint types pe_drake handles: 1-dof joints it can excite or lock, and welds.
SUPPORTED_JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed")

_JOINT = re.compile(r"<joint\b[^>]*>", re.S)
_ATTR = re.compile(r"""\b(name|type)\s*=\s*(["'])(.*?)\2""", re.S)
_DOCTYPE = re.compile(r"<!DOCTYPE\b(?:[^\[>]*\[.*?\]\s*>|[^>]*>)", re.S)
#: An entity reference other than XML's five and numeric ones: Drake keeps it as text.
_ENTITY_REF = re.compile(r"&(?!(?:amp|lt|gt|quot|apos|#\d+|#x[0-9a-fA-F]+);)")


def urdf_tree(text: str) -> ET.Element:
    """The URDF's element tree as Drake reads it: the ``<!DOCTYPE>`` ignored and its entities
    not expanded (``effort="&foo;"`` is the text '&foo;').

    Python's parser would expand a DOCTYPE's entities and fail on external or undefined ones
    where Drake reads the file. Raises ``ParseError`` for text that is not XML.
    """
    text = _DOCTYPE.sub(lambda m: "\n" * m.group(0).count("\n"), text)  # newlines kept: line numbers stay
    return ET.fromstring(_ENTITY_REF.sub("&amp;", text))


def has_entities(text: str) -> bool:
    """Whether the text has a ``<!DOCTYPE>`` and uses an entity of its own (``&foo;``)."""
    return bool(_DOCTYPE.search(text)) and bool(_ENTITY_REF.search(text))


def check_joint_types(urdf_text: str, model_path: str | Path) -> None:
    """Refuses (ConfigError) joints pe_drake cannot excite or lock (floating, planar, ball, ...)."""
    # comments out, newlines kept (line numbers stay right): G1's URDF comments out a floating joint
    urdf_text = re.sub(r"<!--.*?-->", lambda m: "\n" * m.group(0).count("\n"), urdf_text, flags=re.S)
    for match in _JOINT.finditer(urdf_text):
        attrs = {m.group(1): m.group(3) for m in _ATTR.finditer(match.group(0))}
        kind = attrs.get("type", "")
        if kind and kind not in SUPPORTED_JOINT_TYPES:
            line = urdf_text.count("\n", 0, match.start()) + 1
            hint = ("For a floating base, delete that joint: the root link is then welded to the "
                    "world at robot.base_position / base_quaternion_wxyz (as G1's pelvis is)"
                    if kind == "floating" else
                    "Replace it by 1-dof joints, or make it fixed to lock it")
            raise ConfigError(
                f"'{Path(model_path).name}', line {line}: joint '{attrs.get('name', '?')}' has "
                f"type '{kind}'; pe_drake supports {', '.join(SUPPORTED_JOINT_TYPES)} joints "
                f"(1-dof joints are excited or locked, fixed ones welded). {hint}")


def urdf_joint_efforts(path: Path) -> dict[str, float]:
    """{joint: effort} from a URDF's <limit effort=...> (Drake keeps them only with actuators)."""
    if path.suffix.lower() != ".urdf":
        return {}
    out = {}
    try:
        root = urdf_tree(path.read_text())  # as Drake reads it: a DOCTYPE made ET.parse fail
    except (ET.ParseError, OSError, UnicodeDecodeError):
        return {}
    for joint in root.iter("joint"):
        limit = joint.find("limit")
        try:
            effort = float(limit.get("effort")) if limit is not None else 0.0
        except (TypeError, ValueError):  # no effort, or text Drake refuses itself
            continue
        if effort > 0:
            out[joint.get("name")] = effort
    return out


def urdf_joint_dynamics(path: Path, attribute: str) -> dict[str, float]:
    """{joint: value} of a URDF's ``<dynamics attribute=...>`` ({} for another format, bad text)."""
    if path.suffix.lower() != ".urdf":
        return {}
    try:
        root = urdf_tree(path.read_text())
    except (ET.ParseError, OSError, UnicodeDecodeError):
        return {}
    out = {}
    for joint in root.findall("joint"):  # not a <transmission>'s <joint>, which has no dynamics
        dynamics = joint.find("dynamics")
        try:
            value = float(dynamics.get(attribute))
        except (AttributeError, TypeError, ValueError):  # no <dynamics>, no attribute, bad text
            continue
        if np.isfinite(value):
            out[joint.get("name")] = value
    return out
