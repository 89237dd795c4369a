"""Hour-long logs in bounded memory: the CSV read as a stream, filtered a column at a time, the
regressor folded block by block (``identification.folded_rows``), and a diagnosis that cannot
fit refused before it starts.

Before: identify held 5.4 kB per 1 kHz row (2.1 GB for a 6-minute Panda log; 12 GB for an hour)
and diagnose crashed at 15 GB on an hour.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pe_drake.bench_memory import peak_of, write_long_log
from pe_drake.cli import main
from pe_drake.diagnosis import record
from pe_drake.exceptions import ConfigError, DataError
from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.multibody.drive_columns import DriveTermOptions, drive_columns, drive_layout
from pe_drake.identification.estimators import identify
from pe_drake.identification.intake import prepare_measurement
from pe_drake.identification.measurements import read_measurement_csv
from pe_drake.identification.lowpass import design_lowpass
from pe_drake.multibody import load_robot
from pe_drake.multibody.base_parameters import compute_base_parameters
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.simulation.synthetic import model_measurement

DATA = Path(__file__).parent / "data"


@pytest.mark.slow
def test_identify_memory_per_row_is_bounded(tmp_path):
    """Peak memory of `pe-drake identify` on 2- and 6-minute 1 kHz logs: the difference per row
    (the cost that grows with the log) stays below 0.6 kB, so an hour fits in 2 GB."""
    peaks = {}
    for minutes in (2, 6):
        log = tmp_path / f"log{minutes}.csv"
        rows = write_long_log(log, minutes)
        peak, _, code = peak_of(["identify", "--robot", "panda", "--data", str(log), "--out", str(tmp_path / f"o{minutes}")])
        assert code == 0
        peaks[minutes] = (peak, rows)
    (p2, r2), (p6, r6) = peaks[2], peaks[6]
    per_row = (p6 - p2) * 1e6 / (r6 - r2)
    assert per_row < 600, f"{per_row:.0f} B per row ({p2:.0f} MB at 2 min, {p6:.0f} MB at 6 min)"
    assert p2 + per_row * (3_600_000 - r2) / 1e6 < 2000


def _panda_run(seconds: float = 20.0, seed: int = 3):
    robot = load_robot("panda")
    trajectory, _ = load_trajectory(DATA / "panda_optimized.json")
    m = model_measurement(robot, trajectory, rate_hz=1000.0, duration=seconds, tau_noise_std=0.05, seed=seed)
    tau = m.tau + 0.8 * np.tanh(m.v / 0.01) + 0.3 * m.v + 0.1
    return robot, prepare_measurement(robot, m.replace(tau=tau, v=None, vd=None))


def test_folded_fit_equals_the_fit_on_all_rows():
    """OLS on the folded rows against numpy's lstsq on every row stacked (an independent path)."""
    robot, data = _panda_run()
    result = identify(robot, data, "ols", drive_terms="friction")
    model = RegressorModel(robot)
    base = compute_base_parameters(robot, model=model)
    YB = base.reduce(model(data.q, data.v, data.vd))
    layout = drive_layout(robot, None, DriveTermOptions("friction", result.drive_layout.velocity_scale))
    D = drive_columns(data.v, data.vd, layout)
    S, n, _ = YB.shape
    W = np.concatenate([YB, D], axis=2).reshape(S * n, -1)
    x = np.linalg.lstsq(W, data.tau.reshape(S * n), rcond=None)[0]
    assert np.allclose(result.phi_B, x[: base.count], rtol=1e-8, atol=1e-10 * np.abs(x).max())
    residual = data.tau - (W @ x).reshape(S, n)
    assert np.allclose(result.residual_rms, np.sqrt(np.mean(residual**2, axis=0)), rtol=1e-9)


def test_columnwise_filter_is_the_same_filter():
    from scipy.signal import sosfiltfilt

    lowpass = design_lowpass(4.0, 1000.0, 20000, 4)
    x = np.random.default_rng(0).normal(size=(20000, 5))
    assert np.array_equal(lowpass.apply(x), sosfiltfilt(lowpass.sos, x, axis=0, padtype="odd", padlen=lowpass.padlen))


def test_a_line_longer_than_the_limit_is_refused_by_number(tmp_path, monkeypatch):
    path = tmp_path / "long.csv"
    robot = load_robot("panda")
    header = ",".join(["t"] + [f"q.{j}" for j in robot.joint_names] + [f"tau.{j}" for j in robot.joint_names])
    row = ",".join(["0"] * 15)
    path.write_text(header + "\n" + row + "\n" + "1" * (2**20 + 10) + "\n")
    with pytest.raises(DataError, match=r"line 3 is longer than 1,048,576 characters, the 1 MB limit \(PE_DRAKE_MAX_CSV_LINE_MB"):
        read_measurement_csv(path, robot.joint_names)
    monkeypatch.setenv("PE_DRAKE_MAX_CSV_LINE_MB", "2")  # the setting named in the message
    with pytest.raises(DataError, match=r"fields where the header has"):  # read now, and refused for its content
        read_measurement_csv(path, robot.joint_names)
    monkeypatch.setenv("PE_DRAKE_MAX_CSV_LINE_MB", "lots")
    with pytest.raises(ConfigError, match="PE_DRAKE_MAX_CSV_LINE_MB='lots'"):
        read_measurement_csv(path, robot.joint_names)


def test_diagnose_keeps_single_joint_columns_once_and_long_ones_in_float32(monkeypatch):
    """The candidate columns (one joint each) are one series, not an (S, n) block; the stored
    columns of a long segment are float32 with the Gram matrices of the float64 columns."""
    from pe_drake.diagnosis import columns, regression

    rng = np.random.default_rng(1)
    S, n, b = 500, 3, 4
    dense, y = rng.normal(size=(S, n, b + 1)), rng.normal(size=(S, n))
    single = {b + 1 + j: (j, rng.normal(size=S)) for j in range(n)}  # one candidate per joint
    full = np.zeros((S, n, b + 1 + n))
    full[:, :, : b + 1] = dense
    for c, (j, values) in single.items():
        full[:, j, c] = values
    ref = regression.Columns.from_matrix(full, y)

    def fill(rows, out):
        out[...] = dense[rows]

    for threshold, dtype in ((1e12, np.float64), (0.0, np.float32)):
        monkeypatch.setattr(columns, "LONG_LOG_BYTES", threshold)
        cols = regression.Columns.assemble(y, b + 1 + n, range(b + 1), fill, single, chunk=128)
        assert cols.A.shape == (S, n, b + 1) and cols.A.dtype == dtype
        np.testing.assert_allclose(cols.gram, ref.gram, rtol=1e-12, atol=1e-10)  # float64 sums either way
        np.testing.assert_allclose(cols.rhs, ref.rhs, rtol=1e-12, atol=1e-10)
        x = rng.normal(size=b + 1 + n)
        np.testing.assert_allclose(cols.product(range(b + 1 + n), x), full @ x, rtol=0, atol=1e-5)
        np.testing.assert_allclose(cols.joint_dot(1, y[:, 1]), y[:, 1] @ full[:, 1, :], rtol=1e-6, atol=1e-5)
        np.testing.assert_allclose(cols.block(slice(None)), full, atol=1e-6)


class _Hour:
    duration, rate_hz, num_joints, source = 3600.0, 1000.0, 7, "hour.csv"


def test_a_diagnosis_that_cannot_fit_is_refused_with_the_figure():
    with pytest.raises(DataError, match=r"diagnose would need about 5\.3 GB for 60\.0 min .* 6\.0 GB available"):
        record.check_fits_in_memory(_Hour(), None, available=6_000_000_000)
    record.check_fits_in_memory(_Hour(), None, available=40_000_000_000)  # a bigger machine runs it


def test_the_cli_refuses_before_any_work(tmp_path, monkeypatch, capsys):
    log = tmp_path / "log.csv"
    write_long_log(log, 0.5)
    monkeypatch.setattr(record, "available_bytes", lambda: 300_000_000)
    assert main(["diagnose", "--robot", "panda", "--data", str(log), "--out", str(tmp_path / "out")]) == 2
    assert "diagnose would need about" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
