"""pe_drake: persistently exciting trajectories, identification and diagnosis on Drake.

The public API is re-exported here and imported on first use, so ``import pe_drake`` stays
fast and does not load pydrake.
"""

from __future__ import annotations

from pe_drake.exports import exports_by_module, lazy_exports

__version__ = "0.1.0"

_EXPORTS = exports_by_module(__name__, {
    # robots and configuration
    "multibody.robot": "load_robot Robot",
    "multibody.registry": "builtin_robots",
    "config": "Config RobotConfig ExcitationConfig SolverConfig load_config",
    # trajectories, regressor, base parameters, criteria
    "excitation.fourier": "FourierTrajectory",
    "multibody.regressor": "RegressorModel",
    "multibody.base_parameters": "BaseParameters compute_base_parameters",
    "excitation.criteria": "evaluate_criterion",
    # what is measured: joint torques, the ground wrench, or both
    "multibody.sensors": "MeasurementType SensorRows",
    "multibody.wrench": "static_wrench weld_reaction_wrench",
    # the excitation program (build / solve, and pieces for your own program)
    "excitation.problem": "ExcitationProblem",
    "excitation.program": "ExcitationProgram build_excitation_program add_excitation_cost "
                          "add_sampled_constraint",
    "excitation.solve": "ExcitationResult solve_excitation optimize_excitation check_margins",
    "excitation.limits": "add_joint_limit_constraints add_rest_constraints",
    # what a motion will tell you
    "excitation.quality": "excitation_quality QualityReport",
    # constraints
    "excitation.constraints.base": "SampledConstraint",
    "excitation.constraints.balance": "BalanceConstraint",
    "excitation.constraints.collision": "CollisionConstraint",
    "excitation.constraints": "constraints_from_config",
    # the front doors of the commands (README "As a Python library")
    "excitation.motion_plan": "optimize_motion",
    "simulation.simulated_run": "simulate_run SimulateOptions",
    "identification.intake": "read_measurements",  # any supported log, checked
    "identification.identify_model": "identify_model IdentifyOptions",
    "identification.validate_model": "validate_model ValidateOptions",
    "identification.payload": "identify_payload",
    # diagnosis: which effects the model misses
    "diagnosis.workflow": "diagnose",
    "diagnosis.options": "DiagnosisConfig",
    "diagnosis.result": "DiagnosisResult",
    # the model where it is used: MuJoCo, Drake/ROS, controllers
    "export.model_export": "export_model ExportOptions ExportResult",
    # files
    "excitation.trajectory_file": "load_trajectory save_trajectory",
    # errors
    "exceptions": "PeDrakeError ConfigError DataError InfeasibleError NoSolutionFound "
                  "UnknownNameError NotWithinLimitsError",
})

__all__ = sorted(_EXPORTS) + ["__version__"]

__getattr__ = lazy_exports(__name__, _EXPORTS)


def __dir__():
    return __all__
