"""The identified robot where it is used (``pe-drake export``): MJCF, URDF/SDFormat, controller
feed-forward, PD gains and randomization ranges, and ``validate --model`` of such a file.

Its names load on first use: ``validate`` with an identified.json imports no exporter.
"""

from pe_drake.exports import exports_by_module, lazy_exports

_EXPORTS = exports_by_module(__name__, {
    "model_export": "FORMATS ExportOptions ExportResult export_model",
    "model_source": "IdentifiedSpread exported_model identified_spread",
    "simulator_validation": "is_simulator_model validate_exported",
})

__all__ = sorted(_EXPORTS)
__getattr__ = lazy_exports(__name__, _EXPORTS)
