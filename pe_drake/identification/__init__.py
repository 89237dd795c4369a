"""From measured data to parameters (Eq. 4): measurements, preprocessing, estimators.

Imports only ``excitation``, ``multibody`` and the base layer. Re-exports the names that
``pe_drake.identification`` offered as a single module.
"""

from pe_drake.identification.drive_terms import DriveFit, DriveTermOptions
from pe_drake.identification.estimators import (
    IdentificationResult,
    identify,
    predict,
    predict_wrench,
    prepare_measurement,
    read_robot_measurement,
    robot_torques,
    torque_errors,
)
from pe_drake.identification.identified_file import load_identified
from pe_drake.identification.identify_model import IdentifiedModel, IdentifyOptions, identify_model
from pe_drake.identification.intake import read_measurements
from pe_drake.identification.payload import PayloadBox, PayloadOptions, PayloadResult, identify_payload
from pe_drake.identification.payload_run import PayloadIdentification, identify_payload_runs, parse_payload_box
from pe_drake.identification.physical_fit import LinkBox, PhysicalBounds
from pe_drake.identification.time_window import TimeWindow
from pe_drake.identification.validate_model import ValidateOptions, ValidationReport, validate_model

__all__ = [
    "DriveFit",
    "DriveTermOptions",
    "IdentificationResult",
    "IdentifiedModel",
    "IdentifyOptions",
    "LinkBox",
    "PhysicalBounds",
    "PayloadBox",
    "PayloadOptions",
    "PayloadResult",
    "identify",
    "identify_payload",
    "load_identified",
    "read_measurements",
    "predict",
    "predict_wrench",
    "prepare_measurement",
    "read_robot_measurement",
    "robot_torques",
    "torque_errors",
    "ValidateOptions",
    "ValidationReport",
    "identify_model",
    "PayloadIdentification",
    "identify_payload_runs",
    "parse_payload_box",
    "TimeWindow",
    "validate_model",
]
