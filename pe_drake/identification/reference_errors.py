"""References every identified model must beat on held-out data: the a-priori model (the model
file's inertias and joint friction) and predicting zero torque.

:func:`shortfalls` names every channel whose error is worse than a reference's on the same
samples, beyond the sampling noise: the per-sample difference of squared errors
d = e_model² − e_ref² has a mean > 0 of at least :data:`SIGNIFICANCE` standard errors, inflated
by d's integrated autocorrelation time (:mod:`~pe_drake.identification.statistics`). Without it a
model equal to the CAD up to estimation noise would be flagged on every joint.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from pe_drake.identification.statistics import integrated_autocorrelation

#: A channel is flagged when its mean squared-error excess is this many standard errors above 0.
SIGNIFICANCE = 2.0

#: The references and how the output names them.
REFERENCE_NAMES = {"a_priori": "the a-priori (model file) model", "zero": "predicting zero",
                   "start": "the starting fit (identify's, on the same training part)"}


@dataclasses.dataclass(frozen=True)
class Shortfall:
    """A channel whose held-out error is worse than a reference's.

    Attributes:
        channel: the joint (or ``tau.<joint>``, ``wrench.fx``, ... as the caller names them).
        reference: a key of :data:`REFERENCE_NAMES`.
        rms, reference_rms: the model's and the reference's RMS error [N·m, N].
        z: mean(e_model² − e_ref²) over its standard error.
        reason: why, when the caller knows ("" otherwise).
    """

    channel: str
    reference: str
    rms: float
    reference_rms: float
    z: float
    reason: str = ""

    @property
    def percent_worse(self) -> float:
        """100 (rms / reference_rms − 1) [%]."""
        return 100.0 * (self.rms / max(self.reference_rms, 1e-300) - 1.0)

    def as_dict(self) -> dict[str, Any]:
        return {"channel": self.channel, "reference": self.reference, "rms": self.rms,
                "reference_rms": self.reference_rms, "percent_worse": self.percent_worse, "z": self.z,
                **({"reason": self.reason} if self.reason else {})}

    def line(self) -> str:
        return (f"warning: {self.channel}: held-out RMS {self.rms:.4g} is {self.percent_worse:.0f} % worse than "
                f"{REFERENCE_NAMES[self.reference]} ({self.reference_rms:.4g}, z {self.z:.3g})"
                + (f": {self.reason}" if self.reason else ""))


def shortfalls(channels: Sequence[str], measured: np.ndarray, predicted: np.ndarray,
               references: Mapping[str, np.ndarray | None], min_percent: float = math.inf) -> list[Shortfall]:
    """Every channel whose error is significantly worse than a reference's (module docstring).

    Args:
        measured, predicted: (S, r), r = len(channels).
        references: {``a_priori`` | ``zero``: the reference's prediction, (S, r), or (S, k)
            for the first k channels only (the a-priori model predicts torques, not a wrench),
            or None (not computed)}.
        min_percent: a channel worse by more than this [%] is named even below
            :data:`SIGNIFICANCE` (a short held-out part: the diagnosis against its starting fit).

    Returns:
        The shortfalls, reference by reference, channels in order.
    """
    measured, predicted = np.asarray(measured, float), np.asarray(predicted, float)
    e_model = measured - predicted
    out = []
    for reference, pred in references.items():
        if pred is None:
            continue
        pred = np.asarray(pred, float)
        k = pred.shape[1]
        e_ref = measured[:, :k] - pred
        d = e_model[:, :k] ** 2 - e_ref**2
        S = d.shape[0]
        stderr = np.sqrt(np.var(d, axis=0) * integrated_autocorrelation(d) / max(S, 1))
        z = np.mean(d, axis=0) / np.maximum(stderr, 1e-300)
        rms, rms_ref = np.sqrt(np.mean(e_model[:, :k] ** 2, axis=0)), np.sqrt(np.mean(e_ref**2, axis=0))
        out += [Shortfall(channels[j], reference, float(rms[j]), float(rms_ref[j]), float(z[j]))
                for j in range(k) if rms[j] > rms_ref[j]
                and (z[j] >= SIGNIFICANCE or rms[j] > (1 + min_percent / 100) * rms_ref[j])]
    return out


def shortfall_report(found: Sequence[Shortfall], references: Sequence[str]) -> dict[str, Any]:
    """The JSON entry: the references compared and every shortfall."""
    return {"references": {r: REFERENCE_NAMES[r] for r in references}, "significance_z": SIGNIFICANCE,
            "worse": [s.as_dict() for s in found]}
