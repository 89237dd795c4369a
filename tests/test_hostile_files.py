"""Input files that are not regular files (issue 34): a named pipe or a device given as
``--data``, ``--config``, ``--robot``, ``--model`` or a trajectory is refused at once, naming
what it is, instead of blocking on the pipe or being called missing. Each command runs in a
child process limited to 30 s and 1 GB, so a regression fails instead of hanging the suite."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BOUNDED = """
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (2**30, 2**30))
from pe_drake.cli import main
sys.exit(main(sys.argv[1:]))
"""


def run_bounded(argv: list[str], cwd: Path, seconds: float = 30) -> subprocess.CompletedProcess:
    """``pe-drake argv`` in a child limited to 1 GB of address space and ``seconds``."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-c", BOUNDED, *argv], capture_output=True, text=True,
                          timeout=seconds, env=env, cwd=cwd)


@pytest.mark.parametrize("argv, named", [
    (["identify", "--robot", "panda", "--data", "{fifo}.csv", "--out", "out"], "named pipe"),
    (["optimize", "--robot", "panda", "--config", "{fifo}.yaml", "--out", "out"], "named pipe"),
    (["optimize", "--robot", "{fifo}.urdf", "--out", "out"], "named pipe"),
    (["view", "{fifo}.json", "--html", "p.html"], "named pipe"),
    (["validate", "--robot", "panda", "--model", "{fifo}.json", "--data", "{fifo}.csv"], "named pipe"),
    (["identify", "--robot", "panda", "--data", "{zero}.csv", "--out", "out"], "is a device"),
])
def test_pipes_and_devices_as_inputs_are_named(tmp_path, argv, named):
    for suffix in (".csv", ".yaml", ".urdf", ".json"):
        os.mkfifo(tmp_path / f"pipe{suffix}")
        os.symlink("/dev/zero", tmp_path / f"zero{suffix}")
    argv = [a.format(fifo=tmp_path / "pipe", zero=tmp_path / "zero") for a in argv]
    done = run_bounded(argv, tmp_path)
    assert done.returncode == 2, done.stderr
    assert named in done.stderr and "Traceback" not in done.stderr, done.stderr


def _anchors(indent: str, levels: int) -> str:
    """``levels`` anchors, each a list of ten aliases of the one before: 10^levels values."""
    rows = [f"{indent}l0: &b0 [1, 2, 3]"]
    rows += [f"{indent}l{k}: &b{k} [{', '.join([f'*b{k - 1}'] * 10)}]" for k in range(1, levels)]
    return "\n".join(rows) + "\n"


@pytest.mark.parametrize("text, message", [
    (_anchors("", 25), "expand to"),  # under unknown top-level keys
    ("robot:\n  model: x.urdf\n  support_points:\n" + _anchors("    ", 25), "expand to"),  # as values
    ("robot: &r\n  joints: [*r]\n", "cycle"),
    ("solver:\n  max_iterations: 10\nexcitation:\n  harmonics: 3\nsolver:\n  max_iterations: 20\n",
     "line 5: key 'solver' is given twice"),
    ("robot:\n  joints: [a]\n  joints: [b]\n", "line 3: key 'joints' is given twice"),
])
def test_yaml_alias_bombs_and_repeated_keys_are_refused(tmp_path, text, message):
    """Linear in the file's size: each refused in well under the child's 30 s."""
    (tmp_path / "c.yaml").write_text(text)
    done = run_bounded(["optimize", "--robot", "panda", "--config", "c.yaml", "--out", "out"], tmp_path)
    assert done.returncode == 2, done.stderr
    assert message in done.stderr and "c.yaml" in done.stderr, done.stderr


PANDA = [f"panda_joint{k}" for k in range(1, 8)]


def _bag(path: Path, names_of, count: int = 40) -> Path:
    """An MCAP bag of ``count`` JointState messages whose names are ``names_of(k)``."""
    import numpy as np
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    state, header, time = (ts.types[t] for t in ("sensor_msgs/msg/JointState", "std_msgs/msg/Header",
                                                  "builtin_interfaces/msg/Time"))
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection("/joint_states", state.__msgtype__, typestore=ts)
        for k in range(count):
            names = names_of(k)
            stamp = 10**9 + k * 10**7
            msg = state(header=header(stamp=time(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id=""),
                        name=names, position=np.full(len(names), 0.1 * k), velocity=np.zeros(0),
                        effort=np.arange(len(names), dtype=float))
            writer.write(conn, stamp, ts.serialize_cdr(msg, state.__msgtype__))
    return path


@pytest.mark.parametrize("names, named", [
    (["panda_joint1", *PANDA], "'panda_joint1' more than once"),  # the second copy won silently
    (["panda_joint1", *PANDA[:6], "panda_joint1"], "'panda_joint1' more than once"),  # and joint 7 was np.empty
])
def test_bag_naming_a_joint_twice_is_refused(tmp_path, names, named):
    from pe_drake.exceptions import DataError
    from pe_drake.identification.readers.rosbag import read_joint_state_bag

    bag = _bag(tmp_path / "run", lambda k: names)
    with pytest.raises(DataError, match=named):
        read_joint_state_bag(bag, PANDA)


def _mcap_bomb(path: Path, declared: int, inflated: int) -> Path:
    """An MCAP file with one zstd chunk of ``inflated`` zero bytes that declares ``declared``."""
    import struct

    from backports import zstd

    compressor = zstd.ZstdCompressor()
    block = bytes(2**24)
    data = b"".join(compressor.compress(block) for _ in range(inflated // len(block))) + compressor.flush()

    def record(opcode: int, body: bytes) -> bytes:
        return struct.pack("<BQ", opcode, len(body)) + body

    def string(s: str) -> bytes:
        return struct.pack("<I", len(s)) + s.encode()

    chunk = struct.pack("<QQQI", 0, 1, declared, 0) + string("zstd") + struct.pack("<Q", len(data)) + data
    body = (b"\x89MCAP0\r\n" + record(0x01, string("ros2") + string("pe_drake-test")) + record(0x06, chunk)
            + record(0x02, bytes(20)) + b"\x89MCAP0\r\n")
    path.write_bytes(body)
    return path


@pytest.mark.parametrize("declared, message", [(1000, "decompression bomb"), (2**31, "over the 256 MB limit")])
def test_zstd_bomb_mcap_is_refused_in_bounded_memory(tmp_path, declared, message):
    """58 kB that inflate to 1.6 GB: refused within the child's 30 s and 1 GB."""
    bomb = _mcap_bomb(tmp_path / "bomb.mcap", declared, 1600 * 2**20)
    assert bomb.stat().st_size < 200_000
    done = run_bounded(["identify", "--robot", "panda", "--data", str(bomb), "--out", "out"], tmp_path)
    assert done.returncode == 2, done.stderr
    assert message in done.stderr and "bomb.mcap" in done.stderr, done.stderr


def test_a_huge_bag_message_is_refused(tmp_path):
    from pe_drake.exceptions import DataError
    from pe_drake.identification.readers.rosbag import read_joint_state_bag

    bag = _bag(tmp_path / "run", lambda k: PANDA * (20_000 if k == 3 else 1))
    with pytest.raises(DataError, match="message 3 on '/joint_states' has .* MB"):
        read_joint_state_bag(bag, PANDA)


UR5 = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]


def _rtde(path: Path, rows: int = 3000, extra_column: str = "", edit=None) -> Path:
    """A UR RTDE log (spaces between fields, as UR's writer) of ``rows`` samples."""
    columns = ["timestamp"] + [f"actual_q_{k}" for k in range(6)] + [f"actual_current_{k}" for k in range(6)]
    columns += [extra_column] if extra_column else []
    lines = [" ".join(columns)]
    for r in range(rows):
        values = [f"{0.002 * r:.3f}"] + [f"{0.1 * k + 1e-4 * r:.6f}" for k in range(12)]
        lines.append(" ".join(values + (["0.5"] if extra_column else [])))
    if edit:
        edit(lines)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def test_rtde_log_with_a_repeated_column_is_refused(tmp_path):
    from pe_drake.exceptions import DataError
    from pe_drake.identification.readers.columns import read_mapped_csv, rtde_columns

    path = _rtde(tmp_path / "run.csv", extra_column="actual_q_0")
    columns = (tmp_path / "run.csv").read_text().splitlines()[0].split()
    with pytest.raises(DataError, match=r"'actual_q_0' \(columns 2, 14\) more than once"):
        read_mapped_csv(path, UR5, rtde_columns(UR5, columns, str(path)), dict.fromkeys(UR5, 1.0))


def test_a_latin1_byte_after_64_kb_of_an_rtde_log_is_named(tmp_path):
    from pe_drake.exceptions import DataError
    from pe_drake.identification.readers.columns import read_mapped_csv, rtde_columns

    path = _rtde(tmp_path / "run.csv")
    data = path.read_bytes().splitlines(keepends=True)
    data[2500] = data[2500].replace(b" ", b" \xe9", 1)
    path.write_bytes(b"".join(data))
    assert sum(len(line) for line in data[:2500]) > 65536
    columns = data[0].decode().split()
    with pytest.raises(DataError, match="line 2501: byte 0xe9 is not UTF-8"):
        read_mapped_csv(path, UR5, rtde_columns(UR5, columns, str(path)), dict.fromkeys(UR5, 1.0))


STAGED_SLEEPER = """
import sys, time
from pe_drake.io_utils import staged_output_dir, terminated_as_exception
with terminated_as_exception():
    with staged_output_dir(sys.argv[1], "report.json", ("report.json", "trajectory.csv")) as tmp:
        (tmp / "trajectory.csv").write_text("half")
        print("staged", flush=True)
        time.sleep(60)
"""


def test_sigterm_cleans_up_like_an_exception(tmp_path):
    """``timeout`` and systemd send SIGTERM: the staged folder and the lock go, as on Ctrl-C."""
    import signal

    out = tmp_path / "out"
    child = subprocess.Popen([sys.executable, "-c", STAGED_SLEEPER, str(out)], stdout=subprocess.PIPE, text=True,
                             env={**os.environ, "PYTHONPATH": str(ROOT)}, cwd=tmp_path)
    try:
        assert child.stdout.readline().strip() == "staged"
        assert list(out.glob(".staging-*"))
        child.send_signal(signal.SIGTERM)
        child.wait(timeout=30)
    finally:
        child.kill()
    assert child.returncode != 0
    assert not out.exists() or not list(out.iterdir())  # no .staging-*, no lock, nothing half-written


def test_the_cli_turns_sigterm_into_a_clean_exit(tmp_path):
    """``pe-drake optimize`` under SIGTERM exits 143 with a message and leaves no staging folder."""
    import signal
    import time

    out = tmp_path / "out"
    (tmp_path / "slow.yaml").write_text("solver:\n  max_iterations: 3000\n")
    child = subprocess.Popen([sys.executable, "-c", BOUNDED.replace("resource.setrlimit", "# resource.setrlimit"),
                              "optimize", "--robot", "panda", "--config", "slow.yaml", "--out", str(out), "--quiet"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             env={**os.environ, "PYTHONPATH": str(ROOT)}, cwd=tmp_path)
    try:
        deadline = time.monotonic() + 60
        while not (out / ".pe_drake.lock").exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(1.0)
        child.send_signal(signal.SIGTERM)
        _, err = child.communicate(timeout=60)
    finally:
        child.kill()
    assert child.returncode == 143, err[-2000:]
    assert "terminated (SIGTERM)" in err
    assert not out.exists() or not list(out.glob(".staging-*")) and not (out / ".pe_drake.lock").exists()


STOPPED_WORKER = """
import multiprocessing, os, signal, sys, time
from pe_drake.excitation.parallel import open_executor
from pe_drake.multibody.robot import load_robot


def double(state, payload):
    return 2 * payload


if __name__ == "__main__":
    with open_executor(load_robot("panda"), "local", 2) as ex:
        assert [d.value for d in ex.map(double, [1, 2, 3])] == [2, 4, 6]
        os.kill(next(iter(ex.processes())), signal.SIGSTOP)
        begin = time.monotonic()
    print(f"closed in {time.monotonic() - begin:.1f} s; children left: {len(multiprocessing.active_children())}")
"""


def test_a_stopped_idle_worker_does_not_hang_the_end_of_a_run(tmp_path):
    """SIGSTOP on a worker after every task finished: closing the pool waited forever for it
    (over 800 s); now it is killed after CLOSE_TIMEOUT_S. In a child bounded to 60 s."""
    from pe_drake.excitation.parallel.local import CLOSE_TIMEOUT_S

    (tmp_path / "stopped_worker.py").write_text(STOPPED_WORKER)
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{tmp_path}"}
    done = subprocess.run([sys.executable, str(tmp_path / "stopped_worker.py")], capture_output=True, text=True,
                          timeout=60, env=env, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    seconds = float(done.stdout.split("closed in ")[1].split(" s")[0])
    assert seconds < CLOSE_TIMEOUT_S + 10 and "children left: 0" in done.stdout, done.stdout


def test_config_workers_are_capped_at_the_cores(tmp_path, capsys):
    """A shared config's 'workers: 200' starts no more processes than this machine has cores."""
    from pe_drake.cli import main
    from pe_drake.excitation.parallel import default_workers

    (tmp_path / "c.yaml").write_text("solver:\n  max_iterations: 2\nparallel:\n  starts: 3\n  workers: 200\n")
    main(["optimize", "--robot", "panda", "--config", str(tmp_path / "c.yaml"), "--out", str(tmp_path / "out"),
          "--no-html", "--allow-unchecked"])
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["executor"]["workers"] == min(3, default_workers()), report["executor"]


@pytest.mark.parametrize("edit, message", [
    ({"ramp_duration": 1e9}, "ramp_duration is 1e\\+09 s, over the 600 s"),
    ({"periods": 1000, "ramp_duration": 500.0}, "the whole motion .* over the 7200 s"),
])
def test_an_absurd_motion_length_is_refused_before_sampling(tmp_path, edit, message):
    """'ramp_duration: 1e9' asked for 447 GiB when the motion was sampled."""
    import json

    from pe_drake.exceptions import DataError
    from pe_drake.excitation.trajectory_file import load_motion

    data = json.loads((ROOT / "tests" / "data" / "panda_optimized.json").read_text())
    data.update(edit)
    path = tmp_path / "trajectory.json"
    path.write_text(json.dumps(data))
    with pytest.raises(DataError, match=message):
        load_motion(path)


def test_an_iteration_count_beyond_the_solvers_is_refused(tmp_path):
    from pe_drake.config import load_config
    from pe_drake.exceptions import ConfigError

    (tmp_path / "c.yaml").write_text("solver:\n  max_iterations: 100000000000000000000000000000000000\n")
    with pytest.raises(ConfigError, match=r"line 2: solver.max_iterations must be an integer from 1 to 2147483647"):
        load_config(tmp_path / "c.yaml")


def test_a_file_named_as_capsules_is_not_echoed(tmp_path):
    (tmp_path / "id_rsa").write_text("-----BEGIN OPENSSH PRIVATE KEY-----\nCANARY-b3BlbnNzaC1rZXk\n")
    (tmp_path / "c.yaml").write_text(f"robot:\n  capsules: {tmp_path / 'id_rsa'}\n")
    done = run_bounded(["optimize", "--robot", "panda", "--config", "c.yaml", "--out", "out"], tmp_path)
    assert done.returncode == 2 and "capsule" in done.stderr, done.stderr
    assert "CANARY" not in done.stderr and "PRIVATE KEY" not in done.stderr, done.stderr


def test_a_nan_effort_in_a_bag_is_named(tmp_path):
    """A NaN effort was reported as "check the torque units" further on."""
    import numpy as np
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from pe_drake.exceptions import DataError
    from pe_drake.identification.readers.rosbag import read_joint_state_bag

    ts = get_typestore(Stores.ROS2_HUMBLE)
    state, header, time = (ts.types[t] for t in ("sensor_msgs/msg/JointState", "std_msgs/msg/Header",
                                                  "builtin_interfaces/msg/Time"))
    with Writer(tmp_path / "run", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection("/joint_states", state.__msgtype__, typestore=ts)
        for k in range(40):
            effort = np.arange(7.0)
            effort[3] = np.nan if k == 17 else 3.0
            stamp = 10**9 + k * 10**7
            msg = state(header=header(stamp=time(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id=""),
                        name=PANDA, position=np.zeros(7), velocity=np.zeros(0), effort=effort)
            writer.write(conn, stamp, ts.serialize_cdr(msg, state.__msgtype__))
    with pytest.raises(DataError, match=r"effort of joint 'panda_joint4' is nan in the message stamped 1.170000000 s"):
        read_joint_state_bag(tmp_path / "run", PANDA)


def test_a_swapped_row_is_called_out_of_order_not_repeated():
    import numpy as np

    from pe_drake.exceptions import DataError
    from pe_drake.identification.csv_checks import check_time_order

    t = np.arange(50) * 0.002
    t[[20, 21]] = t[[21, 20]]
    with pytest.raises(DataError, match="Put the rows back in time order") as err:
        check_time_order(t, "run.csv")
    assert "repeated" not in str(err.value)


@pytest.mark.parametrize("mode", ["message", "file"])
def test_a_compressed_rosbag2_bomb_is_refused(tmp_path, mode, monkeypatch):
    """rosbags inflates a message-compressed db3 message, or a file-compressed storage file,
    whole: one message of 51 kB that inflates to 1.6 GB is refused before that."""
    import sqlite3

    import numpy as np
    from backports import zstd
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from pe_drake.identification.readers.rosbag import read_joint_state_bag

    ts = get_typestore(Stores.ROS2_HUMBLE)
    state, header, time = (ts.types[t] for t in ("sensor_msgs/msg/JointState", "std_msgs/msg/Header",
                                                  "builtin_interfaces/msg/Time"))
    compressor = zstd.ZstdCompressor()
    bomb = b"".join(compressor.compress(bytes(2**24)) for _ in range(100)) + compressor.flush()
    writer = Writer(tmp_path / "run", version=9, storage_plugin=StoragePlugin.SQLITE3)
    writer.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with writer:
        conn = writer.add_connection("/joint_states", state.__msgtype__, typestore=ts)
        for k in range(40):
            stamp = 10**9 + k * 10**7
            msg = state(header=header(stamp=time(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id=""),
                        name=PANDA, position=np.zeros(7), velocity=np.zeros(0), effort=np.ones(7))
            writer.write(conn, stamp, ts.serialize_cdr(msg, state.__msgtype__))
    assert read_joint_state_bag(tmp_path / "run", PANDA).num_samples == 40  # an honest compressed bag reads
    db3 = next((tmp_path / "run").glob("*.db3"))
    if mode == "message":
        with sqlite3.connect(db3) as db:
            db.execute("UPDATE messages SET data = ? WHERE id = 5", (bomb,))
    else:
        zipped = db3.with_name(db3.name + ".zstd")
        zipped.write_bytes(bomb)
        db3.unlink()
        meta = (tmp_path / "run" / "metadata.yaml").read_text()
        meta = meta.replace("compression_mode: message", "compression_mode: file").replace(db3.name, zipped.name)
        (tmp_path / "run" / "metadata.yaml").write_text(meta)
        monkeypatch.setenv("PE_DRAKE_MAX_BAG_FILE_MB", "64")  # the 1.6 GB is over it: quicker than 4 GB
    done = run_bounded(["identify", "--robot", "panda", "--data", str(tmp_path / "run"), "--out", "out"], tmp_path)
    assert done.returncode == 2 and re.search("inflates past .* decompression bomb", done.stderr), done.stderr
