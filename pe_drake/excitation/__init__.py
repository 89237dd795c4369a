"""The paper's optimization (Eqs. 3-53): Fourier motions, criteria, constraints, the program, its solve.

Imports only ``multibody`` and the base layer. Re-exports the names that ``pe_drake.excitation``
offered as a single module.
"""

from pe_drake.excitation.program import (
    ExcitationProblem,
    ExcitationProgram,
    ExcitationResult,
    add_excitation_cost,
    add_joint_limit_constraints,
    add_rest_constraints,
    add_sampled_constraint,
    build_excitation_program,
    check_margins,
    optimize_excitation,
    solve_excitation,
)

__all__ = [
    "ExcitationProblem",
    "ExcitationProgram",
    "ExcitationResult",
    "add_excitation_cost",
    "add_joint_limit_constraints",
    "add_rest_constraints",
    "add_sampled_constraint",
    "build_excitation_program",
    "check_margins",
    "optimize_excitation",
    "solve_excitation",
]
