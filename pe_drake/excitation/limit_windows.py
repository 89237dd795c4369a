"""Joint limits (Eq. 51) at every instant with few rows: one row per window of the period.

The limits are semi-infinite: q, v and vdot must stay within bounds at every t. The sampled
formulation (:func:`~pe_drake.excitation.limits.add_joint_limit_constraints`) imposes them as
linear rows at hundreds of samples per joint, and IPOPT's cost per iteration grows with the
row count (BUILD_NOTES.md, "What was tried"). Here the period is cut into W windows, and for
joint j, quantity x ∈ {q, v, vdot} and each side, one row bounds the window's maximum:

    g(alpha) = max over t in [t_w, t_w+1] of  s·(x(t) − bound)/scale  ≤  −backoff,

with s = +1 for the upper and −1 for the lower limit. The maximum is found on a grid of
``grid`` points per window and refined by Newton steps on x'(t) = 0 in continuous time
(x is a trigonometric polynomial, so x' and x'' are exact), clamped to the window. By the
envelope theorem ∂g/∂alpha is the Fourier row at the maximizing instant t*: x(t*) is linear in
alpha and x'(t*) = 0 (or t* sits on the window's edge, where it does not move). So the row
is exact at every instant, not only at samples, and smooth while one peak dominates each
window. W defaults to 2N: a window is then half the period of the highest harmonic, so it
rarely holds two competing peaks (two peaks make the row a max of two smooth functions, a
kink IPOPT tolerates but converges more slowly on).

On G1 (N = 10, 14 joints) that is 6·20 = 120 rows per joint instead of 600 sampled rows,
each on the joint's own 2N+1 coefficients. The rows are nonlinear but convex (a maximum of
functions linear in alpha) with modest curvature, unlike the smooth-max aggregate whose
sharp log-sum-exp curvature stalled IPOPT's quasi-Newton steps.

Optionally (``two_sided``) one row per quantity and window bounds max |x(t) − c| by the
half-range around the limits' centre c: half the rows, but its side can switch between
evaluations (a kink where both limits are near), and it ended worse (BUILD_NOTES.md).
"""

from __future__ import annotations

import time

import numpy as np

from pe_drake.exceptions import ConfigError
from pe_drake.excitation.problem import ExcitationProblem, check_variables


def trig_rows(k_omega: np.ndarray, t: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Rows of the ``order``-th time derivative of [sin(kωt)…, cos(kωt)…, 1] at times t.

    Args:
        k_omega: kω for k = 1..N, shape (N,) [rad/s].
        t: times, any shape S [s].
        order: derivative order per time, broadcastable to S (0 = value).

    Returns:
        shape S + (2N+1,); the last column is 1 for order 0 (the offset q0), else 0.
    """
    order = np.broadcast_to(np.asarray(order), t.shape)[..., None]
    # d/dt shifts the phase by a quarter turn: the m-th derivative of sin(kωt) is
    # (kω)^m sin(kωt + mπ/2), and likewise for cos (one sin and one cos per entry).
    phase = t[..., None] * k_omega + order * (0.5 * np.pi)
    power = k_omega**order
    S = np.sin(phase) * power
    C = np.cos(phase) * power
    one = (order == 0).astype(float)
    return np.concatenate([S, C, one], axis=-1)


class CachedRows:
    """Constraint rows g(x) and their Jacobian for Drake, evaluated once per point (IPOPT asks for
    the values and then the Jacobian at the same point), the time spent in ``seconds`` [s];
    a subclass computes them in ``_rows(x, key)`` (``key``: ``x.tobytes()``)."""

    seconds = 0.0
    _key: bytes | None = None
    _value: tuple[np.ndarray, np.ndarray] | None = None

    def values_and_jacobian(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """g (R,) and ∂g/∂x (R, len(x)) at ``x`` (cached on x)."""
        x = np.asarray(x, float)
        key = x.tobytes()
        if key == self._key and self._value is not None:
            return self._value
        start = time.perf_counter()
        self._value = self._rows(x, key)
        self._key = key
        self.seconds += time.perf_counter() - start
        return self._value

    def __call__(self, x):
        # pydrake is imported lazily so that `import pe_drake` stays light.
        from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff

        if x.dtype == object:
            g, J = self.values_and_jacobian(ExtractValue(x).reshape(-1))
            return InitializeAutoDiff(g, J @ ExtractGradient(x)).reshape(-1)
        return self.values_and_jacobian(np.asarray(x, float))[0]


class WindowMaxRows(CachedRows):
    """Drake evaluator of one joint's window rows (see the module docstring).

    Args:
        k_omega: kω, shape (N,).
        order: quantity of each row (0 position, 1 velocity, 2 acceleration), shape (R,).
        sign: +1 (upper limit) or −1 (lower limit) per row, shape (R,).
        scale: normalizing scale per row, shape (R,) [unit of the quantity].
        bound: the limit per row, shape (R,) [unit of the quantity].
        start, stop: each row's window [s], shape (R,).
        grid: search points per window.
        newton_steps: Newton refinements of the maximizing instant.
        center: None for one-sided rows; else each row is two-sided, bounding
            max |x(t) − center| by bound − center (sign must then be +1), shape (R,).

    Attributes:
        seconds: time spent in evaluations so far [s].
    """

    def __init__(
        self, k_omega, order, sign, scale, bound, start, stop, grid: int = 24, newton_steps: int = 3, center=None
    ):
        self.k_omega = np.asarray(k_omega, float)
        self.order = np.asarray(order, int)
        self.gain = np.asarray(sign, float) / np.asarray(scale, float)  # s/scale per row
        self.offset = -self.gain * np.asarray(bound, float)
        # Two-sided rows bound max |x − c| (one row for both limits): the side is picked per
        # evaluation, at the window's largest deviation from the centre c (kept as c/scale).
        self.scaled_center = None if center is None else np.asarray(center, float) * self.gain
        if self.scaled_center is not None and np.any(self.gain <= 0):
            raise ValueError("two-sided window rows take sign +1")
        self.start, self.stop = np.asarray(start, float), np.asarray(stop, float)
        width = self.stop - self.start
        self.spacing = width / (grid - 1)
        # Both edges are on the grid: a window's maximum may sit on its edge.
        self.t_grid = self.start[:, None] + np.arange(grid) * self.spacing[:, None]  # (R, grid)
        self.grid_rows = trig_rows(self.k_omega, self.t_grid, self.order[:, None]) * self.gain[:, None, None]
        self.newton_steps = newton_steps
        self.derivative_power = self.k_omega ** (self.order[:, None] + 1)  # (kω)^(m+1) per row, (R, N)
        self.phase_shift = self.order[:, None] * (0.5 * np.pi)  # d^m/dt^m shifts by mπ/2, (R, 1)

    @property
    def num_rows(self) -> int:
        return len(self.order)

    def maximizers(self, coefficients: np.ndarray) -> np.ndarray:
        """t* of each row: the window's maximizing instant of s·x(t) (of |x(t) − c| for
        two-sided rows), shape (R,) [s]."""
        return self._search(np.asarray(coefficients, float))[0]

    def _search(self, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """t* (R,) and the side s = ±1 of each row (always +1 for one-sided rows)."""
        y = self.grid_rows @ a  # (R, grid)
        rows = np.arange(self.num_rows)
        side = np.ones(self.num_rows)
        if self.scaled_center is not None:
            y = y - self.scaled_center[:, None]
            best = np.argmax(np.abs(y), axis=1)
            side = np.where(y[rows, best] < 0, -1.0, 1.0)
        else:
            best = np.argmax(y, axis=1)
        t = self.t_grid[rows, best]
        lo, hi = np.maximum(t - self.spacing, self.start), np.minimum(t + self.spacing, self.stop)
        N = len(self.k_omega)
        # The row's derivative coefficients, its side's sign folded in (d1 = s·x^(m+1), d2 = s·x^(m+2))
        row_scale = ((self.gain * side)[:, None]) * self.derivative_power  # (R, N)
        a_sin, a_cos = a[:N] * row_scale, a[N : 2 * N] * row_scale
        b_sin, b_cos = a_sin * self.k_omega, a_cos * self.k_omega
        for _ in range(self.newton_steps):
            # x^(m+1) and x^(m+2) at t from one sin and cos of the row's phase (trig_rows)
            phase = t[:, None] * self.k_omega + self.phase_shift
            sin, cos = np.sin(phase), np.cos(phase)
            d1 = (a_sin * cos - a_cos * sin).sum(axis=1)
            d2 = -(b_sin * sin + b_cos * cos).sum(axis=1)
            concave = d2 < 0
            step = np.where(concave, -d1 / np.where(concave, d2, -1.0), 0.0)
            t = np.clip(t + step, lo, hi)
        return t, side

    def _rows(self, a: np.ndarray, key: bytes) -> tuple[np.ndarray, np.ndarray]:
        """g (R,) and ∂g/∂coefficients (R, 2N+1) at the joint's coefficients [a, b, q0]."""
        t, side = self._search(a)
        J = trig_rows(self.k_omega, t, self.order) * (self.gain * side)[:, None]
        g = J @ a + self.offset
        if self.scaled_center is not None:  # s·(x − c)/scale − (bound − c)/scale
            g += (1.0 - side) * self.scaled_center
        return g, J


def default_windows(problem: ExcitationProblem) -> int:
    """2N windows per period: each is half a period of the highest harmonic."""
    return 2 * problem.harmonics


def joint_window_rows(
    problem: ExcitationProblem,
    joint: int,
    windows: int,
    *,
    grid: int = 24,
    backoff: float = 1e-4,
    two_sided: bool = False,
) -> tuple[WindowMaxRows, np.ndarray]:
    """The :class:`WindowMaxRows` of one joint and the indices of its coefficients in alpha.

    ``backoff`` (a fraction of each limit's scale) keeps the rows that far inside the limits,
    so that IPOPT's constraint tolerance never shows as a violation at 1 kHz. With
    ``two_sided``, one row per quantity and window bounds |x − centre of the limits|
    (3·W rows instead of 6·W).
    """
    lim = problem.robot.limits
    n, N = problem.n, problem.harmonics
    scale = np.array([0.5 * (lim.q_upper[joint] - lim.q_lower[joint]), lim.v_max[joint], lim.vd_max[joint]])
    upper = np.array([lim.q_upper[joint], lim.v_max[joint], lim.vd_max[joint]])
    lower = np.array([lim.q_lower[joint], -lim.v_max[joint], -lim.vd_max[joint]])
    sides = np.array([1.0]) if two_sided else np.array([1.0, -1.0])
    order, sign, w = np.meshgrid(np.arange(3), sides, np.arange(windows), indexing="ij")
    order, sign, w = order.ravel(), sign.ravel(), w.ravel()
    bound = np.where(sign > 0, upper[order], lower[order]) - sign * backoff * scale[order]
    center = 0.5 * (upper + lower)[order] if two_sided else None
    width = problem.period / windows
    rows = WindowMaxRows(
        np.arange(1, N + 1) * problem.omega, order, sign, scale[order], bound, w * width, (w + 1) * width, grid,
        center=center,
    )
    idx = np.concatenate([joint * N + np.arange(N), n * N + joint * N + np.arange(N), [2 * n * N + joint]])
    return rows, idx


def add_window_limit_constraints(
    prog,
    alpha,
    problem: ExcitationProblem,
    windows: int | None = None,
    *,
    grid: int = 24,
    backoff: float = 1e-4,
    evaluators: list | None = None,
    two_sided: bool = False,
) -> list:
    """Eq. (51) at every instant: one window-maximum row per joint, quantity, side and window
    (per joint, quantity and window with ``two_sided``).

    Args:
        prog, alpha: the Drake program and its Fourier coefficients.
        problem: the :class:`ExcitationProblem`.
        windows: windows per period W (default 2N, :func:`default_windows`).
        grid: search points per window before the Newton refinement.
        backoff: rows stay this fraction of each limit's scale inside it.
        evaluators: if given, the :class:`WindowMaxRows` of each joint are appended to it
            (Drake's bindings hide the Python object; its ``seconds`` times the callbacks).
        two_sided: one row per quantity and window for both limits (3·W rows per joint
            instead of 6·W). Not the default: on G1 it saved no time with IPOPT's extended
            augmented system and ended 10–20 % higher on three starts (BUILD_NOTES.md).

    Returns:
        The bindings, one per joint (6·W rows, or 3·W two-sided, on that joint's 2N+1
        coefficients).

    Raises:
        ConfigError: windows or grid not a positive integer.
    """
    check_variables(alpha, problem)
    windows = default_windows(problem) if windows is None else windows
    for label, value in (("windows", windows), ("grid", grid)):
        if not isinstance(value, (int, np.integer)) or value < 1:
            raise ConfigError(f"joint-limit {label} must be a positive integer, got {value!r}")
    if grid < 2:
        raise ConfigError(f"joint-limit grid must have at least 2 points (the window's edges), got {grid}")
    bindings = []
    for j, name in enumerate(problem.robot.joint_names):
        rows, idx = joint_window_rows(problem, j, windows, grid=grid, backoff=backoff, two_sided=two_sided)
        R = rows.num_rows
        b = prog.AddConstraint(rows, np.full(R, -np.inf), np.zeros(R), vars=alpha[idx])
        b.evaluator().set_description(f"joint limits {name} ({windows} windows)")
        bindings.append(b)
        if evaluators is not None:
            evaluators.append(rows)
    return bindings
