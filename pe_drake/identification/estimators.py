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
import json
import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pe_drake.config import MEASUREMENTS
from pe_drake.exceptions import ConfigError, DataError
from pe_drake.identification.channels import channel_names, measured_rows, measured_values
from pe_drake.identification.measurements import Measurement, check_torque_units, preprocess, read_measurement_csv
from pe_drake.multibody.base_parameters import BaseParameters, compute_base_parameters
from pe_drake.multibody.inertia import PARAMETER_NAMES, pseudo_inertia_basis, validity_problems
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
        preprocessing: what :func:`pe_drake.identification.measurements.preprocess` did (or None).
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
    preprocessing: Any = None
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
) -> Measurement:
    """Checks the joints and torque units and preprocesses for identification.

    Args:
        robot: the robot the data belongs to.
        measurement: raw data.
        cutoff_hz, fundamental_hz, harmonics, rate_hz: see
            :func:`pe_drake.identification.measurements.preprocess` (``rate_hz`` = ``decimate_to_hz``).
        filtering: False uses the data as it is; it must then hold v and vdot (exact,
            noise-free data, e.g. from :func:`pe_drake.identification.synthetic.model_measurement`).
        check_units: compare the torques with the a-priori model (refuses N·mm or kN·m).

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
        data = preprocess(
            measurement,
            cutoff_hz=cutoff_hz,
            fundamental_hz=fundamental_hz,
            harmonics=harmonics,
            decimate_to_hz=rate_hz,
        )
    else:
        if measurement.v is None or measurement.vd is None:
            raise DataError(
                "without filtering the data must hold v.<joint> and vdot.<joint> columns",
                file=measurement.source,
            )
        data = measurement
    if check_units and data.tau is not None:
        check_torque_units(data, robot_torques(robot, data, robot.phi_model))
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


def regressor_matrices(
    robot, data: Measurement, base: BaseParameters | None = None, model: RegressorModel | None = None
) -> tuple[np.ndarray, np.ndarray, BaseParameters, np.ndarray]:
    """The data's regressors.

    Returns:
        (Y_B shape (S, n, b), τ shape (S, n), the base composition, Y shape (S, n, p)).
    """
    model = model or RegressorModel(robot)
    base = base or compute_base_parameters(robot, model=model)
    Y = np.concatenate([model(data.q[r], data.v[r], data.vd[r]) for r in _chunks(data.num_samples)])
    return base.reduce(Y), np.asarray(data.tau, float), base, Y


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


def measurement_base_parameters(robot, measurement: str = "joint_torque", model: RegressorModel | None = None):
    """The base parameters a measurement identifies (:mod:`pe_drake.multibody.sensors`)."""
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
        measurement: the channels to fit: "joint_torque" (tau), "base_wrench" (the ground
            wrench alone) or "both" (WLS weighs them by their residuals).

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
    tau = measured_values(robot, data, measurement)  # (S, r): one column per channel
    Y = measured_rows(robot, data, measurement, model)
    YB = base.reduce(Y)
    S, n, b = YB.shape
    W = YB.reshape(S * n, b)
    y = tau.reshape(S * n)
    # Eq. (4): ordinary least squares.
    phi_B, cov_unit, s = _lstsq(W, y)
    cond = float(s[0] / s[-1])
    rho = (y - W @ phi_B).reshape(S, n)
    dof = max(S - b / n, 1.0)
    noise_std = np.sqrt(np.sum(rho**2, axis=0) / dof)
    sigma2 = float(np.sum(rho**2)) / max(S * n - b, 1)
    cov = sigma2 * cov_unit
    phi = None
    if method in ("wls", "physical"):
        # Gautier: rows of joint j weighted by 1/σ_j.
        w = 1.0 / np.maximum(noise_std, 1e-9 * max(float(noise_std.max()), 1e-12))
        Ww = (YB * w[None, :, None]).reshape(S * n, b)
        yw = (tau * w).reshape(S * n)
        phi_B, cov, _ = _lstsq(Ww, yw)
        if method == "physical":
            Yw = (Y * w[None, :, None]).reshape(S * n, -1)
            prior = robot.phi_model if prior is None else np.asarray(prior, float)
            phi = physical_fit(Yw, yw, prior, robot.body_names)
            phi_B = base.base_values(phi)
    rho = tau - (YB @ phi_B)
    residual_rms = np.sqrt(np.mean(rho**2, axis=0))
    tau_norm = np.linalg.norm(tau, axis=0)
    relative_error = 100.0 * np.linalg.norm(rho, axis=0) / np.maximum(tau_norm, 1e-300)
    return IdentificationResult(
        robot=robot.name,
        method=method,
        joints=tuple(robot.joint_names),
        base=base,
        phi_B=phi_B,
        sigma_percent=_sigma_percent(phi_B, cov),
        phi=phi,
        cond=cond,
        residual_rms=residual_rms,
        relative_error=relative_error,
        noise_std=noise_std,
        samples=S,
        preprocessing=data.preprocessing,
        wall_time=time.perf_counter() - start,
        source=data.source,
        measurement=measurement,
        channels=channels,
    )


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
    # Scale the variables so that the prior is 1 in magnitude per body block: better numerics.
    scale = np.ones(p)
    for b in active:
        m = prior[10 * b]
        scale[10 * b] = m
        scale[10 * b + 1 : 10 * b + 4] = max(np.max(np.abs(prior[10 * b + 1 : 10 * b + 4])), 1e-3 * m)
        scale[10 * b + 4 :] = max(np.max(np.abs(prior[10 * b + 4 : 10 * b + 10])), 1e-6 * m)
    D = scale[cols]
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
    """The ground wrench the identified model predicts at the samples of ``data``, (S, 6) [N, N·m]
    (static bodies' weight from the a-priori model included; no sensor offset)."""
    model = model or RegressorModel(robot)
    W = np.concatenate(
        [model.wrench_regressor(model.kinematics(data.q[r], data.v[r], data.vd[r])) for r in _chunks(data.num_samples)]
    )
    return result.base.reduce(W) @ result.phi_B + static_wrench(robot)


def torque_errors(tau_measured: np.ndarray, tau_predicted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint RMS error [N·m] and relative error 100·‖τ_meas − τ_pred‖/‖τ_meas‖ [%]."""
    e = np.asarray(tau_measured) - np.asarray(tau_predicted)
    rms = np.sqrt(np.mean(e**2, axis=0))
    rel = 100.0 * np.linalg.norm(e, axis=0) / np.maximum(np.linalg.norm(tau_measured, axis=0), 1e-300)
    return rms, rel


# ---- files -----------------------------------------------------------------------------------


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def result_to_dict(result: IdentificationResult, robot, model_file: str | None = None) -> dict[str, Any]:
    """The content of identified.json."""
    out: dict[str, Any] = {
        "robot": result.robot,
        "method": result.method,
        "measurement": result.measurement,
        "joints": list(result.joints),
        "data": result.source,
        "samples": result.samples,
        "cond": result.cond,
        "base_parameters": [
            {
                "name": name,
                "value": float(v),
                "sigma_percent": _finite_or_none(float(sp)),
                "column": int(col),
            }
            for name, v, sp, col in zip(
                result.base.base_names, result.phi_B, result.sigma_percent, result.base.independent
            )
        ],
        "residual_rms": dict(zip(result.channels or result.joints, map(float, result.residual_rms))),
        "relative_error": dict(zip(result.channels or result.joints, map(float, result.relative_error))),
        "noise_std": dict(zip(result.channels or result.joints, map(float, result.noise_std))),
        "wall_time": result.wall_time,
    }
    if result.preprocessing is not None:
        out["preprocessing"] = dataclasses.asdict(result.preprocessing)
    if result.phi is not None:
        out["standard_parameters"] = standard_parameters_dict(robot, result.phi)
        out["physically_valid"] = not validity_problems(robot.body_names, result.phi)
    if model_file:
        out["model_file"] = model_file
    return out


def standard_parameters_dict(robot, phi: np.ndarray) -> dict[str, dict[str, float]]:
    """{body: {parameter name: value}} (names of ``pe_drake.multibody.robot.PARAMETER_NAMES``)."""
    return {
        body: dict(zip(PARAMETER_NAMES, map(float, phi[10 * b : 10 * b + 10])))
        for b, body in enumerate(robot.body_names)
    }


def load_identified(path: str | Path, robot) -> IdentificationResult:
    """Reads identified.json and checks it belongs to ``robot``.

    Raises:
        DataError: missing/unreadable file, other robot or joints, base parameters that do
            not match the robot's composition.
    """
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise DataError("identified model file does not exist", file=str(path)) from None
    except (OSError, json.JSONDecodeError) as err:
        raise DataError(f"cannot read the identified model: {err}", file=str(path)) from err
    try:
        joints = tuple(d["joints"])
        entries = d["base_parameters"]
        phi_B = np.array([float(e["value"]) for e in entries])
        columns = np.array([int(e["column"]) for e in entries])
        sigma = np.array(
            [np.inf if e.get("sigma_percent") is None else float(e["sigma_percent"]) for e in entries]
        )
    except (KeyError, TypeError, ValueError) as err:
        raise DataError(
            f"not an identified.json written by pe-drake identify ({err!r} missing or malformed)",
            file=str(path),
        ) from err
    if joints != tuple(robot.joint_names):
        raise DataError(
            f"the model was identified for joints {', '.join(joints)}; robot '{robot.name}' "
            f"excites {', '.join(robot.joint_names)}",
            file=str(path),
        )
    measurement = d.get("measurement", "joint_torque")
    if measurement not in MEASUREMENTS:
        raise DataError(f"measurement '{measurement}' is not one of {', '.join(MEASUREMENTS)}", file=str(path))
    base = measurement_base_parameters(robot, measurement)
    channels = channel_names(robot, measurement)
    if not np.array_equal(columns, base.independent):
        raise DataError(
            f"the base parameters in the file ({len(columns)}) do not match robot '{robot.name}' "
            f"({base.count}); was it identified with another model or config?",
            file=str(path),
        )
    phi = None
    if "standard_parameters" in d:
        try:
            table = d["standard_parameters"]
            phi = np.array([float(table[b][k]) for b in robot.body_names for k in PARAMETER_NAMES])
        except (KeyError, TypeError, ValueError) as err:
            raise DataError(f"standard_parameters: {err!r} missing or malformed", file=str(path)) from err
    return IdentificationResult(
        robot=d.get("robot", robot.name),
        method=d.get("method", "ols"),
        joints=joints,
        base=base,
        phi_B=phi_B,
        sigma_percent=sigma,
        phi=phi,
        cond=float(d.get("cond", float("nan"))),
        residual_rms=np.array([d.get("residual_rms", {}).get(c, np.nan) for c in channels]),
        relative_error=np.array([d.get("relative_error", {}).get(c, np.nan) for c in channels]),
        noise_std=np.array([d.get("noise_std", {}).get(c, np.nan) for c in channels]),
        samples=int(d.get("samples", 0)),
        source=d.get("data", ""),
        measurement=measurement,
        channels=channels,
    )


def standard_from_base(robot, result: IdentificationResult) -> np.ndarray:
    """Standard parameters closest to the a-priori model that reproduce φ_B:
    φ = φ0 + K⁺(φ_B − K φ0). Not necessarily physically valid."""
    K = result.base.K
    phi0 = robot.phi_model
    return phi0 + np.linalg.pinv(K) @ (result.phi_B - K @ phi0)
