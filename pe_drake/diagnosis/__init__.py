"""Which effect the model is missing: residual analysis, candidate effects, payload, augmented model.

The top stage of the library; imports every lower stage. The modules follow the workflow:
options → record (data preparation) → effects (the library) → regression (fits and
selection) → payload → augmented_model → result, report → workflow (:func:`diagnose`).
"""

from pe_drake.diagnosis.options import DiagnosisConfig
from pe_drake.diagnosis.result import DiagnosisResult, write_outputs
from pe_drake.diagnosis.workflow import diagnose

__all__ = ["DiagnosisConfig", "DiagnosisResult", "diagnose", "write_outputs"]
