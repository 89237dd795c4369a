"""The one door for measured files: :func:`read_measurements` reads any supported log and runs
the raw-data checks; :func:`prepare_measurement` checks a run against the robot and preprocesses
it for a fit or a prediction."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from pe_drake.config import DataConfig
from pe_drake.exceptions import DataError, check_joints
from pe_drake.identification.data_checks import check_raw_measurement
from pe_drake.identification.gaps import MAX_GAP_S, preprocess_segments
from pe_drake.identification.measurements import Measurement, amps_hint, check_torque_units, read_measurement_csv
from pe_drake.identification.prediction import robot_torques
from pe_drake.identification.preprocessing import PreprocessOptions
from pe_drake.identification.readers import read_log
from pe_drake.identification.time_window import TimeWindow
from pe_drake.multibody.robot import Robot


def read_measurements(robot: Robot, path: str | Path, options: DataConfig | None = None, *,
                      progress: Callable[[str], None] | None = None, **changes) -> Measurement:
    """Reads a measured run of ``robot`` and checks it before any work.

    Args:
        path: pe_drake's CSV, a ROS 2 bag (folder, ``.db3``, ``.mcap``), a UR RTDE CSV, or a CSV
            read through ``options.columns``.
        options: the config's ``data`` section.
        progress: called with :meth:`~Measurement.summary_lines` once the run is read and checked.
        **changes: fields of ``options`` to override (``format=``, ``topic=``, ``effort=``).

    Returns:
        The raw Measurement, joints in the robot's order, with the ``notes`` reading left.

    Raises:
        DataError: an unreadable file, or data that fails the checks (time in ms, positions in
            degrees, ...), naming the file, the column or topic and the row.
        ConfigError: an unknown format or option.
    """
    measurement = read_log(path, robot, options, **changes)
    check_raw_measurement(robot, measurement)  # time units, positions (degrees)
    for line in measurement.summary_lines() if progress is not None else ():
        progress(line)
    return measurement


#: Output rate of the preprocessing [Hz]: the regressor is smooth, 200 Hz is plenty.
DEFAULT_RATE_HZ = 200.0


def read_robot_measurement(robot: Robot, path: str | Path) -> Measurement:
    """Reads a measurement CSV for ``robot``'s excited joints (see measurements.py)."""
    return read_measurement_csv(path, robot.joint_names, min_rows=30)


def prepare_measurement(robot: Robot, measurement: Measurement, *, cutoff_hz: float | None = None,
                        fundamental_hz: float | None = None, harmonics: int | None = None,
                        rate_hz: float | None = DEFAULT_RATE_HZ, filtering: bool = True,
                        check_units: bool = True, max_gap_s: float = MAX_GAP_S,
                        window: TimeWindow | None = None) -> Measurement:
    """Checks the joints and torque units and preprocesses for identification.

    Args:
        cutoff_hz, fundamental_hz, harmonics, rate_hz: see
            :func:`pe_drake.identification.preprocessing.preprocess` (``rate_hz`` = ``decimate_to_hz``).
        filtering: False uses the data as it is; it must then hold v and vdot (exact,
            noise-free data, e.g. from :func:`pe_drake.simulation.synthetic.model_measurement`).
        check_units: compare the torques with the a-priori model (refuses N·mm or kN·m; a
            note when they look like motor currents).
        max_gap_s: longest hole in the time column interpolated [s]; longer ones split the
            run (:func:`~pe_drake.identification.gaps.preprocess_segments`).
        window: the part of the run kept, taken after the whole run is filtered; None: all.

    Raises:
        DataError: other joints than the robot's, missing v/vdot without filtering, torques
            off by orders of magnitude.
    """
    check_joints(robot, measurement.joints, file=measurement.source)
    if filtering:
        options = PreprocessOptions(cutoff_hz=cutoff_hz, fundamental_hz=fundamental_hz, harmonics=harmonics,
                                    decimate_to_hz=rate_hz)
        data = preprocess_segments(measurement, options, max_gap_s)
    else:
        if measurement.v is None or measurement.vd is None:
            raise DataError("without filtering the data must hold v.<joint> and vdot.<joint> "
                            "columns", file=measurement.source)
        data = measurement
    if window is not None:
        data = window.apply(data)
    if check_units and data.tau is not None:
        ratios = check_torque_units(data, robot_torques(robot, data, robot.phi_model))
        hint = amps_hint(data, ratios)
        if hint:
            data = data.replace(notes=data.notes + (hint,))
    return data
