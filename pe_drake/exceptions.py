"""Exceptions raised by pe_drake: every error a user can cause derives from
:class:`PeDrakeError`; subclasses carry the offending values as attributes.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Any

#: Longest value a message shows whole.
MAX_SHOWN = 200
#: A run of this many characters without a space is a value, not prose: cut in any message.
_LONG_RUN = re.compile(r"\S{%d,}" % (2 * MAX_SHOWN + 1))


def shorten(value: Any, limit: int = MAX_SHOWN) -> str:
    """``str(value)``, cut after ``limit`` characters with "… (N characters)" (for messages)."""
    text = str(value)
    if len(text) <= limit:
        return text
    return f"{text[:limit]}… ({len(text)} characters)"


class PeDrakeError(Exception):
    """Root of every pe_drake error; a long unbroken run in its message (a value echoed by
    Drake's own text) is cut by :func:`shorten`."""

    def __init__(self, *args: Any):
        super().__init__(*(_LONG_RUN.sub(lambda m: shorten(m.group(0)), a) if isinstance(a, str) else a
                           for a in args))


class ConfigError(PeDrakeError, ValueError):
    """A configuration value is missing, malformed or out of range."""


class UnknownNameError(ConfigError):
    """A robot, joint, link or option name (of ``kind``) is not one of the valid ``choices``."""

    def __init__(self, kind: str, name: str, choices: Sequence[str], where: str = ""):
        self.kind, self.name, self.choices = kind, name, tuple(choices)
        place = f" in {where}" if where else ""
        shown = ", ".join(self.choices[:60]) + (" ..." if len(self.choices) > 60 else "")
        super().__init__(f"unknown {kind} '{shorten(name)}'{place}; valid {kind}s: {shown}")


class NotWithinLimitsError(ConfigError):
    """A value lies outside a joint's limits [lower, upper]."""

    def __init__(self, joint: str, value: float, lower: float, upper: float, what: str = "position"):
        self.joint, self.value, self.lower, self.upper = joint, value, lower, upper
        super().__init__(f"joint '{joint}': {what} {value:.6g} is outside its limits "
                         f"[{lower:.6g}, {upper:.6g}]")


class InfeasibleError(PeDrakeError):
    """The limits or constraints leave no feasible trajectory."""


class DataError(PeDrakeError, ValueError):
    """Measured data is malformed: names the file, column and row where it can."""

    def __init__(self, message: str, *, file: str = "", column: str = "", row: int | None = None):
        self.file, self.column, self.row = file, column, row
        where = [f"file '{file}'"] if file else []
        where += [f"column '{column}'"] if column else []
        where += [f"row {row}"] if row is not None else []
        prefix = (", ".join(where) + ": ") if where else ""
        super().__init__(prefix + message)


class JointMismatchError(DataError, ConfigError):
    """A file's joints (``joints``) are not the robot's (``robot_joints``): bad data or the wrong
    --robot/--config. ``missing``: the robot's the file lacks; ``extra``: the file's the robot lacks."""

    def __init__(self, joints: Sequence[str], robot_name: str, robot_joints: Sequence[str], *, file: str = "",
                 what: str = "the data"):
        self.joints, self.robot_joints = tuple(joints), tuple(robot_joints)
        self.missing = tuple(j for j in self.robot_joints if j not in self.joints)
        self.extra = tuple(j for j in self.joints if j not in self.robot_joints)
        detail = "; ".join(f"{label}: {', '.join(names)}" for label, names in (
            ("missing", self.missing), ("not the robot's", self.extra)) if names) or "the same joints in another order"
        # "robot 'panda': its excited joints", not "robot 'panda''s excited joints" (a quote, then 's)
        super().__init__(f"{what}'s joints {', '.join(self.joints)} differ from robot '{robot_name}': its excited "
                         f"joints are {', '.join(self.robot_joints)} ({detail}); pass the --robot/--config they were "
                         "recorded or optimized with", file=file)


def check_joints(robot, joints: Sequence[str], *, file: str = "", what: str = "the data",
                 any_order: bool = False) -> None:
    """The package's one check that a file's joints are ``robot``'s excited joints (in order,
    or in ``any_order``); raises :class:`JointMismatchError` if not."""
    joints = tuple(str(j) for j in joints)
    expected = tuple(robot.joint_names)
    if joints != expected and not (any_order and sorted(joints) == sorted(expected) and len(set(joints)) == len(joints)):
        raise JointMismatchError(joints, robot.name, expected, file=str(file), what=what)


class NoSolutionFound(PeDrakeError):
    """The solver found no solution that satisfies every constraint; ``result`` (the
    :class:`~pe_drake.excitation.solve.ExcitationResult`) is kept for inspection."""

    def __init__(self, message: str, result: Any = None):
        self.result = result
        super().__init__(message)


class MissingDependencyError(PeDrakeError, ImportError):
    """An optional package is needed for this feature."""

    def __init__(self, package: str, feature: str):
        super().__init__(f"{feature} needs the package '{package}': pip install {package}")


class OutputWriteError(PeDrakeError, OSError):
    """The outputs could not be written (a full disk, a quota): nothing was half-written, and
    a solved motion was saved in the file :attr:`rescued` (or nowhere: None)."""

    def __init__(self, message: str, rescued: str | None = None):
        self.rescued = rescued
        super().__init__(message)
