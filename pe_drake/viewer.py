"""Meshcat playback of an exciting trajectory: robot, collision capsules, CoM and support area.

:func:`play_trajectory` replays a ``trajectory.json`` (one recording of the whole motion, Eq. 50)
and :func:`write_plan_playback` a live motion plan; both can save a self-contained offline HTML
file (``Meshcat.StaticHtml``). What is drawn around the robot lives in :mod:`pe_drake.viewer_scene`.
Imported lazily by the CLI: it loads pydrake's geometry.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import types
from pathlib import Path
from typing import Any

import numpy as np

from pe_drake.exceptions import ConfigError, DataError, UnknownNameError, check_joints
from pe_drake.excitation.ramp import check_within_limits
from pe_drake.excitation.trajectory_file import load_motion, recorded_environment
from pe_drake.io_utils import atomic_write_text
from pe_drake.multibody.capsule_fitting import FITTED_CAPSULES_NAME
from pe_drake.multibody.model_files import is_xacro
from pe_drake.multibody.registry import builtin_robots, resolve_robot_config, robot_display_name
from pe_drake.multibody.robot import Robot
from pe_drake.viewer_scene import (
    COM_PATH,
    ENVIRONMENT_PATH,
    SUPPORT_PATH,
    com_marker_pose,
    draw_environment,
    draw_markers,
    frame_camera,
    motion_extent,
    support_polygon,
)

#: Meshcat paths (under ``/drake``) of what this module draws.
VISUAL_PREFIX = "visual"
CAPSULES_PREFIX = "capsules"

_CAPSULE_RGBA = (1.0, 0.55, 0.0, 0.35)


@dataclasses.dataclass(frozen=True)
class Playback:
    """A recorded trajectory playback."""

    meshcat: Any  # keep a reference to keep its server alive
    url: str
    html: Path | None  # the HTML file written, or None
    num_frames: int  # the whole motion including both ends
    duration: float  # the motion of trajectory.csv (ramps and periods) [s]
    frames_per_second: float  # num_frames - 1 frames per motion [1/s]
    loops: bool  # the animation repeats (no ramps); with ramps it plays once and holds at rest
    robot: Any
    com_xy: np.ndarray  # the whole-body CoM's ground projection, shape (num_frames, 2) [m]
    support_polygon: np.ndarray  # corners (x, y), counter-clockwise, shape (m, 2) [m]; m may be 0
    # Meshcat paths of the layers visual, capsules, com, support, environment (None: not drawn).
    paths: dict[str, str | None]
    # (camera position, target), and (lower, upper) corners of the box the robot sweeps, in
    # world, each shape (3,) [m].
    camera: tuple[np.ndarray, np.ndarray] = (np.zeros(3), np.zeros(3))
    extent: tuple[np.ndarray, np.ndarray] = (np.zeros(3), np.zeros(3))
    capsule_file: str | None = None  # the capsule file drawn


def play_trajectory(trajectory_json: str | Path, *, robot: str | None = None,
                    config: str | Path | None = None, html: str | Path | None = None,
                    show_capsules: bool = True, rate: float = 30.0, meshcat: Any = None,
                    host: str = "localhost", trust_xacro: bool = False) -> Playback:
    """Records the whole motion of trajectory.csv in Meshcat and optionally writes it as HTML.

    Never blocks: the Meshcat server lives as long as the returned ``Playback.meshcat``.

    Args:
        trajectory_json: a ``trajectory.json`` written by ``pe-drake optimize``.
        robot: built-in name or URDF/SDF path; default: the robot named in the file.
        config: YAML config of the robot. Without it (and unless ``robot`` names another
            robot), the joints, locked posture, root link, base pose, capsules and environment
            recorded in the file are used: the posture and obstacles it was optimized for.
        html: write a self-contained offline HTML playback here (atomically).
        rate: frames per second of the recording [1/s].
        meshcat: an existing ``pydrake.geometry.Meshcat`` to draw into; default: a new one.
        host: interface a new Meshcat server listens on ("*": every interface).
        trust_xacro: expand a xacro ``robot`` the caller names (never one the file names) with
            xacro's full Python.

    Raises:
        DataError: missing or malformed trajectory file.
        ConfigError: an invalid rate, a robot that cannot be loaded or lacks the trajectory's
            joints (named).
    """
    if not (isinstance(rate, (int, float)) and math.isfinite(rate) and 0 < rate <= 1000):
        raise ConfigError(f"playback rate must be a number of frames per second in (0, 1000], got {rate!r}")
    motion, data = load_motion(trajectory_json)
    times, fps = frame_times(motion.duration, rate)

    meshcat = _prepare_meshcat(meshcat, host="localhost" if html is not None else host)
    rob, environment = _load_robot_with_visualizers(trajectory_json, data, robot, config, meshcat,
                                                    fps=fps, show_capsules=show_capsules,
                                                    trust_xacro=trust_xacro)
    order = _joint_order(trajectory_json, data, rob)
    check_within_limits(motion, _limits_in_file_order(rob.limits, order), data["joints"], source=str(trajectory_json))
    q = motion.evaluate(times)[0][:, order]
    # With ramps the motion starts and ends at rest at two different postures of the path:
    # looping would jump between them, so it plays once and stays at the final rest.
    loop = motion.ramp_duration == 0.0
    com_xy, support = _record_motion(meshcat, rob, q, fps, loop=loop)
    extent, camera, drawn = _draw_surroundings(meshcat, rob, q, environment)

    html_path = None if html is None else _write_html(meshcat, html)
    capsules = _has_proximity_geometry(rob.scene_graph)
    paths = {
        "visual": f"/drake/{VISUAL_PREFIX}",
        "capsules": f"/drake/{CAPSULES_PREFIX}" if capsules else None,
        "com": f"/drake/{COM_PATH}",
        "support": f"/drake/{SUPPORT_PATH}" if len(support) else None,
        "environment": f"/drake/{ENVIRONMENT_PATH}" if drawn else None,
    }
    return Playback(meshcat=meshcat, url=meshcat.web_url(), html=html_path, num_frames=len(times),
                    duration=motion.duration, frames_per_second=fps, loops=loop, robot=rob,
                    com_xy=com_xy, support_polygon=support, paths=paths, camera=camera,
                    extent=extent, capsule_file=rob.config.capsules or None)


def frame_times(duration: float, rate: float) -> tuple[np.ndarray, float]:
    """(frame times [s], frames per second) of a recording of ``duration`` at about ``rate``.

    Frame k falls exactly at k·T/K, so a periodic clip ends on its first pose and loops seamlessly.
    """
    num_intervals = max(2, int(round(duration * rate)))
    return np.arange(num_intervals + 1) * (duration / num_intervals), num_intervals / duration


def _prepare_meshcat(meshcat: Any, host: str) -> Any:
    """A new Meshcat listening on ``host``, or the given one with our earlier layers and
    recording deleted (recordings merge)."""
    from pydrake.geometry import Meshcat, MeshcatParams  # lazy: pydrake is heavy

    if meshcat is None:
        drake_logger = logging.getLogger("drake")
        level = drake_logger.level
        drake_logger.setLevel(logging.WARNING)  # no "Meshcat listening ..." line from Drake
        try:
            return Meshcat(MeshcatParams(host=host, show_stats_plot=False))
        finally:
            drake_logger.setLevel(level)
    for path in (VISUAL_PREFIX, CAPSULES_PREFIX, COM_PATH, SUPPORT_PATH, ENVIRONMENT_PATH):
        meshcat.Delete(path)
    meshcat.DeleteRecording()
    return meshcat


def _record_motion(meshcat, rob, q: np.ndarray, fps: float, loop: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Records the frames q with the CoM marker, looping or played once and held at its end;
    leaves the still scene at frame 0.

    Returns:
        (CoM ground projection per frame, shape (len(q), 2) [m]; support polygon, shape (m, 2)).
    """
    from pydrake.geometry import MeshcatAnimation  # lazy: pydrake is heavy

    plant, diagram = rob.plant, rob.diagram
    context = diagram.CreateDefaultContext()
    plant_context = plant.GetMyMutableContextFromRoot(context)

    support = support_polygon(rob, plant, plant_context, q[0])
    draw_markers(meshcat, support)

    meshcat.StartRecording(frames_per_second=fps, set_visualizations_while_recording=False)
    com_xy = np.empty((len(q), 2))
    massive = plant.CalcTotalMass(plant_context) > 0
    for k in range(len(q)):
        # Meshcat files a keyframe at floor(time·fps): stamp mid-frame so rounding of k·T/K
        # cannot drop frame k onto k - 1.
        t_record = (k + 0.5) / fps
        context.SetTime(t_record)
        plant.SetPositions(plant_context, q[k])
        diagram.ForcedPublish(context)
        # Drake refuses the CoM of a massless model (no inertials): the robot is still drawn
        p_WCcm = plant.CalcCenterOfMassPositionInWorld(plant_context) if massive else np.zeros(3)
        com_xy[k] = p_WCcm[:2]
        meshcat.SetTransform(COM_PATH, com_marker_pose(com_xy[k]), t_record)
    meshcat.StopRecording()
    animation = meshcat.get_mutable_recording()
    if loop:
        animation.set_loop_mode(MeshcatAnimation.LoopMode.kLoopRepeat)
        animation.set_repetitions(1_000_000)  # "forever": the periodic part of the motion
    else:
        animation.set_loop_mode(MeshcatAnimation.LoopMode.kLoopOnce)
        animation.set_clamp_when_finished(True)
    meshcat.PublishRecording()
    # The still scene (before the animation starts, or when it is paused) shows t = 0.
    context.SetTime(0.0)
    plant.SetPositions(plant_context, q[0])
    diagram.ForcedPublish(context)
    meshcat.SetTransform(COM_PATH, com_marker_pose(com_xy[0]))
    return com_xy, support


def _draw_surroundings(meshcat, rob, q: np.ndarray, environment):
    """Draws the environment and frames the camera; returns (extent, camera, {object: path})."""
    extent = motion_extent(rob, q)
    drawn = draw_environment(meshcat, rob, environment, extent)
    return extent, frame_camera(meshcat, extent), drawn


def _load_robot_with_visualizers(path, data, robot: Robot, config, meshcat, *, fps: float, show_capsules: bool,
                                 trust_xacro: bool = False):
    """The robot of a trajectory file, with Meshcat visualizers in its diagram, and the
    environment to draw around it."""
    recorded = data.get("robot")
    name = robot or recorded
    if not name:
        raise DataError("the file names no robot: pass --robot", file=str(path))
    source = name
    if robot is None and name not in builtin_robots() and data.get("model"):
        source = str(data["model"])  # a robot loaded from a model file: its stem is not a name
        if "://" not in source and not Path(source).is_absolute():  # recorded relative to the file
            source = str(Path(path).resolve().parent / source)
    if robot is None and is_xacro(str(source)):
        raise ConfigError(
            f"trajectory '{path}' names the xacro model '{source}': a xacro file is a program, and pe_drake "
            "expands only one you name yourself; pass --robot (the .xacro or its expanded URDF) or --config")
    full = resolve_robot_config(source, config)
    cfg, environment = full.robot, full.environment
    if trust_xacro:
        cfg = dataclasses.replace(cfg, trust_xacro=True)
    from_file = config is None and (robot is None or robot == recorded)
    if from_file:
        cfg = _config_from_file(cfg, data)
        environment = recorded_environment(data, environment, path)
    if robot is None or robot == recorded:
        cfg = dataclasses.replace(cfg, capsules=_run_capsule_file(cfg.capsules, data, path, from_file))

    display = robot_display_name(name)
    hook = _visualizer_hook(meshcat, fps, show_capsules)
    try:
        return Robot(display, cfg, obj_visuals=True, builder_hook=hook), environment
    except UnknownNameError as err:
        if not from_file or err.kind != "joint":
            raise
        raise ConfigError(
            f"trajectory '{path}' names joint '{err.name}', which robot "
            f"'{display}' does not have; its joints: {', '.join(err.choices)}. Pass the --robot "
            "the trajectory was optimized for."
        ) from err


def _visualizer_hook(meshcat, fps: float, show_capsules: bool):
    """A ``Robot`` builder hook adding Meshcat visualizers of the illustration geometry and of
    the proximity geometry (capsules) when there is any."""
    from pydrake.geometry import MeshcatVisualizer, MeshcatVisualizerParams, Rgba, Role  # lazy: pydrake is heavy

    def add_visualizers(builder, plant, scene_graph) -> None:
        common = {"publish_period": 1.0 / fps, "delete_on_initialization_event": False}
        params = MeshcatVisualizerParams(role=Role.kIllustration, prefix=VISUAL_PREFIX, **common)
        MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, params)
        if _has_proximity_geometry(scene_graph):
            params = MeshcatVisualizerParams(role=Role.kProximity, prefix=CAPSULES_PREFIX,
                                             default_color=Rgba(*_CAPSULE_RGBA),
                                             visible_by_default=show_capsules, **common)
            MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, params)

    return add_visualizers


def _has_proximity_geometry(scene_graph) -> bool:
    """Whether the scene has proximity geometry (the capsules layer)."""
    from pydrake.geometry import Role  # lazy: pydrake is heavy

    return scene_graph.model_inspector().NumGeometriesWithRole(Role.kProximity) > 0


def _run_capsule_file(configured: str, data: dict, path, from_file: bool) -> str:
    """The capsule file the run that wrote the trajectory checked, or ``configured``.

    That is the file the trajectory records, else a ``fitted_capsules.yaml`` beside it. Without
    ``--config`` (``from_file``) it wins over the robot's default capsules; with one,
    ``robot.capsules`` wins.
    """
    if configured and not from_file:
        return configured
    recorded = data.get("capsules", FITTED_CAPSULES_NAME)
    if not (isinstance(recorded, str) and recorded):
        return configured
    candidate = Path(path).resolve().parent / recorded
    # normpath: a recorded '../../models/x.yaml' is printed as the file's own path
    return os.path.normpath(candidate) if candidate.is_file() else configured


def _config_from_file(cfg, data: dict):
    """The robot config set to the file's excited joints, locked posture, root link and base
    pose (limit tables kept for those joints only)."""
    joints = [str(j) for j in data["joints"]]
    keep = set(joints)
    changes: dict[str, Any] = {"joints": joints}
    for table in ("position_limits", "velocity_limits", "acceleration_limits", "effort_limits",
                  "nominal_positions"):
        changes[table] = {j: v for j, v in getattr(cfg, table).items() if j in keep}
    locked = {j: v for j, v in cfg.locked_positions.items() if j not in keep}
    locked.update({j: float(v) for j, v in (data.get("locked_positions") or {}).items() if j not in keep})
    changes["locked_positions"] = locked
    pose = data.get("base_pose") or {}
    if len(pose.get("position", ())) == 3 and len(pose.get("quaternion_wxyz", ())) == 4:
        changes["base_position"] = [float(x) for x in pose["position"]]
        changes["base_quaternion_wxyz"] = [float(x) for x in pose["quaternion_wxyz"]]
    if data.get("root_link"):
        changes["root_link"] = str(data["root_link"])
    return dataclasses.replace(cfg, **changes)


def _limits_in_file_order(limits, order: np.ndarray):
    """The robot's limits rearranged to the trajectory file's joint order (``order[k]`` is the
    file column of robot joint k, a permutation)."""
    inverse = np.argsort(order)
    return types.SimpleNamespace(**{name: np.asarray(getattr(limits, name))[inverse]
                                    for name in ("q_lower", "q_upper", "v_max", "vd_max")})


def _joint_order(path, data: dict, rob) -> np.ndarray:
    """Column of the trajectory for each plant position; JointMismatchError on a joint mismatch."""
    joints = [str(j) for j in data["joints"]]
    check_joints(rob, joints, file=str(path), what="the trajectory", any_order=True)
    return np.array([joints.index(j) for j in rob.joint_names])


def write_plan_playback(plan, html_path: str | Path, *, show_capsules: bool = True, rate: float = 30.0) -> Path:
    """Writes the HTML playback of a live :class:`~pe_drake.excitation.motion_plan.MotionPlan`
    (``pe-drake optimize``): its robot config, capsules, environment and motion."""
    motion = plan.motion
    times, fps = frame_times(motion.duration, rate)
    meshcat = _prepare_meshcat(None, host="localhost")
    rob = Robot(plan.robot.name, plan.config.robot, obj_visuals=True, builder_hook=_visualizer_hook(meshcat, fps, show_capsules))
    q = motion.evaluate(times)[0]  # the same config: the same joints in the same order
    _record_motion(meshcat, rob, q, fps, loop=motion.ramp_duration == 0.0)
    _draw_surroundings(meshcat, rob, q, plan.config.environment)
    return _write_html(meshcat, html_path)


def _write_html(meshcat, path: str | Path) -> Path:
    """Writes the scene and recording as a self-contained offline HTML file, atomically."""
    atomic_write_text(path, meshcat.StaticHtml())
    return Path(path)
