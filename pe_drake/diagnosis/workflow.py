"""Diagnosis: where the a-priori model and the measurement disagree, which effect is missing.

``pe-drake diagnose --robot ROBOT --data ident.csv [--validation other.csv] --out DIR``; the
method and its criteria (a)-(d) are described in the README's "Diagnosing a model".
:func:`diagnose` runs the steps in order, one function each: :func:`prepare` (records,
:mod:`pe_drake.diagnosis.record`), 1. :func:`nominal` (the a-priori model plus the model file's
friction against the measured torque; every later fit is of the measured torque minus that
friction), :func:`candidate_library`, 2. :func:`rigid_reidentification`, 3. the selection
(:mod:`pe_drake.diagnosis.selection`, :mod:`pe_drake.diagnosis.regression`), the naming, the
payload step (:mod:`pe_drake.diagnosis.payload`), 4. :func:`augment` (the effects in Drake,
:mod:`pe_drake.diagnosis.augmented_model`) and 5. :func:`unexplained`; each returns a small
frozen dataclass.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from pe_drake.diagnosis.augmented_model import augmented_model
from pe_drake.diagnosis.consistent_cv import ConsistentCrossValidation, consistent_fit
from pe_drake.diagnosis.decisions import decision_list
from pe_drake.diagnosis.effects import (Separability, joint_candidates, prior_parameter_covariance,
                                        separability)
from pe_drake.diagnosis.naming import Naming, name_effects
from pe_drake.diagnosis.options import MAX_COND, DiagnosisConfig
from pe_drake.diagnosis.payload import (BaseChange, PayloadOutcome, not_separable_report,
                                        payload_search, rigid_report)
from pe_drake.diagnosis.holding import holding_note, holding_report, holding_separability, holding_torque
from pe_drake.diagnosis.holding_selection import add_friction_pairs
from pe_drake.diagnosis.presliding import PRESLIDING, PreslidingStep, presliding_effects, presliding_step
from pe_drake.diagnosis.prior import (prior_drive_torque, prior_own_parameters,
                                     prior_parameters, reference_shortfalls)
from pe_drake.diagnosis.record import (Record, Segment, check_fits_in_memory, check_record_signs,
                                      delayed_states, model_file_friction, prepare_record, split_segments)
from pe_drake.diagnosis.regression import (Fit, Library, Regression, Selection, condition_number,
                                           integrated_autocorrelation, regime_analysis, rms,
                                           unexplained_joints)
from pe_drake.diagnosis.selection import (CrossValidation, InternalSplit, internal_split,
                                         say_selection, select, timing_report)
from pe_drake.diagnosis.report import decision_summary
from pe_drake.diagnosis.start import identify_columns, start_shortfalls, starting_fit
from pe_drake.diagnosis.result import DiagnosisResult
from pe_drake.exceptions import DataError, check_joints
from pe_drake.identification.estimators import IdentificationResult
from pe_drake.identification.gaps import longest_segment
from pe_drake.identification.measurements import Measurement, check_torque_units
from pe_drake.multibody.base_parameters import BaseParameters, compute_base_parameters
from pe_drake.multibody.drive_columns import coulomb_column
from pe_drake.multibody.joint_limits import EFFORT_UNITS, effort_label
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.robot import Robot
from pe_drake.multibody.robot_model import RobotModel


@dataclasses.dataclass(frozen=True, eq=False)
class Prepared:
    """The filtered records, their two parts and the base regressor on each; ``phi_prior``
    (10·nb,): the a-priori standard parameters (the model file's, or those of the earlier model
    ``prior``, ``diagnose --model``), ``phi_B_prior`` = K φ_prior (b,)."""

    record: Record
    validation: Record | None
    training: Segment
    held: Segment
    model: RegressorModel
    base: BaseParameters
    phi_B_prior: np.ndarray
    internal: InternalSplit
    phi_prior: np.ndarray
    prior: IdentificationResult | RobotModel | None = None


def prepare(robot: Robot, data: Measurement, validation: Measurement | None, config: DiagnosisConfig,
            say: Callable[[str], None], prior: IdentificationResult | RobotModel | None = None) -> Prepared:
    """Records, training and held-out parts, the base regressor on each (data preparation)."""
    record = prepare_record(data, config)
    vrecord = prepare_record(validation, config) if validation is not None else None
    for r in (record, vrecord):  # sign-flipped torque columns, on the record filtered once
        if r is not None:
            check_record_signs(robot, r)
    training, held = split_segments(record, config, vrecord)
    say(f"data: {record.source}: {data.num_samples} samples at {record.rate_hz:.4g} Hz, cut-off "
        f"{record.cutoff_hz:.3g} Hz, fitted at {record.rate_hz / record.step:.4g} Hz; training "
        f"{training.t[0]:.2f}-{training.t[-1]:.2f} s, held-out "
        f"{held.t[0]:.2f}-{held.t[-1]:.2f} s" + (f" of {vrecord.source}" if vrecord else ""))
    model = RegressorModel(robot)
    base = compute_base_parameters(robot, model=model)
    if base.rank_note:
        say(f"note: {base.rank_note}")
    n = robot.n
    if training.num_samples * n < 3 * (base.count + 4 * n):
        raise DataError(
            f"{training.num_samples} training samples × {n} joints are too few for {base.count} base "
            f"parameters and {4 * n} effect candidates; record a longer run", file=record.source)
    phi = prior_parameters(robot, prior)
    return Prepared(record, vrecord, training, held, model, base, base.base_values(phi), internal_split(training),
                    np.asarray(phi, float), prior)


@dataclasses.dataclass(frozen=True, eq=False)
class Nominal:
    """The a-priori model along the held-out motion (step 1): torque, residual (S, n) and RMS
    (n,) [N·m], and the regimes of both parts."""

    tau_held: np.ndarray
    residual_held: np.ndarray
    rms: np.ndarray
    regimes: dict[str, Any]


def nominal(robot: Robot, prep: Prepared, regression: Regression) -> Nominal:
    """Y φ_prior plus the model file's joint friction against the measured torque."""
    training, held, joints = prep.training, prep.held, robot.joint_names
    base = range(prep.base.count)
    tau_nom_tr, tau_nom_ho = (c.product(base, prep.phi_B_prior) + prior_drive_torque(robot, prep.prior, s)
                              for c, s in ((regression.train, training), (regression.held, held)))
    for seg, pred in ((training, tau_nom_tr), (held, tau_nom_ho)):
        check_torque_units(Measurement(seg.t, seg.q, seg.tau, None, None, joints, seg.record.source), pred)
    res_tr, res_ho = training.tau - tau_nom_tr, held.tau - tau_nom_ho
    regimes = regime_analysis(
        np.concatenate([res_tr, res_ho]),
        np.concatenate([training.q, held.q]), np.concatenate([training.v, held.v]),
        np.concatenate([training.vd, held.vd]), np.concatenate([training.t, held.t]), joints)
    return Nominal(tau_nom_ho, res_ho, rms(held.tau - tau_nom_ho), regimes)


@dataclasses.dataclass(frozen=True, eq=False)
class CandidateLibrary:
    """Every candidate's separability test, the library and the regression on both parts."""

    separability: list[Separability]
    library: Library
    regression: Regression


def candidate_library(robot: Robot, prep: Prepared, config: DiagnosisConfig) -> CandidateLibrary:
    """The separable candidates' columns appended to the base regressor."""
    candidates = joint_candidates(robot, config.effects)  # friction as corrections of the model file's
    sep = separability(robot, prep.base, candidates, model=prep.model)
    sep += holding_separability(robot, prep.training)
    library = Library(prep.base.count, tuple(s.candidate for s in sep if s.separable))
    training, held = prep.training, prep.held
    reg = Regression(*(library.segment_columns(prep.model, prep.base.independent, seg, model_file_friction(robot, seg))
                       for seg in (training, held)), library.num_base)
    b = library.num_base
    cond = condition_number(reg.train.gram[:, :b, :b].sum(axis=0))
    if cond > MAX_COND:
        raise DataError(
            f"the training part ({training.duration:.3g} s) does not excite every base parameter: the "
            f"condition number of its regressor is {cond:.3g} (> {MAX_COND:.0e}); record a longer or more "
            "exciting run (pe-drake optimize)", file=prep.record.source)
    return CandidateLibrary(sep, library, reg)


def rigid_reidentification(reg: Regression, training: Segment) -> Fit:
    """WLS of the base parameters alone with Gautier's per-joint weights (step 2); sets the
    regression's weights and autocorrelation inflation, which the later fits keep."""
    ols = reg.fit([])
    spread_tr = np.std(training.tau, axis=0)
    sigma = np.maximum(ols.rms_train, np.maximum(training.record.noise_floor, 1e-6 * spread_tr + 1e-12))
    reg.set_weights(1.0 / sigma)
    reg.inflation = integrated_autocorrelation(reg.residual("training", ols))
    rigid = reg.fit([])
    reg.inflation = integrated_autocorrelation(reg.residual("training", rigid))
    return rigid


@dataclasses.dataclass(frozen=True, eq=False)
class PayloadStep:
    """The base-parameter change of the final fit, the payload search, the rigid-body report
    and the effects that merge with base parameters."""

    change: BaseChange
    outcome: PayloadOutcome
    rigid: dict[str, Any]
    not_separable: list[dict[str, Any]]


def payload_step(robot: Robot, prep: Prepared, lib: CandidateLibrary, sel: Selection, naming: Naming,
                 config: DiagnosisConfig) -> PayloadStep:
    """Payload search and rigid-body report from the final fit's base parameters."""
    base, final = prep.base, sel.final
    b = base.count
    Sigma_phi = prior_parameter_covariance(robot, config.prior_uncertainty)
    change = BaseChange.from_fit(base.K, final.x[:b], prep.phi_B_prior, final.cov[:b, :b], Sigma_phi)
    outcome = (payload_search(robot, base, change, config, naming.last_fit.rms_held) if config.payload
               else PayloadOutcome({"searched": False}, None, None))
    return PayloadStep(change, outcome, rigid_report(base, change),
                       not_separable_report(lib.separability, base, change))


@dataclasses.dataclass(frozen=True, eq=False)
class Augmentation:
    """The augmented Drake model on the held-out data (step 4).

    Attributes:
        tau: its torque along the held-out motion, (S, n) [N·m].
        rms: per-joint held-out RMS of measured minus that torque [N·m].
        drake_check: max |Drake torque - least-squares prediction| per joint [N·m].
    """

    model: RobotModel
    tau: np.ndarray
    rms: np.ndarray
    drake_check: np.ndarray


def augment(robot: Robot, prep: Prepared, lib: CandidateLibrary, pre: PreslidingStep, naming: Naming, pay: PayloadStep,
            config: DiagnosisConfig) -> Augmentation:
    """The named effects added to the model in Drake, its held-out torque and the gap."""
    held, library = prep.held, lib.library
    # the model is the consistent fit of the selected columns (the one the selection's last pass
    # scored), not a projection of the least-squares base parameters (diagnosis/consistent_cv.py)
    fit = consistent_fit(pre.regression, pre.final.columns, library, prep.base.K, prep.phi_prior, robot.body_names,
                         delivered=True)
    final = pre.final if fit is None else dataclasses.replace(pre.final, x=fit[0])
    dahl = {f.column: f for f in pre.fits}  # Coulomb slots holding pre-sliding friction
    # a starting-fit term the later columns pushed below its bound is held there (diagnosis/start.py)
    values = {col: max(final.value(col), c.lower) if c.nonnegative else final.value(col) for col in naming.effect_cols
              if col != library.timing_col and col not in dahl and col not in pre.dropped and (c := library.cand_of[col])}
    presliding = {f.joint: (final.value(c), final.value(c) / f.displacement) for c, f in dahl.items()}
    delay = final.value(library.timing_col) if library.timing_col in naming.effect_cols else 0.0
    effect = pay.outcome.effect
    augmented = augmented_model(robot, prep.base, final.x[: prep.base.count], pay.change.Sigma_phi,
                                pay.outcome.delta_phi,
                                {library.cand_of[c].label: (library.cand_of[c], v) for c, v in values.items()},
                                config.coulomb_velocity_scale,
                                effect.link if effect is not None else None,
                                cov_B=pay.change.cov_B, time_delay=delay, presliding=presliding,
                                phi_prior=prior_own_parameters(robot, prep.prior),
                                phi_consistent=fit[1] if fit is not None else None)
    # Drake's torque at the held-out samples (along the motion `delay` earlier), its Coulomb term
    # filtered like the measured torque (the rest of the torque is smooth within the pass band)
    q, v, vd, coulomb = (delayed_states(held, delay, config.coulomb_velocity_scale) if delay
                         else (held.q, held.v, held.vd, held.coulomb))
    tau_after = augmented.plant(robot).inverse_dynamics(q, v, vd, include_damping=True) + augmented.offset
    tau_after += augmented.coulomb * (coulomb - coulomb_column(v, config.coulomb_velocity_scale)) + pre.held_torque
    tau_after += holding_torque(pre.regression.held, final, library)  # friction held at rest
    # the linear model's prediction with the final values (a delay by its linearization -d·dτ/dt)
    ls_pred = pre.regression.held.product(final.columns, final.x) + model_file_friction(robot, held)
    return Augmentation(augmented, tau_after, rms(held.tau - tau_after),
                        np.max(np.abs(tau_after - ls_pred), axis=0))


@dataclasses.dataclass(frozen=True, eq=False)
class Unexplained:
    """What the augmented model leaves (step 5): the timing report, {joint: details}."""

    timing: dict[str, Any]
    joints: dict[str, dict[str, Any]]


def unexplained(robot: Robot, prep: Prepared, lib: CandidateLibrary, sel: Selection, nom: Nominal, aug: Augmentation,
                config: DiagnosisConfig) -> Unexplained:
    """Joints whose held-out residual stays above their threshold, with their signature."""
    timing = timing_report(lib.regression, lib.library, sel, config)
    held = prep.held
    found = unexplained_joints(held.tau - aug.tau, held, sel.thresholds.unexplained, held.record.noise_floor,
                               nom.rms, robot.joint_names, timing)
    return Unexplained(timing, found)


def diagnose(robot: Robot, data: Measurement, validation: Measurement | None = None,
             options: DiagnosisConfig | None = None, *, prior: IdentificationResult | RobotModel | None = None,
             progress: Callable[[str], None] | None = None) -> DiagnosisResult:
    """Runs the five steps of the module docstring.

    Args:
        data: the measured run, raw (:func:`~pe_drake.identification.intake.read_measurements`):
            a run paused for longer than ``options.max_gap_s`` is diagnosed on its longest segment.
        validation: another run to hold out; None: the last ``holdout_fraction`` of ``data``.
        prior: an earlier model to start from instead of the model file's parameters
            (:func:`~pe_drake.identification.identified_file.load_identified`: identified.json
            or augmented_model.json): its parameters and drive terms are the a-priori model.
        progress: called with one line per step (e.g. ``print``).

    Raises:
        DataError: joints that differ from the robot's, a run too short, torques in the
            wrong units or sign-flipped (naming the file and column).
    """
    config = options or DiagnosisConfig()
    say = progress or (lambda _msg: None)
    lap = _Laps()
    joints = robot.joint_names
    unit = effort_label(j.kind for j in robot.joints)  # N·m, or N on a prismatic joint
    for m in filter(None, (data, validation)):
        check_joints(robot, m.joints, file=m.source)
    data, validation = (longest_segment(m, config.max_gap_s) if m is not None else None for m in (data, validation))
    check_fits_in_memory(data, validation)
    for note in (*data.notes, *(validation.notes if validation is not None else ())):
        say(f"note: {note}")
    if isinstance(prior, RobotModel) and prior.presliding is not None and np.any(prior.presliding):
        say("note: the earlier model's pre-sliding (Dahl) friction is not part of the a-priori model")
    prep = prepare(robot, data, validation, config, say, prior)
    lap("prepare")
    lib = candidate_library(robot, prep, config)
    nom = nominal(robot, prep, lib.regression)
    say(f"1. a-priori model, held-out RMS [{unit}]: " + _fmt_joints(joints, nom.rms))
    lap("nominal")
    start = starting_fit(lib.regression, identify_columns(robot, prep.base, prep.model, lib.library))
    say(f"2. starting fit (identify's: WLS with drive terms), held-out RMS [{unit}]: " + _fmt_joints(joints, start.fit.rms_held))
    rigid = rigid_reidentification(lib.regression, prep.training)
    say(f"2. for comparison, rigid-body parameters alone, held-out RMS [{unit}]: " + _fmt_joints(joints, rigid.rms_held))
    lap("rigid")
    lib.regression.set_weights(start.weights)  # identify's weights (the fixed point) for the effects
    split = CrossValidation.of(lib.regression, prep.internal)
    consistent = ConsistentCrossValidation(split.folds, lib.library, prep.base.K, prep.phi_prior, robot.body_names)
    sel = select(lib.regression, split, lib.library, rigid, prep.training, prep.held, config, start, consistent)
    sel = add_friction_pairs(lib.regression, split, lib.library, sel, config.max_effects)  # sliding + at rest
    say_selection(say, sel, lib.library, joints, _fmt_joints, unit)
    lap("effects")
    naming = name_effects(robot, lib.regression, lib.library, sel, rigid, nom.rms, config)
    pre = presliding_step(prep, lib, sel, config, split, consistent)
    naming = dataclasses.replace(naming, effects=presliding_effects(naming.effects, pre, lib.library, joints),
                                 series=pre.series(naming.series, joints), rejected=naming.rejected + pre.not_named(),
                                 cumulative=naming.cumulative + [(f"+ {PRESLIDING}", pre.final.rms_held)] * bool(pre.fits))
    for f in pre.fits:
        say(f"3. {PRESLIDING}[{joints[f.joint]}] (x_p {1e3 * f.displacement:.3g} mrad) in its Coulomb slot")
    holding = holding_report(prep.training, prep.held, lib.library, pre, naming.effects, joints)
    if note := holding_note(holding):
        say(note)
    lap("presliding")
    pay = payload_step(robot, prep, lib, sel, naming, config)
    if pay.outcome.effect is not None:
        say(f"3. payload on {pay.outcome.effect.link}: {pay.outcome.effect.value:+.3g} kg "
            f"(χ² {pay.outcome.report['chi2_before']:.3g} → {pay.outcome.report['chi2_after']:.3g})")
    decisions = decision_list(lib.library, lib.separability, sel, pre, pay.outcome.report, config.timing_check)
    say("3. decisions: " + decision_summary(decisions))
    lap("payload")
    aug = augment(robot, prep, lib, pre, naming, pay, config)
    say(f"4. augmented Drake model, held-out RMS [{unit}]: " + _fmt_joints(joints, aug.rms))
    worse = reference_shortfalls(robot, prep.base, lib.regression.held, prep.held, aug.tau) + start_shortfalls(
        joints, lib.regression.held.y, start, lib.regression.held.product(start.fit.columns, start.fit.x),
        pre.regression.held.product(pre.final.columns, pre.final.x), aug.tau - model_file_friction(robot, prep.held),
        pre.final.columns, lib.library)
    for shortfall in worse:
        say(shortfall.line())
    lap("augmented")
    left = unexplained(robot, prep, lib, sel, nom, aug, config)
    say(_unexplained_line(robot, left.joints))
    lap("unexplained")
    held, residual_rigid = prep.held, lib.regression.residual("held-out", rigid)
    return DiagnosisResult(
        robot=robot, joints=joints, config=config, training=prep.training, held_out=held,
        effects=naming.effects + ([pay.outcome.effect] if pay.outcome.effect is not None else []),
        rms_nominal=nom.rms, rms_rigid=rigid.rms_held, rms_after=aug.rms, cumulative=naming.cumulative,
        unexplained=left.joints, not_separable=pay.not_separable, rejected=naming.rejected, regimes=nom.regimes,
        rigid=pay.rigid, payload_test=pay.outcome.report, timing=left.timing,
        predictions={"t": held.t, "measured": held.tau, "nominal": nom.tau_held, "rigid": held.tau - residual_rigid,
                     "after": aug.tau},
        residual_series={"effects": naming.series, "nominal": nom.residual_held, "rigid": residual_rigid,
                         "after": held.tau - aug.tau},
        augmented=aug.model, drake_check=aug.drake_check, timings=lap.timings, noise_floor=held.record.noise_floor,
        thresholds=sel.thresholds.unexplained, decisions=decisions, holding_test=holding, worse=tuple(worse),
        selection={**prep.internal.describe(), "held_out": "used only for the figures reported"},
        start=start.as_dict(lib.library, joints))


class _Laps:
    """Wall time of each step [s], rounded to the millisecond."""

    def __init__(self) -> None:
        self.timings: dict[str, float] = {}
        self.clock = time.perf_counter()

    def __call__(self, name: str) -> None:
        now = time.perf_counter()
        self.timings[name] = round(now - self.clock, 3)
        self.clock = now


def _unexplained_line(robot: Robot, left: dict[str, dict[str, Any]]) -> str:
    """Step 5's line: each joint's unexplained held-out RMS in its effort unit."""
    kinds = {info.name: info.kind for info in robot.joints}
    if not left:
        return "5. nothing left unexplained above the thresholds"
    return "5. unexplained: " + ", ".join(f"{j} {u['rms']:.3g} {EFFORT_UNITS[kinds[j]]}" for j, u in left.items())


def _fmt_joints(joints: Sequence[str], x) -> str:
    return ", ".join(f"{j} {v:.3g}" for j, v in zip(joints, x))
