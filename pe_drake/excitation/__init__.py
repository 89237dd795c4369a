"""The paper's optimization (Eqs. 3-53): Fourier motions, criteria, constraints, the program, its solve.

Imports only ``multibody`` and the base layer. Re-exports the names that ``pe_drake.excitation``
offered as a single module.
"""

from __future__ import annotations

from pe_drake.exports import lazy_exports

#: The stage's public names and their modules, imported on first use (pe_drake/exports.py).
_EXPORTS = {
    "add_joint_limit_constraints": "pe_drake.excitation.limits",
    "add_rest_constraints": "pe_drake.excitation.limits",
    "MotionPlan": "pe_drake.excitation.motion_plan",
    "check_csv_size": "pe_drake.excitation.motion_plan",
    "optimize_motion": "pe_drake.excitation.motion_plan",
    "MotionReport": "pe_drake.excitation.optimize_report",
    "optimize_payload": "pe_drake.excitation.payload_plan",
    "write_payload_plan": "pe_drake.excitation.payload_plan",
    "PayloadMotionPlan": "pe_drake.excitation.payload_motion",
    "optimize_payload_motion": "pe_drake.excitation.payload_motion",
    "ExcitationProblem": "pe_drake.excitation.problem",
    "ExcitationProgram": "pe_drake.excitation.program",
    "add_excitation_cost": "pe_drake.excitation.program",
    "add_sampled_constraint": "pe_drake.excitation.program",
    "build_excitation_program": "pe_drake.excitation.program",
    "SequentialStudy": "pe_drake.excitation.sequential_study",
    "StudyOptions": "pe_drake.excitation.sequential_study",
    "run_sequential_study": "pe_drake.excitation.sequential_study",
    "ExcitationResult": "pe_drake.excitation.solve",
    "check_margins": "pe_drake.excitation.solve",
    "optimize_excitation": "pe_drake.excitation.solve",
    "solve_excitation": "pe_drake.excitation.solve",
}

__all__ = sorted(_EXPORTS)
__getattr__ = lazy_exports(__name__, _EXPORTS)
