"""An output folder holds one run, whole: a lock against a second writer, a SHA-256 manifest
that readers check, and a full disk that loses nothing solved.

Each test fails on the code before the lock and the manifest: a run stopped between two
renames left a set that every reader accepted; two runs on one folder both went ahead; a full
disk gave an OSError traceback and lost the optimized motion.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import shutil
from pathlib import Path

import pytest

from pe_drake.cli import main
from pe_drake.exceptions import ConfigError, DataError, OutputWriteError
from pe_drake.excitation import motion_plan, optimize_motion
from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.identification import IdentifyOptions, identify_model
from pe_drake.identification.identified_file import load_identified
from pe_drake.io_utils import staged_output_dir
from pe_drake.multibody import load_robot, resolve_robot_config
from pe_drake.output_paths import DIAGNOSE_OUTPUTS, IDENTIFY_OUTPUTS, OPTIMIZE_OUTPUTS
from pe_drake.output_set import LOCK_NAME, check_output_set, output_lock
from pe_drake.simulation.synthetic import model_measurement

DATA = Path(__file__).parent / "data"


def _write_run(out: Path, tag: str) -> None:
    """A run of optimize's file names: trajectory.json (real), a CSV, a bag folder, report.json."""
    trajectory = json.loads((DATA / "panda_optimized.json").read_text())
    trajectory["cond"] = 100.0 + len(tag)  # two runs differ in every file
    with staged_output_dir(out, "report.json", OPTIMIZE_OUTPUTS) as tmp:
        (tmp / "trajectory.json").write_text(json.dumps(trajectory))
        (tmp / "trajectory.csv").write_text(f"t,q\n0,{tag}\n")
        (tmp / "trajectory_goal_bag").mkdir()
        (tmp / "trajectory_goal_bag" / "goal.mcap").write_text(tag)
        (tmp / "report.json").write_text(json.dumps({"run": tag}, indent=2))


def test_manifest_lists_every_file_with_its_digest(tmp_path):
    _write_run(tmp_path, "a")
    outputs = json.loads((tmp_path / "report.json").read_text())["outputs"]
    assert sorted(outputs) == ["trajectory.csv", "trajectory.json", "trajectory_goal_bag/goal.mcap"]
    assert all(len(d) == 64 for d in outputs.values())
    load_trajectory(tmp_path / "trajectory.json")  # a whole set is read
    assert not (tmp_path / LOCK_NAME).exists() and not list(tmp_path.glob(".staging-*"))


@pytest.mark.parametrize("stop_at", range(4))
def test_a_run_stopped_between_renames_is_refused_by_readers(tmp_path, monkeypatch, stop_at):
    """Fault injection at each rename: whatever is left is one whole run or refused."""
    _write_run(tmp_path, "first")
    real_replace, calls = os.replace, []

    def replace(src, dst):
        if len(calls) == stop_at:
            raise KeyboardInterrupt  # the process stops here
        calls.append(dst)
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(KeyboardInterrupt):
        _write_run(tmp_path, "second")
    monkeypatch.setattr(os, "replace", real_replace)
    csv = tmp_path / "trajectory.csv"
    report = json.loads((tmp_path / "report.json").read_text())["run"]
    if report == "first" and csv.is_file() and "first" in csv.read_text():  # stopped before anything moved
        load_trajectory(tmp_path / "trajectory.json")
    elif (tmp_path / "trajectory.json").is_file():
        with pytest.raises(DataError, match="has changed since|is missing since"):
            load_trajectory(tmp_path / "trajectory.json")


#: Each command's manifest and the files a controller or ROS tool reads without pe_drake.
CONSUMER_SETS = {
    "optimize": ("report.json", OPTIMIZE_OUTPUTS, ("trajectory.json", "trajectory.csv", "trajectory_goal.yaml",
                                                  "trajectory_goal_bag/goal.mcap", "playback.html")),
    "identify": ("identified.json", IDENTIFY_OUTPUTS, ("model.urdf", "drive_effects.yaml", "residuals.png")),
    "diagnose": ("diagnosis.json", DIAGNOSE_OUTPUTS, ("augmented_model.urdf", "report.md", "gap.png")),
}


def _write_set(out: Path, command: str, tag: str) -> None:
    manifest, own, files = CONSUMER_SETS[command]
    with staged_output_dir(out, manifest, own) as tmp:
        for name in files:
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp / name).write_text(tag)
        (tmp / manifest).write_text(json.dumps({"run": tag}))


@pytest.mark.parametrize("command", CONSUMER_SETS)
def test_a_kill_before_any_rename_never_leaves_old_files_beside_a_new_manifest(tmp_path, monkeypatch, command):
    """A kill injected before each os.replace of optimize's, identify's and diagnose's output
    sets: each file a tool reads without pe_drake (goal, bag, CSV, URDF) is then the old run's
    beside the old manifest, or absent, or the new run's beside the new manifest."""
    manifest, _, files = CONSUMER_SETS[command]
    real_replace = os.replace
    stop_at = 0
    while True:
        out = tmp_path / f"run{stop_at}"
        _write_set(out, command, "old")
        calls = []

        def replace(src, dst):
            if len(calls) == stop_at:
                raise KeyboardInterrupt
            calls.append(dst)
            real_replace(src, dst)

        monkeypatch.setattr(os, "replace", replace)
        try:
            _write_set(out, command, "new")
            finished = True
        except KeyboardInterrupt:
            finished = False
        monkeypatch.setattr(os, "replace", real_replace)
        run = json.loads((out / manifest).read_text())["run"]
        for name in files:
            if (out / name).exists():
                assert (out / name).read_text() == run, (stop_at, name, run)
        assert not list(out.glob(".staging-*"))
        if finished:
            break
        stop_at += 1
    assert stop_at >= 2 * len(files)  # every file moved out and in again


def test_an_edited_file_of_the_set_is_named(tmp_path):
    _write_run(tmp_path, "a")
    (tmp_path / "trajectory.csv").write_text("t,q\n0,edited\n")
    with pytest.raises(DataError, match=r"trajectory\.csv' has changed"):
        check_output_set(tmp_path / "trajectory.json")
    copy = tmp_path / "alone"
    copy.mkdir()
    shutil.copy(tmp_path / "trajectory.json", copy)  # the advice given: a file used alone is read
    load_trajectory(copy / "trajectory.json")


def test_identified_model_with_a_changed_urdf_is_refused(tmp_path):
    robot = load_robot("panda")
    trajectory, _ = load_trajectory(DATA / "panda_optimized.json")
    data = model_measurement(robot, trajectory, rate_hz=500.0, duration=12.0, tau_noise_std=0.05, seed=1)
    identify_model(robot, data, IdentifyOptions(method="ols")).write(tmp_path)
    load_identified(tmp_path / "identified.json", robot)
    (tmp_path / "residuals.png").write_bytes(b"another run's figure")
    with pytest.raises(DataError, match="residuals.png' has changed"):
        load_identified(tmp_path / "identified.json", robot)


def test_a_second_writer_is_refused_and_the_first_is_untouched(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    fd = os.open(out / LOCK_NAME, os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX)  # another process's run (flock conflicts across descriptors)
    try:
        code = main(["optimize", "--robot", "panda", "--out", str(out)])
    finally:
        os.close(fd)
    assert code == 2
    assert "another pe-drake run is writing to" in capsys.readouterr().err
    with output_lock(out):  # free again once the holder is gone
        pass


def test_a_planted_lock_symlink_is_refused(tmp_path):
    target = tmp_path / "victim"
    target.write_text("keep")
    out = tmp_path / "out"
    out.mkdir()
    (out / LOCK_NAME).symlink_to(target)
    with pytest.raises(ConfigError, match="symbolic link"):
        with output_lock(out):
            pass
    assert target.read_text() == "keep"


def test_stale_staging_folders_are_cleaned(tmp_path):
    (tmp_path / ".staging-killed").mkdir()
    (tmp_path / ".staging-killed" / "trajectory.csv").write_text("half")
    _write_run(tmp_path, "a")
    assert not list(tmp_path.glob(".staging-*"))


def test_a_refused_run_leaves_no_folder(tmp_path):
    out = tmp_path / "new"
    assert main(["optimize", "--robot", "panda", "--seed", "-1", "--out", str(out)]) == 2
    assert not out.exists()


def _full_disk(*_args, **_kwargs):
    raise OSError(errno.ENOSPC, "No space left on device", "trajectory.csv")


def test_full_disk_keeps_the_solved_motion(tmp_path, monkeypatch):
    cfg = tmp_path / "small.yaml"
    cfg.write_text("solver:\n  max_iterations: 10\n")
    plan = optimize_motion(resolve_robot_config("panda", cfg), name="panda")
    monkeypatch.setattr(motion_plan, "write_motion_csv", _full_disk)
    out = tmp_path / "out"
    with pytest.raises(OutputWriteError, match="no space left on the device") as err:
        plan.write(out)
    rescued = Path(err.value.rescued)
    trajectory, _ = load_trajectory(rescued)
    assert trajectory.a.shape == plan.trajectory.a.shape
    assert sorted(p.name for p in out.iterdir()) == [rescued.name]  # nothing else half-written


def test_full_disk_at_the_cli_is_one_line_and_exit_1(tmp_path, monkeypatch, capsys):
    cfg = tmp_path / "small.yaml"
    cfg.write_text("solver:\n  max_iterations: 10\n")
    monkeypatch.setattr(motion_plan, "write_motion_csv", _full_disk)
    code = main(["optimize", "--robot", "panda", "--config", str(cfg), "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 1
    assert "no space left on the device" in err and "trajectory.rescued-" in err and "Traceback" not in err


def test_validate_writes_its_json_and_figure_both_or_neither(tmp_path, monkeypatch, capsys):
    """A full disk while the figure is written left validation.json without it."""
    from pe_drake.identification.measurements import write_measurement_csv
    import importlib

    validate_module = importlib.import_module("pe_drake.identification.validate_model")

    robot = load_robot("panda")
    trajectory, _ = load_trajectory(DATA / "panda_optimized.json")
    data = model_measurement(robot, trajectory, rate_hz=200.0, duration=8.0, tau_noise_std=0.05, seed=1)
    identify_model(robot, data, IdentifyOptions(method="ols")).write(tmp_path / "model")
    write_measurement_csv(tmp_path / "run.csv", data)
    monkeypatch.setattr(validate_module, "plot_prediction", _full_disk)  # the figure
    code = main(["validate", "--robot", "panda", "--model", str(tmp_path / "model" / "identified.json"),
                 "--data", str(tmp_path / "run.csv"), "--json", str(tmp_path / "v.json"), "--plot", str(tmp_path / "v.png")])
    assert code == 1 and "no space left" in capsys.readouterr().err
    assert not (tmp_path / "v.json").exists() and not (tmp_path / "v.png").exists()
