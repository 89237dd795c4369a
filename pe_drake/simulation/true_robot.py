"""The robot a truth simulates in Drake (:class:`TrueRobot`, :func:`build_true_robot`): the
plant of the truth's :class:`~pe_drake.multibody.robot_model.RobotModel`
(:func:`~pe_drake.simulation.truth.make_truth`). The sign convention of the effects is in
:mod:`pe_drake.simulation.simulation`'s docstring."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import numpy as np

from pe_drake.multibody.model_plant import APPLIED_FORCE_PORT
from pe_drake.multibody.robot_model import RobotModel
from pe_drake.simulation.contact import without_contact

if TYPE_CHECKING:  # the types only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot
    from pe_drake.simulation.truth import Truth



@dataclasses.dataclass(frozen=True)
class TrueRobot:
    """The simulated robot: its model and its Drake plant.

    Attributes:
        robot: the :class:`~pe_drake.multibody.robot.Robot` (continuous plant) of ``model``
            (:meth:`~pe_drake.multibody.robot_model.RobotModel.plant`); with pre-sliding
            friction its diagram exports the input ``applied_generalized_force`` the controller drives.
        model: the true :class:`~pe_drake.multibody.robot_model.RobotModel` (the truth's).
        model_damping, model_friction: the model file's joint damping and ``<dynamics
            friction>``, (n,) (the model's friction where the truth does not set it).
    """

    robot: Any
    model: RobotModel
    model_damping: np.ndarray
    model_friction: np.ndarray

    def force_input(self):
        """(port, context) of the applied generalized force the controller sets: the
        plant's, or the diagram's exported input when the Dahl system adds its torque."""
        if self.robot.diagram.HasInputPort(APPLIED_FORCE_PORT):  # pre-sliding or prismatic Coulomb friction
            return self.robot.diagram.GetInputPort(APPLIED_FORCE_PORT), self.robot.context
        return self.robot.plant.get_applied_generalized_force_input_port(), self.robot.plant_context


def build_true_robot(robot: Robot, truth: Truth) -> TrueRobot:
    """The robot as built of a truth (``truth.model``) in Drake.

    Args:
        robot: the a-priori :class:`~pe_drake.multibody.robot.Robot` (its config is reloaded; bodies
            added by its own ``before_finalize`` are not carried over).
        truth: a :class:`~pe_drake.simulation.truth.Truth` of this robot.

    The plant applies no contact force (:mod:`pe_drake.simulation.contact`).
    """
    plant = truth.model.plant(robot)
    without_contact(plant)
    return TrueRobot(plant, truth.model, robot.joint_damping, robot.joint_friction)
