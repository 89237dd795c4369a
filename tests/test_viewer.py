"""Meshcat playback HTML of pe_drake.viewer, checked by decoding the file (no browser).

Drake's ``Meshcat.StaticHtml`` embeds every scene command as a base64 msgpack blob,
``fetch("data:application/octet-binary;base64,...")``, replayed by the page: ``set_object``
(geometry, meshes inlined as file text), ``set_transform``, ``set_property`` and one
``set_animation`` whose clips hold one keyframe per recorded frame for each animated path.
The tests decode those blobs with the small msgpack reader below.
"""

from __future__ import annotations

import base64
import json
import re
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from pe_drake.exceptions import ConfigError, DataError
from pe_drake.excitation.fourier import FourierTrajectory
from pe_drake.excitation.ramp import RampedMotion
from pe_drake.excitation.trajectory_file import save_trajectory
from pe_drake.multibody.meshes import CACHE_ENV
from pe_drake.multibody.robot import load_robot
from pe_drake.viewer import play_trajectory
from pe_drake.viewer_scene import COM_PATH, convex_hull_2d

# ---- reading the HTML -----------------------------------------------------------------------
_BLOB = re.compile(r'fetch\("data:application/octet-binary;base64,([A-Za-z0-9+/=]*)"\)')


def msgpack_unpack(data: bytes):
    """Decodes one msgpack object (the subset Meshcat writes, which is all but timestamps)."""
    value, end = _unpack(memoryview(data), 0)
    assert end == len(data)
    return value


def _unpack(b, i):
    c = b[i]
    i += 1
    if c <= 0x7F:
        return c, i
    if c >= 0xE0:
        return c - 256, i
    if 0x80 <= c <= 0x8F:
        return _unpack_map(b, i, c & 0x0F)
    if 0x90 <= c <= 0x9F:
        return _unpack_array(b, i, c & 0x0F)
    if 0xA0 <= c <= 0xBF:
        n = c & 0x1F
        return str(b[i : i + n], "utf-8"), i + n
    if c in (0xC0, 0xC2, 0xC3):
        return {0xC0: None, 0xC2: False, 0xC3: True}[c], i
    scalars = {
        0xCA: ">f",
        0xCB: ">d",
        0xCC: ">B",
        0xCD: ">H",
        0xCE: ">I",
        0xCF: ">Q",
        0xD0: ">b",
        0xD1: ">h",
        0xD2: ">i",
        0xD3: ">q",
    }
    if c in scalars:
        return struct.unpack_from(scalars[c], b, i)[0], i + struct.calcsize(scalars[c])
    sized = {
        0xC4: (">B", "bin"),
        0xC5: (">H", "bin"),
        0xC6: (">I", "bin"),
        0xD9: (">B", "str"),
        0xDA: (">H", "str"),
        0xDB: (">I", "str"),
        0xDC: (">H", "array"),
        0xDD: (">I", "array"),
        0xDE: (">H", "map"),
        0xDF: (">I", "map"),
        0xC7: (">B", "ext"),
        0xC8: (">H", "ext"),
        0xC9: (">I", "ext"),
    }
    if c in sized:
        fmt, kind = sized[c]
        n = struct.unpack_from(fmt, b, i)[0]
        i += struct.calcsize(fmt)
        if kind == "array":
            return _unpack_array(b, i, n)
        if kind == "map":
            return _unpack_map(b, i, n)
        if kind == "ext":  # Meshcat packs typed arrays as ext: (type, raw bytes)
            return ("ext", b[i], bytes(b[i + 1 : i + 1 + n])), i + 1 + n
        raw = bytes(b[i : i + n])
        return (raw.decode() if kind == "str" else raw), i + n
    fixext = {0xD4: 1, 0xD5: 2, 0xD6: 4, 0xD7: 8, 0xD8: 16}
    if c in fixext:
        n = fixext[c]
        return ("ext", b[i], bytes(b[i + 1 : i + 1 + n])), i + 1 + n
    raise ValueError(f"msgpack byte 0x{c:02x} at {i - 1}")


def _unpack_array(b, i, n):
    out = []
    for _ in range(n):
        value, i = _unpack(b, i)
        out.append(value)
    return out, i


def _unpack_map(b, i, n):
    out = {}
    for _ in range(n):
        key, i = _unpack(b, i)
        out[key], i = _unpack(b, i)
    return out, i


def html_commands(path: Path) -> list[dict]:
    text = Path(path).read_text()
    assert text.lstrip().startswith("<!DOCTYPE html>")
    return [msgpack_unpack(base64.b64decode(blob)) for blob in _BLOB.findall(text)]


def animation_clips(commands: list[dict]) -> dict[str, dict]:
    """{path: {track name: keys}} of the one recorded animation, and its options."""
    (animation,) = [c for c in commands if c["type"] == "set_animation"]
    clips = {a["path"]: a["clip"] for a in animation["animations"]}
    return clips, animation["options"]


def track(clip: dict, name: str) -> tuple[np.ndarray, np.ndarray]:
    (t,) = [t for t in clip["tracks"] if t["name"] == name]
    return np.array([k["time"] for k in t["keys"]]), np.array([k["value"] for k in t["keys"]])


# ---- fixtures -------------------------------------------------------------------------------
@pytest.fixture(scope="module", autouse=True)
def mesh_cache(tmp_path_factory):
    """Converted meshes in a test folder, not the user's cache."""
    mp = pytest.MonkeyPatch()
    mp.setenv(CACHE_ENV, str(tmp_path_factory.mktemp("mesh-cache")))
    yield
    mp.undo()


def make_trajectory(folder: Path, name: str, period: float, amplitude: float = 0.1, seed: int = 0):
    robot = load_robot(name)
    rng = np.random.default_rng(seed)
    n, N = robot.n, 3
    traj = FourierTrajectory(
        amplitude * rng.standard_normal((n, N)) / np.arange(1, N + 1),
        amplitude * rng.standard_normal((n, N)) / np.arange(1, N + 1),
        robot.nominal_posture(),
        2 * np.pi / period,
    )
    path = folder / f"{name}_trajectory.json"
    save_trajectory(path, robot, traj)
    return path, robot, traj


@pytest.fixture(scope="module")
def panda_traj(tmp_path_factory):
    return make_trajectory(tmp_path_factory.mktemp("panda"), "panda", period=2.0)


@pytest.fixture(scope="module")
def panda_html(panda_traj, tmp_path_factory):
    path = tmp_path_factory.mktemp("panda-html") / "panda.html"
    start = time.perf_counter()
    playback = play_trajectory(panda_traj[0], html=path, rate=20.0)
    print(
        f"\npanda HTML: {path.stat().st_size / 1e6:.1f} MB, {playback.num_frames} frames, "
        f"{time.perf_counter() - start:.2f} s"
    )
    return playback, html_commands(path)


@pytest.fixture(scope="module")
def g1_html(tmp_path_factory):
    folder = tmp_path_factory.mktemp("g1")
    path_json, robot, traj = make_trajectory(folder, "g1", period=8.0, amplitude=0.15)
    path = folder / "g1.html"
    start = time.perf_counter()
    playback = play_trajectory(path_json, html=path, rate=30.0)
    print(
        f"\nG1 HTML: {path.stat().st_size / 1e6:.1f} MB, {playback.num_frames} frames, "
        f"{time.perf_counter() - start:.2f} s (meshes converted on first use)"
    )
    return playback, html_commands(path), traj


def body_poses(robot, traj, times, body: str) -> tuple[np.ndarray, np.ndarray]:
    """Positions (T, 3) and quaternions xyzw (T, 4) of a body along the trajectory."""
    q = traj.evaluate(times)[0]
    body = robot.plant.GetBodyByName(body)
    p, quat = [], []
    for qk in q:
        robot.plant.SetPositions(robot.plant_context, qk)
        X = robot.plant.EvalBodyPoseInWorld(robot.plant_context, body)
        p.append(X.translation())
        w, x, y, z = X.rotation().ToQuaternion().wxyz()
        quat.append([x, y, z, w])
    return np.array(p), np.array(quat)


# ---- the recorded animation -----------------------------------------------------------------
def test_panda_animation_has_one_keyframe_per_frame_over_one_period(panda_traj, panda_html):
    path_json, robot, traj = panda_traj
    playback, commands = panda_html
    clips, options = animation_clips(commands)
    assert playback.num_frames == 41 and playback.duration == pytest.approx(2.0)
    assert options["loopMode"] == 2201  # THREE.LoopRepeat: a periodic motion loops
    links = [f"/drake/visual/panda/panda_link{k}" for k in range(1, 8)] + ["/drake/visual/panda/panda_hand"]
    for path in links + [f"/drake/{COM_PATH}"]:
        clip = clips[path]
        frames, _ = track(clip, ".position")
        np.testing.assert_array_equal(frames, np.arange(playback.num_frames))  # no frame lost
        # The clip's last keyframe is one period after the first.
        assert frames[-1] / clip["fps"] == pytest.approx(playback.duration)

    # Keyframes are the plant's body poses along q(t) of Eq. (50).
    times = np.arange(playback.num_frames) / clips[links[0]]["fps"]
    for body in ("panda_link4", "panda_link7"):
        p_expected, quat_expected = body_poses(robot, traj, times, body)
        _, p = track(clips[f"/drake/visual/panda/{body}"], ".position")
        _, quat = track(clips[f"/drake/visual/panda/{body}"], ".quaternion")
        np.testing.assert_allclose(p, p_expected, atol=1e-9)
        np.testing.assert_allclose(np.abs(np.sum(quat * quat_expected, axis=1)), 1.0, atol=1e-9)
        assert np.ptp(p, axis=0).max() > 1e-3  # the link does move
    np.testing.assert_allclose(p[0], p[-1], atol=1e-9)  # periodic: the loop closes


def test_com_marker_follows_the_whole_body_com(panda_traj, panda_html):
    _, robot, traj = panda_traj
    playback, commands = panda_html
    clips, _ = animation_clips(commands)
    _, p = track(clips[f"/drake/{COM_PATH}"], ".position")
    times = np.arange(playback.num_frames) / clips[f"/drake/{COM_PATH}"]["fps"]
    expected = []
    for qk in traj.evaluate(times)[0]:
        robot.plant.SetPositions(robot.plant_context, qk)
        expected.append(robot.plant.CalcCenterOfMassPositionInWorld(robot.plant_context)[:2])
    np.testing.assert_allclose(p[:, :2], expected, atol=1e-9)
    np.testing.assert_allclose(p[:, :2], playback.com_xy, atol=1e-12)
    assert np.all(np.abs(p[:, 2]) < 0.01)  # on the ground
    objects = {c["path"] for c in commands if c["type"] == "set_object"}
    assert f"/drake/{COM_PATH}/disc" in objects


def test_panda_html_embeds_the_meshes(panda_html):
    playback, commands = panda_html
    meshes = {
        c["path"]: c["object"]["geometries"][0]
        for c in commands
        if c["type"] == "set_object" and c["path"].startswith("/drake/visual/")
    }
    for k in range(8):
        (geometry,) = [g for p, g in meshes.items() if f"/panda_link{k}/" in p]
        assert geometry["type"] == "_meshfile_geometry" and geometry["format"] == "dae"
        assert len(geometry["data"]) > 1000
    assert playback.paths["support"] is None  # an arm has no support points


def proximity_count(robot) -> int:
    from pydrake.geometry import Role

    return robot.scene_graph.model_inspector().NumGeometriesWithRole(Role.kProximity)


@pytest.mark.parametrize("fixture", ["panda_html", "g1_html"])
def test_capsule_layer_matches_the_scene_graph(fixture, request):
    """Every proximity geometry of the robot (its capsule file, if any) is drawn, none else."""
    playback, commands = request.getfixturevalue(fixture)[:2]
    drawn = [
        c["path"] for c in commands if c["type"] == "set_object" and c["path"].startswith("/drake/capsules/")
    ]
    assert len(drawn) == proximity_count(playback.robot)
    assert (playback.paths["capsules"] is not None) == bool(drawn)


def test_g1_html_has_obj_meshes_support_area_and_com(g1_html):
    playback, commands, traj = g1_html
    objects = {c["path"]: c["object"] for c in commands if c["type"] == "set_object"}
    model = "/drake/visual/g1_29dof_rev_1_0"
    arm_meshes = [o["geometries"][0] for p, o in objects.items() if p.startswith(f"{model}/left_elbow_link/")]
    assert arm_meshes and arm_meshes[0]["format"] == "obj" and "\nv " in arm_meshes[0]["data"]
    assert sum(1 for p in objects if p.startswith(model)) == 35  # every visual, none skipped

    clips, _ = animation_clips(commands)
    for arm in ("left", "right"):
        frames, p = track(clips[f"{model}/{arm}_wrist_yaw_link"], ".position")
        assert len(frames) == playback.num_frames == 241
        assert np.ptp(p, axis=0).max() > 1e-2

    # Support area: both feet's points, a quadrilateral around the CoM projection.
    assert "/drake/support_area/area" in objects and "/drake/support_area/outline" in objects
    polygon = playback.support_polygon
    assert polygon.shape == (4, 2)
    assert np.ptp(polygon[:, 1]) == pytest.approx(0.297, abs=0.01)  # two feet apart
    _, com = track(clips[f"/drake/{COM_PATH}"], ".position")
    edges = np.roll(polygon, -1, axis=0) - polygon
    rel = com[:, None, :2] - polygon[None]
    inside = edges[None, :, 0] * rel[..., 1] - edges[None, :, 1] * rel[..., 0] > 0
    assert inside.all()


def test_capsule_layer_drawn_and_toggleable(panda_traj, tmp_path, monkeypatch):
    """Whatever proximity geometry the scene graph has goes to its own Meshcat layer."""
    from pydrake.geometry import Capsule
    from pydrake.math import RigidTransform
    from pydrake.multibody.plant import CoulombFriction

    from pe_drake.multibody.robot import Robot

    def register(self, plant, scene_graph):
        for link in ("panda_link3", "panda_link5"):
            plant.RegisterCollisionGeometry(
                plant.GetBodyByName(link),
                RigidTransform(),
                Capsule(0.06, 0.2),
                f"{link}_capsule",
                CoulombFriction(0.5, 0.5),
            )
        self.capsules = ()

    monkeypatch.setattr(Robot, "_scene_graph_builder_hook", register)
    for show in (True, False):
        html = tmp_path / f"capsules_{show}.html"
        playback = play_trajectory(panda_traj[0], html=html, show_capsules=show, rate=5.0)
        assert playback.html == html
        commands = html_commands(html)
        capsules = [
            c for c in commands if c["type"] == "set_object" and c["path"].startswith("/drake/capsules/")
        ]
        assert {c["path"].split("/")[4] for c in capsules} == {"panda_link3", "panda_link5"}
        visible = [
            c["value"]
            for c in commands
            if c["type"] == "set_property" and c["path"] == "/drake/capsules" and c["property"] == "visible"
        ]
        assert visible == [show]
        clips, _ = animation_clips(commands)
        assert "/drake/capsules/panda/panda_link5" in clips


def test_reused_meshcat_does_not_merge_recordings(panda_traj, tmp_path):
    from pydrake.geometry import Meshcat

    meshcat = Meshcat()
    play_trajectory(panda_traj[0], rate=10.0, meshcat=meshcat)
    playback = play_trajectory(panda_traj[0], rate=4.0, meshcat=meshcat, html=tmp_path / "p.html")
    clips, _ = animation_clips(html_commands(playback.html))
    frames, _ = track(clips[f"/drake/{COM_PATH}"], ".position")
    assert len(frames) == playback.num_frames == 9


def test_html_written_atomically(panda_traj, tmp_path):
    html = tmp_path / "out" / "play.html"
    play_trajectory(panda_traj[0], html=html, rate=5.0)
    assert [p.name for p in html.parent.iterdir()] == ["play.html"]


def test_convex_hull_2d():
    rng = np.random.default_rng(1)
    points = rng.uniform(-1, 1, (200, 2))
    corners = np.array([[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]])
    hull = convex_hull_2d(np.vstack([points, corners, [[0.0, -2.0]]]))  # a collinear point
    np.testing.assert_allclose(hull, corners)


# ---- CLI ------------------------------------------------------------------------------------
def test_view_command_writes_html(panda_traj, tmp_path, capsys):
    from pe_drake.cli import main

    html = tmp_path / "view.html"
    assert main(["view", str(panda_traj[0]), "--html", str(html), "--rate", "5", "--no-capsules"]) == 0
    assert html.is_file() and "wrote" in capsys.readouterr().out


def test_view_command_serves_until_ctrl_c(panda_traj, monkeypatch, capsys):
    import pe_drake.cli.view as view
    from pe_drake.cli import main

    def interrupt(_):
        raise KeyboardInterrupt

    monkeypatch.setattr(view.time, "sleep", interrupt)
    assert main(["view", str(panda_traj[0]), "--rate", "5"]) == 0
    assert "http://" in capsys.readouterr().out


# ---- errors ---------------------------------------------------------------------------------
def test_missing_or_invalid_trajectory_raises_data_error(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        play_trajectory(tmp_path / "none.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(DataError, match="not valid JSON"):
        play_trajectory(bad)
    bad.write_text(json.dumps({"robot": "panda", "joints": ["panda_joint1"], "omega": 1.0}))
    with pytest.raises(DataError, match="missing key 'a'"):
        play_trajectory(bad)


def test_robot_mismatch_names_the_joints(panda_traj, tmp_path):
    with pytest.raises(ConfigError, match="panda_joint1") as err:
        play_trajectory(panda_traj[0], robot="ur5")
    assert "shoulder_pan_joint" in str(err.value)  # the robot's joints are listed too

    data = json.loads(Path(panda_traj[0]).read_text())
    data["joints"][2] = "elbow_of_another_robot"
    renamed = tmp_path / "renamed.json"
    renamed.write_text(json.dumps(data))
    with pytest.raises(ConfigError, match="elbow_of_another_robot"):
        play_trajectory(renamed)


def test_bad_rate_raises_config_error(panda_traj):
    with pytest.raises(ConfigError, match="rate"):
        play_trajectory(panda_traj[0], rate=0.0)


def test_import_pe_drake_stays_headless():
    code = (
        "import sys, pe_drake, pe_drake.viewer, pe_drake.multibody.meshes; "
        "bad = [m for m in sys.modules if m.startswith('pydrake')]; "
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_ramped_motion_plays_once_and_holds_its_final_rest(panda_traj, tmp_path):
    """A motion with ramps starts and ends at rest at two different postures: looping it would
    jump from the last to the first, so it plays once and stays at its last frame."""
    _, robot, traj = panda_traj
    path = tmp_path / "ramped.json"
    motion = RampedMotion(traj, periods=1, ramp_duration=1.0, phase=0.3)
    save_trajectory(path, robot, traj, **motion.to_dict())
    playback = play_trajectory(path, html=tmp_path / "ramped.html", rate=20.0)
    _, options = animation_clips(html_commands(tmp_path / "ramped.html"))
    assert not playback.loops and playback.duration == pytest.approx(motion.duration)
    assert options["loopMode"] == 2200 and options["clampWhenFinished"]  # THREE.LoopOnce
    q_start, q_end = motion.evaluate(np.array([0.0, motion.duration]))[0]
    assert np.abs(q_start - q_end).max() > 1e-3  # the two rest postures differ


def test_view_names_a_recorded_capsule_file_by_its_own_path(panda_traj, tmp_path, monkeypatch, capsys):
    """trajectory.json records the capsule file relative to its folder ('../../models/x.yaml'):
    `view` printed it joined to that folder, '/out/panda/../../…/panda_capsules.yaml'."""
    import json
    import os

    import pe_drake.cli.view as view
    from pe_drake.cli import main
    from pe_drake.multibody.registry import models_dir

    capsules = models_dir() / "panda_capsules.yaml"
    folder = tmp_path / "out" / "panda"
    folder.mkdir(parents=True)
    data = json.loads(panda_traj[0].read_text())
    data["capsules"] = os.path.relpath(capsules, folder)
    (folder / "trajectory.json").write_text(json.dumps(data))
    monkeypatch.setattr(view.time, "sleep", lambda _: (_ for _ in ()).throw(KeyboardInterrupt))
    assert main(["view", str(folder / "trajectory.json"), "--rate", "5"]) == 0
    out = capsys.readouterr().out
    assert f"capsules from {os.path.normpath(capsules)} (shown)" in out, out
