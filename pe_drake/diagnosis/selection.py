"""The effect selection on the training data alone: its blocked cross-validation.

The held-out data are never looked at by the selection: they give only the figures reported.
The gain and relevance tests (criteria (c)-(d)) need data the trial fit has not seen, so the
training segment is cut into blocks for a blocked ("hv-block", Racine 2000) cross-validation:

- ``FOLDS`` = 3 classes of alternating blocks (block k in class k mod 3); fold f predicts the
  blocks of class f from a fit of the rest, so every training sample is predicted once.
  Blocks, so that each part covers the whole motion and a slow drift falls on both alike;
  three folds, because one fit on two thirds of a short run identifies the base parameters
  less well than the whole run.
- a block is ``BLOCK_PERIODS`` periods of the cut-off (about 20 independent samples of
  filtered noise), shorter only to keep two blocks of each class;
- a fold's fit part leaves out the samples within 1 / cut-off of its selection part (about two
  correlation times of the zero-phase filter's noise): a column fitted on the fit part lowers
  the selection part's residual only if it models something both parts share.

The significance test (criteria (a)-(b)) uses the fit on the whole training segment.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from pe_drake.diagnosis.options import DiagnosisConfig, Thresholds
from pe_drake.diagnosis.record import Segment
from pe_drake.diagnosis.consistent_cv import ConsistentCrossValidation
from pe_drake.diagnosis.effects import JOINT_EFFECTS
from pe_drake.diagnosis.regression import (Columns, Fit, Library, Regression, Score, Scorer, Selection, Verdict,
                                           accept, select_effects)
from pe_drake.diagnosis.start import StartingFit, start_terms
from pe_drake.exceptions import DataError

BLOCK_PERIODS = 10.0  # length of a block of the internal split, in periods of the cut-off
#: Folds of the cross-validation: block k is in the selection part of fold k mod FOLDS.
FOLDS = 3


@dataclasses.dataclass(frozen=True)
class Moments:
    """What a fit needs of a set of samples: per-joint A_jᵀ A_j (n, P, P), A_jᵀ y_j (n, P),
    y_jᵀ y_j (n,) and the sample count."""

    gram: np.ndarray
    rhs: np.ndarray
    yy: np.ndarray
    count: int

    @classmethod
    def of_rows(cls, columns: Columns, rows: Sequence[slice]) -> Moments:
        """The moments of some runs of samples of ``columns`` (a block at a time: no copy of A)."""
        return cls(*columns.moments(rows))


@dataclasses.dataclass(frozen=True)
class Fold:
    """One fold: runs of training samples fitted, predicted, and in neither (the guards)."""

    fit_rows: tuple[slice, ...]
    selection_rows: tuple[slice, ...]
    guard_rows: tuple[slice, ...] = ()


def _count(rows: Sequence[slice]) -> int:
    return int(sum(s.stop - s.start for s in rows))


@dataclasses.dataclass(frozen=True)
class InternalSplit:
    """The training segment's folds, block length and guard [s] (module docstring)."""

    folds: tuple[Fold, ...]
    block_s: float
    guard_s: float

    def describe(self) -> dict[str, Any]:
        """The split as written to diagnosis.json."""
        return {"method": f"blocked {len(self.folds)}-fold cross-validation on the training data",
                "block_s": self.block_s, "guard_s": self.guard_s,
                "blocks_per_fold": [len(f.selection_rows) for f in self.folds],
                "fit_samples": [_count(f.fit_rows) for f in self.folds],
                "selection_samples": [_count(f.selection_rows) for f in self.folds]}


def internal_split(training: Segment) -> InternalSplit:
    """The blocks and folds of the training segment (module docstring)."""
    t = training.t
    cutoff = training.record.cutoff_hz
    duration = float(t[-1] - t[0])
    guard = 1.0 / cutoff
    # two blocks of each class where the segment allows, never blocks under 3 guards
    block = max(min(BLOCK_PERIODS / cutoff, duration / (2 * FOLDS)), 3 * guard)
    # a last partial block joins the one before (no block shorter than ``block``)
    last = max(int(np.floor(duration / block + 1e-9)), 1) - 1
    k = np.minimum(np.floor((t - t[0]) / block).astype(int), last)
    folds = []
    for f in range(FOLDS):
        selection = k % FOLDS == f
        sel_t = t[selection]
        if len(sel_t) < 20 or len(sel_t) > len(t) - 20:
            raise DataError(f"the training part ({duration:.3g} s, {training.num_samples} samples) is too short for "
                            f"a {FOLDS}-fold cross-validation of the effects; record a longer run",
                            file=training.record.source)
        # distance of each sample to the nearest selection sample
        pos = np.clip(np.searchsorted(sel_t, t), 1, len(sel_t) - 1)
        near = np.minimum(np.abs(t - sel_t[pos - 1]), np.abs(t - sel_t[pos]))
        fit = ~selection & (near > guard)
        folds.append(Fold(_runs(fit), _runs(selection), _runs(~selection & ~fit)))
    return InternalSplit(tuple(folds), block, guard)


def _runs(mask: np.ndarray) -> tuple[slice, ...]:
    """The runs of True in a boolean array, as slices."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return tuple(slice(int(a), int(b)) for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


class CrossValidation:
    """The folds' regressions (``held``: the fold's selection part, moments only), scored."""

    def __init__(self, folds: Sequence[Regression]):
        self.folds = list(folds)

    @classmethod
    def of(cls, reg: Regression, split: InternalSplit) -> CrossValidation:
        """The folds of ``split`` on the training columns of ``reg``, with its weights."""
        out = []
        total = reg.train
        for fold in split.folds:
            # the fit part as the whole minus the rest: each sample's products once over the
            # folds (3 passes over A for an hour's log otherwise), the guards are short
            sel, guard = Moments.of_rows(total, fold.selection_rows), Moments.of_rows(total, fold.guard_rows)
            fit = Moments(total.gram - sel.gram - guard.gram, total.rhs - sel.rhs - guard.rhs,
                          total.yy - sel.yy - guard.yy, total.count - sel.count - guard.count)
            out.append(Regression(fit, sel, reg.num_base, reg.weights))
        return cls(out)

    def fit(self, extra: Sequence[int]) -> Score:
        """The base parameters and ``extra`` fitted on each fold's fit part, scored on the rest."""
        rss, count, wrss = 0.0, 0, 0.0
        for r in self.folds:
            f = r.fit(extra)
            rss = rss + f.rms_held**2 * r.held.count
            count += r.held.count
            wrss += f.wrss_held
        return Score(np.sqrt(rss / count), float(wrss))


def split_with_column(cv: CrossValidation, columns: Columns, split: InternalSplit, index: int, joint: int,
                      values: np.ndarray) -> CrossValidation:
    """``cv`` with column ``index`` set to ``values`` (S,) on ``joint`` (zero on the other
    joints), as :func:`pe_drake.diagnosis.presliding.replace_column` does to ``columns``, the
    whole training segment's columns ``cv`` was built from."""
    values = np.asarray(values, float)
    block = columns.joint_block(joint)  # (S, P), earlier replaced columns included
    y = columns.y[:, joint]
    out = []
    for reg, fold in zip(cv.folds, split.folds):
        parts = []
        for moments, rows in ((reg.train, fold.fit_rows), (reg.held, fold.selection_rows)):
            row = np.zeros(moments.rhs.shape)
            row[joint] = sum(values[s] @ block[s] for s in rows)
            row[joint, index] = sum(values[s] @ values[s] for s in rows)
            gram, rhs = moments.gram.copy(), moments.rhs.copy()
            gram[:, index, :] = row
            gram[:, :, index] = row
            rhs[:, index] = 0.0
            rhs[joint, index] = sum(values[s] @ y[s] for s in rows)
            parts.append(Moments(gram, rhs, moments.yy, moments.count))
        out.append(Regression(parts[0], parts[1], reg.num_base, reg.weights))
    return CrossValidation(out)


def selection_thresholds(config: DiagnosisConfig, training: Segment, held: Segment, num_tests: int) -> Thresholds:
    """The selection's thresholds from the training data (noise floor, torque spread); the
    ``unexplained`` threshold of step 5, a reported figure, from the held-out data."""
    train = Thresholds.from_data(config, training.record.noise_floor, np.std(training.tau, axis=0), num_tests)
    report = Thresholds.from_data(config, held.record.noise_floor, np.std(held.tau, axis=0), num_tests)
    return dataclasses.replace(train, unexplained=report.unexplained)


def select(reg: Regression, split: CrossValidation, library: Library, rigid: Fit, training: Segment, held: Segment,
           config: DiagnosisConfig, start: StartingFit | None = None,
           consistent: ConsistentCrossValidation | None = None) -> Selection:
    """The thresholds, the starting fit's terms, forward selection and backward check, then the
    terms kept, not named, that lower the consistent model's cross-validated error."""
    thresholds = selection_thresholds(config, training, held, len(library.candidates) + 1)
    terms = (start_terms(reg, split, library, start.columns, thresholds, config.max_effects, consistent)
             if start is not None else None)
    sel = select_effects(reg, split, library, rigid, thresholds, config, terms)
    sel = renamed(reg, split, library, sel) if terms is not None else sel
    sel = kept_by_cross_validation(reg, consistent or split, library, sel)
    # the values the augmented model holds: the consistent fit's (diagnosis/consistent_cv.py)
    return dataclasses.replace(sel, final=consistent.final(reg, sel.final)) if consistent is not None else sel


def kept_by_cross_validation(reg: Regression, split: Scorer, library: Library, sel: Selection) -> Selection:
    """The per-joint candidates that lower the cross-validated error of the model without
    reaching the significance bound, kept in the model and not named.

    ``split`` scores the model the diagnosis delivers (the physically consistent fit, every
    term at its bound or above, so a term the least-squares fit takes negative is tried again).
    Greedy, the largest drop of the weighted cross-validated residual first, each held to
    criteria (c)-(d).
    """
    t = sel.thresholds
    selected, unnamed, verdicts, rejected = list(sel.selected), list(sel.unnamed), dict(sel.verdicts), dict(sel.rejected)
    pool = [c for c, cand in library.cand_of.items() if c not in selected and cand.effect in JOINT_EFFECTS]
    current = split.fit(selected)
    while pool:
        best, passed = None, []
        for col in pool:
            j = library.cand_of[col].joint
            trial = split.fit(selected + [col])
            r0, r1 = float(current.rms_held[j]), float(trial.rms_held[j])
            passes = (r1 <= (1 - t.min_heldout_gain) * r0 and trial.wrss_held < current.wrss_held
                      and np.sqrt(max(r0**2 - r1**2, 0.0)) >= t.relevance[j])
            passed += [col] * bool(passes)
            if passes and (best is None or trial.wrss_held < best[1].wrss_held):
                best = (col, trial, r0, r1)
        if best is None:
            break
        col, current, r0, r1 = best
        pool = [c for c in passed if c != col]  # one that does not help now is not tried again (each try is 3 SDPs)
        fit = reg.fit(selected + [col])
        z = abs(fit.value(col)) / max(fit.std(col), 1e-300)
        reason = (f"not named (z = {z:.2g} < {t.z_min:.2g} or a sign its least-squares value lacks), kept in the model: "
                  f"it lowers the cross-validated RMS of the physically consistent model {r0:.4g} → {r1:.4g}")
        stats = {"z": float(z), "z_min": float(t.z_min), "value": fit.value(col), "std": fit.std(col),
                 "rms_before": r0, "rms_after": r1, "relative_gain": 1 - r1 / r0 if r0 > 0 else 0.0}
        verdicts[col] = Verdict(False, reason, "z", stats)
        selected.append(col)
        unnamed.append(col)
        rejected.pop(col, None)
    if len(unnamed) == len(sel.unnamed):
        return sel
    return dataclasses.replace(sel, selected=selected, order=[*sel.order, *selected[len(sel.selected):]],
                               final=reg.fit(selected), verdicts=verdicts, rejected=rejected, unnamed=tuple(unnamed),
                               kept_cv=tuple(unnamed[len(sel.unnamed):]))


def renamed(reg: Regression, split: CrossValidation, library: Library, sel: Selection) -> Selection:
    """A starting-fit term named before the forward selection added columns stays named only if
    it still passes :func:`~pe_drake.diagnosis.regression.accept` against the final model without
    it (a Coulomb friction that stood in for a time delay is not named once the delay is in);
    else it stays in the model unnamed."""
    added = {col for _, col, _ in sel.steps}
    if not added:
        return sel
    verdicts, unnamed = dict(sel.verdicts), list(sel.unnamed)
    current = split.fit(sel.selected)
    for col in sel.selected:
        if col in added or col in unnamed or col == library.timing_col:
            continue
        without = [c for c in sel.selected if c != col]
        verdict = accept(col, sel.final, current, split.fit(without), library, sel.thresholds)
        if not verdict.accepted:
            verdicts[col], unnamed = verdict, unnamed + [col]
    return dataclasses.replace(sel, verdicts=verdicts, unnamed=tuple(unnamed))


def say_selection(say: Callable[[str], None], sel: Selection, library: Library, joints: Sequence[str],
                  fmt: Callable[[Sequence[str], Any], str], unit: str = "N·m") -> None:
    """One progress line per addition (with the held-out RMS [``unit``], a reported figure) or removal."""
    if sel.order:
        kept = [c for c in sel.order if c not in {col for _, col, _ in sel.steps} and c not in sel.kept_cv]
        named = [library.label(c) for c in kept if c not in sel.unnamed]
        if kept:
            say(f"3. from the starting fit: {len(kept)} drive terms kept (within their physical bounds), "
                f"named: {', '.join(named) or 'none'}")
    if sel.kept_cv:
        say("3. kept, not named (not significant, but they lower the cross-validated error of the physically "
            f"consistent model): {', '.join(library.label(c) for c in sel.kept_cv)}")
    for sign, col, fit in sel.steps:
        if sign == "+":
            say(f"3. + {library.label(col)}: held-out RMS [{unit}] " + fmt(joints, fit.rms_held))
        else:
            say(f"3. - {library.label(col)} (no longer significant)")


def rejected_list(reg: Regression, library: Library, sel: Selection) -> list[dict[str, Any]]:
    """Every candidate tried and not named, with its z (with the selected effects) and the
    reason, strongest first."""
    out = []
    for col, reason in sel.rejected.items():
        if col == library.timing_col or col in sel.selected:
            continue
        c = library.cand_of[col]
        f = reg.fit(sel.selected + [col])
        z = abs(f.value(col)) / max(f.std(col), 1e-300)
        out.append({"effect": c.effect, "joint": c.joint_name, "value": f.value(col),
                    "unit": c.unit, "z": float(z), "reason": reason})
    out.sort(key=lambda r: -r["z"])
    return out


def timing_report(reg: Regression, library: Library, sel: Selection, config: DiagnosisConfig) -> dict[str, Any]:
    """The timing-offset nuisance: its estimate and whether the selection needed it."""
    timing_col = library.timing_col
    timing: dict[str, Any] = {"checked": config.timing_check}
    if timing_col in sel.selected:
        timing.update(offset_s=sel.final.value(timing_col), std_s=sel.final.std(timing_col), needed=True,
                      named=True, convention="positive: the torque log lags the positions")
    else:
        f = reg.fit(sel.selected + [timing_col])
        timing.update(offset_s=f.value(timing_col), std_s=f.std(timing_col), needed=False,
                      reason=sel.rejected.get(timing_col, ""))
    return timing
