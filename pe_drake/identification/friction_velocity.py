"""The velocity inside the Coulomb column's tanh(v/v_s), as close to the true one as the sensor allows.

The torque is low-pass filtered, so its friction part is the *filtered* tanh(v/v_s) (parallel
filtering, Gautier 1997). The v inside the tanh must not be filtered at the torque's cut-off: tanh
is nonlinear, and a joint with tanh friction sticks at each reversal for tens of ms that a 4 Hz
filter smears out (BUILD_NOTES, "The velocity inside the Coulomb column").

:func:`friction_velocity` takes the recorded v, else differentiates q, each low-passed at the
widest cut-off whose velocity noise (measured from the data, the encoder's quantization step as a
floor, times the filter's gain) stays below ``NOISE_FRACTION`` × v_s: more noise than that widens
the tanh near the reversals more than the filter's smear would.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from pe_drake.identification.lowpass import design_lowpass, differentiate

#: The velocity noise (RMS) allowed inside tanh(v/v_s), as a fraction of v_s.
NOISE_FRACTION = 0.5
#: Widest filtered cut-off tried, as a fraction of the sample rate (beyond it: unfiltered).
MAX_FRACTION = 0.4


class FrictionVelocity(NamedTuple):
    """The velocities for the Coulomb columns and how they were obtained.

    Attributes:
        v: velocities on the uniform grid, shape (T, n) [rad/s or m/s].
        cutoff_hz: each joint's low-pass cut-off, shape (n,) [Hz]; inf: not filtered.
        source: "measured" (the recorded v) or "differentiated" (from q).
        noise: each joint's estimated velocity noise after that filter, shape (n,) [rad/s].
    """

    v: np.ndarray
    cutoff_hz: np.ndarray
    source: str
    noise: np.ndarray


def white_noise_level(x: np.ndarray) -> np.ndarray:
    """White-noise level of a sampled signal per column: second differences remove the smooth
    motion (median absolute deviation · 1.4826 / √6), shape (T, n) → (n,) or (T,) → scalar."""
    d2 = np.diff(x, n=2, axis=0)
    return 1.4826 * np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0) / math.sqrt(6.0)


def _quantization_level(x: np.ndarray) -> np.ndarray:
    """The smallest nonzero step between samples / √12 of a signal (T,): the noise of a quantized
    signal (an encoder), which the median of second differences misses when most are zero."""
    d = np.abs(np.diff(x, axis=0))
    d = np.where(d > 0, d, np.inf)
    step = np.min(d, axis=0)
    return np.where(np.isfinite(step), step, 0.0) / math.sqrt(12.0)


def _noise_gains(cutoffs: list[float], rate_hz: float, order: int, derivative: bool) -> np.ndarray:
    """RMS gain of white noise through each cut-off's zero-phase filter (then the central
    difference when ``derivative``), as in :meth:`LowPassFilter.white_noise_gain`; the last
    entry of ``cutoffs`` may be inf (no filter)."""
    dt = 1.0 / rate_hz
    out = []
    for fc in cutoffs:
        length = 201 if not math.isfinite(fc) else int(min(max(40 * rate_hz / fc, 200), 200000)) | 1
        h = np.zeros(length)
        h[length // 2] = 1.0
        if math.isfinite(fc):
            h = design_lowpass(fc, rate_hz, length, order).apply(h)
        if derivative:
            h = differentiate(h[:, None], dt)[:, 0]
        out.append(math.sqrt(float(np.sum(h**2))))
    return np.array(out)


def friction_velocity(q: np.ndarray, v: np.ndarray | None, rate_hz: float, torque_cutoff_hz: float,
                      velocity_scale: float, order: int = 4, *, file: str = "") -> FrictionVelocity:
    """The velocities to put inside tanh(v/v_s), a joint at a time (module docstring).

    Args:
        q: raw positions on a uniform grid, shape (T, n) [rad or m].
        v: raw recorded velocities on the same grid, shape (T, n), or None.
        rate_hz: the grid's rate [Hz].
        torque_cutoff_hz: the torque's low-pass cut-off [Hz]: the narrowest one used.
        velocity_scale: v_s [rad/s].
    """
    src = v if v is not None else q
    top = MAX_FRACTION * rate_hz
    cutoffs = [torque_cutoff_hz]
    while cutoffs[-1] * 2 < top:
        cutoffs.append(cutoffs[-1] * 2)
    if top > torque_cutoff_hz:
        cutoffs.append(top)
    cutoffs.append(math.inf)
    gains = _noise_gains(cutoffs, rate_hz, order, derivative=v is None)
    dt = 1.0 / rate_hz
    n = src.shape[1]
    out, chosen, noise = np.empty(src.shape), np.empty(n), np.empty(n)
    for j in range(n):  # a joint at a time: a long log's full-rate columns one by one
        sigma = max(float(white_noise_level(src[:, j])), float(_quantization_level(src[:, j])))
        ok = np.flatnonzero(sigma * gains <= NOISE_FRACTION * velocity_scale)
        k = int(ok[-1]) if ok.size else 0  # the noise grows with the cut-off: the widest that passes
        fc = cutoffs[k]
        x = src[:, j]
        if math.isfinite(fc):
            x = design_lowpass(fc, rate_hz, len(src), order, file=file).apply(x)
        out[:, j] = x if v is not None else differentiate(x[:, None], dt)[:, 0]
        chosen[j], noise[j] = fc, sigma * gains[k]
    return FrictionVelocity(out, chosen, "measured" if v is not None else "differentiated", noise)
