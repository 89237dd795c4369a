"""Base inertial parameters, computed numerically (Gautier & Khalil 1990; Eq. 2).

The regressor Y of random states is factored by QR with column pivoting, Y P = Q [R1 R2]: the
first b pivoted columns are independent and Y_dep = Y_ind β with β = R1⁻¹ R2, so
Y φ = Y_B φ_B with Y_B = Y X and φ_B = K φ, K = [I β] Pᵀ.

The rank b is decided twice: |R_ii| ≤ ``rank_tolerance``·|R_00| of the equilibrated columns is
rounding; then, of the sizes s_i = |R_ii|·‖y_i‖ in the rows' units, those below a jump of more
than :data:`RANK_GAP_RATIO` are dropped (BUILD_NOTES.md "Rank from a gap").
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
import scipy.linalg

from pe_drake.multibody.regressor import RegressorModel

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


@dataclasses.dataclass(frozen=True)
class BaseParameters:
    """The base-parameter composition of a robot (b base, p standard parameters)."""

    independent: np.ndarray  # the standard parameters kept as base columns, (b,)
    K: np.ndarray  # φ_B = K φ, (b, p)
    names: tuple[str, ...]  # standard parameter names, length p
    base_names: tuple[str, ...]  # each base parameter as a combination: "Izz.link1 + 0.09 m.link3"
    rank_tolerance: float
    diag_R: np.ndarray  # |R_ii| of the pivoted QR, (p,)
    measurement: str = "joint_torque"  # the rows: "joint_torque" (Eq. 1), "base_wrench" or "both"
    dropped: tuple[str, ...] = ()  # parameters below the rank gap (K maps them by least squares)
    dropped_size: tuple[float, ...] = ()  # their s_i = |R_ii|·‖y_i‖ relative to the largest
    # smallest kept s_i / largest dropped one; with none dropped, the largest neighbour ratio
    rank_gap: float = 1.0
    gap_ratio: float | None = None

    @property
    def rank_note(self) -> str | None:
        """Which directions the rank gap dropped and why, or None when it dropped none."""
        if not self.dropped:
            return None
        sizes = ", ".join(f"{x:.2g}" for x in self.dropped_size)
        return (f"rank from a gap: {len(self.dropped)} direction(s) dropped from the {self.measurement} base "
                f"parameters, carried by {', '.join(self.dropped)} ({sizes} of the largest); the smallest kept "
                f"one is {self.rank_gap:.3g} times larger (gap threshold {self.gap_ratio:g}). Angles rounded in "
                "a URDF (1.5708 for π/2) leave such a gap: an axis tilted by µrad")

    @property
    def count(self) -> int:
        """b, the number of base parameters."""
        return len(self.independent)

    @property
    def X(self) -> np.ndarray:
        """Composition matrix of Eq. (2): Y_B = Y X, shape (p, b)."""
        X = np.zeros((self.K.shape[1], self.count))
        X[self.independent, np.arange(self.count)] = 1.0
        return X

    def reduce(self, Y: np.ndarray) -> np.ndarray:
        """Y_B from Y (any leading shape, last axis p)."""
        return Y[..., self.independent]

    def base_values(self, phi: np.ndarray) -> np.ndarray:
        """φ_B = K φ."""
        return self.K @ phi

    def closest_standard(self, phi_B: np.ndarray, phi0: np.ndarray) -> np.ndarray:
        """The standard parameters closest to ``phi0`` that give ``phi_B``, (10·nb,).

        φ = φ0 + K⁺(φ_B − K φ0): the same torques, not physically consistent in general."""
        phi0 = np.asarray(phi0, float)
        return phi0 + np.linalg.pinv(self.K) @ (np.asarray(phi_B, float) - self.K @ phi0)


#: Two neighbouring sizes s_i = |R_ii|·‖y_i‖ of the sorted base directions further apart than
#: this are a gap (BUILD_NOTES.md "Rank from a gap").
RANK_GAP_RATIO = 1e3

#: Columns smaller than this fraction of the largest are equilibrated to it, not to 1: their
#: pivots come after the real ones.
EQUILIBRATION_FLOOR = 1e-4


def compute_base_parameters(robot: Robot, *, samples: int | None = None, seed: int = 0,
                            rank_tolerance: float = 1e-8,
                            gap_ratio: float | None = RANK_GAP_RATIO,
                            model: RegressorModel | None = None,
                            rows: Callable[..., np.ndarray] | None = None,
                            measurement: str = "joint_torque") -> BaseParameters:
    """Numerical base parameters of ``robot`` from random states within its limits.

    Args:
        samples: number of random states (default: enough for 4× as many rows as params).
        rank_tolerance: |R_ii| ≤ tol·|R_00| (equilibrated columns) counts as zero.
        gap_ratio: the rank gap (module docstring); None keeps every direction above
            ``rank_tolerance``.
        model: an existing :class:`RegressorModel` to reuse.
        rows: the measured rows as a function of (q, v, vdot), shape (T, r, 10·nb); default
            the joint torques, ``model(q, v, vd)``.
        measurement: the name of those rows, kept in the result.
    """
    model = model or RegressorModel(robot)
    p = model.num_params
    samples = samples or max(20, int(np.ceil(4 * p / robot.n)))
    rng = np.random.default_rng(seed)
    lo, hi = robot.limits.q_lower, robot.limits.q_upper
    q = rng.uniform(lo, hi, (samples, robot.n))
    v = rng.uniform(-1, 1, (samples, robot.n)) * np.minimum(robot.limits.v_max, 3.0)
    vd = rng.uniform(-1, 1, (samples, robot.n)) * np.minimum(robot.limits.vd_max, 10.0)
    W = (rows or model)(q, v, vd).reshape(-1, p)
    # Columns that never affect a torque (e.g. the mass of a body whose origin lies on every
    # axis above it) are exactly zero up to rounding: drop them before equilibrating, or the
    # scaling would turn their rounding noise into an "independent" column.
    norms = np.linalg.norm(W, axis=0)
    live = np.flatnonzero(norms > 1e-9 * norms.max())
    # Equilibrate columns so that the pivot order is not driven by units alone; but not the
    # ones that are tiny for this data (an axis tilted by µrad makes a column of 1e-6):
    # scaled up to 1 they would be as strong a pivot as any, and would be chosen first.
    scale = np.maximum(norms[live], EQUILIBRATION_FLOOR * norms.max())
    R, perm_live = pivoted_qr_r(W[:, live] / scale)
    d = np.abs(np.diag(R))
    b = int(np.sum(d > rank_tolerance * d[0]))  # rounding: exact combinations
    size = d[:b] * scale[perm_live[:b]]  # s_i: what pivot i adds, in the rows' own units
    below, rank_gap = _rank_gap(size, gap_ratio)
    keep = np.setdiff1d(np.arange(b), below)
    dropped, by_size = live[perm_live[below]], np.argsort(-size[below])
    order = np.concatenate([perm_live[keep], perm_live[below], perm_live[b:]])
    if len(below) and not np.array_equal(order, perm_live):
        # A dropped pivot came before a kept one: factor again with the kept columns first,
        # so that the dropped ones are expressed by the kept ones (a truncated QR).
        R = np.linalg.qr(W[:, live[order]] / scale[order], mode="r")
    b, perm_live = len(keep), order
    ind, dep = live[perm_live[:b]], live[perm_live[b:]]
    # β from the unscaled columns: Y_dep = Y_ind β (least squares for the dropped ones).
    beta_scaled = scipy.linalg.solve_triangular(R[:b, :b], R[:b, b:])
    beta = beta_scaled * scale[perm_live[b:]][None, :] / scale[perm_live[:b]][:, None]
    beta[np.abs(beta) < 1e-10] = 0.0
    if len(below):  # what moves the rows less than the dropped directions is not resolved either
        beta[np.abs(beta) * norms[ind][:, None] <= size[below].max()] = 0.0
    by_body = np.argsort(ind)  # keep base parameters in body order
    ind, beta = ind[by_body], beta[by_body]
    K = np.zeros((b, p))
    K[np.arange(b), ind] = 1.0
    K[:, dep] = beta
    names = robot.parameter_names
    return BaseParameters(
        ind, K, names, composed_names(K, names), rank_tolerance, d, measurement,
        dropped=tuple(names[i] for i in dropped[by_size]),
        dropped_size=tuple(float(x) for x in size[below][by_size] / size.max()),
        rank_gap=rank_gap, gap_ratio=gap_ratio,
    )


def _rank_gap(size: np.ndarray, gap_ratio: float | None) -> tuple[np.ndarray, float]:
    """Pivots below the largest jump between sorted sizes if it exceeds ``gap_ratio``, and it."""
    order = np.argsort(-size)
    steps = size[order[:-1]] / size[order[1:]]
    if not len(steps):
        return np.zeros(0, dtype=int), 1.0
    k = int(np.argmax(steps))
    if gap_ratio is None or steps[k] <= gap_ratio:
        return np.zeros(0, dtype=int), float(steps[k])
    return np.sort(order[k + 1 :]), float(steps[k])


#: Remaining column norms within this relative distance of the largest count as tied; ties go
#: to the column earliest in the parameter order.
PIVOT_TIE_TOLERANCE = 1e-8


def pivoted_qr_r(A: np.ndarray, tie_tolerance: float = PIVOT_TIE_TOLERANCE) -> tuple[np.ndarray, np.ndarray]:
    """R and the column order of a Householder QR with column pivoting, A[:, perm] = Q R.

    Like LAPACK's geqp3, except that near-ties go to the lowest column index: the equilibrated
    regressor is full of exact ties, and geqp3 breaks them by rounding, so the choice would
    depend on summation order rather than on the robot and the samples.

    Returns:
        (R, perm): R of shape (min(m, n), n), upper triangular in its leading square block;
        perm, the column order.
    """
    A = np.array(A, dtype=float)
    m, n = A.shape
    perm = np.arange(n)
    steps = min(m, n)
    for k in range(steps):
        rest = A[k:, k:]
        norms = np.sqrt(np.einsum("ij,ij->j", rest, rest))
        top = norms.max()
        if top == 0.0:
            break
        j = k + int(np.flatnonzero(norms >= (1.0 - tie_tolerance) * top)[0])
        if j != k:
            A[:, [k, j]] = A[:, [j, k]]
            perm[[k, j]] = perm[[j, k]]
        x = A[k:, k]
        alpha = -np.copysign(np.linalg.norm(x), x[0])
        v = x.copy()
        v[0] -= alpha
        vv = v @ v
        if vv > 0.0:
            A[k:, k:] -= np.outer(v, (2.0 / vv) * (v @ A[k:, k:]))
        A[k + 1 :, k] = 0.0
        A[k, k] = alpha
    return np.triu(A[:steps]), perm


def composed_names(K: np.ndarray, names: tuple[str, ...]) -> tuple[str, ...]:
    """Each base parameter as the combination it is, coefficients to 4 digits (±1 as a sign)."""
    out = []
    for row in K:
        text = ""
        for k in np.flatnonzero(row):
            shown = f"{row[k]:+.4g}"
            sign, magnitude = shown[0], shown[1:]
            term = names[k] if magnitude == "1" else f"{magnitude} {names[k]}"
            text += (("-" if sign == "-" else "") + term) if not text else f" {sign} {term}"
        out.append(text)
    return tuple(out)
