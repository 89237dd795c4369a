"""Joint limits (Eq. 51) at every instant with few rows: one row per window of the period.

The period is cut into W windows, and for joint j, quantity x ∈ {q, v, vdot} and each side, one
row bounds the window's maximum:

    g(alpha) = max over t in [t_w, t_w+1] of  s·(x(t) − bound)/scale  ≤  −backoff,

with s = +1 for the upper and −1 for the lower limit. The maximum is found on a grid of
``grid`` points per window, refined by Newton steps on x'(t) = 0 (exact for a trigonometric
polynomial) clamped to the window; by the envelope theorem ∂g/∂alpha is the Fourier row at the
maximizing instant t*. So the row is exact at every instant, convex, and smooth while one peak
dominates each window: with W = 2N windows, half a period of the highest harmonic each, two
competing peaks (a kink) are rare. Far fewer rows than
:func:`~pe_drake.excitation.limits.add_joint_limit_constraints`.
"""

from __future__ import annotations

import numpy as np

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
    the values and then the Jacobian at the same point); a subclass computes them in
    ``_rows(x, key)`` (``key``: ``x.tobytes()``)."""

    _key: bytes | None = None
    _value: tuple[np.ndarray, np.ndarray] | None = None

    def values_and_jacobian(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """g (R,) and ∂g/∂x (R, len(x)) at ``x`` (cached on x)."""
        x = np.asarray(x, float)
        key = x.tobytes()
        if key == self._key and self._value is not None:
            return self._value
        self._value = self._rows(x, key)
        self._key = key
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
    """

    #: Newton refinements of the maximizing instant.
    newton_steps = 3

    def __init__(self, k_omega, order, sign, scale, bound, start, stop, grid: int = 24):
        self.k_omega = np.asarray(k_omega, float)
        self.order = np.asarray(order, int)
        self.gain = np.asarray(sign, float) / np.asarray(scale, float)  # s/scale per row
        self.offset = -self.gain * np.asarray(bound, float)
        self.start, self.stop = np.asarray(start, float), np.asarray(stop, float)
        self.spacing = (self.stop - self.start) / (grid - 1)
        # Both edges are on the grid: a window's maximum may sit on its edge.
        self.t_grid = self.start[:, None] + np.arange(grid) * self.spacing[:, None]  # (R, grid)
        self.grid_rows = trig_rows(self.k_omega, self.t_grid, self.order[:, None]) * self.gain[:, None, None]
        self.derivative_power = self.k_omega ** (self.order[:, None] + 1)  # (kω)^(m+1) per row, (R, N)
        self.phase_shift = self.order[:, None] * (0.5 * np.pi)  # d^m/dt^m shifts by mπ/2, (R, 1)

    @property
    def num_rows(self) -> int:
        return len(self.order)

    def _search(self, a: np.ndarray) -> np.ndarray:
        """t* of each row: the window's maximizing instant of s·x(t), shape (R,) [s]."""
        y = self.grid_rows @ a  # (R, grid)
        t = self.t_grid[np.arange(self.num_rows), np.argmax(y, axis=1)]
        lo, hi = np.maximum(t - self.spacing, self.start), np.minimum(t + self.spacing, self.stop)
        N = len(self.k_omega)
        # The row's derivative coefficients, its sign folded in (d1 = s·x^(m+1), d2 = s·x^(m+2))
        row_scale = self.gain[:, None] * self.derivative_power  # (R, N)
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
        return t

    def _rows(self, a: np.ndarray, key: bytes) -> tuple[np.ndarray, np.ndarray]:
        """g (R,) and ∂g/∂coefficients (R, 2N+1) at the joint's coefficients [a, b, q0]."""
        J = trig_rows(self.k_omega, self._search(a), self.order) * self.gain[:, None]
        return J @ a + self.offset, J


def joint_window_rows(
    problem: ExcitationProblem, joint: int, windows: int, *, grid: int = 24, backoff: float = 1e-4
) -> tuple[WindowMaxRows, np.ndarray]:
    """The :class:`WindowMaxRows` of one joint and the indices of its coefficients in alpha.

    ``backoff`` (a fraction of each limit's scale) keeps the rows that far inside the limits,
    so that IPOPT's constraint tolerance never shows as a violation at 1 kHz.
    """
    lim = problem.robot.limits
    n, N = problem.n, problem.harmonics
    scale = np.array([0.5 * (lim.q_upper[joint] - lim.q_lower[joint]), lim.v_max[joint], lim.vd_max[joint]])
    upper = np.array([lim.q_upper[joint], lim.v_max[joint], lim.vd_max[joint]])
    lower = np.array([lim.q_lower[joint], -lim.v_max[joint], -lim.vd_max[joint]])
    order, sign, w = np.meshgrid(np.arange(3), [1.0, -1.0], np.arange(windows), indexing="ij")
    order, sign, w = order.ravel(), sign.ravel(), w.ravel()
    bound = np.where(sign > 0, upper[order], lower[order]) - sign * backoff * scale[order]
    width = problem.period / windows
    k_omega = np.arange(1, N + 1) * problem.omega
    start, stop = w * width, (w + 1) * width
    rows = WindowMaxRows(k_omega, order, sign, scale[order], bound, start, stop, grid)
    own = joint * N + np.arange(N)
    idx = np.concatenate([own, n * N + own, [2 * n * N + joint]])
    return rows, idx


def add_window_limit_constraints(
    prog, alpha, problem: ExcitationProblem, evaluators: list | None = None
) -> list:
    """Eq. (51) at every instant: one window-maximum row per joint, quantity, side and window
    (2N windows, :func:`joint_window_rows`).

    Args:
        evaluators: if given, the :class:`WindowMaxRows` of each joint are appended to it
            (Drake's bindings hide the Python object).

    Returns:
        The bindings, one per joint (6·2N rows on that joint's 2N+1 coefficients).
    """
    check_variables(alpha, problem)
    windows = 2 * problem.harmonics
    bindings = []
    for j, name in enumerate(problem.robot.joint_names):
        rows, idx = joint_window_rows(problem, j, windows)
        R = rows.num_rows
        b = prog.AddConstraint(rows, np.full(R, -np.inf), np.zeros(R), vars=alpha[idx])
        b.evaluator().set_description(f"joint limits {name} ({windows} windows)")
        bindings.append(b)
        if evaluators is not None:
            evaluators.append(rows)
    return bindings
