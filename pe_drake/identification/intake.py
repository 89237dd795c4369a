"""The one door for measured files: :func:`read_measurements` reads any supported log and runs
the raw-data checks, so the library refuses what the CLI refuses."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from pe_drake.config import DataConfig
from pe_drake.identification.data_checks import check_raw_measurement
from pe_drake.identification.measurements import Measurement
from pe_drake.identification.readers import read_log
from pe_drake.multibody.robot import Robot


def read_measurements(robot: Robot, path: str | Path, options: DataConfig | None = None, *,
                      progress: Callable[[str], None] | None = None, **changes) -> Measurement:
    """Reads a measured run of ``robot`` and checks it before any work.

    Args:
        robot: the :class:`~pe_drake.multibody.robot.Robot` (its excited joints, drive gains).
        path: pe_drake's CSV, a ROS 2 bag (folder, ``.db3``, ``.mcap``), a UR RTDE CSV, or a CSV
            read through ``options.columns``.
        options: the config's ``data`` section (:class:`~pe_drake.config.DataConfig`).
        progress: called with :meth:`~Measurement.summary_lines` once the run is read and checked.
        **changes: fields of ``options`` to override (``format=``, ``topic=``, ``effort=``).

    Returns:
        The raw :class:`~pe_drake.identification.measurements.Measurement`, joints in the robot's
        order, with the ``notes`` reading left (interpolated holes, dropped messages).

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
