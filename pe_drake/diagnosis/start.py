"""The diagnosis's starting fit: ``identify``'s fit on the diagnosis's training part.

:func:`starting_fit` is identify's default fit (the base parameters with its default drive
terms, WLS with per-joint weights iterated to their fixed point) on the diagnosis's own columns.
It is the figure the augmented model is held to (:func:`start_shortfalls`).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.diagnosis.consistent_cv import ConsistentCrossValidation
from pe_drake.diagnosis.effects import EFFECT_TERMS
from pe_drake.diagnosis.options import Thresholds
from pe_drake.diagnosis.regression import Fit, Library, Regression, Scorer, Verdict, accept
from pe_drake.identification.least_squares import MAX_WEIGHT_ITERATIONS, MIN_RELATIVE_SIGMA, WEIGHT_TOLERANCE
from pe_drake.identification.reference_errors import Shortfall, shortfalls
from pe_drake.multibody.drive_columns import DriveTermOptions, drive_layout

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: A joint whose augmented model is this much worse than the starting fit [%] is named even when
#: the held-out part is too short for the difference to be significant (issue 36's bar).
START_TOLERANCE_PERCENT = 5.0

#: A term of the starting fit this many σ below its physical bound is named in the reason.
BOUND_SIGMAS = 2.0

#: The starting fit as the output and diagnosis.json name it.
START_NAME = "identify's fit (WLS with drive terms) on the training part"


@dataclasses.dataclass(frozen=True, eq=False)
class StartingFit:
    """``identify``'s fit on the diagnosis's columns (module docstring).

    Attributes:
        columns: the library columns of identify's drive terms (base parameters not included).
        weights: its per-joint weights 1/σ_j at the fixed point, (n,).
        iterations: the weighted solves.
    """

    columns: tuple[int, ...]
    fit: Fit
    weights: np.ndarray
    iterations: int
    converged: bool

    def as_dict(self, library: Library, joints) -> dict:
        """The diagnosis.json entry: its held-out RMS per joint and its drive terms."""
        return {"name": START_NAME, "weight_iterations": self.iterations, "weights_converged": self.converged,
                "held_out_rms": {j: float(r) for j, r in zip(joints, self.fit.rms_held)},
                "drive_terms": {library.label(c): self.fit.value(c) for c in self.columns}}


def identify_columns(robot: Robot, base, model, library: Library) -> tuple[int, ...]:
    """The library columns of the drive terms ``identify`` fits by default on this robot."""
    layout = drive_layout(robot, base, DriveTermOptions(), model)
    wanted = {(term, joint) for term, joint in zip(layout.terms, layout.joints)}
    return tuple(col for col, c in library.cand_of.items()
                 if c.effect in EFFECT_TERMS and (EFFECT_TERMS[c.effect], c.joint) in wanted)


def starting_fit(reg: Regression, columns: tuple[int, ...]) -> StartingFit:
    """The base parameters and ``columns`` with identify's iterated per-joint weights (σ_j² =
    RSS_j / (S − p/n) of the weighted fit itself); ``reg``'s weights are left unchanged."""
    saved = reg.weights
    S, n = reg.train.count, len(reg.weights)
    dof_scale = np.sqrt(S / max(S - (reg.num_base + len(columns)) / n, 1.0))
    reg.set_weights(np.ones(n))
    sigma = reg.fit(columns).rms_train * dof_scale  # the OLS σ_j, as identify starts from
    floor = MIN_RELATIVE_SIGMA * max(float(np.max(sigma)), 1e-12)
    sigma = np.maximum(sigma, floor)
    converged = False
    for iterations in range(1, MAX_WEIGHT_ITERATIONS + 1):
        reg.set_weights(1.0 / sigma)
        fit = reg.fit(columns)
        new = np.maximum(fit.rms_train * dof_scale, floor)
        converged = bool(np.max(np.abs(new / sigma - 1.0)) < WEIGHT_TOLERANCE)
        if converged:
            break
        sigma = new
    weights = reg.weights
    reg.set_weights(saved)
    return StartingFit(tuple(columns), fit, weights, iterations, converged)


def below_bound(fit: Fit, col: int, library: Library) -> bool:
    """A friction or armature of ``fit`` significantly below its physical bound (by more than
    ``BOUND_SIGMAS`` σ: a value at the noise level of a zero is not a finding)."""
    c = library.cand_of[col]
    return c.nonnegative and fit.value(col) < c.lower - BOUND_SIGMAS * fit.std(col)


def start_shortfalls(joints, y: np.ndarray, start: StartingFit, start_pred: np.ndarray, selected_pred: np.ndarray,
                     tau_after: np.ndarray, final_columns, library: Library) -> list[Shortfall]:
    """The joints whose augmented model is worse on the held-out part than the starting fit,
    each with the reason (drive terms the selection left out, or the physically consistent model).

    Args:
        y: the held-out torque the columns fit (measured minus the model file's friction), (S, n).
        start_pred: the starting fit's torque on the held-out part, (S, n).
        selected_pred: the selected effects' least-squares torque there, (S, n).
        tau_after: the augmented model's (Drake), minus the model file's friction, (S, n).
    """
    found = shortfalls(joints, y, tau_after, {"start": start_pred}, START_TOLERANCE_PERCENT)
    if not found:
        return []
    selected_worse = {s.channel for s in shortfalls(joints, y, selected_pred, {"start": start_pred},
                                                    START_TOLERANCE_PERCENT)}
    out = []
    for s in found:
        j = list(joints).index(s.channel)
        own = [c for c in start.columns if library.cand_of[c].joint == j]
        left_out = [library.label(c) for c in own if c not in final_columns]
        negative = [f"{library.label(c)} = {start.fit.value(c):.3g}" for c in own if below_bound(start.fit, c, library)]
        if s.channel in selected_worse:
            why = ("the selection left out the starting fit's " + ", ".join(left_out) if left_out
                   else "the selected fit's rigid-body part differs from the starting fit's")
        else:
            why = "the physically consistent model (Drake) departs from the selected least-squares fit"
        if negative:
            why += f"; the starting fit holds {', '.join(negative)}, below its physical bound"
        out.append(dataclasses.replace(s, reason=why))
    return out


@dataclasses.dataclass(frozen=True)
class StartTerms:
    """Which of the starting fit's drive terms the diagnosis keeps (a physical model can hold
    them), which it names (they pass criteria (a)-(d)), and the verdict on each column."""

    kept: tuple[int, ...]
    named: tuple[int, ...]
    verdicts: dict[int, Verdict]


def start_terms(reg: Regression, split: Scorer, library: Library, columns: tuple[int, ...],
                thresholds: Thresholds, max_effects: int, consistent: ConsistentCrossValidation | None = None,
                ) -> StartTerms:
    """The starting fit's drive terms a physical model can hold, and which of them are named.

    1. A friction or armature that identify's physical fit (``consistent``) holds on its bound
       is held there: the column is left out (only when ``consistent`` is None or its solver
       fails, the negative terms are removed one at a time, the most negative in σ first).
    2. Each column kept is named if it passes :func:`~pe_drake.diagnosis.regression.accept`
       against the kept model without it, the largest z first and at most ``max_effects``; the
       others stay in the model unnamed.
    """
    kept: list[int] = list(columns)
    verdicts: dict[int, Verdict] = {}
    _hold_at_bounds(reg, split, library, kept, verdicts, thresholds, consistent)
    named: list[int] = []
    for col in kept:
        verdicts[col] = _verdict(reg, split, library, kept, col, thresholds)
    for col in sorted((c for c in kept if verdicts[c].accepted), key=lambda c: -verdicts[c].stats["z"]):
        if len(named) < max_effects:
            named.append(col)
        else:
            reason = f"passed, but the selection stopped at max_effects = {max_effects}"
            verdicts[col] = Verdict(False, reason, "max_effects", verdicts[col].stats)
    return StartTerms(tuple(kept), tuple(c for c in kept if c in named), verdicts)


def _verdict(reg: Regression, split: Scorer, library: Library, kept: list[int], col: int,
             thresholds: Thresholds) -> Verdict:
    """:func:`~pe_drake.diagnosis.regression.accept` of ``col`` against ``kept`` without it."""
    return accept(col, reg.fit(kept), split.fit(kept), split.fit([x for x in kept if x != col]), library, thresholds)


def _hold_at_bounds(reg: Regression, split: Scorer, library: Library, kept: list[int], verdicts: dict[int, Verdict],
                    thresholds: Thresholds, consistent: ConsistentCrossValidation | None = None) -> None:
    """Step 1 of :func:`start_terms` (updates ``kept`` and ``verdicts`` in place)."""
    held = consistent.on_bounds(reg, kept) if consistent is not None else None
    if held is not None:
        fit = reg.fit(kept)
        for col in held:
            stats = _verdict(reg, split, library, kept, col, thresholds).stats
            c = library.cand_of[col]
            verdicts[col] = Verdict(False, f"on its physical bound in the physically consistent starting fit (least "
                                    f"squares {fit.value(col):.3g} {c.unit}): held at the bound, as identify's "
                                    "physical fit holds it", "sign", stats)
        kept[:] = [c for c in kept if c not in held]
        return
    while kept:
        fit = reg.fit(kept)
        low = {c: (fit.value(c) - library.cand_of[c].lower) / max(fit.std(c), 1e-300) for c in kept
               if library.cand_of[c].nonnegative and fit.value(c) < library.cand_of[c].lower}
        if not low:
            return
        col = min(low, key=low.get)
        stats = _verdict(reg, split, library, kept, col, thresholds).stats
        kept.remove(col)
        c = library.cand_of[col]
        verdicts[col] = Verdict(False, f"below its physical bound in the starting fit ({fit.value(col):.3g} {c.unit}): "
                                "held at the bound, as identify's physical fit holds it", "sign", stats)
