"""The excitation problem: the cost of Eq. (41) over the Fourier coefficients and its gradient.

:class:`ExcitationProblem` holds what the cost is built from (robot, Fourier bases at the T
cost and K constraint samples, base parameters, prior data C0) and evaluates the criterion of C
with its analytic gradient (Eq. 49; docs/derivations.md).
"""

from __future__ import annotations

import copy
import math
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.config import Config, ExcitationConfig, validate_config
from pe_drake.exceptions import ConfigError, InfeasibleError
from pe_drake.excitation.criteria import CriterionValue, evaluate_criterion
from pe_drake.excitation.drive_block import excitation_drive_block
from pe_drake.excitation.fourier import FourierBasis, FourierTrajectory, sample_times
from pe_drake.multibody.base_parameters import BaseParameters
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.sensors import SensorRows, measurement_base_parameters, measurement_type

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


class ExcitationProblem:
    """The excitation cost of Eq. (41) for a robot, with its analytic gradient (Eq. 49).

    Args:
        C0: prior data, the stacked rows of C of earlier motions (base regressor, then the
            drive columns), shape (m1, columns).
        base: base parameters to use (computed if not given).

    Attributes:
        num_variables: (2N+1)·n.
        drive: the drive terms' columns of C (``excitation.drive_terms``), none by default.
        columns: columns of C: the base parameters, then the drive terms.
        cost_basis / constraint_basis: Fourier bases at the T cost / K constraint samples.
    """

    def __init__(
        self,
        robot: Robot,
        config: ExcitationConfig | None = None,
        *,
        C0: np.ndarray | None = None,
        base: BaseParameters | None = None,
        model: RegressorModel | None = None,
    ):
        self.robot = robot
        self.config = config or ExcitationConfig()
        validate_config(Config(excitation=self.config))
        self.model = model or RegressorModel(robot)
        # The rows of C: joint torques (Eq. 1), the ground wrench, or both.
        self.rows = SensorRows(self.model, measurement_type(self.config, joint_names=robot.joint_names))
        self.base = base or measurement_base_parameters(robot, self.config.measurement, self.model, rows=self.rows)
        if self.base.measurement != self.config.measurement:
            raise ConfigError(
                f"the base parameters given are those of the {self.base.measurement} rows, the problem's "
                f"measurement is {self.config.measurement}: pass base=ExcitationProblem(robot, config).base "
                "(also to a WorkerPool)"
            )
        self.n = robot.n
        self.drive = excitation_drive_block(robot, self.config.drive_terms, self.base, self.rows, self.model)
        self.columns = self.base.count + self.drive.count
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
        self.C0 = _checked_prior(C0, self.columns)
        self._cache_key: bytes | None = None
        self._cache: CriterionValue | None = None
        self.num_evaluations = 0

    def with_prior(self, C0: np.ndarray | None) -> ExcitationProblem:
        """This problem with other prior data C0 (Eq. 41), sharing everything else (ConfigError:
        C0 without one column per base parameter and drive term)."""
        other = copy.copy(self)
        other.C0 = _checked_prior(C0, self.columns)
        other.clear_cache()
        other.num_evaluations = 0
        return other

    def clear_cache(self) -> None:
        """Forgets the cached evaluation, so the next :meth:`evaluate` computes from scratch."""
        self._cache_key, self._cache = None, None

    def trajectory(self, alpha: np.ndarray) -> FourierTrajectory:
        return FourierTrajectory.from_alpha(alpha, self.n, self.harmonics, self.omega)

    def regressor_block(self, alpha: np.ndarray) -> np.ndarray:
        """Ŷ_B of one motion at the T cost samples (Eq. 3), then the drive columns, shape
        (T·r, columns) (r rows per sample)."""
        q, v, vd = self.cost_basis.evaluate_alpha(np.asarray(alpha, float), self.n)
        return self.rows_at(q, v, vd)

    def rows_at(self, q: np.ndarray, v: np.ndarray, vd: np.ndarray) -> np.ndarray:
        """The rows of C at the samples (q, v, v̇), each (S, n): shape (S·r, columns)."""
        return self._with_drive(self.base.reduce(self.rows(q, v, vd)), v, vd)

    def _with_drive(self, Y_B: np.ndarray, v: np.ndarray, vd: np.ndarray) -> np.ndarray:
        """The reduced rows Y_B (S, r, b) with the drive columns appended, as (S·r, columns)."""
        if self.drive.count:
            Y_B = np.concatenate([Y_B, self.drive.columns(v, vd)], axis=2)
        return Y_B.reshape(-1, self.columns)

    def stacked(self, alpha: np.ndarray) -> np.ndarray:
        """C = [C0; Ŷ_B] (Eq. 41)."""
        block = self.regressor_block(alpha)
        return block if self.C0 is None else np.vstack([self.C0, block])

    def value(self, alpha: np.ndarray) -> float:
        """The criterion at alpha (no gradient)."""
        return evaluate_criterion(self.stacked(alpha), self.config.criterion, gradient=False).value

    def evaluate(self, alpha: np.ndarray) -> CriterionValue:
        """Criterion and its analytic gradient with respect to alpha (``grad``, the shape of alpha).

        dc/dC (Eqs. 16–17) → Z^(t) (Eq. 46) → dc/d(q, v, vdot) by the regressor's adjoint
        (Eq. 47) → alpha (Eq. 49). Cached on alpha: Drake's solvers ask for a point repeatedly.
        """
        alpha = np.asarray(alpha, float)
        key = alpha.tobytes()
        if key == self._cache_key and self._cache is not None:
            return self._cache
        self.num_evaluations += 1
        q, v, vd = self.cost_basis.evaluate_alpha(alpha, self.n)
        kin = self.model.kinematics(q, v, vd)
        independent = self.base.independent
        Y_B = self.rows.rows(kin, columns=independent)  # Y_B only: the other columns never enter C
        T, r, b = Y_B.shape[0], Y_B.shape[1], self.base.count
        block = self._with_drive(Y_B, v, vd)
        C = block if self.C0 is None else np.vstack([self.C0, block])
        crit = evaluate_criterion(C, self.config.criterion)  # Eq. (17) for cond, (16) for soft_cond
        if not np.isfinite(crit.value):
            out = CriterionValue(np.inf, np.zeros_like(alpha), crit.singular_values)
        else:
            G = crit.grad[C.shape[0] - T * r :].reshape(T, r, self.columns)
            # Eq. (46): Z = X C(C) S^T, zero outside the independent columns: passed as those.
            q_bar, v_bar, vd_bar = self.rows.pullback(kin, G[..., :b], independent)  # Eq. (47); docs/derivations.md §4a
            if self.drive.count:  # the drive columns depend on v and v̇ only (drive_block.py)
                v_drive, vd_drive = self.drive.pullback(v, vd, G[..., b:])
                v_bar, vd_bar = v_bar + v_drive, vd_bar + vd_drive
            grad = self.cost_basis.pullback(q_bar, v_bar, vd_bar)  # Eq. (49)
            out = CriterionValue(crit.value, grad, crit.singular_values)
        self._cache_key, self._cache = key, out
        return out

    def initial_guess(self, seed: int | None = None, amplitude: float | None = None) -> np.ndarray:
        """A random alpha within the joint limits at the constraint samples.

        Coefficients ~ N(0, (amplitude/k)²) around the nominal posture, scaled down as needed
        (q, v, vdot are linear in the coefficients) to use at most 90 % of each limit.
        """
        rng = np.random.default_rng(self.config.seed if seed is None else seed)
        amplitude = self.config.amplitude if amplitude is None else amplitude
        n, N = self.n, self.harmonics
        k = np.arange(1, N + 1)
        a, b = (rng.normal(size=(n, N)) * amplitude / k for _ in range(2))
        alpha = np.concatenate([a.ravel(), b.ravel(), self.robot.nominal_posture()])
        if self.config.rest_at_ends:  # the minimal change with A alpha = 0 (q0 does not enter A)
            A, _ = rest_constraint_matrix(self)
            alpha = alpha - np.linalg.pinv(A) @ (A @ alpha)
        return scale_into_limits(self, alpha, 0.9)


def _check_cost_rows(problem: ExcitationProblem) -> None:
    """C needs at least as many rows as columns, base parameters and drive terms (the wrench
    gives 6 rows per sample)."""
    rows = problem.config.cost_samples * problem.rows.num_rows
    if rows < problem.columns:
        need = math.ceil(problem.columns / problem.rows.num_rows)
        drive = f" and {problem.drive.count} drive terms" if problem.drive.count else ""
        raise ConfigError(
            f"excitation.cost_samples = {problem.config.cost_samples} gives {rows} rows of "
            f"{problem.config.measurement} for {problem.base.count} base parameters{drive}: use at least {need}"
        )


def scale_into_limits(problem: ExcitationProblem, alpha: np.ndarray, fraction: float) -> np.ndarray:
    """Shrinks the motion of alpha to use at most ``fraction`` (in (0, 1]) of each joint limit.

    Checked at the K constraint samples. q, v and vdot are linear in the sine/cosine
    coefficients, so one common factor (never above 1) keeps the motion's shape; the offsets q0
    are kept. alpha has shape ((2N+1)·n,).

    Raises:
        InfeasibleError: an offset q0 is not strictly inside its joint's position limits.
    """
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


def check_variables(alpha, problem: ExcitationProblem) -> None:
    """Refuses decision variables that are not the problem's (2N+1)·n coefficients (ConfigError)."""
    if len(alpha) != problem.num_variables:
        raise ConfigError(
            f"alpha has {len(alpha)} variables; the problem needs {problem.num_variables} "
            f"((2N+1)·n = (2·{problem.harmonics}+1)·{problem.n})"
        )


def _checked_prior(C0: np.ndarray | None, columns: int) -> np.ndarray | None:
    """Prior data C0 (Eq. 41) as floats, refused without one column per column of C (base
    parameters, then drive terms)."""
    if C0 is None:
        return None
    C0 = np.asarray(C0, float)
    if C0.ndim != 2 or C0.shape[1] != columns:
        raise ConfigError(f"prior data C0 has shape {C0.shape}; it needs {columns} columns (the robot's base "
                          "parameters and the excitation's drive terms)")
    return C0
