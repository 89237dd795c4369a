"""The solver's coordinates: each harmonic's coefficients sized by what the limits allow it.

Harmonic k's coefficient moves the velocity k times and the acceleration k² times as much as the
first's, a spread of curvature IPOPT's limited-memory Hessian spends iterations learning. In
beta = alpha / d, a_jk and b_jk are in units of the largest amplitude joint j's limits allow
harmonic k alone, A_jk = min(half the position range, v_max/(kω), vdot_max/(kω)²), relative to
the first harmonic's (d_jk = A_jk / A_j1; d = 1 for q0).

pydrake 1.51.1's IpoptSolver ignores ``MathematicalProgram.SetVariableScaling``, so
:func:`scaled_copy` rebinds every cost and constraint of the program, pe_drake's own and a user's,
to beta by the chain rule alpha = d·beta. The program itself is unchanged, and
:class:`ScaledResult` answers ``GetSolution(program.alpha)`` in alpha.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pe_drake.excitation.limit_windows import CachedRows


def harmonic_scale(harmonics: int, omega: float, limits) -> np.ndarray:
    """d of alpha = d·beta (module docstring), shape ((2N+1)·n,), for N = ``harmonics``, ω
    [rad/s] and the robot's joint ``limits``."""
    w = np.arange(1, harmonics + 1) * omega  # kω, (N,)
    half_range = 0.5 * (np.asarray(limits.q_upper, float) - np.asarray(limits.q_lower, float))
    amplitude = np.minimum.reduce([
        np.broadcast_to(half_range[:, None], (len(half_range), harmonics)),
        np.asarray(limits.v_max, float)[:, None] / w,
        np.asarray(limits.vd_max, float)[:, None] / w**2,
    ])  # (n, N)
    with np.errstate(invalid="ignore"):
        relative = amplitude / amplitude[:, :1]
    relative = np.where(np.isfinite(relative) & (relative > 0), relative, 1.0)  # unbounded joints: 1
    dk = relative.ravel()
    return np.concatenate([dk, dk, np.ones(len(half_range))])


class _ScaledCost:
    """Anything with ``value_and_gradient(alpha)`` (the ExcitationCost) over beta."""

    def __init__(self, inner, d: np.ndarray):
        self.inner, self.d = inner, d

    def __call__(self, x):
        # pydrake is imported lazily so that `import pe_drake` stays light.
        from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, ExtractValue

        if x.dtype == object:
            value, grad = self.inner.value_and_gradient(ExtractValue(x).reshape(-1) * self.d)
            return AutoDiffXd(value, (grad * self.d) @ ExtractGradient(x))
        return self.inner.value_and_gradient(np.asarray(x, float) * self.d)[0]


class _ScaledRows(CachedRows):
    """A constraint evaluator with ``values_and_jacobian(alpha)`` over beta: its rows at d·beta,
    their Jacobian times d."""

    def __init__(self, inner, d: np.ndarray):
        self.inner, self.d = inner, d

    def _rows(self, x: np.ndarray, key: bytes) -> tuple[np.ndarray, np.ndarray]:
        g, J = self.inner.values_and_jacobian(x * self.d)
        return g, J * self.d


class _ScaledAny:
    """Any other Drake evaluator over beta: its Eval at d·x (AutoDiff carries the chain rule)."""

    def __init__(self, evaluator, d: np.ndarray, scalar: bool):
        self.evaluator, self.d, self.scalar = evaluator, d, scalar

    def __call__(self, x):
        y = self.evaluator.Eval(x * self.d)
        return y[0] if self.scalar else y


class ScaledProgram(NamedTuple):
    """A program over beta (:func:`scaled_copy`)."""

    prog: object  # MathematicalProgram over beta
    beta: np.ndarray  # its variables, one per variable of the original program, in its order
    scale: np.ndarray  # d: original variable = d · beta, shape (num_vars,)
    original: np.ndarray  # the original program's variables, in the same order
    # per binding, costs first: "own" (double path), "linear" (A·d) or "eval" (Eval at d·beta)
    rebound: tuple[str, ...]


def _rebind(target, binding, ours: dict, beta, d, cost: bool) -> str:
    """Adds ``binding`` (of the original program) to ``target`` over the variables ``beta``,
    whose scales are ``d``; returns how (:attr:`ScaledProgram.rebound`)."""
    ev = binding.evaluator()
    kind = type(ev).__name__
    own = ours.get(id(ev))
    if cost:
        if kind == "LinearCost":
            target.AddLinearCost(ev.a() * d, ev.b(), beta)
            return "linear"
        if own is not None:
            target.AddCost(_ScaledCost(own, d), vars=beta, description=ev.get_description())
            return "own"
        target.AddCost(_ScaledAny(ev, d, True), vars=beta, description=ev.get_description())
        return "eval"
    lower, upper = ev.lower_bound(), ev.upper_bound()
    if kind == "BoundingBoxConstraint":
        new = target.AddBoundingBoxConstraint(lower / d, upper / d, beta)
    elif kind == "LinearEqualityConstraint":
        new = target.AddLinearEqualityConstraint(ev.GetDenseA() * d, lower, beta)
    elif kind == "LinearConstraint":
        new = target.AddLinearConstraint(ev.GetDenseA() * d, lower, upper, beta)
    else:
        wrapper = _ScaledRows(own, d) if own is not None else _ScaledAny(ev, d, False)
        new = target.AddConstraint(wrapper, lower, upper, vars=beta)
    new.evaluator().set_description(ev.get_description())
    linear = kind in ("BoundingBoxConstraint", "LinearEqualityConstraint", "LinearConstraint")
    return "linear" if linear else "own" if own is not None else "eval"


def scaled_copy(prog, alpha: np.ndarray, d: np.ndarray, ours: list[tuple[object, object]] = ()) -> ScaledProgram:
    """``prog`` over beta = alpha / d (module docstring); other variables keep scale 1.

    Args:
        alpha: its Fourier coefficients, shape ((2N+1)·n,).
        d: their scales (:func:`harmonic_scale`), shape ((2N+1)·n,).
        ours: (binding, evaluator object) of pe_drake's own Python evaluators: their
            values and Jacobians are taken in double and scaled (no AutoDiff on the hot
            path); every other evaluator is evaluated at d·beta through Drake.
    """
    from pydrake.solvers import MathematicalProgram  # lazily, as above

    original = prog.decision_variables()
    index = {v.get_id(): i for i, v in enumerate(original)}
    scale = np.ones(len(original))
    for v, s in zip(alpha, d):
        scale[index[v.get_id()]] = s
    target = MathematicalProgram()
    beta = target.NewContinuousVariables(len(original), "beta")
    # Keep the evaluators' Python wrappers alive: pybind11 then hands back the same object
    # for the same C++ evaluator, so identity finds our own.
    alive = [b.evaluator() for b, _ in ours]
    own = {id(ev): obj for ev, (_, obj) in zip(alive, ours)}
    rebound = []
    for bindings, cost in ((prog.GetAllCosts(), True), (prog.GetAllConstraints(), False)):
        for b in bindings:
            idx = [index[v.get_id()] for v in b.variables()]
            rebound.append(_rebind(target, b, own, beta[idx], scale[idx], cost))
    return ScaledProgram(target, beta, scale, original, tuple(rebound))


class ScaledResult:
    """Drake's result of a :class:`ScaledProgram`'s solve, ``GetSolution`` in the original
    variables (d·beta); everything else is Drake's (``raw``)."""

    def __init__(self, raw, scaled: ScaledProgram):
        self.raw, self.scaled = raw, scaled
        self._index = {v.get_id(): i for i, v in enumerate(scaled.original)}

    def GetSolution(self, variables=None):  # noqa: N802 (Drake's name)
        x = self.scaled.scale * np.asarray(self.raw.GetSolution(self.scaled.beta), float)
        if variables is None:
            return x
        if isinstance(variables, np.ndarray):
            return np.array([x[self._index[v.get_id()]] for v in variables.ravel()]).reshape(variables.shape)
        return float(x[self._index[variables.get_id()]])

    def __getattr__(self, name):
        return getattr(self.raw, name)


def solve_scaled(solver, prog, alpha, d, x0: np.ndarray, options, ours=()) -> ScaledResult:
    """Solves ``prog`` from x0 (in the original variables) in the coordinates beta = x / d."""
    scaled = scaled_copy(prog, alpha, d, ours)
    raw = solver.Solve(scaled.prog, np.asarray(x0, float) / scaled.scale, options)
    return ScaledResult(raw, scaled)
