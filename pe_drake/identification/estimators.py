"""Identification of the inertial parameters from measured joint data.

The measured torques of S samples of n joints (or the ground wrench, or both) are stacked into
the linear model of Eq. (4), τ = Y_B(q, v, v̇) φ_B + ρ, W = [Y_B(1); …; Y_B(S)] (S·n × b),
solved by one of three estimators:

- ``ols``: ordinary least squares, φ_B = W⁺ τ (Eq. 4);
- ``wls`` (the default): weighted least squares with per-joint noise weights (Gautier 1997),
  iterated to their fixed point (:mod:`pe_drake.identification.least_squares`);
- ``physical``: the standard parameters φ with every body's pseudo-inertia J(φ_b) ⪰ 0,
  friction and armature ≥ 0 and the user's mass and CoM bounds, weighted as WLS
  (:mod:`pe_drake.identification.physical_fit`).

By default the regressor carries a drive block W = [Y_B | D]
(:mod:`pe_drake.identification.drive_terms`); the ground-wrench rows of D are zero. The
relative standard deviation %σ = 100·√(Σ_ii)/|φ_B,i| of each base parameter uses the sandwich
covariance inflated by each channel's residual autocorrelation time.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from pe_drake.exceptions import ConfigError, DataError
from pe_drake.identification.channels import channel_names, measured_values
from pe_drake.identification.drive_terms import (layout_torque, model_file_terms,
                                                 model_file_terms_lost, separable_on_data,
                                                 unphysical_drive_terms, with_known)
from pe_drake.multibody.drive_columns import (TERMS, DriveLayout, DriveTermOptions, drive_columns,
                                              drive_layout, drive_options, model_tables)
from pe_drake.identification.measurements import Measurement, Preprocessing
from pe_drake.identification.least_squares import ordinary_fit, weighted_fit
from pe_drake.identification.physical_fit import ON_BOUND, PhysicalBounds, physical_fit
from pe_drake.identification.welded import merge_welded
from pe_drake.identification.folded_rows import (BLOCK, FoldedRows, column_map, fold_rows,
                                                 known_columns_removed)
from pe_drake.identification.statistics import integrated_autocorrelation
from pe_drake.multibody.base_parameters import BaseParameters
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.robot_model import RobotModel
from pe_drake.multibody.sensors import MeasurementType, SensorRows, measurement_base_parameters
from pe_drake.threads import single_threaded_blas

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

METHODS = ("ols", "wls", "physical")
#: Rows per base parameter needed at least (S·n ≥ MIN_ROWS_PER_PARAMETER · b): fewer leave
#: the noise nothing to average over.
MIN_ROWS_PER_PARAMETER = 10
#: A rigid-body-only fit warns when friction and offsets would explain more than this fraction
#: of its residual energy (by chance, 3n extra columns explain ~3n/(S·n), < 1 %).
FRICTION_SHARE_WARNING = 0.5
#: The physical fit's pull toward the a-priori model may raise the (correlation-corrected) χ²
#: of the data by at most this over the unconstrained optimum (physical_fit's stage 2).
PHYSICAL_DELTA_CHI2 = 4.0
#: The physical fit's σ_c is at least this fraction of the channel's RMS torque: no torque
#: sensor resolves finer, and the SDP solver cannot resolve a thinner confidence region.
PHYSICAL_MIN_RELATIVE_SIGMA = 1e-6
#: The physical fit names every channel whose residual RMS exceeds the least-squares (WLS) fit's
#: on the same data by more than this [%].
PHYSICAL_WORSE_PERCENT = 5.0


@dataclasses.dataclass(frozen=True)
class IdentificationResult:
    """An identified model.

    Attributes:
        base: the base-parameter composition (Eq. 2) the estimate refers to.
        phi_B: identified base parameters, shape (b,).
        sigma_percent: relative standard deviation of each base parameter [%], shape (b,).
        phi: identified standard parameters (10 per body, about each body origin) for
            ``physical``, else None.
        cond: cond(W) of the (unweighted) stacked data regressor.
        residual_rms: per-channel RMS of y − W φ_B on the identification data [N·m, N].
        relative_error: per-channel 100·‖ρ_c‖/‖y_c‖ [%].
        noise_std: per-channel σ_c: the OLS residual's for ``ols``; for ``wls`` and
            ``physical`` the σ_c of the WLS weights 1/σ_c (``residual_rms`` is the fit's own).
        wall_time: seconds spent in the estimator (regressor included).
        channels: the channel of each entry of residual_rms, relative_error and noise_std:
            joint names (torques), then :data:`~pe_drake.multibody.wrench.WRENCH_COLUMNS`.
        model: the robot as built this fit gives: ``phi``, or for base parameters only the
            standard parameters closest to the a-priori model that give them, and the drive
            terms with their σ.
        drive_layout: the fitted drive columns, or None (a model without them).
        friction_share: for a fit without drive terms, the fraction of the OLS residual's
            energy that Coulomb + viscous friction and offsets would explain (None otherwise).
        cov_B: covariance of ``phi_B``, shape (b, b), or None (an older identified.json).
        coupling: warnings of joints whose residual looks like a coupled drive the model lacks.
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
    model: RobotModel | None = None
    drive_layout: DriveLayout | None = None
    physical_notes: tuple[str, ...] = ()
    friction_share: float | None = None
    weight_iterations: int = 0
    weights_converged: bool = False
    cov_B: np.ndarray | None = None
    coupling: tuple[str, ...] = ()


def _check_rows(data: Measurement, count: int, channels: int) -> None:
    rows = data.num_samples * channels
    need = MIN_ROWS_PER_PARAMETER * count
    if rows < need:
        windowed = any(note.startswith("--window") for note in data.notes)
        raise DataError(
            f"{data.num_samples} samples × {channels} channels = {rows} equations after "
            f"preprocessing; identifying {count} parameters (base parameters and drive terms) needs at least {need} "
            f"({math.ceil(need / channels)} samples): " + ("widen --window or " if windowed else "") + "record a longer run",
            file=data.source,
        )


def _sigma_percent(x: np.ndarray, cov: np.ndarray) -> np.ndarray:
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(np.abs(x) > 0, 100.0 * sd / np.abs(x), np.inf)


def identify(robot: Robot, data: Measurement, method: str = "wls", *,
             measurement: str = "joint_torque", drive_terms: DriveTermOptions | str | None = None,
             bounds: PhysicalBounds | None = None, coulomb: np.ndarray | None = None,
             rest: np.ndarray | None = None) -> IdentificationResult:
    """Identifies the base parameters and the drive terms (and, for ``physical``, the standard
    parameters).

    Args:
        data: preprocessed data (:func:`~pe_drake.identification.intake.prepare_measurement`), with v and vd.
        measurement: the channels to fit: "joint_torque", "base_wrench" (the ground wrench
            alone) or "both".
        drive_terms: friction, offset and armature columns per joint (default "all"; none with
            ``measurement="base_wrench"``).
        coulomb: the Coulomb columns to use, (S, n) (e.g. tanh(v/v_s) filtered like the
            torque); default tanh(v/v_s) of ``data.v``.
        rest: the joint-torque rows kept out of the fit, (S, n) bool (a joint at rest), or None.

    Raises:
        ConfigError: unknown method or measurement, bounds naming unknown links.
        DataError: too few samples, a data set that does not excite every base parameter,
            data without the measurement's channels.
    """
    if method not in METHODS:
        raise ConfigError(f"unknown identification method '{method}'; valid: {', '.join(METHODS)}")
    if data.v is None or data.vd is None:
        raise DataError("the data has no velocities/accelerations; preprocess it first", file=data.source)
    with single_threaded_blas():  # thousands of small QRs: BLAS threads only contend (threads.py)
        return _identify(robot, data, method, measurement, drive_terms, bounds, coulomb, rest)


def _identify(robot: Robot, data: Measurement, method: str, measurement: str, drive_terms,
              bounds: PhysicalBounds | None, coulomb: np.ndarray | None,
              rest: np.ndarray | None) -> IdentificationResult:
    """:func:`identify` after its checks."""
    start = time.perf_counter()
    model = RegressorModel(robot)
    base = measurement_base_parameters(robot, measurement, model)
    channels = channel_names(robot, measurement)
    measured_values(robot, data, measurement)  # refuses data without the channels, naming them
    layouts = _layouts(robot, measurement, drive_options(drive_terms), method, model)
    _check_rows(data, base.count + layouts.drive.count, len(channels))
    known = model_file_terms(robot, layouts.drive) if MeasurementType(measurement).torques else None
    blocks = _row_blocks(robot, data, measurement, model, layouts, coulomb, known, rest)
    folded = fold_rows(blocks)  # the rows never held at once: an hour of data fits (folded_rows)
    cols = _Columns(folded.R.shape[1] - 1, 10 * len(robot.body_names), base, layouts)
    layout, keep = separable_on_data(folded.stacked(cols.base)[0], folded.stacked(cols.drive)[0], layouts.drive)
    if layout.count < layouts.drive.count:  # a column the data cannot separate keeps the model file's value
        known, lost = model_file_terms_lost(robot, layout, layouts.drive, known)
        theta = cols.drive @ lost  # over the folded columns
        folded, blocks = folded.with_known_columns(theta), known_columns_removed(blocks, theta)
    T = np.hstack([cols.base, cols.drive[:, keep]])  # Y_B | drive columns
    ols = fit = ordinary_fit(folded, blocks, T)
    share = _friction_share(folded, cols, layouts, folded.residual_ss(T, ols.x), robot.n)
    if method in ("wls", "physical"):  # rows of channel c divided by σ_c
        # Reweighting to the fixed point takes the residual for noise; a residual that is mostly
        # friction would weight the joints by how little friction they have (least_squares).
        fit = weighted_fit(folded, blocks, T, ols.noise_std,
                           iterate=share is None or share <= FRICTION_SHARE_WARNING)
    x, cov, phi, physical = fit.x, fit.cov, None, None
    if method == "physical":
        # Stage 2 of the fit stays in the 95 % confidence region of this estimate: whitened
        # rows count τ̄ times for correlated samples (statistics.sandwich_from_grams).
        tau_bar = float(np.mean(integrated_autocorrelation(fit.residual)))
        # σ_c ≥ 1e-6 RMS: noise-free data's σ left stage 2's region too thin for the SDP solver
        sigma = np.maximum(fit.noise_std, PHYSICAL_MIN_RELATIVE_SIGMA * np.sqrt(folded.measured_ss() / folded.samples))
        physical = _physical(robot, base, layout, folded, cols, keep, layouts.armature, 1.0 / sigma,
                             robot.phi_model, bounds, tau_bar * PHYSICAL_DELTA_CHI2)
        phi, x = physical.phi, physical.x
    b = base.count
    residual_ss = folded.residual_ss(T, x)
    if physical is not None:
        worse = physical_fit_excess(channels, np.sqrt(residual_ss / folded.samples),
                                         np.sqrt(folded.residual_ss(T, fit.x) / folded.samples))
        physical = physical._replace(notes=(*physical.notes, *worse))
    layout, theta, sigma = with_known(layout, x[b:], np.sqrt(np.maximum(np.diag(cov)[b:], 0.0)), known)
    drive, drive_sigma = model_tables(layout, theta, sigma, physical.merged_armature if physical is not None else {})
    phi_model = phi if phi is not None else base.closest_standard(x[:b], robot.phi_model)
    model = RobotModel(tuple(robot.joint_names), tuple(robot.body_names), phi_model, drive, drive_sigma,
                       layout.velocity_scale, notes=physical.notes if physical is not None else (),
                       transmission=layout.transmission)
    return IdentificationResult(
        robot=robot.name, method=method, joints=tuple(robot.joint_names), base=base, phi_B=x[:b],
        sigma_percent=_sigma_percent(x[:b], cov[:b, :b]), phi=phi, cond=ols.cond,
        residual_rms=np.sqrt(residual_ss / folded.samples),
        relative_error=100.0 * np.sqrt(residual_ss) / np.maximum(np.sqrt(folded.measured_ss()), 1e-300),
        noise_std=fit.noise_std, weight_iterations=fit.iterations, weights_converged=fit.converged,
        samples=folded.samples, preprocessing=data.preprocessing,
        wall_time=time.perf_counter() - start, source=data.source, measurement=measurement,
        channels=channels, model=model, drive_layout=layout,
        physical_notes=physical.notes if physical is not None else (), friction_share=share,
        cov_B=cov[:b, :b])


class _Layouts(NamedTuple):
    drive: DriveLayout  # the drive columns asked for (before the data decides which separate)
    armature: DriveLayout  # physical: the merged armatures, variables of the fit too
    friction: DriveLayout  # a rigid-body-only fit of torques: friction, to say what it leaves


def _layouts(robot: Robot, measurement: str, options: DriveTermOptions, method: str, model: RegressorModel) -> _Layouts:
    none = drive_layout(robot, None, DriveTermOptions("none", options.velocity_scale))
    if measurement == "base_wrench":  # the ground wrench does not see the drives
        return _Layouts(none, none, none)
    # The armature's separability is decided on the rows fitted: with the ground wrench
    # ("both") the base parameters are the wrench-and-torque ones and merge fewer armatures.
    fitted_base = measurement_base_parameters(robot, measurement, model) if "armature" in TERMS[options.terms] else None
    drive = drive_layout(robot, fitted_base, options, model, rows=SensorRows(model, MeasurementType(measurement)))
    armature = none
    if method == "physical" and drive.merged:
        armature = _armature_layout(drive, [robot.joint_names.index(j) for j in drive.merged])
    friction = none
    if not drive.count:  # per joint, as the Coulomb columns of a fit without drive terms are
        friction = dataclasses.replace(drive_layout(robot, None, DriveTermOptions("friction", options.velocity_scale)),
                                       transmission=None)
    return _Layouts(drive, armature, friction)


def _armature_layout(drive: DriveLayout, joints: list[int]) -> DriveLayout:
    """Armature columns of ``joints`` (the merged ones: variables of the physical fit)."""
    return DriveLayout(("armature",) * len(joints), tuple(joints), drive.joint_names,
                       tuple("kg·m²" for _ in joints), drive.velocity_scale, transmission=drive.transmission)


class _Columns:
    """Maps from the folded columns [Y | drive | armature | friction] to the fits' columns."""

    def __init__(self, total: int, standard: int, base: BaseParameters, layouts: _Layouts):
        d, a, f = layouts.drive.count, layouts.armature.count, layouts.friction.count
        self.standard = column_map(total, range(standard))
        self.base = self.standard[:, base.independent]
        self.drive = column_map(total, range(standard, standard + d))
        self.armature = column_map(total, range(standard + d, standard + d + a))
        self.friction = column_map(total, range(standard + d + a, standard + d + a + f))


def _row_blocks(robot: Robot, data: Measurement, measurement: str, model: RegressorModel, layouts: _Layouts,
                coulomb: np.ndarray | None, known: tuple[DriveLayout, np.ndarray] | None = None,
                rest: np.ndarray | None = None):
    """The rows [Y | drive | armature | friction] and y of ``data``, BLOCK samples at a time
    (y without the model file's ``known`` friction; the torque rows ``rest`` zero)."""
    rows = SensorRows(model, MeasurementType(measurement))
    r = len(channel_names(robot, measurement))

    def blocks():
        for s in range(0, data.num_samples, BLOCK):
            k = slice(s, min(s + BLOCK, data.num_samples))
            part = data.take(k)
            sign = None if coulomb is None else coulomb[k]
            F = [rows.rows(model.kinematics(part.q, part.v, part.vd), scaled=False)]
            F += [drive_columns(part.v, part.vd, layout, sign, rows=r) for layout in layouts]
            y = measured_values(robot, part, measurement)
            if known is not None:  # the torque channels come first
                y[:, : robot.n] -= layout_torque(*known, part.v, part.vd, sign)
            F = np.concatenate(F, axis=2)
            if rest is not None and MeasurementType(measurement).torques:  # the torque channels come first
                at_rest = np.zeros(y.shape, bool)
                at_rest[:, : robot.n] = rest[k]
                F[at_rest], y[at_rest] = 0.0, 0.0
            yield k, F, y

    return blocks


def _friction_share(folded: FoldedRows, cols: _Columns, layouts: _Layouts, residual_ss: np.ndarray,
                    torques: int) -> float | None:
    """For a rigid-body-only fit: the fraction of the residual energy of its ``torques`` joint
    torque channels that friction and offsets would explain (else None)."""
    if not layouts.friction.count:
        return None
    _, keep = separable_on_data(folded.stacked(cols.base)[0], folded.stacked(cols.friction)[0], layouts.friction)
    T = np.hstack([cols.base, cols.friction[:, keep]])
    x = np.linalg.lstsq(*folded.stacked(T), rcond=None)[0]
    before = float(np.sum(residual_ss[:torques]))
    after = float(np.sum(folded.residual_ss(T, x)[:torques]))
    return 1.0 - after / before if before > 0 else 0.0


class _Physical(NamedTuple):
    phi: np.ndarray  # standard parameters (10·nb,)
    x: np.ndarray  # base parameters (merged armatures included), then drive terms
    notes: tuple[str, ...]
    merged_armature: dict[str, float]  # {joint: value} of the merged armatures


def _physical(robot: Robot, base: BaseParameters, layout: DriveLayout, folded: FoldedRows, cols: _Columns, keep: list[int],
              armature: DriveLayout, w: np.ndarray, prior: np.ndarray, bounds: PhysicalBounds | None,
              chi2_tolerance: float) -> _Physical:
    """The physical fit with the drive terms; the merged armatures are variables ≥ 0 too, so
    what a merged base parameter holds beyond physical links goes to the rotor."""
    merged = [robot.joint_names.index(j) for j in layout.merged]
    extra = _armature_layout(layout, merged)
    A, yw = folded.stacked(cols.standard, w)
    T_E = np.hstack([cols.drive[:, keep], cols.armature[:, [armature.joints.index(j) for j in merged]]])
    E, _ = folded.stacked(T_E, w)
    # one body per rigid group (welded.py): only a group's sum is identifiable
    groups = merge_welded(robot, prior, [*bounds.mass_bounds, *bounds.boxes] if bounds is not None else ())
    c = groups.cols()
    fit = physical_fit(A[:, c], yw, groups.prior(prior), groups.names(robot.body_names), extra=E,
                       extra_lower=np.r_[layout.lower_bounds(), np.zeros(len(merged))],
                       extra_names=layout.labels + extra.labels, bounds=bounds, base_K=base.K[:, c],
                       chi2_tolerance=chi2_tolerance, rows=folded.samples * folded.channels,
                       extra_in_base={layout.count + i: _in_base(base, layout.merged[robot.joint_names[j]])
                                      for i, j in enumerate(merged)})
    phi, group_notes = groups.split(fit.phi, prior, robot.body_names)
    fit = fit._replace(phi=phi, notes=(*group_notes, *fit.notes))
    phi_B = base.base_values(fit.phi)
    notes = list(fit.notes)
    on_bound = ON_BOUND * max(float(np.max(np.abs(fit.theta))) if len(fit.theta) else 1.0, 1e-9)  # physical_fit's test
    for j, a in zip(merged, fit.theta[layout.count :]):
        name = robot.joint_names[j]
        for base_name, coef in layout.merged[name].items():  # v̇_j = Σ coef_k · (column k of Y_B)
            phi_B[base.base_names.index(base_name)] += a * coef
        if a > on_bound:  # one on its bound 0 (solver round-off, 1e-11) is noted as such, not as holding a part
            notes.append(f"armature[{name}] {a:.4g} kg·m² (not separately identifiable) holds the part of "
                         f"{', '.join(layout.merged[name])} above what links near the a-priori model hold")
    values = {robot.joint_names[j]: float(a) for j, a in zip(merged, fit.theta[layout.count :])}
    return _Physical(fit.phi, np.concatenate([phi_B, fit.theta[: layout.count]]), tuple(notes), values)


def physical_fit_excess(channels, rms: np.ndarray, rms_ls: np.ndarray) -> list[str]:
    """Notes on the channels where the physical fit's residual RMS ``rms`` (r,) is above the
    least-squares fit's ``rms_ls`` on the same rows by more than :data:`PHYSICAL_WORSE_PERCENT`."""
    percent = 100.0 * (np.asarray(rms) / np.maximum(rms_ls, 1e-300) - 1.0)
    return [f"{name}: residual RMS {a:.4g}, {p:.0f} % above the least-squares (WLS) fit's {a_ls:.4g} on the same "
            "data (what the physical constraints and bounds cost, or the solver); compare --method wls"
            for name, p, a, a_ls in zip(channels, percent, rms, rms_ls) if p > PHYSICAL_WORSE_PERCENT]


def _in_base(base: BaseParameters, coef: dict[str, float]) -> np.ndarray:
    """{base parameter name: coefficient} as a vector over the base parameters, shape (b,)."""
    out = np.zeros(base.count)
    for name, c in coef.items():
        out[base.base_names.index(name)] = c
    return out


def fit_warnings(result: IdentificationResult) -> list[str]:
    """What a reader of the fit must know: the physical fit's notes, negative drive terms, and
    a rigid-body-only fit whose residual is mostly friction."""
    out = [f"physical fit: {note}" for note in result.physical_notes]
    if result.method != "physical" and result.drive_layout is not None:
        out += unphysical_drive_terms(result.model, result.drive_layout)
    share = result.friction_share
    if share is not None and share > FRICTION_SHARE_WARNING:
        out.append(
            f"warning: the OLS residual of this rigid-body-only fit is {100 * share:.0f} % joint friction "
            "and offsets: the link parameters absorb what they can of it and the model is not finished; "
            "identify with --drive-terms friction or all"
            + ("; the WLS weights are those of the OLS residual (one step), not iterated to their fixed point, "
               "which takes the residual for noise" if result.method != "ols" else ""))
    return out + list(result.coupling)
