"""The robot and its rigid-body dynamics (Eqs. 1-2): Drake plant, regressor, base parameters, capsules.

The lowest stage: it imports only the shared base layer (``exceptions``, ``config``, ...).
"""

from pe_drake.multibody.registry import builtin_robots, resolve_robot_config, robot_display_name
from pe_drake.multibody.robot import Robot, load_robot

__all__ = ["Robot", "builtin_robots", "load_robot", "resolve_robot_config", "robot_display_name"]
