"""Checks of measured data against the robot and its a-priori model, before identification.

Each refuses with the file, the column and the row (the header is row 1), and the likely fix:
time in milliseconds or a rate too low to identify; repeated or decreasing time stamps; joint
positions far outside the robot's limits (with a degrees or mm hint); a torque column whose sign
is flipped against the a-priori model. Holes in the time column are not refused
(:mod:`pe_drake.identification.gaps`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.exceptions import DataError
from pe_drake.identification.csv_checks import check_time_order
from pe_drake.multibody.drive_columns import COULOMB_VELOCITY_SCALE, coulomb_column
from pe_drake.identification.prediction import robot_torques

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Lowest sample rate accepted [Hz].
MIN_RATE_HZ = 10.0
#: Slack beyond the position limits before data is refused [rad or m].
POSITION_SLACK = 0.1
#: Cosine similarity of measured and model torque below which a column is called flipped.
FLIP_SIMILARITY = -0.3


def check_time_column(t: np.ndarray, source: str = "") -> None:
    """Refuses repeated or decreasing time stamps, time in milliseconds and too low a rate.

    Raises:
        DataError: naming the file, column 't' and the row.
    """
    t = np.asarray(t, float)
    # The CSV readers refuse these with file lines; a bag's or a caller's own data lands here.
    check_time_order(t, source)
    if len(t) < 3:
        return
    dt = np.diff(t)
    step = float(np.median(dt))
    rate = 1.0 / step
    if rate < MIN_RATE_HZ:
        hint = ""
        if 0.5 <= step <= 20 and t[-1] - t[0] > 100:
            hint = "; the time column looks like milliseconds: divide it by 1000 to get seconds"
        raise DataError(f"median time step {step:.4g} s ({rate:.3g} Hz) is too slow for "
                        f"identification (at least {MIN_RATE_HZ:g} Hz expected){hint}", file=source,
                        column="t")


def check_positions(robot: Robot, q: np.ndarray, source: str = "") -> None:
    """Refuses positions far outside the robot's limits; says so when they look like degrees.

    Raises:
        DataError: naming the file, the column q.<joint> and the row.
    """
    q = np.asarray(q, float)
    lim = robot.limits
    slack = POSITION_SLACK + float(getattr(robot.config, "position_margin", 0.0))
    lo, hi = lim.q_lower - slack, lim.q_upper + slack
    if q.size == 0:
        return
    worst = []  # per joint (how far out, first row): a column at a time, an hour's log is not copied thrice
    for j in range(q.shape[1]):
        over = np.maximum(lo[j] - q[:, j], q[:, j] - hi[j])
        k = int(np.argmax(over))
        worst.append((float(over[k]), k))
    if not any(w > 0 for w, _ in worst):
        return
    top = max(w for w, _ in worst)
    k, j = min((k, j) for j, (w, k) in enumerate(worst) if w == top)  # as argmax over rows, then joints
    name = robot.joint_names[j]
    prismatic = robot.joints[j].kind == "prismatic"
    # a prismatic joint's likely unit slip is mm, not degrees (issue 37)
    scaled = q[:, j] / 1000 if prismatic else q[:, j] * math.pi / 180
    slipped = bool(np.all((scaled >= lo[j]) & (scaled <= hi[j]))) and np.abs(q[:, j]).max() > (1.0 if prismatic else 2 * math.pi)
    if not slipped:
        hint = "; check the units (rad or m) and the joint order of the columns"
    elif prismatic:
        hint = "; the column looks like mm: divide by 1000 to get m"
    else:
        hint = "; the column looks like degrees: multiply by π/180 to get rad"
    raise DataError(f"position {q[k, j]:.6g} is outside the limits [{lim.q_lower[j]:.4g}, "
                    f"{lim.q_upper[j]:.4g}] of joint '{name}'{hint}", file=source,
                    column=f"q.{name}", row=k + 2)  # the header is row 1


def check_raw_measurement(robot: Robot, measurement) -> None:
    """Time column and positions of a raw measurement (:func:`check_time_column`,
    :func:`check_positions`)."""
    check_time_column(measurement.t, measurement.source)
    check_positions(robot, measurement.q, measurement.source)


def check_torque_signs(measured, predicted: np.ndarray, joints, source: str = "", relevant: float = 0.05) -> np.ndarray:
    """Refuses a torque column whose sign is flipped against the a-priori model.

    The uncentred cosine similarity s_j = Σ τ_m τ_p / (|τ_m| |τ_p|) keeps gravity (the bulk of
    a slow run's torque) in the comparison: a correct column gives s near +1, a flipped one
    near −1. Joints whose predicted RMS is below ``relevant`` × the largest are skipped
    (friction-dominated, the model says little there).

    ``measured`` and ``predicted`` (the a-priori model's) are torques, shape (T, n) [N·m];
    returns s per joint, (n,) (NaN where skipped).

    Raises:
        DataError: naming the file and the column, with the similarity.
    """
    m, p = np.asarray(measured, float), np.asarray(predicted, float)
    rms_p = np.sqrt(np.mean(p**2, axis=0))
    rms_m = np.sqrt(np.mean(m**2, axis=0))
    s = np.full(m.shape[1], np.nan)
    ok = (rms_p >= relevant * rms_p.max()) & (rms_m > 0) if rms_p.max() > 0 else np.zeros(m.shape[1], bool)
    s[ok] = np.sum(m[:, ok] * p[:, ok], axis=0) / (len(m) * rms_m[ok] * rms_p[ok])
    flipped = np.flatnonzero(ok & (s < FLIP_SIMILARITY))
    if len(flipped):
        j = int(flipped[np.argmin(s[flipped])])
        raise DataError(f"the torque looks sign-flipped: its similarity with the a-priori "
                        f"model's torque is {s[j]:+.2f} (about +1 expected); negate the column, or "
                        "check the joint's sign convention and the column order", file=source,
                        column=f"tau.{joints[j]}")
    return s


def check_against_model(robot: Robot, prepared) -> np.ndarray:
    """:func:`check_torque_signs` of preprocessed data against the robot's a-priori model: the
    similarity per joint (empty when the data has no torque columns, only a wrench)."""
    if prepared.tau is None:
        return np.empty(0)
    return check_torque_signs(prepared.tau, a_priori_torque(robot, prepared), prepared.joints, prepared.source)


def a_priori_torque(robot: Robot, prepared, coulomb: np.ndarray | None = None) -> np.ndarray:
    """The a-priori model's joint torques at the samples of ``prepared``, (S, n) [N·m]: the
    model file's inertias and its joint friction d·v + f_c·tanh(v/v_s).

    Args:
        coulomb: the Coulomb columns tanh(v/v_s) at v_s = ``COULOMB_VELOCITY_SCALE``, parallel-
            filtered like the torque (:func:`~pe_drake.identification.drive_terms.filtered_coulomb`);
            None: tanh of ``prepared``'s v.
    """
    if coulomb is None:
        coulomb = coulomb_column(prepared.v, COULOMB_VELOCITY_SCALE)
    rigid = robot_torques(robot, prepared, robot.phi_model)
    return rigid + robot.joint_damping * prepared.v + robot.joint_friction * coulomb
