"""Which effect the model is missing: residual analysis, candidate effects, payload, augmented model.

The top stage of the library; imports every lower stage. The modules follow the workflow:
options → record (data preparation) → effects (the library) → regression (fits and
selection) → payload → augmented_model → result, report → workflow (:func:`diagnose`).
"""

from pe_drake.exports import exports_by_module, lazy_exports

_EXPORTS = exports_by_module(__name__, {
    "options": "DiagnosisConfig",
    "result": "DiagnosisResult",
    "workflow": "diagnose",
})

__all__ = sorted(_EXPORTS)
__getattr__ = lazy_exports(__name__, _EXPORTS)
