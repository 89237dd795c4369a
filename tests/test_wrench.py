"""The ground-wrench rows (issue 14): Drake's weld reaction, rank, recovery, adjoint."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import ground_wrench, random_states

from pe_drake.exceptions import ConfigError
from pe_drake.multibody.base_parameters import RANK_GAP_RATIO
from pe_drake.multibody.registry import builtin_config
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.robot import load_robot
from pe_drake.multibody.sensors import MEASUREMENTS, WRENCH_RANK_TOLERANCE, MeasurementType, SensorRows
from pe_drake.multibody.wrench import WRENCH_COLUMNS, static_wrench, weld_reaction_wrench

WAIST = ["waist_yaw_joint", "waist_roll_joint", "waist_pitch_joint"]
_ROBOTS: dict = {}


def g1_variant(waist: bool):
    """G1 with the arms (and the waist) excited, without capsules.

    The capsules are collision geometry: Drake's forward dynamics (used for the weld
    reaction) adds contact forces where random states make them overlap.
    """
    if waist not in _ROBOTS:
        cfg = builtin_config("g1").robot
        joints = (WAIST if waist else []) + list(cfg.joints)
        _ROBOTS[waist] = load_robot(dataclasses.replace(cfg, joints=joints, capsules=""))
    return _ROBOTS[waist]


@pytest.mark.parametrize("waist", [False, True], ids=["arms", "arms+waist"])
def test_wrench_rows_equal_drake_weld_reaction(waist):
    robot = g1_variant(waist)
    model = RegressorModel(robot)
    q, v, vd = random_states(robot, 6, seed=3)
    rows = model.wrench_regressor(model.kinematics(q, v, vd))
    assert rows.shape == (6, 6, 10 * robot.num_bodies)
    predicted = rows @ robot.phi_model + static_wrench(robot)
    drake = weld_reaction_wrench(robot, q, v, vd)
    assert np.abs(predicted - drake).max() < 1e-9 * max(1.0, np.abs(drake).max())
    # The arms move the wrench: it is not only the robot's weight.
    assert np.ptp(drake[:, 3:], axis=0).max() > 1.0


def test_wrench_rows_of_arbitrary_parameters_are_newton_euler_sums(g1):
    """Each body's 10 columns are its world-frame Newton–Euler wrench per unit parameter."""
    model = RegressorModel(g1)
    q, v, vd = random_states(g1, 2, seed=5)
    kin = model.kinematics(q, v, vd)
    rows = model.wrench_regressor(kin)
    phi = np.random.default_rng(0).normal(size=model.num_params)
    F = np.einsum("tjak,jk->ta", kin.F_W, phi.reshape(-1, 10))  # [n; f] summed over bodies
    assert np.allclose(rows @ phi, np.concatenate([F[:, 3:], F[:, :3]], axis=1), rtol=0, atol=1e-12)


@pytest.mark.parametrize("waist, expected", [(False, (90, 96)), (True, (113, 118))], ids=["arms", "arms+waist"])
def test_rank_of_wrench_rows(waist, expected):
    """The wrench identifies every torque-identifiable parameter and some the torques miss.

    Issue 14 quoted 97 (arms) and 120 (arms + waist). Measured here at the joint-torque
    tolerance: 97 and 118; the arms' 97th direction is 1.5e-4 of the strongest on R's
    diagonal (WRENCH_RANK_TOLERANCE drops it), the next one 0.39.
    """
    robot = g1_variant(waist)
    model = RegressorModel(robot)
    counts = [SensorRows(model, MeasurementType(kind)).base_parameters().count for kind in MEASUREMENTS]
    assert tuple(counts[:2]) == expected
    assert counts[2] == expected[1]  # both = the union; the wrench already covers the torques
    exact = SensorRows(model, MeasurementType("base_wrench")).base_parameters(rank_tolerance=1e-8, gap_ratio=None)
    assert exact.count == expected[1] + (0 if waist else 1)
    d = np.sort(exact.diag_R)[::-1] / exact.diag_R.max()
    if not waist:
        assert d[95] > 0.1 and 1e-5 < d[96] < WRENCH_RANK_TOLERANCE


@pytest.mark.parametrize("tolerance", [1e-8, None], ids=["numerical rank 97", "default 96"])
def test_noise_free_identification_from_the_wrench(g1, tolerance):
    model = RegressorModel(g1)
    rows = SensorRows(model, MeasurementType("base_wrench"))
    base = rows.base_parameters(rank_tolerance=tolerance, gap_ratio=None if tolerance else RANK_GAP_RATIO)
    q, v, vd = random_states(g1, 40, seed=7)
    W = model.wrench_regressor(model.kinematics(q, v, vd))
    phi = g1.phi_model * np.random.default_rng(2).uniform(0.8, 1.2, model.num_params)
    w = W @ phi  # the measured wrench minus the static bodies' weight
    phi_B = np.linalg.lstsq(base.reduce(W).reshape(-1, base.count), w.ravel(), rcond=None)[0]
    truth = base.base_values(phi)
    # Exact with every numerically independent direction; without the nearly unobservable
    # 97th, what it does to the wrench (~1e-4 of the largest term) lands in the others.
    tol = 1e-8 if tolerance else 1e-4
    assert np.abs(phi_B - truth).max() < tol * np.abs(truth).max()
    # The base parameters predict the wrench of any other motion: K X = I and W X K = W.
    q2, v2, vd2 = random_states(g1, 5, seed=8)
    W2 = model.wrench_regressor(model.kinematics(q2, v2, vd2))
    assert np.abs(base.reduce(W2) @ phi_B - W2 @ phi).max() < tol * np.abs(W2 @ phi).max()
    # ... and the joint torques: what the torques identify, the wrench identifies too.
    Y2 = model(q2, v2, vd2)
    assert np.abs(Y2 @ (base.X @ phi_B) - Y2 @ phi).max() < tol * np.abs(Y2 @ phi).max()


@pytest.mark.parametrize("kind", ["base_wrench", "both"])
def test_sensor_rows_adjoint_matches_central_differences(g1, kind):
    rows = SensorRows(RegressorModel(g1), MeasurementType(kind, force_std=0.5, moment_std=0.05))
    q, v, vd = random_states(g1, 2, seed=11)
    kin = rows.kinematics(q, v, vd)
    Z = np.random.default_rng(1).normal(size=rows.rows(kin).shape)
    grads = rows.pullback(kin, Z)
    h = 1e-6
    rng = np.random.default_rng(4)
    for k in range(3):
        for _ in range(6):  # random entries of q, v, vdot
            t, i = rng.integers(2), rng.integers(g1.n)
            plus, minus = [q.copy(), v.copy(), vd.copy()], [q.copy(), v.copy(), vd.copy()]
            plus[k][t, i] += h
            minus[k][t, i] -= h
            numeric = (np.sum(Z * rows(*plus)) - np.sum(Z * rows(*minus))) / (2 * h)
            scale = max(1.0, np.abs(grads[k]).max())
            assert abs(grads[k][t, i] - numeric) < 1e-7 * scale, (k, t, i)


def test_rows_are_scaled_by_the_sensor_noise(g1):
    model = RegressorModel(g1)
    q, v, vd = random_states(g1, 2, seed=1)
    kin = model.kinematics(q, v, vd)
    both = SensorRows(model, MeasurementType("both", torque_std=2.0, force_std=0.5, moment_std=0.05))
    A = both.rows(kin)
    assert A.shape == (2, g1.n + 6, model.num_params)
    assert np.allclose(A[:, : g1.n], model.regressor(kin) / 2.0)
    assert np.allclose(A[:, g1.n : g1.n + 3], model.wrench_regressor(kin)[:, :3] / 0.5)
    assert np.allclose(A[:, g1.n + 3 :], model.wrench_regressor(kin)[:, 3:] / 0.05)
    assert both.measurement.row_names(g1.joint_names)[-6:] == WRENCH_COLUMNS


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"kind": "force_plate"}, "joint_torque, base_wrench, both"),
        ({"force_std": 0.0}, "force_std"),
        ({"moment_std": float("nan")}, "moment_std"),
        ({"torque_std": -1.0}, "torque_std"),
    ],
)
def test_bad_measurement_types_are_refused(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        MeasurementType(**kwargs)


def test_config_measurement_and_noise(tmp_path):
    from pe_drake.config import load_config
    from pe_drake.multibody.sensors import measurement_type

    path = tmp_path / "c.yaml"
    path.write_text("excitation: {measurement: base_wrench, noise_std: {force: 0.2, moment: 0.02}}\n")
    config = load_config(path)
    m = measurement_type(config.excitation)
    assert (m.kind, m.force_std, m.moment_std, m.torque_std) == ("base_wrench", 0.2, 0.02, 0.05)
    assert measurement_type(config.excitation, "both").kind == "both"
    path.write_text("excitation: {measurement: force_plate}\n")
    with pytest.raises(ConfigError, match="excitation.measurement 'force_plate'"):
        load_config(path)
    path.write_text("excitation: {noise_std: {moment: -1}}\n")
    with pytest.raises(ConfigError, match="excitation.noise_std.moment"):
        load_config(path)
    # One torque noise table for the row weights (issue 14) and the quality figures (issue 13).
    path.write_text("excitation: {measurement: both, noise_std: {torque: {all: 0.1, panda_joint2: 0.4}}}\n")
    m = measurement_type(load_config(path).excitation, joint_names=["panda_joint1", "panda_joint2"])
    assert m.torque_std == (0.1, 0.4)
    assert list(m.row_std(2)) == [0.1, 0.4, 0.5, 0.5, 0.5, 0.05, 0.05, 0.05]


def test_channels_of_a_run(g1):
    """Rows and values of each measurement type; a run without wrench is refused by name."""
    import types

    from pe_drake.exceptions import DataError
    from pe_drake.identification.channels import channel_names, measured_values

    q, v, vd = random_states(g1, 4, seed=2)
    model = RegressorModel(g1)
    wrench = ground_wrench(g1, g1.phi_model, q, v, vd)
    tau = model(q, v, vd) @ g1.phi_model
    data = types.SimpleNamespace(q=q, v=v, vd=vd, tau=tau, wrench=wrench, num_samples=4, source="run.csv")
    for kind in MEASUREMENTS:
        A = SensorRows(model, MeasurementType(kind)).rows(model.kinematics(q, v, vd), scaled=False)
        y = measured_values(g1, data, kind)
        assert A.shape[:2] == y.shape == (4, len(channel_names(g1, kind)))
        assert np.allclose(A @ g1.phi_model, y, rtol=0, atol=1e-9)
    assert channel_names(g1, "both")[-6:] == WRENCH_COLUMNS
    with pytest.raises(DataError, match=r"run.csv.*wrench.fx"):
        measured_values(g1, types.SimpleNamespace(**{**vars(data), "wrench": None}), "base_wrench")
    with pytest.raises(DataError, match="tau"):
        measured_values(g1, types.SimpleNamespace(**{**vars(data), "tau": None}), "both")
