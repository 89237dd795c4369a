"""The exchange step for the sampled constraints: re-check at 1 kHz, add the violated instants.

Balance, self-collision and the environment (Eqs. 52–53) are imposed at the K constraint
samples and can still be violated between them. :func:`add_violated_samples` evaluates every
sampled constraint at the check rate and adds one row per local minimum of its margin below
zero (kept ``backoff`` inside the bound); the solver then continues from the current point.
Semi-infinite programming calls this an exchange method: rows only where the constraint binds.
The joint limits need none: their window rows are exact at every instant.
"""

from __future__ import annotations

import numpy as np

from pe_drake.excitation.fourier import FourierBasis
from pe_drake.excitation.program import ExcitationProgram, SampledConstraintEvaluator


def violated_instants(margin: np.ndarray, tolerance: float) -> np.ndarray:
    """Indices of the periodic local minima of ``margin`` (shape (M,)) below −tolerance."""
    margin = np.asarray(margin, float)
    local = (margin <= np.roll(margin, 1)) & (margin < np.roll(margin, -1))
    return np.flatnonzero(local & (margin < -tolerance))


def add_violated_samples(
    program: ExcitationProgram, alpha: np.ndarray, rate: float = 1000.0, tolerance: float = 1e-6, backoff: float = 1e-4
) -> int:
    """Adds a row at each instant where a sampled constraint is violated (module docstring).

    ``program`` gains one binding per constraint with violations (``exchange_bindings``,
    ``exchange_evaluators``); a margin below −``tolerance`` at ``rate`` [Hz] is a violation,
    and the added rows stay ``backoff`` inside the bound (both in the constraint's unit).

    Returns:
        The number of instants added (0: nothing violated at ``rate``).
    """
    problem = program.problem
    t = np.arange(0.0, problem.period, 1.0 / rate)
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
    program.cost.evaluators = program.evaluators + program.exchange_evaluators
    return added
