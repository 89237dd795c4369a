"""Which effect the model is missing: residual analysis, candidate effects, payload, augmented model.

The top stage of the library; imports every lower stage. Re-exports the names that
``pe_drake.diagnosis`` offered as a single module.
"""

from pe_drake.diagnosis.workflow import DiagnosisConfig, DiagnosisResult, diagnose, write_outputs

__all__ = ["DiagnosisConfig", "DiagnosisResult", "diagnose", "write_outputs"]
