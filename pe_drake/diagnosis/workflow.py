"""Diagnosis: where the a-priori model and the measurement disagree, which effect is missing.

``pe-drake diagnose --robot ROBOT --data ident.csv [--validation other.csv] --out DIR``

1. **Nominal comparison.** The a-priori model's torque along the measured motion (Drake's
   inverse dynamics = Y φ_prior, plus the model file's joint damping) against the measured
   torque, per joint and per regime (velocity sign, speed, acceleration, position, time).
2. **Rigid-body re-identification** of the base parameters alone (WLS, Gautier's per-joint
   weights), reported as its own step: inertial errors are not a missing effect.
3. **Effects.** Candidate columns of :mod:`pe_drake.diagnosis.effects` are appended to the base
   regressor and selected by forward stepwise regression. A candidate is named only if, fitted
   with the rigid-body parameters on the training data, (a) its value is physically plausible
   (friction, armature ≥ 0), (b) it is significant: |θ| / σ_θ ≥ z, with σ_θ from the sandwich
   covariance inflated by the integrated autocorrelation time of the joint's residual (filtered
   samples are not independent) and z the two-sided Bonferroni bound for ``alpha`` over all
   candidates, (c) it lowers the held-out RMS of its joint by at least ``min_heldout_gain``
   (relative) and the weighted held-out residual overall, and (d) what it explains there is
   relevant: √(RMS_before² - RMS_after²) ≥ max(``noise_factor`` × noise floor,
   ``min_effect_fraction`` × the joint's torque spread, ``resolution_fraction`` × the largest
   joint's spread) (a value that is large only because the column is nearly collinear with
   rigid-body terms on this motion explains little).
   A backward pass drops effects that no longer pass (a)–(b) once the others are in.
   Effects that no motion can separate from the rigid-body terms are reported as such with
   the base parameter they merge into. A **payload** is sought in the re-identified base
   parameters: Δφ_B = φ_B - K φ_prior explained by one link's 10 parameters (GLS with the
   covariance C = K Σ_φ Kᵀ + Cov(φ_B), Σ_φ the a-priori uncertainty, default 10 %), named
   when the χ² gain passes ``payload_alpha``, the mass change exceeds
   ``payload_min_prior_sigmas`` a-priori standard deviations of the link's mass and 3 of its
   own, and what is left is consistent with the a-priori uncertainty (localized).
   A timing offset between the torque and position logs (a common logging fault, not a
   physical effect) enters the selection as a nuisance column -dτ/dt (τ_rec(t) ≈ τ(t) - d τ̇):
   it keeps the library from absorbing it, and is reported under ``unexplained``, never named.
4. **Augmented model.** The selected effects are added to the model in Drake (joint damping,
   rotor inertia, a welded payload body, Coulomb friction as a ``DoorHinge`` force element,
   offsets as a generalized force; :mod:`pe_drake.diagnosis.augmented_model`), the held-out torque is
   recomputed with Drake's inverse dynamics, and the gap before and after is reported.
5. **Unexplained.** Joints whose held-out residual stays above max(``noise_factor`` × noise
   floor, ``unexplained_fraction`` × the joint's torque spread, ``resolution_fraction`` × the
   largest joint's spread) are listed with the signals their residual correlates with.

Data preparation: the measurement is brought to a uniform grid and low-pass filtered with a
zero-phase Butterworth (:func:`pe_drake.identification.measurements.preprocess`, same filter on q and τ);
v, v̇ by central differences; then decimated to about ``decimate_to_hz``. The Coulomb column
tanh(v/v_s) has content far above the cut-off, so it is computed at the full rate and filtered
with the same filter as τ before decimation (parallel filtering, Gautier 1997), as is the
augmented model's Drake torque. The noise floor of each joint is the raw torque's white-noise
level (median absolute second difference / √6 · 1.4826) times the filter's noise gain.
Without ``--validation`` the last ``holdout_fraction`` of the record is held out, with a gap
of 2 / cut-off between the two parts so the zero-phase filter does not leak across.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pe_drake.diagnosis.effects import (
    COULOMB_VELOCITY_SCALE,
    EXPOSING_REGIME,
    JOINT_EFFECTS,
    PRIOR_RELATIVE_UNCERTAINTY,
    Candidate,
)
from pe_drake.exceptions import ConfigError, DataError
from pe_drake.identification.measurements import Measurement

#: The nuisance column of a torque/position timing offset.
TIMING = "timing_offset"
#: Largest condition number of the (column-scaled) training regressor the diagnosis accepts
#: (optimized trajectories give about 10; above this some base parameters are barely excited
#: and effects cannot be told apart from them reliably).
MAX_COND = 1e4
#: Shortest part (training or held-out), in periods of the cut-off frequency: about 2 × this
#: many independent samples of filtered noise.
MIN_PERIODS = 10.0


@dataclasses.dataclass(frozen=True)
class DiagnosisConfig:
    """Options of the diagnosis (defaults are what the module docstring describes).

    Attributes:
        holdout_fraction: fraction of the record held out at its end when no validation file
            is given, in (0.05, 0.8).
        cutoff_hz: low-pass cut-off [Hz]; None: from the data's spectrum (preprocess).
        decimate_to_hz: rate of the samples fitted [Hz].
        coulomb_velocity_scale: v_s of tanh(v / v_s) [rad/s].
        effects: per-joint effects of the library to try.
        payload: look for a payload.
        timing_check: use the timing-offset nuisance column.
        alpha: family-wise probability of naming an effect that is not there.
        min_heldout_gain: relative held-out RMS reduction an effect must bring on its joint.
        min_effect_fraction: the held-out torque an effect explains (RMS) must reach this
            fraction of its joint's torque spread (std).
        noise_factor: multiples of the noise floor for relevance and for ``unexplained``.
        unexplained_fraction: a joint is unexplained when its held-out residual RMS exceeds
            this fraction of its torque spread (and ``noise_factor`` × its noise floor).
        resolution_fraction: torque resolution as a fraction of the largest joint's torque
            spread (1e-4: a 14-bit sensor); no joint is held to less, neither for relevance
            nor for ``unexplained`` (noise-free simulated data have no noise floor).
        prior_uncertainty: relative a-priori uncertainty of the inertial parameters.
        payload_alpha: false-alarm probability of the payload test.
        payload_min_prior_sigmas: a payload's mass must exceed this many a-priori standard
            deviations of its link's mass.
        max_effects: at most this many effects are named.
    """

    holdout_fraction: float = 0.3
    cutoff_hz: float | None = None
    decimate_to_hz: float = 200.0
    coulomb_velocity_scale: float = COULOMB_VELOCITY_SCALE  # [rad/s]
    effects: tuple[str, ...] = JOINT_EFFECTS
    payload: bool = True
    timing_check: bool = True
    alpha: float = 1e-3
    min_heldout_gain: float = 0.03
    min_effect_fraction: float = 0.001
    noise_factor: float = 3.0
    unexplained_fraction: float = 0.005
    resolution_fraction: float = 1e-4
    prior_uncertainty: float = PRIOR_RELATIVE_UNCERTAINTY
    payload_alpha: float = 1e-6
    payload_min_prior_sigmas: float = 3.0
    max_effects: int = 40

    def __post_init__(self) -> None:
        def check(name, value, lo, hi):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"diagnosis option {name} must be a number, got {value!r}")
            if not lo <= value <= hi:
                raise ConfigError(f"diagnosis option {name} = {value} is outside [{lo}, {hi}]")

        check("holdout_fraction", self.holdout_fraction, 0.05, 0.8)
        if self.cutoff_hz is not None:
            check("cutoff_hz [Hz]", self.cutoff_hz, 1e-3, 1e6)
        check("decimate_to_hz [Hz]", self.decimate_to_hz, 1.0, 1e6)
        check("coulomb_velocity_scale [rad/s]", self.coulomb_velocity_scale, 1e-6, 10.0)
        check("alpha", self.alpha, 1e-12, 0.5)
        check("min_heldout_gain", self.min_heldout_gain, 0.0, 0.9)
        check("min_effect_fraction", self.min_effect_fraction, 0.0, 1.0)
        check("noise_factor", self.noise_factor, 0.0, 100.0)
        check("unexplained_fraction", self.unexplained_fraction, 0.0, 1.0)
        check("resolution_fraction", self.resolution_fraction, 0.0, 0.1)
        check("prior_uncertainty", self.prior_uncertainty, 1e-3, 0.5)
        check("payload_alpha", self.payload_alpha, 1e-15, 0.5)
        check("payload_min_prior_sigmas", self.payload_min_prior_sigmas, 0.0, 100.0)
        check("max_effects", self.max_effects, 0, 1000)
        for e in self.effects:
            if e not in JOINT_EFFECTS:
                from pe_drake.exceptions import UnknownNameError

                raise UnknownNameError("effect", e, JOINT_EFFECTS, where="diagnosis effects")


# ---- data preparation ----------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class Record:
    """One measurement file at its full (uniform) rate after zero-phase filtering.

    Attributes:
        source: file name.
        t, q, v, vd, tau: filtered full-rate signals, (T,) and (T, n).
        sos: the Butterworth filter (second-order sections) applied to q and tau.
        rate_hz: full rate [Hz].
        cutoff_hz: cut-off [Hz].
        step: decimation step.
        trim_s: time dropped at each end [s].
        raw_noise: white-noise level of the raw torque per joint [N·m].
        noise_gain: noise power gain of the zero-phase filter.
        preprocessing: the choices made, as :class:`~pe_drake.identification.measurements.Preprocessing`.
        padlen: samples of odd extension at each end of the filter.
    """

    source: str
    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    vd: np.ndarray
    tau: np.ndarray
    sos: np.ndarray
    rate_hz: float
    cutoff_hz: float
    step: int
    trim_s: float
    raw_noise: np.ndarray
    noise_gain: float
    preprocessing: Any
    padlen: int

    def filtered(self, x: np.ndarray) -> np.ndarray:
        """The same zero-phase filter as the torque, along time (parallel filtering)."""
        from scipy.signal import sosfiltfilt

        return sosfiltfilt(self.sos, x, axis=0, padtype="odd", padlen=self.padlen)

    def usable(self) -> np.ndarray:
        """Indices of the decimated samples away from the filter's edge transients."""
        t = self.t
        keep = (t >= t[0] + self.trim_s - 1e-12) & (t <= t[-1] - self.trim_s + 1e-12)
        keep &= (np.arange(len(t)) % self.step) == 0
        return np.flatnonzero(keep)

    @property
    def noise_floor(self) -> np.ndarray:
        """Standard deviation of white torque noise after the filter, per joint [N·m]."""
        return self.raw_noise * math.sqrt(self.noise_gain)


def prepare_record(measurement: Measurement, config: DiagnosisConfig) -> Record:
    """Uniform grid, zero-phase filter, derivatives at the full rate (module docstring).

    The cut-off follows :func:`pe_drake.identification.measurements.preprocess` (``CUTOFF_FACTOR`` × the
    motion bandwidth, at least ``MIN_CUTOFF_HZ``, at most 0.4 × the rate). The filter runs
    forward and backward with an odd extension of 3 / cut-off at each end: a short extension
    leaves edge transients in the twice-differentiated acceleration that reach past the
    2 / cut-off trimmed at each end.

    Raises:
        DataError: too few samples for the filter, from the file named.
        ConfigError: a cut-off at or above the Nyquist frequency.
    """
    from scipy.signal import butter, sosfiltfilt

    from pe_drake.identification.measurements import Preprocessing
    from pe_drake.identification.preprocessing import (
        CUTOFF_FACTOR,
        MIN_CUTOFF_HZ,
        UNIFORM_TOLERANCE,
        motion_bandwidth_hz,
    )

    m = measurement
    if m.num_samples < 30:
        raise DataError(f"only {m.num_samples} samples; the diagnosis needs at least 30", file=m.source)
    dt_all = np.diff(m.t)
    dt = float(np.median(dt_all))
    resampled = float(np.max(np.abs(dt_all - dt))) > UNIFORM_TOLERANCE * dt
    signals = {"q": m.q, "tau": m.tau, "v": m.v}
    if resampled:
        count = int(math.floor((m.t[-1] - m.t[0]) / dt + 1e-9)) + 1
        t = m.t[0] + dt * np.arange(count)
        signals = {k: None if x is None else np.column_stack([np.interp(t, m.t, x[:, j]) for j in range(x.shape[1])])
                   for k, x in signals.items()}
    else:
        t = m.t.copy()
        dt = float((t[-1] - t[0]) / (len(t) - 1))
    rate = 1.0 / dt
    if config.cutoff_hz is not None:
        if config.cutoff_hz >= 0.5 * rate:
            raise ConfigError(f"cutoff_hz = {config.cutoff_hz:g} Hz is not below the Nyquist frequency "
                              f"{0.5 * rate:.4g} Hz of the data in '{m.source}'")
        cutoff, source = float(config.cutoff_hz), "argument"
    else:
        cutoff = min(max(CUTOFF_FACTOR * motion_bandwidth_hz(t, signals["q"]), MIN_CUTOFF_HZ), 0.4 * rate)
        source = "spectrum"
    order = 4
    sos = butter(order, cutoff, btype="low", fs=rate, output="sos")
    padlen = int(min(len(t) - 1, max(3 * (2 * len(sos) + 1), math.ceil(3.0 * rate / cutoff))))
    if len(t) < 4 * padlen:
        raise DataError(f"only {len(t)} samples at {rate:.4g} Hz: the record is too short for a "
                        f"{cutoff:.3g} Hz low-pass filter (at least {4 * padlen / rate:.3g} s)", file=m.source)

    def filt(x):
        return sosfiltfilt(sos, x, axis=0, padtype="odd", padlen=padlen)

    q, tau = filt(signals["q"]), filt(signals["tau"])
    v = filt(signals["v"]) if signals["v"] is not None else np.gradient(q, dt, axis=0)
    vd = np.gradient(v, dt, axis=0)
    step = 1
    if config.decimate_to_hz < rate:
        step = max(1, int(round(rate / config.decimate_to_hz)))
        while step > 1 and 0.5 * rate / step < 1.25 * cutoff:
            step -= 1
    trim = 2.0 / cutoff
    # White-noise level of the raw torque: second differences remove the smooth motion.
    d2 = np.diff(m.tau, n=2, axis=0)
    raw = 1.4826 * np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0) / math.sqrt(6.0)
    length = int(min(max(40 * rate / cutoff, 200), 200000))
    impulse = np.zeros(length)
    impulse[length // 2] = 1.0
    gain = float(np.sum(sosfiltfilt(sos, impulse) ** 2))
    info = Preprocessing(
        cutoff_hz=cutoff, cutoff_source=source, filter_order=order, input_rate_hz=1.0 / float(np.median(dt_all)),
        resampled=bool(resampled), rate_hz=rate / step, trim_s=trim,
        velocity_source="measured" if m.v is not None else "differentiated",
        acceleration_source="differentiated", samples_in=m.num_samples, samples_out=0)
    return Record(m.source, t, q, v, vd, tau, sos, rate, cutoff, step, trim, raw, gain, info, padlen)


@dataclasses.dataclass(frozen=True, eq=False)
class Segment:
    """Decimated samples of one record used for fitting or for held-out evaluation.

    Attributes:
        name: "training" or "held-out".
        record: the :class:`Record` the samples come from.
        idx: their indices into the record's full-rate arrays, (S,).
        coulomb: parallel-filtered Coulomb columns tanh(v/v_s) per joint, (S, n).
        dtau: time derivative of the filtered measured torque, (S, n) [N·m/s].
    """

    name: str
    record: Record
    idx: np.ndarray
    coulomb: np.ndarray
    dtau: np.ndarray

    @property
    def t(self) -> np.ndarray:
        return self.record.t[self.idx]

    @property
    def q(self) -> np.ndarray:
        return self.record.q[self.idx]

    @property
    def v(self) -> np.ndarray:
        return self.record.v[self.idx]

    @property
    def vd(self) -> np.ndarray:
        return self.record.vd[self.idx]

    @property
    def tau(self) -> np.ndarray:
        return self.record.tau[self.idx]

    @property
    def num_samples(self) -> int:
        return len(self.idx)

    @property
    def duration(self) -> float:
        t = self.t
        return float(t[-1] - t[0]) if len(t) else 0.0


def _segment(name: str, record: Record, idx: np.ndarray, coulomb_full: np.ndarray,
             dtau_full: np.ndarray) -> Segment:
    return Segment(name, record, idx, coulomb_full[idx], dtau_full[idx])


def split_segments(record: Record, config: DiagnosisConfig, validation: Record | None = None,
                   ) -> tuple[Segment, Segment]:
    """Training and held-out segments (module docstring).

    Raises:
        DataError: a part too short to be used.
    """
    columns = {}
    for rec in (record, validation):
        if rec is None:
            continue
        coulomb = rec.filtered(np.tanh(rec.v / config.coulomb_velocity_scale))
        dtau = np.gradient(rec.tau, 1.0 / rec.rate_hz, axis=0)
        columns[id(rec)] = (coulomb, dtau)
    usable = record.usable()
    if validation is None:
        t = record.t
        split = t[0] + (1.0 - config.holdout_fraction) * (t[-1] - t[0])
        gap = record.trim_s / 2
        train = usable[t[usable] < split - gap]
        held = usable[t[usable] > split + gap]
        training = _segment("training", record, train, *columns[id(record)])
        held_out = _segment("held-out", record, held, *columns[id(record)])
    else:
        training = _segment("training", record, usable, *columns[id(record)])
        held_out = _segment("held-out", validation, validation.usable(), *columns[id(validation)])
    for seg in (training, held_out):
        if seg.num_samples < 20 or seg.duration < MIN_PERIODS / seg.record.cutoff_hz:
            raise DataError(
                f"the {seg.name} part is {seg.duration:.3g} s long ({seg.num_samples} samples) after "
                f"filtering and trimming {seg.record.trim_s:.3g} s at each end; it needs at least "
                f"{MIN_PERIODS / seg.record.cutoff_hz:.3g} s ({MIN_PERIODS:g} periods of the "
                f"{seg.record.cutoff_hz:.3g} Hz cut-off): record a longer run"
                + (" or lower the held-out fraction" if validation is None else ""),
                file=seg.record.source,
            )
    return training, held_out


# ---- regression with the library -----------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class _Columns:
    """Every column of one segment: base regressor, candidates, timing nuisance."""

    A: np.ndarray  # (S, n, P)
    y: np.ndarray  # (S, n) target: the measured torque
    gram: np.ndarray  # (n, P, P) per-joint A_jᵀ A_j
    rhs: np.ndarray  # (n, P) per-joint A_jᵀ y_j
    yy: np.ndarray  # (n,) per-joint y_jᵀ y_j
    count: int  # S


def _columns(Y_B: np.ndarray, extra: np.ndarray, y: np.ndarray) -> _Columns:
    A = np.concatenate([Y_B, extra], axis=2)
    gram = np.einsum("sjp,sjq->jpq", A, A, optimize=True)
    rhs = np.einsum("sjp,sj->jp", A, y, optimize=True)
    yy = np.einsum("sj,sj->j", y, y)
    return _Columns(A, y, gram, rhs, yy, y.shape[0])


@dataclasses.dataclass(frozen=True, eq=False)
class Fit:
    """A weighted least-squares fit of the base parameters and some library columns.

    Attributes:
        columns: indices of the fitted columns (base parameters first).
        x: their values, shape (len(columns),).
        cov: their covariance (sandwich, autocorrelation-inflated).
        rms_train: per-joint RMS residual on the training segment.
        rms_held: per-joint RMS residual on the held-out segment.
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


class _Regression:
    """Fits of subsets of columns from per-joint Gram matrices (fast repeated refits)."""

    def __init__(self, train: _Columns, held: _Columns, num_base: int):
        self.train = train
        self.held = held
        self.num_base = num_base
        n = train.gram.shape[0]
        self.weights = np.ones(n)
        self.inflation = np.ones(n)  # integrated autocorrelation time per joint
        self.scale = np.ones(train.gram.shape[1])

    def set_weights(self, weights: np.ndarray) -> None:
        self.weights = np.asarray(weights, float)

    def fit(self, extra: Sequence[int]) -> Fit:
        cols = list(range(self.num_base)) + [int(c) for c in extra]
        w2 = self.weights**2
        Gj = self.train.gram[:, cols][:, :, cols]
        G = np.einsum("j,jpq->pq", w2, Gj)
        g = np.einsum("j,jp->p", w2, self.train.rhs[:, cols])
        d = np.sqrt(np.maximum(np.diag(G), 1e-300))
        Gs = G / np.outer(d, d)
        try:
            Hinv = np.linalg.inv(Gs)
        except np.linalg.LinAlgError:
            Hinv = np.linalg.pinv(Gs)
        x = (Hinv @ (g / d)) / d
        Hinv = Hinv / np.outer(d, d)
        rss_tr = self._rss(self.train, cols, x)
        rss_ho = self._rss(self.held, cols, x)
        S_tr, S_ho = self.train.count, self.held.count
        var_j = np.maximum(rss_tr, 0.0) / max(S_tr - len(cols) / len(w2), 1.0)
        # Sandwich: Var x = H⁻¹ (Σ_j w_j⁴ s_j τ_j G_j) H⁻¹ with s_j the joint's residual variance.
        meat = np.einsum("j,jpq->pq", w2**2 * var_j * self.inflation, Gj)
        cov = Hinv @ meat @ Hinv
        return Fit(tuple(cols), x, cov, np.sqrt(np.maximum(rss_tr, 0) / S_tr),
                   np.sqrt(np.maximum(rss_ho, 0) / S_ho), float(np.sum(w2 * rss_ho)))

    @staticmethod
    def _rss(c: _Columns, cols: list[int], x: np.ndarray) -> np.ndarray:
        G = c.gram[:, cols][:, :, cols]
        r = c.rhs[:, cols]
        return c.yy - 2 * r @ x + np.einsum("p,jpq,q->j", x, G, x)

    def residual(self, which: str, fit: Fit) -> np.ndarray:
        c = self.train if which == "training" else self.held
        return c.y - c.A[:, :, list(fit.columns)] @ fit.x

    def contribution_rms(self, which: str, fit: Fit, column: int) -> np.ndarray:
        """Per-joint RMS of one column's torque θ·c in a segment."""
        c = self.train if which == "training" else self.held
        k = fit.columns.index(column)
        return np.abs(fit.x[k]) * np.sqrt(c.gram[:, column, column] / c.count)


def integrated_autocorrelation(r: np.ndarray, max_lag_fraction: float = 0.1) -> np.ndarray:
    """τ_int = 1 + 2 Σ ρ_k per column, summed while ρ_k > 0 (initial positive sequence).

    Args:
        r: residuals, (S, n).

    Returns:
        (n,), ≥ 1: the factor by which correlated samples inflate a variance.
    """
    S = r.shape[0]
    x = r - r.mean(axis=0)
    f = np.fft.rfft(x, n=2 * S, axis=0)
    ac = np.fft.irfft(f * np.conj(f), axis=0)[:S]
    out = np.ones(r.shape[1])
    max_lag = max(1, int(max_lag_fraction * S))
    for j in range(r.shape[1]):
        if ac[0, j] <= 0:
            continue
        rho = ac[1 : max_lag + 1, j] / ac[0, j]
        neg = np.flatnonzero(rho <= 0)
        stop = neg[0] if neg.size else len(rho)
        out[j] = 1.0 + 2.0 * float(np.sum(rho[:stop]))
    return np.clip(out, 1.0, S / 2.0)


# ---- result types ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class NamedEffect:
    """An effect the diagnosis names.

    Attributes:
        effect: ``coulomb_friction``, ``viscous_friction``, ``armature``, ``torque_offset`` or
            ``payload``.
        joint: the joint (per-joint effects) or "" (payload).
        link: the link (payload) or "".
        value: identified value in ``unit`` (payload: the added mass).
        unit: unit of ``value``.
        std: its standard deviation (autocorrelation-inflated).
        z: |value| / std of the fitted increment (per-joint effects) or the mass (payload).
        heldout_rms_before: per-joint held-out RMS before the effect was added [N·m].
        heldout_rms_after: the same after.
        details: effect-specific extras (payload centre of mass, welded bodies, χ² values).
    """

    effect: str
    joint: str
    link: str
    value: float
    unit: str
    std: float
    z: float
    heldout_rms_before: dict[str, float]
    heldout_rms_after: dict[str, float]
    details: dict[str, Any]

    def as_dict(self) -> dict[str, Any]:
        out = {"effect": self.effect}
        if self.joint:
            out["joint"] = self.joint
        if self.link:
            out["link"] = self.link
        out.update(value=self.value, unit=self.unit, std=self.std, z=self.z,
                   heldout_rms_before=self.heldout_rms_before, heldout_rms_after=self.heldout_rms_after,
                   **self.details)
        return out


@dataclasses.dataclass(frozen=True, eq=False)
class DiagnosisResult:
    """Everything the diagnosis found (JSON via :meth:`to_json_dict`).

    Attributes:
        robot: robot name.
        joints: excited joints.
        config: the :class:`DiagnosisConfig` used.
        training, held_out: the two :class:`Segment`s.
        effects: the :class:`NamedEffect`s, in the order they were selected (payload last).
        rms_nominal, rms_rigid, rms_after: per-joint held-out RMS [N·m] of the a-priori model,
            after rigid-body re-identification, and of the augmented Drake model.
        cumulative: [(step label, per-joint held-out RMS)] nominal → rigid → each effect.
        unexplained: {joint: details} of joints the effects do not explain.
        not_separable: effects that cannot be told apart from rigid-body terms.
        rejected: the strongest candidates that were not named, with the reason.
        regimes: nominal residual per joint and regime.
        rigid: the rigid-body step's base parameters against the a-priori model.
        payload_test: the payload search (best link, χ² values, decision).
        timing: the timing-offset nuisance (estimated offset [s], whether it was needed).
        predictions: held-out torques {"measured", "nominal", "rigid", "after"}, each (S, n).
        residual_series: held-out residuals before/after each named effect, for plots.
        augmented: the :class:`~pe_drake.diagnosis.augmented_model.AugmentedModel`.
        drake_check: max |Drake augmented torque - least-squares prediction| per joint [N·m].
        timings: wall time per step [s].
    """

    robot: str
    joints: tuple[str, ...]
    config: DiagnosisConfig
    training: Segment
    held_out: Segment
    effects: list[NamedEffect]
    rms_nominal: np.ndarray
    rms_rigid: np.ndarray
    rms_after: np.ndarray
    cumulative: list[tuple[str, np.ndarray]]
    unexplained: dict[str, dict[str, Any]]
    not_separable: list[dict[str, Any]]
    rejected: list[dict[str, Any]]
    regimes: dict[str, Any]
    rigid: dict[str, Any]
    payload_test: dict[str, Any]
    timing: dict[str, Any]
    predictions: dict[str, np.ndarray]
    residual_series: dict[str, Any]
    augmented: Any
    drake_check: np.ndarray
    timings: dict[str, float]
    noise_floor: np.ndarray
    thresholds: np.ndarray

    def per_joint(self, x: np.ndarray) -> dict[str, float]:
        return {j: float(v) for j, v in zip(self.joints, x)}

    def to_json_dict(self) -> dict[str, Any]:
        """The content of diagnosis.json."""
        rec_tr, rec_ho = self.training.record, self.held_out.record
        return {
            "robot": self.robot,
            "joints": list(self.joints),
            "units": {"torque": "N·m (N for prismatic joints)", "rms": "N·m"},
            "data": {
                "training": _segment_info(self.training),
                "held_out": _segment_info(self.held_out),
                "validation_file": rec_ho.source if rec_ho is not rec_tr else None,
                "cutoff_hz": rec_tr.cutoff_hz,
                "full_rate_hz": rec_tr.rate_hz,
                "fitted_rate_hz": rec_tr.rate_hz / rec_tr.step,
            },
            "effects": [e.as_dict() for e in self.effects],
            "rms_nominal": self.per_joint(self.rms_nominal),
            "rms_rigid": self.per_joint(self.rms_rigid),
            "rms_after": self.per_joint(self.rms_after),
            "gap_closed": {
                j: _closed(a, b, c) for j, a, b, c in zip(self.joints, self.rms_nominal, self.rms_rigid,
                                                           self.rms_after)
            },
            "cumulative": [{"step": s, "rms": self.per_joint(r)} for s, r in self.cumulative],
            "unexplained": self.unexplained,
            "noise_floor": self.per_joint(self.noise_floor),
            "unexplained_threshold": self.per_joint(self.thresholds),
            "not_separable": self.not_separable,
            "rejected": self.rejected,
            "regimes": self.regimes,
            "rigid": self.rigid,
            "payload_test": self.payload_test,
            "timing": self.timing,
            "drake_check_max_abs": self.per_joint(self.drake_check),
            "config": {k: (list(v) if isinstance(v, tuple) else v)
                       for k, v in dataclasses.asdict(self.config).items()},
            "timings_s": self.timings,
        }


def _closed(nominal: float, rigid: float, after: float) -> dict[str, float]:
    """Fractions of the nominal held-out mean-square gap closed by each stage."""
    if nominal <= 0:
        return {"rigid": 0.0, "total": 0.0}
    return {"rigid": float(1 - (rigid / nominal) ** 2), "total": float(1 - (after / nominal) ** 2)}


def _segment_info(seg: Segment) -> dict[str, Any]:
    return {"file": seg.record.source, "t_start": float(seg.t[0]), "t_end": float(seg.t[-1]),
            "samples": seg.num_samples}


# ---- the workflow ---------------------------------------------------------------------------


def diagnose(
    robot,
    data: Measurement,
    validation: Measurement | None = None,
    config: DiagnosisConfig | None = None,
    progress: Callable[[str], None] | None = None,
) -> DiagnosisResult:
    """Runs the five steps of the module docstring.

    Args:
        robot: the a-priori :class:`~pe_drake.multibody.robot.Robot`.
        data: the measured run (raw, as read by
            :func:`~pe_drake.identification.measurements.read_measurement_csv`).
        validation: another run to hold out; None: the last ``holdout_fraction`` of ``data``.
        config: options (:class:`DiagnosisConfig`).
        progress: called with one line per step (e.g. ``print``).

    Returns:
        The :class:`DiagnosisResult`.

    Raises:
        DataError: joints that differ from the robot's, a run too short, torques in the
            wrong units (naming the file and column).
    """
    from pe_drake.diagnosis.augmented_model import AugmentedModel, augmented_torque, build_augmented_robot
    from pe_drake.diagnosis.effects import joint_candidates, separability
    from pe_drake.identification.measurements import check_torque_units
    from pe_drake.multibody.base_parameters import compute_base_parameters
    from pe_drake.multibody.regressor import RegressorModel

    config = config or DiagnosisConfig()
    say = progress or (lambda _msg: None)
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(name):
        nonlocal clock
        now = time.perf_counter()
        timings[name] = round(now - clock, 3)
        clock = now

    for m in (data, validation):
        if m is not None and tuple(m.joints) != tuple(robot.joint_names):
            raise DataError(
                f"the data's joints {', '.join(m.joints)} differ from robot '{robot.name}''s excited "
                f"joints {', '.join(robot.joint_names)}", file=m.source)
    n = robot.n
    joints = robot.joint_names

    # -- preparation
    record = prepare_record(data, config)
    vrecord = prepare_record(validation, config) if validation is not None else None
    training, held = split_segments(record, config, vrecord)
    say(f"data: {record.source}: {data.num_samples} samples at {record.rate_hz:.4g} Hz, cut-off "
        f"{record.cutoff_hz:.3g} Hz, fitted at {record.rate_hz / record.step:.4g} Hz; training "
        f"{training.t[0]:.2f}-{training.t[-1]:.2f} s, held-out "
        f"{held.t[0]:.2f}-{held.t[-1]:.2f} s" + (f" of {vrecord.source}" if vrecord else ""))
    model = RegressorModel(robot)
    base = compute_base_parameters(robot, model=model)
    Y_tr = base.reduce(model(training.q, training.v, training.vd))
    Y_ho = base.reduce(model(held.q, held.v, held.vd))
    phi_B_prior = base.base_values(robot.phi_model)
    damping = robot.joint_damping
    if training.num_samples * n < 3 * (base.count + 4 * n):
        raise DataError(
            f"{training.num_samples} training samples × {n} joints are too few for {base.count} base "
            f"parameters and {4 * n} effect candidates; record a longer run", file=record.source)
    lap("prepare")

    # -- 1. nominal
    tau_nom_tr = Y_tr @ phi_B_prior + damping * training.v
    tau_nom_ho = Y_ho @ phi_B_prior + damping * held.v
    for seg, pred in ((training, tau_nom_tr), (held, tau_nom_ho)):
        check_torque_units(Measurement(seg.t, seg.q, seg.tau, None, None, joints, seg.record.source), pred)
    rms_nominal = _rms(held.tau - tau_nom_ho)
    res_nom = {"training": training.tau - tau_nom_tr, "held-out": held.tau - tau_nom_ho}
    regimes = regime_analysis(
        np.concatenate([res_nom["training"], res_nom["held-out"]]),
        np.concatenate([training.q, held.q]), np.concatenate([training.v, held.v]),
        np.concatenate([training.vd, held.vd]), np.concatenate([training.t, held.t]), joints)
    say("1. a-priori model, held-out RMS [N·m]: " + _fmt_joints(joints, rms_nominal))
    lap("nominal")

    # -- candidate columns
    candidates = joint_candidates(robot, config.effects)
    sep = separability(robot, base, candidates, model=model)
    usable = [s.candidate for s in sep if s.separable]
    labels = [c.label for c in usable]

    def extra_columns(seg: Segment) -> np.ndarray:
        cols = np.zeros((seg.num_samples, n, len(usable) + 1))
        for k, c in enumerate(usable):
            if c.effect == "coulomb_friction":
                cols[:, c.joint, k] = seg.coulomb[:, c.joint]
            else:
                from pe_drake.diagnosis.effects import effect_column

                cols[:, c.joint, k] = effect_column(c.effect, seg.q, seg.v, seg.vd, c.joint)
        cols[:, :, -1] = -seg.dtau  # timing nuisance: tau_rec(t) ≈ tau(t) - d·dtau/dt
        return cols

    b = base.count
    reg = _Regression(
        _columns(Y_tr, extra_columns(training), training.tau),
        _columns(Y_ho, extra_columns(held), held.tau),
        b,
    )
    cond = _condition_number(reg.train.gram[:, :b, :b].sum(axis=0))
    if cond > MAX_COND:
        raise DataError(
            f"the training part ({training.duration:.3g} s) does not excite every base parameter: the "
            f"condition number of its regressor is {cond:.3g} (> {MAX_COND:.0e}); record a longer or more "
            "exciting run (pe-drake optimize)", file=record.source)
    timing_col = b + len(usable)
    col_of = {lab: b + k for k, lab in enumerate(labels)}
    cand_of = {b + k: c for k, c in enumerate(usable)}

    # -- 2. rigid-body re-identification (WLS with Gautier's per-joint weights)
    ols = reg.fit([])
    noise_floor = held.record.noise_floor
    spread_tr = np.std(training.tau, axis=0)
    sigma = np.maximum(ols.rms_train, np.maximum(training.record.noise_floor, 1e-6 * spread_tr + 1e-12))
    reg.set_weights(1.0 / sigma)
    reg.inflation = integrated_autocorrelation(reg.residual("training", ols))
    rigid = reg.fit([])
    rms_rigid = rigid.rms_held
    reg.inflation = integrated_autocorrelation(reg.residual("training", rigid))
    say("2. rigid-body parameters re-identified, held-out RMS [N·m]: " + _fmt_joints(joints, rms_rigid))
    lap("rigid")

    # -- 3. effects: forward selection, backward check
    spread_ho = np.std(held.tau, axis=0)
    resolution = config.resolution_fraction * float(np.max(spread_ho))
    relevance = np.maximum.reduce([config.noise_factor * noise_floor, config.min_effect_fraction * spread_ho,
                                   np.full(n, resolution)])
    num_tests = len(usable) + 1
    z_min = _z_two_sided(config.alpha / num_tests)
    selected: list[int] = []
    current = rigid
    order: list[int] = []
    rejected: dict[int, str] = {}
    pool = list(col_of.values()) + ([timing_col] if config.timing_check else [])
    while len([c for c in selected if c != timing_col]) < config.max_effects:
        best, best_fit, best_gain = None, None, 0.0
        for col in pool:
            if col in selected:
                continue
            fit = reg.fit(selected + [col])
            ok, reason = _accept(col, fit, current, reg, cand_of, timing_col, damping, z_min, relevance,
                                 config)
            if not ok:
                rejected[col] = reason
                continue
            gain = current.wrss_held - fit.wrss_held
            if gain > best_gain:
                best, best_fit, best_gain = col, fit, gain
        if best is None:
            break
        selected.append(best)
        order.append(best)
        rejected.pop(best, None)
        current = best_fit
        reg.inflation = integrated_autocorrelation(reg.residual("training", current))
        say(f"3. + {_col_label(best, cand_of, timing_col)}: held-out RMS [N·m] "
            + _fmt_joints(joints, current.rms_held))
    # Backward check: every named effect must still be plausible and significant with the others.
    while selected:
        worst, worst_z = None, np.inf
        for col in selected:
            value = current.value(col)
            z = abs(value) / max(current.std(col), 1e-300)
            if col in cand_of and cand_of[col].nonnegative and value < 0:
                z = -1.0
            if z < z_min and z < worst_z:
                worst, worst_z = col, z
        if worst is None:
            break
        selected.remove(worst)
        rejected[worst] = f"dropped in the backward check (z = {worst_z:.2g} < {z_min:.2g} with the others)"
        current = reg.fit(selected)
        say(f"3. - {_col_label(worst, cand_of, timing_col)} (no longer significant)")
    order = [c for c in order if c in selected]
    final = current
    lap("effects")

    # cumulative table (without the timing nuisance: it is not part of the model)
    cumulative = [("nominal", rms_nominal), ("rigid", rms_rigid)]
    effect_cols = [c for c in order if c != timing_col]
    fits_cum = [rigid]
    for k in range(len(effect_cols)):
        f = reg.fit(effect_cols[: k + 1])
        fits_cum.append(f)
        cumulative.append((f"+ {_col_label(effect_cols[k], cand_of, timing_col)}", f.rms_held))
    # fits with everything but one effect, for the before/after plots of that effect
    named: list[NamedEffect] = []
    residual_series: dict[str, Any] = {"effects": []}
    res_final = reg.residual("held-out", reg.fit(effect_cols))
    for k, col in enumerate(effect_cols):
        c = cand_of[col]
        without = reg.fit([x for x in effect_cols if x != col])
        value = final.value(col)
        std = final.std(col)
        shown = value
        details: dict[str, Any] = {"contribution_rms": float(reg.contribution_rms("held-out", final, col)[c.joint])}
        if c.effect == "viscous_friction":
            details["model_file_damping"] = float(damping[c.joint])
        if c.effect == "coulomb_friction":
            details["velocity_scale"] = config.coulomb_velocity_scale
        named.append(NamedEffect(
            c.effect, c.joint_name, "", float(shown), c.unit, float(std), float(abs(value) / max(std, 1e-300)),
            _pj(joints, fits_cum[k].rms_held), _pj(joints, fits_cum[k + 1].rms_held), details))
        residual_series["effects"].append({
            "label": c.label, "effect": c.effect, "joint": c.joint, "regime": EXPOSING_REGIME[c.effect],
            "before": reg.residual("held-out", without)[:, c.joint],
            "after": res_final[:, c.joint],
        })
    # candidates that were close: the reason they were not named (strongest first)
    rejected_list = []
    for col, reason in rejected.items():
        if col == timing_col or col in selected:
            continue
        c = cand_of[col]
        f = reg.fit(selected + [col])
        z = abs(f.value(col)) / max(f.std(col), 1e-300)
        rejected_list.append({"effect": c.effect, "joint": c.joint_name, "value": f.value(col),
                              "unit": c.unit, "z": float(z), "reason": reason})
    rejected_list.sort(key=lambda r: -r["z"])
    rejected_list = rejected_list[:12]

    # -- payload and the rigid-body report (from the final fit's base parameters)
    from pe_drake.diagnosis.effects import prior_parameter_covariance

    phi_B = final.x[:b]
    cov_B = final.cov[:b, :b]
    Sigma_phi = prior_parameter_covariance(robot, config.prior_uncertainty)
    C = base.K @ Sigma_phi @ base.K.T + cov_B
    delta_B = phi_B - phi_B_prior
    payload_test, payload_effect, payload_phi = (
        _payload_search(robot, base, delta_B, C, Sigma_phi, config, joints, reg, fits_cum[-1], b)
        if config.payload else ({"searched": False}, None, None))
    if payload_effect is not None:
        named.append(payload_effect)
        say(f"3. payload on {payload_effect.link}: {payload_effect.value:+.3g} kg "
            f"(χ² {payload_test['chi2_before']:.3g} → {payload_test['chi2_after']:.3g})")
    rigid_report = _rigid_report(base, phi_B, phi_B_prior, C, cov_B, base.K @ Sigma_phi @ base.K.T)
    not_separable = _not_separable(sep, base, delta_B, base.K @ Sigma_phi @ base.K.T, damping)
    lap("payload")

    # -- 4. augmented model in Drake
    values = {col: final.value(col) for col in effect_cols}
    augmented = AugmentedModel.from_fit(robot, base, phi_B, Sigma_phi, payload_phi,
                                        {cand_of[c].label: (cand_of[c], v) for c, v in values.items()},
                                        config.coulomb_velocity_scale,
                                        payload_effect.link if payload_effect is not None else None,
                                        cov_B=cov_B)
    true = build_augmented_robot(robot, augmented)
    # Drake's torque at the held-out samples, its Coulomb term filtered like the measured torque
    # (the parallel-filtered column; the rest of the torque is smooth within the pass band).
    tau_after = augmented_torque(true, augmented, held.q, held.v, held.vd)
    tau_after += augmented.coulomb * (held.coulomb - np.tanh(held.v / config.coulomb_velocity_scale))
    rms_after = _rms(held.tau - tau_after)
    # the least-squares prediction with the final values (timing nuisance left out)
    keep = [k for k, c in enumerate(final.columns) if c != timing_col]
    ls_pred = reg.held.A[:, :, [final.columns[k] for k in keep]] @ final.x[keep]
    drake_check = np.max(np.abs(tau_after - ls_pred), axis=0)
    say("4. augmented Drake model, held-out RMS [N·m]: " + _fmt_joints(joints, rms_after))
    lap("augmented")

    # -- 5. unexplained
    thresholds = np.maximum.reduce([config.noise_factor * noise_floor, config.unexplained_fraction * spread_ho,
                                    np.full(n, resolution)])
    residual_after = held.tau - tau_after
    timing = {"checked": config.timing_check}
    if timing_col in selected:
        timing.update(offset_s=final.value(timing_col), std_s=final.std(timing_col), needed=True,
                      convention="positive: the torque log lags the positions")
    else:
        f = reg.fit(selected + [timing_col])
        timing.update(offset_s=f.value(timing_col), std_s=f.std(timing_col), needed=False,
                      reason=rejected.get(timing_col, ""))
    unexplained = _unexplained(residual_after, held, thresholds, noise_floor, rms_nominal, joints, timing)
    if unexplained:
        say("5. unexplained: " + ", ".join(f"{j} {u['rms']:.3g} N·m" for j, u in unexplained.items()))
    else:
        say("5. nothing left unexplained above the thresholds")
    lap("unexplained")

    residual_series["nominal"] = res_nom["held-out"]
    residual_series["rigid"] = reg.residual("held-out", rigid)
    residual_series["after"] = residual_after
    predictions = {"t": held.t, "measured": held.tau, "nominal": tau_nom_ho,
                   "rigid": held.tau - residual_series["rigid"], "after": tau_after}
    return DiagnosisResult(
        robot.name, joints, config, training, held, named, rms_nominal, rms_rigid, rms_after,
        cumulative, unexplained, not_separable, rejected_list, regimes, rigid_report, payload_test,
        timing, predictions, residual_series, augmented, drake_check, timings, noise_floor, thresholds)


def _accept(col, fit: Fit, current: Fit, reg: _Regression, cand_of, timing_col, damping, z_min,
            relevance, config) -> tuple[bool, str]:
    """Criteria (a)-(d) of the module docstring for adding one column."""
    value, std = fit.value(col), fit.std(col)
    z = abs(value) / max(std, 1e-300)
    if col == timing_col:
        if z < z_min:
            return False, f"not significant (z = {z:.2g} < {z_min:.2g})"
        if fit.wrss_held > (1 - config.min_heldout_gain) ** 2 * current.wrss_held:
            return False, "held-out gain too small"
        explained = np.sqrt(np.maximum(current.rms_held**2 - fit.rms_held**2, 0.0))
        if not np.any(explained >= relevance):
            return False, "explains too little on every joint"
        return True, ""
    c: Candidate = cand_of[col]
    j = c.joint
    if c.nonnegative and value < 0:
        return False, f"physically implausible sign ({value:.3g} {c.unit})"
    if z < z_min:
        return False, f"not significant (z = {z:.2g} < {z_min:.2g})"
    if fit.rms_held[j] > (1 - config.min_heldout_gain) * current.rms_held[j]:
        return False, (f"held-out RMS of {c.joint_name} only {current.rms_held[j]:.4g} → "
                       f"{fit.rms_held[j]:.4g} N·m")
    if fit.wrss_held >= current.wrss_held:
        return False, "held-out residual of the other joints grows"
    explained = math.sqrt(max(current.rms_held[j] ** 2 - fit.rms_held[j] ** 2, 0.0))
    if explained < relevance[j]:
        return False, f"explains too little ({explained:.3g} < {relevance[j]:.3g} N·m RMS on held-out data)"
    return True, ""


def _payload_search(robot, base, delta_B, C, Sigma_phi, config, joints, reg, fit_last, b):
    """The payload test of the module docstring. Returns (report, NamedEffect or None, Δφ_L)."""
    from pe_drake.diagnosis.effects import chi2, chi2_quantile, fit_payload, payload_groups

    chi2_0 = chi2(delta_B, C)
    groups = payload_groups(robot, base)
    report: dict[str, Any] = {"searched": True, "chi2_before": chi2_0, "dof": int(base.count),
                              "prior_uncertainty": config.prior_uncertainty, "links": []}
    best = None
    fits = []
    for j, lead, group in groups:
        K_L = base.K[:, 10 * lead : 10 * lead + 10]
        x, cov, chi2_after = fit_payload(delta_B, C, K_L)
        rank = int(np.linalg.matrix_rank(K_L, 1e-9))
        m, m_std = float(x[0]), math.sqrt(max(float(cov[0, 0]), 0.0))
        idx = [10 * k for k, name in enumerate(robot.body_names) if name in group]
        m_prior_std = math.sqrt(max(float(Sigma_phi[np.ix_(idx, idx)].sum()), 0.0))
        entry = {"link": robot.body_names[lead], "joint": joints[j], "chi2_after": chi2_after,
                 "gain": chi2_0 - chi2_after, "rank": rank, "mass": m, "mass_std": m_std,
                 "mass_prior_std": m_prior_std}
        report["links"].append(entry)
        fits.append((entry, x, cov, lead, group, j))
        if best is None or entry["gain"] > best[0]["gain"]:
            best = fits[-1]
    if best is None:
        report["decision"] = "no link where an added mass is identifiable"
        return report, None, None
    # Links whose fit is as good within χ²₁(95 %) explain the change equally well (a mass on
    # the axis of joint k moves the same whether it rides on link k or on the link before):
    # name the most distal one, where payloads are carried, and list the others.
    tie = best[0]["gain"] - chi2_quantile(0.95, 1)
    equivalent = [c for c in fits if c[0]["gain"] >= tie]
    best = max(equivalent, key=lambda c: c[5])
    entry, x, cov, lead, group, j = best
    report["equivalent_links"] = [c[0]["link"] for c in equivalent if c is not best]
    gain_needed = chi2_quantile(1 - config.payload_alpha, entry["rank"])
    rest_allowed = chi2_quantile(0.999, base.count - entry["rank"])
    report.update(best_link=entry["link"], gain_needed=gain_needed, rest_allowed=rest_allowed,
                  chi2_after=entry["chi2_after"])
    reasons = []
    if entry["gain"] < gain_needed:
        reasons.append(f"χ² gain {entry['gain']:.3g} < {gain_needed:.3g}")
    if abs(entry["mass"]) < config.payload_min_prior_sigmas * entry["mass_prior_std"]:
        reasons.append(f"mass change {entry['mass']:+.3g} kg within {config.payload_min_prior_sigmas:g} "
                       f"a-priori σ ({entry['mass_prior_std']:.3g} kg)")
    if abs(entry["mass"]) < 3 * entry["mass_std"]:  # detection is the χ² test; this says it is a mass
        reasons.append(f"mass change {entry['mass']:+.3g} ± {entry['mass_std']:.2g} kg not significant")
    if entry["chi2_after"] > rest_allowed:
        reasons.append(f"not localized: χ² left {entry['chi2_after']:.3g} > {rest_allowed:.3g} (the "
                       "rest of the model also differs from the a-priori one)")
    if reasons:
        report["decision"] = "no payload: " + "; ".join(reasons)
        return report, None, None
    m = float(x[0])
    com = (x[1:4] / m).tolist()
    report["decision"] = f"payload on {entry['link']}"
    eff = NamedEffect(
        "payload", "", entry["link"], m, "kg", entry["mass_std"], abs(m) / max(entry["mass_std"], 1e-300),
        _pj(joints, fit_last.rms_held), _pj(joints, fit_last.rms_held),
        {"com": com, "com_unit": "m, in the link frame", "rigidly_attached": list(group),
         "equally_well_on": report["equivalent_links"],
         "delta_phi": x.tolist(), "chi2_before": report["chi2_before"], "chi2_after": entry["chi2_after"],
         "mass_prior_std": entry["mass_prior_std"],
         "note": ("a negative mass: the a-priori model carries more mass on this link than measured "
                  "(a tool or hand in the model but not on the robot?)") if m < 0 else
                 "the rigid-body step already fits it; the augmented model carries it as a welded body"})
    return report, eff, x


def _rigid_report(base, phi_B, phi_B_prior, C, cov_B, C_prior) -> dict[str, Any]:
    sd_prior = np.sqrt(np.maximum(np.diag(C_prior), 0))
    sd_est = np.sqrt(np.maximum(np.diag(cov_B), 0))
    z = (phi_B - phi_B_prior) / np.maximum(np.sqrt(np.diag(C)), 1e-300)
    order = np.argsort(-np.abs(z))
    rows = [{"name": base.base_names[k], "prior": float(phi_B_prior[k]), "identified": float(phi_B[k]),
             "std": float(sd_est[k]), "prior_std": float(sd_prior[k]), "z_vs_prior": float(z[k])}
            for k in order]
    return {"count": base.count, "base_parameters": rows,
            "max_abs_z_vs_prior": float(np.abs(z).max()) if z.size else 0.0}


def _not_separable(sep, base, delta_B, C_prior, damping) -> list[dict[str, Any]]:
    out = []
    names = list(base.base_names)
    for s in sep:
        if s.separable:
            continue
        c = s.candidate
        entry: dict[str, Any] = {"effect": c.effect, "joint": c.joint_name,
                                 "merged_with": s.merged_with, "unit": c.unit}
        if s.merged_with:
            # The column is Σ_k β_k (column of base parameter k): the effect's value θ moves
            # those base parameters by θ β_k. θ if the whole change were this effect: the
            # least-squares fit of Δφ_B on β over those parameters, weighted by the prior.
            idx = [names.index(name) for name in s.merged_with]
            beta = np.array(list(s.merged_with.values()))
            sd = np.sqrt(np.maximum(np.diag(C_prior)[idx], 1e-300))
            w = 1.0 / sd**2
            theta = float(np.sum(w * beta * delta_B[idx]) / np.sum(w * beta**2))
            theta_sd = float(1.0 / np.sqrt(np.sum(w * beta**2)))
            entry.update(base_parameter_change={n: float(delta_B[k]) for n, k in zip(s.merged_with, idx)},
                         prior_std={n: float(x) for n, x in zip(s.merged_with, sd)},
                         implied_value_if_all=theta, implied_value_prior_std=theta_sd,
                         z_vs_prior=theta / theta_sd,
                         note="only its sum with the base parameter(s) it merges with is identifiable: the "
                              "change is reported with the rigid-body step, not named as this effect")
        out.append(entry)
    return out


def _unexplained(residual, held: Segment, thresholds, noise_floor, rms_nominal, joints, timing):
    out = {}
    rms = _rms(residual)
    t = held.t
    signals = {"sign(v)": np.sign(held.v), "v": held.v, "vd": held.vd, "q": held.q,
               "dtau/dt": held.dtau, "t": np.repeat((t - t.mean())[:, None], len(joints), axis=1)}
    for j, name in enumerate(joints):
        if rms[j] <= thresholds[j]:
            continue
        r = residual[:, j]
        corr = {k: _corr(r, x[:, j]) for k, x in signals.items()}
        top = max(corr, key=lambda k: abs(corr[k]))
        hint = f"residual correlates most with {top} ({corr[top]:+.2f})"
        if timing.get("needed"):
            hint += (f"; the data fit a timing offset of {1e3 * timing['offset_s']:+.3g} ms between the torque "
                     "and position logs (torque lags when positive): check the logging, this is not a "
                     "model effect")
        out[name] = {"rms": float(rms[j]), "threshold": float(thresholds[j]), "noise_floor": float(noise_floor[j]),
                     "fraction_of_nominal_rms": float(rms[j] / rms_nominal[j]) if rms_nominal[j] > 0 else 0.0,
                     "correlations": corr, "hint": hint}
    return out


def regime_analysis(residual, q, v, vd, t, joints) -> dict[str, Any]:
    """Mean and RMS of a residual per joint in each regime (step 1).

    Regimes: velocity sign (v < 0, |v| ≤ 5 % of max |v|, v > 0), speed (|v| terciles),
    acceleration (v̇ terciles), position (q terciles), time (quarters of the record).

    Returns:
        {joint: {"overall": {...}, "regimes": [{"regime", "bin", "count", "mean", "rms"}],
        "strongest": the bin whose mean departs most from the overall mean}}.
    """
    out = {}
    for j, name in enumerate(joints):
        r = residual[:, j]
        bins = []
        vmax = float(np.max(np.abs(v[:, j]))) or 1.0
        still = np.abs(v[:, j]) <= 0.05 * vmax
        masks = [("velocity sign", "v < 0", (v[:, j] < 0) & ~still), ("velocity sign", "v ≈ 0", still),
                 ("velocity sign", "v > 0", (v[:, j] > 0) & ~still)]
        for regime, x, names in (("speed", np.abs(v[:, j]), ("slow", "medium", "fast")),
                                 ("acceleration", vd[:, j], ("vd low", "vd mid", "vd high")),
                                 ("position", q[:, j], ("q low", "q mid", "q high"))):
            e1, e2 = np.quantile(x, [1 / 3, 2 / 3])
            masks += [(regime, names[0], x <= e1), (regime, names[1], (x > e1) & (x <= e2)),
                      (regime, names[2], x > e2)]
        edges = np.quantile(t, [0.25, 0.5, 0.75])
        quarter = np.searchsorted(edges, t)
        masks += [("time", f"quarter {k + 1}", quarter == k) for k in range(4)]
        for regime, label, mask in masks:
            if mask.sum() == 0:
                continue
            bins.append({"regime": regime, "bin": label, "count": int(mask.sum()),
                         "mean": float(r[mask].mean()), "rms": float(np.sqrt(np.mean(r[mask] ** 2)))})
        overall = {"mean": float(r.mean()), "rms": float(np.sqrt(np.mean(r**2)))}
        strongest = max(bins, key=lambda e: abs(e["mean"] - overall["mean"]))
        out[name] = {"overall": overall, "regimes": bins, "strongest": strongest,
                     "correlation_sign_v": _corr(r, np.sign(v[:, j])), "correlation_v": _corr(r, v[:, j]),
                     "correlation_vd": _corr(r, vd[:, j])}
    return out


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    d = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b / d) if d > 0 else 0.0


def _rms(x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(np.asarray(x) ** 2, axis=0))


def _pj(joints, x) -> dict[str, float]:
    return {j: float(v) for j, v in zip(joints, x)}


def _fmt_joints(joints, x) -> str:
    return ", ".join(f"{j.replace('panda_', '')} {v:.3g}" for j, v in zip(joints, x))


def _col_label(col, cand_of, timing_col) -> str:
    return TIMING if col == timing_col else cand_of[col].label


def _condition_number(G: np.ndarray) -> float:
    """cond of A with column-equilibrated A from its Gram matrix G = AᵀA."""
    d = np.sqrt(np.maximum(np.diag(G), 1e-300))
    w = np.linalg.eigvalsh(G / np.outer(d, d))
    return float(np.sqrt(w.max() / w.min())) if w.min() > 0 else float("inf")


def _z_two_sided(p: float) -> float:
    """z with P(|N(0, 1)| > z) = p (scipy.special: lighter to import than scipy.stats)."""
    from scipy.special import ndtri

    return float(-ndtri(p / 2))


# ---- command and benchmark ------------------------------------------------------------------




def write_outputs(folder: str | Path, robot, result: DiagnosisResult) -> list[Path]:
    """diagnosis.json, report.md, the figures and the augmented model files into ``folder``."""
    from pe_drake.diagnosis.augmented_model import write_augmented_model
    from pe_drake.diagnosis.report import write_report
    from pe_drake.io_utils import atomic_write_text

    folder = Path(folder)
    model_files = write_augmented_model(folder, robot, result.augmented)
    figures = write_report(folder, result, model_files)
    data = result.to_json_dict()
    data["model_files"] = [Path(p).name for p in model_files]
    data["figures"] = [Path(p).name for p in figures]
    atomic_write_text(folder / "diagnosis.json", json.dumps(_jsonable(data), indent=2) + "\n")
    return [folder / "diagnosis.json", folder / "report.md", *figures, *model_files]


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x






