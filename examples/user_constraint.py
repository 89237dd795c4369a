"""pe_drake as a plugin for Drake's MathematicalProgram: add your own constraint.

The excitation program is an ordinary Drake MathematicalProgram. Here we add a constraint
written by the user next to pe_drake's cost and limits: the Panda's flange (panda_link8)
must stay above a table at z = 0.45 m. The height comes from one of Drake's kinematic
constraints (PositionConstraint) evaluated at every configuration sample; its gradient with
respect to q is chained through the Fourier map by pe_drake's add_sampled_constraint.

The solver sees the constraint only at the K samples, 0.05 s apart; between two of them the
flange can dip below the line joining them by up to |z̈|·Δt²/8, about 1.5 mm at 5 m/s².
So the samples keep a 2 mm allowance above the table, and the result is checked at 1 kHz
against the table itself.

    python examples/user_constraint.py
"""

from __future__ import annotations

import math

import numpy as np

from pe_drake.config import ExcitationConfig, SolverConfig
from pe_drake.excitation.constraints import constraints_from_config
from pe_drake.excitation.constraints.base import SampledConstraint, SampledValues
from pe_drake.excitation.problem import ExcitationProblem
from pe_drake.excitation.program import add_sampled_constraint, build_excitation_program
from pe_drake.excitation.solve import check_margins, solve_excitation
from pe_drake.multibody.robot import load_robot

TABLE_HEIGHT = 0.45  # [m]
SAMPLE_ALLOWANCE = 0.002  # [m] kept at the samples for the dips between them


class FlangeAboveTable(SampledConstraint):
    """z of panda_link8's origin ≥ height, via Drake's PositionConstraint."""

    name = "flange height"

    def __init__(self, robot, height: float = TABLE_HEIGHT):
        from pydrake.multibody.inverse_kinematics import PositionConstraint

        plant = robot.plant
        self._context = plant.CreateDefaultContext()
        self._drake = PositionConstraint(
            plant,
            plant.world_frame(),
            np.array([-np.inf, -np.inf, height]),
            np.array([np.inf, np.inf, np.inf]),
            plant.GetFrameByName("panda_link8"),
            np.zeros(3),
            self._context,
        )
        super().__init__(["flange z"], [height], [np.inf])

    def evaluate(self, q, v, vd, derivatives=True):
        from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff

        K, n = q.shape
        value = np.empty((K, 1))
        d_q = np.zeros((K, 1, n))
        for k in range(K):
            y = self._drake.Eval(InitializeAutoDiff(q[k]))  # Drake's own gradient
            value[k, 0] = ExtractValue(y)[2, 0]
            d_q[k, 0] = ExtractGradient(y)[2]
        return SampledValues(value, d_q)


def main() -> None:
    robot = load_robot("panda")
    config = ExcitationConfig(
        harmonics=4, omega=2 * math.pi / 10, cost_samples=40, constraint_samples=200, collision_margin=0.01
    )
    problem = ExcitationProblem(robot, config)
    # pe_drake's own constraints first (the capsules 1 cm apart), then ours.
    program = build_excitation_program(problem, constraints_from_config(robot, config))
    above = FlangeAboveTable(robot, TABLE_HEIGHT + SAMPLE_ALLOWANCE)
    add_sampled_constraint(program.prog, program.alpha, problem, above, group=1)
    table = FlangeAboveTable(robot)
    program.constraints.append(table)  # re-checked at 1 kHz with the others, against the table

    result = solve_excitation(program, SolverConfig(max_iterations=150))
    q, _, _ = result.trajectory.evaluate(np.linspace(0, problem.period, 2000))
    z = table.evaluate(q, q, q, derivatives=False).value
    print(f"success: {result.success} ({result.message})")
    print(f"cond: {result.cond:.4g}   solve time: {result.wall_time:.1f} s")
    print(f"lowest flange height over the period: {z.min():.4f} m (table at {TABLE_HEIGHT} m)")
    print("margins at 1 kHz:", {k: round(m, 5) for k, m in check_margins(problem, result.x, program.constraints).items()})


if __name__ == "__main__":
    main()
