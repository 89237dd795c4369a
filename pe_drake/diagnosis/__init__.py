"""Which effect the model is missing: residual analysis, candidate effects, payload, augmented model.

The top stage of the library; imports every lower stage. The modules follow the workflow:
options → record (data preparation) → effects (the library) → regression (fits and
selection) → payload → augmented_model → result, report → workflow (:func:`diagnose`).
"""

from __future__ import annotations

from pe_drake.exports import lazy_exports

#: The stage's public names and their modules, imported on first use (pe_drake/exports.py).
_EXPORTS = {
    "DiagnosisConfig": "pe_drake.diagnosis.options",
    "DiagnosisResult": "pe_drake.diagnosis.result",
    "write_outputs": "pe_drake.diagnosis.result",
    "diagnose": "pe_drake.diagnosis.workflow",
}

__all__ = sorted(_EXPORTS)
__getattr__ = lazy_exports(__name__, _EXPORTS)
