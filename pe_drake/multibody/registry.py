"""Where robots come from: the built-in robot configs (``models/<name>.yaml``: ``panda``,
``ur5``, ``g1``, whose models are in the ``example-robot-data`` wheel) or a model file path."""

from __future__ import annotations

import dataclasses
import re
from importlib.resources import files
from pathlib import Path

from pe_drake.config import SAFE_DEFAULTS, Config, RobotConfig, load_config, validate_config
from pe_drake.exceptions import ConfigError, UnknownNameError
from pe_drake.limits import input_file_problem
from pe_drake.multibody.excited_joints import PER_JOINT_TABLES
from pe_drake.multibody.model_files import model_stem
from pe_drake.multibody.packages import example_robot_data_dir
from pe_drake.multibody.standing_defaults import standing_defaults
from pe_drake.yaml_check import key_line

#: Package holding the built-in robot configs (``<name>.yaml``).
MODELS_PACKAGE = "pe_drake.models"
#: URI prefix of the models of the ``example-robot-data`` wheel.
EXAMPLE_ROBOT_DATA_URI = "package://example-robot-data/"


def models_dir() -> Path:
    """The folder of the built-in robot, capsule and truth files."""
    return Path(str(files(MODELS_PACKAGE)))


def builtin_robots() -> tuple[str, ...]:
    """Names of the built-in robot configs (``models/<name>.yaml``)."""
    # A robot config has a top-level "robot:" section; capsule and truth files do not.
    return tuple(sorted(p.stem for p in models_dir().glob("*.yaml")
                        if re.search(r"^robot:", p.read_text(), flags=re.M)))


def robot_display_name(robot: str) -> str:
    """The name a robot is shown by: its built-in name, else its model file's stem."""
    return robot if robot in builtin_robots() else model_stem(robot)


def builtin_config(name: str) -> Config:
    """The config of a built-in robot; UnknownNameError listing the built-in names."""
    path = models_dir() / f"{name}.yaml"
    if not path.is_file():
        raise UnknownNameError("robot", name, builtin_robots())
    return load_config(path)


def example_robot_data_models(name: str, limit: int = 3) -> tuple[str, ...]:
    """Paths of example-robot-data's URDFs named like ``name`` (``z1`` → ``.../z1.urdf``).

    Shortest first: what to pass as ``--robot`` for a name that is not built in; empty when the
    wheel is not installed or has none.
    """
    stem = name.strip().lower()
    if not stem or not re.fullmatch(r"[\w.-]+", stem):
        return ()
    try:
        robots = example_robot_data_dir() / "robots"
    except ConfigError:
        return ()
    found = sorted((p for p in robots.rglob("*.urdf") if p.stem.lower().startswith(stem)),
                   key=lambda p: (len(p.stem), str(p)))
    return tuple(str(p) for p in found[:limit])


def resolve_robot_config(robot: str, config_file: str | Path | None = None) -> Config:
    """Config for a robot given by built-in name or model path, with a user file on top.

    UnknownNameError for a name neither built in nor a file; ConfigError for a missing model
    file or a bad config."""
    if robot in builtin_robots():
        base = builtin_config(robot)
    else:
        path = Path(robot)
        if path.suffix.lower() not in (".urdf", ".sdf", ".xml", ".xacro"):
            raise UnknownNameError("robot", robot, builtin_robots() + ("<path to .urdf/.sdf/.urdf.xacro>",)
                                   + example_robot_data_models(robot))
        problem = input_file_problem(path)
        if problem:
            raise ConfigError(f"robot model file '{robot}' {problem}")
        # The shipped robots' margins (SAFE_DEFAULTS), not RobotConfig's 0 and 100 %.
        base = Config(robot=RobotConfig(model=str(path.resolve()), **SAFE_DEFAULTS, assumed=list(SAFE_DEFAULTS)))
        standing = standing_defaults(path)  # a humanoid: arms excited, standing on its feet
        if standing is not None:
            robot = dataclasses.replace(base.robot, **standing["robot"])
            excitation = dataclasses.replace(base.excitation, **standing["excitation"])
            base = dataclasses.replace(base, robot=robot, excitation=excitation)
    if config_file is not None:
        config = load_config(config_file, base=base)
        # What the user's file sets is theirs, not assumed (a file may set the same value).
        config.robot.assumed = [k for k in config.robot.assumed if key_line(config_file, f"robot.{k}") is None]
        if key_line(config_file, "robot.joints") is not None:
            drop_entries_of_unexcited_joints(config.robot, config_file)
        return config
    return validate_config(base)


def drop_entries_of_unexcited_joints(robot: RobotConfig, config_file: str | Path) -> None:
    """Drops the per-joint table entries the user's file did not write for joints its
    ``robot.joints`` no longer excites.

    The file's tables are merged onto the built-in ones (models/panda.yaml limits all 7 joints),
    so a config exciting 4 of the Panda's joints was refused for panda_joint5 in
    robot.acceleration_limits, a line the user never wrote. Entries the file writes stay, and are
    refused as before when their joint is not excited.

    Args:
        robot: the merged robot section, changed in place.
        config_file: the user's YAML file.
    """
    for table in PER_JOINT_TABLES:
        values = getattr(robot, table)
        for joint in [j for j in values if j not in robot.joints]:
            if key_line(config_file, f"robot.{table}.{joint}") is None:
                del values[joint]


def resolve_model_path(model: str) -> Path:
    """The model file of ``robot.model`` (a path, or a ``package://example-robot-data/`` URI).

    Raises:
        ConfigError: an empty name or a missing file (the path is named).
    """
    if not model:
        raise ConfigError("robot.model is empty: give a URDF/SDF path or a built-in robot name")
    if model.startswith(EXAMPLE_ROBOT_DATA_URI):
        path = example_robot_data_dir() / model[len(EXAMPLE_ROBOT_DATA_URI):]
    else:
        path = Path(model)
    problem = input_file_problem(path)
    if problem:
        raise ConfigError(f"robot model file '{path}' {problem}")
    return path
