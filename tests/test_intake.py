"""``pe_drake.read_measurements`` is the one door for measured files: the library refuses what the
CLI refuses (positions in degrees here), naming the file."""

from __future__ import annotations

import numpy as np
import pytest

import pe_drake
from pe_drake.exceptions import DataError
from pe_drake.identification.measurements import Measurement, measurement_to_csv_text


def _log(robot, q_scale: float) -> Measurement:
    t = np.arange(0, 4, 0.001)
    mid = 0.5 * (robot.limits.q_lower + robot.limits.q_upper)
    q = (mid + 0.1 * np.sin(np.outer(t, np.arange(1, robot.n + 1)))) * q_scale
    tau = np.tile(np.linspace(1, 2, robot.n), (t.size, 1)) + 0.1 * np.sin(t)[:, None]
    return Measurement(t=t, q=q, v=None, vd=None, tau=tau, joints=tuple(robot.joint_names))


@pytest.fixture(scope="module")
def panda():
    return pe_drake.load_robot("panda")


def test_library_door_refuses_positions_in_degrees(panda, tmp_path):
    path = tmp_path / "degrees.csv"
    path.write_text(measurement_to_csv_text(_log(panda, 180 / np.pi)))
    with pytest.raises(DataError, match="degrees.csv"):
        pe_drake.read_measurements(panda, path)


def test_library_door_reads_a_plain_log(panda, tmp_path):
    path = tmp_path / "run.csv"
    path.write_text(measurement_to_csv_text(_log(panda, 1.0)))
    m = pe_drake.read_measurements(panda, path)
    assert m.joints == panda.joint_names and m.num_samples == 4000
