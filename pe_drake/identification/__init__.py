"""From measured data to parameters (Eq. 4): measurements, preprocessing, estimators.

Imports only ``excitation``, ``multibody`` and the base layer. Re-exports the names that
``pe_drake.identification`` offered as a single module.
"""

from pe_drake.exports import exports_by_module, lazy_exports

# Bound now, not lazily: these names are also submodules', and importing a submodule sets the
# package's attribute to the module, which a lazy __getattr__ would never see.
from pe_drake.identification.identify_model import identify_model
from pe_drake.identification.validate_model import validate_model

_EXPORTS = exports_by_module(__name__, {
    "estimators": "IdentificationResult identify",
    "identified_file": "load_identified model_method unapplied_effects",
    "identify_model": "IdentifiedModel IdentifyOptions identify_model",
    "intake": "prepare_measurement read_measurements read_robot_measurement",
    "payload": "PayloadBox PayloadOptions PayloadResult identify_payload",
    "payload_run": "PayloadIdentification identify_payload_runs parse_payload_box",
    "physical_fit": "LinkBox PhysicalBounds",
    "prediction": "predict predict_wrench robot_torques torque_errors",
    "time_window": "TimeWindow",
    "validate_model": "ValidateOptions ValidationReport validate_model",
}) | {"DriveTermOptions": "pe_drake.multibody.drive_columns"}

__all__ = sorted(_EXPORTS)
__getattr__ = lazy_exports(__name__, _EXPORTS)
