"""pe_drake: persistently exciting trajectories, identification and diagnosis on Drake.

The public API is re-exported here and imported on first use, so ``import pe_drake`` stays
fast and does not load pydrake.
"""

from __future__ import annotations

from pe_drake.exports import lazy_exports

__version__ = "0.1.0"

_EXPORTS = {
    # robots and configuration
    "load_robot": "pe_drake.multibody.robot",
    "Robot": "pe_drake.multibody.robot",
    "builtin_robots": "pe_drake.multibody.registry",
    "Config": "pe_drake.config",
    "RobotConfig": "pe_drake.config",
    "ExcitationConfig": "pe_drake.config",
    "SolverConfig": "pe_drake.config",
    "load_config": "pe_drake.config",
    # trajectories, regressor, base parameters, criteria
    "FourierTrajectory": "pe_drake.excitation.fourier",
    "RegressorModel": "pe_drake.multibody.regressor",
    "BaseParameters": "pe_drake.multibody.base_parameters",
    "compute_base_parameters": "pe_drake.multibody.base_parameters",
    "evaluate_criterion": "pe_drake.excitation.criteria",
    # what is measured: joint torques, the ground wrench, or both
    "MeasurementType": "pe_drake.multibody.sensors",
    "SensorRows": "pe_drake.multibody.sensors",
    "static_wrench": "pe_drake.multibody.wrench",
    "weld_reaction_wrench": "pe_drake.multibody.wrench",
    # the excitation program (build / solve, and pieces for your own program)
    "ExcitationProblem": "pe_drake.excitation.problem",
    "ExcitationProgram": "pe_drake.excitation.program",
    "ExcitationResult": "pe_drake.excitation.solve",
    "build_excitation_program": "pe_drake.excitation.program",
    "solve_excitation": "pe_drake.excitation.solve",
    "optimize_excitation": "pe_drake.excitation.solve",
    "add_excitation_cost": "pe_drake.excitation.program",
    "add_joint_limit_constraints": "pe_drake.excitation.limits",
    "add_rest_constraints": "pe_drake.excitation.limits",
    "add_sampled_constraint": "pe_drake.excitation.program",
    "check_margins": "pe_drake.excitation.solve",
    # what a motion will tell you
    "excitation_quality": "pe_drake.excitation.quality",
    "QualityReport": "pe_drake.excitation.quality",
    # constraints
    "SampledConstraint": "pe_drake.excitation.constraints.base",
    "BalanceConstraint": "pe_drake.excitation.constraints.balance",
    "CollisionConstraint": "pe_drake.excitation.constraints.collision",
    "constraints_from_config": "pe_drake.excitation.constraints",
    # the front doors of the commands (README "As a Python library")
    "optimize_motion": "pe_drake.excitation.motion_plan",
    "simulate_run": "pe_drake.simulation.simulated_run",
    "SimulateOptions": "pe_drake.simulation.simulated_run",
    "read_measurements": "pe_drake.identification.intake",  # any supported log, checked
    "identify_model": "pe_drake.identification.identify_model",
    "IdentifyOptions": "pe_drake.identification.identify_model",
    "validate_model": "pe_drake.identification.validate_model",
    "ValidateOptions": "pe_drake.identification.validate_model",
    "identify_payload": "pe_drake.identification.payload",
    # diagnosis: which effects the model misses
    "diagnose": "pe_drake.diagnosis.workflow",
    "DiagnosisConfig": "pe_drake.diagnosis.options",
    "DiagnosisResult": "pe_drake.diagnosis.result",
    # the model where it is used: MuJoCo, Drake/ROS, controllers
    "export_model": "pe_drake.export.model_export",
    "ExportOptions": "pe_drake.export.model_export",
    "ExportResult": "pe_drake.export.model_export",
    # files
    "load_trajectory": "pe_drake.excitation.trajectory_file",
    "save_trajectory": "pe_drake.excitation.trajectory_file",
    # errors
    "PeDrakeError": "pe_drake.exceptions",
    "ConfigError": "pe_drake.exceptions",
    "DataError": "pe_drake.exceptions",
    "InfeasibleError": "pe_drake.exceptions",
    "NoSolutionFound": "pe_drake.exceptions",
    "UnknownNameError": "pe_drake.exceptions",
    "NotWithinLimitsError": "pe_drake.exceptions",
}

__all__ = sorted(_EXPORTS) + ["__version__"]

__getattr__ = lazy_exports(__name__, _EXPORTS)


def __dir__():
    return __all__
