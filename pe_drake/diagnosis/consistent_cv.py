"""The cross-validated error of the physically consistent model.

The selection's fits are unconstrained least squares; the augmented model the diagnosis
delivers is physically consistent. A term the data need can look useless to the least-squares
fit, whose base parameters absorb it in a combination no set of bodies can hold (BUILD_NOTES,
"diagnose within 5 % of identify on the real Panda"). :class:`ConsistentCrossValidation` scores
a set of columns as the cross-validation does, with identification's physical fit (the one SDP)
in place of least squares: the fold's weighted Gram matrix folded into as many rows as it has
columns, the base parameters as K φ, the drive columns with their physical lower bounds.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from pe_drake.diagnosis.regression import Fit, Library, Regression, Score
from pe_drake.exceptions import NoSolutionFound
from pe_drake.identification.estimators import PHYSICAL_DELTA_CHI2
from pe_drake.identification.physical_fit import ON_BOUND, physical_fit


class ConsistentCrossValidation:
    """The physically consistent fit of each fold (``folds``: the cross-validation's
    regressions), scored on its selection part; K (b, 10·nb), phi_prior (10·nb,)."""

    def __init__(self, folds: Sequence[Regression], library: Library, K: np.ndarray, phi_prior: np.ndarray,
                 body_names: Sequence[str]):
        self.folds, self.library, self.K = list(folds), library, np.asarray(K, float)
        self.phi_prior, self.body_names = np.asarray(phi_prior, float), list(body_names)

    def final(self, reg: Regression, fit: Fit) -> Fit:
        """``fit`` (of ``reg``) with the consistent fit's values and residuals, its σ kept (the
        significance test's); unchanged when the solver fails."""
        found = consistent_fit(reg, fit.columns, self.library, self.K, self.phi_prior, self.body_names, delivered=True)
        if found is None:
            return fit
        x, cols = found[0], list(fit.columns)
        rss = [np.maximum(reg.rss(c, cols, x), 0.0) for c in (reg.train, reg.held)]
        return dataclasses.replace(fit, x=x, rms_train=np.sqrt(rss[0] / reg.train.count),
                                   rms_held=np.sqrt(rss[1] / reg.held.count),
                                   wrss_held=float(np.sum(reg.weights**2 * rss[1])))

    def on_bounds(self, reg: Regression, extra: Sequence[int]) -> list[int] | None:
        """The columns of ``extra`` that the consistent fit of ``reg``'s training part holds on
        their physical bound (``identify --method physical``'s test), or None when the solver fails."""
        found = consistent_fit(reg, [*range(reg.num_base), *extra], self.library, self.K, self.phi_prior,
                               self.body_names)
        if found is None:
            return None
        theta = found[0][reg.num_base:]
        tolerance = ON_BOUND * max(float(np.max(np.abs(theta))) if len(theta) else 1.0, 1e-9)
        cand = self.library.cand_of
        return [int(c) for c, value in zip(extra, theta)
                if c in cand and cand[c].nonnegative and value <= cand[c].lower + tolerance]

    def fit(self, extra: Sequence[int]) -> Score:
        """The consistent fit of the base parameters and ``extra`` on each fold's fit part, scored
        on its selection part (a fold whose SDP fails: by its least-squares fit)."""
        rss, count, wrss = 0.0, 0, 0.0
        for reg in self.folds:
            cols = list(range(reg.num_base)) + [int(c) for c in extra]
            fit = consistent_fit(reg, cols, self.library, self.K, self.phi_prior, self.body_names)
            if fit is None:
                f = reg.fit(extra)
                rss_j, w = f.rms_held**2 * reg.held.count, float(f.wrss_held)
            else:
                rss_j = np.maximum(reg.rss(reg.held, cols, fit[0]), 0.0)
                w = float(np.sum(reg.weights**2 * rss_j))
            rss, count, wrss = rss + rss_j, count + reg.held.count, wrss + w
        return Score(np.sqrt(rss / count), wrss)


def consistent_fit(reg: Regression, cols: Sequence[int], library: Library, K: np.ndarray, phi_prior: np.ndarray,
                   body_names: Sequence[str], *, delivered: bool = False) -> tuple[np.ndarray, np.ndarray] | None:
    """The physically consistent fit of ``cols`` (the base parameters first) on ``reg``'s
    training moments with its weights: ([K φ, θ] in the order of ``cols``, φ), or None when
    the solver fails; θ at least each column's physical bound.

    The cross-validation scores stage 1, the best consistent fit; the model ``delivered`` is
    stage 2's, as ``identify --method physical``'s: within
    :data:`~pe_drake.identification.estimators.PHYSICAL_DELTA_CHI2` of stage 1's χ², the fit
    nearest the a-priori model."""
    cols, w2, b = list(cols), reg.weights**2, reg.num_base
    G = np.einsum("j,jpq->pq", w2, reg.train.gram[:, cols][:, :, cols])
    g = np.einsum("j,jp->p", w2, reg.train.rhs[:, cols])
    yy = float(np.sum(w2 * reg.train.yy))
    # rows R with RᵀR = [[G, g], [gᵀ, yᵀy]]: the same misfit as the samples
    ev, V = np.linalg.eigh(np.block([[G, g[:, None]], [g[None, :], np.array([[yy]])]]))
    R = (V * np.sqrt(np.maximum(ev, 0.0))).T
    lower = np.array([library.cand_of[c].lower if c in library.cand_of and library.cand_of[c].nonnegative
                      else -np.inf for c in cols[b:]])
    # Stage 2's budget without identify's correlation inflation τ̄: where the residual is model
    # error, not noise, τ̄ is large and an inflated budget moves what the data determine.

    chi2 = PHYSICAL_DELTA_CHI2 if delivered else 0.0
    try:
        fit = physical_fit(R[:, :b] @ K, R[:, -1], np.asarray(phi_prior, float), list(body_names),
                           extra=R[:, b:-1], extra_lower=lower, base_K=K, chi2_tolerance=chi2,
                           rows=reg.train.count * len(w2))
    except NoSolutionFound:
        return None
    return np.concatenate([K @ fit.phi, fit.theta]), fit.phi
