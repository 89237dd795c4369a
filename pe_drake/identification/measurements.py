"""Measured joint data: the CSV format every data-reading command uses, and its unit check.

File format (SI units, one row per sample, comma separated, one header line):

- ``t``: time [s], strictly increasing, not necessarily uniform;
- ``q.<joint>``: joint position [rad or m], for every excited joint;
- ``tau.<joint>``: joint torque [N·m or N] the actuator applies, for every excited joint;
- ``v.<joint>``: joint velocity [rad/s or m/s], optional (all joints or none);
- ``vdot.<joint>``: joint acceleration [rad/s² or m/s²], optional (all joints or none);
- ``wrench.fx, wrench.fy, wrench.fz, wrench.mx, wrench.my, wrench.mz``: the wrench the ground
  applies to the robot [N, N·m] (world frame, moment about the world origin), optional (all
  six or none); with them the ``tau.<joint>`` columns may be left out (a robot without
  joint-torque sensors, identified from its feet's force/torque sensors).

Columns may come in any order; columns with none of the prefixes above are ignored. Messages
count **data rows from 1** (the first line after the header is data row 1) and give the file line.
"""

from __future__ import annotations

import dataclasses
import io
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pe_drake.exceptions import ConfigError, DataError
from pe_drake.identification.csv_checks import check_time_order
from pe_drake.identification.csv_table import read_header_line, read_table
from pe_drake.io_utils import atomic_write_text
from pe_drake.multibody.wrench import WRENCH_COLUMNS
from pe_drake.output_paths import output_file

#: Column prefixes of the format, in the order written.
PREFIXES = ("q", "v", "vdot", "tau")
#: The fields of a :class:`Measurement` with one row per sample.
SAMPLE_FIELDS = ("t", "q", "tau", "v", "vd", "wrench")


@dataclasses.dataclass(frozen=True)
class Preprocessing:
    """What :func:`~pe_drake.identification.preprocessing.preprocess` chose, for reports.

    Attributes:
        cutoff_source: "argument", "trajectory" or "spectrum"
            (:func:`~pe_drake.identification.preprocessing.choose_cutoff`).
        input_rate_hz: median sample rate of the raw data [Hz]; rate_hz: of the output [Hz].
        resampled: the raw time was not uniform and was linearly interpolated onto a grid.
        trim_s: time dropped at each end [s].
        velocity_source, acceleration_source: "measured" (filtered columns) or "differentiated".
        duration_in_s, duration_out_s: time span of the raw record and of the output [s].
        segments: records filtered on their own and stacked (:mod:`~pe_drake.identification.gaps`).
    """

    cutoff_hz: float
    cutoff_source: str
    filter_order: int
    input_rate_hz: float
    resampled: bool
    rate_hz: float
    trim_s: float
    velocity_source: str
    acceleration_source: str
    samples_in: int
    samples_out: int
    duration_in_s: float = 0.0
    duration_out_s: float = 0.0
    segments: int = 1

    def describe(self) -> str:
        """One line for a command's output: what was done to the raw data."""
        grid = (f"resampled onto a uniform {self.input_rate_hz:.0f} Hz grid (the raw time steps vary), "
                if self.resampled else "")
        return (f"preprocessing: {grid}low-pass {self.cutoff_hz:.2f} Hz ({self.cutoff_source}), "
                f"{self.samples_out} samples at {self.rate_hz:.0f} Hz from {self.samples_in} raw rows, "
                f"{self.trim_s:.2f} s trimmed at each end ({self.duration_out_s:.2f} of {self.duration_in_s:.2f} s "
                f"used), v {self.velocity_source}, vdot {self.acceleration_source}")


@dataclasses.dataclass(frozen=True, eq=False)
class Measurement:
    """Joint data of one run (units of the module docstring).

    Attributes:
        t: time, shape (T,) [s], strictly increasing.
        q, tau, v, vd: shape (T, n); tau None when only the ground wrench was measured, v and
            vd None when not measured.
        joints: joint names, length n, in column order of q/tau/v/vd.
        source: file the data came from ("" when built in memory).
        preprocessing: what :func:`~pe_drake.identification.preprocessing.preprocess` did, or
            None for raw data.
        wrench: the ground wrench, shape (T, 6) (columns :data:`WRENCH_COLUMNS`), or None.
        notes: what reading and preprocessing did that a user should know, one sentence each.
    """

    t: np.ndarray
    q: np.ndarray
    tau: np.ndarray | None
    v: np.ndarray | None = None
    vd: np.ndarray | None = None
    joints: tuple[str, ...] = ()
    source: str = ""
    preprocessing: Preprocessing | None = None
    wrench: np.ndarray | None = None
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        t = np.asarray(self.t, float)
        if t.ndim != 1:
            raise DataError(f"t must have shape (T,), got {t.shape}", file=self.source)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "joints", tuple(self.joints))
        object.__setattr__(self, "notes", tuple(self.notes))
        n = len(self.joints)
        if self.wrench is not None:
            wrench = np.asarray(self.wrench, float)
            if wrench.shape != (t.shape[0], 6):
                raise DataError(f"wrench has shape {wrench.shape}, expected ({t.shape[0]}, 6)", file=self.source)
            object.__setattr__(self, "wrench", wrench)
        for name in ("q", "tau", "v", "vd"):
            value = getattr(self, name)
            if value is None:
                if name == "q" or (name == "tau" and self.wrench is None):
                    raise DataError(f"{name} is required" + (" (or the wrench)" if name == "tau" else ""),
                                    file=self.source)
                continue
            value = np.asarray(value, float)
            if value.shape != (t.shape[0], n):
                raise DataError(f"{name} has shape {value.shape}, expected ({t.shape[0]}, {n}) for "
                                f"{t.shape[0]} samples of joints {', '.join(self.joints)}",
                                file=self.source)
            object.__setattr__(self, name, value)

    @property
    def num_samples(self) -> int:
        return self.t.shape[0]

    @property
    def num_joints(self) -> int:
        return len(self.joints)

    @property
    def duration(self) -> float:
        """t[-1] - t[0] [s]."""
        return float(self.t[-1] - self.t[0]) if self.num_samples else 0.0

    @property
    def rate_hz(self) -> float:
        """Median sample rate [Hz]."""
        return float(1.0 / np.median(np.diff(self.t))) if self.num_samples > 1 else 0.0

    def replace(self, **changes) -> Measurement:
        """A copy with some fields changed (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)

    def take(self, rows: slice | np.ndarray) -> Measurement:
        """The samples ``rows`` (a slice, indices or a mask) of every per-sample field."""
        return self.replace(**{f: None if getattr(self, f) is None else getattr(self, f)[rows]
                               for f in SAMPLE_FIELDS})

    def summary_lines(self) -> list[str]:
        """The run in one line (file, samples, duration, rate), then what reading it did."""
        return [f"data {self.source}: {self.num_samples} samples, {self.duration:.2f} s at {self.rate_hz:.0f} Hz",
                *(f"note: {note}" for note in self.notes)]

    def write(self, folder: str | Path, *, name: str = "measurement.csv") -> list[str]:
        """Writes the run as pe_drake's CSV ``folder/name``, whole or not at all; returns its path."""
        path = output_file(folder, name)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_measurement_csv(path, self)
        return [str(path)]


def _expected_columns(joints: Sequence[str]) -> list[str]:
    return ["t"] + [f"q.{j}" for j in joints] + [f"tau.{j}" for j in joints]


def read_measurement_csv(path: str | Path, joints, *, min_rows: int = 10) -> Measurement:
    """Reads and validates a measurement CSV (format in the module docstring).

    Args:
        joints: the robot's excited joints (names in the robot's order), or a ``Robot``.

    Returns:
        The :class:`Measurement`, joints in the order given (not the file's column order).

    Raises:
        DataError: a missing or empty file, a missing, unknown or repeated column, ``v.``/
            ``vdot.`` for only some joints, a bad row or value, time that does not strictly
            increase, fewer than ``min_rows`` rows: naming the column and the data row.
    """
    path, file = Path(path), str(path)
    joints = getattr(joints, "joint_names", joints)  # a Robot or a sequence of names
    if isinstance(joints, str):
        raise ConfigError(f"joints must be a sequence of joint names, got the string '{joints}'")
    joints = tuple(joints)
    header_line, columns = read_header_line(path)
    has_wrench = _all_or_none(list(WRENCH_COLUMNS), columns, file,
                              "ground-wrench columns are incomplete: {} missing; give all of "
                              + ", ".join(WRENCH_COLUMNS) + " [N, N·m] or none")
    index = _column_index(columns, joints, file, tau_required=not has_wrench)
    has_tau, has_v, has_vd = (
        _all_or_none([f"{prefix}.{j}" for j in joints], index, file,
                     f"'{prefix}.' columns are given for some joints but not for {{}}; give them "
                     "for every joint or for none")
        for prefix in ("tau", "v", "vdot"))
    wanted = ["t"] + [f"q.{j}" for j in joints]
    for prefix, present in (("tau", has_tau), ("v", has_v), ("vdot", has_vd)):
        if present:
            wanted += [f"{prefix}.{j}" for j in joints]
    if has_wrench:
        wanted += list(WRENCH_COLUMNS)

    table, linenos = read_table(path, header_line, columns, wanted, index)
    if table.shape[0] < min_rows:
        raise DataError(f"only {table.shape[0]} data rows; at least {min_rows} are needed", file=file)
    t = table[:, 0]
    check_time_order(t, file, linenos)
    n = len(joints)
    # Views into the one table, not copies: an hour at 1 kHz is read at the table's size.
    wrench = table[:, -6:] if has_wrench else None
    blocks = iter(table[:, 1 + k * n : 1 + (k + 1) * n] for k in range(1 + has_tau + has_v + has_vd))
    q = next(blocks)
    tau, v, vd = (next(blocks) if present else None for present in (has_tau, has_v, has_vd))
    return Measurement(t, q, tau, v, vd, joints, file, wrench=wrench)


def _all_or_none(names: list[str], columns, file: str, message: str) -> bool:
    """Whether the file has every one of ``names`` (not one of them: False; some: DataError with
    ``message`` formatted with the missing ones)."""
    missing = [c for c in names if c not in columns]
    if missing and len(missing) < len(names):
        raise DataError(message.format(", ".join(missing)), file=file, column=missing[0])
    return bool(names) and not missing


def _column_index(columns: list[str], joints: tuple[str, ...], file: str, tau_required: bool = True) -> dict[str, int]:
    index: dict[str, int] = {}
    for k, name in enumerate(columns):
        if name in index:
            raise DataError(f"column '{name}' appears twice (fields {index[name] + 1} and {k + 1})",
                            file=file, column=name)
        index[name] = k
        prefix, dot, joint = name.partition(".")
        if dot and prefix in PREFIXES and joint not in joints:
            raise DataError(f"'{joint}' is not one of the robot's excited joints; valid joints: "
                            f"{', '.join(joints)} (rename or drop the column)", file=file,
                            column=name)
    required = [c for c in _expected_columns(joints) if tau_required or not c.startswith("tau.")]
    missing = [c for c in required if c not in index]
    if missing:
        raise DataError(f"missing column(s) {', '.join(missing)}; expected columns: "
                        f"{', '.join(_expected_columns(joints))} (optional: v.<joint>, "
                        f"vdot.<joint>; {', '.join(WRENCH_COLUMNS)}, which make tau.<joint> "
                        "optional)", file=file, column=missing[0])
    return index


def measurement_to_csv_text(measurement: Measurement) -> str:
    """The CSV text of a measurement, 10 significant digits; DataError for a NaN or inf value."""
    m = measurement
    header = ["t"] + [f"q.{j}" for j in m.joints]
    blocks = [m.t[:, None], m.q]
    for prefix, x in (("v", m.v), ("vdot", m.vd), ("tau", m.tau)):
        if x is not None:
            header += [f"{prefix}.{j}" for j in m.joints]
            blocks.append(x)
    if m.wrench is not None:
        header += list(WRENCH_COLUMNS)
        blocks.append(m.wrench)
    table = np.hstack(blocks)
    bad = ~np.isfinite(table)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise DataError("value is not finite; refusing to write it", file=m.source,
                        column=header[c], row=int(r) + 1)
    buffer = io.StringIO()
    np.savetxt(buffer, table, fmt="%.10g", delimiter=",", header=",".join(header), comments="")
    return buffer.getvalue()


def write_measurement_csv(path: str | Path, measurement: Measurement) -> None:
    """Writes a measurement CSV atomically; DataError when a value is NaN or infinite."""
    atomic_write_text(path, measurement_to_csv_text(measurement))


def check_torque_units(measurement: Measurement, tau_predicted: np.ndarray, *,
                       max_ratio: float = 30.0, joint_max_ratio: float = 300.0) -> np.ndarray:
    """Refuses torques that are off by orders of magnitude from a model's prediction.

    Compares RMS values (mean included: gravity torques are the bulk of a slow run): all
    joints together must agree within ``max_ratio``; each joint within ``joint_max_ratio``,
    checked only on joints whose predicted RMS is at least 1 % of the largest one (light
    distal joints are friction-dominated, so their ratio says little about units).

    Returns the per-joint ratios RMS(measured) / RMS(``tau_predicted`` (T, n) [N·m]), (n,).

    Raises:
        DataError: naming the file and the column, with the likely unit fix.
    """
    tau = measurement.tau
    pred = np.asarray(tau_predicted, float)
    if pred.shape != tau.shape:
        raise DataError(f"predicted torques have shape {pred.shape}, measured {tau.shape}",
                        file=measurement.source)
    rms_m = np.sqrt(np.mean(tau**2, axis=0))
    rms_p = np.sqrt(np.mean(pred**2, axis=0))
    tiny = np.finfo(float).tiny
    with np.errstate(over="ignore"):  # a model without inertials predicts 0: ratio inf, not a warning
        ratios = rms_m / np.maximum(rms_p, tiny)
    overall_m, overall_p = math.sqrt(float(np.mean(tau**2))), math.sqrt(float(np.mean(pred**2)))
    if overall_p > 0:
        overall = overall_m / overall_p
        if not 1 / max_ratio <= overall <= max_ratio:
            worst = int(np.argmax(np.abs(np.log10(np.maximum(ratios, tiny)))))
            raise DataError(f"torques are {_factor_text(overall)} the model's prediction over all "
                            f"joints (RMS {overall_m:.4g} vs {overall_p:.4g} N·m); "
                            f"{_unit_hint(overall)}", file=measurement.source,
                            column=f"tau.{measurement.joints[worst]}")
    relevant = rms_p >= 0.01 * rms_p.max() if rms_p.max() > 0 else np.zeros_like(rms_p, bool)
    for k in np.nonzero(relevant)[0]:
        r = ratios[k]
        if not 1 / joint_max_ratio <= r <= joint_max_ratio:
            raise DataError(f"torque is {_factor_text(r)} the model's prediction (RMS "
                            f"{rms_m[k]:.4g} vs {rms_p[k]:.4g} N·m); {_unit_hint(r)}",
                            file=measurement.source, column=f"tau.{measurement.joints[k]}")
    return ratios


#: Measured/model torque ratios in this range look like motor currents [A] taken for torques:
#: τ = k·i with drive gains k of a few to a few tens of N·m/A.
AMPS_RATIO = (1 / 30, 0.3)


def amps_hint(measurement: Measurement, ratios: np.ndarray) -> str:
    """A hint when the torques look like motor currents (RMS 1/30-0.3× the model's), else "".

    ``ratios``: RMS(measured) / RMS(model) per joint (:func:`check_torque_units`).
    """
    lo, hi = AMPS_RATIO
    low = [j for j, r in zip(measurement.joints, np.asarray(ratios, float)) if lo <= r <= hi]
    if not low or len(low) < max(1, len(measurement.joints) // 2):
        return ""
    return (
        f"the torques of {', '.join(low)} are {_factor_text(float(np.median(ratios)))} the model's: if the "
        "file holds motor currents [A], name the columns current.<joint> (a ROS bag: --effort current) and "
        "give robot.drive_gains {joint: k [N·m/A]} (τ = k·i)"
    )


def _factor_text(ratio: float) -> str:
    if ratio >= 1:
        return f"{ratio:.3g}× larger than"
    return f"{1 / ratio:.3g}× smaller than" if ratio > 0 else "zero compared with"


def _unit_hint(ratio: float) -> str:
    if ratio <= 0:
        return "the column holds only zeros"
    exponent = math.log10(ratio)
    if abs(exponent - 3) < 0.7:
        return "the file is probably in N·mm (or mN·m): divide the torques by 1000 to get N·m"
    if abs(exponent + 3) < 0.7:
        return "the file is probably in kN·m: multiply the torques by 1000 to get N·m"
    return "check the torque units (N·m expected) and the sign/joint order of the columns"
