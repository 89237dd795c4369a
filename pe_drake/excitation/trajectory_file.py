"""Reading and writing ``trajectory.json`` and ``trajectory.csv``.

trajectory.json keys: ``robot``, ``model`` (relative to the file's folder; absolute in older
files), ``joints``, ``omega`` [rad/s], ``harmonics``, ``a`` and ``b`` (n × N), ``q0`` (n),
``duration`` [s], ``locked_positions``, ``base_pose`` {``position``, ``quaternion_wxyz``} of
``root_link`` in world, ``cond``; q_j(t) = Σ_k a_jk sin(kωt) + b_jk cos(kωt) + q0_j (Eq. 50).
Optional: ``periods``, ``ramp_duration``, ``phase``, ``motion_duration``, ``layout``
(:mod:`pe_drake.excitation.ramp`; without them: one period, no ramps), ``capsules`` (the
capsule file the run checked, or null) and ``environment`` (``floor``, ``floor_height``,
``boxes``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pe_drake import limits
from pe_drake.config import BoxConfig, EnvironmentConfig
from pe_drake.exceptions import ConfigError, DataError
from pe_drake.excitation.fourier import FourierTrajectory
from pe_drake.excitation.ramp import CSV_DIGITS, RampedMotion, ramped_motion_from_dict
from pe_drake.io_utils import atomic_write_text, final_folder, loads_json, portable_path
from pe_drake.output_set import check_output_set

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Physical range of ω [rad/s]: periods from 0.1 s to 10 minutes.
OMEGA_RANGE = (2 * np.pi / 600.0, 2 * np.pi / 0.1)


def save_trajectory(path: str | Path, robot: Robot, trajectory: FourierTrajectory, **extra: Any) -> None:
    """Writes trajectory.json atomically, the model's and capsules' paths relative to its folder
    (no user's folder in a shared file)."""
    folder = final_folder(path)
    if isinstance(extra.get("capsules"), str):  # relative like the model: view reads it against the folder
        extra["capsules"] = portable_path(extra["capsules"], folder)
    pose = robot.base_pose
    data = {
        "robot": robot.name, "model": portable_path(robot.model_path, folder),
        "joints": list(robot.joint_names), "omega": trajectory.omega,
        "harmonics": trajectory.harmonics, "a": trajectory.a.tolist(), "b": trajectory.b.tolist(),
        "q0": trajectory.q0.tolist(), "duration": trajectory.period,
        "locked_positions": dict(robot.locked_positions), "root_link": robot.root_link,
        "base_pose": {"position": np.asarray(pose.translation()).tolist(),
                      "quaternion_wxyz": pose.rotation().ToQuaternion().wxyz().tolist()},
        **extra,
    }
    atomic_write_text(path, json.dumps(data, indent=2))


def load_trajectory(path: str | Path) -> tuple[FourierTrajectory, dict[str, Any]]:
    """Reads trajectory.json: the trajectory and the whole JSON dict; DataError for a missing
    file or key, or inconsistent shapes."""
    path = Path(path)
    problem = limits.input_file_problem(path)
    if problem:
        raise DataError(f"trajectory file {problem}", file=str(path))
    size = path.stat().st_size
    if size > limits.in_bytes(limits.TRAJECTORY):
        raise DataError(f"{size / 2**20:.1f} MB is more than a trajectory file holds: over "
                        f"{limits.describe(limits.TRAJECTORY)}", file=str(path))
    check_output_set(path)  # not a trajectory.json beside another run's trajectory.csv
    try:
        data = loads_json(path.read_text(), str(path))
    except json.JSONDecodeError as err:
        raise DataError(f"not valid JSON: {err}", file=str(path)) from err
    if not isinstance(data, dict):
        raise DataError("expected a JSON object with joints, omega, a, b, q0", file=str(path))
    for key in ("joints", "omega", "a", "b", "q0"):
        if key not in data:
            raise DataError(f"missing key '{key}'", file=str(path))
    omega = data["omega"]
    if isinstance(omega, bool) or not isinstance(omega, (int, float)) or not np.isfinite(omega):
        raise DataError(f"'omega' must be a finite number [rad/s], got {omega!r}", file=str(path))
    if not OMEGA_RANGE[0] <= omega <= OMEGA_RANGE[1]:
        raise DataError(f"'omega' = {omega!r} rad/s is outside [{OMEGA_RANGE[0]:.4g}, "
                        f"{OMEGA_RANGE[1]:.4g}] (periods from 0.1 s to 600 s)", file=str(path))
    if not isinstance(data["joints"], list) or not all(isinstance(j, str) for j in data["joints"]):
        raise DataError("'joints' must be a list of joint names", file=str(path))
    arrays = {}
    for key in ("a", "b", "q0"):
        try:
            arrays[key] = np.asarray(data[key], float)
        except (TypeError, ValueError):
            raise DataError(f"'{key}' must hold numbers only", file=str(path)) from None
    a, b, q0 = arrays["a"], arrays["b"], arrays["q0"]
    n = len(data["joints"])
    if a.ndim != 2 or a.shape[0] != n or b.shape != a.shape or q0.shape != (n,):
        raise DataError(f"a {a.shape}, b {b.shape}, q0 {q0.shape} do not match {n} joints",
                        file=str(path))
    if a.shape[1] > limits.value(limits.HARMONICS):
        raise DataError(f"{a.shape[1]} harmonics; at most {limits.value(limits.HARMONICS):g} are read: "
                        f"{limits.describe(limits.HARMONICS)}", file=str(path))
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and np.all(np.isfinite(q0))):
        raise DataError("coefficients contain NaN or inf", file=str(path))
    return FourierTrajectory(a, b, q0, float(omega)), data


def write_motion_csv(path: str | Path, joints: tuple[str, ...] | list[str], motion: RampedMotion, rate: float) -> None:
    """Writes t, q.<joint>, v.<joint>, vdot.<joint> of the whole motion (ramp-in, N periods,
    ramp-out) sampled at ``rate`` [Hz] from t = 0 (at rest) to the end (at rest)."""
    if not rate > 0:
        raise ValueError(f"sample rate must be positive, got {rate}")
    t = motion.sample_times(rate)
    q, v, vd = motion.evaluate(t)
    header = ["t"] + [f"q.{j}" for j in joints] + [f"v.{j}" for j in joints] + [f"vdot.{j}" for j in joints]
    table = np.column_stack([t, q, v, vd])
    lines = [",".join(header)] + [",".join(f"{x:.{CSV_DIGITS}g}" for x in row) for row in table]
    atomic_write_text(path, "\n".join(lines) + "\n")


def load_motion(path: str | Path) -> tuple[RampedMotion, dict[str, Any]]:
    """Reads trajectory.json as the motion trajectory.csv holds (ramps and periods included);
    DataError as :func:`load_trajectory`, or for a bad ``periods``/``ramp_duration``/``phase``."""
    trajectory, data = load_trajectory(path)
    try:
        return ramped_motion_from_dict(trajectory, data, source=str(path)), data
    except ConfigError as err:
        raise DataError(str(err).split(": ", 1)[-1], file=str(path)) from err


def environment_record(environment: EnvironmentConfig) -> dict[str, Any]:
    """The ``environment`` entry of trajectory.json: the obstacles the motion was optimized
    against (what ``pe-drake view`` draws)."""
    height = environment.floor_height
    return {"floor": bool(environment.floor),
            "floor_height": None if height is None else float(height),
            "boxes": [{"name": b.name, "center": [float(x) for x in b.center],
                       "size": [float(x) for x in b.size]} for b in environment.boxes]}


def recorded_environment(data: dict[str, Any], default: EnvironmentConfig, source: str | Path) -> EnvironmentConfig:
    """The environment a trajectory file records (:func:`environment_record`), or ``default``
    for a file without one; DataError for a malformed entry."""
    entry = data.get("environment")
    if entry is None:
        return default
    try:
        height = entry.get("floor_height")
        boxes = [BoxConfig(center=[float(x) for x in b["center"]], size=[float(x) for x in b["size"]],
                           name=str(b.get("name", ""))) for b in entry.get("boxes", [])]
        numbers = [height] if height is not None else []
        numbers += [x for b in boxes for x in b.center + b.size]
        if not np.all(np.isfinite(np.asarray(numbers, float))):
            raise ValueError("a floor_height, center or size that is not finite")
        return EnvironmentConfig(floor=bool(entry.get("floor", True)),
                                 floor_height=None if height is None else float(height), boxes=boxes)
    except (AttributeError, KeyError, TypeError, ValueError) as err:
        raise DataError(f"'environment' must be {{floor, floor_height, boxes: [{{center, size}}]}}: {err!r}",
                        file=str(source)) from None
