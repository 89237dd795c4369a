"""The exchange step for the sampled constraints: re-check at 1 kHz, add the violated instants.

Balance and self-collision (Eqs. 52–53) are imposed at the K constraint samples (grouped by
:class:`~pe_drake.excitation.program.SampledConstraintEvaluator`); between two samples they
can still be violated. After a solve, :func:`add_violated_samples` evaluates every sampled
constraint at the check rate, finds the instants where its margin has a local minimum below
zero, and adds one row per such instant to the program (kept ``backoff`` inside the bound, so
the peak's small drift in the next solve does not reopen the violation). The solver then
restarts from the current point with what remains of the iteration budget. Semi-infinite
programming calls this an exchange method: rows are added only where the constraint binds,
so the program stays small while the result holds at every checked instant.

The joint limits need no exchange: their window rows
(:mod:`pe_drake.excitation.limit_windows`) are exact at every instant.
"""

from __future__ import annotations

import numpy as np

from pe_drake.excitation.fourier import FourierBasis
from pe_drake.excitation.program import ExcitationProgram, SampledConstraintEvaluator


def check_times(period: float, rate: float) -> np.ndarray:
    """The instants of one period at ``rate`` [Hz] (those of ``check_margins``), [s]."""
    return np.arange(0.0, period, 1.0 / rate)


def violated_instants(margin: np.ndarray, tolerance: float) -> np.ndarray:
    """Indices of the periodic local minima of ``margin`` (shape (M,)) below −tolerance."""
    margin = np.asarray(margin, float)
    local = (margin <= np.roll(margin, 1)) & (margin < np.roll(margin, -1))
    return np.flatnonzero(local & (margin < -tolerance))


def add_violated_samples(
    program: ExcitationProgram, alpha: np.ndarray, rate: float = 1000.0, tolerance: float = 1e-6, backoff: float = 1e-4
) -> int:
    """Adds a row at each instant where a sampled constraint is violated (see module docstring).

    Args:
        program: the built program; it gains one binding per constraint with violations
            (``program.exchange_bindings``, their evaluators in ``program.exchange_evaluators``,
            which the fallback to a feasible point also consults).
        alpha: the point to check, shape ((2N+1)·n,).
        rate: check rate [Hz].
        tolerance: a margin below −tolerance is a violation [constraint's unit].
        backoff: the added rows stay this far inside the bound [constraint's unit].

    Returns:
        The number of instants added (0: nothing violated at ``rate``).
    """
    problem = program.problem
    t = check_times(problem.period, rate)
    basis = FourierBasis(problem.harmonics, problem.omega, t)
    q, v, vd = basis.evaluate_alpha(np.asarray(alpha, float), problem.n)
    added = 0
    for c in list(program.constraints):
        worst = np.min(c.margins(q, v, vd), axis=1)
        idx = violated_instants(worst, tolerance)
        if len(idx) == 0:
            continue
        rows = FourierBasis(problem.harmonics, problem.omega, t[idx])
        evaluator = SampledConstraintEvaluator(problem, c, rows, 1, 0.0)
        lower, upper = evaluator.bounds()
        binding = program.prog.AddConstraint(
            evaluator, lower + backoff, upper - backoff, vars=program.alpha, description=f"{c.name} (exchange)"
        )
        program.exchange_evaluators.append(evaluator)
        program.exchange_bindings.append(binding)
        added += len(idx)
    if program.cost is not None:
        program.cost.evaluators = program.evaluators + program.exchange_evaluators
    return added
