"""The robot and its rigid-body dynamics (Eqs. 1-2): Drake plant, regressor, base parameters, capsules.

The lowest stage: it imports only the shared base layer (``exceptions``, ``config``, ...).
"""

from pe_drake.exports import exports_by_module, lazy_exports

_EXPORTS = exports_by_module(__name__, {
    "registry": "builtin_robots resolve_robot_config robot_display_name",
    "robot": "Robot load_robot",
})

__all__ = sorted(_EXPORTS)
__getattr__ = lazy_exports(__name__, _EXPORTS)
