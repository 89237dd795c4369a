"""``pe-drake validate --model model.xml | model.urdf | model.sdf``: an exported model predicts a
held-out run in the simulator it was exported for.

An MJCF's torques are MuJoCo's own (:mod:`pe_drake.export.mujoco_dynamics`, plus
``frictionloss·sign(v)``); a URDF's or SDFormat's are Drake's inverse dynamics of the file loaded
as a robot (a URDF's ``<dynamics friction>`` as f·tanh(v/v_s); an SDFormat file's none). Offsets
and whatever else the format cannot hold are not predicted.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pe_drake.exceptions import ConfigError
from pe_drake.export.drake_files import reloaded_robot
from pe_drake.export.mujoco_dynamics import joint_frictionloss, load_mjcf, mujoco_torques
from pe_drake.multibody.drive_columns import COULOMB_VELOCITY_SCALE, coulomb_column
from pe_drake.identification.data_checks import check_against_model
from pe_drake.identification.drive_terms import filtered_coulomb
from pe_drake.identification.intake import prepare_measurement
from pe_drake.identification.prediction import torque_errors
from pe_drake.identification.measurements import Measurement
from pe_drake.identification.validate_model import ValidateOptions, ValidationReport
from pe_drake.multibody.robot import Robot

#: v_s standing for sign(v): MuJoCo's dry friction on a sliding joint [rad/s].
SIGN_VELOCITY_SCALE = 1e-6
#: Suffixes of the model files validate predicts with a simulator.
SIMULATOR_SUFFIXES = (".xml", ".urdf", ".sdf")


def is_simulator_model(path: str | Path) -> bool:
    """Whether ``validate --model`` names an exported simulator file (not an identified.json)."""
    return Path(path).suffix.lower() in SIMULATOR_SUFFIXES


def simulator_torques(robot: Robot, path: str | Path, q: np.ndarray, v: np.ndarray, vd: np.ndarray,
                      friction_columns=None) -> tuple[np.ndarray, str]:
    """(torques (S, n), what computed them) of the model file at the samples (module docstring).

    Args:
        friction_columns: ``f(v_s) -> (S, n)`` the Coulomb columns tanh(v/v_s) of the samples
            (validate: filtered like the torques); default tanh of ``v``.

    Raises:
        ConfigError: a file the simulator refuses or whose joints differ from the robot's.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"--model '{path}' does not exist")
    columns = friction_columns or (lambda scale: coulomb_column(v, scale))
    if path.suffix.lower() == ".xml":
        model = load_mjcf(path)
        tau = mujoco_torques(model, robot.joint_names, q, v, vd)
        tau = tau + joint_frictionloss(model, robot.joint_names) * columns(SIGN_VELOCITY_SCALE)
        return tau, "MuJoCo mj_inverse (armature, damping) + frictionloss·sign(v)"
    loaded = reloaded_robot(robot, path.read_text(), path.suffix.lower())
    if loaded.joint_names != robot.joint_names:
        raise ConfigError(f"'{path.name}' has joints {', '.join(loaded.joint_names)}; robot '{robot.name}' excites "
                          f"{', '.join(robot.joint_names)}")
    tau = loaded.inverse_dynamics(q, v, vd, include_damping=True)
    if path.suffix.lower() == ".sdf":  # Drake ignores <friction>, and pe_drake reads it from URDFs only
        return tau, "Drake inverse dynamics (rotor inertia, damping); an SDFormat file's <friction> is not applied"
    tau = tau + loaded.joint_friction * columns(COULOMB_VELOCITY_SCALE)
    return tau, "Drake inverse dynamics (rotor inertia, damping) + the file's friction·tanh(v/v_s)"


def validate_exported(robot: Robot, path: str | Path, measurements: Measurement,
                      options: ValidateOptions | None = None) -> ValidationReport:
    """``validate`` with an exported model file: the run's torques predicted by its simulator.

    ConfigError as :func:`simulator_torques` or for a wrench; DataError for refused data."""
    options = options or ValidateOptions()
    if options.measurement != "joint_torque":
        raise ConfigError(f"validate --model {Path(path).name} predicts joint torques only; "
                          f"--measurement {options.measurement} needs an identified.json")
    data = prepare_measurement(robot, measurements, cutoff_hz=options.cutoff_hz, max_gap_s=options.max_gap_s,
                               window=options.window)
    check_against_model(robot, data)
    # the torque was low-pass filtered: so is the friction's sign (parallel filtering, as validate_model)
    predicted, how = simulator_torques(robot, path, data.q, data.v, data.vd,
                                       lambda scale: filtered_coulomb(measurements, data, scale))
    rms, rel = torque_errors(data.tau, predicted)
    total = float(100 * np.linalg.norm(data.tau - predicted) / max(np.linalg.norm(data.tau), 1e-300))
    simulator = "MuJoCo" if Path(path).suffix.lower() == ".xml" else "Drake"
    return ValidationReport(robot.name, f"{Path(path).name}, torques by {simulator}", "joint_torque",
                            tuple(robot.joint_names), data.t, data.tau, predicted, rms, rel,
                            total, data.num_samples, (*data.notes, f"torques computed by {how}"), data.preprocessing)
