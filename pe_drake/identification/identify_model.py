"""The front door of ``pe-drake identify``: :func:`identify_model` takes a raw measured run and
does what the command does, checks included: preprocessing, the torque-sign check, the fit with
its drive terms (Eq. 4) and the physically valid standard parameters for ``model.urdf``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from pe_drake.config import Config
from pe_drake.exceptions import ConfigError
from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.identification.time_window import TimeWindow
from pe_drake.identification.channels import measured_values
from pe_drake.identification.coupling import coupled_pairs, coupling_warnings
from pe_drake.identification.data_checks import check_against_model
from pe_drake.identification.drive_terms import drive_summary, filtered_coulomb, format_percent
from pe_drake.multibody.drive_columns import COULOMB_VELOCITY_SCALE, DriveTermOptions
from pe_drake.identification.estimators import IdentificationResult, fit_warnings, identify
from pe_drake.identification.intake import prepare_measurement
from pe_drake.identification.prediction import predict, predict_wrench
from pe_drake.identification.gaps import MAX_GAP_S
from pe_drake.identification.identified_file import result_to_dict, standard_parameters_dict
from pe_drake.identification.measurements import Measurement
from pe_drake.identification.physical_fit import PhysicalBounds, bounds_from_config
from pe_drake.identification.rest import REST_CHOICES, RestDecision, decide_rest
from pe_drake.io_utils import staged_output_dir
from pe_drake.multibody.inertia import PhysicallyInvalidError, validity_problems
from pe_drake.multibody.robot import Robot
from pe_drake.multibody.robot_model import RobotModel
from pe_drake.multibody.sensors import MeasurementType
from pe_drake.multibody.transmission import Transmission, robot_transmission
from pe_drake.output_paths import IDENTIFY_OUTPUTS, check_output_dir
from pe_drake.plots import plot_prediction


@dataclasses.dataclass(frozen=True)
class IdentifyOptions:
    """How ``identify`` fits (one frozen record; :meth:`from_config` reads the config's sections).

    Attributes:
        measurement: the channels to fit: "joint_torque", "base_wrench" or "both".
        cutoff_hz: low-pass cut-off [Hz] (None: from ``trajectory`` or the data).
        trajectory: the trajectory.json that was run: its highest harmonic sets the cut-off.
        filtering: False uses the data as it is (exact data with v.* and vdot.* columns).
        max_gap_s: holes in the time column up to this are interpolated [s].
        window: the part of the run fitted, cut after filtering (None: all of it).
        rest: the joint-torque rows of a joint at rest: ``auto`` (kept out of the fit if
            cross-validation says so), ``keep`` or ``exclude``.
    """

    method: str = "wls"
    measurement: str = "joint_torque"
    cutoff_hz: float | None = None
    trajectory: str | None = None
    filtering: bool = True
    drive: DriveTermOptions = DriveTermOptions()
    bounds: PhysicalBounds | None = None
    max_gap_s: float = MAX_GAP_S
    window: TimeWindow | None = None
    rest: str = "auto"

    def __post_init__(self):
        if self.method not in ("ols", "wls", "physical"):
            raise ConfigError(f"identification method '{self.method}' is not one of ols, wls, physical")
        if self.rest not in REST_CHOICES:
            raise ConfigError(f"--rest '{self.rest}' is not one of {', '.join(REST_CHOICES)}")
        if self.cutoff_hz is not None and not (math.isfinite(self.cutoff_hz) and self.cutoff_hz > 0):
            raise ConfigError(f"--cutoff must be a positive frequency [Hz], got {self.cutoff_hz}")

    @classmethod
    def from_config(cls, config: Config, **changes: Any) -> IdentifyOptions:
        """The options of a config (``identification``, ``data``, ``excitation.measurement``),
        with ``changes`` on top (None values are ignored; ``drive_terms="none"`` sets the
        drive terms' kind)."""
        changes = {k: v for k, v in changes.items() if v is not None}
        choice = config.identification
        kind = changes.pop("drive_terms", None) or choice.drive_terms
        v_s = choice.coulomb_velocity_scale or COULOMB_VELOCITY_SCALE
        base = cls(measurement=config.excitation.measurement, drive=DriveTermOptions(kind, v_s),
                   bounds=bounds_from_config(choice), max_gap_s=config.data.max_gap_s)
        return dataclasses.replace(base, **changes)


@dataclasses.dataclass(frozen=True, eq=False)
class IdentifiedModel:
    """An identified model and the data it came from; :meth:`write` writes ``identify``'s files.

    Attributes:
        raw: the measured run as read; data: as preprocessed for the fit.
        coulomb: the parallel-filtered Coulomb columns (None without filtering).
        phi: physically valid standard parameters for model.urdf (None: none).
        note: what was done to get them, or why model.urdf is not written.
        rest: what was done with the samples at rest (None: a fit of the ground wrench alone).
    """

    robot: Robot
    result: IdentificationResult
    raw: Measurement
    data: Measurement
    coulomb: np.ndarray | None
    phi: np.ndarray | None
    note: str
    wall_time: float
    rest: RestDecision | None = None

    @property
    def model(self) -> RobotModel:
        """The identified robot as built: the fit's parameters (``phi`` when the fit has base
        parameters only) and drive terms with their σ."""
        return self.result.model

    def summary_lines(self) -> list[str]:
        """What the command prints: the data, its preprocessing, the fit and its warnings."""
        robot, raw, result, p = self.robot, self.raw, self.result, self.data.preprocessing
        lines = [f"robot {robot.name}: {robot.n} joints; data {raw.source}: {raw.num_samples} samples, "
                 f"{raw.duration:.2f} s at {raw.rate_hz:.0f} Hz"]
        if p is not None:
            lines.append(p.describe())
        lines += [f"note: {note}" for note in self.data.notes]
        lines += [self.rest.line()] if self.rest is not None else []
        lines.append(f"{result.method} from {result.measurement}: {result.base.count} base parameters, "
                     f"cond(W) = {result.cond:.4g}, {result.wall_time:.2f} s"
                     + _weights_note(result))
        if result.base.rank_note:
            lines.append(f"note: {result.base.rank_note}")
        worst = np.argsort(result.sigma_percent)[-min(5, len(result.sigma_percent)):][::-1]
        lines.append("least determined base parameters (%σ): "
                     + ", ".join(f"{_short_name(result.base, i)} {format_percent(result.sigma_percent[i])}" for i in worst))
        lines.append("residual RMS [N·m, N]: " + ", ".join(f"{c} {r:.4g}" for c, r in zip(result.channels, result.residual_rms)))
        return lines + drive_summary(result.model, result.drive_layout) + fit_warnings(result)

    def write(self, folder: str | Path, *, progress: Callable[[str], None] | None = None) -> list[str]:
        """Writes identified.json, residuals.png and, when physically valid, model.urdf and
        drive_effects.yaml into ``folder``, all or nothing; returns the paths written.
        ``progress`` is called with the note on model.urdf, when there is one."""
        out, robot, result = check_output_dir(folder), self.robot, self.result
        note, written = self.note, ["identified.json", "residuals.png"]
        with staged_output_dir(out, "identified.json", IDENTIFY_OUTPUTS) as tmp:
            model_file = None
            if self.phi is not None:
                model = self.model
                try:
                    model.write_urdf(tmp / "model.urdf", robot)
                    model_file = "model.urdf"
                    note = "; ".join([note] * bool(note) + _urdf_notes(model))
                except (PhysicallyInvalidError, ConfigError) as err:
                    note = f"model.urdf not written: {err}"
            d = result_to_dict(result, robot, model_file)
            if result.phi is None and self.phi is not None:
                d["standard_parameters"] = standard_parameters_dict(robot, self.phi)
                d["physically_valid"] = True
            if note:
                d["note"] = note
            d["total_time_s"] = self.wall_time
            if self.rest is not None:
                d["rest"] = self.rest.as_dict()
            (tmp / "identified.json").write_text(json.dumps(d, indent=2))
            measured, predicted = prediction(robot, result, self.data, MeasurementType(result.measurement), self.coulomb)
            plot_prediction(tmp / "residuals.png", robot.name, self.data.t, measured, predicted, result.relative_error,
                            result.channels, f"{robot.name}: {result.method} fit on the identification data")
            if model_file:
                written.append(model_file)
                if result.drive_layout is not None and result.drive_layout.count:
                    (tmp / "drive_effects.yaml").write_text(self.model.effects_yaml(DRIVE_EFFECTS_HEADER))
                    written.append("drive_effects.yaml")
        if note and progress is not None:
            progress(note)
        return [str(out / name) for name in written]


#: drive_effects.yaml's header.
DRIVE_EFFECTS_HEADER = ("# Drive terms identified by pe-drake identify (TRUTH.yaml schema of pe-drake simulate):\n"
                        "#   pe-drake simulate --robot model.urdf --truth drive_effects.yaml ...\n")


def _urdf_notes(model: RobotModel) -> list[str]:
    """What model.urdf leaves out (negative friction or armature; Coulomb friction and offsets)."""
    if not model.drive:
        return []
    # through a transmission: what the per-joint URDF leaves out of the motors' terms, noted too
    written = model.per_joint_model().nonnegative("is written as 0 to the URDF")
    return list(written.notes[len(model.notes):]) + [
        "Coulomb friction is in <dynamics friction> (Drake's parser ignores it, pe_drake reads it as the model file's "
        "friction) and identified.json; torque offsets in identified.json only"]


def _weights_note(result) -> str:
    """What the WLS weights did, for the summary line ("" for OLS and the one step)."""
    if result.weight_iterations <= 1:
        return ""
    if result.weights_converged:
        return f"; weights 1/σ_j at their fixed point after {result.weight_iterations} solves"
    return (f"; warning: the weights 1/σ_j did not reach their fixed point in {result.weight_iterations} solves "
            "(the last solve's are used)")


def _short_name(base, i: int) -> str:
    """The standard parameter a base parameter is built on, '+…' when others are lumped in."""
    name = base.names[base.independent[i]]
    return name if base.base_names[i] == name else name + "+…"


def _trajectory_band(path: str | None) -> tuple[float | None, int | None]:
    """(fundamental [Hz], harmonics) of a trajectory.json, to choose the filter cut-off: the
    highest harmonic the motion uses, not the file's zero-padded count (which set 400 Hz)."""
    if not path:
        return None, None
    trajectory, _ = load_trajectory(path)
    return trajectory.omega / (2 * math.pi), max(trajectory.highest_harmonic, 1)


def identify_model(robot: Robot, measurements: Measurement, options: IdentifyOptions | None = None, *,
                   progress: Callable[[str], None] | None = None) -> IdentifiedModel:
    """What ``pe-drake identify`` does, from a raw measured run to an :class:`IdentifiedModel`.

    Args:
        measurements: the raw run (:func:`~pe_drake.identification.intake.read_measurements`).
        progress: called with the :meth:`~IdentifiedModel.summary_lines` once the fit is done.

    Raises:
        DataError: data the checks refuse (units, gaps, sign-flipped torque columns, too short),
            naming the file and the column.
    """
    start = time.perf_counter()
    options = options or IdentifyOptions()
    f0, harmonics = _trajectory_band(options.trajectory)
    data = prepare_measurement(robot, measurements, cutoff_hz=options.cutoff_hz, fundamental_hz=f0,
                               harmonics=harmonics, filtering=options.filtering, max_gap_s=options.max_gap_s,
                               window=options.window)
    check_against_model(robot, data)  # sign-flipped torque columns
    coulomb = (filtered_coulomb(measurements, data, options.drive.velocity_scale, fitted_transmission(robot, options))
               if data is not measurements else None)
    rest = _rest_decision(robot, measurements, data, options, coulomb)
    result = identify(robot, data, options.method, measurement=options.measurement, drive_terms=options.drive,
                      bounds=options.bounds, coulomb=coulomb, rest=None if rest is None else rest.mask)
    result = dataclasses.replace(result, coupling=tuple(_coupling(robot, result, data, coulomb)))
    phi, note = _model_parameters(robot, result)
    model = IdentifiedModel(robot, result, measurements, data, coulomb, phi, note, time.perf_counter() - start, rest)
    for line in model.summary_lines() if progress is not None else ():
        progress(line)
    return model


def fitted_transmission(robot: Robot, options: IdentifyOptions) -> Transmission | None:
    """The transmission the drive terms of ``options`` act through (None: per joint), as
    :func:`~pe_drake.multibody.drive_columns.drive_layout` decides: the robot's, unless R = I.
    The Coulomb columns are the motors' exactly when this is not None."""
    T = robot_transmission(robot)
    none = options.drive.terms == "none" or MeasurementType(options.measurement).kind == "base_wrench"
    return None if T.identity or none else T


def _coupling(robot: Robot, result: IdentificationResult, data: Measurement, coulomb: np.ndarray | None) -> list[str]:
    """The warning of :mod:`~pe_drake.identification.coupling` on the joint torques' residual
    (none for the ground wrench alone or a fit without drive terms, whose residual holds all
    the friction)."""
    layout = result.drive_layout
    if not MeasurementType(result.measurement).torques or layout is None or not layout.count:
        return []
    residual = data.tau - predict(robot, result, data, coulomb=coulomb)
    T = layout.transmission
    return coupling_warnings(coupled_pairs(robot.joint_names, data.v, data.vd, residual,
                                           layout.velocity_scale, None if T is None else T.R))


def _rest_decision(robot: Robot, raw: Measurement, data: Measurement, options: IdentifyOptions,
                   coulomb: np.ndarray | None) -> RestDecision | None:
    """What to do with the rows at rest (:func:`~pe_drake.identification.rest.decide_rest`);
    None for the ground wrench alone, which no friction acts on. The folds are fitted by least
    squares (wls for the physical fit: an SDP per fold would cost more than it decides)."""
    if not MeasurementType(options.measurement).torques:
        return None
    method = "ols" if options.method == "ols" else "wls"

    def fit(idx, mask):
        part = None if coulomb is None else coulomb[idx]
        return identify(robot, data.take(idx), method, measurement=options.measurement,
                        drive_terms=options.drive, coulomb=part, rest=mask)

    def predicted(result, idx):
        part = None if coulomb is None else coulomb[idx]
        return predict(robot, result, data.take(idx), coulomb=part)

    return decide_rest(raw, data, options.rest, fit, predicted)


def _model_parameters(robot: Robot, result: IdentificationResult) -> tuple[np.ndarray | None, str]:
    """Standard parameters for model.urdf (None: none physically valid) and a note on them: the
    physical fit's, or the a-priori model moved to the identified base parameters when valid."""
    if result.phi is not None:
        return result.phi, ""
    candidate = result.model.phi  # the a-priori model moved to the base parameters
    if not validity_problems(robot.body_names, candidate):
        return candidate, "standard parameters: the a-priori model moved to the identified base parameters"
    return None, ("model.urdf not written: the least-squares estimate has no physically valid standard "
                  "parameters near the a-priori model; use --method physical")


def prediction(robot: Robot, result: IdentificationResult, data: Measurement, kind: MeasurementType,
               coulomb: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(measured, predicted), each (S, r): the joint torques, then the ground wrench
    (``coulomb``: the parallel-filtered Coulomb columns of the drive terms)."""
    measured_values(robot, data, kind.kind)  # refuses data without the channels, naming them
    measured, predicted = [], []
    if kind.torques:
        measured.append(data.tau)
        predicted.append(predict(robot, result, data, coulomb=coulomb))
    if kind.wrench:
        measured.append(data.wrench)
        predicted.append(predict_wrench(robot, result, data))
    return np.hstack(measured), np.hstack(predicted)
