"""Exciting-trajectory optimization as pieces of a Drake MathematicalProgram.

The problem (Eq. 7): minimize cond(C) (by default its smooth bound ``soft_cond``), C = [C0; Y_B
at T samples] (Eq. 41), over the Fourier coefficients alpha (Eq. 50), subject to the joint limits
(Eq. 51) and any sampled constraint (balance Eq. 52, self-collision Eq. 53, ...).

Use it like pink's build/solve split::

    problem = ExcitationProblem(robot, config.excitation)
    program = build_excitation_program(problem)          # a Drake MathematicalProgram inside
    program.prog.AddConstraint(...)                      # add your own Drake constraints
    result = solve_excitation(program, solver="ipopt")   # pe_drake.excitation.solve

or add the pieces to a program of your own with :func:`add_excitation_cost`,
:func:`~pe_drake.excitation.limits.add_joint_limit_constraints`,
:func:`~pe_drake.excitation.limits.add_rest_constraints` and :func:`add_sampled_constraint`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable

import numpy as np

from pe_drake.exceptions import ConfigError
from pe_drake.excitation.constraints.base import SampledConstraint
from pe_drake.excitation.fourier import FourierBasis, sample_times
from pe_drake.excitation.limit_windows import CachedRows, add_window_limit_constraints
from pe_drake.excitation.limits import (
    add_joint_limit_constraints,
    add_rest_constraints,
    joint_limit_violation,
)
from pe_drake.excitation.problem import ExcitationProblem, check_variables
from pe_drake.excitation.scaling import harmonic_scale
from pe_drake.excitation.stall import CriterionStalled, StallRule

#: Samples per row of a one-sided sampled constraint (balance, collision, environment): each
#: run of this many samples becomes one log-sum-exp row (these dense rows dominate IPOPT's
#: linear algebra; BUILD_NOTES.md has the measurements).
SAMPLES_PER_ROW = 16
#: From this many harmonics on, the default solves in the coordinates of
#: :mod:`pe_drake.excitation.scaling` (cheaper for N = 10, worse for N = 5: BUILD_NOTES.md).
SCALED_HARMONICS = 8
#: The stall rule of every IPOPT solve of a built program unless told otherwise.
DEFAULT_STALL = StallRule()


class ExcitationCost:
    """A callable Drake cost: the criterion with our gradient (BUILD_NOTES.md, "Drake facts").

    Args:
        on_evaluate: optional ``f(alpha, value)`` called after each evaluation (progress).
        stall: a :class:`~pe_drake.excitation.stall.StallRule`: the callback raises
            :class:`~pe_drake.excitation.stall.CriterionStalled` when it holds; None never.
    """

    def __init__(self, problem: ExcitationProblem, on_evaluate: Callable | None = None, stall: StallRule | None = None):
        self.problem, self.on_evaluate, self.stall = problem, on_evaluate, stall
        #: set only inside solve_excitation with IPOPT (NLopt's C callbacks swallow exceptions)
        self.stall_enabled = False
        #: the lowest criterion evaluated so far, after each evaluation (the stall rule's
        #: measure; within the limits or not: IPOPT's iterates sit slightly outside them)
        self.best_history: list[float] = []
        self._lowest = np.inf
        #: the program's sampled-constraint evaluators; each records its violation per alpha
        self.evaluators: list = []
        # (value, alpha) of every evaluated point within the joint limits, and the 8 best
        self._evaluated: list[tuple[float, np.ndarray]] = []
        self._best: list[tuple[float, np.ndarray]] = []

    @property
    def candidates(self) -> list[tuple[float, np.ndarray]]:
        """Fallback points when the solver stops at an infeasible iterate, to try in order.

        First the 8 best evaluated points that met the joint limits and every sampled
        constraint at the samples, then the 8 best that met the joint limits (by value alone,
        cheaper infeasible iterates would crowd the feasible ones out).
        """
        feasible = []
        for value, alpha in self._evaluated:
            key = alpha.tobytes()
            seen = [ev.violations.get(key) for ev in self.evaluators]
            if all(v is not None and v <= 0.0 for v in seen):
                feasible.append((value, alpha))
        feasible.sort(key=lambda c: c[0])
        picked = feasible[:8]
        ids = {id(alpha) for _, alpha in picked}
        return picked + [c for c in self._best if id(c[1]) not in ids]

    @property
    def best_value(self) -> float | None:
        """The lowest criterion evaluated within the joint limits (None before any)."""
        return self._best[0][0] if self._best else None

    def reset(self) -> None:
        """Forgets the points of earlier solves (each solve falls back to its own points)."""
        self._evaluated.clear()
        self._best.clear()
        self.best_history.clear()
        self._lowest = np.inf
        for ev in self.evaluators:
            ev.violations.clear()

    def remember(self, alpha: np.ndarray, value: float) -> None:
        """Keeps (value, alpha) as a fallback candidate if finite and within the joint limits."""
        if not np.isfinite(value) or joint_limit_violation(self.problem, alpha) > 1e-9:
            return
        entry = (value, alpha.copy())
        self._evaluated.append(entry)
        if len(self._best) < 8 or value < self._best[-1][0]:
            self._best.append(entry)
            self._best.sort(key=lambda c: c[0])
            del self._best[8:]

    def value_and_gradient(self, alpha: np.ndarray) -> tuple[float, np.ndarray]:
        """The criterion (1e20 where it is not finite) and its gradient at alpha."""
        alpha = np.asarray(alpha, float)
        out = self.problem.evaluate(alpha)
        value = out.value if np.isfinite(out.value) else 1e20
        self.remember(alpha, out.value)
        if self.on_evaluate is not None:
            self.on_evaluate(alpha, value)
        if np.isfinite(out.value):
            self._lowest = min(self._lowest, float(out.value))
        self.best_history.append(self._lowest)
        logarithmic = self.problem.config.criterion in ("log_cond", "dopt")
        if self.stall is not None and self.stall_enabled and self.stall.stalled(self.best_history, logarithmic):
            raise CriterionStalled(f"{self.problem.config.criterion} improved by less than "
                                   f"{self.stall.improvement:.3g} in {self.stall.window} evaluations")
        return value, out.grad

    def __call__(self, x):
        # pydrake is imported lazily so that `import pe_drake` stays light.
        from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, ExtractValue

        if x.dtype == object:
            value, grad = self.value_and_gradient(ExtractValue(x).reshape(-1))
            return AutoDiffXd(value, grad @ ExtractGradient(x))
        value = self.problem.evaluate(np.asarray(x, float)).value
        return value if np.isfinite(value) else 1e20


def add_excitation_cost(prog, alpha, problem: ExcitationProblem, on_evaluate: Callable | None = None):
    """Adds the excitation criterion of ``problem`` as a cost on ``alpha``; returns the binding."""
    check_variables(alpha, problem)
    return prog.AddCost(ExcitationCost(problem, on_evaluate), vars=alpha, description="excitation")


class SampledConstraintEvaluator(CachedRows):
    """Chains a :class:`SampledConstraint` through the Fourier map (Eq. 49) for Drake.

    With ``group`` > 1, each run of ``group`` consecutive samples becomes one row bounded by
    a log-sum-exp over the run: ``upper + τ log Σ exp((g − upper)/τ) ≤ upper`` for an upper
    bound (``lower − τ log Σ exp((lower − g)/τ) ≥ lower`` for a lower bound). It is never
    below the run's maximum (above its minimum), so every sample still meets its bound; the
    aggregate is conservative by at most τ·log(group).
    """

    def __init__(
        self, problem: ExcitationProblem, constraint: SampledConstraint, basis: FourierBasis, group: int, tau: float
    ):
        self.problem, self.constraint, self.basis = problem, constraint, basis
        self.group, self.tau = group, tau
        lo, hi = constraint.lower, constraint.upper
        self.upper_side = np.isfinite(hi) & ~np.isfinite(lo)
        if group > 1 and not np.all(np.isfinite(lo) ^ np.isfinite(hi)):
            raise ConfigError(f"constraint '{constraint.name}': grouping needs one-sided bounds")
        self.last_violation = 0.0
        #: worst violation at the samples per evaluated alpha.tobytes() (ExcitationCost.candidates)
        self.violations: dict[bytes, float] = {}

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        rows = len(self.basis.t) // self.group
        return np.tile(self.constraint.lower, rows), np.tile(self.constraint.upper, rows)

    def _rows(self, alpha: np.ndarray, key: bytes) -> tuple[np.ndarray, np.ndarray]:
        n, basis = self.problem.n, self.basis
        q, v, vd = basis.evaluate_alpha(alpha, n)
        out = self.constraint.evaluate(q, v, vd)
        K, m = out.value.shape
        # Chain rule through the Fourier map (Eq. 49); balance and collision depend on q
        # only, so their v and vdot terms are skipped rather than multiplied by zeros.
        terms = [(d, i) for i, d in enumerate((out.d_q, out.d_v, out.d_vd)) if d is not None]

        def part(*S):
            return sum(d[..., None] * S[i][:, None, None, :] for d, i in terms).reshape(K, m, -1)

        J = np.concatenate(
            [part(basis.S_q, basis.S_v, basis.S_vd), part(basis.C_q, basis.C_v, basis.C_vd), out.d_q], axis=-1
        )
        g = out.value
        lo, hi = self.constraint.lower, self.constraint.upper
        self.last_violation = float(max(0.0, np.max(lo - g), np.max(g - hi)))
        self.violations[key] = self.last_violation
        if self.group > 1:
            G, tau = self.group, self.tau
            bound = np.where(self.upper_side, hi, lo)
            sign = np.where(self.upper_side, 1.0, -1.0)
            z = (sign * (g - bound) / tau).reshape(K // G, G, m)
            zmax = z.max(axis=1, keepdims=True)
            e = np.exp(z - zmax)
            total = e.sum(axis=1, keepdims=True)
            g = bound + sign * tau * (zmax + np.log(total))[:, 0, :]
            w = (e / total)[..., None]  # softmax weights, (K/G, G, m, 1)
            J = (w * J.reshape(K // G, G, m, -1)).sum(axis=1)
            K = K // G
        return g.reshape(-1), J.reshape(K * m, -1)


def add_sampled_constraint(
    prog,
    alpha,
    problem: ExcitationProblem,
    constraint: SampledConstraint,
    samples: int | None = None,
    group: int | None = None,
    tau: float = 2e-4,
):
    """Adds lower ≤ g(q(t), v(t), vdot(t)) ≤ upper at the constraint samples (or ``samples``
    evenly spaced ones) as a Drake constraint on alpha with an analytic Jacobian.

    Returns the binding, described by the constraint's name.

    Args:
        group: samples per row (:class:`SampledConstraintEvaluator`); default for one-sided
            constraints gcd(K, :data:`SAMPLES_PER_ROW`), else 1.
        tau: smoothing of the grouped rows, in the constraint's unit (0.2 mm for metres:
            conservative by at most τ·log(group) ≈ 0.55 mm).
    """
    check_variables(alpha, problem)
    return _add_sampled(prog, alpha, problem, constraint, samples, group, tau)[0]


def _add_sampled(prog, alpha, problem, constraint, samples=None, group=None, tau=2e-4):
    basis = problem.constraint_basis
    if samples is not None:
        basis = FourierBasis(problem.harmonics, problem.omega, sample_times(problem.period, samples))
    K = len(basis.t)
    one_sided = np.all(np.isfinite(constraint.lower) ^ np.isfinite(constraint.upper))
    if group is None:  # the largest run of at most SAMPLES_PER_ROW that divides K
        group = math.gcd(K, SAMPLES_PER_ROW) if one_sided else 1
    if K % group:
        raise ConfigError(f"constraint '{constraint.name}': group {group} does not divide {K} samples")
    evaluator = SampledConstraintEvaluator(problem, constraint, basis, group, tau)
    lower, upper = evaluator.bounds()
    binding = prog.AddConstraint(evaluator, lower, upper, vars=alpha, description=constraint.name)
    return binding, evaluator


@dataclasses.dataclass
class ExcitationProgram:
    """A built Drake program and what it was built from.

    Attributes:
        prog: the MathematicalProgram (add your own costs/constraints before solving).
        alpha: its decision variables, shape ((2N+1)·n,).
        constraints: the :class:`SampledConstraint` objects added (balance, collision, ...);
            ``evaluators`` (and ``sampled_bindings``) theirs, in order.
        progress: the ``f(alpha, value)`` called after each cost evaluation, or None.
        cost: the program's :class:`ExcitationCost` (its fallback ``candidates``).
        limits: how the joint limits were added ("windows" or "sampled"); ``limit_evaluators``
            the :class:`~pe_drake.excitation.limit_windows.WindowMaxRows` ("windows" only).
        exchange_bindings / exchange_evaluators: rows added by the exchange step.
        variable_scale: d of the solver's coordinates beta = alpha / d
            (:mod:`pe_drake.excitation.scaling`), or None to solve in alpha.
    """

    prog: object
    alpha: np.ndarray
    problem: ExcitationProblem
    constraints: list[SampledConstraint]
    evaluators: list[SampledConstraintEvaluator] = dataclasses.field(default_factory=list)
    progress: Callable | None = None
    cost: ExcitationCost | None = None
    limits: str = "windows"
    limit_bindings: list = dataclasses.field(default_factory=list)
    limit_evaluators: list = dataclasses.field(default_factory=list)
    exchange_bindings: list = dataclasses.field(default_factory=list)
    exchange_evaluators: list[SampledConstraintEvaluator] = dataclasses.field(default_factory=list)
    cost_binding: object = None
    sampled_bindings: list = dataclasses.field(default_factory=list)
    variable_scale: np.ndarray | None = None

    def own_evaluators(self) -> list[tuple[object, object]]:
        """(binding, Python evaluator) of every row and cost this module added whose
        evaluator has ``values_and_jacobian`` (``value_and_gradient`` for the cost)."""
        pairs = [(self.cost_binding, self.cost), *zip(self.sampled_bindings, self.evaluators)]
        pairs += list(zip(self.limit_bindings, self.limit_evaluators))
        return pairs + list(zip(self.exchange_bindings, self.exchange_evaluators))



def build_excitation_program(
    problem: ExcitationProblem,
    constraints: list[SampledConstraint] | None = None,
    *,
    progress: bool | Callable = False,
    limits: str = "windows",
    sample_stride: int | None = None,
    scaling: str = "auto",
    stall: StallRule | None = DEFAULT_STALL,
) -> ExcitationProgram:
    """A Drake MathematicalProgram for the excitation problem.

    Args:
        constraints: extra sampled constraints (balance, collision, torque); joint limits
            and (if configured) rest at the ends are always added.
        progress: True to print a progress line every 2 s, or a callable ``f(alpha, value)``.
        limits: how the joint limits (Eq. 51) enter: "windows" (one exact window-maximum row
            per joint, quantity, side and window, :mod:`pe_drake.excitation.limit_windows`) or
            "sampled" (linear rows at every stride-th constraint sample, tightened for the
            overshoot between them).
        sample_stride: the sampled constraints are imposed at every ``sample_stride``-th
            constraint sample (default 1), the instants in between left to the exchange step
            of :func:`~pe_drake.excitation.solve.solve_excitation`.
        scaling: the solver's coordinates: "harmonic" (:mod:`pe_drake.excitation.scaling`),
            "none" (alpha itself) or "auto" ("harmonic" from :data:`SCALED_HARMONICS` on).
        stall: a :class:`StallRule` ending the solve when the criterion stalls, or None to run
            to convergence or ``solver.max_iterations``.

    Raises:
        ConfigError: an unknown ``limits`` or ``scaling``, a bad ``sample_stride``.
    """
    if limits not in ("windows", "sampled"):
        raise ConfigError(f"unknown joint-limit formulation '{limits}'; valid: windows, sampled")
    if scaling not in ("harmonic", "none", "auto"):
        raise ConfigError(f"unknown variable scaling '{scaling}'; valid: harmonic, none, auto")
    if scaling == "auto":
        scaling = "harmonic" if problem.harmonics >= SCALED_HARMONICS else "none"
    K = problem.config.constraint_samples
    stride = 1 if sample_stride is None else sample_stride
    if not isinstance(stride, int) or stride < 1 or K % stride:
        raise ConfigError(f"sample_stride must be a positive integer dividing the {K} constraint "
                          f"samples, got {stride!r}")
    from pydrake.solvers import MathematicalProgram  # lazily, as above

    prog = MathematicalProgram()
    alpha = prog.NewContinuousVariables(problem.num_variables, "alpha")
    program = ExcitationProgram(prog, alpha, problem, list(constraints or []), limits=limits)
    if scaling == "harmonic":
        program.variable_scale = harmonic_scale(problem.harmonics, problem.omega, problem.robot.limits)
    program.progress = _ProgressPrinter(program) if progress is True else progress or None
    program.cost = ExcitationCost(problem, program.progress, stall)
    program.cost_binding = prog.AddCost(program.cost, vars=alpha, description="excitation")
    if limits == "windows":
        evaluators = program.limit_evaluators
        program.limit_bindings = add_window_limit_constraints(prog, alpha, problem, evaluators)
    else:
        program.limit_bindings = add_joint_limit_constraints(prog, alpha, problem)
    if problem.config.rest_at_ends:
        add_rest_constraints(prog, alpha, problem)
    for c in program.constraints:
        binding, evaluator = _add_sampled(prog, alpha, problem, c, samples=K // stride)
        program.sampled_bindings.append(binding)
        program.evaluators.append(evaluator)
    program.cost.evaluators = program.evaluators
    return program


class _ProgressPrinter:
    """Prints evaluation count, best criterion so far and the worst constraint violation."""

    every = 2.0  # [s] between lines

    def __init__(self, program: ExcitationProgram):
        self.program, self.best, self.count = program, np.inf, 0
        self.last_print, self.start = -np.inf, time.perf_counter()

    def __call__(self, alpha: np.ndarray, value: float) -> None:
        self.count += 1
        now = time.perf_counter()
        violation = joint_limit_violation(self.program.problem, alpha)
        for ev in self.program.evaluators:
            violation = max(violation, ev.last_violation)
        if violation < 1e-6:
            self.best = min(self.best, value)
        if now - self.last_print >= self.every:
            self.last_print = now
            print(f"  eval {self.count:5d}  {self.program.problem.config.criterion} {value:12.5g}"
                  f"  best feasible {self.best:12.5g}  max violation {violation:9.2e}"
                  f"  {now - self.start:6.1f} s", flush=True)
