"""Samples at rest in ``identify``: kept in the fit or kept out, decided by cross-validation.

A sliding joint's friction is a function of its velocity (tanh(v/v_s)); a stopped one's is not:
at rest the torque is gravity plus a holding friction anywhere within ±F_c, which tanh(0) = 0
reads as none, so a least-squares fit gives that holding torque to the gravity parameters.

A joint rests where its filtered |v| stays below ``v_rest`` for at least :func:`min_rest_s`;
``v_rest`` is :data:`NOISE_SIGMAS` times the filtered velocity's encoder noise
(:func:`rest_velocity`), and at least :data:`REST_FLOOR`. The resting joint's rows at those
samples are kept out only if that lowers the mean held-out mean-square error over joints in
:data:`REST_CV_FOLDS`-fold cross-validation over contiguous parts of the run (:func:`decide_rest`).
The holding torque itself is a history term ``pe-drake diagnose`` tests
(:mod:`pe_drake.diagnosis.holding`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from pe_drake.exceptions import ConfigError, DataError
from pe_drake.multibody.drive_columns import COULOMB_VELOCITY_SCALE
from pe_drake.identification.measurements import Measurement

#: The lowest rest threshold [rad/s or m/s], where tanh(v/v_s) < 0.25.
REST_FLOOR = 0.25 * COULOMB_VELOCITY_SCALE
#: The rest threshold in standard deviations of the filtered velocity's encoder noise.
NOISE_SIGMAS = 4.0
#: Shortest rest [s] (:func:`min_rest_s`): a velocity reversal crosses v = 0 in milliseconds.
MIN_REST_S = 0.2
#: Contiguous parts of the run for the cross-validation.
REST_CV_FOLDS = 4
#: ``identify``'s choices: decided by cross-validation, always kept, always kept out.
REST_CHOICES = ("auto", "keep", "exclude")


def rest_mask(v: np.ndarray, rate_hz: float, v_rest: float, min_s: float) -> np.ndarray:
    """Where a joint rests, (T,) bool: |v| < ``v_rest`` [rad/s] for at least ``min_s`` [s].

    ``v``: one joint's velocity, (T,) [rad/s], uniformly sampled at ``rate_hz`` [Hz].
    """
    still = np.abs(np.asarray(v, float)) < v_rest
    edges = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(np.int8), [0]])))
    out = np.zeros(still.shape, bool)
    for start, stop in zip(edges[::2], edges[1::2]):
        if stop - start >= min_s * rate_hz:
            out[start:stop] = True
    return out


def count_runs(mask: np.ndarray) -> int:
    """Number of runs of True in a boolean series."""
    m = np.asarray(mask, bool)
    return int(np.count_nonzero(m[1:] & ~m[:-1]) + bool(m.size and m[0]))


def min_rest_s(cutoff_hz: float | None) -> float:
    """The shortest rest [s]: :data:`MIN_REST_S` and at least 2 / cut-off, so that the zero-phase
    filter's transient of the stop is over."""
    return max(MIN_REST_S, 2.0 / cutoff_hz) if cutoff_hz else MIN_REST_S


def encoder_noise(raw: Measurement) -> np.ndarray:
    """The position noise of the recorded q per joint, (n,) [rad or m], from its third
    differences (Δ³ of white noise has variance 20σ²; a smooth motion adds only q⃛·dt³). The
    mean, not a median: a median reads a slow joint's quantized staircase as noise-free."""
    d3 = np.diff(np.asarray(raw.q, float), n=3, axis=0)
    if d3.shape[0] == 0:
        return np.zeros(raw.num_joints)
    return np.sqrt(np.mean(d3**2, axis=0) / 20.0)


def rest_velocity(raw: Measurement, data: Measurement) -> np.ndarray:
    """The rest threshold per joint, (n,) [rad/s]: :data:`NOISE_SIGMAS` σ_v and at least
    :data:`REST_FLOOR`, σ_v the noise of the filtered velocity: white position noise σ_q at
    rate f_s through an ideal low-pass at f_c and a derivative, σ_v² = σ_q² (2/f_s) ∫₀^f_c (2πf)² df
    = σ_q² (2π f_c)² · 2 f_c / (3 f_s). Data used unfiltered (exact v columns) gets the floor."""
    p = data.preprocessing
    if p is None:
        return np.full(data.num_joints, REST_FLOOR)
    fs, fc = raw.rate_hz, p.cutoff_hz
    sigma_v = encoder_noise(raw) * 2 * np.pi * fc * np.sqrt(2 * fc / (3 * fs))
    return np.maximum(REST_FLOOR, NOISE_SIGMAS * sigma_v)


def rest_rows(data: Measurement, v_rest: np.ndarray) -> np.ndarray:
    """Where each joint rests in preprocessed data, (S, n) bool (:func:`rest_mask`)."""
    p = data.preprocessing
    min_s = min_rest_s(p.cutoff_hz if p is not None else None)
    rate = 1.0 / float(np.median(np.diff(data.t))) if data.num_samples > 1 else 1.0
    return np.column_stack([rest_mask(data.v[:, j], rate, v_rest[j], min_s) for j in range(data.num_joints)])


@dataclasses.dataclass(frozen=True, eq=False)
class RestDecision:
    """What identify did with the samples at rest.

    Attributes:
        handling: ``none`` (no joint rests), ``kept`` or ``excluded``.
        reason: how it was decided (cross-validation, the user's choice, a fold too short).
        seconds: time each joint rests [s], (n,); rests: their number per joint.
        v_rest: the threshold per joint [rad/s].
        cv_kept, cv_excluded: cross-validated RMS per joint of both choices [N·m], or None.
        mask: the rows kept out of the fit, (S, n), or None.
    """

    handling: str
    reason: str
    joints: tuple[str, ...]
    seconds: np.ndarray
    rests: np.ndarray
    v_rest: np.ndarray
    cv_kept: np.ndarray | None = None
    cv_excluded: np.ndarray | None = None
    mask: np.ndarray | None = None

    def line(self) -> str:
        """The summary line."""
        if self.handling == "none":
            return f"rest: no joint rests (|v| below {_range(self.v_rest)} rad/s for a while): every sample fitted"
        resting = ", ".join(f"{j} {s:.2g} s" for j, s in zip(self.joints, self.seconds) if s > 0)
        what = "kept out of the fit" if self.handling == "excluded" else "kept in the fit"
        cv = ""
        if self.cv_kept is not None:
            cv = (f" (held-out RMS in {REST_CV_FOLDS}-fold cross-validation, mean over joints: kept "
                  f"{_mean_rms(self.cv_kept):.4g}, kept out {_mean_rms(self.cv_excluded):.4g})")
        return f"rest: samples at rest ({resting}; |v| < {_range(self.v_rest)} rad/s) {what}: {self.reason}{cv}"

    def as_dict(self) -> dict[str, Any]:
        """identified.json's ``rest`` block."""
        def table(x):
            return None if x is None else {j: float(v) for j, v in zip(self.joints, x)}

        return {"handling": self.handling, "reason": self.reason, "seconds": table(self.seconds),
                "rests": {j: int(r) for j, r in zip(self.joints, self.rests)}, "v_rest": table(self.v_rest),
                "cv_folds": REST_CV_FOLDS if self.cv_kept is not None else None,
                "cv_rms_kept": table(self.cv_kept), "cv_rms_excluded": table(self.cv_excluded)}


def _range(x: np.ndarray) -> str:
    lo, hi = float(np.min(x)), float(np.max(x))
    return f"{lo:.2g}" if np.isclose(lo, hi) else f"{lo:.2g}-{hi:.2g}"


def _mean_rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.asarray(x) ** 2)))


#: fit(sample indices, rows kept out or None) -> a model; predict(model, sample indices) -> (k, n) torques.
FitFunction = Callable[[np.ndarray, np.ndarray | None], Any]
PredictFunction = Callable[[Any, np.ndarray], np.ndarray]


def decide_rest(raw: Measurement, data: Measurement, choice: str, fit: FitFunction,
                predict: PredictFunction) -> RestDecision:
    """Whether the rows at rest are kept out of the fit (module docstring).

    Args:
        raw: the run as recorded (its q's noise sets the threshold).
        data: as preprocessed for the fit.
        choice: one of :data:`REST_CHOICES`.
        fit, predict: the fit of a subset of ``data``'s samples and its prediction of others.

    Raises:
        ConfigError: an unknown ``choice``.
    """
    if choice not in REST_CHOICES:
        raise ConfigError(f"rest handling '{choice}' is not one of {', '.join(REST_CHOICES)}")
    v_rest = rest_velocity(raw, data)
    mask = rest_rows(data, v_rest)
    dt = np.gradient(data.t) if data.num_samples > 1 else np.zeros(data.num_samples)
    seconds, rests = mask.T.astype(float) @ dt, np.array([count_runs(m) for m in mask.T])
    base = (data.joints, seconds, rests, v_rest)
    if not mask.any():
        return RestDecision("none", "no rest", *base)
    if choice != "auto":
        return RestDecision("excluded" if choice == "exclude" else "kept", f"--rest {choice}", *base,
                            mask=mask if choice == "exclude" else None)
    try:
        kept, excluded = _cross_validated(data, mask, fit, predict)
    except DataError as err:  # a fold too short for the parameters: keep what the whole run fits
        return RestDecision("kept", f"not cross-validated ({err})", *base)
    ratio = float(np.mean(excluded**2 / np.maximum(kept**2, 1e-300)))
    if ratio < 1.0:
        reason = f"cross-validation: mean-square error × {ratio:.3g}"
        return RestDecision("excluded", reason, *base, kept, excluded, mask)
    return RestDecision("kept", f"cross-validation: keeping them out would give × {ratio:.3g}", *base, kept, excluded)


def _cross_validated(data: Measurement, mask: np.ndarray, fit: FitFunction,
                     predict: PredictFunction) -> tuple[np.ndarray, np.ndarray]:
    """Held-out RMS per joint of both choices over :data:`REST_CV_FOLDS` contiguous parts, (n,) each."""
    S = data.num_samples
    bounds = np.linspace(0, S, REST_CV_FOLDS + 1).astype(int)
    sse = {"kept": np.zeros(data.num_joints), "excluded": np.zeros(data.num_joints)}
    for k in range(REST_CV_FOLDS):
        held = np.arange(bounds[k], bounds[k + 1])
        train = np.setdiff1d(np.arange(S), held)
        kept = fit(train, None)
        sse["kept"] += np.sum((data.tau[held] - predict(kept, held)) ** 2, axis=0)
        # a training part without rests gives the same fit either way
        excluded = fit(train, mask[train]) if mask[train].any() else kept
        sse["excluded"] += np.sum((data.tau[held] - predict(excluded, held)) ** 2, axis=0)
    return np.sqrt(sse["kept"] / S), np.sqrt(sse["excluded"] / S)
