"""Stopping a solve whose criterion has stalled (issue 38).

IPOPT's own tests never end a G1 or two-arm start: its dual infeasibility stays far above any
tolerance while the criterion creeps (cond 189 → 188 over the last 100 of 300 iterations on
G1 in the harmonic coordinates of :mod:`pe_drake.excitation.scaling`), and its "acceptable"
rule needs every error small at once (it did not fire on G1 either, BUILD_NOTES.md). This
rule watches the solver's progress: the lowest criterion evaluated so far (not only among
the points within the joint limits: IPOPT's iterates sit 1e-4–1e-3 outside them for long
stretches, and that best then lags; on the Panda it ended a start at cond 12.7 instead of
11). When it has improved by less than ``improvement`` (relative) over the last ``window``
cost evaluations, the cost callback raises :class:`CriterionStalled`,
which unwinds Drake's solve; :func:`~pe_drake.excitation.solve.solve_excitation` catches it
and continues as after an iteration limit (the best valid point evaluated, re-checked at
1 kHz).
"""

from __future__ import annotations

import contextlib
import dataclasses
from typing import NamedTuple

import numpy as np


class CriterionStalled(Exception):
    """Raised by the cost callback to end a solve whose criterion has stalled (control flow
    inside :func:`~pe_drake.excitation.solve.solve_excitation`, never seen by a caller)."""


@dataclasses.dataclass(frozen=True)
class StallRule:
    """Stop when the lowest criterion evaluated improved by less than ``improvement`` over
    the last ``window`` evaluations, after at least ``min_evaluations``.

    Replayed on recorded 300-iteration histories (BUILD_NOTES.md, "Third round"): with 40
    evaluations, 1 % and 150, G1 (6 seeds) would have stopped at 0.93–1.05× the former
    formulation's 300-iteration cond (mean 0.97) in about half its iterations, the two-arm
    robot at 0.96–1.06× (mean 1.01). Live, 1 % let the two-arm robot run 157–300 iterations;
    2 % (the default) stopped it after 141–145 at 1.00–1.03× the former cond. The
    minimum keeps an early plateau from ending a start (G1 with 20 quasi-Newton pairs paused
    at cond 218 after 103 iterations; the UR5 at 11.3 after 114 evaluations, ending at 8.9).
    """

    window: int = 40  # cost evaluations
    improvement: float = 0.02  # relative (for a logarithmic criterion: of its exponential)
    min_evaluations: int = 150

    def __post_init__(self):
        for name in ("window", "min_evaluations"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"stall {name} must be a positive integer, got {value!r}")
        if not 0.0 <= self.improvement < 1.0:
            raise ValueError(f"stall improvement must be in [0, 1), got {self.improvement!r}")

    def stalled(self, best: list[float], logarithmic: bool = False) -> bool:
        """Whether the history ``best`` (the best criterion after each evaluation, inf before
        the first finite value) has stalled. ``logarithmic``: the
        criterion is a logarithm (log_cond, dopt), judged on its difference."""
        if len(best) <= max(self.window, self.min_evaluations - 1):
            return False
        now, then = best[-1], best[-1 - self.window]
        if not (np.isfinite(now) and np.isfinite(then)):
            return False
        if logarithmic:
            return then - now < -np.log1p(-self.improvement)
        return then - now < self.improvement * abs(then)


class _Status(NamedTuple):
    name: str


class StalledResult:
    """What a solve ended by :class:`~pe_drake.excitation.stall.CriterionStalled` returns in
    place of Drake's result: not a success; its solution is the best evaluated point
    within the joint limits (the fallback re-checks it at 1 kHz)."""

    def __init__(self, alpha: np.ndarray, x: np.ndarray, reason: str):
        self._alpha, self._x, self.reason = alpha, np.asarray(x, float), reason

    def is_success(self) -> bool:
        return False

    def GetSolution(self, variables):  # noqa: N802 (Drake's name)
        if variables is not self._alpha:
            raise ValueError("a stalled solve knows only the Fourier coefficients alpha")
        return self._x.copy()

    def get_solution_result(self) -> _Status:
        return _Status("kStalled")

    def get_solver_details(self):
        return self

    def ConvertStatusToString(self) -> str:  # noqa: N802 (Drake's name)
        return self.reason


@contextlib.contextmanager
def stall_rule_active(cost, enabled: bool):
    """The stall rule of ``cost`` (an :class:`~pe_drake.excitation.program.ExcitationCost`, or
    None) acts inside this block only, where the solve catches :class:`CriterionStalled`."""
    if cost is None:
        yield
        return
    cost.stall_enabled = enabled
    try:
        yield
    finally:
        cost.stall_enabled = False
