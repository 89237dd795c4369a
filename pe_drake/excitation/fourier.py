"""Finite Fourier series trajectories, Eq. (50), and their linear maps.

q_j(t) = Σ_k a_jk sin(kωt) + b_jk cos(kωt) + q0_j,  k = 1..N.

The optimization vector is ``alpha = [a.ravel(), b.ravel(), q0]`` with ``a`` and ``b`` of shape
(n, N) (row j: joint j). q, v and vdot are linear in alpha (Eq. 49 needs only these maps).
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class FourierTrajectory:
    """A joint trajectory of Eq. (50).

    Attributes:
        a, b: sine and cosine coefficients, shape (n, N) [rad].
        q0: offsets, shape (n,) [rad].
        omega: base angular frequency [rad/s].
    """

    a: np.ndarray
    b: np.ndarray
    q0: np.ndarray
    omega: float

    @property
    def num_joints(self) -> int:
        return self.a.shape[0]

    @property
    def harmonics(self) -> int:
        return self.a.shape[1]

    @property
    def highest_harmonic(self) -> int:
        """The highest k with a non-zero a_k or b_k on any joint (0 for a constant posture): the
        band the motion really occupies, whatever zero-padding the file carries."""
        used = np.flatnonzero(np.any(self.a != 0, axis=0) | np.any(self.b != 0, axis=0))
        return int(used[-1]) + 1 if used.size else 0

    @property
    def period(self) -> float:
        """Duration of one period, 2π/ω [s]."""
        return 2 * np.pi / self.omega

    @property
    def alpha(self) -> np.ndarray:
        """The optimization vector, shape ((2N+1)·n,)."""
        return np.concatenate([self.a.ravel(), self.b.ravel(), self.q0])

    @staticmethod
    def from_alpha(alpha: np.ndarray, num_joints: int, harmonics: int, omega: float) -> FourierTrajectory:
        n, N = num_joints, harmonics
        alpha = np.asarray(alpha, float)
        if alpha.shape != ((2 * N + 1) * n,):
            raise ValueError(f"alpha has shape {alpha.shape}, expected ({(2 * N + 1) * n},)")
        return FourierTrajectory(
            alpha[: n * N].reshape(n, N).copy(),
            alpha[n * N : 2 * n * N].reshape(n, N).copy(),
            alpha[2 * n * N :].copy(),
            float(omega),
        )

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q, v, vdot at times t, each of shape (T, n)."""
        basis = FourierBasis(self.harmonics, self.omega, t)
        return basis.q(self.a, self.b, self.q0), basis.v(self.a, self.b), basis.vd(self.a, self.b)


class FourierBasis:
    """sin/cos values of Eq. (50) and its derivatives at sample times t (T,) [s], for N =
    ``harmonics`` harmonics of ω [rad/s]."""

    def __init__(self, harmonics: int, omega: float, t: np.ndarray):
        self.harmonics = harmonics
        self.omega = float(omega)
        self.t = np.asarray(t, float).ravel()
        k = np.arange(1, harmonics + 1)
        self.k_omega = k * self.omega  # (N,)
        phase = np.outer(self.t, self.k_omega)  # (T, N)
        self.sin, self.cos = np.sin(phase), np.cos(phase)
        kw, kw2 = self.k_omega, self.k_omega**2
        # Rows are time samples; columns harmonics. q = a·S_q + b·C_q + q0 (per joint).
        self.S_q, self.C_q = self.sin, self.cos
        self.S_v, self.C_v = self.cos * kw, -self.sin * kw
        self.S_vd, self.C_vd = -self.sin * kw2, -self.cos * kw2

    def q(self, a: np.ndarray, b: np.ndarray, q0: np.ndarray) -> np.ndarray:
        return self.S_q @ a.T + self.C_q @ b.T + q0

    def v(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return self.S_v @ a.T + self.C_v @ b.T

    def vd(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return self.S_vd @ a.T + self.C_vd @ b.T

    def evaluate_alpha(self, alpha: np.ndarray, num_joints: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q, v, vdot, each (T, n), from the optimization vector."""
        n, N = num_joints, self.harmonics
        a, b = alpha[: n * N].reshape(n, N), alpha[n * N : 2 * n * N].reshape(n, N)
        return self.q(a, b, alpha[2 * n * N :]), self.v(a, b), self.vd(a, b)

    def pullback(self, q_bar: np.ndarray, v_bar: np.ndarray, vd_bar: np.ndarray) -> np.ndarray:
        """Chain rule of Eq. (49): gradients w.r.t. q, v, vdot (each (T, n)) → w.r.t. alpha."""
        a_bar = q_bar.T @ self.S_q + v_bar.T @ self.S_v + vd_bar.T @ self.S_vd  # (n, N)
        b_bar = q_bar.T @ self.C_q + v_bar.T @ self.C_v + vd_bar.T @ self.C_vd
        return np.concatenate([a_bar.ravel(), b_bar.ravel(), q_bar.sum(axis=0)])

    def matrices(self, num_joints: int, joint: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Linear maps of one joint: (A_q, A_v, A_vd) of shape (T, 2N+1) on that joint's
        coefficients [a_j1..a_jN, b_j1..b_jN, q0_j], and the indices of those in alpha."""
        n, N = num_joints, self.harmonics
        ones, zeros = np.ones((len(self.t), 1)), np.zeros((len(self.t), 1))
        A_q = np.hstack([self.S_q, self.C_q, ones])
        A_v = np.hstack([self.S_v, self.C_v, zeros])
        A_vd = np.hstack([self.S_vd, self.C_vd, zeros])
        own = joint * N + np.arange(N)
        idx = np.concatenate([own, n * N + own, [2 * n * N + joint]])
        return A_q, A_v, A_vd, idx


def sample_times(period: float, count: int) -> np.ndarray:
    """``count`` evenly spaced times over one period, excluding the end (it equals the start)."""
    return np.arange(count) * (period / count)
