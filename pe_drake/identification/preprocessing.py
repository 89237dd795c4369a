"""Preprocessing of a raw recording into what identification needs, as named steps.

:func:`preprocess` chains the steps, each usable on its own (the diagnosis uses them too):

1. :func:`resample_uniform`: linear interpolation onto a uniform grid when the steps vary;
2. :func:`choose_cutoff`: the low-pass cut-off (argument, trajectory band or spectrum);
3. :func:`~pe_drake.identification.lowpass.design_lowpass`: the zero-phase Butterworth filter,
   on q and tau alike so torque and motion keep the same phase;
4. :func:`fill_derivatives`: v and vd by central differences where they were not measured;
5. :func:`decimation_step`: keep every k-th sample, alias-free;
6. :func:`trim_indices`: drop the ends, where the filter and the differences see the edges.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from pe_drake.config import check_finite
from pe_drake.exceptions import ConfigError, DataError
from pe_drake.identification.lowpass import LowPassFilter, design_lowpass, differentiate
from pe_drake.identification.measurements import Measurement, Preprocessing

#: Cut-off = CUTOFF_FACTOR × highest motion frequency (harmonic N·f0, or spectral estimate).
CUTOFF_FACTOR = 5.0
#: Lower bound of an automatically chosen cut-off [Hz].
MIN_CUTOFF_HZ = 4.0
#: An automatically chosen cut-off stays below this fraction of the sample rate.
MAX_CUTOFF_FRACTION = 0.4
#: Fraction of the (detrended, windowed) energy of q below the estimated motion bandwidth.
ENERGY_FRACTION = 0.999
#: Relative spread of the time steps above which the data is resampled to a uniform grid.
UNIFORM_TOLERANCE = 1e-3
#: Time trimmed at each end of a ground-wrench record by default, in periods of the cut-off.
TRIM_PERIODS = 2.0
#: Decimation keeps the output Nyquist frequency at least this factor above the cut-off.
ALIAS_MARGIN = 1.25
#: Fewest raw samples :func:`preprocess` accepts.
MIN_SAMPLES = 30


@dataclasses.dataclass(frozen=True)
class PreprocessOptions:
    """The choices of :func:`preprocess`, checked at construction.

    Attributes:
        cutoff_hz: low-pass cut-off [Hz], below the input Nyquist frequency; None: automatic.
        fundamental_hz: trajectory's base frequency ω/2π [Hz] (with ``harmonics``).
        harmonics: number of harmonics N of the trajectory (with ``fundamental_hz``).
        decimate_to_hz: wanted output rate [Hz]; None keeps the input rate.
        trim_s: time dropped at each end [s]; None: what the filter needs
            (:meth:`LowPassFilter.edge_transient_s`).
        filter_order: Butterworth order in [1, 10] (the zero-phase filter doubles it).

    Raises:
        ConfigError: a non-positive rate or cut-off, only one of fundamental_hz/harmonics,
            a negative trim, a bad order.
    """

    cutoff_hz: float | None = None
    fundamental_hz: float | None = None
    harmonics: int | None = None
    decimate_to_hz: float | None = 200.0
    trim_s: float | None = None
    filter_order: int = 4

    def __post_init__(self) -> None:
        for name in ("decimate_to_hz", "cutoff_hz", "fundamental_hz"):
            if getattr(self, name) is not None:
                check_finite(name, getattr(self, name), positive=True)
        if (self.fundamental_hz is None) != (self.harmonics is None):
            raise ConfigError("give both fundamental_hz and harmonics (or neither)")
        h = self.harmonics
        if h is not None and (not isinstance(h, (int, np.integer)) or h < 1):
            raise ConfigError(f"harmonics must be a positive integer, got {h!r}")
        if self.trim_s is not None:
            check_finite("trim_s [s]", self.trim_s, nonneg=True)
        order = self.filter_order
        if not isinstance(order, (int, np.integer)) or not 1 <= order <= 10:
            raise ConfigError(f"filter_order must be an integer in [1, 10], got {order!r}")


@dataclasses.dataclass(frozen=True, eq=False)
class UniformSignals:
    """Signals on a uniform time grid t (T,) [s] of step dt [s] (:func:`resample_uniform`).

    ``signals`` maps each name to its (T, n) array (None where the input had None);
    ``resampled``: the input steps were not uniform and the signals were interpolated.
    """

    t: np.ndarray
    dt: float
    rate_hz: float
    resampled: bool
    signals: dict[str, np.ndarray | None]


def resample_uniform(t: np.ndarray, signals: dict[str, np.ndarray | None],
                     tolerance: float = UNIFORM_TOLERANCE) -> UniformSignals:
    """Puts signals (T, n) on a uniform grid, by linear interpolation when the steps vary.

    Args:
        t: strictly increasing time, shape (T,) [s], T ≥ 2.
        tolerance: relative spread of the steps around their median above which the
            signals are interpolated onto a grid at the median step.

    Returns:
        Without resampling, t and the signals are the input arrays and
        dt = (t[-1] − t[0]) / (T − 1); with it, dt is the median step.
    """
    dt_all = np.diff(t)
    dt = float(np.median(dt_all))
    resampled = float(np.max(np.abs(dt_all - dt))) > tolerance * dt
    if resampled:
        count = int(math.floor((t[-1] - t[0]) / dt + 1e-9)) + 1
        grid = t[0] + dt * np.arange(count)
        signals = {k: None if x is None else _interp_rows(grid, t, x) for k, x in signals.items()}
    else:
        grid = t
        dt = float((t[-1] - t[0]) / (len(t) - 1))
    return UniformSignals(grid, dt, 1.0 / dt, bool(resampled), dict(signals))


def _interp_rows(t_new: np.ndarray, t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Linear interpolation of every column of x (T, n) from times t onto t_new."""
    k = np.clip(np.searchsorted(t, t_new, side="right") - 1, 0, len(t) - 2)
    w = ((t_new - t[k]) / (t[k + 1] - t[k]))[:, None]
    return x[k] * (1 - w) + x[k + 1] * w


class Cutoff(NamedTuple):
    """A low-pass cut-off [Hz] and its source: "argument", "trajectory" or "spectrum"."""

    hz: float
    source: str


def motion_bandwidth_hz(t: np.ndarray, q: np.ndarray, energy_fraction: float = ENERGY_FRACTION) -> float:
    """Frequency [Hz] below which ``energy_fraction`` of the motion's energy lies, worst joint.

    Each joint's q (T, n) on the uniform grid t is detrended (linear) and Hann-windowed
    first: a non-periodic record otherwise leaks energy to high frequencies through its end
    discontinuity. 0 for a motionless record.
    """
    from scipy.signal import detrend, get_window  # lazy: keeps `import pe_drake` light

    T = q.shape[0]
    dt = (t[-1] - t[0]) / (T - 1)
    window = get_window("hann", T)
    freqs = np.fft.rfftfreq(T, dt)[1:]  # DC holds the (removed) mean
    idx = []
    for j in range(q.shape[1]):  # a joint at a time: the spectra of a long log one by one
        power = np.abs(np.fft.rfft(detrend(q[:, j], type="linear") * window)[1:]) ** 2
        total = power.sum()
        if total > 0:
            idx.append(int(np.searchsorted(np.cumsum(power) / total, energy_fraction)))
    if not idx:
        return 0.0
    return float(freqs[min(max(idx), len(freqs) - 1)])


def choose_cutoff(t: np.ndarray, q: np.ndarray, rate_hz: float, *, cutoff_hz: float | None = None,
                  fundamental_hz: float | None = None, harmonics: int | None = None,
                  file: str = "") -> Cutoff:
    """The low-pass cut-off for positions q (T, n) on the uniform grid t (T,) [s] at ``rate_hz``.

    In order of precedence: ``cutoff_hz`` ("argument"); ``CUTOFF_FACTOR`` × ``harmonics`` ×
    ``fundamental_hz`` ("trajectory"); else ``CUTOFF_FACTOR`` × :func:`motion_bandwidth_hz` of q
    ("spectrum"). An automatic cut-off is at least ``MIN_CUTOFF_HZ`` and at most
    ``MAX_CUTOFF_FRACTION`` × the rate.

    Raises:
        ConfigError: ``cutoff_hz`` at or above the Nyquist frequency (the file is named).
    """
    nyquist = 0.5 * rate_hz
    if cutoff_hz is not None:
        if cutoff_hz >= nyquist:
            raise ConfigError(f"cutoff_hz = {cutoff_hz:g} Hz is not below the Nyquist frequency "
                              f"{nyquist:.4g} Hz of the data in '{file}'")
        return Cutoff(float(cutoff_hz), "argument")
    if fundamental_hz is not None:
        source, highest = "trajectory", harmonics * fundamental_hz
    else:
        source, highest = "spectrum", motion_bandwidth_hz(t, q)
    cutoff = min(max(CUTOFF_FACTOR * highest, MIN_CUTOFF_HZ), MAX_CUTOFF_FRACTION * rate_hz)
    return Cutoff(cutoff, source)


class Derivatives(NamedTuple):
    """Velocities and accelerations (T, n), each "measured" or "differentiated"."""

    v: np.ndarray
    vd: np.ndarray
    velocity_source: str
    acceleration_source: str


def fill_derivatives(q: np.ndarray, dt: float, v: np.ndarray | None = None,
                     vd: np.ndarray | None = None) -> Derivatives:
    """Keeps measured v and vd; differentiates q (then v) where they are missing.

    Args:
        q: filtered positions, shape (T, n) [rad or m], on a uniform grid of step dt [s].
        v, vd: filtered measured velocities and accelerations, shape (T, n), or None.
    """
    velocity = v if v is not None else differentiate(q, dt)
    acceleration = vd if vd is not None else differentiate(velocity, dt)
    return Derivatives(velocity, acceleration, "measured" if v is not None else "differentiated",
                       "measured" if vd is not None else "differentiated")


def _on_grid(t: np.ndarray, x: np.ndarray, grid: UniformSignals) -> np.ndarray:
    """One column x (T,) on the uniform grid."""
    return _interp_rows(grid.t, t, x[:, None])[:, 0] if grid.resampled else x


def _filtered_columns(t: np.ndarray, x: np.ndarray, grid: UniformSignals, lowpass: LowPassFilter,
                      idx: np.ndarray) -> np.ndarray:
    """x (T, k) on the grid, filtered, at the kept samples ``idx``: one column at a time, so a
    long log costs one full-rate column at once."""
    columns = [lowpass.apply(_on_grid(t, x[:, j], grid))[idx] for j in range(x.shape[1])]
    return np.column_stack(columns)


def _filtered_motion(m: Measurement, grid: UniformSignals, lowpass: LowPassFilter,
                     idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q, v, vd) filtered at ``idx``: measured v and vd kept (filtered), the others
    differentiated at the full rate (:func:`fill_derivatives`), a joint at a time."""
    out = np.empty((3, idx.size, m.num_joints))
    for j in range(m.num_joints):
        q = lowpass.apply(grid.signals["q"][:, j])
        v = None if m.v is None else lowpass.apply(_on_grid(m.t, m.v[:, j], grid))
        vd = None if m.vd is None else lowpass.apply(_on_grid(m.t, m.vd[:, j], grid))
        d = fill_derivatives(q, grid.dt, v, vd)
        out[0, :, j], out[1, :, j], out[2, :, j] = q[idx], d.v[idx], d.vd[idx]
    return out[0], out[1], out[2]


def decimation_step(rate_hz: float, target_hz: float | None, cutoff_hz: float) -> int:
    """Keep every k-th sample to get close to ``target_hz`` [Hz], alias-free.

    k is reduced until the output Nyquist frequency is at least ``ALIAS_MARGIN`` × the
    cut-off; 1 when ``target_hz`` is None or not below ``rate_hz``.
    """
    step = 1
    if target_hz is not None and target_hz < rate_hz:
        step = max(1, int(round(rate_hz / target_hz)))
        while step > 1 and 0.5 * rate_hz / step < ALIAS_MARGIN * cutoff_hz:
            step -= 1
    return step


def trim_indices(t: np.ndarray, trim_s: float, step: int = 1, *, file: str = "") -> np.ndarray:
    """Sorted indices (S,), S ≥ 2, of the samples of the uniform grid t kept: every
    ``step``-th one, ``trim_s`` [s] away from both ends.

    Raises:
        DataError: fewer than two samples left.
    """
    keep = (t >= t[0] + trim_s - 1e-12) & (t <= t[-1] - trim_s + 1e-12)
    keep &= (np.arange(len(t)) % step) == 0
    idx = np.nonzero(keep)[0]
    if idx.size < 2:
        raise DataError(f"nothing left after trimming {trim_s:g} s at each end of a "
                        f"{t[-1] - t[0]:.4g} s record; pass a smaller trim_s", file=file)
    return idx


def preprocess(measurement: Measurement, options: PreprocessOptions | None = None, **fields) -> Measurement:
    """Uniform grid, zero-phase low-pass, derivatives, decimation and trimmed ends.

    The steps of the module docstring, in order; the same filter runs on q, tau, the ground
    wrench and measured v/vd, so their phases match. ``**fields``: instead of ``options``, its
    fields by name (``cutoff_hz=8.0``, ...). Returns the processed :class:`Measurement` with v
    and vd filled and ``preprocessing`` set.

    Raises:
        ConfigError: a bad option.
        DataError: too few samples, or nothing left after trimming.
    """
    if options is not None and fields:
        raise ConfigError(f"give options or {', '.join(fields)}, not both")
    opts = options if options is not None else PreprocessOptions(**fields)
    m = measurement
    if m.num_samples < MIN_SAMPLES:
        raise DataError(f"only {m.num_samples} samples; preprocessing needs at least {MIN_SAMPLES}",
                        file=m.source)
    grid = resample_uniform(m.t, {"q": m.q})
    cutoff = choose_cutoff(grid.t, grid.signals["q"], grid.rate_hz, cutoff_hz=opts.cutoff_hz,
                           fundamental_hz=opts.fundamental_hz, harmonics=opts.harmonics,
                           file=m.source)
    lowpass = design_lowpass(cutoff.hz, grid.rate_hz, len(grid.t), opts.filter_order, file=m.source)
    step = decimation_step(grid.rate_hz, opts.decimate_to_hz, cutoff.hz)
    if opts.trim_s is not None:
        trim = float(opts.trim_s)
    elif m.wrench is not None:  # the arms move it by 1-3 N·m on top of a 300 N weight
        trim = TRIM_PERIODS / lowpass.cutoff_hz
    else:
        trim = lowpass.edge_transient_s()
    idx = trim_indices(grid.t, trim, step, file=m.source)
    q, v, vd = _filtered_motion(m, grid, lowpass, idx)
    tau, wrench = (None if x is None else _filtered_columns(m.t, x, grid, lowpass, idx)
                   for x in (m.tau, m.wrench))
    info = Preprocessing(
        cutoff_hz=cutoff.hz, cutoff_source=cutoff.source, filter_order=int(opts.filter_order),
        input_rate_hz=grid.rate_hz, resampled=grid.resampled, rate_hz=grid.rate_hz / step,
        trim_s=trim, velocity_source="measured" if m.v is not None else "differentiated",
        acceleration_source="measured" if m.vd is not None else "differentiated",
        samples_in=m.num_samples, samples_out=int(idx.size), duration_in_s=float(m.t[-1] - m.t[0]),
        duration_out_s=float(grid.t[idx[-1]] - grid.t[idx[0]]),
    )
    return Measurement(grid.t[idx], q, tau, v, vd, m.joints, m.source, info, wrench=wrench,
                       notes=m.notes)
