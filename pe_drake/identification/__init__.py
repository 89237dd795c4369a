"""From measured data to parameters (Eq. 4): measurements, preprocessing, estimators, simulated runs.

Imports only ``excitation``, ``multibody`` and the base layer. Re-exports the names that
``pe_drake.identification`` offered as a single module.
"""

from __future__ import annotations

from pe_drake.exports import lazy_exports

# Bound now, not lazily: these names are also submodules', and importing a submodule sets the
# package's attribute to the module, which a lazy __getattr__ would never see.
from pe_drake.identification.identify_model import identify_model
from pe_drake.identification.validate_model import validate_model

#: The stage's public names and their modules, imported on first use (pe_drake/exports.py).
_EXPORTS = {
    "DriveFit": "pe_drake.identification.drive_terms",
    "DriveTermOptions": "pe_drake.identification.drive_terms",
    "IdentificationResult": "pe_drake.identification.estimators",
    "identify": "pe_drake.identification.estimators",
    "predict": "pe_drake.identification.estimators",
    "predict_wrench": "pe_drake.identification.estimators",
    "prepare_measurement": "pe_drake.identification.estimators",
    "read_robot_measurement": "pe_drake.identification.estimators",
    "robot_torques": "pe_drake.identification.estimators",
    "torque_errors": "pe_drake.identification.estimators",
    "load_identified": "pe_drake.identification.identified_file",
    "IdentifiedModel": "pe_drake.identification.identify_model",
    "IdentifyOptions": "pe_drake.identification.identify_model",
    "identify_model": "pe_drake.identification.identify_model",
    "read_measurements": "pe_drake.identification.intake",
    "PayloadBox": "pe_drake.identification.payload",
    "PayloadOptions": "pe_drake.identification.payload",
    "PayloadResult": "pe_drake.identification.payload",
    "identify_payload": "pe_drake.identification.payload",
    "PayloadIdentification": "pe_drake.identification.payload_run",
    "identify_payload_runs": "pe_drake.identification.payload_run",
    "parse_payload_box": "pe_drake.identification.payload_run",
    "LinkBox": "pe_drake.identification.physical_fit",
    "PhysicalBounds": "pe_drake.identification.physical_fit",
    "SimulatedRun": "pe_drake.identification.simulated_run",
    "simulate_run": "pe_drake.identification.simulated_run",
    "TimeWindow": "pe_drake.identification.time_window",
    "ValidateOptions": "pe_drake.identification.validate_model",
    "ValidationReport": "pe_drake.identification.validate_model",
    "validate_model": "pe_drake.identification.validate_model",
}

__all__ = sorted(_EXPORTS)
__getattr__ = lazy_exports(__name__, _EXPORTS)
