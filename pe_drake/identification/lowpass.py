"""The package's one low-pass filter: a Butterworth design run forward and backward (zero phase)
with an odd extension of a few cut-off periods at the ends (:func:`design_lowpass`), and the
central differences that give v and v̇ from the filtered signals (:func:`differentiate`)."""

from __future__ import annotations

import dataclasses

import numpy as np

from pe_drake.exceptions import DataError

#: Odd extension at each end of the filtered record, in periods of the cut-off: a short one
#: leaves edge transients in the twice-differentiated acceleration past the trimmed ends.
EDGE_PERIODS = 3.0
#: The default trim drops the samples where the filter's edge transient on the acceleration
#: exceeds this fraction of the acceleration at the end (:meth:`LowPassFilter.edge_transient_s`).
EDGE_TOLERANCE = 0.05


@dataclasses.dataclass(frozen=True, eq=False)
class LowPassFilter:
    """A Butterworth low-pass run forward and backward (:func:`design_lowpass`).

    Second-order sections (``scipy.signal.sosfiltfilt``) stay accurate at cut-offs of a few
    Hz at 1 kHz where the transfer-function form of ``filtfilt`` loses precision.

    Attributes:
        sos: second-order sections, shape (⌈order/2⌉, 6).
        order: Butterworth order (the zero-phase filter doubles it).
        padlen: samples of odd extension at each end.
    """

    sos: np.ndarray
    cutoff_hz: float
    rate_hz: float
    order: int
    padlen: int

    def apply(self, x: np.ndarray) -> np.ndarray:
        """Zero-phase filtered x along its first axis (time), same shape (T, ...)."""
        from scipy.signal import sosfiltfilt  # lazy: keeps `import pe_drake` light

        x = np.asarray(x, float)
        if x.ndim < 2:
            return sosfiltfilt(self.sos, x, axis=0, padtype="odd", padlen=self.padlen)
        # Column by column: scipy's padded copies then cost one column of a long log, not all.
        out = np.empty(x.shape)
        for k in np.ndindex(x.shape[1:]):
            column = (slice(None), *k)
            out[column] = sosfiltfilt(self.sos, x[column], padtype="odd", padlen=self.padlen)
        return out

    def edge_transient_s(self, tolerance: float = EDGE_TOLERANCE) -> float:
        """How far from each end the filter's edge transient spoils the accelerations [s].

        The odd extension continues a record's value and slope across its ends but flips its
        curvature, so the filtered, twice-differentiated acceleration of a record with constant
        acceleration a is wrong near the ends. This is the time from an end beyond which that
        error stays below ``tolerance`` × |a|: dropping more only loses information.
        """
        from scipy.signal import sosfiltfilt  # lazy: keeps `import pe_drake` light

        length = 4 * self.padlen + 1
        t = np.arange(length) / self.rate_hz
        y = sosfiltfilt(self.sos, 0.5 * t**2, padtype="odd", padlen=self.padlen)
        dt = 1.0 / self.rate_hz
        error = np.abs(differentiate(differentiate(y[:, None], dt), dt)[: length // 2, 0] - 1.0)
        bad = np.flatnonzero(error > tolerance)
        return float((bad[-1] + 1) / self.rate_hz) if bad.size else 0.0

    def white_noise_gain(self) -> float:
        """Σ h² of the zero-phase impulse response: the variance ratio of filtered white noise."""
        from scipy.signal import sosfiltfilt  # lazy: keeps `import pe_drake` light

        length = int(min(max(40 * self.rate_hz / self.cutoff_hz, 200), 200000))
        impulse = np.zeros(length)
        impulse[length // 2] = 1.0
        return float(np.sum(sosfiltfilt(self.sos, impulse) ** 2))


def design_lowpass(cutoff_hz: float, rate_hz: float, num_samples: int, order: int = 4, *,
                   edge_periods: float = EDGE_PERIODS, file: str = "") -> LowPassFilter:
    """The package's Butterworth low-pass for a record of ``num_samples`` samples.

    The odd extension covers ``edge_periods`` periods of the cut-off (not scipy's default 27
    samples), so the edge transient of the second derivative dies out within the trimmed ends;
    it is at least scipy's minimum and at most num_samples − 1.

    Args:
        cutoff_hz: cut-off [Hz], below rate_hz / 2.

    Raises:
        DataError: a record too short for the filter (the file is named).
    """
    from scipy.signal import butter  # lazy: keeps `import pe_drake` light

    sos = butter(order, cutoff_hz, btype="low", fs=rate_hz, output="sos")
    min_padlen = 3 * (2 * len(sos) + 1)
    if num_samples <= min_padlen:
        raise DataError(f"only {num_samples} samples; the filter needs more than {min_padlen}", file=file)
    padlen = int(min(num_samples - 1, max(min_padlen, round(edge_periods * rate_hz / cutoff_hz))))
    return LowPassFilter(sos, float(cutoff_hz), float(rate_hz), int(order), padlen)


def differentiate(x: np.ndarray, dt: float) -> np.ndarray:
    """Central differences along time (one-sided at the ends), shape (T, n) → (T, n) [unit/s]."""
    return np.gradient(x, dt, axis=0)
