"""What the playback draws around the robot: the run's capsules, the environment, the camera.

The HTML is decoded as in tests/test_viewer.py (no browser). Meshcat's camera commands are
in three.js coordinates (y up): a Drake point (x, y, z) is (x, z, −y) there.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from pe_drake.exceptions import DataError
from pe_drake.excitation.fourier import FourierTrajectory
from pe_drake.excitation.trajectory_file import save_trajectory
from pe_drake.multibody.robot import load_robot
from pe_drake.multibody.registry import example_robot_data_dir
from pe_drake.viewer import play_trajectory
from pe_drake.viewer_scene import camera_pose
from tests.test_viewer import animation_clips, html_commands, make_trajectory, mesh_cache, track  # noqa: F401

SO101 = "robots/so_arm_description/urdf/so101.urdf"


def objects(commands: list[dict], prefix: str) -> dict[str, dict]:
    return {c["path"]: c["object"] for c in commands if c["type"] == "set_object" and c["path"].startswith(prefix)}


def camera_in_world(commands: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """(camera position, target) in Drake's world of the HTML's camera commands."""
    (position,) = [c["value"] for c in commands
                   if c["type"] == "set_property" and c["path"] == "/Cameras/default/rotated/<object>"]
    (target,) = [c["value"] for c in commands if c["type"] == "set_target"]
    to_world = lambda v: np.array([v[0], -v[2], v[1]])  # noqa: E731  three.js (y up) to Drake (z up)
    return to_world(position), to_world(target)


@pytest.fixture(scope="module")
def panda_traj(tmp_path_factory):
    return make_trajectory(tmp_path_factory.mktemp("panda-scene"), "panda", period=2.0)


def with_entries(path: Path, folder: Path, **entries) -> Path:
    """A copy of a trajectory file in ``folder`` with extra top-level entries."""
    data = json.loads(Path(path).read_text())
    data.update(entries)
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / "trajectory.json"
    out.write_text(json.dumps(data))
    return out


CAPSULES = """capsules:
  - {name: upper, link: panda_link3, radius: 0.07, length: 0.2, xyz: [0, 0, -0.1]}
  - {name: fore, link: panda_link5, radius: 0.06, length: 0.15, xyz: [0, 0.05, -0.1]}
"""


# ---- the run's capsules ---------------------------------------------------------------------
@pytest.mark.parametrize("recorded", [False, True])
def test_the_runs_capsules_are_drawn_one_per_capsule_on_its_link(panda_traj, tmp_path, recorded):
    """``optimize`` writes fitted_capsules.yaml beside trajectory.json (and now records its
    name): ``view`` draws those, not the robot's default capsules."""
    folder = tmp_path / "run"
    entries = {"capsules": "mine.yaml"} if recorded else {}
    path = with_entries(panda_traj[0], folder, **entries)
    (folder / ("mine.yaml" if recorded else "fitted_capsules.yaml")).write_text(CAPSULES)
    playback = play_trajectory(path, html=folder / "p.html", rate=2.0)
    drawn = objects(html_commands(folder / "p.html"), "/drake/capsules/")
    assert sorted(p.split("/")[4] for p in drawn) == ["panda_link3", "panda_link5"]  # named by link
    assert sorted(p.rsplit("/", 1)[1] for p in drawn) == ["fore", "upper"]
    (geometry,) = [o["geometries"][0] for p, o in drawn.items() if p.endswith("/upper")]
    assert geometry["type"] == "CapsuleGeometry" and geometry["radius"] == pytest.approx(0.07)
    assert playback.capsule_file == str((folder / ("mine.yaml" if recorded else "fitted_capsules.yaml")).resolve())


def test_a_config_naming_capsules_wins_over_the_fitted_file(panda_traj, tmp_path):
    folder = tmp_path / "run"
    path = with_entries(panda_traj[0], folder)
    (folder / "fitted_capsules.yaml").write_text(CAPSULES)
    (tmp_path / "own.yaml").write_text(CAPSULES.replace("upper", "own_upper"))
    (tmp_path / "config.yaml").write_text("robot: {capsules: own.yaml}\n")
    play_trajectory(path, config=tmp_path / "config.yaml", html=folder / "p.html", rate=2.0)
    drawn = objects(html_commands(folder / "p.html"), "/drake/capsules/")
    assert sorted(p.rsplit("/", 1)[1] for p in drawn) == ["fore", "own_upper"]


# ---- the environment ------------------------------------------------------------------------
def test_recorded_boxes_and_floor_are_drawn_translucent(panda_traj, tmp_path):
    environment = {"floor": True, "floor_height": -0.05,
                   "boxes": [{"name": "table top", "center": [0.5, 0.0, 0.1], "size": [0.3, 0.8, 0.05]}]}
    path = with_entries(panda_traj[0], tmp_path / "run", environment=environment)
    playback = play_trajectory(path, html=tmp_path / "p.html", rate=2.0)
    commands = html_commands(tmp_path / "p.html")
    drawn = objects(commands, "/drake/environment/")
    assert set(drawn) == {"/drake/environment/floor", "/drake/environment/boxes/table_top"}
    box = drawn["/drake/environment/boxes/table_top"]
    geometry, material = box["geometries"][0], box["materials"][0]
    assert (geometry["width"], geometry["height"], geometry["depth"]) == pytest.approx((0.3, 0.8, 0.05))
    assert material["transparent"] and material["opacity"] < 1
    poses = {c["path"]: np.array(c["matrix"]).reshape(4, 4).T for c in commands if c["type"] == "set_transform"}
    np.testing.assert_allclose(poses["/drake/environment/boxes/table_top"][:3, 3], [0.5, 0.0, 0.1])
    floor = drawn["/drake/environment/floor"]["geometries"][0]
    X_WF = poses["/drake/environment/floor"]
    np.testing.assert_allclose(X_WF[:3, 2], [0, 0, 1], atol=1e-12)  # upright base: a horizontal floor
    assert X_WF[2, 3] + floor["depth"] / 2 == pytest.approx(-0.05, abs=2e-3)  # its top face at floor_height
    lo, hi = playback.extent
    assert floor["width"] >= np.max(hi - lo)  # it spans what the arm sweeps
    assert playback.paths["environment"] == "/drake/environment"


def test_config_environment_drawn_and_no_floor_when_off(panda_traj, tmp_path):
    (tmp_path / "c.yaml").write_text("environment: {floor: false, boxes: [{center: [0.6, 0, 0.3], size: [0.1, 0.1, 0.6]}]}\n")
    play_trajectory(panda_traj[0], config=tmp_path / "c.yaml", html=tmp_path / "p.html", rate=2.0)
    assert set(objects(html_commands(tmp_path / "p.html"), "/drake/environment/")) == {"/drake/environment/boxes/box0"}


@pytest.mark.parametrize("entry", [{"boxes": [{"center": [0, 0]}]}, {"floor_height": float("nan")}, [1, 2]])
def test_malformed_recorded_environment_names_the_file(panda_traj, tmp_path, entry):
    path = with_entries(panda_traj[0], tmp_path / "run", environment=entry)
    with pytest.raises(DataError, match="environment") as err:
        play_trajectory(path, rate=2.0)
    assert str(path) in str(err.value)


# ---- the camera -----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def so101_playback(tmp_path_factory):
    folder = tmp_path_factory.mktemp("so101")
    # Not make_trajectory: it names the file after the robot, here a path.
    rob = load_robot(str(example_robot_data_dir() / SO101))
    rng = np.random.default_rng(0)
    traj = FourierTrajectory(0.1 * rng.standard_normal((rob.n, 3)), 0.1 * rng.standard_normal((rob.n, 3)),
                             rob.nominal_posture(), math.pi)
    path = folder / "trajectory.json"
    save_trajectory(path, rob, traj)
    playback = play_trajectory(path, html=folder / "p.html", rate=2.0)
    return playback, html_commands(folder / "p.html")


@pytest.fixture(scope="module")
def panda_playback(panda_traj, tmp_path_factory):
    html = tmp_path_factory.mktemp("panda-camera") / "p.html"
    return play_trajectory(panda_traj[0], html=html, rate=4.0), html_commands(html)


def test_camera_is_framed_on_the_motion_and_scales_with_the_robot(so101_playback, panda_playback):
    distances = {}
    for name, (playback, commands) in {"so101": so101_playback, "panda": panda_playback}.items():
        camera, target = camera_in_world(commands)
        np.testing.assert_allclose(camera, playback.camera[0], atol=1e-9)
        np.testing.assert_allclose(target, playback.camera[1], atol=1e-9)
        lo, hi = playback.extent
        np.testing.assert_allclose(target, (lo + hi) / 2)
        # The extent holds every link origin of every recorded frame.
        clips, _ = animation_clips(commands)
        for path, clip in clips.items():
            if path.startswith("/drake/visual/"):
                p = track(clip, ".position")[1]
                assert np.all(p >= lo - 1e-9) and np.all(p <= hi + 1e-9), path
        distances[name] = np.linalg.norm(camera - target)
        assert camera[2] > target[2]  # from above
    size = {n: np.linalg.norm(np.subtract(*pb.extent[::-1])) for n, pb in
            (("so101", so101_playback[0]), ("panda", panda_playback[0]))}
    assert size["so101"] < 0.6 * size["panda"]  # a small arm ...
    assert distances["so101"] / distances["panda"] == pytest.approx(size["so101"] / size["panda"], rel=0.3)
    assert distances["so101"] < 1.0  # ... seen from close, not from Meshcat's fixed default


def test_camera_pose_fits_every_corner_in_the_view():
    lo, hi = np.array([-0.1, -0.3, 0.0]), np.array([0.4, 0.2, 0.5])
    camera, target = camera_pose((lo, hi), fill=0.9)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    axis = (target - camera) / np.linalg.norm(target - camera)
    angles = np.degrees(np.arccos((corners - camera) @ axis / np.linalg.norm(corners - camera, axis=1)))
    assert angles.max() <= 0.9 * 75.0 / 2 * 1.0001 * math.sqrt(2)  # inside the cone of the fov's corners
    assert angles.max() >= 0.5 * 75.0 / 2  # and not lost in it
    # Twice the extent about the same centre: twice as far.
    centre = (lo + hi) / 2
    camera2, target2 = camera_pose((centre + 2 * (lo - centre), centre + 2 * (hi - centre)), fill=0.9)
    np.testing.assert_allclose(target2, target)
    np.testing.assert_allclose(camera2 - target2, 2 * (camera - target))
