"""Configuration dataclasses and their YAML loader.

A config file maps onto :class:`Config` through Drake's ``yaml_load_typed``, which fills
dataclasses by attribute assignment: so they are plain dataclasses, checked by
:func:`validate_config` after loading (and by every public entry point). Units are SI.
"""

import dataclasses
import math
import re
from pathlib import Path

from pe_drake.config_sections import (  # noqa: F401  (re-exported: config.X keeps working)
    DATA_FORMATS,
    EFFORT_KINDS,
    ControllerConfig,
    DataConfig,
    IdentificationConfig,
    JointMapConfig,
    NoiseStdConfig,
    TransmissionConfig,
    check_choice,
    check_finite,
    check_fraction,
    validate_identification,
    validate_log_sections,
)
from pe_drake.exceptions import ConfigError, shorten
from pe_drake.yaml_check import key_line, load_yaml_typed


@dataclasses.dataclass
class RobotConfig:
    """Which model to load, which joints to excite, how to hold the rest.

    Joint tables are {joint: value} in [rad] or [m] (per s, s², s³ for rates); a limit table may
    only tighten the model's limits, or replace a zero placeholder.
    """

    model: str = ""  # URDF/SDF path (relative to the config file) or package://...
    joints: list[str] = dataclasses.field(default_factory=list)  # excited; empty: every movable one
    # The other joints' posture; unlisted ones at 0 (or the nearest limit).
    locked_positions: dict[str, float] = dataclasses.field(default_factory=dict)
    root_link: str = ""  # welded to the world; empty: the model's root link
    # The root link's pose in world [m] (replaces a URDF's fixed world joint; [0, 1, 0, 0]: a
    # ceiling mount).
    base_position: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    base_quaternion_wxyz: list[float] = dataclasses.field(
        default_factory=lambda: [1.0, 0.0, 0.0, 0.0]
    )
    position_limits: dict[str, list[float]] = dataclasses.field(default_factory=dict)
    velocity_limits: dict[str, float] = dataclasses.field(default_factory=dict)
    acceleration_limits: dict[str, float] = dataclasses.field(default_factory=dict)
    default_acceleration_limit: float = 10.0  # for joints not in acceleration_limits
    effort_limits: dict[str, float] = dataclasses.field(default_factory=dict)  # [N·m or N]
    position_margin: float = 0.0  # kept away from each position limit
    velocity_scale: float = 1.0  # fraction (0, 1] of each velocity limit used; likewise below
    acceleration_scale: float = 1.0
    effort_scale: float = 1.0
    # The posture the optimizer starts from (q0 of Eq. 50); unlisted joints start mid-range.
    nominal_positions: dict[str, float] = dataclasses.field(default_factory=dict)
    capsules: str = ""  # capsule file for self-collision (relative to the config file)
    # {link: [[x, y, z], ...]}: the feet's contact points in the link frame [m], for balance.
    support_points: dict[str, list[list[float]]] = dataclasses.field(default_factory=dict)
    # {package: folder} of the model's package:// URIs (relative to the config file); others
    # are searched (pe_drake/multibody/packages.py).
    packages: dict[str, str] = dataclasses.field(default_factory=dict)
    # {joint: k} [N·m/A or N/A]: τ = k·i, for logs with current.* columns.
    drive_gains: dict[str, float] = dataclasses.field(default_factory=dict)
    # Checked on the exported controller goal; empty: not checked.
    jerk_limits: dict[str, float] = dataclasses.field(default_factory=dict)
    # Gear ratios and coupling: a motor-side log is converted with them.
    transmission: TransmissionConfig = dataclasses.field(default_factory=TransmissionConfig)
    # What pe_drake chose for a model given without a config, printed by every command.
    notes: list[str] = dataclasses.field(default_factory=list)
    # The SAFE_DEFAULTS fields pe_drake set because no config gave them; an assumed position
    # margin is cut to a quarter of a joint's range where it does not fit.
    assumed: list[str] = dataclasses.field(default_factory=list)
    # Expand a xacro with xacro's full Python ($(eval), load_yaml, $(env)): refused by default,
    # because a xacro is a program. Only for files whose author you trust.
    trust_xacro: bool = False


#: The shipped robots' conservative limits, given to a model path without a config that sets
#: them: position margin [rad or m] and velocity fraction (a config file starts from 0 and 1).
SAFE_DEFAULTS = {"position_margin": 0.05, "velocity_scale": 0.8}


#: Largest solver.max_iterations: IPOPT and NLopt take a C int.
MAX_ITERATIONS = 2**31 - 1


@dataclasses.dataclass
class ExcitationConfig:
    """The trajectory and the optimization problem (paper, section IV-A)."""

    harmonics: int = 10  # N in Eq. (50)
    omega: float = math.pi / 4  # base angular frequency ω [rad/s]; the period is 2π/ω
    cost_samples: int = 40  # T, samples stacked in C (Eq. 3), evenly spread over one period
    constraint_samples: int = 400  # K, samples where the limits are imposed (Eq. 51)
    # "soft_cond" (a smooth upper bound of cond(C), fewer iterations), "cond" (Eq. 5, the
    # paper's), "log_cond" or "dopt" (-log det CᵀC).
    criterion: str = "soft_cond"
    rest_at_ends: bool = False  # start and end with zero velocity and acceleration
    amplitude: float = 0.05  # scale of the random initial coefficients [rad]
    balance_radius: float = 0.0  # r of Eq. (52) [m]; 0 disables the balance constraint
    collision_margin: float = -1.0  # least capsule distance (Eq. 53) [m]; negative disables
    torque_limits: bool = False  # keep the a-priori model's torques within robot.limits.effort_max
    seed: int = 0
    periods: int = 1  # periods of the optimized path in trajectory.csv (the cost uses one)
    ramp: bool = True  # trajectory.csv starts and ends at rest (a time scaling of the path)
    # The rows of C: "joint_torque" (Eq. 1), "base_wrench" (the ground wrench on a robot standing
    # on the ground) or "both".
    measurement: str = "joint_torque"
    noise_std: NoiseStdConfig = dataclasses.field(default_factory=NoiseStdConfig)  # row weights
    # identify's drive terms as columns of C too: "none" (the paper's), "friction" (Coulomb,
    # viscous, offset) or "all" (also the armature where separable); not with base_wrench.
    drive_terms: str = "none"


@dataclasses.dataclass
class SolverConfig:
    """Which solver and its options: ``algorithm`` is NLopt's (ignored by IPOPT),
    ``max_iterations`` counts evaluations for NLopt, ``tolerance`` is relative, ``max_time`` [s]
    (0: none), ``ipopt_options`` {name: value as text} apply after pe_drake's own."""

    name: str = "ipopt"
    algorithm: str = "LD_SLSQP"
    max_iterations: int = 300
    tolerance: float = 1e-6
    max_time: float = 0.0
    verbose: bool = True
    ipopt_options: dict[str, str] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass
class BoxConfig:
    """An axis-aligned box obstacle in world: ``center`` [m], full edge lengths ``size`` [m]."""

    center: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    size: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    name: str = ""


@dataclasses.dataclass
class EnvironmentConfig:
    """The robot's surroundings, kept ``max(excitation.collision_margin, 0)`` from every capsule."""

    floor: bool = True  # a floor under a fixed-base arm (a robot without robot.support_points)
    # z of the floor in world for an upright base [m]; null: through the root link's origin. The
    # floor is normal to the base's z axis (a ceiling for an upside-down base).
    floor_height: float | None = None
    boxes: list[BoxConfig] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class ParallelConfig:
    """Where the independent solves of a multi-start run."""

    executor: str = "local"  # "local" (a process pool) or "ray" (a Ray cluster)
    address: str = ""  # Ray cluster address, e.g. "ray://head:10001"; empty: ray.init()'s default
    starts: int = 1  # random starts; start k uses seed excitation.seed + k
    workers: int = 0  # starts at once; 0: the cores available, at most starts
    # A worker silent this long [s] is stopped and its start fails; 0: never (not checked with
    # one worker, in this process).
    hung_after_s: float = 600.0


@dataclasses.dataclass
class Config:
    """A whole pe_drake configuration file."""

    robot: RobotConfig = dataclasses.field(default_factory=RobotConfig)
    excitation: ExcitationConfig = dataclasses.field(default_factory=ExcitationConfig)
    solver: SolverConfig = dataclasses.field(default_factory=SolverConfig)
    environment: EnvironmentConfig = dataclasses.field(default_factory=EnvironmentConfig)
    parallel: ParallelConfig = dataclasses.field(default_factory=ParallelConfig)
    data: DataConfig = dataclasses.field(default_factory=DataConfig)
    controller: ControllerConfig = dataclasses.field(default_factory=ControllerConfig)
    identification: IdentificationConfig = dataclasses.field(default_factory=IdentificationConfig)


CRITERIA = ("cond", "soft_cond", "log_cond", "dopt")
MEASUREMENTS = ("joint_torque", "base_wrench", "both")
SOLVERS = ("ipopt", "nlopt")
NLOPT_ALGORITHMS = ("LD_SLSQP", "LD_MMA", "LD_CCSAQ")
EXECUTORS = ("local", "ray")


def validate_config(config: Config) -> Config:
    """Checks every number and choice of a config (ConfigError naming the field and the bad
    value); returns it unchanged."""
    r, e, s = config.robot, config.excitation, config.solver
    for name in ("velocity_limits", "acceleration_limits", "effort_limits"):
        for joint, value in getattr(r, name).items():
            check_finite(f"robot.{name}['{joint}']", value, positive=True)
    for joint, pair in r.position_limits.items():
        if len(pair) != 2:
            raise ConfigError(f"robot.position_limits['{joint}'] must be [lower, upper]")
        for v in pair:
            check_finite(f"robot.position_limits['{joint}']", v)
        if pair[0] >= pair[1]:
            raise ConfigError(f"robot.position_limits['{joint}']: lower {pair[0]} >= upper {pair[1]}")
    for table in ("locked_positions", "nominal_positions"):
        for joint, value in getattr(r, table).items():
            check_finite(f"robot.{table}['{joint}']", value)
    check_finite("robot.default_acceleration_limit", r.default_acceleration_limit, positive=True)
    check_finite("robot.position_margin", r.position_margin, nonneg=True)
    for name in ("velocity_scale", "acceleration_scale", "effort_scale"):
        check_fraction(f"robot.{name}", getattr(r, name))
    for name in r.assumed:
        if name not in SAFE_DEFAULTS:
            raise ConfigError(f"robot.assumed entry '{shorten(name)}' is not one of {', '.join(SAFE_DEFAULTS)}")
    if len(r.base_position) != 3:
        raise ConfigError(f"robot.base_position must have 3 numbers, got {r.base_position}")
    if len(r.base_quaternion_wxyz) != 4:
        raise ConfigError(f"robot.base_quaternion_wxyz must have 4 numbers, got {r.base_quaternion_wxyz}")
    for v in list(r.base_position) + list(r.base_quaternion_wxyz):
        check_finite("robot.base_pose", v)
    if math.sqrt(sum(v * v for v in r.base_quaternion_wxyz)) < 1e-9:
        raise ConfigError("robot.base_quaternion_wxyz must not be zero")
    if not isinstance(r.trust_xacro, bool):
        raise ConfigError(f"robot.trust_xacro must be true or false, got {r.trust_xacro!r}")
    for package, folder in r.packages.items():
        if not Path(str(folder)).expanduser().is_dir():
            raise ConfigError(f"robot.packages['{package}']: folder '{folder}' does not exist")

    if not isinstance(e.harmonics, int) or e.harmonics < 1:
        raise ConfigError(f"excitation.harmonics must be a positive integer, got {e.harmonics!r}")
    check_finite("excitation.omega", e.omega, positive=True)
    if not isinstance(e.cost_samples, int) or e.cost_samples < 1:
        raise ConfigError(f"excitation.cost_samples must be a positive integer, got {e.cost_samples!r}")
    if not isinstance(e.constraint_samples, int) or e.constraint_samples < 2:
        raise ConfigError(f"excitation.constraint_samples must be an integer >= 2, "
                          f"got {e.constraint_samples!r}")
    check_choice("excitation.criterion", e.criterion, CRITERIA, suggest=True)
    check_finite("excitation.amplitude", e.amplitude, positive=True)
    check_finite("excitation.balance_radius", e.balance_radius, nonneg=True)
    check_finite("excitation.collision_margin", e.collision_margin)
    check_choice("excitation.measurement", e.measurement, MEASUREMENTS)
    check_choice("excitation.drive_terms", e.drive_terms, ("none", "friction", "all"))
    if e.drive_terms != "none" and e.measurement == "base_wrench":
        raise ConfigError("excitation.drive_terms (--drive-terms) needs joint-torque rows: the ground wrench "
                          "(measurement: base_wrench) does not see joint friction; use measurement: both "
                          "(--measurement both) or drive_terms: none (--drive-terms none)")
    torque = e.noise_std.torque
    for joint, value in (torque.items() if isinstance(torque, dict) else [("all", torque)]):
        check_finite(f"excitation.noise_std.torque['{joint}'] [N·m]", value, positive=True)
    for name in ("force", "moment"):
        check_finite(f"excitation.noise_std.{name}", getattr(e.noise_std, name), positive=True)

    check_choice("solver.name", s.name, SOLVERS)
    check_choice("solver.algorithm", s.algorithm, NLOPT_ALGORITHMS)
    if isinstance(s.max_iterations, bool) or not isinstance(s.max_iterations, int) or not 1 <= s.max_iterations <= MAX_ITERATIONS:
        raise ConfigError(f"solver.max_iterations must be an integer from 1 to {MAX_ITERATIONS} (the solvers take a "
                          f"32-bit count), got {shorten(repr(s.max_iterations))}")
    check_finite("solver.tolerance", s.tolerance, positive=True)
    check_finite("solver.max_time", s.max_time, nonneg=True)
    _validate_safety(config)
    _validate_parallel(config.parallel)
    validate_log_sections(config.robot, config.data, config.controller)
    validate_identification(config.identification)
    return config


def _validate_safety(config: Config) -> None:
    """Periods, ramp, environment and physically sensible sampling."""
    e, env = config.excitation, config.environment
    period = 2 * math.pi / e.omega
    if not 0.1 <= period <= 600:
        raise ConfigError(
            f"excitation.omega = {e.omega!r} rad/s gives a period of {period:.4g} s; use a period from "
            "0.1 s to 600 s (omega from 0.0105 to 62.8 rad/s)"
        )
    if e.constraint_samples < 8 * e.harmonics:
        raise ConfigError(
            f"excitation.constraint_samples = {e.constraint_samples} is too few for {e.harmonics} harmonics: "
            f"the limits need at least 8 samples per period of the highest harmonic ({8 * e.harmonics})"
        )
    if isinstance(e.periods, bool) or not isinstance(e.periods, int) or not 1 <= e.periods <= 1000:
        raise ConfigError(f"excitation.periods must be an integer from 1 to 1000, got {e.periods!r}")
    if isinstance(e.seed, bool) or not isinstance(e.seed, int) or not 0 <= e.seed < 2**32:
        raise ConfigError(f"excitation.seed must be an integer from 0 to 2^32 - 1, got {e.seed!r}")
    if not isinstance(e.ramp, bool):
        raise ConfigError(f"excitation.ramp must be true or false, got {e.ramp!r}")
    if not isinstance(env.floor, bool):
        raise ConfigError(f"environment.floor must be true or false, got {env.floor!r}")
    if env.floor_height is not None and (
        isinstance(env.floor_height, bool)
        or not isinstance(env.floor_height, (int, float))
        or not math.isfinite(env.floor_height)
    ):
        raise ConfigError(f"environment.floor_height must be a finite number [m], got {env.floor_height!r}")
    for k, box in enumerate(env.boxes):
        for key in ("center", "size"):
            value = getattr(box, key)
            if len(value) != 3 or not all(isinstance(x, (int, float)) and math.isfinite(x) for x in value):
                raise ConfigError(f"environment.boxes[{k}].{key} must be 3 finite numbers [m], got {value!r}")
        if any(x <= 0 for x in box.size):
            raise ConfigError(f"environment.boxes[{k}].size must be 3 positive edge lengths [m], got {box.size!r}")


def _validate_parallel(p: ParallelConfig) -> None:
    check_choice("parallel.executor", p.executor, EXECUTORS)
    if p.address and p.executor != "ray":
        raise ConfigError(f"parallel.address '{shorten(p.address)}' needs parallel.executor: ray (it is '{shorten(p.executor)}')")
    if isinstance(p.starts, bool) or not isinstance(p.starts, int) or p.starts < 1:
        raise ConfigError(f"parallel.starts must be a positive integer, got {p.starts!r}")
    if isinstance(p.workers, bool) or not isinstance(p.workers, int) or p.workers < 0:
        raise ConfigError(f"parallel.workers must be a positive integer (0: the cores available), got {p.workers!r}")
    check_finite("parallel.hung_after_s [s] (0: never)", p.hung_after_s, nonneg=True)


def load_config(path: str | Path, base: Config | None = None) -> Config:
    """Reads a YAML config file onto :class:`Config` (starting from ``base``) and validates it.

    Raises:
        ConfigError: missing file, unknown key, wrong type, or invalid value.
    """
    path = Path(path)
    config = load_yaml_typed(path, Config, base, "config")
    _resolve_paths(config.robot, path.parent)
    try:
        return validate_config(config)
    except ConfigError as err:
        # The value checks name the dotted key first ("excitation.criterion '…' is …"):
        # point at its line when this file sets it.
        key = re.match(r"[a-z_]+(\.[a-z_]+)+", str(err))
        line = key_line(path, key.group(0)) if key else None
        where = f", line {line}" if line is not None else ""
        raise ConfigError(f"config file '{path}'{where}: {err}") from None


def _resolve_paths(robot: RobotConfig, folder: Path) -> None:
    for attr in ("model", "capsules"):
        value = getattr(robot, attr)
        if value and "://" not in value and not Path(value).is_absolute():
            setattr(robot, attr, str((folder / value).resolve()))
    robot.packages = {
        name: str((folder / Path(value).expanduser()).resolve()) for name, value in robot.packages.items()
    }
