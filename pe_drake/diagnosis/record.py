"""Data preparation of the diagnosis: one filtered full-rate record per file, then its parts.

The measurement is brought to a uniform grid and low-pass filtered with a zero-phase
Butterworth (same filter on q and τ, as :func:`pe_drake.identification.measurements.preprocess`);
v, v̇ by central differences; then decimated to about ``decimate_to_hz``. The noise floor of
each joint is the raw torque's white-noise level (median absolute second difference / √6 ·
1.4826) times the filter's noise gain. Without a validation record the last
``holdout_fraction`` is held out, with a gap of 2 / cut-off between the two parts so the
zero-phase filter does not leak across (:func:`split_segments`).

:func:`prepare_record` is a sequence of small steps (:func:`uniform_grid`,
:func:`choose_cutoff`, :func:`design_filter`, :func:`decimation_step`,
:func:`raw_noise_level`, :func:`filter_noise_gain`) that mirror identification's
``preprocess``, so they can be swapped for its public step functions one by one.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from pe_drake.diagnosis.options import MIN_PERIODS, DiagnosisConfig
from pe_drake.exceptions import ConfigError, DataError
from pe_drake.identification.measurements import (
    CUTOFF_FACTOR,
    MIN_CUTOFF_HZ,
    UNIFORM_TOLERANCE,
    Measurement,
    Preprocessing,
    motion_bandwidth_hz,
)

#: Order of the Butterworth low-pass (the zero-phase filter doubles it).
FILTER_ORDER = 4


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
        return zero_phase(self.sos, self.padlen, x)

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


def zero_phase(sos: np.ndarray, padlen: int, x: np.ndarray) -> np.ndarray:
    """``sos`` forward and backward along axis 0 with an odd extension of ``padlen`` samples."""
    # scipy.signal imported here: it is heavy and kept out of `import pe_drake`.
    from scipy.signal import sosfiltfilt

    return sosfiltfilt(sos, x, axis=0, padtype="odd", padlen=padlen)


def uniform_grid(m: Measurement) -> tuple[np.ndarray, dict[str, np.ndarray | None], float, bool]:
    """The record's time grid and signals q, tau, v on it.

    Returns:
        (t, {"q", "tau", "v"} on t (v None when not measured), the step dt [s], whether the raw
        time was not uniform (within ``UNIFORM_TOLERANCE``) and was linearly interpolated).
    """
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
    return t, signals, dt, bool(resampled)


def choose_cutoff(config: DiagnosisConfig, t: np.ndarray, q: np.ndarray, rate: float,
                  source: str) -> tuple[float, str]:
    """(cut-off [Hz], "argument" or "spectrum"): the configured one or ``CUTOFF_FACTOR`` × the
    motion bandwidth, at least ``MIN_CUTOFF_HZ``, at most 0.4 × the rate.

    Raises:
        ConfigError: a configured cut-off at or above the Nyquist frequency of file ``source``.
    """
    if config.cutoff_hz is not None:
        if config.cutoff_hz >= 0.5 * rate:
            raise ConfigError(f"cutoff_hz = {config.cutoff_hz:g} Hz is not below the Nyquist frequency "
                              f"{0.5 * rate:.4g} Hz of the data in '{source}'")
        return float(config.cutoff_hz), "argument"
    return min(max(CUTOFF_FACTOR * motion_bandwidth_hz(t, q), MIN_CUTOFF_HZ), 0.4 * rate), "spectrum"


def design_filter(cutoff: float, rate: float, num_samples: int, source: str) -> tuple[np.ndarray, int]:
    """(second-order sections, padlen) of the zero-phase low-pass.

    The odd extension is 3 / cut-off at each end: a short extension leaves edge transients in
    the twice-differentiated acceleration that reach past the 2 / cut-off trimmed at each end.

    Raises:
        DataError: too few samples for the filter, from file ``source``.
    """
    # scipy.signal imported here: it is heavy and kept out of `import pe_drake`.
    from scipy.signal import butter

    sos = butter(FILTER_ORDER, cutoff, btype="low", fs=rate, output="sos")
    padlen = int(min(num_samples - 1, max(3 * (2 * len(sos) + 1), math.ceil(3.0 * rate / cutoff))))
    if num_samples < 4 * padlen:
        raise DataError(f"only {num_samples} samples at {rate:.4g} Hz: the record is too short for a "
                        f"{cutoff:.3g} Hz low-pass filter (at least {4 * padlen / rate:.3g} s)", file=source)
    return sos, padlen


def decimation_step(rate: float, cutoff: float, decimate_to_hz: float) -> int:
    """Keep every step-th sample: about ``decimate_to_hz``, Nyquist at least 1.25 × the cut-off."""
    step = 1
    if decimate_to_hz < rate:
        step = max(1, int(round(rate / decimate_to_hz)))
        while step > 1 and 0.5 * rate / step < 1.25 * cutoff:
            step -= 1
    return step


def raw_noise_level(tau: np.ndarray) -> np.ndarray:
    """White-noise level of a raw torque per joint [N·m]: second differences remove the smooth
    motion (median absolute deviation · 1.4826 / √6)."""
    d2 = np.diff(tau, n=2, axis=0)
    return 1.4826 * np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0) / math.sqrt(6.0)


def filter_noise_gain(sos: np.ndarray, rate: float, cutoff: float) -> float:
    """Noise power gain of the zero-phase filter: the energy of its impulse response."""
    # scipy.signal imported here: it is heavy and kept out of `import pe_drake`.
    from scipy.signal import sosfiltfilt

    length = int(min(max(40 * rate / cutoff, 200), 200000))
    impulse = np.zeros(length)
    impulse[length // 2] = 1.0
    return float(np.sum(sosfiltfilt(sos, impulse) ** 2))


def prepare_record(measurement: Measurement, config: DiagnosisConfig) -> Record:
    """Uniform grid, zero-phase filter, derivatives at the full rate (module docstring).

    Raises:
        DataError: too few samples for the filter, from the file named.
        ConfigError: a cut-off at or above the Nyquist frequency.
    """
    m = measurement
    if m.num_samples < 30:
        raise DataError(f"only {m.num_samples} samples; the diagnosis needs at least 30", file=m.source)
    t, signals, dt, resampled = uniform_grid(m)
    rate = 1.0 / dt
    cutoff, cutoff_source = choose_cutoff(config, t, signals["q"], rate, m.source)
    sos, padlen = design_filter(cutoff, rate, len(t), m.source)
    q, tau = zero_phase(sos, padlen, signals["q"]), zero_phase(sos, padlen, signals["tau"])
    v = zero_phase(sos, padlen, signals["v"]) if signals["v"] is not None else np.gradient(q, dt, axis=0)
    vd = np.gradient(v, dt, axis=0)
    step = decimation_step(rate, cutoff, config.decimate_to_hz)
    trim = 2.0 / cutoff
    raw = raw_noise_level(m.tau)
    gain = filter_noise_gain(sos, rate, cutoff)
    info = Preprocessing(
        cutoff_hz=cutoff, cutoff_source=cutoff_source, filter_order=FILTER_ORDER,
        input_rate_hz=1.0 / float(np.median(np.diff(m.t))), resampled=resampled, rate_hz=rate / step,
        trim_s=trim, velocity_source="measured" if m.v is not None else "differentiated",
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
