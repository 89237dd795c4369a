"""The a-priori model of the diagnosis: the robot's model file, or an earlier model
(``pe-drake diagnose --model``: identified.json of ``identify`` or augmented_model.json of an
earlier diagnosis, read by :func:`~pe_drake.identification.identified_file.load_identified` as
``validate`` reads them).

Only the nominal comparison (step 1), the payload search's Δφ_B and the augmented model's
closest standard parameters start from it. The rigid-body and effect fits are of the measured
torque minus the *model file's* friction, with or without an earlier model
(:func:`~pe_drake.diagnosis.record.model_file_friction`): a friction named is what the model file lacks, so an earlier
model's friction is found again as effects when the data show it.
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
    """The a-priori standard parameters, (10·nb,): the model file's, or an earlier model's own
    (physical fits, augmented_model.json) or, for a base-parameter fit, the ones closest to the
    model file's that give its base parameters."""
    if prior is None:
        return np.asarray(robot.phi_model, float)
    phi = _own_parameters(prior)
    return np.asarray(phi if phi is not None else prior.model.phi, float)


def _own_parameters(prior: IdentificationResult | RobotModel) -> np.ndarray | None:
    """The standard parameters an earlier model holds as its own: a RobotModel's (its payload added),
    a physical fit's; None for a base-parameter fit."""
    return prior.phi_total if isinstance(prior, RobotModel) else prior.phi


def prior_own_parameters(robot: Robot, prior: IdentificationResult | RobotModel | None) -> np.ndarray | None:
    """The standard parameters the augmented model's closest ones are sought from: an earlier
    model's own when physically valid (a physical fit, augmented_model.json), else None (the
    model file's). An OLS/WLS fit's standard parameters (``IdentificationResult.model.phi``: the model
    file's null-space part) are often not physically valid, and the physically consistent fit
    of the augmented model cannot start from them (Clarabel fails)."""
    phi = _own_parameters(prior) if prior is not None else None
    if phi is None or validity_problems(robot.body_names, phi):
        return None
    return np.asarray(phi, float)


def prior_drive_torque(robot: Robot, prior: IdentificationResult | RobotModel | None, seg: Segment) -> np.ndarray:
    """The a-priori model's joint torque beside Y φ on a segment, (S, n) [N·m]: the model file's
    joint friction, or an earlier model's drive terms (its Coulomb column tanh(v/v_s) with its
    own v_s, parallel-filtered like the torque, as ``validate`` predicts; the model file's
    damping is not added, as in ``validate``). Through the model's transmission the terms are
    each motor's: τ = Rᵀ τ_m(θ̇ = R q̇, θ̈ = R q̈), a coupled motor's Coulomb column the filtered
    tanh of its own velocity (:func:`~pe_drake.multibody.drive_columns.coulomb_columns`)."""
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
    regressor ``columns`` (:class:`~pe_drake.diagnosis.columns.Columns` of ``seg``) plus its
    friction; the reference the augmented model must beat (issue 36), the a-priori model too
    unless ``diagnose --model`` gave an earlier one."""
    return columns.product(range(base.count), base.base_values(robot.phi_model)) + model_file_friction(robot, seg)


def reference_shortfalls(robot: Robot, base, columns, seg: Segment, tau: np.ndarray) -> list[Shortfall]:
    """The joints whose torque ``tau`` along ``seg`` (the augmented model's on the held-out part)
    is worse than the model file's (:func:`model_file_torque`) or than predicting zero."""
    references = {"a_priori": model_file_torque(robot, base, columns, seg), "zero": np.zeros_like(tau)}
    return shortfalls(robot.joint_names, seg.tau, tau, references)
