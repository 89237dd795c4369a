"""Stopping a solve whose criterion has stalled (issue 38).

IPOPT's own tests rarely end a G1 or two-arm start: its dual infeasibility stays far above any
tolerance while the criterion creeps. This rule watches the lowest criterion evaluated so far
(within the joint limits or not: IPOPT's iterates sit slightly outside them for long stretches).
When it has improved by less than ``improvement`` (relative) over the last ``window`` cost
evaluations, the cost callback raises :class:`CriterionStalled`, which unwinds Drake's solve;
:func:`~pe_drake.excitation.solve.solve_excitation` catches it and continues as after an
iteration limit. The defaults were tuned on recorded histories (BUILD_NOTES.md).
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
    the last ``window`` evaluations, after at least ``min_evaluations`` (which keeps an early
    plateau from ending a start)."""

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
        the first finite value) has stalled. ``logarithmic``: the criterion is a logarithm
        (log_cond, dopt), judged on its difference."""
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
    """Drake's result in place, for a solve ended by :class:`CriterionStalled`: not a success;
    its solution is the best evaluated point within the joint limits."""

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
    """The stall rule of ``cost`` (an :class:`~pe_drake.excitation.program.ExcitationCost`)
    acts inside this block only, where the solve catches :class:`CriterionStalled`."""
    cost.stall_enabled = enabled
    try:
        yield
    finally:
        cost.stall_enabled = False
