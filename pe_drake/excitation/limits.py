"""Joint limits (Eq. 51) and rest at the ends as Drake constraints on the Fourier coefficients.

The limits are linear in alpha: :func:`add_joint_limit_constraints` adds them as linear rows on
every ``stride``-th constraint sample, tightened by :func:`intersample_allowance` so that they
hold at every instant. :func:`joint_limit_violation` measures a point against them.
"""

from __future__ import annotations

import numpy as np

from pe_drake.excitation.fourier import FourierTrajectory
from pe_drake.excitation.problem import ExcitationProblem, check_variables, rest_constraint_matrix


def add_joint_limit_constraints(
    prog, alpha, problem: ExcitationProblem, stride: int | None = None, max_conservatism: float = 0.02
) -> list:
    """Eq. (51): q, v, vdot within the robot's limits at the K constraint samples (and between).

    One linear constraint per joint and quantity, on that joint's 2N+1 coefficients, imposed on
    every ``stride``-th sample with the bound tightened by :func:`intersample_allowance`, so the
    limits hold at every instant. The default stride is the largest (≤ 8) whose tightening stays
    within ``max_conservatism`` of each velocity and acceleration limit. Returns the bindings.
    """
    check_variables(alpha, problem)
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


def intersample_allowance(problem: ExcitationProblem, stride: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How far q, v, vdot can overshoot their samples between two samples, each (n,).

    a_max·h²/8, Nω·a_max·h²/8 and (Nω)²·a_max·h²/8 for rows on every ``stride``-th constraint
    sample (spacing h): docs/derivations.md §6.
    """
    h = stride * problem.period / problem.config.constraint_samples
    w_max = problem.harmonics * problem.omega
    base = problem.robot.limits.vd_max * h**2 / 8
    return base, w_max * base, w_max**2 * base


def add_rest_constraints(prog, alpha, problem: ExcitationProblem):
    """Start (and, the series being periodic, end) at rest: v = vdot = 0 at t = 0."""
    check_variables(alpha, problem)
    A, b = rest_constraint_matrix(problem)
    binding = prog.AddLinearEqualityConstraint(A, b, alpha)
    binding.evaluator().set_description("rest at ends")
    return binding


def joint_limit_violation(problem: ExcitationProblem, alpha: np.ndarray) -> float:
    """Worst violation of the joint limits (Eq. 51) at the K constraint samples, in limit units."""
    q, v, vd = problem.constraint_basis.evaluate_alpha(np.asarray(alpha, float), problem.n)
    lim = problem.robot.limits
    worst = (lim.q_lower - q, q - lim.q_upper, np.abs(v) - lim.v_max, np.abs(vd) - lim.vd_max)
    return float(max(0.0, *(np.max(x) for x in worst)))


#: How far (a fraction of each limit's scale: half the position range, v_max, vd_max)
#: :func:`keep_strictly_inside` keeps a path inside its limits in continuous time: more than
#: the rounding of trajectory.csv's 9 significant digits, far less than anything cond notices.
STRICT_BACKOFF = 1e-8
#: Samples per cycle of the highest harmonic at which :func:`path_limit_bounds` samples.
BOUND_SAMPLES_PER_CYCLE = 2048


def path_limit_bounds(trajectory: FourierTrajectory) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(q_max, q_min, |v|_max, |vd|_max), each (n,), bounding a periodic path at every instant.

    Between samples h apart, a smooth periodic x(t) rises above its largest sample by at most
    h²/8·max|x''| (its maximum has x' = 0 and a sample within h/2), and
    max|x''| ≤ Σ_k (kω)^(m+2)·|(a_k, b_k)| for the m-th derivative of Eq. (50).
    """
    N = max(trajectory.highest_harmonic, 1)
    count = BOUND_SAMPLES_PER_CYCLE * N
    h = trajectory.period / count
    n = trajectory.num_joints
    q_hi, q_lo, v_abs, vd_abs = np.full(n, -np.inf), np.full(n, np.inf), np.zeros(n), np.zeros(n)
    chunk = max(1, 2_000_000 // max(trajectory.harmonics, 1))  # bases of chunk × N values at a time
    for start in range(0, count, chunk):  # one period, uniform across the wrap
        q, v, vd = trajectory.evaluate(np.arange(start, min(start + chunk, count)) * h)
        q_hi, q_lo = np.maximum(q_hi, q.max(0)), np.minimum(q_lo, q.min(0))
        v_abs, vd_abs = np.maximum(v_abs, np.abs(v).max(0)), np.maximum(vd_abs, np.abs(vd).max(0))
    k_omega = np.arange(1, trajectory.harmonics + 1) * trajectory.omega
    amplitude = np.hypot(trajectory.a, trajectory.b)  # (n, N)
    slack = [h * h / 8 * (amplitude @ k_omega ** (m + 2)) for m in range(3)]
    return q_hi + slack[0], q_lo - slack[0], v_abs + slack[1], vd_abs + slack[2]


def keep_strictly_inside(
    problem: ExcitationProblem, alpha: np.ndarray, backoff: float = STRICT_BACKOFF
) -> tuple[np.ndarray, float]:
    """alpha with its motion about q0 scaled down, if needed, so that q, v and vd stay
    ``backoff`` inside every joint limit at every instant (:func:`path_limit_bounds`), and the
    factor applied (1.0 when the path already holds, or when q0 itself is not inside).

    The solver's tolerance and the 1 kHz re-check accept a path a hair (≤ 1e-6) outside a
    limit; nothing outside a limit may be written. q, v and vd are linear in the motion about
    q0, so one factor does it.
    """
    alpha = np.asarray(alpha, float)
    n = problem.n
    lim, q0 = problem.robot.limits, alpha[-n:]
    q_hi, q_lo, v_abs, vd_abs = path_limit_bounds(problem.trajectory(alpha))
    half = 0.5 * (lim.q_upper - lim.q_lower)
    top, bottom = lim.q_upper - backoff * half, lim.q_lower + backoff * half
    if np.any(q0 >= top) or np.any(q0 <= bottom):
        return alpha, 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = np.concatenate([
            np.where(q_hi > top, (top - q0) / (q_hi - q0), np.inf),
            np.where(q_lo < bottom, (q0 - bottom) / (q0 - q_lo), np.inf),
            np.where(v_abs > lim.v_max * (1 - backoff), lim.v_max * (1 - backoff) / v_abs, np.inf),
            np.where(vd_abs > lim.vd_max * (1 - backoff), lim.vd_max * (1 - backoff) / vd_abs, np.inf),
        ])
    scale = float(np.min(ratios))
    if not scale < 1.0:
        return alpha, 1.0
    out = alpha * scale
    out[-n:] = q0
    return out, scale
