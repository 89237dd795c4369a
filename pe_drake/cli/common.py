"""What the commands share: the robot named by ``--robot`` (and ``--config``)."""

from __future__ import annotations

import argparse
from collections.abc import Callable

import pe_drake
from pe_drake.config import Config
from pe_drake.multibody import Robot, resolve_robot_config, robot_display_name


def config_from_args(args: argparse.Namespace, adjust: Callable[[Config], Config] | None = None) -> Config:
    """The config of ``--robot`` with ``--config`` on top, then ``adjust`` (other flags) applied."""
    config = resolve_robot_config(args.robot, getattr(args, "config", None))
    if getattr(args, "trust_xacro", False):  # the user vouches for the xacro they named
        config.robot.trust_xacro = True
    return adjust(config) if adjust is not None else config


def robot_from_args(args: argparse.Namespace, config: Config | None = None,
                    show_limit_notes: bool = False) -> Robot:
    """The :class:`~pe_drake.multibody.robot.Robot` of ``--robot``/``--config``, printing its notes.

    Args:
        config: the config already resolved by :func:`config_from_args`; None: resolve it here.
        show_limit_notes: also print the limit margins assumed for a model without a config.
    """
    config = config if config is not None else config_from_args(args)
    robot = Robot(robot_display_name(args.robot), config.robot)
    for note in robot.notes + (robot.limit_notes if show_limit_notes else []):
        print(f"note: {note}", flush=True)
    return robot


def measurement_from_args(args: argparse.Namespace, config: Config) -> str:
    """``--measurement`` if given, else the config's ``excitation.measurement``."""
    return getattr(args, "measurement", None) or config.excitation.measurement


def read_log_from_args(args: argparse.Namespace, robot: Robot, config: Config | None, path=None):
    """The measured log ``--data`` (or ``path``) read and checked with the config's ``data``
    section and the log flags (:func:`~pe_drake.identification.intake.read_measurements`)."""
    options = config.data if config is not None else None
    # Through the package's lazy export: `pe-drake optimize` loads no identification module.
    return pe_drake.read_measurements(robot, path or args.data, options, format=getattr(args, "format", None),
                    topic=getattr(args, "topic", None), effort=getattr(args, "effort", None))


def export_hint(model, robot: str, config: str | None = None) -> str:
    """Where the model goes next: the ``pe-drake export`` command line for it (with the run's
    ``--config``: without it the export would load another robot, e.g. the base at its URDF pose)."""
    config_flag = f" --config {config}" if config else ""
    return (f"use it in a simulator or controller: pe-drake export {model} --robot {robot}{config_flag} "
            "--to mjcf|urdf|sdf|feedforward|gains --out FILE")
