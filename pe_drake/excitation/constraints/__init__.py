"""Sampled trajectory constraints (one file per member) and their assembly from a config."""

from __future__ import annotations

from typing import TYPE_CHECKING

from pe_drake.exceptions import ConfigError
from pe_drake.excitation.constraints.balance import BalanceConstraint
from pe_drake.excitation.constraints.base import SampledConstraint, SampledValues
from pe_drake.excitation.constraints.collision import CollisionConstraint
from pe_drake.excitation.constraints.environment import EnvironmentConstraint, environment_from_config
from pe_drake.excitation.constraints.torque import TorqueConstraint

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

__all__ = ["EnvironmentConstraint", "SampledConstraint", "SampledValues", "constraints_from_config"]


def constraints_from_config(robot: Robot, excitation, environment=None) -> list[SampledConstraint]:
    """The sampled constraints an :class:`~pe_drake.config.ExcitationConfig` asks for.

    ``balance_radius > 0`` adds balance (Eq. 52), ``collision_margin >= 0`` self-collision
    (Eq. 53), ``torque_limits`` the a-priori model's torque limits, ``environment`` (an
    EnvironmentConfig) the floor and boxes. Each is checked at the nominal posture first.

    Raises:
        ConfigError: the robot lacks what a requested constraint needs (support points, capsules).
        InfeasibleError: the nominal posture already violates a constraint.
    """
    out: list[SampledConstraint] = []
    q0 = robot.nominal_posture()[None, :]
    if excitation.balance_radius > 0:
        balance = BalanceConstraint(robot, excitation.balance_radius)
        balance.check_posture(q0)
        out.append(balance)
    if excitation.collision_margin >= 0:
        if not robot.capsules:
            raise ConfigError(
                f"excitation.collision_margin is set but robot '{robot.name}' has no capsule file "
                "(robot.capsules)"
            )
        collision = CollisionConstraint(robot, excitation.collision_margin)
        collision.check_posture(q0)
        out.append(collision)
    if excitation.torque_limits:
        torque = TorqueConstraint(robot)
        torque.check_posture(q0)
        out.append(torque)
    if environment is not None:
        env = environment_from_config(robot, excitation, environment)
        if env is not None:
            env.check_posture(q0)
            out.append(env)
    return out
