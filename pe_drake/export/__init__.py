"""The identified robot where it is used: MJCF for MuJoCo, URDF/SDFormat for Drake and ROS,
controller feed-forward, PD gains and randomization ranges (``pe-drake export``), and
``validate --model`` of such a file in its simulator.

Its names load on first use, so ``pe-drake validate`` with an identified.json does not import
the exporters (nor the diagnosis they draw randomization projections from).
"""

from pe_drake.exports import exports_by_module, lazy_exports

_EXPORTS = exports_by_module(__name__, {
    "model_export": "FORMATS ExportOptions ExportResult export_model",
    "model_source": "IdentifiedSpread exported_model identified_spread",
    "simulator_validation": "is_simulator_model validate_exported",
})

__all__ = sorted(_EXPORTS)
__getattr__ = lazy_exports(__name__, _EXPORTS)
