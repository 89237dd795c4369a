"""A nominal posture that clears the floor and the robot itself, for a model without one.

The optimizer starts from the nominal posture (q0 of Eq. 50), and the constraints refuse a q0
that violates them. A model without a config starts mid-range, which for a UR arm (limits ±2π)
puts the wrist below the base plane, so :func:`choose_nominal_posture` tries, first match wins:

1. the mid-range posture;
2. one joint moved by ±π/4, ±π/2, ±3π/4 (base side first, within the limits);
3. two consecutive joints moved by ±π/2 each.

A candidate is taken when every environment row (floor, boxes) and every self-collision pair
keeps its margin (``max(excitation.collision_margin, 0)``).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.exceptions import ConfigError, InfeasibleError
from pe_drake.excitation.constraints.collision import CollisionConstraint
from pe_drake.excitation.constraints.environment import environment_from_config

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

_OFFSETS = (-math.pi / 4, math.pi / 4, -math.pi / 2, math.pi / 2, -3 * math.pi / 4, 3 * math.pi / 4)


def candidate_postures(robot: Robot) -> Iterator[np.ndarray]:
    """The candidates of the module docstring, each within the joint limits, shape (n,)."""
    lo, hi = robot.limits.q_lower, robot.limits.q_upper
    q0 = robot.nominal_posture()
    yield q0
    for k, offset in itertools.product(range(robot.n), _OFFSETS):
        q = q0.copy()
        q[k] += offset
        if lo[k] <= q[k] <= hi[k]:
            yield q
    for k, (a, b) in itertools.product(range(robot.n - 1), itertools.product((-1, 1), repeat=2)):
        q = q0.copy()
        q[k] += a * math.pi / 2
        q[k + 1] += b * math.pi / 2
        if lo[k] <= q[k] <= hi[k] and lo[k + 1] <= q[k + 1] <= hi[k + 1]:
            yield q


def choose_nominal_posture(robot: Robot, excitation, environment) -> str | None:
    """Sets ``robot.config.nominal_positions`` (in place, so that worker processes rebuilding
    the robot start there too) to the first candidate posture that clears the floor, the boxes
    and self-collision, when the config gives none and the mid-range one does not clear.

    Returns:
        A note saying which posture was chosen, or None when nothing was changed.

    Raises:
        InfeasibleError: no candidate clears (the message names the joints to set).
    """
    if robot.config.nominal_positions:
        return None  # the user's posture: the constraints check it and say what is wrong
    try:
        env = environment_from_config(robot, excitation, environment) if environment is not None else None
    except ConfigError:
        env = None  # no capsules: nothing to clear (the constraint assembly reports it)
    checks = [] if env is None else [env]
    if excitation.collision_margin >= 0 and robot.capsules:
        checks.append(CollisionConstraint(robot, excitation.collision_margin))
    if not checks:
        return None
    tried, floor_blocks = 0, env is not None
    for q in candidate_postures(robot):
        tried += 1
        floor_blocks = floor_blocks and not _clears(env, q)
        if all(_clears(c, q) for c in checks):
            if tried == 1:
                return None
            robot.config.nominal_positions = {name: float(v) for name, v in zip(robot.joint_names, q)}
            mid = 0.5 * (robot.limits.q_lower + robot.limits.q_upper)
            moved = [f"{n} = {v:.4g}" for n, v, v0 in zip(robot.joint_names, q, mid) if v != v0]
            return (
                f"the mid-range posture does not clear the floor/obstacles/self-collision margin; starting from "
                f"{', '.join(moved)} (others mid-range); set robot.nominal_positions to choose"
            )
    if floor_blocks and environment is not None and environment.floor:
        # a robot that hangs below its base (Drake's Acrobot) cannot clear a floor at any posture:
        # moving joints will not help, the floor setting will (issue 37)
        floor = ("the base's support plane" if environment.floor_height is None
                 else f"environment.floor_height {environment.floor_height:g} m")
        raise InfeasibleError(
            f"the floor blocks every one of {tried} candidate postures (mid-range, one or two joints "
            f"moved): part of the robot is below the floor ({floor}) whatever its joints do, as for a "
            "robot hanging below its base; raise the base with robot.base_position (world [m]) and set "
            "environment.floor_height (world z [m]) below its lowest point (without floor_height the floor "
            "stays at the base's plane wherever the base is), or set environment: {floor: false}")
    raise InfeasibleError(
        f"none of {tried} candidate postures (mid-range, one or two joints moved) clears the floor, the boxes and "
        f"the self-collision margin; set robot.nominal_positions for the joints {', '.join(robot.joint_names)} "
        "(e.g. the upper arm raised), or move the obstacles"
    )


def _clears(constraint, q: np.ndarray) -> bool:
    try:
        constraint.check_posture(q[None, :])
    except InfeasibleError:
        return False
    return True
