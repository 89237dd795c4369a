"""The a-priori model of the diagnosis: the robot's model file, or an earlier model
(``pe-drake diagnose --model``, read as ``validate`` reads it).

Only the nominal comparison (step 1), the payload search's Δφ_B and the augmented model's
closest standard parameters start from it; the fits are of the measured torque minus the
*model file's* friction, so an earlier model's friction is found again as effects.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from pe_drake.diagnosis.record import Segment, model_file_friction
from pe_drake.identification.drive_terms import drive_torque
from pe_drake.identification.estimators import IdentificationResult
from pe_drake.identification.reference_errors import Shortfall, shortfalls
from pe_drake.multibody.drive_columns import coulomb_columns
from pe_drake.multibody.inertia import validity_problems
from pe_drake.multibody.robot_model import RobotModel

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


def prior_parameters(robot: Robot, prior: IdentificationResult | RobotModel | None) -> np.ndarray:
    """The a-priori standard parameters, (10·nb,): the model file's, an earlier model's own, or
    for a base-parameter fit the ones closest to the model file's that give its base parameters."""
    if prior is None:
        return np.asarray(robot.phi_model, float)
    phi = _own_parameters(prior)
    return np.asarray(phi if phi is not None else prior.model.phi, float)


def _own_parameters(prior: IdentificationResult | RobotModel) -> np.ndarray | None:
    """An earlier model's own standard parameters (payload added); None for a base-parameter fit."""
    return prior.phi_total if isinstance(prior, RobotModel) else prior.phi


def prior_own_parameters(robot: Robot, prior: IdentificationResult | RobotModel | None) -> np.ndarray | None:
    """The standard parameters the augmented model's closest ones are sought from: an earlier
    model's own when physically valid, else None (the model file's: the physically consistent
    fit cannot start from an OLS/WLS fit's often invalid ones)."""
    phi = _own_parameters(prior) if prior is not None else None
    if phi is None or validity_problems(robot.body_names, phi):
        return None
    return np.asarray(phi, float)


def prior_drive_torque(robot: Robot, prior: IdentificationResult | RobotModel | None, seg: Segment) -> np.ndarray:
    """The a-priori model's joint torque beside Y φ on a segment, (S, n) [N·m]: the model file's
    joint friction, or an earlier model's drive terms as ``validate`` predicts them (Coulomb
    column parallel-filtered, through the model's transmission)."""
    if prior is None:  # the model file's friction, d·v + f_c·tanh(v/v_s) (issue 21)
        return model_file_friction(robot, seg)
    model, layout = (prior, prior.layout()) if isinstance(prior, RobotModel) else (prior.model, prior.drive_layout)
    if layout is None or not layout.count:
        return np.zeros_like(seg.v)
    rec = seg.record
    coulomb = rec.filtered(coulomb_columns(rec.friction_v, layout))[seg.idx]
    return drive_torque(model, layout, seg.v, seg.vd, coulomb)


def model_file_torque(robot: Robot, base, columns, seg: Segment) -> np.ndarray:
    """The model file's (CAD) torque along a segment, (S, n) [N·m]: Y φ_model from the base
    regressor ``columns`` of ``seg`` plus its friction (the reference to beat)."""
    return columns.product(range(base.count), base.base_values(robot.phi_model)) + model_file_friction(robot, seg)


def reference_shortfalls(robot: Robot, base, columns, seg: Segment, tau: np.ndarray) -> list[Shortfall]:
    """The joints whose torque ``tau`` along ``seg`` is worse than the model file's or than zero."""
    references = {"a_priori": model_file_torque(robot, base, columns, seg), "zero": np.zeros_like(tau)}
    return shortfalls(robot.joint_names, seg.tau, tau, references)
