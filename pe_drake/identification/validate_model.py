"""The front door of ``pe-drake validate``: :func:`validate_model` predicts another measured run
with an identified model (``identified.json`` or the diagnosis's ``augmented_model.json``,
:func:`~pe_drake.identification.identified_file.load_identified`) and reports the error per
channel. Any identified model predicts any channel: one identified from the ground wrench
alone predicts the joint torques too.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from pe_drake.config import MEASUREMENTS
from pe_drake.identification.time_window import TimeWindow
from pe_drake.identification.data_checks import a_priori_torque, check_against_model
from pe_drake.identification.drive_terms import filtered_coulomb, filtered_presliding
from pe_drake.multibody.drive_columns import COULOMB_VELOCITY_SCALE
from pe_drake.identification.estimators import IdentificationResult
from pe_drake.identification.intake import prepare_measurement
from pe_drake.identification.prediction import torque_errors
from pe_drake.identification.gaps import MAX_GAP_S
from pe_drake.identification.identify_model import prediction
from pe_drake.identification.measurements import Measurement
from pe_drake.identification.coupling import coupled_pairs, coupling_warnings
from pe_drake.identification.reference_errors import Shortfall, shortfall_report, shortfalls
from pe_drake.io_utils import atomic_write_text
from pe_drake.multibody.robot import Robot
from pe_drake.multibody.robot_model import RobotModel
from pe_drake.multibody.sensors import MeasurementType
from pe_drake.plots import plot_prediction


@dataclasses.dataclass(frozen=True)
class ValidateOptions:
    """How ``validate`` reads the run (cut-off [Hz], longest hole interpolated [s]; unfiltered:
    the torques as recorded, which then need v.* and vdot.* columns)."""

    measurement: str = "joint_torque"
    cutoff_hz: float | None = None
    max_gap_s: float = MAX_GAP_S
    window: TimeWindow | None = None
    filtering: bool = True


@dataclasses.dataclass(frozen=True, eq=False)
class ValidationReport:
    """Measured and predicted channels of a run and their errors.

    Attributes:
        names: the channels ("tau.<joint>", "wrench.fx", ...).
        rms: RMS error per channel [N·m, N]; relative: per channel [%]; relative_total [%].
        worse: the channels worse than the a-priori model (torques) or than predicting zero.
        model_measurement: what an identified model was fitted to (a ``MEASUREMENTS`` name),
            or for a model file (``validate --model model.xml``) the file and its simulator.
        coupling: the warning of joints whose held-out residual looks like a coupled drive the
            model lacks.
    """

    robot: str
    model_measurement: str
    measurement: str
    names: tuple[str, ...]
    t: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    rms: np.ndarray
    relative: np.ndarray
    relative_total: float
    samples: int
    notes: tuple[str, ...] = ()
    preprocessing: Any = None
    worse: tuple[Shortfall, ...] = ()
    coupling: tuple[str, ...] = ()

    def summary_lines(self) -> list[str]:
        """What ``validate`` prints: the preprocessing, the model, the error table, the warnings."""
        width = max(len(j) for j in self.names)
        lines = [self.preprocessing.describe() if self.preprocessing is not None
                 else "the run as recorded (--no-filter): its torques, v.* and vdot.* columns unfiltered"]
        # a model file was not identified from anything: say which file and simulator predicted
        source = (f"model identified from {self.model_measurement}" if self.model_measurement in MEASUREMENTS
                  else f"model: {self.model_measurement}")
        lines += [f"{source}; predicting {self.measurement}",
                 f"{'channel':<{width}}  {'RMS [N·m, N]':>12}  {'relative [%]':>12}"]
        lines += [f"{j:<{width}}  {r:>12.4f}  {e:>12.2f}" for j, r, e in zip(self.names, self.rms, self.relative)]
        lines.append(f"{'all':<{width}}  {float(np.sqrt(np.mean(self.rms**2))):>12.4f}  {self.relative_total:>12.2f}")
        return lines + [s.line() for s in self.worse] + list(self.coupling)

    def to_dict(self, model: str | Path = "", data: str | Path = "") -> dict[str, Any]:
        """``validate --json``'s content (``model``, ``data``: the files, as given)."""
        return {
            "robot": self.robot, "model": str(model), "model_measurement": self.model_measurement,
            "measurement": self.measurement, "data": str(data),
            "rms": dict(zip(self.names, map(float, self.rms))),
            "relative_error": dict(zip(self.names, map(float, self.relative))),
            "relative_error_total": self.relative_total, "samples": self.samples,
            "filtered": self.preprocessing is not None,
            "worse_than_references": shortfall_report(self.worse, ("a_priori", "zero")),
            "coupling_warnings": list(self.coupling),
        }

    def write(self, folder: str | Path, *, json_name: str | Path | None = "validation.json",
              plot_name: str | Path | None = "validation.png", model: str | Path = "",
              data: str | Path = "") -> list[str]:
        """Writes ``validate --json`` and ``--plot`` into ``folder`` (a name may be a path;
        None: not written), both or neither; ``model``, ``data``: the files as given, recorded
        in the JSON. Returns the paths written."""
        folder, written = Path(folder), []
        try:
            if json_name:
                text = json.dumps(self.to_dict(model, data), indent=2)
                atomic_write_text(folder / json_name, text)
                written.append(str(folder / json_name))
            if plot_name:
                plot_prediction(folder / plot_name, self.robot, self.t, self.measured,
                                self.predicted, self.relative, self.names)
                written.append(str(folder / plot_name))
        except BaseException:
            for path in written:
                Path(path).unlink(missing_ok=True)
            raise
        return written


def validate_model(robot: Robot, model: IdentificationResult | RobotModel, measurements: Measurement,
                   options: ValidateOptions | None = None, *,
                   progress: Callable[[str], None] | None = None) -> ValidationReport:
    """What ``pe-drake validate`` does: the run preprocessed and checked, predicted by ``model``.

    Args:
        model: a loaded model (:func:`~pe_drake.identification.identified_file.load_identified`).
        measurements: the raw run (:func:`~pe_drake.identification.intake.read_measurements`).
        progress: called with the :meth:`~ValidationReport.summary_lines` once predicted.


    Raises:
        DataError: data the checks refuse (sign-flipped torque, missing channels, ...).
    """
    options = options or ValidateOptions()
    data = prepare_measurement(robot, measurements, cutoff_hz=options.cutoff_hz, max_gap_s=options.max_gap_s,
                               window=options.window, filtering=options.filtering)
    check_against_model(robot, data)
    kind = MeasurementType(options.measurement)
    as_built = isinstance(model, RobotModel)
    layout = model.layout() if as_built else model.drive_layout
    scale = layout.velocity_scale if layout is not None else COULOMB_VELOCITY_SCALE
    transmission = layout.transmission if layout is not None else None
    measured, predicted = prediction(robot, model, data, kind, filtered_coulomb(measurements, data, scale, transmission))
    dahl = filtered_presliding(measurements, data, model) if as_built and kind.torques else None
    if dahl is not None:  # diagnose's pre-sliding friction: a state along the run's q (the torque channels first)
        predicted[:, : robot.n] += dahl
    rms, rel = torque_errors(measured, predicted)
    total = float(100 * np.linalg.norm(measured - predicted) / max(np.linalg.norm(measured), 1e-300))
    names = tuple(kind.row_names(robot.joint_names))
    worse = shortfalls(names, measured, predicted, {"a_priori": _a_priori(robot, measurements, data, kind),
                                                     "zero": np.zeros_like(measured)})
    coupling = ()
    if kind.torques and layout is not None and layout.count:  # the torque channels come first
        R = transmission.R if transmission is not None else None
        coupling = tuple(coupling_warnings(coupled_pairs(robot.joint_names, data.v, data.vd,
                                                         (measured - predicted)[:, : robot.n], scale, R)))
    report = ValidationReport(robot.name, "joint_torque" if as_built else model.measurement, options.measurement,
                              names, data.t, measured, predicted, rms, rel, total, data.num_samples,
                              tuple(data.notes), data.preprocessing, tuple(worse), coupling)
    for line in report.summary_lines() if progress is not None else ():
        progress(line)
    return report


def _a_priori(robot: Robot, raw: Measurement, data: Measurement, kind: MeasurementType) -> np.ndarray | None:
    """The a-priori model's torques on the torque channels (first in the report), or None."""
    if not kind.torques:
        return None
    coulomb = filtered_coulomb(raw, data, COULOMB_VELOCITY_SCALE) if robot.joint_friction.any() else None
    return a_priori_torque(robot, data, coulomb)
