"""The identified.json format: an :class:`IdentificationResult` written and read back.

It holds the base parameters (value, relative σ, the standard-parameter column each stands for),
the drive terms in their own block, the per-channel errors, the preprocessing and, for the
physical fit, the standard parameters per body; :func:`load_identified` checks that a file
belongs to the robot (a file without ``drive_terms`` loads as a model without them).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pe_drake.config import MEASUREMENTS
from pe_drake.exceptions import DataError, check_joints
from pe_drake.limits import input_file_problem
from pe_drake.identification.channels import channel_names
from pe_drake.identification.drive_terms import drive_block
from pe_drake.multibody.drive_columns import read_drive_block
from pe_drake.identification.estimators import IdentificationResult, fit_warnings
from pe_drake.identification.measurements import Preprocessing
from pe_drake.io_utils import loads_json
from pe_drake.multibody.inertia import PARAMETER_NAMES, validity_problems
from pe_drake.multibody.robot_model import RobotModel
from pe_drake.multibody.sensors import measurement_base_parameters
from pe_drake.multibody.transmission import robot_transmission
from pe_drake.output_set import check_output_set

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


def data_used(p: Preprocessing, samples: int) -> dict[str, Any]:
    """How much of the recording the fit used (identified.json's ``data_used``)."""
    # A fit on part of the preprocessed samples (e.g. the first half) used samples / rate of it.
    fitted_s = p.duration_out_s if samples == p.samples_out else samples / p.rate_hz
    return {
        "samples_fitted": int(samples), "samples_recorded": int(p.samples_in),
        "time_fitted_s": fitted_s, "time_recorded_s": p.duration_in_s,
        "trimmed_at_each_end_s": p.trim_s,
        "fraction_of_record_time": fitted_s / p.duration_in_s if p.duration_in_s > 0 else None,
        "why_trimmed": "the low-pass filter's edge transient (odd extension) on the accelerations",
    }


def result_to_dict(result: IdentificationResult, robot: Robot, model_file: str | None = None) -> dict[str, Any]:
    """The content of identified.json."""
    base = zip(result.base.base_names, result.phi_B, result.sigma_percent, result.base.independent)
    channels = result.channels or result.joints  # joints (torques), then wrench.fx ... mz
    out: dict[str, Any] = {
        "robot": result.robot, "method": result.method, "measurement": result.measurement,
        "joints": list(result.joints), "data": result.source, "samples": result.samples,
        "cond": result.cond,
        "base_parameters": [{"name": name, "value": float(v),
                             "sigma_percent": float(sp) if math.isfinite(sp) else None,
                             "column": int(col)} for name, v, sp, col in base],
        "residual_rms": dict(zip(channels, map(float, result.residual_rms))),
        "relative_error": dict(zip(channels, map(float, result.relative_error))),
        "noise_std": dict(zip(channels, map(float, result.noise_std))),
        "wall_time": result.wall_time,
    }
    if result.preprocessing is not None:
        out["preprocessing"] = dataclasses.asdict(result.preprocessing)
        out["data_used"] = data_used(result.preprocessing, result.samples)
    if result.cov_B is not None and np.all(np.isfinite(result.cov_B)):  # export --to gains draws from it
        cov = np.asarray(result.cov_B, float)
        out["base_parameter_covariance"] = (0.5 * (cov + cov.T)).tolist()  # the sandwich is symmetric up to rounding
    if result.drive_layout is not None:
        out["drive_terms"] = drive_block(result.model, result.drive_layout, result.phi is not None)
    if result.physical_notes:
        out["physical_fit_notes"] = list(result.physical_notes)
    if result.friction_share is not None:  # of the OLS residual's energy
        out["friction_share_of_residual"] = result.friction_share
    if result.weight_iterations:  # noise_std holds the σ_j of these weights
        out["wls_weights"] = {"solves": result.weight_iterations, "fixed_point": result.weights_converged}
    warnings = fit_warnings(result)
    if warnings:
        out["warnings"] = warnings
    if result.phi is not None:
        out["standard_parameters"] = standard_parameters_dict(robot, result.phi)
        out["physically_valid"] = not validity_problems(robot.body_names, result.phi)
    if model_file:
        out["model_file"] = model_file
    return out


def standard_parameters_dict(robot: Robot, phi: np.ndarray) -> dict[str, dict[str, float]]:
    """{body: {parameter name: value}} (names of ``pe_drake.multibody.inertia.PARAMETER_NAMES``)."""
    return {body: dict(zip(PARAMETER_NAMES, map(float, phi[10 * b : 10 * b + 10])))
            for b, body in enumerate(robot.body_names)}


def load_identified(path: str | Path, robot: Robot) -> IdentificationResult | RobotModel:
    """Reads identified.json, or the diagnosis's augmented_model.json as a
    :class:`~pe_drake.multibody.robot_model.RobotModel` (:func:`read_augmented_model`), and checks it
    belongs to ``robot``.

    Raises:
        DataError: missing/unreadable file, other robot or joints, base parameters that do
            not match the robot's composition.
    """
    path = Path(path)
    problem = input_file_problem(path)
    if problem:
        raise DataError(f"identified model file {problem}", file=str(path))
    if path.is_file():
        check_output_set(path)  # its model.urdf and residuals are of the same run
    try:
        d = loads_json(path.read_text(), str(path))
    except FileNotFoundError:
        raise DataError("identified model file does not exist", file=str(path)) from None
    except (OSError, json.JSONDecodeError) as err:
        raise DataError(f"cannot read the identified model: {err}", file=str(path)) from err
    if isinstance(d, dict) and "base_parameters" not in d and "phi" in d and "torque_equation" in d:
        return read_augmented_model(d, robot, str(path))
    try:
        joints = tuple(d["joints"])
        entries = d["base_parameters"]
        phi_B = np.array([float(e["value"]) for e in entries])
        columns = np.array([int(e["column"]) for e in entries])
        sigma = np.array([np.inf if e.get("sigma_percent") is None else float(e["sigma_percent"])
                          for e in entries])
    except (KeyError, TypeError, ValueError) as err:
        raise DataError("not an identified.json written by pe-drake identify nor an "
                        f"augmented_model.json of pe-drake diagnose ({err!r} missing or malformed)",
                        file=str(path)) from err
    check_joints(robot, joints, file=str(path), what="the model")
    measurement = d.get("measurement", "joint_torque")
    if measurement not in MEASUREMENTS:
        raise DataError(f"measurement '{measurement}' is not one of {', '.join(MEASUREMENTS)}", file=str(path))
    base = measurement_base_parameters(robot, measurement)
    channels = channel_names(robot, measurement)
    if not np.array_equal(columns, base.independent):
        raise DataError(f"the base parameters in the file ({len(columns)}) do not match robot "
                        f"'{robot.name}' ({base.count}); was it identified with another model or "
                        "config?", file=str(path))
    cov_B = _covariance(d, base.count, str(path))
    try:  # files written before the drive terms have none
        model = RobotModel.from_dict(d, robot.body_names, base=base, phi_prior=robot.phi_model)
        layout = read_drive_block(d["drive_terms"], robot.joint_names)[0] if d.get("drive_terms") is not None else None
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise DataError(f"standard_parameters or drive_terms: {err!r} missing or malformed", file=str(path)) from err
    if layout is not None and layout.transmission is not None:
        _check_transmission(layout.transmission, robot, path)
    def per_channel(key):
        return np.array([d.get(key, {}).get(c, np.nan) for c in channels])

    return IdentificationResult(
        robot=d.get("robot", robot.name), method=d.get("method", "ols"), joints=joints, base=base,
        phi_B=phi_B, sigma_percent=sigma, phi=model.phi if "standard_parameters" in d else None,
        cond=float(d.get("cond", float("nan"))), residual_rms=per_channel("residual_rms"),
        relative_error=per_channel("relative_error"), noise_std=per_channel("noise_std"),
        samples=int(d.get("samples", 0)), source=d.get("data", ""), measurement=measurement,
        channels=channels, model=model, drive_layout=layout,
        physical_notes=tuple(d.get("physical_fit_notes", ())), cov_B=cov_B,
    )


def _covariance(d: dict[str, Any], count: int, path: str) -> np.ndarray | None:
    """The file's ``base_parameter_covariance``, (count, count), made symmetric, or None.

    Raises:
        DataError: a covariance of another size, or not finite.
    """
    if d.get("base_parameter_covariance") is None:
        return None
    try:
        cov = np.array(d["base_parameter_covariance"], dtype=float)
    except (TypeError, ValueError) as err:
        raise DataError(f"base_parameter_covariance: not a matrix of numbers ({err})", file=path) from err
    if cov.shape != (count, count):
        raise DataError(f"base_parameter_covariance has shape {cov.shape}; the {count} base parameters need "
                        f"({count}, {count})", file=path)
    if not np.all(np.isfinite(cov)):
        raise DataError("base_parameter_covariance must hold finite numbers", file=path)
    return 0.5 * (cov + cov.T)


def read_augmented_model(d: dict[str, Any], robot: Robot, path: str = "") -> RobotModel:
    """The diagnosis's augmented_model.json as the :class:`~pe_drake.multibody.robot_model.RobotModel`
    it is (validate, ``diagnose --model`` and export take it as it is).

    Raises:
        DataError: other joints, a malformed file.
    """
    check_joints(robot, tuple(d.get("joints") or ()), file=path, what="the model")
    try:
        return RobotModel.from_dict(d, robot.body_names)
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise DataError(f"not an augmented_model.json written by pe-drake diagnose ({err!r} missing or malformed)",
                        file=path) from err


def model_method(model: IdentificationResult | RobotModel) -> str:
    """What made a loaded model: the fit's method, or "diagnose" (a RobotModel: the augmented model)."""
    return "diagnose" if isinstance(model, RobotModel) else model.method


def unapplied_effects(model: IdentificationResult | RobotModel) -> list[str]:
    """What of a loaded model a prediction of the torque log sample by sample leaves out (validate,
    ``diagnose --model``): a :class:`~pe_drake.multibody.robot_model.RobotModel`'s time delay and
    holding torque at rest (validate applies its pre-sliding friction, diagnose --model says it
    does not); nothing of an identified fit."""
    if not isinstance(model, RobotModel):
        return []
    notes = []
    if model.torque_delay != 0.0:
        notes.append(f"the model's time delay {model.torque_delay:.4g} s is not applied (validate pairs samples as "
                     "recorded)")
    if np.any(model.holding_torque):
        notes.append("the model's holding torque at rest is not applied ("
                     + ", ".join(f"{j} {x:.3g} N·m" for j, x in zip(model.joints, model.holding_torque) if x) + ")")
    return notes


def _check_transmission(T, robot: Robot, path) -> None:
    """Refuses a model fitted through another transmission T than the robot's config gives: the
    config's R converts motor-side logs, the file's R carries its per-motor terms."""
    mine = robot_transmission(robot)
    if not np.allclose(mine.R, T.R, rtol=1e-12, atol=0.0):
        given = "none (R = I)" if mine.identity else f"R = {mine.R.tolist()}"
        raise DataError(f"the model's drive terms are per motor through robot.transmission R = {T.R.tolist()}; this "
                        f"robot's config gives {given}: load the robot with the config it was identified with "
                        "(--config)", file=str(path))
