"""Issue 22: real logs in: pauses and dropped packets, ROS 2 bags, UR RTDE logs with motor currents.

Every log is made from the Panda's (or UR5's) inverse dynamics along a Fourier trajectory with
white torque noise, and must be identified to its noise floor: the identified model predicts
the noise-free torques far more closely than the noise.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from pe_drake.cli import main as cli
from pe_drake.config import DataConfig, JointMapConfig
from pe_drake.exceptions import DataError
from pe_drake.excitation.fourier import FourierTrajectory
from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.identification.data_checks import check_raw_measurement
from pe_drake.identification.estimators import identify
from pe_drake.identification.intake import prepare_measurement
from pe_drake.identification.prediction import predict, robot_torques
from pe_drake.identification.gaps import longest_segment, split_at_pauses
from pe_drake.identification.readers import read_log
from pe_drake.simulation.synthetic import model_measurement

NOISE = 0.05  # [N·m]
REAL = next((p / "shared" / "datasets" / "panda_gaz2019" / "excitation_1.csv" for p in Path(__file__).resolve().parents
             if (p / "shared" / "datasets" / "panda_gaz2019" / "excitation_1.csv").is_file()),
            Path(__file__).resolve().parents[1] / ".." / "shared" / "datasets" / "panda_gaz2019" / "excitation_1.csv")


@pytest.fixture(scope="module")
def panda_run(panda):
    trajectory, _ = load_trajectory(Path(__file__).parent / "data" / "panda_optimized.json")
    return model_measurement(panda, trajectory, rate_hz=500.0, duration=14.0, tau_noise_std=NOISE, seed=3)


def prediction_error(robot, raw, max_gap_s: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """(RMS of the OLS model's prediction minus the noise-free torque, residual RMS) per joint [N·m]."""
    data = prepare_measurement(robot, raw, max_gap_s=max_gap_s)
    result = identify(robot, data, "ols")
    error = predict(robot, result, data) - robot_torques(robot, data, robot.phi_model)
    return np.sqrt(np.mean(error**2, axis=0)), result.residual_rms


def assert_noise_floor(robot, raw, max_gap_s: float = 0.02) -> None:
    """OLS on the prepared log predicts the noise-free torques to well below the noise, and its
    residual is the filtered noise only: the torque noise σ = NOISE, up to 10 %."""
    rms, residual = prediction_error(robot, raw, max_gap_s)
    print("prediction error RMS vs truth [N·m]:", rms.round(4), "residual", residual.round(4), "noise", NOISE)
    assert rms.max() < 0.25 * NOISE
    assert np.all(residual < 1.1 * NOISE)


# ---- pauses and dropped packets ----------------------------------------------------------------


def test_a_2s_pause_splits_the_run_and_both_segments_are_identified_to_the_noise_floor(panda, panda_run):
    m = panda_run
    keep = (m.t < 5.0) | (m.t >= 7.0)  # logging paused for 2 s while the robot moved on
    drops = np.isin(np.arange(m.num_samples), [*range(800, 805), *range(1500, 1506)])  # 12, 14 ms holes
    raw = m.replace(**{f: getattr(m, f)[keep & ~drops] for f in ("t", "q", "tau")}, v=None, vd=None)
    check_raw_measurement(panda, raw)  # refused before issue 22
    segments, notes = split_at_pauses(raw)
    assert len(segments) == 2 and any("2 hole(s)" in n for n in notes) and any("pause" in n for n in notes)
    data = prepare_measurement(panda, raw)
    assert data.preprocessing.segments == 2
    assert not np.any((data.t > 5.0) & (data.t < 7.0))
    assert_noise_floor(panda, raw)
    longest = longest_segment(raw)
    assert longest.t[0] >= 7.0 and "longest segment" in longest.notes[-1]


def test_interpolating_across_the_pause_would_not_reach_the_noise_floor(panda, panda_run):
    """The split matters: one filter across the pause invents the motion in between."""
    m = panda_run
    keep = (m.t < 5.0) | (m.t >= 7.0)
    raw = m.replace(**{f: getattr(m, f)[keep] for f in ("t", "q", "tau")}, v=None, vd=None)
    with pytest.raises(AssertionError):
        assert_noise_floor(panda, raw, max_gap_s=3.0)


# ---- ROS 2 bags -------------------------------------------------------------------------------


def write_joint_state_bag(path: Path, m, storage: str, *, prefix: str = "", seed: int = 0, zero_stamps: bool = False,
                          velocity: bool = False) -> None:
    """A bag of m as sensor_msgs/JointState: shuffled names per message, a gripper, duplicates, a partial message."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    JointState = ts.types["sensor_msgs/msg/JointState"]
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    rng = np.random.default_rng(seed)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    start = 1_700_000_000 * 10**9

    def message(stamp_ns, names, q, v, tau):
        stamp = Time(sec=0, nanosec=0) if zero_stamps else Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
        return JointState(header=Header(stamp=stamp, frame_id=""), name=list(names), position=np.asarray(q, float),
                          velocity=np.asarray(v, float), effort=np.asarray(tau, float))

    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conn = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=ts)
        other = writer.add_connection("/rosout_like", "std_msgs/msg/String", typestore=ts)
        writer.write(other, start, ts.serialize_cdr(ts.types["std_msgs/msg/String"](data="hi"), "std_msgs/msg/String"))
        names = [prefix + j for j in m.joints] + ["panda_finger_joint1"]
        for k in range(m.num_samples):
            stamp = start + int(round(m.t[k] * 1e9))
            order = rng.permutation(len(names))
            q = np.append(m.q[k], 0.04)[order]
            tau = np.append(m.tau[k], 1.0)[order]
            v = np.append(m.v[k], 0.0)[order] if velocity else []
            data = ts.serialize_cdr(message(stamp, np.array(names)[order], q, v, tau), JointState.__msgtype__)
            writer.write(conn, stamp + 300_000, data)
            if k % 97 == 5 and not zero_stamps:  # the same stamp again
                writer.write(conn, stamp + 400_000, data)
            if k % 50 == 0:  # the gripper alone, and a partial arm message
                grip = message(stamp, ["panda_finger_joint1"], [0.04], [], [1.0])
                writer.write(conn, stamp + 100_000, ts.serialize_cdr(grip, JointState.__msgtype__))
                part = message(stamp + 1000, [prefix + m.joints[0]], [m.q[k, 0]], [], [m.tau[k, 0]])
                writer.write(conn, stamp + 200_000, ts.serialize_cdr(part, JointState.__msgtype__))


@pytest.mark.parametrize("storage", ["db3", "mcap"])
def test_bag_with_shuffled_names_gripper_duplicates_and_partial_messages_is_identified(panda, panda_run, tmp_path,
                                                                                        storage):
    bag = tmp_path / "run"
    write_joint_state_bag(bag, panda_run, storage, seed=1)
    raw = read_log(bag, panda)
    assert raw.num_samples == panda_run.num_samples and raw.v is None
    np.testing.assert_allclose(raw.q, panda_run.q, atol=1e-12)
    np.testing.assert_allclose(raw.t, panda_run.t - panda_run.t[0], atol=2e-9)
    assert any("repeated stamp" in n for n in raw.notes) and any("gripper" in n for n in raw.notes)
    assert_noise_floor(panda, raw)
    single = next(bag.glob(f"*.{storage}"))  # the storage file alone, without metadata.yaml
    np.testing.assert_array_equal(read_log(single, panda).q, raw.q)


def test_bag_with_a_joint_prefix_signs_and_zero_stamps(panda, panda_run, tmp_path):
    m = panda_run
    flipped = m.replace(q=m.q * np.array([1, 1, -1, 1, 1, 1, 1]) - np.array([0, 0, 0.1, 0, 0, 0, 0]),
                        tau=m.tau * np.array([1, 1, -1, 1, 1, 1, 1]), v=m.v * np.array([1, 1, -1, 1, 1, 1, 1]))
    bag = tmp_path / "prefixed"
    write_joint_state_bag(bag, flipped, "mcap", prefix="arm_", zero_stamps=True, velocity=True)
    with pytest.raises(DataError, match="never published: panda_joint1.*arm_panda_joint1.*strip_prefix"):
        read_log(bag, panda)
    options = DataConfig(joint_map=JointMapConfig(strip_prefix="arm_", sign={"panda_joint3": -1},
                                                  offset={"panda_joint3": -0.1}))
    raw = read_log(bag, panda, options)
    assert any("receive time" in n for n in raw.notes) and raw.v is not None
    np.testing.assert_allclose(raw.q, m.q, atol=1e-12)
    assert_noise_floor(panda, raw)


def test_bag_topics_are_picked_or_listed(panda, panda_run, tmp_path):
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    bag = tmp_path / "two"
    with Writer(bag, version=9) as writer:
        for topic in ("/joint_states", "/franka/joint_states"):
            writer.add_connection(topic, "sensor_msgs/msg/JointState", typestore=ts)
    with pytest.raises(DataError, match=r"2 sensor_msgs/msg/JointState topics \(/franka/joint_states, /joint_states\)"):
        read_log(bag, panda)
    with pytest.raises(DataError, match="'/nope' is not a sensor_msgs/msg/JointState topic"):
        read_log(bag, panda, topic="/nope")


# ---- UR RTDE logs with motor currents ----------------------------------------------------------

UR_GAINS = (13.2, 12.8, 9.6, 4.4, 4.1, 4.3)  # [N·m/A], of the order of a UR5's


def ur5_run(ur5, seed: int = 4):
    rng = np.random.default_rng(seed)
    n, harmonics = ur5.n, 5
    k = np.arange(1, harmonics + 1)
    trajectory = FourierTrajectory(rng.uniform(-0.4, 0.4, (n, harmonics)) / k, rng.uniform(-0.4, 0.4, (n, harmonics)) / k,
                                   0.5 * (ur5.limits.q_lower + ur5.limits.q_upper).clip(-1.5, 1.5), 2 * math.pi / 10)
    return model_measurement(ur5, trajectory, rate_hz=500.0, duration=20.0, tau_noise_std=NOISE, seed=seed)


def write_rtde(path: Path, m, gains, torque_field: str = "actual_current") -> None:
    current = m.tau / np.array(gains)
    header = (["timestamp"] + [f"actual_q_{k}" for k in range(6)] + [f"actual_qd_{k}" for k in range(6)]
              + [f"{torque_field}_{k}" for k in range(6)] + ["robot_mode"])
    table = np.column_stack([m.t + 1234.5, m.q, m.v, current, np.full(m.num_samples, 7)])
    np.savetxt(path, table, fmt="%.10g", delimiter=" ", header=" ".join(header), comments="")


def test_rtde_log_with_currents_and_known_gains_is_identified(ur5, tmp_path):
    import dataclasses

    m = ur5_run(ur5)
    path = tmp_path / "robot_data.csv"
    write_rtde(path, m, UR_GAINS)
    with pytest.raises(DataError, match="drive_gains has no gain for shoulder_pan_joint"):
        read_log(path, ur5)
    robot = _with_gains(ur5, dict(zip(ur5.joint_names, UR_GAINS)))
    raw = read_log(path, robot)
    assert raw.v is not None and any("drive_gains" in n for n in raw.notes)
    np.testing.assert_allclose(raw.tau, m.tau, rtol=1e-8, atol=1e-8)
    assert_noise_floor(robot, raw)
    assert dataclasses.is_dataclass(robot.config)


def _with_gains(robot, gains):
    import copy

    other = copy.copy(robot)
    other.config = copy.copy(robot.config)
    other.config.drive_gains = gains
    return other


def test_refused_fields_and_amps_taken_for_torques(ur5, tmp_path):
    m = ur5_run(ur5)
    path = tmp_path / "as_torque.csv"
    write_rtde(path, m, UR_GAINS, torque_field="actual_current_as_torque")
    with pytest.raises(DataError, match="actual_current_as_torque is gravity-compensated"):
        read_log(path, ur5)
    kuka = tmp_path / "kuka.csv"
    kuka.write_text("time,a,b\n0,1,2\n")
    columns = {"t": "time", "q.shoulder_pan_joint": "a", "tau.shoulder_pan_joint": "external_torque_1"}
    with pytest.raises(DataError, match="does not have"):
        read_log(kuka, ur5, DataConfig(columns=columns))
    kuka.write_text("time,a,external_torque_1\n0,1,2\n")
    with pytest.raises(DataError, match="KUKA's external_torque"):
        read_log(kuka, ur5, DataConfig(columns=columns))
    # currents in a tau column: accepted by the unit check (about 0.1x), but with a hint
    amps = m.replace(tau=m.tau / np.array(UR_GAINS), v=None, vd=None)
    data = prepare_measurement(ur5, amps)
    assert any("current.<joint>" in n and "drive_gains" in n for n in data.notes)
    assert not prepare_measurement(ur5, m.replace(v=None, vd=None)).notes


def test_any_csv_through_a_column_map(panda, panda_run, tmp_path):
    m = panda_run
    path = tmp_path / "lab.csv"
    header = ["time_s"] + [f"pos{k}" for k in range(7)] + [f"trq{k}" for k in range(7)]
    np.savetxt(path, np.column_stack([m.t, m.q, m.tau]), fmt="%.10g", delimiter=";", header=";".join(header),
               comments="")
    columns = {"t": "time_s", **{f"q.{j}": f"pos{k}" for k, j in enumerate(panda.joint_names)},
               **{f"tau.{j}": f"trq{k}" for k, j in enumerate(panda.joint_names)}}
    raw = read_log(path, panda, DataConfig(columns=columns))
    np.testing.assert_allclose(raw.tau, m.tau, rtol=1e-9)
    with pytest.raises(DataError, match="no q.<joint> column for panda_joint7"):
        read_log(path, panda, DataConfig(columns={k: v for k, v in columns.items() if k != "q.panda_joint7"}))


# ---- the real Panda recording through the CLI ----------------------------------------------------


@pytest.mark.skipif(not REAL.is_file(), reason=f"real data not present ({REAL})")
def test_real_panda_recording_runs_through_identify_and_diagnose(tmp_path, capsys):
    """Four 8-9 ms holes in 20 s: refused before issue 22, interpolated with a note now."""
    assert cli(["identify", "--robot", "panda", "--data", str(REAL), "--out", str(tmp_path / "id")]) == 0
    out = capsys.readouterr().out
    assert "4 hole(s) in the time column of up to 8.81 ms" in out
    assert cli(["diagnose", "--robot", "panda", "--data", str(REAL), "--out", str(tmp_path / "diag")]) == 0
    assert (tmp_path / "diag" / "diagnosis.json").is_file()


def test_rtde_log_through_the_cli_with_gains_from_the_config(ur5, tmp_path, capsys):
    from pe_drake.exceptions import ConfigError
    from pe_drake.multibody.registry import resolve_robot_config

    path = tmp_path / "robot_data.csv"
    write_rtde(path, ur5_run(ur5), UR_GAINS)
    gains = ", ".join(f"{j}: {k}" for j, k in zip(ur5.joint_names, UR_GAINS))
    config = tmp_path / "ur5.yaml"
    config.write_text(f"robot:\n  drive_gains: {{{gains}}}\ndata:\n  max_gap_s: 0.05\n")
    assert cli(["identify", "--robot", "ur5", "--config", str(config), "--data", str(path),
                "--out", str(tmp_path / "id")]) == 0
    assert "multiplied by robot.drive_gains" in capsys.readouterr().out
    assert cli(["identify", "--robot", "ur5", "--data", str(path), "--out", str(tmp_path / "id2")]) == 2
    assert "robot.drive_gains has no gain for shoulder_pan_joint" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text("data:\n  effort: amps\n")
    with pytest.raises(ConfigError, match="line 2: data.effort 'amps' is not one of torque, current"):
        resolve_robot_config("ur5", str(bad))
