"""What every export writes: the robot as built (:class:`~pe_drake.multibody.robot_model.RobotModel`),
read from a model file in one place (:func:`exported_model`), and the identification's spread for
randomization (:func:`identified_spread`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.identification.prediction import predict
from pe_drake.identification.identified_file import load_identified
from pe_drake.multibody.robot_model import RobotModel
from pe_drake.simulation.simulated_model import load_simulation_model

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


@dataclasses.dataclass(frozen=True, eq=False)
class IdentifiedSpread:
    """The identification's uncertainty of the p base parameters (the drive terms' σ is the
    model's own ``RobotModel.sigma``)."""

    K: np.ndarray  # φ_B = K φ, (p, 10·nb)
    sigma: np.ndarray  # (p,); inf or NaN: not identified
    names: tuple[str, ...] = ()
    cov: np.ndarray | None = None  # (p, p); None: drawn independently from σ (``note`` says so)
    note: str = ""  # what the draws could not use


def exported_model(robot: Robot, model: str | Path | None) -> RobotModel:
    """The model to export, physically consistent: that of ``model`` (an identified.json of any
    method or augmented_model.json), projected as ``simulate --model`` does, or the robot's own.

    Raises:
        DataError: a model file of another robot, or not one of these files.
        NoSolutionFound: no physically valid parameters near a base-parameter model.
    """
    if model is None:
        return RobotModel.from_robot(robot)
    # physically consistent, friction and armature ≥ 0; a transmission's per-motor terms as the
    # joints hold them (a coupled motor's friction and rotor-inertia coupling left out, noted)
    out = load_simulation_model(model, robot).per_joint_model()
    # the simulator's notes of the same adjustment, in the export's words
    notes = (n.replace(" is simulated as 0", " is written as 0")
             .replace("the simulated ", "the exported ") for n in out.notes)
    return dataclasses.replace(out, notes=tuple(notes))


def identified_spread(robot: Robot, model: str | Path | None) -> IdentifiedSpread | None:
    """The base parameters' σ of an identified.json, or None (the CAD model, an augmented one)."""
    if model is None:
        return None
    result = load_identified(model, robot)
    if isinstance(result, RobotModel):
        return None
    sigma = np.abs(np.asarray(result.phi_B, float)) * np.asarray(result.sigma_percent, float) / 100.0
    note = "" if result.cov_B is not None else (
        f"'{model}' has no base_parameter_covariance (written before identify stored it): the base parameters "
        "are drawn independently from their σ, their correlations left out; identify again to draw from it")
    return IdentifiedSpread(np.asarray(result.base.K, float), sigma, tuple(result.base.base_names), result.cov_B,
                            note)


def projection_change(robot: Robot, model: str | Path, exported: RobotModel, data) -> np.ndarray | None:
    """RMS [N·m] per joint of the change of the prediction on ``data`` (a preprocessed run)
    between the model file's base parameters and the exported consistent φ, or None when the
    file's standard parameters are exported as they are."""
    result = load_identified(model, robot)
    if isinstance(result, RobotModel) or result.phi is not None:
        return None
    own = predict(robot, result, data)
    return np.sqrt(np.mean((own - exported.torque(robot, data.q, data.v, data.vd)) ** 2, axis=0))


def random_states(robot: Robot, samples: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q, v, v̇), each (samples, n), uniform within the robot's limits."""
    rng = np.random.default_rng(seed)
    lim = robot.limits
    q = rng.uniform(lim.q_lower, lim.q_upper, (samples, robot.n))
    v = rng.uniform(-1, 1, (samples, robot.n)) * lim.v_max
    vd = rng.uniform(-1, 1, (samples, robot.n)) * lim.vd_max
    return q, v, vd
