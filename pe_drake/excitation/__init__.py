"""The paper's optimization (Eqs. 3-53): Fourier motions, criteria, constraints, the program, its solve.

Imports only ``multibody`` and the base layer. Re-exports the names that ``pe_drake.excitation``
offered as a single module.
"""

from pe_drake.excitation.limits import add_joint_limit_constraints, add_rest_constraints
from pe_drake.excitation.motion_plan import MotionPlan, check_csv_size, optimize_motion
from pe_drake.excitation.optimize_report import MotionReport
from pe_drake.excitation.payload_plan import optimize_payload, write_payload_plan
from pe_drake.excitation.payload_motion import PayloadMotionPlan, optimize_payload_motion
from pe_drake.excitation.problem import ExcitationProblem
from pe_drake.excitation.program import (
    ExcitationProgram,
    add_excitation_cost,
    add_sampled_constraint,
    build_excitation_program,
)
from pe_drake.excitation.sequential_study import SequentialStudy, StudyOptions, run_sequential_study
from pe_drake.excitation.solve import (
    ExcitationResult,
    check_margins,
    optimize_excitation,
    solve_excitation,
)

__all__ = [
    "ExcitationProblem",
    "ExcitationProgram",
    "ExcitationResult",
    "MotionPlan",
    "MotionReport",
    "PayloadMotionPlan",
    "SequentialStudy",
    "StudyOptions",
    "add_excitation_cost",
    "add_joint_limit_constraints",
    "add_rest_constraints",
    "add_sampled_constraint",
    "build_excitation_program",
    "check_csv_size",
    "check_margins",
    "optimize_excitation",
    "optimize_motion",
    "optimize_payload",
    "optimize_payload_motion",
    "write_payload_plan",
    "run_sequential_study",
    "solve_excitation",
]
