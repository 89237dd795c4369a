"""The regression of the measured torque on the base regressor and the library's columns.

:class:`Regression` refits any subset of columns from per-joint Gram matrices (WLS, sandwich
covariance inflated by each joint's autocorrelation time); :func:`select_effects` runs the
stepwise selection on criteria (a)-(d) (:func:`accept`); then the residual analysis of steps 1
and 5.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from typing import Any, NamedTuple, Protocol

import numpy as np

from pe_drake.diagnosis.columns import Columns
from pe_drake.diagnosis.effects import Candidate, effect_column
from pe_drake.diagnosis.holding import HOLDING, holding_column
from pe_drake.diagnosis.options import TIMING, DiagnosisConfig, Thresholds
from pe_drake.diagnosis.record import Segment
from pe_drake.identification.least_squares import solve_normal_equations
from pe_drake.identification.statistics import integrated_autocorrelation


@dataclasses.dataclass(frozen=True, eq=False)
class Fit:
    """A weighted least-squares fit of the base parameters and some library columns.

    Attributes:
        columns: indices of the fitted columns (base parameters first).
        x: their values, shape (len(columns),).
        cov: their covariance (sandwich, autocorrelation-inflated).
        wrss_held: held-out residual sum of squares weighted like the fit.
    """

    columns: tuple[int, ...]
    x: np.ndarray
    cov: np.ndarray
    rms_train: np.ndarray
    rms_held: np.ndarray
    wrss_held: float

    def value(self, column: int) -> float:
        return float(self.x[self.columns.index(column)])

    def std(self, column: int) -> float:
        k = self.columns.index(column)
        return math.sqrt(max(float(self.cov[k, k]), 0.0))


class Regression:
    """Fits of subsets of columns from per-joint Gram matrices (fast repeated refits)."""

    def __init__(self, train: Columns, held: Columns, num_base: int, weights=None):
        self.train = train
        self.held = held
        self.num_base = num_base
        n = train.gram.shape[0]
        self.weights = np.ones(n) if weights is None else np.asarray(weights, float)
        self.inflation = np.ones(n)  # integrated autocorrelation time per joint

    def set_weights(self, weights: np.ndarray) -> None:
        """Per-joint weights of the WLS, (n,)."""
        self.weights = np.asarray(weights, float)

    def fit(self, extra: Sequence[int]) -> Fit:
        """The base parameters and the ``extra`` columns, fitted on the training segment."""
        cols = list(range(self.num_base)) + [int(c) for c in extra]
        w2 = self.weights**2
        Gj = self.train.gram[:, cols][:, :, cols]
        G = np.einsum("j,jpq->pq", w2, Gj)
        g = np.einsum("j,jp->p", w2, self.train.rhs[:, cols])
        x, Hinv = solve_normal_equations(G, g)
        rss_tr = self.rss(self.train, cols, x)
        rss_ho = self.rss(self.held, cols, x)
        S_tr, S_ho = self.train.count, self.held.count
        var_j = np.maximum(rss_tr, 0.0) / max(S_tr - len(cols) / len(w2), 1.0)
        # Sandwich: Var x = H⁻¹ (Σ_j w_j⁴ s_j τ_j G_j) H⁻¹ with s_j the joint's residual variance.
        meat = np.einsum("j,jpq->pq", w2**2 * var_j * self.inflation, Gj)
        return Fit(tuple(cols), x, Hinv @ meat @ Hinv, np.sqrt(np.maximum(rss_tr, 0) / S_tr),
                   np.sqrt(np.maximum(rss_ho, 0) / S_ho), float(np.sum(w2 * rss_ho)))

    @staticmethod
    def rss(c: Columns, cols: list[int], x: np.ndarray) -> np.ndarray:
        """Per-joint residual sum of squares of the columns ``cols`` at ``x`` from the moments."""
        G = c.gram[:, cols][:, :, cols]
        r = c.rhs[:, cols]
        return c.yy - 2 * r @ x + np.einsum("p,jpq,q->j", x, G, x)

    def residual(self, which: str, fit: Fit) -> np.ndarray:
        """Measured minus fitted torque on "training" or "held-out", (S, n)."""
        c = self.train if which == "training" else self.held
        return c.y - c.product(fit.columns, fit.x)

    def contribution_rms(self, which: str, fit: Fit, column: int) -> np.ndarray:
        """Per-joint RMS of one column's torque θ·c in a segment."""
        c = self.train if which == "training" else self.held
        k = fit.columns.index(column)
        return np.abs(fit.x[k]) * np.sqrt(c.gram[:, column, column] / c.count)


def condition_number(G: np.ndarray) -> float:
    """cond of A with column-equilibrated A from its Gram matrix G = AᵀA."""
    d = np.sqrt(np.maximum(np.diag(G), 1e-300))
    w = np.linalg.eigvalsh(G / np.outer(d, d))
    return float(np.sqrt(w.max() / w.min())) if w.min() > 0 else float("inf")


@dataclasses.dataclass(frozen=True)
class Library:
    """Where the separable candidates and the timing nuisance sit among the columns: the b
    base-parameter columns, the candidates at b … b + len - 1, the timing column last."""

    num_base: int
    candidates: tuple[Candidate, ...]

    @property
    def timing_col(self) -> int:
        return self.num_base + len(self.candidates)

    @functools.cached_property
    def col_of(self) -> dict[str, int]:
        """{candidate label: column}."""
        return {c.label: self.num_base + k for k, c in enumerate(self.candidates)}

    @functools.cached_property
    def cand_of(self) -> dict[int, Candidate]:
        """{column: candidate}."""
        return {self.num_base + k: c for k, c in enumerate(self.candidates)}

    def label(self, col: int) -> str:
        """The candidate's label, or ``time_delay`` for the timing column."""
        return TIMING if col == self.timing_col else self.cand_of[col].label

    def segment_columns(self, model, independent: np.ndarray, seg: Segment,
                        known: np.ndarray | None = None) -> Columns:
        """A segment's base regressor (``model``'s ``independent`` columns), timing nuisance and
        candidate columns, built a block of samples at a time (never held twice, nor in float64).

        Args:
            known: torque the a-priori model already holds outside the regressor (the model
                file's friction), (S, n) [N·m]: the fit is of the measured torque minus it.
        """
        b = self.num_base
        q, v, vd, dtau = seg.q, seg.v, seg.vd, seg.dtau

        def fill(rows: slice, out: np.ndarray) -> None:
            model.columns(q[rows], v[rows], vd[rows], independent, out=out[:, :, :b])
            out[:, :, b] = -dtau[rows]  # the timing nuisance: tau_rec(t) ≈ tau(t) - d·dtau/dt

        y = seg.tau if known is None else seg.tau - known
        # the columns acting on every joint are stored whole: the base regressor and timing
        return Columns.assemble(y, b + len(self.candidates) + 1, [*range(b), self.timing_col],
                                fill, self.single_joint_columns(seg))

    def single_joint_columns(self, seg: Segment) -> dict[int, tuple[int, np.ndarray]]:
        """{column: (joint, values (S,))}: each candidate's column on its own joint."""
        out, q, v, vd = {}, seg.q, seg.v, seg.vd
        for k, c in enumerate(self.candidates):
            if c.effect == HOLDING:  # a history column (diagnosis/holding.py), not a function of the state
                values = holding_column(seg, c.joint)
            else:
                values = (seg.coulomb[:, c.joint].copy() if c.effect == "coulomb_friction"
                          else effect_column(c.effect, q, v, vd, c.joint))
            out[self.num_base + k] = (c.joint, values)
        return out


class Verdict(NamedTuple):
    """The decision on one column tried in the forward selection.

    Attributes:
        test: the criterion it fails: ``sign``, ``z``, ``gain``, ``other_joints``,
            ``relevance``, or ``max_effects`` (passed when the selection was full); "" if accepted.
        stats: ``z`` (whole training segment), the cross-validated RMS before/after on its
            joint (``rms_before``, ``rms_after`` [N·m], all joints for the timing column),
            ``relative_gain``, ``explained_rms`` [N·m], ``wrss_gain``.
    """

    accepted: bool
    reason: str
    test: str
    stats: dict[str, Any]


class Score(NamedTuple):
    """How a set of columns predicts data it was not fitted on (RMS [N·m], weighted RSS)."""

    rms_held: np.ndarray
    wrss_held: float


class Scorer(Protocol):
    """What scores a set of columns on data it was not fitted on (the cross-validation)."""

    def fit(self, extra: Sequence[int]) -> Score: ...


def accept(col: int, fit: Fit, trial: Score, before: Score, library: Library, thresholds: Thresholds) -> Verdict:
    """Criteria (a)-(d) for adding column ``col``: (a), (b) on ``fit`` (the training segment),
    (c), (d) on the cross-validated scores ``trial`` (with it) and ``before`` (without)."""
    value, std = fit.value(col), fit.std(col)
    z = abs(value) / max(std, 1e-300)
    z_min, relevance, gain_min = thresholds.z_min, thresholds.relevance, thresholds.min_heldout_gain
    stats: dict[str, Any] = {"z": float(z), "z_min": float(z_min), "value": float(value), "std": float(std),
                             "wrss_gain": float(before.wrss_held - trial.wrss_held)}
    if col == library.timing_col:
        explained = np.sqrt(np.maximum(before.rms_held**2 - trial.rms_held**2, 0.0))
        stats.update(rms_before=[float(x) for x in before.rms_held], rms_after=[float(x) for x in trial.rms_held],
                     relative_gain=float(1 - math.sqrt(trial.wrss_held / max(before.wrss_held, 1e-300))),
                     explained_rms=float(np.max(explained)))
        if z < z_min:
            return Verdict(False, f"not significant (z = {z:.2g} < {z_min:.2g})", "z", stats)
        if trial.wrss_held > (1 - gain_min) ** 2 * before.wrss_held:
            return Verdict(False, f"cross-validated gain {100 * stats['relative_gain']:.2g} % < {100 * gain_min:.2g} %",
                           "gain", stats)
        if not np.any(explained >= relevance):
            return Verdict(False, "explains too little on every joint", "relevance", stats)
        return Verdict(True, "", "", stats)
    c: Candidate = library.cand_of[col]
    j = c.joint
    r0, r1 = float(before.rms_held[j]), float(trial.rms_held[j])
    explained = math.sqrt(max(r0**2 - r1**2, 0.0))
    stats.update(rms_before=r0, rms_after=r1, relative_gain=1 - r1 / r0 if r0 > 0 else 0.0,
                 explained_rms=explained, relevance=float(relevance[j]))
    # A correction of a model file's friction (lower < 0) is checked against its bound in the
    # backward pass, with every effect in: alone, it also takes its joint's missing terms.
    if c.nonnegative and c.lower == 0 and value < 0:
        return Verdict(False, f"physically implausible sign ({value:.3g} {c.unit})", "sign", stats)
    if z < z_min:
        return Verdict(False, f"not significant (z = {z:.2g} < {z_min:.2g})", "z", stats)
    if r1 > (1 - gain_min) * r0:
        return Verdict(False, f"cross-validated RMS of {c.joint_name} only {r0:.4g} → {r1:.4g} N·m "
                       f"({100 * stats['relative_gain']:.2g} % < {100 * gain_min:.2g} %)", "gain", stats)
    if trial.wrss_held >= before.wrss_held:
        return Verdict(False, "cross-validated residual of the other joints grows", "other_joints", stats)
    if explained < relevance[j]:
        return Verdict(False, f"explains too little ({explained:.3g} < {relevance[j]:.3g} N·m cross-validated "
                       "RMS)", "relevance", stats)
    return Verdict(True, "", "", stats)


@dataclasses.dataclass(frozen=True, eq=False)
class Selection:
    """The outcome of the stepwise selection.

    Attributes:
        selected: the columns kept (effects and possibly the timing nuisance); ``order``: the
            same in the order they were added.
        final: the fit with ``selected`` on the whole training segment.
        steps: ("+" or "-", column, the fit after an addition or None) in order.
        verdicts: {column: the :class:`Verdict` that decided it}: a selected column's addition
            (its ``z`` then from ``final``), a rejected one's last trial, test ``backward``.
        unnamed: the starting fit's drive terms kept but not named, then ``kept_cv``; in
            ``selected`` and ``order``.
        kept_cv: the candidates kept, not named, because they lower the cross-validated error
            of the consistent model.
    """

    selected: list[int]
    order: list[int]
    final: Fit
    rejected: dict[int, str]
    thresholds: Thresholds
    steps: list[tuple[str, int, Fit | None]]
    verdicts: dict[int, Verdict] = dataclasses.field(default_factory=dict)
    unnamed: tuple[int, ...] = ()
    kept_cv: tuple[int, ...] = ()


def select_effects(reg: Regression, split: Scorer, library: Library, rigid: Fit, thresholds: Thresholds,
                   config: DiagnosisConfig, start: Any = None) -> Selection:
    """Forward stepwise selection, then a backward check (step 3), on the training segment.

    Args:
        reg: the regression on the training segment (values, σ); each accepted column
            re-estimates its autocorrelation inflation, which it keeps.
        split: the blocked cross-validation of the training segment: the gain and relevance tests.
        start: the starting fit's drive terms (:class:`~pe_drake.diagnosis.start.StartTerms`),
            or None: the forward selection starts from them, the backward check keeps them,
            the ones it left out are not tried again, and ``max_effects`` counts the others.
    """
    kept = list(start.kept) if start is not None else []
    selected: list[int] = list(kept)
    order: list[int] = list(kept)
    verdicts: dict[int, Verdict] = dict(start.verdicts) if start is not None else {}
    rejected: dict[int, str] = {c: v.reason for c, v in verdicts.items() if c not in kept}
    steps: list[tuple[str, int, Fit | None]] = []
    current, current_split = (reg.fit(kept), split.fit(kept)) if kept else (rigid, split.fit([]))
    if kept:
        reg.inflation = integrated_autocorrelation(reg.residual("training", current))
    timing_col = library.timing_col
    pool = [c for c in library.col_of.values() if c not in verdicts] + ([timing_col] if config.timing_check else [])
    unnamed = tuple(c for c in kept if c not in start.named) if start is not None else ()
    while len([c for c in selected if c != timing_col and c not in unnamed]) < config.max_effects:
        best, best_fits, best_gain = None, None, 0.0
        for col in pool:
            if col in selected:
                continue
            fit, trial = reg.fit(selected + [col]), split.fit(selected + [col])
            verdict = accept(col, fit, trial, current_split, library, thresholds)
            verdicts[col] = verdict
            if not verdict.accepted:
                rejected[col] = verdict.reason
                continue
            # Order of the additions: the largest drop of the weighted training residual
            # (largest partial F) among the columns that pass; the noisier cross-validated
            # scores only gate (ordered by them, Coulomb stood in for pre-sliding friction).
            gain = float(np.sum(reg.weights**2 * (current.rms_train**2 - fit.rms_train**2)) * reg.train.count)
            if gain > best_gain:
                best, best_fits, best_gain = col, (fit, trial), gain
        if best is None:
            break
        selected.append(best)
        order.append(best)
        rejected.pop(best, None)
        current, current_split = best_fits
        reg.inflation = integrated_autocorrelation(reg.residual("training", current))
        steps.append(("+", best, current))
    for col, verdict in list(verdicts.items()):  # passed its last trial, but the selection was full
        if verdict.accepted and col not in selected:
            reason = f"passed, but the selection stopped at max_effects = {config.max_effects}"
            verdicts[col] = Verdict(False, reason, "max_effects", verdict.stats)
            rejected[col] = reason
    current = _backward_check(reg, library, selected, current, thresholds.z_min, rejected, steps, verdicts, kept)
    return Selection(selected, [c for c in order if c in selected], current, rejected, thresholds, steps, verdicts,
                     unnamed)


def _backward_check(reg: Regression, library: Library, selected: list[int], current: Fit, z_min: float,
                    rejected: dict[int, str], steps: list, verdicts: dict[int, Verdict], kept: Sequence[int] = ()) -> Fit:
    """Drops (in place) the columns no longer plausible and significant, except ``kept``."""
    cand_of = library.cand_of
    while selected:
        worst, worst_z = None, np.inf
        for col in (c for c in selected if c not in kept):
            value = current.value(col)
            z = abs(value) / max(current.std(col), 1e-300)
            if col in cand_of and cand_of[col].nonnegative and value < cand_of[col].lower:
                z = -1.0
            if z < z_min and z < worst_z:
                worst, worst_z = col, z
        if worst is None:
            break
        selected.remove(worst)
        rejected[worst] = f"dropped in the backward check (z = {worst_z:.2g} < {z_min:.2g} with the others)"
        verdicts[worst] = Verdict(False, rejected[worst], "backward",
                                  {**verdicts[worst].stats, "z": float(worst_z), "z_min": float(z_min)})
        current = reg.fit(selected)
        steps.append(("-", worst, None))
    return current


def rms(x: np.ndarray) -> np.ndarray:
    """Root mean square along the first axis."""
    return np.sqrt(np.mean(np.asarray(x) ** 2, axis=0))


def corr(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of two series (0 when either is constant)."""
    a, b = a - a.mean(), b - b.mean()
    d = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b / d) if d > 0 else 0.0


def regime_analysis(residual, q, v, vd, t, joints) -> dict[str, Any]:
    """Mean and RMS of a residual per joint in each regime of :func:`_regime_masks` (step 1).

    Returns:
        {joint: {"overall": {...}, "regimes": [{"regime", "bin", "count", "mean", "rms"}],
        "strongest": the bin whose mean departs most from the overall mean, correlations}}.
    """
    out = {}
    for j, name in enumerate(joints):
        r = residual[:, j]
        bins = []
        for regime, label, mask in _regime_masks(q[:, j], v[:, j], vd[:, j], t):
            if mask.sum() == 0:
                continue
            bins.append({"regime": regime, "bin": label, "count": int(mask.sum()),
                         "mean": float(r[mask].mean()), "rms": float(np.sqrt(np.mean(r[mask] ** 2)))})
        overall = {"mean": float(r.mean()), "rms": float(np.sqrt(np.mean(r**2)))}
        strongest = max(bins, key=lambda e: abs(e["mean"] - overall["mean"]))
        out[name] = {"overall": overall, "regimes": bins, "strongest": strongest,
                     "correlation_sign_v": corr(r, np.sign(v[:, j])), "correlation_v": corr(r, v[:, j]),
                     "correlation_vd": corr(r, vd[:, j])}
    return out


def _regime_masks(q: np.ndarray, v: np.ndarray, vd: np.ndarray, t: np.ndarray) -> list[tuple[str, str, np.ndarray]]:
    """(regime, bin, mask) of one joint's samples: velocity sign (|v| ≤ 5 % of max: v ≈ 0),
    speed, acceleration and position terciles, time quarters."""
    vmax = float(np.max(np.abs(v))) or 1.0
    still = np.abs(v) <= 0.05 * vmax
    masks = [("velocity sign", "v < 0", (v < 0) & ~still), ("velocity sign", "v ≈ 0", still),
             ("velocity sign", "v > 0", (v > 0) & ~still)]
    for regime, x, names in (("speed", np.abs(v), ("slow", "medium", "fast")),
                             ("acceleration", vd, ("vd low", "vd mid", "vd high")),
                             ("position", q, ("q low", "q mid", "q high"))):
        e1, e2 = np.quantile(x, [1 / 3, 2 / 3])
        masks += [(regime, names[0], x <= e1), (regime, names[1], (x > e1) & (x <= e2)),
                  (regime, names[2], x > e2)]
    edges = np.quantile(t, [0.25, 0.5, 0.75])
    quarter = np.searchsorted(edges, t)
    masks += [("time", f"quarter {k + 1}", quarter == k) for k in range(4)]
    return masks


def unexplained_joints(residual: np.ndarray, held: Segment, thresholds: np.ndarray, noise_floor: np.ndarray,
                       rms_nominal: np.ndarray, joints: Sequence[str], timing: dict[str, Any]) -> dict[str, Any]:
    """Joints whose held-out residual stays above their threshold, with its signature (step 5)."""
    out = {}
    rms_j = rms(residual)
    t = held.t
    signals = {"sign(v)": np.sign(held.v), "v": held.v, "vd": held.vd, "q": held.q,
               "dtau/dt": held.dtau, "t": np.repeat((t - t.mean())[:, None], len(joints), axis=1)}
    for j, name in enumerate(joints):
        if rms_j[j] <= thresholds[j]:
            continue
        r = residual[:, j]
        correlations = {k: corr(r, x[:, j]) for k, x in signals.items()}
        top = max(correlations, key=lambda k: abs(correlations[k]))
        hint = f"residual correlates most with {top} ({correlations[top]:+.2f})"
        if timing.get("needed"):
            hint += (f"; a time delay of {1e3 * timing['offset_s']:+.3g} ms between the torque and position logs "
                     "is named and corrected for")
        out[name] = {"rms": float(rms_j[j]), "threshold": float(thresholds[j]), "noise_floor": float(noise_floor[j]),
                     "fraction_of_nominal_rms": float(rms_j[j] / rms_nominal[j]) if rms_nominal[j] > 0 else 0.0,
                     "correlations": correlations, "hint": hint}
    return out
