"""The robot a truth simulates (:func:`true_model`): a :class:`~pe_drake.multibody.robot_model.RobotModel`
(the a-priori robot with its model file's friction, or an identified model) with the truth's
effects, its bodies' parameters perturbed and the payload welded, and that model in Drake
(:class:`TrueRobot`, :func:`build_true_robot`). The sign convention of the effects is in
:mod:`pe_drake.simulation.simulation`'s docstring."""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from pe_drake.exceptions import ConfigError
from pe_drake.multibody.inertia import inertia_matrix, perturb_inertias
from pe_drake.multibody.model_plant import APPLIED_FORCE_PORT
from pe_drake.multibody.payload import PayloadInertia
from pe_drake.multibody.robot_model import FILE_KEYS, RobotModel
from pe_drake.multibody.transmission import robot_transmission
from pe_drake.simulation.contact import without_contact
from pe_drake.simulation.truth import ALL_JOINTS, Truth, per_joint_values, validate_truth

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot



@dataclasses.dataclass(frozen=True)
class TrueRobot:
    """The simulated robot: its model and its Drake plant.

    Attributes:
        robot: the :class:`~pe_drake.multibody.robot.Robot` (continuous plant) of ``model``
            (:meth:`~pe_drake.multibody.robot_model.RobotModel.plant`); with pre-sliding
            friction its diagram exports the input ``applied_generalized_force`` the controller drives.
        model: the true :class:`~pe_drake.multibody.robot_model.RobotModel` (:func:`true_model`).
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


def true_model(robot: Robot, truth: Truth, model: RobotModel | None = None) -> RobotModel:
    """The robot a truth simulates: ``model`` (default: the a-priori robot with its model file's
    friction) with the truth's effects, its bodies' parameters perturbed and the payload welded.

    The truth's friction replaces the model file's on the joints it sets (module docstring);
    on an identified ``model`` (``simulate --model``) the truth's per-joint effects add to the
    model's, its delay too. With a transmission (the model's, or the robot config's
    ``robot.transmission``) the truth's viscous, coulomb, armature and torque_offset are per
    motor (named by its joint) and act through R, and the model file's joint friction is not
    simulated (as ``identify`` fits the motors' terms as the drive's whole friction).

    Raises:
        ConfigError, UnknownNameError: from :func:`validate_truth`; a truth with Coulomb friction of
            another v_s than the model's, or pre-sliding friction where the model has its own.
    """
    validate_truth(truth, robot)
    joints, e = robot.joint_names, truth.effects
    # the truth's tables are named as the model file's (RobotModel.FILE_KEYS)
    tables = {t: per_joint_values(getattr(e, field), joints) for t, field in FILE_KEYS.items()}
    fc, sigma0 = per_joint_values(e.presliding_friction, joints), per_joint_values(e.presliding_stiffness, joints)
    transmission = robot_transmission(robot) if model is None else model.transmission
    transmission = None if transmission is None or transmission.identity else transmission
    if model is None and transmission is not None:  # per motor: the model file's joint friction is not the motors'
        phi, v_s, delay = robot.phi_model, float(e.coulomb_velocity_scale), float(e.torque_delay)
    elif model is None:  # the truth's friction where it sets a joint (by name or all), else the model file's
        tables["viscous"], tables["coulomb"] = (
            per_joint_values(t, joints) if ALL_JOINTS in t else np.array([float(t.get(j, m)) for j, m in zip(joints, x)])
            for t, x in ((e.viscous, robot.joint_damping), (e.coulomb, robot.joint_friction)))
        phi, v_s, delay = robot.phi_model, float(e.coulomb_velocity_scale), float(e.torque_delay)
    else:
        _check_model_truth(model, tables["coulomb"], fc, e.coulomb_velocity_scale)
        tables = {t: x + model.term(t) for t, x in tables.items()}
        if np.any(model.presliding > 0):
            fc, sigma0 = model.presliding, model.presliding_stiffness
        phi, v_s, delay = model.phi_total, model.velocity_scale, e.torque_delay + model.torque_delay
    rng = np.random.default_rng(np.random.SeedSequence(truth.seed).spawn(2)[0])
    phi = perturb_inertias(np.asarray(phi, float), truth.inertia_perturbation, rng, body_names=robot.body_names)
    p = e.payload
    payload = PayloadInertia(float(p.mass), np.asarray(p.com, float), inertia_matrix(p.inertia)) if p.link else None
    return RobotModel(joints, robot.body_names, phi, tables, velocity_scale=v_s, payload=payload,
                      payload_link=p.link, torque_delay=float(delay), presliding=fc, presliding_stiffness=sigma0,
                      notes=model.notes if model is not None else (), transmission=transmission)


def _check_model_truth(model: RobotModel, coulomb: np.ndarray, presliding: np.ndarray, v_s: float) -> None:
    """One tanh(v/v_s) and one Dahl model per joint are simulated (:func:`true_model`)."""
    if np.any(coulomb > 0) and not math.isclose(v_s, model.velocity_scale, rel_tol=1e-12):
        raise ConfigError(f"effects.coulomb_velocity_scale {v_s:g} rad/s of the truth file differs from the model's "
                          f"{model.velocity_scale:g} rad/s: one tanh(v/v_s) is simulated; remove the truth's coulomb "
                          "or set the model's v_s")
    if np.any(model.presliding > 0) and np.any(presliding > 0):
        raise ConfigError("both the truth file and the model have pre-sliding friction: one Dahl model per joint is "
                          "simulated; remove the truth's presliding_*")


def build_true_robot(robot: Robot, truth: Truth, model: RobotModel | None = None) -> TrueRobot:
    """The true robot of a truth (:func:`true_model`) in Drake.

    Args:
        robot: the a-priori :class:`~pe_drake.multibody.robot.Robot` (its config is reloaded; bodies
            added by its own ``before_finalize`` are not carried over).
        truth: a :class:`Truth`.
        model: the robot the truth perturbs (``simulate --model``); default the a-priori one.

    The plant applies no contact force (:mod:`pe_drake.simulation.contact`).
    """
    true = true_model(robot, truth, model)
    plant = true.plant(robot)
    without_contact(plant)
    return TrueRobot(plant, true, robot.joint_damping, robot.joint_friction)
