"""Exciting-trajectory optimization as pieces of a Drake MathematicalProgram.

The problem (Eq. 7): minimize cond(C), C = [C0; Y_B at T samples] (Eq. 41), over the
Fourier coefficients alpha (Eq. 50), subject to joint limits at K samples (Eq. 51) and any
sampled constraint (balance Eq. 52, self-collision Eq. 53, ...).

Use it like pink's build/solve split::

    problem = ExcitationProblem(robot, config.excitation)
    program = build_excitation_program(problem)          # a Drake MathematicalProgram inside
    program.prog.AddConstraint(...)                      # add your own Drake constraints
    result = solve_excitation(program, solver="ipopt")

or add the pieces to a program of your own with :func:`add_excitation_cost`,
:func:`add_joint_limit_constraints`, :func:`add_rest_constraints` and
:func:`add_sampled_constraint`.
"""

from __future__ import annotations

import dataclasses
import math
import re
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from pe_drake.config import ExcitationConfig, SolverConfig, validate_config
from pe_drake.exceptions import ConfigError, InfeasibleError, NoSolutionFound
from pe_drake.excitation.constraints.base import SampledConstraint
from pe_drake.excitation.criteria import evaluate_criterion
from pe_drake.excitation.fourier import FourierBasis, FourierTrajectory, sample_times
from pe_drake.memory import reuse_freed_memory
from pe_drake.multibody.base_parameters import BaseParameters, compute_base_parameters
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.sensors import SensorRows, measurement_type
from pe_drake.threads import single_threaded_blas


@dataclasses.dataclass(frozen=True)
class CostValue:
    """Value and gradient of the excitation cost at one alpha."""

    value: float
    grad: np.ndarray
    singular_values: np.ndarray


class ExcitationProblem:
    """The excitation cost of Eq. (41) for a robot, with its analytic gradient (Eq. 49).

    Args:
        robot: the :class:`~pe_drake.multibody.robot.Robot`.
        config: harmonics, ω, sample counts, criterion (:class:`ExcitationConfig`).
        C0: prior data, the stacked base regressor of earlier motions, shape (m1, b).
        base: base parameters to use (computed if not given).

    Attributes:
        num_variables: (2N+1)·n.
        cost_basis / constraint_basis: Fourier bases at the T cost / K constraint samples.
    """

    def __init__(
        self,
        robot,
        config: ExcitationConfig | None = None,
        *,
        C0: np.ndarray | None = None,
        base: BaseParameters | None = None,
        model: RegressorModel | None = None,
    ):
        from pe_drake.config import Config

        self.robot = robot
        self.config = config or ExcitationConfig()
        validate_config(Config(excitation=self.config))
        self.model = model or RegressorModel(robot)
        # The rows of C: joint torques (Eq. 1), the ground wrench, or both (issue 14).
        self.rows = SensorRows(self.model, measurement_type(self.config))
        if base is None and self.config.measurement == "joint_torque":
            base = compute_base_parameters(robot, model=self.model)
        self.base = base or self.rows.base_parameters()
        self.n = robot.n
        _check_cost_rows(self)
        self.harmonics = self.config.harmonics
        self.omega = self.config.omega
        self.period = 2 * math.pi / self.omega
        self.num_variables = (2 * self.harmonics + 1) * self.n
        self.cost_basis = FourierBasis(
            self.harmonics, self.omega, sample_times(self.period, self.config.cost_samples)
        )
        self.constraint_basis = FourierBasis(
            self.harmonics, self.omega, sample_times(self.period, self.config.constraint_samples)
        )
        if C0 is not None:
            C0 = np.asarray(C0, float)
            if C0.ndim != 2 or C0.shape[1] != self.base.count:
                raise ConfigError(
                    f"prior data C0 has shape {C0.shape}; it needs {self.base.count} columns "
                    "(the robot's base parameters)"
                )
        self.C0 = C0
        self._cache_key: bytes | None = None
        self._cache: CostValue | None = None
        self.num_evaluations = 0

    # ---- cost ---------------------------------------------------------------------------
    def trajectory(self, alpha: np.ndarray) -> FourierTrajectory:
        return FourierTrajectory.from_alpha(alpha, self.n, self.harmonics, self.omega)

    def regressor_block(self, alpha: np.ndarray) -> np.ndarray:
        """Ŷ_B of one motion at the T cost samples (Eq. 3), shape (T·r, b) (r rows per sample)."""
        q, v, vd = self.cost_basis.evaluate_alpha(np.asarray(alpha, float), self.n)
        Y = self.rows(q, v, vd)
        return self.base.reduce(Y).reshape(-1, self.base.count)

    def stacked(self, alpha: np.ndarray) -> np.ndarray:
        """C = [C0; Ŷ_B] (Eq. 41)."""
        block = self.regressor_block(alpha)
        return block if self.C0 is None else np.vstack([self.C0, block])

    def value(self, alpha: np.ndarray) -> float:
        """The criterion at alpha (no gradient)."""
        return evaluate_criterion(self.stacked(alpha), self.config.criterion, gradient=False).value

    def evaluate(self, alpha: np.ndarray) -> CostValue:
        """Criterion and its analytic gradient with respect to alpha.

        The chain: Eq. (17) gives dc/dC; its rows for sample t times Xᵀ give Z^(t)
        (Eqs. 45–46); the regressor's adjoint turns Z into dc/d(q, v, vdot) (Eq. 47); the
        Fourier map pulls that back to alpha (Eq. 49). Cached on alpha, because Drake's
        solvers ask for the same point more than once.
        """
        alpha = np.asarray(alpha, float)
        key = alpha.tobytes()
        if key == self._cache_key and self._cache is not None:
            return self._cache
        self.num_evaluations += 1
        q, v, vd = self.cost_basis.evaluate_alpha(alpha, self.n)
        kin = self.model.kinematics(q, v, vd)
        Y = self.rows.rows(kin)
        T, r, b = Y.shape[0], Y.shape[1], self.base.count
        block = self.base.reduce(Y).reshape(T * r, b)
        C = block if self.C0 is None else np.vstack([self.C0, block])
        crit = evaluate_criterion(C, self.config.criterion)  # Eq. (17)
        if not np.isfinite(crit.value):
            out = CostValue(np.inf, np.zeros_like(alpha), crit.singular_values)
        else:
            G = crit.grad[C.shape[0] - T * r :].reshape(T, r, b)
            Z = np.zeros_like(Y)
            Z[..., self.base.independent] = G  # Eq. (46): Z = X C(C) S^T
            q_bar, v_bar, vd_bar = self.rows.pullback(kin, Z)  # Eq. (47); docs/derivations.md §4a
            grad = self.cost_basis.pullback(q_bar, v_bar, vd_bar)  # Eq. (49)
            out = CostValue(crit.value, grad, crit.singular_values)
        self._cache_key, self._cache = key, out
        return out

    # ---- initial point --------------------------------------------------------------------
    def initial_guess(self, seed: int | None = None, amplitude: float | None = None) -> np.ndarray:
        """A random alpha within the joint limits at the constraint samples.

        Coefficients ~ N(0, (amplitude/k)²) around the nominal posture, scaled down as needed
        (q, v, vdot are linear in the coefficients) to use at most 90 % of each limit.
        """
        rng = np.random.default_rng(self.config.seed if seed is None else seed)
        amplitude = self.config.amplitude if amplitude is None else amplitude
        n, N = self.n, self.harmonics
        k = np.arange(1, N + 1)
        a = rng.normal(size=(n, N)) * amplitude / k
        b = rng.normal(size=(n, N)) * amplitude / k
        q0 = self.robot.nominal_posture().copy()
        alpha = np.concatenate([a.ravel(), b.ravel(), q0])
        if self.config.rest_at_ends:
            alpha = _project_rest(self, alpha)
        return _scale_into_limits(self, alpha, 0.9)


def _check_cost_rows(problem: ExcitationProblem) -> None:
    """C needs at least as many rows as base parameters (the wrench gives 6 per sample)."""
    rows = problem.config.cost_samples * problem.rows.num_rows
    if rows < problem.base.count:
        need = math.ceil(problem.base.count / problem.rows.num_rows)
        raise ConfigError(
            f"excitation.cost_samples = {problem.config.cost_samples} gives {rows} rows of "
            f"{problem.config.measurement} for {problem.base.count} base parameters: use at least {need}"
        )


def _project_rest(problem: ExcitationProblem, alpha: np.ndarray) -> np.ndarray:
    A, _ = rest_constraint_matrix(problem)
    # Minimal change of alpha with A alpha = 0 (q0 does not enter A).
    return alpha - np.linalg.pinv(A) @ (A @ alpha)


def _scale_into_limits(problem: ExcitationProblem, alpha: np.ndarray, fraction: float) -> np.ndarray:
    basis, lim, n = problem.constraint_basis, problem.robot.limits, problem.n
    nN = n * problem.harmonics
    q0 = alpha[2 * nN :]
    dyn = alpha.copy()
    dyn[2 * nN :] = 0.0
    q, v, vd = basis.evaluate_alpha(dyn, n)
    room_up = fraction * (lim.q_upper - q0)
    room_lo = fraction * (q0 - lim.q_lower)
    if np.any(room_up <= 0) or np.any(room_lo <= 0):
        bad = int(np.argmin(np.minimum(room_up, room_lo)))
        name = problem.robot.joint_names[bad]
        raise InfeasibleError(
            f"nominal position {q0[bad]:.4g} of joint '{name}' is not inside its limits "
            f"[{lim.q_lower[bad]:.4g}, {lim.q_upper[bad]:.4g}]"
        )
    ratios = [
        np.max(np.maximum(q, 0) / room_up[None, :]),
        np.max(np.maximum(-q, 0) / room_lo[None, :]),
        np.max(np.abs(v) / (fraction * lim.v_max)),
        np.max(np.abs(vd) / (fraction * lim.vd_max)),
    ]
    scale = 1.0 / max(1.0, max(ratios))
    out = dyn * scale
    out[2 * nN :] = q0
    return out


# ---- Drake program pieces -------------------------------------------------------------------
class ExcitationCost:
    """A callable Drake cost: the criterion with our gradient (DRAKE_NOTES.md pattern).

    Args:
        problem: the :class:`ExcitationProblem`.
        on_evaluate: optional ``f(alpha, value)`` called after each evaluation (progress).
    """

    def __init__(self, problem: ExcitationProblem, on_evaluate: Callable | None = None):
        self.problem = problem
        self.on_evaluate = on_evaluate
        #: The program's sampled-constraint evaluators (set by build_excitation_program);
        #: each records its violation per evaluated alpha.
        self.evaluators: list = []
        # (value, alpha) of every evaluated point that met the joint limits at the samples,
        # and the 8 best of them.
        self._evaluated: list[tuple[float, np.ndarray]] = []
        self._best: list[tuple[float, np.ndarray]] = []

    @property
    def candidates(self) -> list[tuple[float, np.ndarray]]:
        """Fallback points when the solver stops at an infeasible iterate, to try in order.

        First the 8 best evaluated points that met the joint limits and every sampled
        constraint at the samples, then the 8 best that met the joint limits. Ranking by value
        alone missed the feasible points whenever lower-valued infeasible ones crowded them
        out (a feasible start, then cheaper iterates in collision).
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

    def reset(self) -> None:
        """Forgets the points of earlier solves (each solve falls back to its own points)."""
        self._evaluated.clear()
        self._best.clear()
        for ev in self.evaluators:
            ev.violations.clear()

    def _remember(self, alpha: np.ndarray, value: float) -> None:
        if not np.isfinite(value) or joint_limit_violation(self.problem, alpha) > 1e-9:
            return
        entry = (value, alpha.copy())
        self._evaluated.append(entry)
        if len(self._best) < 8 or value < self._best[-1][0]:
            self._best.append(entry)
            self._best.sort(key=lambda c: c[0])
            del self._best[8:]

    def __call__(self, x):
        from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, ExtractValue

        if x.dtype == object:
            alpha = ExtractValue(x).reshape(-1)
            out = self.problem.evaluate(alpha)
            value = out.value if np.isfinite(out.value) else 1e20
            self._remember(alpha, out.value)
            if self.on_evaluate is not None:
                self.on_evaluate(alpha, value)
            return AutoDiffXd(value, out.grad @ ExtractGradient(x))
        alpha = np.asarray(x, float)
        value = self.problem.evaluate(alpha).value
        return value if np.isfinite(value) else 1e20


def add_excitation_cost(prog, alpha, problem: ExcitationProblem, on_evaluate: Callable | None = None):
    """Adds the excitation criterion of ``problem`` as a cost on ``alpha``.

    Returns:
        The Drake cost binding.
    """
    return _add_cost(prog, alpha, problem, on_evaluate)[0]


def _add_cost(prog, alpha, problem, on_evaluate=None):
    _check_vars(alpha, problem)
    cost = ExcitationCost(problem, on_evaluate)
    return prog.AddCost(cost, vars=alpha, description="excitation"), cost


def add_joint_limit_constraints(
    prog, alpha, problem: ExcitationProblem, stride: int | None = None, max_conservatism: float = 0.02
) -> list:
    """Eq. (51): q, v, vdot within the robot's limits at the K constraint samples (and between).

    Linear in alpha, so added as linear constraints, one per joint and quantity (each touches
    only that joint's 2N+1 coefficients). IPOPT's cost per iteration grows quickly with the
    row count (0.5 s at 6K = 2400 rows per joint on G1), so rows are imposed on every
    ``stride``-th sample with the bound tightened by the largest possible overshoot between
    rows (:func:`intersample_allowance`): that implies the limits at all K samples and at
    every instant. The default stride is the largest (≤ 8) whose tightening stays within
    ``max_conservatism`` of each velocity and acceleration limit.

    Returns:
        The bindings.
    """
    _check_vars(alpha, problem)
    lim = problem.robot.limits
    K = len(problem.constraint_basis.t)
    if stride is None:
        stride = 1
        for s in (2, 4, 8):
            dq, dv, dvd = intersample_allowance(problem, s)
            if K % s == 0 and np.all(dv <= max_conservatism * lim.v_max) and np.all(dvd <= max_conservatism * lim.vd_max):
                stride = s
    dq, dv, dvd = intersample_allowance(problem, stride)
    rows = np.arange(0, K, stride)
    bindings = []
    for j, name in enumerate(problem.robot.joint_names):
        A_q, A_v, A_vd, idx = problem.constraint_basis.matrices(problem.n, j)
        for A, lo, hi, what in (
            (A_q, lim.q_lower[j] + dq[j], lim.q_upper[j] - dq[j], "position"),
            (A_v, -lim.v_max[j] + dv[j], lim.v_max[j] - dv[j], "velocity"),
            (A_vd, -lim.vd_max[j] + dvd[j], lim.vd_max[j] - dvd[j], "acceleration"),
        ):
            b = prog.AddLinearConstraint(A[rows], np.full(len(rows), lo), np.full(len(rows), hi), alpha[idx])
            b.evaluator().set_description(f"{what} limit {name}")
            bindings.append(b)
    return bindings


class _SmoothMaxLimits:
    """Every sampled joint limit of Eq. (51), aggregated per joint and bound by a smooth max.

    For joint j and each of q, v, vdot, the K sampled values x_k must stay within
    [lower, upper]. Instead of 2K linear rows (which make IPOPT's limited-memory steps cost
    ~0.5 s per iteration at K = 400 on G1), each side becomes one row
    g = (1/ρ) log Σ_k exp(ρ·(x_k − bound)/s) ≤ 0, with s the limit's scale. Log-sum-exp is
    convex and never below the maximum, so g ≤ 0 implies every sample is within its limit;
    it overestimates the maximum by at most log(K)/ρ·s, which ``conservatism`` sets
    (fraction of s).
    """

    def __init__(self, problem: ExcitationProblem, conservatism: float = 0.005):
        lim = problem.robot.limits
        dq, dv, dvd = intersample_allowance(problem)
        self.problem = problem
        basis = problem.constraint_basis
        K = len(basis.t)
        self.rho = np.log(2 * K) / conservatism
        half = 0.5 * (lim.q_upper - lim.q_lower)
        mid = 0.5 * (lim.q_upper + lim.q_lower)
        # Normalized quantities y = (x - centre)/scale must satisfy |y| ≤ 1.
        self.centre = np.stack([mid, np.zeros(problem.n), np.zeros(problem.n)])  # (3, n)
        self.scale = np.stack([half - dq, lim.v_max - dv, lim.vd_max - dvd])  # (3, n)
        self.basis = basis
        self.labels = [
            f"{what} {side} {name}"
            for name in problem.robot.joint_names
            for what in ("position", "velocity", "acceleration")
            for side in ("upper", "lower")
        ]

    def values_and_jacobian(self, alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p, b = self.problem, self.basis
        n, N = p.n, p.harmonics
        x = np.stack(b.evaluate_alpha(alpha, n))  # (3, K, n)
        y = (x - self.centre[:, None, :]) / self.scale[:, None, :]
        y = np.stack([y, -y], axis=1)  # (3, 2, K, n): upper side, lower side
        z = self.rho * (y - 1.0)
        zmax = z.max(axis=2, keepdims=True)
        e = np.exp(z - zmax)
        total = e.sum(axis=2, keepdims=True)
        g = ((zmax + np.log(total)) / self.rho)[:, :, 0, :]  # (3, 2, n)
        w = e / total  # softmax weights, (3, 2, K, n)
        sign = np.array([1.0, -1.0])[None, :, None]
        dg_dx = w * (sign[..., None] / self.scale[:, None, None, :])  # (3, 2, K, n)
        # ∂x/∂(a, b, q0) of joint j at sample k: rows of the Fourier bases.
        Sa = np.stack([b.S_q, b.S_v, b.S_vd])  # (3, K, N)
        Cb = np.stack([b.C_q, b.C_v, b.C_vd])
        Ja = np.einsum("csKn,cKN->csnN", dg_dx, Sa)
        Jb = np.einsum("csKn,cKN->csnN", dg_dx, Cb)
        Jq0 = dg_dx[0].sum(axis=1)  # (2, n): only q depends on q0
        rows = 6 * n
        J = np.zeros((n, 3, 2, (2 * N + 1) * n))
        for j in range(n):
            J[j, :, :, j * N : (j + 1) * N] = Ja[:, :, j]
            J[j, :, :, n * N + j * N : n * N + (j + 1) * N] = Jb[:, :, j]
            J[j, 0, :, 2 * n * N + j] = Jq0[:, j]
        return g.transpose(2, 0, 1).reshape(rows), J.reshape(rows, -1)

    def __call__(self, x):
        from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff

        if x.dtype == object:
            g, J = self.values_and_jacobian(ExtractValue(x).reshape(-1))
            return InitializeAutoDiff(g, J @ ExtractGradient(x)).reshape(-1)
        return self.values_and_jacobian(np.asarray(x, float))[0]


def add_smooth_joint_limit_constraints(prog, alpha, problem: ExcitationProblem, conservatism: float = 0.005):
    """Eq. (51) at the K samples as 6 smooth rows per joint (see :class:`_SmoothMaxLimits`).

    Much faster for IPOPT than :func:`add_joint_limit_constraints` at large K, at the price
    of keeping ``conservatism`` (fraction of each limit) away from the limits.
    """
    _check_vars(alpha, problem)
    evaluator = _SmoothMaxLimits(problem, conservatism)
    rows = len(evaluator.labels)
    return prog.AddConstraint(evaluator, np.full(rows, -np.inf), np.zeros(rows), vars=alpha, description="joint limits")


def intersample_allowance(problem: ExcitationProblem, stride: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How far q, v, vdot can overshoot their sampled values between two samples.

    A smooth f sampled every h exceeds the larger neighbouring sample by at most
    max|f''|·h²/8. With |vdot| ≤ a_max and Bernstein's inequality for a trigonometric
    polynomial of degree N (|f'| ≤ Nω·max|f|), the bounds are a_max·h²/8 for q,
    Nω·a_max·h²/8 for v and (Nω)²·a_max·h²/8 for vdot. The sampled limits are tightened by
    these, so the limits then hold at every instant, not only at the samples. ``stride``:
    rows on every stride-th constraint sample (spacing stride·h).
    """
    h = stride * problem.period / problem.config.constraint_samples
    w_max = problem.harmonics * problem.omega
    base = problem.robot.limits.vd_max * h**2 / 8
    return base, w_max * base, w_max**2 * base


def rest_constraint_matrix(problem: ExcitationProblem) -> tuple[np.ndarray, np.ndarray]:
    """A with A·alpha = 0 ⇔ v(0) = vdot(0) = 0 for every joint (so also at the period's end)."""
    basis = FourierBasis(problem.harmonics, problem.omega, np.zeros(1))
    n, P = problem.n, problem.num_variables
    A = np.zeros((2 * n, P))
    for j in range(n):
        _, A_v, A_vd, idx = basis.matrices(n, j)
        A[j, idx] = A_v[0]
        A[n + j, idx] = A_vd[0]
    return A, np.zeros(2 * n)


def add_rest_constraints(prog, alpha, problem: ExcitationProblem):
    """Start (and, the series being periodic, end) at rest: v = vdot = 0 at t = 0."""
    _check_vars(alpha, problem)
    A, b = rest_constraint_matrix(problem)
    binding = prog.AddLinearEqualityConstraint(A, b, alpha)
    binding.evaluator().set_description("rest at ends")
    return binding


class _SampledConstraintEvaluator:
    """Chains a :class:`SampledConstraint` through the Fourier map (Eq. 49) for Drake.

    With ``group`` > 1, each run of ``group`` consecutive samples becomes one row bounded by
    a log-sum-exp over the run: ``upper + τ log Σ exp((g − upper)/τ) ≤ upper`` for an upper
    bound (``lower − τ log Σ exp((lower − g)/τ) ≥ lower`` for a lower bound). It is never
    below the run's maximum (above its minimum), so every sample still meets its bound; the
    aggregate is conservative by at most τ·log(group). Dense rows are what make IPOPT's
    iterations expensive, so this cuts the cost per iteration without dropping samples.
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
        #: worst violation at the samples per evaluated alpha (alpha.tobytes() → value), for
        #: the solver's fallback to a feasible point (ExcitationCost.candidates)
        self.violations: dict[bytes, float] = {}

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        rows = len(self.basis.t) // self.group
        return np.tile(self.constraint.lower, rows), np.tile(self.constraint.upper, rows)

    def values_and_jacobian(self, alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n, basis = self.problem.n, self.basis
        q, v, vd = basis.evaluate_alpha(alpha, n)
        out = self.constraint.evaluate(q, v, vd)
        K, m = out.value.shape
        zero = np.zeros_like(out.d_q)
        d_q, d_v = out.d_q, out.d_v if out.d_v is not None else zero
        d_vd = out.d_vd if out.d_vd is not None else zero

        def part(Sq, Sv, Svd):
            return (
                d_q[..., None] * Sq[:, None, None, :]
                + d_v[..., None] * Sv[:, None, None, :]
                + d_vd[..., None] * Svd[:, None, None, :]
            ).reshape(K, m, -1)

        J = np.concatenate(
            [part(basis.S_q, basis.S_v, basis.S_vd), part(basis.C_q, basis.C_v, basis.C_vd), d_q], axis=-1
        )
        g = out.value
        lo, hi = self.constraint.lower, self.constraint.upper
        self.last_violation = float(max(0.0, np.max(lo - g), np.max(g - hi)))
        self.violations[np.asarray(alpha, float).tobytes()] = self.last_violation
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

    def __call__(self, x):
        from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff

        if x.dtype == object:
            g, J = self.values_and_jacobian(ExtractValue(x).reshape(-1))
            return InitializeAutoDiff(g, J @ ExtractGradient(x)).reshape(-1)
        g, _ = self.values_and_jacobian(np.asarray(x, float))
        return g


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

    Args:
        group: samples per row (see :class:`_SampledConstraintEvaluator`); default 8 for
            one-sided constraints when it divides the sample count, else 1.
        tau: smoothing of the grouped rows, in the constraint's unit (default 0.2 mm for
            metres: conservative by at most τ·log(group) ≈ 0.4 mm).

    Returns:
        The binding; its evaluator's description is the constraint's name.
    """
    return _add_sampled(prog, alpha, problem, constraint, samples, group, tau)[0]


def _add_sampled(prog, alpha, problem, constraint, samples=None, group=None, tau=2e-4):
    _check_vars(alpha, problem)
    basis = problem.constraint_basis
    if samples is not None:
        basis = FourierBasis(problem.harmonics, problem.omega, sample_times(problem.period, samples))
    K = len(basis.t)
    one_sided = np.all(np.isfinite(constraint.lower) ^ np.isfinite(constraint.upper))
    if group is None:
        group = 8 if one_sided and K % 8 == 0 else 1
    if K % group:
        raise ConfigError(f"constraint '{constraint.name}': group {group} does not divide {K} samples")
    evaluator = _SampledConstraintEvaluator(problem, constraint, basis, group, tau)
    lower, upper = evaluator.bounds()
    binding = prog.AddConstraint(evaluator, lower, upper, vars=alpha, description=constraint.name)
    return binding, evaluator


def _check_vars(alpha, problem: ExcitationProblem) -> None:
    if len(alpha) != problem.num_variables:
        raise ConfigError(
            f"alpha has {len(alpha)} variables; the problem needs {problem.num_variables} "
            f"((2N+1)·n = (2·{problem.harmonics}+1)·{problem.n})"
        )


# ---- build / solve ------------------------------------------------------------------------
@dataclasses.dataclass
class ExcitationProgram:
    """A built Drake program and what it was built from.

    Attributes:
        prog: the MathematicalProgram (add your own costs/constraints before solving).
        alpha: its decision variables, shape ((2N+1)·n,).
        problem: the :class:`ExcitationProblem`.
        constraints: the :class:`SampledConstraint` objects added (balance, collision, ...).
    """

    prog: object
    alpha: np.ndarray
    problem: ExcitationProblem
    constraints: list[SampledConstraint]
    _evaluators: list = dataclasses.field(default_factory=list)
    _progress: object = None
    _cost: object = None


def build_excitation_program(
    problem: ExcitationProblem,
    constraints: list[SampledConstraint] | None = None,
    *,
    progress: bool | Callable = False,
    smooth_limits: bool = False,
) -> ExcitationProgram:
    """A Drake MathematicalProgram for the excitation problem.

    Args:
        problem: the cost definition.
        constraints: extra sampled constraints (balance, collision, torque); joint limits
            and (if configured) rest at the ends are always added.
        progress: True to print a progress line every few evaluations, or a callable
            ``f(alpha, value)``.
        smooth_limits: joint limits as 6 smooth-max rows per joint instead of 6K linear
            rows. Each IPOPT iteration is ~10× cheaper, but convergence takes many more
            iterations (measured on G1), so the exact linear rows are the default.

    Returns:
        The :class:`ExcitationProgram`.
    """
    from pydrake.solvers import MathematicalProgram

    prog = MathematicalProgram()
    alpha = prog.NewContinuousVariables(problem.num_variables, "alpha")
    program = ExcitationProgram(prog, alpha, problem, list(constraints or []))
    reporter = _ProgressPrinter(program) if progress is True else progress or None
    program._progress = reporter
    program._cost = _add_cost(prog, alpha, problem, on_evaluate=reporter)[1]
    if smooth_limits:
        add_smooth_joint_limit_constraints(prog, alpha, problem)
    else:
        add_joint_limit_constraints(prog, alpha, problem)
    if problem.config.rest_at_ends:
        add_rest_constraints(prog, alpha, problem)
    for c in program.constraints:
        program._evaluators.append(_add_sampled(prog, alpha, problem, c)[1])
    program._cost.evaluators = program._evaluators
    return program


class _ProgressPrinter:
    """Prints evaluation count, best criterion so far and the worst constraint violation."""

    def __init__(self, program: ExcitationProgram, every: float = 2.0, stream=None):
        self.program = program
        self.every = every
        self.stream = stream or sys.stdout
        self.best = np.inf
        self.count = 0
        self.last_print = -np.inf
        self.start = time.perf_counter()

    def __call__(self, alpha: np.ndarray, value: float) -> None:
        self.count += 1
        now = time.perf_counter()
        violation = joint_limit_violation(self.program.problem, alpha)
        for ev in self.program._evaluators:
            violation = max(violation, ev.last_violation)
        if violation < 1e-6:
            self.best = min(self.best, value)
        if now - self.last_print >= self.every:
            self.last_print = now
            print(
                f"  eval {self.count:5d}  {self.program.problem.config.criterion} {value:12.5g}"
                f"  best feasible {self.best:12.5g}  max violation {violation:9.2e}"
                f"  {now - self.start:6.1f} s",
                file=self.stream,
                flush=True,
            )


def joint_limit_violation(problem: ExcitationProblem, alpha: np.ndarray, basis: FourierBasis | None = None) -> float:
    """Worst violation of the joint limits (Eq. 51) at the given samples, in limit units."""
    basis = basis or problem.constraint_basis
    q, v, vd = basis.evaluate_alpha(np.asarray(alpha, float), problem.n)
    lim = problem.robot.limits
    return float(
        max(
            0.0,
            np.max(lim.q_lower - q),
            np.max(q - lim.q_upper),
            np.max(np.abs(v) - lim.v_max),
            np.max(np.abs(vd) - lim.vd_max),
        )
    )


#: Extra IPOPT options (name → value), e.g. for experiments.
IPOPT_EXTRA_OPTIONS: dict = {}


@dataclasses.dataclass
class ExcitationResult:
    """Outcome of :func:`solve_excitation`.

    Attributes:
        x: optimal alpha, shape ((2N+1)·n,).
        trajectory: the :class:`FourierTrajectory` of x.
        fun: criterion value at x.
        cond: cond(C) at x (C includes C0).
        cond_motion: cond of this motion's own Ŷ_B.
        success: x is a valid trajectory: every constraint holds at 1 kHz. When the solver
            stops early (iteration/time limit) at an infeasible iterate, x is the best
            feasible point it evaluated, if any.
        converged: the solver reported convergence to a local optimum.
        message: solver status, which constraint fails by how much, or the fallback used.
        status: Drake's solution result name.
        nit: solver iterations (IPOPT: from its log; NLopt: None).
        nfev: cost evaluations.
        wall_time: [s].
        margins: {constraint: minimum margin at 1 kHz} (negative = violated), in the
            constraint's units (rad, rad/s, rad/s², m, N·m).
        singular_values: σ of C.
        solver: "ipopt" or "nlopt".
        raw: Drake's MathematicalProgramResult.
    """

    x: np.ndarray
    trajectory: FourierTrajectory
    fun: float
    cond: float
    cond_motion: float
    success: bool
    converged: bool
    message: str
    status: str
    nit: int | None
    nfev: int
    wall_time: float
    margins: dict[str, float]
    singular_values: np.ndarray
    solver: str
    raw: object = None


def check_margins(
    problem: ExcitationProblem, alpha: np.ndarray, constraints: list[SampledConstraint] = (), rate: float = 1000.0
) -> dict[str, float]:
    """Minimum margin of each constraint over one period sampled at ``rate`` [Hz].

    Joint limits are reported per quantity (``position``, ``velocity``, ``acceleration``),
    the worst joint; negative means violated.
    """
    t = np.arange(0.0, problem.period, 1.0 / rate)
    basis = FourierBasis(problem.harmonics, problem.omega, t)
    q, v, vd = basis.evaluate_alpha(np.asarray(alpha, float), problem.n)
    lim = problem.robot.limits
    margins = {
        "position": float(np.min(np.minimum(q - lim.q_lower, lim.q_upper - q))),
        "velocity": float(np.min(lim.v_max - np.abs(v))),
        "acceleration": float(np.min(lim.vd_max - np.abs(vd))),
    }
    for c in constraints:
        margins[c.name] = float(np.min(c.margins(q, v, vd)))
    return margins


def solve_excitation(
    program: ExcitationProgram,
    solver: str | SolverConfig = "ipopt",
    initial_guess: np.ndarray | None = None,
    *,
    check_rate: float = 1000.0,
    tolerance: float = 1e-6,
) -> ExcitationResult:
    """Solves a built excitation program with IPOPT or NLopt.

    Args:
        program: from :func:`build_excitation_program` (possibly with user additions).
        solver: "ipopt", "nlopt", or a :class:`SolverConfig` with options.
        initial_guess: alpha to start from (default: ``problem.initial_guess()``).
        check_rate: rate [Hz] at which the constraints are re-checked after solving.
        tolerance: margin below −tolerance counts as a violation in the re-check.

    Returns:
        An :class:`ExcitationResult`; ``success`` is False if the solver failed or any
        constraint is violated between the samples (``message`` says which and by how much).
    """
    from pydrake.solvers import CommonSolverOption, IpoptSolver, NloptSolver, SolverOptions

    cfg = solver if isinstance(solver, SolverConfig) else SolverConfig(name=solver)
    from pe_drake.config import Config

    validate_config(Config(solver=cfg))
    problem = program.problem
    x0 = problem.initial_guess() if initial_guess is None else np.asarray(initial_guess, float)
    if x0.shape != (problem.num_variables,):
        raise ConfigError(f"initial guess has shape {x0.shape}, expected ({problem.num_variables},)")

    options = SolverOptions()
    log_file = None
    if cfg.name == "ipopt":
        backend = IpoptSolver()
        sid = backend.solver_id()
        options.SetOption(sid, "max_iter", int(cfg.max_iterations))
        options.SetOption(sid, "tol", float(cfg.tolerance))
        options.SetOption(sid, "acceptable_tol", float(cfg.tolerance) * 100)
        options.SetOption(sid, "print_level", 0)
        options.SetOption(sid, "file_print_level", 5)
        options.SetOption(sid, "hessian_approximation", "limited-memory")
        for key, value in IPOPT_EXTRA_OPTIONS.items():
            options.SetOption(sid, key, value)
        if cfg.max_time > 0:
            options.SetOption(sid, "max_wall_time", float(cfg.max_time))
        log_file = Path(tempfile.mkstemp(prefix="pe_drake_ipopt_", suffix=".log")[1])
        options.SetOption(CommonSolverOption.kPrintFileName, str(log_file))
    elif cfg.name == "nlopt":
        backend = NloptSolver()
        sid = backend.solver_id()
        options.SetOption(sid, "algorithm", cfg.algorithm)
        options.SetOption(sid, "max_eval", int(cfg.max_iterations))
        options.SetOption(sid, "xtol_rel", float(cfg.tolerance))
        options.SetOption(sid, "constraint_tol", 1e-6)
        if cfg.max_time > 0:
            options.SetOption(sid, "max_time", float(cfg.max_time))
    else:
        raise ConfigError(f"unknown solver '{cfg.name}'; valid: ipopt, nlopt")
    if not backend.available() or not backend.enabled():
        raise ConfigError(f"solver '{cfg.name}' is not available in this Drake build")

    problem.num_evaluations = 0
    if program._cost is not None:
        program._cost.reset()
    reuse_freed_memory()  # a third of each evaluation went to faulting in fresh pages
    start = time.perf_counter()
    with single_threaded_blas():
        result = backend.Solve(program.prog, x0, options)
        stalled = ""
        if cfg.name == "nlopt" and cfg.algorithm == "LD_SLSQP" and problem.num_evaluations <= 2:
            # NLopt's SLSQP sometimes stops after one evaluation with XTOL_REACHED: its first
            # QP step came back zero (seen at starts with gradients of ~1e6). Not a local
            # optimum: start again from the motion shrunk by 5 % toward its offsets (still
            # feasible: the limits are linear in alpha), then, if that stalls too, with MMA
            # (robust but slow with thousands of rows).
            nq0 = problem.n
            retry = x0.copy()
            retry[:-nq0] *= 0.95
            result = backend.Solve(program.prog, retry, options)
            stalled = "; LD_SLSQP stalled at the start, restarted from the motion shrunk by 5 %"
            if problem.num_evaluations <= 4:
                options.SetOption(sid, "algorithm", "LD_MMA")
                result = backend.Solve(program.prog, x0, options)
                stalled = "; LD_SLSQP stalled twice at the start, solved with LD_MMA"
    wall = time.perf_counter() - start
    x = np.asarray(result.GetSolution(program.alpha), float)
    nit = None
    if log_file is not None:
        text = log_file.read_text(errors="replace") if log_file.exists() else ""
        m = re.search(r"Number of Iterations\.*:\s*(\d+)", text)
        nit = int(m.group(1)) if m else None
        log_file.unlink(missing_ok=True)

    status = result.get_solution_result().name
    solved = result.is_success()
    margins = check_margins(problem, x, program.constraints, rate=check_rate)
    fallback = ""
    if (not solved or min(margins.values()) < -tolerance) and program._cost is not None:
        # Stopped at an infeasible or unconverged iterate: keep the best point seen that
        # holds every constraint at 1 kHz.
        for value, candidate in program._cost.candidates:
            if solved and value >= problem.evaluate(x).value:
                break
            m = check_margins(problem, candidate, program.constraints, rate=check_rate)
            if min(m.values()) >= -tolerance:
                x, margins = candidate, m
                fallback = f"; returned the best feasible point evaluated ({problem.config.criterion} {value:.5g})"
                break
    cost = problem.evaluate(x)
    cond = float(cost.singular_values[0] / cost.singular_values[-1]) if cost.singular_values[-1] > 0 else np.inf
    s_motion = np.linalg.svd(problem.regressor_block(x), compute_uv=False)
    cond_motion = float(s_motion[0] / s_motion[-1]) if s_motion[-1] > 0 else np.inf
    violated = {k: m for k, m in margins.items() if m < -tolerance}
    if violated:
        message = "solution violates between samples: " + ", ".join(
            f"{k} by {-m:.3g}" for k, m in violated.items()
        )
    elif not solved:
        message = f"{cfg.name} did not converge: {status}"
        if cfg.name == "ipopt":
            message += f" ({result.get_solver_details().ConvertStatusToString()})"
        message += fallback
    else:
        message = f"{cfg.name}: {status}"
    message += stalled
    return ExcitationResult(
        x=x,
        trajectory=problem.trajectory(x),
        fun=float(cost.value),
        cond=cond,
        cond_motion=cond_motion,
        success=not violated,
        converged=bool(solved),
        message=message,
        status=status,
        nit=nit,
        nfev=problem.num_evaluations,
        wall_time=wall,
        margins=margins,
        singular_values=cost.singular_values,
        solver=cfg.name,
        raw=result,
    )


def optimize_excitation(
    robot,
    config: ExcitationConfig | None = None,
    solver: str | SolverConfig = "ipopt",
    *,
    C0: np.ndarray | None = None,
    constraints: list[SampledConstraint] | None = None,
    initial_guess: np.ndarray | None = None,
    progress: bool = False,
    raise_on_failure: bool = False,
) -> ExcitationResult:
    """Builds and solves in one call (see :func:`build_excitation_program`).

    Raises:
        NoSolutionFound: with ``raise_on_failure``, when no valid trajectory was found (the
            result is kept in the exception's ``result``).
    """
    problem = ExcitationProblem(robot, config, C0=C0)
    program = build_excitation_program(problem, constraints, progress=progress)
    result = solve_excitation(program, solver, initial_guess)
    if raise_on_failure and not result.success:
        raise NoSolutionFound(result.message, result)
    return result
