"""Data preparation of the diagnosis: one filtered full-rate record per file, then its parts.

The measurement is put on a uniform grid and filtered by identification's preprocessing steps
(zero-phase Butterworth on q and τ, v̇ by central differences), so both stages filter alike;
the noise floor is the raw torque's white-noise level times the filter's noise gain. Without a
validation record the last ``holdout_fraction`` is held out, with a gap of 2 / cut-off between
the parts so the zero-phase filter does not leak across (:func:`split_segments`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from pe_drake.diagnosis.options import MIN_PERIODS, DiagnosisConfig
from pe_drake.exceptions import DataError
from pe_drake.identification.data_checks import check_against_model
from pe_drake.identification.friction_velocity import friction_velocity, white_noise_level
from pe_drake.identification.measurements import Measurement, Preprocessing
from pe_drake.identification.lowpass import EDGE_PERIODS, LowPassFilter, design_lowpass
from pe_drake.identification.preprocessing import choose_cutoff, decimation_step, resample_uniform
from pe_drake.memory import available_bytes
from pe_drake.multibody.drive_columns import coulomb_column

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Order of the Butterworth low-pass (the zero-phase filter doubles it).
FILTER_ORDER = 4


@dataclasses.dataclass(frozen=True, eq=False)
class Record:
    """One measurement file at its full (uniform) rate after zero-phase filtering.

    Attributes:
        t, q, v, vd, tau: filtered full-rate signals, (T,) and (T, n).
        trim_s: time dropped at each end [s].
        raw_noise: white-noise level of the raw torque per joint [N·m].
        noise_gain: noise power gain of the zero-phase filter.
        friction_v: the velocities inside the Coulomb columns' tanh, (T, n), as identify's
            (:func:`~pe_drake.identification.friction_velocity.friction_velocity`).
    """

    source: str
    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    vd: np.ndarray
    tau: np.ndarray
    lowpass: LowPassFilter
    rate_hz: float
    cutoff_hz: float
    step: int
    trim_s: float
    raw_noise: np.ndarray
    noise_gain: float
    preprocessing: Any
    friction_v: np.ndarray

    def filtered(self, x: np.ndarray) -> np.ndarray:
        """The same zero-phase filter as the torque, along time (parallel filtering)."""
        return self.lowpass.apply(x)

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
    """Uniform grid, zero-phase filter, derivatives at the full rate (module docstring)."""
    m = measurement
    if m.num_samples < 30:
        raise DataError(f"only {m.num_samples} samples; the diagnosis needs at least 30", file=m.source)
    grid = resample_uniform(m.t, {"q": m.q, "tau": m.tau, "v": m.v})
    t, signals, dt, rate = grid.t, grid.signals, grid.dt, grid.rate_hz
    cutoff, cutoff_source = choose_cutoff(t, signals["q"], rate, cutoff_hz=config.cutoff_hz, file=m.source)
    lowpass = design_lowpass(cutoff, rate, len(t), FILTER_ORDER, edge_periods=EDGE_PERIODS, file=m.source)
    if len(t) < 4 * lowpass.padlen:
        raise DataError(f"only {len(t)} samples at {rate:.4g} Hz: the record is too short for a "
                        f"{cutoff:.3g} Hz low-pass filter (at least {4 * lowpass.padlen / rate:.3g} s)", file=m.source)
    q, tau = lowpass.apply(signals["q"]), lowpass.apply(signals["tau"])
    v = lowpass.apply(signals["v"]) if signals["v"] is not None else np.gradient(q, dt, axis=0)
    vd = np.gradient(v, dt, axis=0)
    step = decimation_step(rate, config.decimate_to_hz, cutoff)
    trim = 2.0 / cutoff
    raw = white_noise_level(m.tau)
    gain = lowpass.white_noise_gain()
    info = Preprocessing(
        cutoff_hz=cutoff, cutoff_source=cutoff_source, filter_order=FILTER_ORDER,
        input_rate_hz=1.0 / float(np.median(np.diff(m.t))), resampled=grid.resampled, rate_hz=rate / step,
        trim_s=trim, velocity_source="measured" if m.v is not None else "differentiated",
        acceleration_source="differentiated", samples_in=m.num_samples, samples_out=0)
    friction = friction_velocity(signals["q"], signals["v"], rate, cutoff, config.coulomb_velocity_scale,
                                 FILTER_ORDER, file=m.source)
    return Record(m.source, t, q, v, vd, tau, lowpass, rate, cutoff, step, trim, raw, gain, info, friction.v)


@dataclasses.dataclass(frozen=True, eq=False)
class Segment:
    """Decimated samples of one record used for fitting or for held-out evaluation.

    Attributes:
        name: "training" or "held-out".
        idx: their indices into the record's full-rate arrays, (S,).
        coulomb: parallel-filtered Coulomb columns tanh(v/v_s) per joint, (S, n).
        dtau: time derivative of the filtered measured torque, (S, n) [N·m/s].
    """

    name: str
    record: Record
    idx: np.ndarray
    coulomb: np.ndarray
    dtau: np.ndarray

    # the record's samples of the segment: time [s], (S,); q, v, vd, tau, each (S, n)
    t = property(lambda self: self.record.t[self.idx])
    q = property(lambda self: self.record.q[self.idx])
    v = property(lambda self: self.record.v[self.idx])
    vd = property(lambda self: self.record.vd[self.idx])
    tau = property(lambda self: self.record.tau[self.idx])

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


def delayed_states(seg: Segment, delay: float, velocity_scale: float) -> tuple[np.ndarray, ...]:
    """q, v, vd and the filtered Coulomb column at t − ``delay`` [s], each (S, n): the motion a
    torque log lagging by ``delay`` pairs with each sample."""
    rec = seg.record
    t = seg.t - delay
    coulomb = rec.filtered(coulomb_column(rec.friction_v, velocity_scale))

    def at(x: np.ndarray) -> np.ndarray:
        return np.column_stack([np.interp(t, rec.t, x[:, j]) for j in range(x.shape[1])])

    return at(rec.q), at(rec.v), at(rec.vd), at(coulomb)


def split_segments(record: Record, config: DiagnosisConfig, validation: Record | None = None,
                   ) -> tuple[Segment, Segment]:
    """Training and held-out segments (module docstring)."""
    columns = {}
    for rec in (record, validation):
        if rec is None:
            continue
        coulomb = rec.filtered(coulomb_column(rec.friction_v, config.coulomb_velocity_scale))
        dtau = np.gradient(rec.tau, 1.0 / rec.rate_hz, axis=0)
        columns[id(rec)] = (coulomb, dtau)
    usable = record.usable()
    if validation is None:
        t = record.t
        gap = record.trim_s / 2
        split = _split_time(record, usable, config.holdout_fraction, gap)
        train = usable[t[usable] < split - gap]
        held = usable[t[usable] > split + gap]
        training = _segment("training", record, train, *columns[id(record)])
        held_out = _segment("held-out", record, held, *columns[id(record)])
    else:
        training = _segment("training", record, usable, *columns[id(record)])
        held_out = _segment("held-out", validation, validation.usable(), *columns[id(validation)])
    for seg, other in ((training, held_out), (held_out, training)):
        need = MIN_PERIODS / seg.record.cutoff_hz
        if seg.num_samples < 20 or seg.duration < need:
            raise DataError(
                f"the {seg.name} part is {seg.duration:.3g} s long ({seg.num_samples} samples) after "
                f"filtering and trimming {seg.record.trim_s:.3g} s at each end; it needs at least "
                f"{need:.3g} s ({MIN_PERIODS:g} periods of the {seg.record.cutoff_hz:.3g} Hz cut-off): "
                + _short_part_advice(seg, other, need, config, validation is None),
                file=seg.record.source,
            )
    return training, held_out


def _split_time(record: Record, usable: np.ndarray, fraction: float, gap: float) -> float:
    """Where the held-out part starts: the last ``fraction``, moved (when the record is long
    enough) so that neither part is shorter than MIN_PERIODS periods of the cut-off."""
    t = record.t
    split = t[0] + (1.0 - fraction) * (t[-1] - t[0])
    if len(usable) < 2:
        return split
    need = MIN_PERIODS / record.cutoff_hz
    u0, u1 = t[usable[0]], t[usable[-1]]
    step = 1.0 / record.rate_hz
    if min(split - gap - u0, u1 - split - gap) >= need + 2 * step:
        return split  # both parts long enough: the configured fraction as it is
    need *= 1.02
    if u1 - u0 < 2 * (need + gap) + 2 * step:
        return split  # too short for both parts: the caller says which and what to change
    return min(max(split, u0 + gap + need), u1 - gap - need)


def _short_part_advice(seg: Segment, other: Segment, need: float, config: DiagnosisConfig, own_split: bool) -> str:
    """What to change when ``seg`` is too short (``other`` is the other part)."""
    if not own_split:
        return f"record a longer {'validation ' if seg.name == 'held-out' else ''}run"
    record = seg.record
    whole = 2 * (need + record.trim_s) + record.trim_s
    advice = f"record a run of at least {whole:.3g} s (now {record.t[-1] - record.t[0]:.3g} s), or give --validation"
    if other.duration >= 2 * need:  # the other part has room to spare
        verb = "raise" if seg.name == "held-out" else "lower"
        advice += f", or {verb} --held-out-fraction (now {config.holdout_fraction:g})"
    return advice


def check_record_signs(robot: Robot, record: Record) -> None:
    """The torque-sign check of :func:`~pe_drake.identification.data_checks.check_against_model`
    on the diagnosis's own filtered record, so a file is filtered once."""
    idx = record.usable()
    check_against_model(robot, Measurement(record.t[idx], record.q[idx], record.tau[idx], record.v[idx],
                                           record.vd[idx], robot.joint_names, record.source))


#: What diagnose holds per fitted sample of a 7-joint log (it fits at 200 Hz at most), rounded
#: up from the peak on 10 minutes (a longer log's float32 columns need less), and its fixed
#: part [bytes].
DIAGNOSE_BYTES_PER_SAMPLE = 7.0e3
DIAGNOSE_BASE_BYTES = 0.25e9
FIT_RATE_HZ = 200.0


def check_fits_in_memory(data: Measurement, validation: Measurement | None = None,
                         available: int | None = None) -> None:
    """Refuses, before any work, a run diagnose would need more memory for than is available."""
    available = available_bytes() if available is None else available
    samples = sum(m.duration * min(m.rate_hz, FIT_RATE_HZ) for m in (data, validation) if m is not None)
    per_sample = DIAGNOSE_BYTES_PER_SAMPLE * max(data.num_joints, 1) / 7.0
    need = DIAGNOSE_BASE_BYTES + per_sample * samples
    usable = None if available is None else 0.8 * available  # the estimate's spread, and the rest of the machine
    if usable is not None and need > usable:
        fits = max(usable - DIAGNOSE_BASE_BYTES, 0.0) / per_sample / min(data.rate_hz, FIT_RATE_HZ) / 60.0
        raise DataError(
            f"diagnose would need about {need / 1e9:.1f} GB for {data.duration / 60:.1f} min of data "
            f"({per_sample * min(data.rate_hz, FIT_RATE_HZ) / 1e6:.1f} MB per second of this log); this machine "
            f"has {available / 1e9:.1f} GB available: diagnose a part of the run (about {fits:.0f} min) and "
            "identify the whole of it (pe-drake identify reads an hour at 1 kHz in under 2 GB)", file=data.source)


def model_file_friction(robot: Robot, seg: Segment) -> np.ndarray:
    """The friction the model file holds, d·v + f_c·tanh(v/v_s), along a segment, (S, n) [N·m]
    (``friction``, which Drake ignores, is part of the a-priori model as in ``identify``)."""
    return robot.joint_damping * seg.v + robot.joint_friction * seg.coulomb
