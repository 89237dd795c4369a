"""The robot and its rigid-body dynamics (Eqs. 1-2): Drake plant, regressor, base parameters, capsules.

The lowest stage: it imports only the shared base layer (``exceptions``, ``config``, ...).
"""

from __future__ import annotations

from pe_drake.exports import lazy_exports

#: The stage's public names and their modules, imported on first use (pe_drake/exports.py).
_EXPORTS = {
    "builtin_robots": "pe_drake.multibody.registry",
    "resolve_robot_config": "pe_drake.multibody.registry",
    "robot_display_name": "pe_drake.multibody.registry",
    "Robot": "pe_drake.multibody.robot",
    "load_robot": "pe_drake.multibody.robot",
}

__all__ = sorted(_EXPORTS)
__getattr__ = lazy_exports(__name__, _EXPORTS)
