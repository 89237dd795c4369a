"""Pre-sliding friction in the diagnosis: a search over the pre-sliding displacement.

The Dahl model (:mod:`pe_drake.multibody.dahl`) gives the friction torque F_c·z(q; x_p), linear
in F_c, nonlinear in x_p = F_c/σ0: each joint's Coulomb column is replaced by the
parallel-filtered Dahl column for every x_p of :data:`DISPLACEMENT_GRID`, the whole model is
refitted, and the x_p with the lowest weighted training residual wins. In sliding the Coulomb
model is the x_p → 0 limit (at rest the Dahl state keeps ±1: on a joint with a named holding
torque the Dahl column is zero at rest). The method is in the README's "Diagnosing a model".
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from pe_drake.diagnosis.holding import HOLDING, record_rest_mask
from pe_drake.diagnosis.result import NamedEffect, per_joint
from pe_drake.diagnosis.selection import split_with_column
from pe_drake.multibody.dahl import dahl_state

PRESLIDING = "presliding_friction"
#: Pre-sliding displacements x_p = F_c/σ0 tried [rad]: 0.05 to 160 mrad, log-spaced (ratio
#: 1.25). At the low end the Dahl column is the Coulomb column tanh(v/v_s) (v_s = 0.01 rad/s
#: reached at 1 rad/s² after 0.05 mrad), so "the smallest fits best" means Coulomb.
DISPLACEMENT_GRID = 0.00005 * 1.25 ** np.arange(37)


@dataclasses.dataclass(frozen=True, eq=False)
class PreslidingFit:
    """The best pre-sliding model of one joint.

    Attributes:
        column: the library column (the joint's Coulomb column) it replaces.
        displacement: x_p [rad] of the best fit; ``coulomb``: F_c [N·m] there.
        stiffness: σ0 = F_c / x_p [N·m/rad].
        rss: training residual sum of squares of the joint over the grid, shape (G,).
        rss_coulomb: the same with the Coulomb column.
        rss_best: the same at ``displacement`` (refined between grid points).
        held_values: the Dahl column at ``displacement`` on the held-out samples, (S,).
        regression: the regression holding the Dahl column in place of the Coulomb one.
    """

    joint: int
    column: int
    displacement: float
    coulomb: float
    stiffness: float
    rss: np.ndarray
    rss_coulomb: float
    fit: object
    regression: object
    rss_best: float = np.inf
    held_values: np.ndarray | None = None


def dahl_columns(record, joint: int, grid: np.ndarray = DISPLACEMENT_GRID, moving: np.ndarray | None = None) -> np.ndarray:
    """The normalized Dahl state of one joint for every x_p of ``grid``, integrated and filtered
    like the torque at the record's full rate, at every ``record.step``-th sample, shape
    (⌈T/step⌉, G); zero outside ``moving`` (a full-rate mask, (T,)) when given.

    The state follows the record's filtered q (a noisy q would reverse at every sample).
    """
    z = dahl_state(record.q[:, joint], np.asarray(grid, float))  # (T, G)
    if moving is not None:
        z *= moving[:, None]
    out = np.empty((len(range(0, z.shape[0], record.step)), z.shape[1]))
    for g in range(z.shape[1]):  # filtered a grid value at a time: no second (T, G) array
        out[:, g] = record.filtered(z[:, g])[:: record.step]
    return out


def replace_column(columns, index: int, joint: int, values: np.ndarray):
    """The segment's columns with column ``index`` set to ``values`` on ``joint`` (zero on the
    other joints), its Gram entries updated; ``A`` is shared, the new column kept beside it."""
    values = np.asarray(values, float)
    row = np.zeros(columns.rhs.shape)
    row[joint] = columns.joint_dot(joint, values)
    row[joint, index] = values @ values
    gram = columns.gram.copy()
    gram[:, index, :] = row
    gram[:, :, index] = row
    rhs = columns.rhs.copy()
    rhs[:, index] = 0.0
    rhs[joint, index] = values @ columns.y[:, joint]
    return dataclasses.replace(columns, gram=gram, rhs=rhs, overrides={**columns.overrides, index: (joint, values)})


def search_presliding(regression, extra: list[int], column: int, joint: int, train_dahl: np.ndarray,
                      held_dahl: np.ndarray, grid: np.ndarray = DISPLACEMENT_GRID,
                      column_at: Callable[[float], tuple[np.ndarray, np.ndarray]] | None = None) -> PreslidingFit:
    """The x_p that fits best when the joint's Coulomb column ``column`` becomes the Dahl column.

    Args:
        extra: the fitted columns besides the base parameters (``column`` among them).
        train_dahl, held_dahl: the joint's Dahl columns at the training / held-out samples,
            (S, G) each, for the x_p of ``grid`` [rad].
        column_at: x_p → (training, held-out) Dahl columns; when given, the best grid point
            is refined by the vertex of a parabola through it and its neighbours (in log x_p).
    """
    base_fit = regression.fit(extra)
    rss_coulomb = float(base_fit.rms_train[joint] ** 2 * regression.train.count)
    rss = np.empty(len(grid))
    for g in range(len(grid)):
        fit = _with_dahl(regression, column, joint, train_dahl[:, g], held_dahl[:, g]).fit(extra)
        rss[g] = fit.rms_train[joint] ** 2 * regression.train.count
    g = int(np.argmin(rss))
    x_p, tr, ho = float(grid[g]), train_dahl[:, g], held_dahl[:, g]
    if column_at is not None and 0 < g < len(grid) - 1:
        x_ref = _parabola_vertex(np.log(grid[g - 1 : g + 2]), rss[g - 1 : g + 2])
        tr_ref, ho_ref = column_at(x_ref)
        fit = _with_dahl(regression, column, joint, tr_ref, ho_ref).fit(extra)
        if fit.rms_train[joint] ** 2 * regression.train.count < rss[g]:
            x_p, tr, ho = x_ref, tr_ref, ho_ref
    reg = _with_dahl(regression, column, joint, tr, ho)
    fit = reg.fit(extra)
    fc = fit.value(column)
    return PreslidingFit(joint, column, x_p, float(fc), float(fc / x_p), rss, rss_coulomb, fit, reg,
                         float(fit.rms_train[joint] ** 2 * reg.train.count), ho)


def _parabola_vertex(u: np.ndarray, f: np.ndarray) -> float:
    """exp of the vertex of the parabola through (u_k, f_k), u = log x_p, kept in [u_0, u_2]."""
    c2, c1, _ = np.polyfit(u, f, 2)
    vertex = -c1 / (2 * c2) if c2 > 0 else u[1]
    return float(np.exp(np.clip(vertex, u[0], u[2])))


def _with_dahl(regression, column: int, joint: int, train_values: np.ndarray, held_values: np.ndarray):
    reg = type(regression)(replace_column(regression.train, column, joint, train_values),
                           replace_column(regression.held, column, joint, held_values),
                           regression.num_base, regression.weights)
    reg.inflation = regression.inflation
    return reg


@dataclasses.dataclass(frozen=True, eq=False)
class PreslidingStep:
    """The pre-sliding test of every joint with a Coulomb slot.

    Attributes:
        fits: the accepted :class:`PreslidingFit`, one per joint.
        report: per tested joint {joint, displacement, coulomb, stiffness, statistic,
            threshold, heldout_rms_coulomb, heldout_rms_presliding, named, reason}.
        regression: the regression with the accepted Dahl columns in place of the Coulomb ones.
        held_torque: the accepted Dahl torques F_c·z on the held-out samples, (S, n) [N·m].
        dropped: selected columns dropped because the Dahl column took their place.
    """

    fits: list[PreslidingFit]
    report: list[dict[str, Any]]
    regression: object
    final: object
    held_torque: np.ndarray
    dropped: tuple[int, ...] = ()

    def series(self, series: list[dict[str, Any]], joints: Sequence[str]) -> list[dict[str, Any]]:
        """The residual-plot entries, an accepted joint's Coulomb entry made its pre-sliding one."""
        if not self.fits:
            return series
        after = self.regression.residual("held-out", self.final)
        out = [dict(e) for e in series]
        for f in self.fits:
            label = f"{PRESLIDING}[{joints[f.joint]}]"
            entry = next((e for e in out if e["effect"] == "coulomb_friction" and e["joint"] == f.joint), None)
            if entry is None:
                before = np.asarray(self.report_entry(joints[f.joint])["heldout_residual_before"])
                entry = {"joint": f.joint, "regime": "v", "before": before}
                out.append(entry)
            entry.update(label=label, effect=PRESLIDING, after=after[:, f.joint])
        return out

    def report_entry(self, joint: str) -> dict[str, Any]:
        return next(r for r in self.report if r["joint"] == joint)

    def not_named(self, min_statistic: float = 4.0) -> list[dict[str, Any]]:
        """The tested joints that came close, as entries of the diagnosis's ``rejected`` list."""
        return [{"effect": PRESLIDING, "joint": r["joint"], "value": r["coulomb"], "unit": "N·m",
                 "z": float(np.sqrt(max(r["statistic"], 0.0))), "reason": r["reason"],
                 "presliding_displacement": r["displacement"]}
                for r in self.report if not r["named"] and r["statistic"] >= min_statistic]


def presliding_step(prep, lib, sel, config, split, consistent=None) -> PreslidingStep:
    """Tries the Dahl column in each joint's Coulomb slot and keeps it when the joint's training
    residual drops significantly (likelihood ratio ≥ z_min², with the joint's autocorrelation-
    inflated noise), its cross-validated RMS (``split``) drops by ``min_heldout_gain``, and x_p
    is not the grid's smallest (the Coulomb limit). The joint's effects no longer significant
    with it are dropped. With ``consistent`` the final values are its consistent fit's."""
    reg, library, extra = lib.regression, lib.library, list(sel.selected)
    cache: dict = {}  # (id(record), joint) -> its filtered Dahl columns (dahl_columns)
    report, fits = [], []
    held_torque = np.zeros_like(prep.held.tau)
    slots = [c for c in library.cand_of if library.cand_of[c].effect == "coulomb_friction"]
    resting = {library.cand_of[c].joint for c in sel.selected if c in library.cand_of
               and library.cand_of[c].effect == HOLDING}  # joints whose rests a holding torque carries
    for col in slots:
        j = library.cand_of[col].joint
        trial = extra if col in extra else extra + [col]
        tr, ho = (_dahl_at(cache, seg, j, j in resting) for seg in (prep.training, prep.held))
        before, split_before = reg.fit(extra), split.fit(extra)
        rss_before = float(before.rms_train[j] ** 2 * reg.train.count)

        def decide(fit: PreslidingFit) -> tuple[dict[str, Any], Any]:
            values = fit.regression.train.overrides[col][1]  # the Dahl column on the training samples
            with_dahl = split_with_column(split, reg.train, prep.internal, col, j, values)
            gain = (float(split_before.rms_held[j]), float(with_dahl.fit(trial).rms_held[j]))
            return _decide(fit, before, rss_before, reg, j, sel.thresholds, config, gain), with_dahl

        fit = search_presliding(reg, trial, col, j, tr, ho)
        decision, with_dahl = decide(fit)
        if decision["named"]:  # refine x_p between grid points (only here: each column costs a pass)
            fit = search_presliding(reg, trial, col, j, tr, ho, column_at=_column_at(prep, j, j in resting))
            decision, with_dahl = decide(fit)
        report.append({"joint": library.cand_of[col].joint_name, "displacement": fit.displacement,
                       "coulomb": fit.coulomb, "stiffness": fit.stiffness, **decision,
                       "heldout_rms_all_before": [float(x) for x in before.rms_held],
                       "heldout_residual_before": reg.residual("held-out", before)[:, j] if decision["named"] else None})
        if decision["named"]:
            fits.append(fit)
            reg, split = fit.regression, with_dahl
            extra = _drop_stand_ins(fit.regression, trial, col, j, library, sel.thresholds)
            held_torque[:, j] = fit.held_values
    final = (reg.fit(extra) if consistent is None else consistent.final(reg, reg.fit(extra))) if fits else sel.final
    for f in fits:  # the Dahl torques with the final values
        held_torque[:, f.joint] *= final.value(f.column)
    return PreslidingStep(fits, report, reg, final, held_torque, tuple(c for c in sel.selected if c not in extra))


def _decide(fit: PreslidingFit, before, rss_before: float, reg, j: int, thresholds, config,
            gain: tuple[float, float]) -> dict[str, Any]:
    """The acceptance tests of :func:`presliding_step` for one joint (``gain``: the joint's
    cross-validated RMS without and with the Dahl column [N·m])."""
    best = int(np.argmin(fit.rss))
    sigma2 = fit.rss_best / reg.train.count
    statistic = float((rss_before - fit.rss_best) / max(sigma2 * reg.inflation[j], 1e-300))
    reasons = []
    if best == 0:
        reasons.append("the smallest pre-sliding displacement fits best (in sliding, the Coulomb model)")
    if statistic < thresholds.z_min**2:
        reasons.append(f"residual drop not significant ({statistic:.3g} < {thresholds.z_min ** 2:.3g})")
    if gain[1] > (1 - config.min_heldout_gain) * gain[0]:
        reasons.append(f"cross-validated RMS only {gain[0]:.4g} → {gain[1]:.4g} N·m")
    if fit.coulomb <= 0:
        reasons.append("non-positive friction level")
    return {"statistic": statistic, "threshold": thresholds.z_min**2, "heldout_rms_before": float(before.rms_held[j]),
            "heldout_rms_presliding": float(fit.fit.rms_held[j]), "selection_rms_before": gain[0],
            "selection_rms_presliding": gain[1], "named": not reasons, "reason": "; ".join(reasons)}


def _drop_stand_ins(reg, extra: list[int], col: int, joint: int, library, thresholds) -> list[int]:
    """``extra`` without the joint's other effects that are no longer significant (weakest first)."""
    extra = list(extra)
    while True:
        fit = reg.fit(extra)
        own = [c for c in extra if c != col and c in library.cand_of and library.cand_of[c].joint == joint]
        z = {c: abs(fit.value(c)) / max(fit.std(c), 1e-300) for c in own}
        weak = [c for c in own if z[c] < thresholds.z_min]
        if not weak:
            return extra
        extra.remove(min(weak, key=lambda c: z[c]))


def _column_at(prep, joint: int, resting: bool = False) -> Callable[[float], tuple[np.ndarray, np.ndarray]]:
    """x_p → the joint's filtered Dahl columns on the training and held-out samples."""

    def at(x_p: float) -> tuple[np.ndarray, np.ndarray]:
        out = []
        for seg in (prep.training, prep.held):
            z = dahl_state(seg.record.q[:, joint], x_p)
            if resting:
                z = z * ~record_rest_mask(seg.record, joint)
            z = seg.record.filtered(z[:, None])[:, 0]
            out.append(z[seg.idx])
        return out[0], out[1]

    return at


def _dahl_at(cache: dict, seg, joint: int, resting: bool = False) -> np.ndarray:
    """:func:`dahl_columns` of a segment's record and joint (once each) at its samples, (S, G),
    zero at rest when ``resting``; the cache keeps the current joint only."""
    key = (id(seg.record), joint)
    if key not in cache:
        for old in [k for k in cache if k[1] != joint]:
            del cache[old]
        cache[key] = dahl_columns(seg.record, joint, moving=~record_rest_mask(seg.record, joint) if resting else None)
    return cache[key][seg.idx // seg.record.step]


def presliding_effects(effects: Sequence[NamedEffect], step: PreslidingStep, library,
                       joints: Sequence[str]) -> list[NamedEffect]:
    """The named effects with each accepted joint's pre-sliding friction (F_c [N·m]; σ0 and x_p
    in the details) in place of its ``coulomb_friction``, without the effects it stood in for."""
    dropped = {library.cand_of[c].label for c in step.dropped if c in library.cand_of}
    out = [_refitted(e, step, library) for e in effects if f"{e.effect}[{e.joint}]" not in dropped]
    for f in step.fits:
        name = joints[f.joint]
        old = [e for e in out if e.effect == "coulomb_friction" and e.joint == name]
        out = [e for e in out if e not in old]
        fc, sd = step.final.value(f.column), step.final.std(f.column)
        details = {"stiffness": fc / f.displacement, "stiffness_unit": "N·m/rad",
                   "presliding_displacement": f.displacement, "presliding_displacement_unit": "rad",
                   "model": "Dahl: dF/dt = stiffness·v·(1 − F/value·sgn v)",
                   "replaces": "coulomb_friction" if old else "",
                   "displacement_grid": [float(x) for x in DISPLACEMENT_GRID]}
        before = (old[0].heldout_rms_before if old
                  else per_joint(joints, step.report_entry(name)["heldout_rms_all_before"]))
        out.append(NamedEffect(PRESLIDING, name, "", float(fc), "N·m", float(sd), float(abs(fc) / max(sd, 1e-300)),
                               before, per_joint(joints, step.final.rms_held), details))
    return out


def _refitted(e: NamedEffect, step: PreslidingStep, library) -> NamedEffect:
    """An effect with its value and std from the fit with the Dahl columns (when any)."""
    col = library.timing_col if e.effect == "time_delay" else library.col_of.get(f"{e.effect}[{e.joint}]")
    if not step.fits or col is None or col not in step.final.columns:
        return e
    value, std = step.final.value(col), step.final.std(col)
    details = dict(e.details)
    if "total" in details:  # a friction on top of the model file's: its total moves with it
        details["total"] += float(value) - e.value
    return dataclasses.replace(e, value=float(value), std=float(std), z=float(abs(value) / max(std, 1e-300)),
                               details=details)
