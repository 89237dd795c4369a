"""What an identified model predicts: the joint torques and the ground wrench at a run's
samples (an identify fit's Y_B φ_B, or a :class:`~pe_drake.multibody.robot_model.RobotModel`'s
Y φ, drive terms included), and the per-joint errors against the measured torque."""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from pe_drake.identification.drive_terms import drive_torque
from pe_drake.identification.estimators import IdentificationResult
from pe_drake.identification.measurements import Measurement
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.robot_model import RobotModel
from pe_drake.multibody.wrench import static_wrench

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


def robot_torques(robot: Robot, data: Measurement, phi: np.ndarray,
                  model: RegressorModel | None = None) -> np.ndarray:
    """Rigid-body torques Y(q, v, v̇) φ at the samples of ``data``, shape (S, n)."""
    model = model or RegressorModel(robot)
    out = np.empty_like(data.q)
    for rows in _chunks(data.num_samples):
        out[rows] = model(data.q[rows], data.v[rows], data.vd[rows]) @ phi
    return out


def _chunks(count: int, size: int = 2000) -> list[slice]:
    return [slice(s, min(s + size, count)) for s in range(0, count, size)]


def predict(robot: Robot, result: IdentificationResult | RobotModel, data: Measurement,
            model: RegressorModel | None = None, coulomb: np.ndarray | None = None) -> np.ndarray:
    """Torques an identified fit (Y_B φ_B) or a :class:`~pe_drake.multibody.robot_model.RobotModel`
    (Y φ, its payload included) predicts at the samples of ``data``, the drive terms included,
    shape (S, n) (``coulomb``: as in :func:`~pe_drake.identification.estimators.identify`; no delay
    or pre-sliding state)."""
    model = model or RegressorModel(robot)
    tau = np.empty_like(data.q)
    as_built = isinstance(result, RobotModel)
    for rows in _chunks(data.num_samples):  # the regressor of a block at a time: long runs fit
        Y = model(data.q[rows], data.v[rows], data.vd[rows])
        tau[rows] = Y @ result.phi_total if as_built else result.base.reduce(Y) @ result.phi_B
    drive = (drive_torque(result, result.layout(), data.v, data.vd, coulomb) if as_built
             else drive_torque(result.model, result.drive_layout, data.v, data.vd, coulomb))
    if drive is not None:
        tau = tau + drive
    if as_built and np.any(result.spring):  # diagnose's joint_stiffness: torque k·q
        tau = tau + data.q * result.spring
    return tau


def predict_wrench(robot: Robot, result: IdentificationResult | RobotModel, data: Measurement,
                   model: RegressorModel | None = None) -> np.ndarray:
    """The ground wrench an identified fit or a :class:`~pe_drake.multibody.robot_model.RobotModel`
    predicts at the samples of ``data``, (S, 6) [N, N·m] (the a-priori weight of the bodies no
    excited joint moves included; no offset)."""
    model = model or RegressorModel(robot)
    W = np.concatenate([model.wrench_regressor(model.kinematics(data.q[r], data.v[r], data.vd[r]))
                        for r in _chunks(data.num_samples)])
    if isinstance(result, RobotModel):
        return W @ result.phi_total + static_wrench(robot)
    return result.base.reduce(W) @ result.phi_B + static_wrench(robot)


class TorqueErrors(NamedTuple):
    """Per-joint RMS of τ_meas − τ_pred (n,) [N·m] and 100·‖τ_meas − τ_pred‖/‖τ_meas‖ (n,) [%]."""

    rms: np.ndarray
    relative: np.ndarray


def torque_errors(tau_measured: np.ndarray, tau_predicted: np.ndarray) -> TorqueErrors:
    """Per-joint :class:`TorqueErrors` (unpacks as (rms, relative))."""
    e = np.asarray(tau_measured) - np.asarray(tau_predicted)
    rms = np.sqrt(np.mean(e**2, axis=0))
    rel = 100.0 * np.linalg.norm(e, axis=0) / np.maximum(np.linalg.norm(tau_measured, axis=0), 1e-300)
    return TorqueErrors(rms, rel)
