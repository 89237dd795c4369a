"""Where the ``example-robot-data`` wheel keeps its robot models."""

from __future__ import annotations

import sys
import sysconfig
from pathlib import Path

from pe_drake.exceptions import ConfigError


def example_robot_data_dir() -> Path:
    """The ``share/example-robot-data`` folder of the installed wheel; ConfigError without it."""
    for root in [sysconfig.get_paths()["purelib"], *sys.path]:
        candidate = Path(root) / "cmeel.prefix" / "share" / "example-robot-data"
        if candidate.is_dir():
            return candidate
    raise ConfigError(
        "the robot models of 'example-robot-data' are not installed: "
        "pip install example-robot-data")
