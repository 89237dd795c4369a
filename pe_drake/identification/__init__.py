"""From measured data to parameters (Eq. 4): measurements, preprocessing, estimators, simulated runs.

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
from pe_drake.identification.intake import read_measurements
from pe_drake.identification.payload import PayloadBox, PayloadOptions, PayloadResult, identify_payload
from pe_drake.identification.physical_fit import LinkBox, PhysicalBounds

__all__ = [
    "DriveFit",
    "DriveTermOptions",
    "IdentificationResult",
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
]
