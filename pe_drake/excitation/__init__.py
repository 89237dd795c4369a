"""The paper's optimization (Eqs. 3-53): Fourier motions, criteria, constraints, the program, its solve.

Imports only ``multibody`` and the base layer. Re-exports the names that ``pe_drake.excitation``
offered as a single module.
"""

from pe_drake.exports import exports_by_module, lazy_exports

_EXPORTS = exports_by_module(__name__, {
    "limits": "add_joint_limit_constraints add_rest_constraints",
    "motion_plan": "MotionPlan check_csv_size optimize_motion",
    "optimize_report": "MotionReport",
    "payload_plan": "optimize_payload write_payload_plan",
    "payload_motion": "PayloadMotionPlan optimize_payload_motion",
    "problem": "ExcitationProblem",
    "program": "ExcitationProgram add_excitation_cost add_sampled_constraint "
               "build_excitation_program",
    "sequential_study": "SequentialStudy StudyOptions run_sequential_study",
    "solve": "ExcitationResult check_margins optimize_excitation solve_excitation",
})

__all__ = sorted(_EXPORTS)
__getattr__ = lazy_exports(__name__, _EXPORTS)
