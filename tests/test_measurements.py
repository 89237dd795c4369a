"""Measurement CSV format, its validation, the torque-unit check and preprocessing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pe_drake.exceptions import ConfigError, DataError
from pe_drake.excitation.fourier import FourierTrajectory
from pe_drake.identification.measurements import (
    Measurement,
    check_torque_units,
    read_measurement_csv,
    write_measurement_csv,
)
from pe_drake.identification.lowpass import design_lowpass
from pe_drake.identification.preprocessing import (
    PreprocessOptions,
    choose_cutoff,
    decimation_step,
    fill_derivatives,
    motion_bandwidth_hz,
    preprocess,
    resample_uniform,
    trim_indices,
)

JOINTS = ("j1", "j2", "j3")
GAZ = Path(__file__).resolve().parents[1].parent / "shared" / "datasets" / "panda_gaz2019" / "excitation_1.csv"
PANDA_JOINTS = tuple(f"panda_joint{i}" for i in range(1, 8))


def _write(path: Path, header: list[str], rows: list[list]) -> Path:
    lines = [",".join(header)] + [",".join(str(x) for x in row) for row in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def _table(rows: int = 20, joints=JOINTS) -> tuple[list[str], list[list]]:
    header = ["t"] + [f"q.{j}" for j in joints] + [f"tau.{j}" for j in joints]
    data = [[0.001 * k] + [0.1 * k + j for j in range(len(joints))] + [1.0 + j for j in range(len(joints))]
            for k in range(rows)]
    return header, data


def _fourier(n: int = 3, harmonics: int = 4, period: float = 5.0, seed: int = 0) -> FourierTrajectory:
    rng = np.random.default_rng(seed)
    return FourierTrajectory(rng.uniform(-0.3, 0.3, (n, harmonics)), rng.uniform(-0.3, 0.3, (n, harmonics)),
                             rng.uniform(-1, 1, n), 2 * np.pi / period)


# ---- reading and writing -------------------------------------------------------------------


def test_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, 50))
    m = Measurement(t, rng.normal(size=(50, 3)), rng.normal(size=(50, 3)), rng.normal(size=(50, 3)),
                    rng.normal(size=(50, 3)), JOINTS)
    path = tmp_path / "m.csv"
    write_measurement_csv(path, m)
    back = read_measurement_csv(path, JOINTS)
    for name in ("t", "q", "tau", "v", "vd"):
        np.testing.assert_allclose(getattr(back, name), getattr(m, name), rtol=1e-9, atol=1e-12)
    assert back.joints == JOINTS and back.source == str(path)
    assert not list(tmp_path.glob(".*tmp"))  # no temporary left behind


def test_column_order_extra_columns_and_joint_order(tmp_path):
    header, data = _table()
    # Reverse the column order and add unrelated columns; joints asked in another order.
    header = ["comment", *reversed(header), "temperature"]
    data = [["x", *reversed(row), 25.0] for row in data]
    m = read_measurement_csv(_write(tmp_path / "m.csv", header, data), ("j3", "j1", "j2"))
    assert m.joints == ("j3", "j1", "j2")
    np.testing.assert_allclose(m.q[:, 0], [0.1 * k + 2 for k in range(20)])
    assert m.v is None and m.vd is None


def test_accepts_a_robot_for_joints(tmp_path):
    class FakeRobot:
        joint_names = JOINTS

    header, data = _table()
    assert read_measurement_csv(_write(tmp_path / "m.csv", header, data), FakeRobot()).joints == JOINTS


def test_missing_file(tmp_path):
    with pytest.raises(DataError, match="does not exist") as err:
        read_measurement_csv(tmp_path / "nope.csv", JOINTS)
    assert err.value.file.endswith("nope.csv")


def test_empty_file(tmp_path):
    (tmp_path / "e.csv").write_text("\n\n")
    with pytest.raises(DataError, match="empty"):
        read_measurement_csv(tmp_path / "e.csv", JOINTS)


def test_missing_column_lists_expected(tmp_path):
    header, data = _table()
    k = header.index("tau.j2")
    header.pop(k)
    for row in data:
        row.pop(k)
    with pytest.raises(DataError) as err:
        read_measurement_csv(_write(tmp_path / "m.csv", header, data), JOINTS)
    assert err.value.column == "tau.j2"
    assert "expected columns: t, q.j1, q.j2, q.j3, tau.j1, tau.j2, tau.j3" in str(err.value)


def test_column_of_unknown_joint_names_valid_joints(tmp_path):
    header, data = _table()
    header.append("q.finger")
    for row in data:
        row.append(0.0)
    with pytest.raises(DataError) as err:
        read_measurement_csv(_write(tmp_path / "m.csv", header, data), JOINTS)
    assert err.value.column == "q.finger"
    assert "valid joints: j1, j2, j3" in str(err.value)


def test_duplicated_column(tmp_path):
    header, data = _table()
    header.append("q.j1")
    for row in data:
        row.append(0.0)
    with pytest.raises(DataError, match="appears twice"):
        read_measurement_csv(_write(tmp_path / "m.csv", header, data), JOINTS)


def test_velocity_for_some_joints_only(tmp_path):
    header, data = _table()
    header += ["v.j1", "v.j2"]
    for row in data:
        row += [0.0, 0.0]
    with pytest.raises(DataError, match="for some joints") as err:
        read_measurement_csv(_write(tmp_path / "m.csv", header, data), JOINTS)
    assert err.value.column == "v.j3"


@pytest.mark.parametrize("bad", ["abc", "", "nan", "inf", "-inf", "NaN"])
def test_bad_value_names_column_and_row(tmp_path, bad):
    header, data = _table()
    data[6][header.index("tau.j2")] = bad  # data row 7 = line 8 of the file
    with pytest.raises(DataError) as err:
        read_measurement_csv(_write(tmp_path / "m.csv", header, data), JOINTS)
    assert err.value.column == "tau.j2"
    assert err.value.row == 7
    assert "line 8" in str(err.value)
    assert "row 7" in str(err.value)


def test_row_numbers_skip_blank_lines_but_line_numbers_do_not(tmp_path):
    header, data = _table()
    data[3][1] = "oops"
    path = _write(tmp_path / "m.csv", header, data)
    lines = path.read_text().splitlines()
    lines.insert(2, "")  # blank line after the first data row
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError) as err:
        read_measurement_csv(path, JOINTS)
    assert err.value.row == 4 and "line 6" in str(err.value)


def test_ragged_row(tmp_path):
    header, data = _table()
    data[4] = data[4][:-1]
    with pytest.raises(DataError, match="fields where the header has") as err:
        read_measurement_csv(_write(tmp_path / "m.csv", header, data), JOINTS)
    assert err.value.row == 5


@pytest.mark.parametrize("value, kind", [(0.004, "duplicated"), (0.002, "decreasing")])
def test_time_must_increase(tmp_path, value, kind):
    header, data = _table()
    data[5][0] = value  # row 5 has t = 0.004 (row 5 is data row 6)
    with pytest.raises(DataError, match=kind) as err:
        read_measurement_csv(_write(tmp_path / "m.csv", header, data), JOINTS)
    assert err.value.column == "t" and err.value.row == 6


def test_too_few_rows(tmp_path):
    header, data = _table(rows=5)
    path = _write(tmp_path / "m.csv", header, data)
    with pytest.raises(DataError, match="only 5 data rows; at least 10"):
        read_measurement_csv(path, JOINTS)
    assert read_measurement_csv(path, JOINTS, min_rows=5).num_samples == 5


def test_measurement_shape_check():
    with pytest.raises(DataError, match="tau has shape"):
        Measurement(np.arange(3.0), np.zeros((3, 2)), np.zeros((2, 2)), joints=("a", "b"))


def test_refuses_to_write_nan(tmp_path):
    m = Measurement(np.arange(3.0), np.zeros((3, 1)), np.array([[0.0], [np.nan], [0.0]]), joints=("a",))
    with pytest.raises(DataError, match="not finite") as err:
        write_measurement_csv(tmp_path / "m.csv", m)
    assert err.value.column == "tau.a" and err.value.row == 2
    assert not (tmp_path / "m.csv").exists()


# ---- torque units --------------------------------------------------------------------------


def _units_case():
    rng = np.random.default_rng(2)
    pred = np.column_stack(
        [20 + 5 * rng.normal(size=200), 8 * rng.normal(size=200), 0.01 * rng.normal(size=200)]
    )
    meas = pred * 1.1 + 0.05 * rng.normal(size=pred.shape)
    meas[:, 2] += 0.5 * np.sign(rng.normal(size=200))  # friction-dominated light joint: ratio ~50
    return Measurement(np.arange(200.0), np.zeros((200, 3)), meas, joints=JOINTS, source="run.csv"), pred


def test_torque_units_accepts_consistent_data():
    m, pred = _units_case()
    ratios = check_torque_units(m, pred)
    assert ratios.shape == (3,) and 1.0 < ratios[0] < 1.2 and ratios[2] > 30


@pytest.mark.parametrize("scale, hint", [(1000.0, "N·mm"), (1e-3, "kN·m")])
def test_torque_units_refuses_all_columns_scaled(scale, hint):
    m, pred = _units_case()
    with pytest.raises(DataError, match=hint) as err:
        check_torque_units(m.replace(tau=m.tau * scale), pred)
    assert err.value.file == "run.csv" and err.value.column.startswith("tau.")


def test_torque_units_refuses_one_column_scaled():
    m, pred = _units_case()
    tau = m.tau.copy()
    tau[:, 1] *= 1000
    with pytest.raises(DataError, match="divide the torques by 1000") as err:
        check_torque_units(m.replace(tau=tau), pred)
    assert err.value.column == "tau.j2"


# ---- preprocessing -------------------------------------------------------------------------


def _synthetic(rate=1000.0, duration=12.0, jitter=0.3, noise=1e-4, seed=0):
    """Fourier motion sampled with jittered time, noisy q; tau = 2·q + 1 (a linear map, to
    check that q and tau get the same filter)."""
    rng = np.random.default_rng(seed)
    traj = _fourier(seed=seed)
    steps = (1 + jitter * rng.uniform(-1, 1, int(duration * rate))) / rate
    t = np.concatenate([[0.0], np.cumsum(steps)])
    q, v, vd = traj.evaluate(t)
    q_meas = q + noise * rng.normal(size=q.shape)
    m = Measurement(t, q_meas, 2 * q_meas + 1, joints=JOINTS)
    return m, traj


def test_preprocess_recovers_derivatives_from_nonuniform_noisy_q():
    m, traj = _synthetic()
    f0 = traj.omega / (2 * np.pi)
    p = preprocess(m, fundamental_hz=f0, harmonics=traj.harmonics)
    info = p.preprocessing
    assert info.resampled and info.cutoff_source == "trajectory"
    assert info.cutoff_hz == pytest.approx(max(5 * 4 * f0, 4.0))
    assert info.rate_hz == pytest.approx(200.0, rel=2e-3)  # median step of jittered time
    assert np.allclose(np.diff(p.t), 1 / info.rate_hz)
    assert p.t[0] >= m.t[0] + info.trim_s - 1e-9 and p.t[-1] <= m.t[-1] - info.trim_s + 1e-9
    q, v, vd = traj.evaluate(p.t)
    scale = lambda x: np.abs(x).max()  # noqa: E731
    assert np.abs(p.q - q).max() < 1e-3 * scale(q)
    assert np.abs(p.v - v).max() < 5e-3 * scale(v)
    assert np.abs(p.vd - vd).max() < 3e-2 * scale(vd)
    np.testing.assert_allclose(p.tau, 2 * p.q + 1, atol=1e-9)  # same filter on q and tau
    assert info.velocity_source == info.acceleration_source == "differentiated"


def test_preprocess_cutoff_from_spectrum_and_argument():
    m, traj = _synthetic(jitter=0.0)
    highest = traj.harmonics * traj.omega / (2 * np.pi)  # 0.8 Hz
    p = preprocess(m)
    assert not p.preprocessing.resampled
    assert p.preprocessing.cutoff_source == "spectrum"
    assert highest * 0.5 <= motion_bandwidth_hz(m.t, m.q) <= highest * 1.5
    assert 4.0 <= p.preprocessing.cutoff_hz <= 5 * 1.5 * highest
    p = preprocess(m, cutoff_hz=12.0, decimate_to_hz=None, trim_s=0.1)
    info = p.preprocessing
    assert (info.cutoff_source, info.cutoff_hz, info.trim_s) == ("argument", 12.0, 0.1)
    assert info.rate_hz == pytest.approx(1000.0)


def test_preprocess_keeps_measured_velocity_and_never_aliases():
    m, traj = _synthetic(jitter=0.0)
    _, v, _ = traj.evaluate(m.t)
    p = preprocess(m.replace(v=v), cutoff_hz=40.0, decimate_to_hz=50.0)
    assert p.preprocessing.velocity_source == "measured"
    assert p.preprocessing.acceleration_source == "differentiated"
    assert 0.5 * p.preprocessing.rate_hz >= 1.25 * 40.0  # decimation reduced to stay alias-free


def test_step_functions_chain_to_preprocess():
    """The public steps, chained by hand, give exactly what preprocess gives."""
    m, traj = _synthetic()
    f0 = traj.omega / (2 * np.pi)
    p = preprocess(m, PreprocessOptions(fundamental_hz=f0, harmonics=traj.harmonics))
    grid = resample_uniform(m.t, {"q": m.q, "tau": m.tau})
    assert grid.resampled and np.allclose(np.diff(grid.t), grid.dt)
    cutoff = choose_cutoff(grid.t, grid.signals["q"], grid.rate_hz, fundamental_hz=f0, harmonics=traj.harmonics)
    assert cutoff.source == "trajectory"
    lowpass = design_lowpass(cutoff.hz, grid.rate_hz, len(grid.t))
    q, tau = lowpass.apply(grid.signals["q"]), lowpass.apply(grid.signals["tau"])
    d = fill_derivatives(q, grid.dt)
    step = decimation_step(grid.rate_hz, 200.0, cutoff.hz)
    idx = trim_indices(grid.t, lowpass.edge_transient_s(), step)
    for name, x in (("t", grid.t), ("q", q), ("tau", tau), ("v", d.v), ("vd", d.vd)):
        np.testing.assert_array_equal(getattr(p, name), x[idx], err_msg=name)
    assert (d.velocity_source, d.acceleration_source) == ("differentiated", "differentiated")


def test_default_trim_is_what_the_filter_needs():
    """Issue 13: the default trim drops the samples where the edge transient spoils the
    accelerations (5 % of the end acceleration), about 0.7 / cut-off instead of 2 / cut-off;
    a record's accelerations beyond it are right, within it they are not."""
    m, traj = _synthetic(jitter=0.0, noise=0.0)
    f0 = traj.omega / (2 * np.pi)
    p = preprocess(m, fundamental_hz=f0, harmonics=traj.harmonics, decimate_to_hz=None)
    info = p.preprocessing
    assert 0.6 / info.cutoff_hz < info.trim_s < 0.8 / info.cutoff_hz
    assert info.duration_in_s == pytest.approx(m.t[-1] - m.t[0])
    assert info.duration_out_s == pytest.approx(info.duration_in_s - 2 * info.trim_s, abs=2e-3)
    _, _, vd = traj.evaluate(p.t)
    end_acc = np.abs(traj.evaluate(m.t[[0, -1]])[2]).max()
    assert np.abs(p.vd - vd).max() < 0.05 * end_acc + 0.01 * np.abs(vd).max()
    full = preprocess(m, fundamental_hz=f0, harmonics=traj.harmonics, decimate_to_hz=None, trim_s=0.0)
    _, _, vd_all = traj.evaluate(full.t)
    assert np.abs(full.vd - vd_all).max() > 0.2 * end_acc  # the ends do need trimming


def test_lowpass_white_noise_gain_matches_filtered_noise():
    lowpass = design_lowpass(10.0, 1000.0, 200000)
    noise = np.random.default_rng(0).normal(size=200000)
    assert np.var(lowpass.apply(noise)) == pytest.approx(lowpass.white_noise_gain(), rel=0.05)
    assert lowpass.padlen == 300  # three periods of the cut-off
    with pytest.raises(DataError, match="the filter needs more than 15"):
        design_lowpass(10.0, 1000.0, 15, file="x.csv")


def test_decimation_step_stays_alias_free():
    assert decimation_step(1000.0, None, 10.0) == 1
    assert decimation_step(1000.0, 200.0, 10.0) == 5
    assert decimation_step(1000.0, 50.0, 40.0) == 10  # 0.5·1000/10 = 50 ≥ 1.25·40
    assert decimation_step(1000.0, 20.0, 40.0) == 10


def test_preprocess_refuses_options_and_fields_together():
    m, _ = _synthetic(duration=4.0, jitter=0.0)
    with pytest.raises(ConfigError, match="not both"):
        preprocess(m, PreprocessOptions(), cutoff_hz=10.0)


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(cutoff_hz=-1.0), ConfigError, "cutoff_hz must be positive"),
        (dict(cutoff_hz=600.0), ConfigError, "Nyquist"),
        (dict(fundamental_hz=0.2), ConfigError, "both fundamental_hz and harmonics"),
        (dict(fundamental_hz=0.2, harmonics=0), ConfigError, "harmonics must be a positive integer"),
        (dict(trim_s=-0.1), ConfigError, "trim_s"),
        (dict(decimate_to_hz=0.0), ConfigError, "decimate_to_hz"),
        (dict(filter_order=0), ConfigError, "filter_order"),
        (dict(trim_s=10.0), DataError, "nothing left after trimming"),
    ],
)
def test_preprocess_errors(kwargs, error, match):
    m, _ = _synthetic(duration=4.0, jitter=0.0)
    with pytest.raises(error, match=match):
        preprocess(m, **kwargs)


def test_preprocess_too_few_samples():
    m = Measurement(np.arange(10.0), np.zeros((10, 1)), np.zeros((10, 1)), joints=("a",), source="s.csv")
    with pytest.raises(DataError, match="at least 30"):
        preprocess(m)


# ---- the real Panda recording --------------------------------------------------------------


@pytest.fixture(scope="module")
def gaz():
    if not GAZ.is_file():
        pytest.skip(f"{GAZ} is absent (shared dataset folder not mounted)")
    return read_measurement_csv(GAZ, PANDA_JOINTS)


def test_real_recording_reads(gaz):
    assert gaz.num_samples == 20544 and gaz.v is not None and gaz.vd is None
    assert 20.9 < gaz.duration < 21.1
    assert np.all(np.diff(gaz.t) > 0)


def test_real_recording_preprocess(gaz):
    p = preprocess(gaz)
    info = p.preprocessing
    assert info.resampled  # steps of 0.7-8.8 ms
    assert info.cutoff_source == "spectrum" and 4.0 <= info.cutoff_hz <= 10.0
    assert info.rate_hz == pytest.approx(200.0, rel=1e-6)
    # Velocity differentiated from the filtered positions agrees with the robot's own.
    q_only = preprocess(gaz.replace(v=None), cutoff_hz=info.cutoff_hz)
    err = np.sqrt(np.mean((q_only.v - p.v) ** 2, axis=0))
    assert np.all(err < 0.03 * np.sqrt(np.mean(p.v**2, axis=0)))


def test_real_recording_units_against_panda_model(gaz):
    from pe_drake.multibody.robot import load_robot

    panda = load_robot("panda")
    p = preprocess(gaz)
    sub = p.replace(t=p.t[::10], q=p.q[::10], tau=p.tau[::10], v=p.v[::10], vd=p.vd[::10])
    pred = panda.inverse_dynamics(sub.q, sub.v, sub.vd)
    check_torque_units(sub, pred)  # N·m: accepted
    with pytest.raises(DataError, match="N·mm"):
        check_torque_units(sub.replace(tau=sub.tau * 1000), pred)
