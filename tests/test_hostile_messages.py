"""Hostile input gets a clear one-line refusal: exit 2, the file, the row/line, the column or
key, the value (cut when huge), and no traceback; a killed worker leaves no IPOPT log behind."""

from __future__ import annotations

import math
import multiprocessing
import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from pe_drake.cli import main
from pe_drake.config import ExcitationConfig, SolverConfig
from pe_drake.exceptions import ConfigError, DataError, PeDrakeError, shorten
from pe_drake.excitation import solver_logs
from pe_drake.excitation.multistart import MultiStartOptions, solve_multistart
from pe_drake.excitation.parallel import ExecutorOptions, WorkerError, open_executor
from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.identification.gaps import split_at_pauses
from pe_drake.identification.identified_file import load_identified
from pe_drake.identification.measurements import Measurement, read_measurement_csv
from pe_drake.identification.readers import read_log
from pe_drake.multibody.robot import load_robot
from pe_drake.yaml_check import check_yaml_file

ROOT = Path(__file__).resolve().parent.parent
JOINTS = ("j1", "j2")
HEADER = ["t", "q.j1", "q.j2", "tau.j1", "tau.j2"]


def _run(argv, capsys):
    code = main(argv)
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


def _csv(path: Path, t=None, rows: int = 40, edit=None, sep: str = ",") -> Path:
    t = np.arange(rows) * 1e-3 if t is None else np.asarray(t)
    lines = [HEADER] + [[repr(float(x)), "0.1", "0.2", "1.5", "-0.5"] for x in t]
    if edit:
        edit(lines)
    path.write_text("\n".join(sep.join(row) for row in lines) + "\n")
    return path


# 1. deep nesting: RecursionError tracebacks


def test_deep_yaml_config_is_refused_naming_the_file(tmp_path, capsys):
    cfg = tmp_path / "deep.yaml"
    cfg.write_text("excitation: " + "[" * 100000 + "]" * 100000 + "\n")
    code, err = _run(["optimize", "--robot", "panda", "--config", str(cfg), "--out", str(tmp_path / "o"), "--quiet"],
                     capsys)
    assert code == 2 and "nested too deeply" in err and "deep.yaml" in err, err
    cfg.write_text("excitation: " + "[" * 150 + "]" * 150 + "\n")  # parses, but no config is so deep
    with pytest.raises(ConfigError, match=r"line 1, column \d+: nested too deeply"):
        check_yaml_file(cfg, ExcitationConfig)


@pytest.mark.parametrize("text", ["[" * 100000 + "]" * 100000, '{"a":' * 100000 + "1" + "}" * 100000,
                                  '{"joints": ' + "[" * 200 + "]" * 200 + "}"])
def test_deep_json_files_are_refused_naming_the_file(tmp_path, text, panda):
    path = tmp_path / "trajectory.json"
    path.write_text(text)
    with pytest.raises(DataError, match=r"trajectory.json'.*nested too deeply"):
        load_trajectory(path)
    path = path.rename(tmp_path / "identified.json")
    with pytest.raises(DataError, match=r"identified.json'.*nested too deeply"):
        load_identified(path, panda)


def test_deep_json_from_the_cli_exits_2(tmp_path, capsys):
    path = tmp_path / "trajectory.json"
    path.write_text("[" * 100000 + "]" * 100000)
    code, err = _run(["view", str(path), "--html", str(tmp_path / "p.html")], capsys)
    assert code == 2 and "nested too deeply" in err and "trajectory.json" in err, err


# 2. tags that build Python objects: a raw dict, or silently accepted


@pytest.mark.parametrize("text, line", [
    ("excitation:\n  harmonics: !!python/object/new:os.system [echo hi]\n", 2),
    ("robot: !!python/object/new:os.system {}\n", 1),  # was "The fields ['_tag'] were unknown to the schema"
    ("!!python/object/new:os.system {excitation: {}}\n", 1),  # was accepted
    ("excitation:\n  criterion: !!python/name:os.system\n", 2),
])
def test_python_object_tags_are_refused_in_one_line(tmp_path, capsys, text, line):
    cfg = tmp_path / "tag.yaml"
    cfg.write_text(text)
    code, err = _run(["optimize", "--robot", "panda", "--config", str(cfg), "--out", str(tmp_path / "o"), "--quiet"],
                     capsys)
    assert code == 2, err
    message = err.strip().splitlines()[-1]
    assert f"tag.yaml' does not match the config format: line {line}, column" in message, err
    assert "YAML tags that build Python objects are not accepted" in message and "!!python/" in message
    assert "{" not in message and not (tmp_path / "o").exists()


# 3. a huge value echoed whole


@pytest.mark.parametrize("text, names_file", [
    ("excitation:\n  harmonics: {}\n", True),
    ("excitation:\n  criterion: {}\n", True),
    ("robot:\n  nominal_positions:\n    ? {}\n    : 0.3\n", False),  # refused where the robot is built
])
def test_a_huge_yaml_value_is_cut_in_the_message(tmp_path, capsys, text, names_file):
    cfg = tmp_path / "big.yaml"
    cfg.write_text(text.format("x" * 100_000))
    code, err = _run(["optimize", "--robot", "panda", "--config", str(cfg), "--out", str(tmp_path / "o"), "--quiet"],
                     capsys)
    assert code == 2 and ("big.yaml" in err) == names_file
    assert "x" * 200 + "… (100000 characters)" in err and len(err) < 1000, err[:3000]


def test_a_10_mb_yaml_file_is_refused_unread(tmp_path):
    cfg = tmp_path / "big.yaml"
    cfg.write_text("excitation:\n  harmonics: " + "x" * 10_000_000 + "\n")
    with pytest.raises(ConfigError, match=r"big.yaml' is 10.0 MB; a config file is a few kB \(at most 1 MB is read\)$"):
        check_yaml_file(cfg, ExcitationConfig)


def test_shorten_and_the_error_net():
    assert shorten("abc") == "abc" and shorten("y" * 300) == "y" * 200 + "… (300 characters)"
    err = PeDrakeError("value '" + "z" * 5000 + "' is bad")
    assert str(err) == "value '" + "z" * 199 + "… (5002 characters) is bad"  # the run includes its quotes
    assert str(DataError("bad " + "w" * 1000, file="f.csv")).endswith("… (1000 characters)")


# 4. repeated time stamps reported as thousands of holes


def test_near_duplicate_time_stamps_are_counted_not_called_gaps(tmp_path):
    t = np.repeat(np.arange(50) * 1e-3, 2) + np.tile([0.0, 1e-9], 50)  # every sample logged twice, 1 ns apart
    with pytest.raises(DataError, match=r"50 duplicated time stamp\(s\).* at row\(s\) 2, 4, 6, 8, 10, … "
                                        r"\(line\(s\) 3, 5, 7, 9, 11 of the file\)") as err:
        read_measurement_csv(_csv(tmp_path / "m.csv", t), JOINTS)
    assert err.value.column == "t" and err.value.row == 2 and "gap" not in str(err.value)
    one = np.arange(40) * 1e-3
    one[20] = one[19] + 1e-9
    with pytest.raises(DataError, match=r"1 duplicated time stamp\(s\).*row\(s\) 21 \(line\(s\) 22"):
        read_measurement_csv(_csv(tmp_path / "one.csv", one), JOINTS)


def test_repeated_stamps_of_data_not_from_a_csv_are_refused_before_the_gaps():
    t = np.repeat(np.arange(5000) * 1e-3, 2)  # a 1 kHz log with every stamp written twice
    m = Measurement(t, np.zeros((len(t), 2)), np.zeros((len(t), 2)), joints=JOINTS, source="log.bag")
    with pytest.raises(DataError, match=r"log.bag', column 't', row 2: .*5000 duplicated time stamp"):
        split_at_pauses(m)  # was: "9999 hole(s) in the time column ... interpolated"


def test_mapped_csv_counts_repeated_and_decreasing_stamps(tmp_path):
    t = np.arange(40) * 1e-3
    t[10], t[30] = t[9], t[5]
    path = _csv(tmp_path / "m.csv", t)
    robot = SimpleNamespace(joint_names=JOINTS, config=SimpleNamespace(drive_gains={}))
    with pytest.raises(DataError, match=r"1 duplicated .* row\(s\) 11; and 1 decreasing .* row\(s\) 31") as err:
        read_log(path, robot, format="columns", columns={"t": "t", "q.j1": "q.j1", "q.j2": "q.j2",
                                                         "tau.j1": "tau.j1", "tau.j2": "tau.j2"})
    assert err.value.row == 11


# 5. numbers Python's float() takes and numpy does not


@pytest.mark.parametrize("fmt", ["pe_drake", "columns"])
@pytest.mark.parametrize("bad", ["0.21_5", "１.5", "0x1p3"])
def test_a_number_with_an_underscore_is_refused_with_row_and_column(tmp_path, fmt, bad):
    def edit(lines):
        lines[20][2] = bad

    path = _csv(tmp_path / "m.csv", edit=edit)
    robot = SimpleNamespace(joint_names=JOINTS, config=SimpleNamespace(drive_gains={}))
    columns = {c: c for c in HEADER} if fmt == "columns" else {}
    with pytest.raises(DataError) as err:
        read_log(path, robot, format=fmt, columns=columns)
    assert f"'{bad}' is not a number (line 21 of the file)" in str(err.value)
    assert err.value.column == "q.j2" and err.value.row == 20


# 6. semicolons, tabs, UTF-16


@pytest.mark.parametrize("name, write, looks", [
    ("semi.csv", lambda p: _csv(p, sep=";"), "looks semicolon-delimited"),
    ("tab.csv", lambda p: _csv(p, sep="\t"), "looks tab-delimited"),
    ("u16.csv", lambda p: p.write_text(",".join(HEADER) + "\n0,0,0,0,0\n", encoding="utf-16"), "looks UTF-16"),
    ("u16be.csv", lambda p: p.write_bytes(b"\xfe\xff" + ",".join(HEADER).encode("utf-16-be")), "looks UTF-16"),
    ("nobom.csv", lambda p: p.write_bytes(",".join(HEADER).encode("utf-16-le")), "looks UTF-16 or binary"),
    ("latin1.csv", lambda p: p.write_bytes(",".join(HEADER).encode() + b"\n# caf\xe9\n"), "line 2: byte 0xe9"),
])
@pytest.mark.parametrize("fmt", ["auto", "pe_drake"])
def test_wrong_delimiter_or_encoding_gets_a_hint(tmp_path, name, write, looks, fmt):
    path = tmp_path / name
    write(path)
    robot = SimpleNamespace(joint_names=JOINTS, config=SimpleNamespace(drive_gains={}))
    with pytest.raises(DataError) as err:
        read_log(path, robot, format=fmt)
    message = str(err.value)
    assert message.startswith(f"file '{path}'") and looks in message, message
    assert "comma-separated UTF-8" in message


# 7. a URDF with a DOCTYPE "has no effort limit"


def _urdf(path: Path, effort: str, prologue: str) -> Path:
    inertial = ('<inertial><origin xyz="0 0 0.1"/><mass value="1"/>'
                '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>')
    links = "".join(f'<link name="{n}">{inertial}</link>\n' for n in ("base", "l1", "l2"))
    joints = "".join(
        f'<joint name="{j}" type="revolute"><parent link="{p}"/><child link="{c}"/><origin xyz="0 0 0.2"/>'
        f'<axis xyz="0 1 0"/><limit lower="-2" upper="2" velocity="2" effort="{effort}"/></joint>\n'
        for j, p, c in (("j1", "base", "l1"), ("j2", "l1", "l2")))
    path.write_text(f'<?xml version="1.0"?>\n{prologue}<robot name="two">\n<gazebo>&ext;</gazebo>\n'
                    f'<link name="world"/><joint name="fix" type="fixed"><parent link="world"/>'
                    f'<child link="base"/></joint>\n{links}{joints}</robot>\n')
    return path


def test_urdf_with_a_doctype_keeps_its_effort_limits(tmp_path):
    # Python's XML parser fails on the external entity Drake ignores: the limits read as none
    path = _urdf(tmp_path / "two.urdf", "50", '<!DOCTYPE robot [\n  <!ENTITY ext SYSTEM "gazebo.xml">\n]>\n')
    robot = load_robot(str(path))
    np.testing.assert_array_equal(robot.limits.effort_max, [50.0, 50.0])


def test_an_effort_limit_given_by_an_entity_is_explained(tmp_path):
    path = _urdf(tmp_path / "two.urdf", "&limit;",
                 '<!DOCTYPE robot [\n  <!ENTITY limit "50">\n  <!ENTITY ext "">\n]>\n')
    with pytest.raises(ConfigError, match=r"got '&limit;'.*<!DOCTYPE> defines entities, which Drake does not expand"):
        load_robot(str(path))


# 8. IPOPT logs of killed workers


def _holder(root: Path) -> subprocess.Popen:
    """A process that makes its log folder under ``root`` and waits to be killed."""
    code = ("import sys, tempfile; tempfile.tempdir = sys.argv[1]; from pe_drake.excitation import solver_logs; "
            "print(solver_logs.new_log_file(), flush=True); import time; time.sleep(60)")
    proc = subprocess.Popen([sys.executable, "-c", code, str(root)], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    Path(proc.stdout.readline().strip()).write_text("Number of Iterations....: 3\n")
    return proc


def test_the_log_folder_of_a_killed_process_is_swept_and_a_live_one_kept(tmp_path):
    dead, alive = _holder(tmp_path), _holder(tmp_path)
    try:
        dead.send_signal(signal.SIGKILL)
        dead.wait()
        folders = sorted(tmp_path.glob(f"{solver_logs.PREFIX}*"))
        assert len(folders) == 2
        removed = solver_logs.remove_orphaned_log_folders(tmp_path)
        assert [p.name for p in removed] == [p.name for p in folders if f"_{dead.pid}_" in p.name]
        assert [p.name for p in tmp_path.iterdir()] == [p.name for p in folders if f"_{alive.pid}_" in p.name]
    finally:
        alive.kill()
        alive.wait()
        dead.stdout.close()
        alive.stdout.close()
    assert solver_logs.remove_orphaned_log_folders(tmp_path) and not list(tmp_path.iterdir())


def test_a_run_whose_worker_is_killed_leaves_no_ipopt_log(panda, tmp_path, monkeypatch):
    monkeypatch.setenv("TMPDIR", str(tmp_path))  # spawned workers read it
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    killed = []

    def kill_workers(event):
        if event.kind == "progress" and not killed:  # IPOPT is running: its log is open
            killed.extend(p.pid for p in multiprocessing.active_children())
            for pid in killed:
                os.kill(pid, signal.SIGKILL)

    config = ExcitationConfig(harmonics=3, omega=2 * math.pi, cost_samples=12, constraint_samples=40,
                              criterion="log_cond", amplitude=0.3)
    with open_executor(panda, "local", 2, tasks=2, start_method="spawn") as ex:
        try:  # a killed worker's start is lost, the others are re-run on a new pool (test_parallel)
            options = MultiStartOptions([3, 4], run=ExecutorOptions(executor=ex, progress_interval=0.05))
            solve_multistart(panda, config, SolverConfig(max_iterations=300, verbose=False), options,
                             progress=kill_workers)
        except WorkerError as err:  # every start lost
            assert "died" in str(err)
    assert killed
    assert not list(tmp_path.iterdir())  # the executor swept the killed workers' folders when it closed
