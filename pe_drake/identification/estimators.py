"""Identification of the inertial parameters from measured joint data.

The measured torques of S samples of n joints (or the ground wrench, or both: the
``measurement`` of :mod:`pe_drake.identification.channels`, issue 14) are stacked into the
linear model of Eq. (4),

    τ = Y_B(q, v, v̇) φ_B + ρ,          W = [Y_B(1); …; Y_B(S)]  (S·n × b),

and solved by one of three estimators:

- ``ols``: ordinary least squares, φ_B = W⁺ τ (Eq. 4);
- ``wls``: weighted least squares with per-joint noise weights (Gautier 1997): the OLS
  residual of joint j gives σ_j² = ‖ρ_j‖² / (S − b/n), rows of joint j are divided by σ_j,
  and the weighted problem is solved again;
- ``physical``: the standard parameters φ (10 per body) with every body's pseudo-inertia
  J(φ_b) ⪰ 0 (Wensing, Kim & Slotine 2017: the body is realizable by a positive mass
  density, which is Drake's physical-validity condition), weighted as WLS and regularized
  toward the a-priori model in the directions the data does not see. Solved as an SDP in
  Drake's MathematicalProgram with Clarabel (SCS when Clarabel is unavailable).

The relative standard deviation of each base parameter, %σ = 100·√(Σ_ii)/|φ_B,i| with
Σ = σ² (WᵀW)⁻¹ (weighted: (WᵀΣ_ρ⁻¹W)⁻¹), tells how well the data determined it.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from pe_drake.exceptions import ConfigError, DataError
from pe_drake.identification.channels import channel_names, measured_rows, measured_values
from pe_drake.identification.gaps import MAX_GAP_S, preprocess_segments
from pe_drake.identification.measurements import (
    Measurement,
    Preprocessing,
    amps_hint,
    check_torque_units,
    read_measurement_csv,
)
from pe_drake.identification.preprocessing import PreprocessOptions
from pe_drake.multibody.base_parameters import BaseParameters, compute_base_parameters
from pe_drake.multibody.inertia import pseudo_inertia_basis
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.sensors import MeasurementType, SensorRows
from pe_drake.multibody.wrench import static_wrench

METHODS = ("ols", "wls", "physical")
#: Weight of the pull toward the a-priori parameters in the physical fit, relative to the
#: smallest non-zero squared singular value of the (weighted) data regressor: small enough
#: not to bias what the data determines, large enough to fix the unobservable directions.
PRIOR_WEIGHT = 1e-6
#: The physical fit keeps J(φ_b) ⪰ PSD_MARGIN · m_b,prior · I so that the result passes
#: Drake's validity test despite the SDP solver's tolerance.
PSD_MARGIN = 1e-7
#: Rows per base parameter needed at least (S·n ≥ MIN_ROWS_PER_PARAMETER · b): fewer leave
#: the noise nothing to average over.
MIN_ROWS_PER_PARAMETER = 10
#: Output rate of the preprocessing [Hz]: the regressor is smooth, 200 Hz is plenty.
DEFAULT_RATE_HZ = 200.0


@dataclasses.dataclass(frozen=True)
class IdentificationResult:
    """An identified model.

    Attributes:
        robot: robot name.
        method: "ols", "wls" or "physical".
        joints: excited joints, in column order.
        base: the base-parameter composition (Eq. 2) the estimate refers to.
        phi_B: identified base parameters, shape (b,).
        sigma_percent: relative standard deviation of each base parameter [%], shape (b,).
        phi: identified standard parameters (10 per body, about each body origin) for
            ``physical``, else None.
        cond: cond(W) of the (unweighted) stacked data regressor.
        residual_rms: per-channel RMS of y − W φ_B on the identification data [N·m, N].
        relative_error: per-channel 100·‖ρ_c‖/‖y_c‖ [%].
        noise_std: per-channel residual standard deviation σ_c (WLS weights).
        samples: S, samples used (after preprocessing).
        preprocessing: what :func:`pe_drake.identification.preprocessing.preprocess` did (or None).
        wall_time: seconds spent in the estimator (regressor included).
        source: the data file.
        measurement: "joint_torque", "base_wrench" or "both": the channels identified from.
        channels: the channel of each entry of residual_rms, relative_error and noise_std:
            joint names (torques), then :data:`~pe_drake.multibody.wrench.WRENCH_COLUMNS`.
    """

    robot: str
    method: str
    joints: tuple[str, ...]
    base: BaseParameters
    phi_B: np.ndarray
    sigma_percent: np.ndarray
    phi: np.ndarray | None
    cond: float
    residual_rms: np.ndarray
    relative_error: np.ndarray
    noise_std: np.ndarray
    samples: int
    preprocessing: Preprocessing | None = None
    wall_time: float = 0.0
    source: str = ""
    measurement: str = "joint_torque"
    channels: tuple[str, ...] = ()


# ---- data ------------------------------------------------------------------------------------


def read_robot_measurement(robot, path: str | Path) -> Measurement:
    """Reads a measurement CSV for ``robot``'s excited joints (see measurements.py)."""
    return read_measurement_csv(path, robot.joint_names, min_rows=30)


def prepare_measurement(
    robot,
    measurement: Measurement,
    *,
    cutoff_hz: float | None = None,
    fundamental_hz: float | None = None,
    harmonics: int | None = None,
    rate_hz: float | None = DEFAULT_RATE_HZ,
    filtering: bool = True,
    check_units: bool = True,
    max_gap_s: float = MAX_GAP_S,
) -> Measurement:
    """Checks the joints and torque units and preprocesses for identification.

    Args:
        robot: the robot the data belongs to.
        measurement: raw data.
        cutoff_hz, fundamental_hz, harmonics, rate_hz: see
            :func:`pe_drake.identification.preprocessing.preprocess` (``rate_hz`` = ``decimate_to_hz``).
        filtering: False uses the data as it is; it must then hold v and vdot (exact,
            noise-free data, e.g. from :func:`pe_drake.identification.synthetic.model_measurement`).
        check_units: compare the torques with the a-priori model (refuses N·mm or kN·m; a
            note when they look like motor currents).
        max_gap_s: longest hole in the time column interpolated [s]; longer ones split the
            run into segments filtered on their own and stacked
            (:func:`~pe_drake.identification.gaps.preprocess_segments`).

    Raises:
        DataError: other joints than the robot's, missing v/vdot without filtering, torques
            off by orders of magnitude.
    """
    if tuple(measurement.joints) != tuple(robot.joint_names):
        raise DataError(
            f"the data has joints {', '.join(measurement.joints)}; robot '{robot.name}' excites "
            f"{', '.join(robot.joint_names)}",
            file=measurement.source,
        )
    if filtering:
        options = PreprocessOptions(cutoff_hz=cutoff_hz, fundamental_hz=fundamental_hz, harmonics=harmonics,
                                    decimate_to_hz=rate_hz)
        data = preprocess_segments(measurement, options, max_gap_s)
    else:
        if measurement.v is None or measurement.vd is None:
            raise DataError(
                "without filtering the data must hold v.<joint> and vdot.<joint> columns",
                file=measurement.source,
            )
        data = measurement
    if check_units and data.tau is not None:
        ratios = check_torque_units(data, robot_torques(robot, data, robot.phi_model))
        hint = amps_hint(data, ratios)
        if hint:
            data = data.replace(notes=data.notes + (hint,))
    return data


def robot_torques(
    robot, data: Measurement, phi: np.ndarray, model: RegressorModel | None = None
) -> np.ndarray:
    """Rigid-body torques Y(q, v, v̇) φ at the samples of ``data``, shape (S, n)."""
    model = model or RegressorModel(robot)
    out = np.empty_like(data.q)
    for rows in _chunks(data.num_samples):
        out[rows] = model(data.q[rows], data.v[rows], data.vd[rows]) @ phi
    return out


def _chunks(count: int, size: int = 2000) -> list[slice]:
    return [slice(s, min(s + size, count)) for s in range(0, count, size)]


class RegressorMatrices(NamedTuple):
    """The regressors of a data set (:func:`regressor_matrices`).

    Attributes:
        YB: base regressor Y_B, shape (S, n, b).
        tau: measured torques τ, shape (S, n) [N·m].
        base: the base composition (Eq. 2).
        Y: standard regressor Y, shape (S, n, 10·nb).
    """

    YB: np.ndarray
    tau: np.ndarray
    base: BaseParameters
    Y: np.ndarray


def regressor_matrices(
    robot, data: Measurement, base: BaseParameters | None = None, model: RegressorModel | None = None
) -> RegressorMatrices:
    """The data's regressors (:class:`RegressorMatrices`; unpacks as (Y_B, τ, base, Y))."""
    model = model or RegressorModel(robot)
    base = base or compute_base_parameters(robot, model=model)
    Y = np.concatenate([model(data.q[r], data.v[r], data.vd[r]) for r in _chunks(data.num_samples)])
    return RegressorMatrices(base.reduce(Y), np.asarray(data.tau, float), base, Y)


# ---- estimators ------------------------------------------------------------------------------


def _check_rows(data: Measurement, base: BaseParameters, channels: int) -> None:
    rows = data.num_samples * channels
    need = MIN_ROWS_PER_PARAMETER * base.count
    if rows < need:
        raise DataError(
            f"{data.num_samples} samples × {channels} channels = {rows} equations after "
            f"preprocessing; identifying {base.count} base parameters needs at least {need} "
            f"({math.ceil(need / channels)} samples): record a longer run",
            file=data.source,
        )


def measurement_base_parameters(
    robot, measurement: str = "joint_torque", model: RegressorModel | None = None
) -> BaseParameters:
    """The base parameters a measurement identifies (:class:`~pe_drake.multibody.sensors.SensorRows`)."""
    model = model or RegressorModel(robot)
    if measurement == "joint_torque":
        return compute_base_parameters(robot, model=model)
    return SensorRows(model, MeasurementType(measurement)).base_parameters()


def _lstsq(W: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least squares through QR then the SVD of R: (x, (WᵀW)⁻¹, singular values of W)."""
    b = W.shape[1]
    R = np.linalg.qr(np.column_stack([W, y]), mode="r")  # [W y] = Q [[R_W, z], [0, r]]
    U, s, Vt = np.linalg.svd(R[:b, :b])
    y = R[:b, b]
    if s[-1] <= s[0] * 1e-12:
        raise DataError(
            f"the data does not excite every base parameter (cond(W) = {s[0] / max(s[-1], 1e-300):.3g}); "
            "use an exciting trajectory (pe-drake optimize)"
        )
    x = Vt.T @ ((U.T @ y) / s)
    cov = (Vt.T / s**2) @ Vt
    return x, cov, s


def _sigma_percent(x: np.ndarray, cov: np.ndarray) -> np.ndarray:
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(np.abs(x) > 0, 100.0 * sd / np.abs(x), np.inf)


def identify(
    robot,
    data: Measurement,
    method: str = "ols",
    *,
    base: BaseParameters | None = None,
    prior: np.ndarray | None = None,
    model: RegressorModel | None = None,
    measurement: str = "joint_torque",
) -> IdentificationResult:
    """Identifies the base parameters (and, for ``physical``, the standard ones).

    Args:
        robot: the robot.
        data: preprocessed data (:func:`prepare_measurement`), with v and vd.
        method: "ols", "wls" or "physical".
        base: the base composition (default: the measurement's, :func:`measurement_base_parameters`).
        prior: a-priori standard parameters for ``physical`` (default: the robot's model).
        model: a :class:`RegressorModel` to reuse.
        measurement: the channels to fit (:mod:`pe_drake.identification.channels`):
            "joint_torque", "base_wrench" (the ground wrench alone) or "both" (WLS weighs
            every channel by its residual).

    Raises:
        ConfigError: unknown method or measurement.
        DataError: too few samples, a data set that does not excite every base parameter,
            data without the measurement's channels.
    """
    if method not in METHODS:
        raise ConfigError(f"unknown identification method '{method}'; valid: {', '.join(METHODS)}")
    if data.v is None or data.vd is None:
        raise DataError("the data has no velocities/accelerations; preprocess it first", file=data.source)
    start = time.perf_counter()
    model = model or RegressorModel(robot)
    base = base or measurement_base_parameters(robot, measurement, model)
    channels = channel_names(robot, measurement)
    _check_rows(data, base, len(channels))
    tau = measured_values(robot, data, measurement)  # (S, r): torques and/or wrench, per channel
    Y = measured_rows(robot, data, measurement, model)
    YB = base.reduce(Y)
    ols = _ordinary_fit(YB, tau)
    phi_B, cov, phi = ols.phi_B, ols.cov, None
    if method in ("wls", "physical"):
        # Gautier: rows of channel j weighted by 1/σ_j.
        noise_std = ols.noise_std
        w = 1.0 / np.maximum(noise_std, 1e-9 * max(float(noise_std.max()), 1e-12))
        S, n, b = YB.shape
        yw = (tau * w).reshape(S * n)
        phi_B, cov, _ = _lstsq((YB * w[None, :, None]).reshape(S * n, b), yw)
        if method == "physical":
            Yw = (Y * w[None, :, None]).reshape(S * n, -1)
            prior = robot.phi_model if prior is None else np.asarray(prior, float)
            phi = physical_fit(Yw, yw, prior, robot.body_names)
            phi_B = base.base_values(phi)
    residual_rms, relative_error = torque_errors(tau, YB @ phi_B)
    return IdentificationResult(
        robot=robot.name,
        method=method,
        joints=tuple(robot.joint_names),
        base=base,
        phi_B=phi_B,
        sigma_percent=_sigma_percent(phi_B, cov),
        phi=phi,
        cond=ols.cond,
        residual_rms=residual_rms,
        relative_error=relative_error,
        noise_std=ols.noise_std,
        samples=YB.shape[0],
        preprocessing=data.preprocessing,
        wall_time=time.perf_counter() - start,
        source=data.source,
        measurement=measurement,
        channels=channels,
    )


class _OrdinaryFit(NamedTuple):
    phi_B: np.ndarray  # (b,)
    cov: np.ndarray  # σ² (WᵀW)⁻¹, (b, b)
    cond: float  # cond(W)
    noise_std: np.ndarray  # per-joint residual standard deviation σ_j, (n,) [N·m]


def _ordinary_fit(YB: np.ndarray, tau: np.ndarray) -> _OrdinaryFit:
    """Eq. (4): ordinary least squares on Y_B (S, n, b) and τ (S, n), with its statistics."""
    S, n, b = YB.shape
    W = YB.reshape(S * n, b)
    y = tau.reshape(S * n)
    phi_B, cov_unit, s = _lstsq(W, y)
    rho = (y - W @ phi_B).reshape(S, n)
    dof = max(S - b / n, 1.0)
    noise_std = np.sqrt(np.sum(rho**2, axis=0) / dof)
    sigma2 = float(np.sum(rho**2)) / max(S * n - b, 1)
    return _OrdinaryFit(phi_B, sigma2 * cov_unit, float(s[0] / s[-1]), noise_std)


def physical_fit(
    A: np.ndarray,
    y: np.ndarray,
    prior: np.ndarray,
    body_names: Sequence[str],
    *,
    prior_weight: float = PRIOR_WEIGHT,
) -> np.ndarray:
    """min ‖A φ − y‖² + λ‖φ − φ_prior‖²  s.t.  J(φ_b) ⪰ ε m_b,prior 1 for every body.

    Bodies whose a-priori mass is zero (frames without inertia) stay at zero. λ is
    ``prior_weight`` × the smallest non-zero squared singular value of A, so the prior only
    decides the directions the data does not determine.

    Args:
        A: weighted standard-parameter regressor, shape (rows, 10·nb).
        y: weighted torques, shape (rows,).
        prior: a-priori parameters, shape (10·nb,).
        body_names: for error messages.

    Returns:
        φ, shape (10·nb,), physically valid.

    Raises:
        DataError: the solver failed.
    """
    # lazy: pydrake stays out of `import pe_drake`
    from pydrake.solvers import ClarabelSolver, MathematicalProgram, ScsSolver, SolverOptions

    p = A.shape[1]
    # Compress the data term with a QR of [A y]: ‖Aφ − y‖² = ‖R φ − z‖² + const.
    R = np.linalg.qr(np.column_stack([A, y]), mode="r")
    Ra, z = R[:p, :p], R[:p, p]
    s = np.linalg.svd(Ra, compute_uv=False)
    rank_s = s[s > s[0] * 1e-10]
    lam = prior_weight * float(rank_s[-1]) ** 2
    active = [b for b in range(len(body_names)) if prior[10 * b] > 0]
    cols = np.concatenate([np.arange(10 * b, 10 * b + 10) for b in active])
    D = _variable_scale(prior, active)[cols]
    Rs = Ra[:, cols] * D  # φ = D x on the active columns
    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(len(cols), "x")
    x_prior = prior[cols] / D
    Q = 2.0 * (Rs.T @ Rs) + 2.0 * lam * np.diag(D**2)
    c = -2.0 * (Rs.T @ z) - 2.0 * lam * (D**2) * x_prior
    norm = float(np.max(np.abs(np.diag(Q))))
    prog.AddQuadraticCost(Q / norm, c / norm, x, is_convex=True)
    F = pseudo_inertia_basis()
    for k, b in enumerate(active):
        xs = x[10 * k : 10 * k + 10]
        d = D[10 * k : 10 * k + 10]
        F0 = -PSD_MARGIN * prior[10 * b] * np.eye(4)
        prog.AddLinearMatrixInequalityConstraint([F0] + [F[i] * d[i] for i in range(10)], xs)
    solver = ClarabelSolver()
    if not solver.available():  # pragma: no cover - the drake wheel ships Clarabel
        solver = ScsSolver()
    options = SolverOptions()
    if solver.solver_id() == ClarabelSolver.id():
        for key in ("tol_gap_abs", "tol_gap_rel", "tol_feas"):
            options.SetOption(solver.solver_id(), key, 1e-10)
    result = solver.Solve(prog, x_prior, options)
    if not result.is_success():
        raise DataError(
            f"the physically consistent fit failed ({solver.solver_id().name()}: "
            f"{result.get_solution_result().name}); try --method wls"
        )
    phi = np.zeros(p)
    phi[cols] = D * result.GetSolution(x)
    return phi


def _variable_scale(prior: np.ndarray, active: list[int]) -> np.ndarray:
    """Per-variable scale, shape (10·nb,), that makes the prior about 1 in magnitude per body
    block (mass; first moments; inertia): better numerics for the SDP."""
    scale = np.ones(prior.size)
    for b in active:
        m = prior[10 * b]
        scale[10 * b] = m
        scale[10 * b + 1 : 10 * b + 4] = max(np.max(np.abs(prior[10 * b + 1 : 10 * b + 4])), 1e-3 * m)
        scale[10 * b + 4 : 10 * b + 10] = max(np.max(np.abs(prior[10 * b + 4 : 10 * b + 10])), 1e-6 * m)
    return scale


# ---- prediction and validation ----------------------------------------------------------------


def predict(
    robot, result: IdentificationResult, data: Measurement, model: RegressorModel | None = None
) -> np.ndarray:
    """Torques the identified model predicts at the samples of ``data``, shape (S, n)."""
    YB, _, _, _ = regressor_matrices(robot, data, result.base, model)
    return YB @ result.phi_B


def predict_wrench(
    robot, result: IdentificationResult, data: Measurement, model: RegressorModel | None = None
) -> np.ndarray:
    """The ground wrench the identified model predicts at the samples of ``data``, (S, 6)
    [N, N·m] (the a-priori weight of the bodies no excited joint moves included; no offset)."""
    model = model or RegressorModel(robot)
    W = np.concatenate(
        [model.wrench_regressor(model.kinematics(data.q[r], data.v[r], data.vd[r])) for r in _chunks(data.num_samples)]
    )
    return result.base.reduce(W) @ result.phi_B + static_wrench(robot)


class TorqueErrors(NamedTuple):
    """Per-joint torque errors (:func:`torque_errors`).

    Attributes:
        rms: RMS of τ_meas − τ_pred, shape (n,) [N·m].
        relative: 100·‖τ_meas − τ_pred‖/‖τ_meas‖, shape (n,) [%].
    """

    rms: np.ndarray
    relative: np.ndarray


def torque_errors(tau_measured: np.ndarray, tau_predicted: np.ndarray) -> TorqueErrors:
    """Per-joint RMS error [N·m] and relative error 100·‖τ_meas − τ_pred‖/‖τ_meas‖ [%]
    (:class:`TorqueErrors`; unpacks as (rms, relative))."""
    e = np.asarray(tau_measured) - np.asarray(tau_predicted)
    rms = np.sqrt(np.mean(e**2, axis=0))
    rel = 100.0 * np.linalg.norm(e, axis=0) / np.maximum(np.linalg.norm(tau_measured, axis=0), 1e-300)
    return TorqueErrors(rms, rel)
