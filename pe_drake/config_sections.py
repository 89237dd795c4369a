"""The config sections of logs in, motions out, sensor noise and identification, and the value
checks every section uses. :mod:`pe_drake.config` assembles them into ``Config``.
"""

import dataclasses
import difflib
import math
from collections.abc import Sequence
from typing import Any, Optional

import numpy as np

from pe_drake.exceptions import ConfigError, shorten


def check_finite(name: str, value: Any, *, positive: bool = False, nonneg: bool = False) -> float:
    """Checks that a config value is a finite number (not a bool; > 0 if ``positive``, >= 0 if
    ``nonneg``) and returns it as a float; else a ConfigError naming the field ``name`` (as the
    user wrote it, with its unit when it helps) and the value."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise ConfigError(f"{name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ConfigError(f"{name} must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise ConfigError(f"{name} must be positive, got {value!r}")
    if nonneg and value < 0:
        raise ConfigError(f"{name} must be non-negative, got {value!r}")
    return float(value)


def check_fraction(name: str, value: Any) -> float:
    """Checks that a config value lies in (0, 1] (ConfigError naming the field); returns it."""
    value = check_finite(name, value, positive=True)
    if value > 1:
        raise ConfigError(f"{name} must lie in (0, 1], got {value!r}")
    return value


def check_choice(name: str, value: Any, choices: Sequence[str], suggest: bool = False) -> None:
    """Checks that a config value is one of ``choices``; else a ConfigError naming the field, the
    value, the choices and (``suggest``) the closest one."""
    if value in choices:
        return
    close = difflib.get_close_matches(str(value), choices, n=1) if suggest else []
    hint = f" (did you mean '{close[0]}'?)" if close else ""
    raise ConfigError(f"{name} '{shorten(value)}' is not one of {', '.join(choices)}{hint}")

@dataclasses.dataclass
class JointMapConfig:
    """A log's joint names and signs → the robot's: ``strip_prefix`` is removed, then ``rename``
    {logged: URDF name} applies; q becomes ``sign·q + offset`` [rad or m] (v, v̇, τ: × sign)."""

    strip_prefix: str = ""
    rename: dict[str, str] = dataclasses.field(default_factory=dict)
    sign: dict[str, float] = dataclasses.field(default_factory=dict)
    offset: dict[str, float] = dataclasses.field(default_factory=dict)


DATA_FORMATS = ("auto", "pe_drake", "rosbag", "rtde", "columns")  # pe_drake.identification.readers
EFFORT_KINDS = ("torque", "current")  # what a ROS bag's JointState effort holds


@dataclasses.dataclass
class DataConfig:
    """How measured logs are read."""

    format: str = "auto"  # one of DATA_FORMATS; auto: told by the file and columns
    topic: str = ""  # the bag's JointState topic; empty: the only one
    effort: str = "torque"  # a bag's effort: torque [N·m] or current [A] (× robot.drive_gains)
    max_gap_s: float = 0.02  # longest hole in t interpolated [s]; a longer one splits the run
    joint_map: JointMapConfig = dataclasses.field(default_factory=JointMapConfig)
    # {t | q|v|vdot|tau|current.<joint>: column} for other CSVs.
    columns: dict[str, str] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass
class ControllerConfig:
    """The ros2_control goal ``optimize`` writes: waypoints at ``goal_rate_hz`` [Hz], ``lead_in_s``
    [s] added to every ``time_from_start``, ``joint_names`` {URDF joint: the driver's name}."""

    goal_rate_hz: float = 50.0
    lead_in_s: float = 1.0
    topic: str = "/joint_trajectory_controller/joint_trajectory"
    joint_names: dict[str, str] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass
class TransmissionConfig:
    """Gear ratios and coupling between motors and joints: θ_m = R q, τ = Rᵀ τ_m."""

    # {joint: ratio} [rad of its motor per rad of the joint]; unlisted joints 1.
    ratios: dict[str, float] = dataclasses.field(default_factory=dict)
    # {joint: {other joint: R entry}}: θ_m = ratio·q + Σ entry·q_other.
    coupling: dict[str, dict[str, float]] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass
class CoMBoxConfig:
    """Where a link's CoM may be, in its frame: ``center`` [m], full edge lengths ``size`` [m]."""

    center: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    size: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])


@dataclasses.dataclass
class IdentificationConfig:
    """What ``pe-drake identify`` models and the bounds of its physical fit."""

    # "all" (Coulomb and viscous friction, a torque offset, and the armature where separable),
    # "friction" (no armature) or "none" (rigid body only).
    drive_terms: str = "all"
    # v_s of the Coulomb column tanh(v/v_s) [rad/s]; unset: drive_columns.COULOMB_VELOCITY_SCALE.
    coulomb_velocity_scale: Optional[float] = None  # noqa: UP045 (yaml_load_typed reads the type at run time)
    # [lo, hi] of the summed mass of the moving links [kg]; empty: no bound.
    total_mass: list[float] = dataclasses.field(default_factory=list)
    mass_bounds: dict[str, list[float]] = dataclasses.field(default_factory=dict)  # [lo, hi] [kg]
    boxes: dict[str, CoMBoxConfig] = dataclasses.field(default_factory=dict)  # where each CoM stays


def validate_log_sections(r, d: "DataConfig", c: "ControllerConfig") -> None:
    """Drive gains, jerk limits, the data and controller sections."""
    for name in ("drive_gains", "jerk_limits"):
        for joint, value in getattr(r, name).items():
            check_finite(f"robot.{name}['{joint}']", value, positive=True)
    for joint, value in r.transmission.ratios.items():
        if check_finite(f"robot.transmission.ratios['{joint}']", value) == 0:
            raise ConfigError(f"robot.transmission.ratios['{joint}'] must not be 0")
    for motor, row in r.transmission.coupling.items():
        for joint, value in row.items():
            check_finite(f"robot.transmission.coupling['{motor}']['{joint}']", value)
    check_choice("data.format", d.format, DATA_FORMATS)
    check_choice("data.effort", d.effort, EFFORT_KINDS)
    check_finite("data.max_gap_s [s]", d.max_gap_s, nonneg=True)
    for joint, value in d.joint_map.sign.items():
        if value not in (1, -1):
            raise ConfigError(f"data.joint_map.sign['{joint}'] must be 1 or -1, got {value!r}")
    for joint, value in d.joint_map.offset.items():
        check_finite(f"data.joint_map.offset['{joint}']", value)
    check_finite("controller.goal_rate_hz [Hz]", c.goal_rate_hz, positive=True)
    check_finite("controller.lead_in_s [s]", c.lead_in_s, positive=True)
    if not c.topic.startswith("/"):
        raise ConfigError(f"controller.topic must start with '/', got '{c.topic}'")


def validate_identification(c: IdentificationConfig) -> None:
    """Drive-term choice and the physical fit's bounds."""
    choices = ("none", "friction", "all")
    if c.drive_terms not in choices:
        raise ConfigError(f"identification.drive_terms '{c.drive_terms}' is not one of {', '.join(choices)}")
    if c.coulomb_velocity_scale is not None:
        check_finite("identification.coulomb_velocity_scale", c.coulomb_velocity_scale, positive=True)
    pairs = [("identification.total_mass", c.total_mass)] if c.total_mass else []
    pairs += [(f"identification.mass_bounds['{k}']", v) for k, v in c.mass_bounds.items()]
    for name, pair in pairs:
        if len(pair) != 2:
            raise ConfigError(f"{name} must be [lo, hi] [kg], got {pair}")
        lo, hi = (check_finite(name, v, nonneg=True) for v in pair)
        if lo > hi:
            raise ConfigError(f"{name}: lower {lo} > upper {hi} [kg]")
    for link, box in c.boxes.items():
        if len(box.center) != 3 or len(box.size) != 3:
            raise ConfigError(f"identification.boxes['{link}'] needs center [x, y, z] and size [sx, sy, sz] [m]")
        for v in box.center:
            check_finite(f"identification.boxes['{link}'].center", v)
        for v in box.size:
            check_finite(f"identification.boxes['{link}'].size", v, nonneg=True)


#: Default joint-torque noise σ [N·m]: a joint-torque sensor's after the low-pass filter.
DEFAULT_NOISE_STD = 0.05


@dataclasses.dataclass
class NoiseStdConfig:
    """Sensor noise σ of each measured quantity: the row weights of C (rows divided by their σ
    make cond(C) independent of units and of the sensor mix)."""

    # Joint-torque noise [N·m or N]: one value, or {joint: value} (all: the joints not named);
    # also sets the quality figures optimize reports. A Drake yaml union: container type first.
    torque: dict[str, float] | float = DEFAULT_NOISE_STD
    force: float = 0.5  # of the ground-wrench sensor [N]
    moment: float = 0.05  # of the ground-wrench sensor [N·m]


def noise_vector(noise_std, joint_names: Sequence[str]) -> np.ndarray:
    """σ_j per joint, shape (n,), from ``excitation.noise_std.torque``.

    Args:
        noise_std: one value; a {joint: value} table (``all``: the joints not named); one value
            per joint; or None (:data:`DEFAULT_NOISE_STD`) [N·m or N].

    Raises:
        ConfigError: an unknown joint, a wrong count, or a value that is not positive (named).
    """
    joints = list(joint_names)
    n = len(joints)
    if noise_std is None:
        return np.full(n, DEFAULT_NOISE_STD)
    if isinstance(noise_std, dict):
        unknown = [k for k in noise_std if k != "all" and k not in joints]
        if unknown:
            raise ConfigError(
                f"excitation.noise_std.torque names unknown joint '{unknown[0]}'; valid: all, {', '.join(joints)}"
            )
        default = noise_std.get("all", DEFAULT_NOISE_STD)
        values = [noise_std.get(j, default) for j in joints]
    elif isinstance(noise_std, (str, bytes)) or not hasattr(noise_std, "__len__"):
        values = [noise_std] * n
    else:
        values = list(noise_std)
        if len(values) != n:
            raise ConfigError(
                f"excitation.noise_std.torque has {len(values)} values; give one value, or one per joint ({n}: "
                f"{', '.join(joints)}), or a {{joint: value}} table"
            )
    out = np.empty(n)
    for j, value in enumerate(values):
        ok = isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool)
        if not ok or not math.isfinite(float(value)) or float(value) <= 0:
            raise ConfigError(
                f"excitation.noise_std.torque of joint '{joints[j]}' must be a positive number [N·m], got {value!r}"
            )
        out[j] = float(value)
    return out
