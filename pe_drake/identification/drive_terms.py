"""Drive terms of the identification model: joint friction, torque offsets and rotor inertia.

Per joint, Coulomb tanh(v/v_s), viscous v, offset 1 and armature v̇ columns on that joint's row
(:mod:`pe_drake.multibody.drive_columns`), so τ = Y_B φ_B + D θ. This module holds what identify
does with them: the fitted values and their σ, the model file's friction, the data's
separability, the outputs.

**The model file's friction** (a URDF's ``<dynamics damping>`` and ``friction``) is part of the
a-priori model. A fitted viscous or Coulomb column estimates the joint's *total* friction; a
term the fit does not have keeps the model file's value (:func:`model_file_terms`): subtracted
from the measured torque before the fit, a drive term with ``"source": "model file"``, σ = 0.

**Through a transmission** the terms are each motor's, acting on the joints through Rᵀ;
identified.json holds them under ``motors`` with their ``joint_side`` view (:func:`joint_side`),
and the model file's joint friction is not used.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from pe_drake.exceptions import shorten
from pe_drake.identification.friction_velocity import friction_velocity
from pe_drake.identification.lowpass import design_lowpass
from pe_drake.identification.preprocessing import resample_uniform
from pe_drake.multibody.drive_columns import (COULOMB_VELOCITY_SCALE, NONNEGATIVE, TERMS, UNITS,
                                              DriveLayout, coulomb_column, model_tables,
                                              drive_columns, coulomb_velocities)
from pe_drake.multibody.dahl import dahl_state
from pe_drake.multibody.robot_model import RobotModel
from pe_drake.multibody.transmission import Transmission

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


def layout_torque(layout: DriveLayout, theta: np.ndarray, v: np.ndarray, vd: np.ndarray,
                  coulomb: np.ndarray | None = None) -> np.ndarray:
    """D θ of ``layout``'s columns at the samples, (S, n) [N·m], a block of samples at a time."""
    out = np.empty(np.shape(v))
    for s in range(0, out.shape[0], 20000):
        k = slice(s, s + 20000)
        out[k] = drive_columns(v[k], vd[k], layout, None if coulomb is None else coulomb[k]) @ theta
    return out


def with_known(layout: DriveLayout, theta: np.ndarray, sigma: np.ndarray,
               known: tuple[DriveLayout, np.ndarray] | None) -> tuple[DriveLayout, np.ndarray, np.ndarray]:
    """The fitted columns with the model file's terms ``known`` (:func:`model_file_terms`)
    appended, σ = 0: (layout, θ, σ)."""
    if known is None or not known[0].count:
        return layout, theta, sigma
    b = known[0]
    layout = dataclasses.replace(layout, terms=layout.terms + b.terms, joints=layout.joints + b.joints,
                                 units=layout.units + b.units, known=layout.known + b.labels)
    return layout, np.r_[theta, known[1]], np.r_[sigma, np.zeros(b.count)]


def layout_values(model: RobotModel, layout: DriveLayout) -> tuple[np.ndarray, np.ndarray]:
    """(θ, σ) of ``layout``'s columns in ``model`` (σ NaN where the model has none), each (d,)."""
    nan = np.full(len(model.joints), np.nan)
    theta = np.array([model.term(t)[j] for t, j in zip(layout.terms, layout.joints)], float)
    sigma = np.array([model.sigma.get(t, nan)[j] for t, j in zip(layout.terms, layout.joints)], float)
    return theta, sigma


def drive_torque(model: RobotModel, layout: DriveLayout | None, v: np.ndarray, vd: np.ndarray,
                 coulomb: np.ndarray | None = None) -> np.ndarray | None:
    """The fitted drive terms' torque D θ, (S, n) [N·m] (the merged armatures are in the base
    parameters), or None when the fit has no drive columns."""
    if layout is None or not layout.count:
        return None
    return layout_torque(layout, layout_values(model, layout)[0], v, vd, coulomb)


def drive_block(model: RobotModel, layout: DriveLayout, physical: bool) -> dict[str, Any]:
    """identified.json's ``drive_terms`` block of a fit: {joint: {term: {value, sigma, sigma_percent,
    unit}}} under ``joints``, or under ``motors`` with the ``transmission`` and the ``joint_side``
    view (``physical``: the merged armatures' values, the model's, are the physical fit's)."""
    theta, sigma = layout_values(model, layout)
    table: dict[str, Any] = {name: {} for name in layout.joint_names}
    for t, j, u, x, s in zip(layout.terms, layout.joints, layout.units, theta, sigma):
        table[layout.joint_names[j]][t] = {
            "value": float(x), "sigma": float(s), "sigma_percent": percent_or_none(x, s), "unit": u}
        if f"{t}[{layout.joint_names[j]}]" in layout.known:
            table[layout.joint_names[j]][t]["source"] = "model file"
    for name, coef in layout.merged.items():
        table[name]["armature"] = {"value": None, "identifiable": False, "merged_into": coef,
                                   "note": "in the span of the rigid-body base columns: only the sum with "
                                           "these base parameters is identifiable"}
        if physical:  # included in the base parameters
            table[name]["armature"]["physical_fit_value"] = float(model.armature[layout.joint_names.index(name)])
    T = layout.transmission
    side = {"joints": table} if T is None else {
        "motors": table, "transmission": T.to_dict(), "joint_side": joint_side(layout, theta),
        "motor_coulomb_model": "coulomb * tanh(theta_dot_m / (|R_ii| velocity_scale)), theta_dot_m = R v; "
                               "every term acts on the joints through R^T"}
    return {**side, "velocity_scale": layout.velocity_scale,
            "coulomb_model": "coulomb * tanh(v / velocity_scale)",
            "torque_equation": "tau = Y_B(q, v, vd) phi_B + coulomb*tanh(v/v_s) + viscous*v + offset "
                               "+ armature*vd",
            "friction": "viscous and coulomb are each joint's total friction; 'source: model file' marks "
                        "a value kept from the model file's <dynamics> (not estimated)",
            "dropped": dict(layout.dropped)}


def joint_side(layout: DriveLayout, theta: np.ndarray) -> dict[str, Any]:
    """A per-motor fit (``layout``'s columns, values ``theta``) as the joints see it (module
    docstring): ``coulomb`` {motor: {joint: |R_ij|·F_c,i}} [N·m] (the amplitude on the joint;
    its sign follows θ̇_m), ``offset`` {joint: (Rᵀ o)_j}, ``viscous`` and ``armature`` {joint:
    {joint: (Rᵀ diag(x) R)_jk}}; joints a motor does not turn are left out."""
    T, names = layout.transmission, layout.joint_names
    table, zero = model_tables(layout, theta, theta, {})[0], np.zeros(len(names))
    values = {t: table.get(t, zero) for t in TERMS["all"]}

    def matrix(M):
        return {a: {b: float(M[j, k]) for k, b in enumerate(names) if M[j, k] != 0} for j, a in enumerate(names)}

    return {"coulomb": {m: {j: float(abs(r) * values["coulomb"][i]) for j, r in zip(names, T.R[i]) if r != 0}
                        for i, m in enumerate(names) if values["coulomb"][i] != 0},
            "offset": dict(zip(names, map(float, T.R.T @ values["offset"]))),
            "viscous": matrix(T.reflected(values["viscous"])), "armature": matrix(T.reflected(values["armature"])),
            "units": "N·m, N·m, N·m·s/rad, kg·m² of the joints"}


def model_file_terms(robot: Robot, layout: DriveLayout) -> tuple[DriveLayout, np.ndarray] | None:
    """The model file's friction that ``layout`` does not estimate, as columns (labels in their
    ``known``) and values (module docstring), or None when there is none (always with a
    transmission)."""
    if layout.transmission is not None:
        return None
    fitted = set(zip(layout.terms, layout.joints))
    cols = [(t, j, float(x)) for j in range(robot.n)
            for t, x in (("coulomb", robot.joint_friction[j]), ("viscous", robot.joint_damping[j]))
            if x != 0 and (t, j) not in fitted]
    if not cols:
        return None
    units = tuple(UNITS[t][0 if robot.joints[j].kind == "revolute" else 1] for t, j, _ in cols)
    known = DriveLayout(tuple(t for t, _, _ in cols), tuple(j for _, j, _ in cols), layout.joint_names, units,
                        layout.velocity_scale)
    return dataclasses.replace(known, known=known.labels), np.array([x for _, _, x in cols])


def model_file_terms_lost(robot: Robot, kept: DriveLayout, asked: DriveLayout,
                          known: tuple[DriveLayout, np.ndarray] | None
                          ) -> tuple[tuple[DriveLayout, np.ndarray] | None, np.ndarray]:
    """The model file's friction once the data has dropped some of the columns ``asked``: a
    column the data cannot separate keeps the model file's value.

    Args:
        kept: the columns the data separates (:func:`separable_on_data`).
        known: :func:`model_file_terms` of ``asked`` (already subtracted from the torque).

    Returns:
        (:func:`model_file_terms` of ``kept``, the values to subtract now: per column of
        ``asked``, the model file's value of the lost columns, else 0, shape (asked.count,)).
    """
    after = model_file_terms(robot, kept)
    before = set(known[0].labels) if known is not None else set()
    lost = np.zeros(asked.count)
    for label, value in zip(after[0].labels, after[1]) if after is not None else ():
        if label not in before:
            lost[asked.labels.index(label)] = value
    return after, lost


#: A least-squares friction or armature this many σ (correlation-inflated) below zero is
#: reported as unphysical: a term whose true value is 0 is named with a one-sided chance of 0.13 %.
UNPHYSICAL_SIGMAS = 3.0


def unphysical_drive_terms(model: RobotModel, layout: DriveLayout) -> list[str]:
    """A warning naming the fitted terms (``layout``'s columns of ``model``) that must be ≥ 0
    (friction, armature) and are below zero by more than :data:`UNPHYSICAL_SIGMAS` σ, or none."""
    theta, sigma = layout_values(model, layout)
    bad = [f"{label} {value:.3g} ± {s:.2g} {unit}"
           for label, term, value, s, unit in zip(layout.labels, layout.terms, theta, sigma, layout.units)
           if term in NONNEGATIVE and label not in layout.known and s > 0 and value < -UNPHYSICAL_SIGMAS * s]
    if not bad:
        return []
    return [f"warning: {len(bad)} drive term(s) negative beyond {UNPHYSICAL_SIGMAS:g}σ, which no drive can have: "
            + "; ".join(bad[:4]) + (" …" if len(bad) > 4 else "") + ". They absorb something the model lacks "
            "(a time shift between the logs, friction smoother than tanh(v/v_s), ...): --method physical keeps "
            "them ≥ 0, pe-drake diagnose tests what else is missing"]


def percent_or_none(value: float, sigma: float) -> float | None:
    """100·σ/|value| [%], None when value is 0 or either is not finite."""
    if not (math.isfinite(value) and math.isfinite(sigma)) or value == 0:
        return None
    return 100.0 * abs(sigma) / abs(value)


def format_percent(p: float | None) -> str:
    """A relative σ for people: "3.2 %", ">1000 % (undetermined)" or "undetermined"."""
    if p is None or not math.isfinite(p):
        return "undetermined"
    if p > 1000:
        return ">1000 % (undetermined)"
    return f"{p:.3g} %"


#: A drive column is dropped when, with every column scaled to unit norm, the smallest singular
#: value of [Y_B | D] is below this fraction of the largest and the column carries the most of
#: that direction: the data cannot tell it from the others (e.g. a joint that never reverses).
DATA_COLLINEARITY = 1e-8


def separable_on_data(W_base: np.ndarray, D: np.ndarray, layout: DriveLayout) -> tuple[DriveLayout, list[int]]:
    """The drive columns D (rows, d) this data set can tell apart from the others and the base
    regressor's rows W_base (rows, b): (the layout of the kept columns, their indices into D)."""
    b = W_base.shape[1]
    keep = list(range(D.shape[1]))
    reasons: dict[str, str] = {}
    A = np.column_stack([W_base, D])
    norms = np.linalg.norm(A, axis=0)
    for k in range(D.shape[1]):
        if norms[b + k] == 0:
            reasons[layout.labels[k]] = "its column is zero on this data (the joint does not move or accelerate)"
            keep.remove(k)
    A = A / np.where(norms > 0, norms, 1.0)
    while keep:
        R = np.linalg.qr(A[:, list(range(b)) + [b + k for k in keep]], mode="r")
        _, s, Vt = np.linalg.svd(R)
        if s[-1] > DATA_COLLINEARITY * s[0]:
            break
        worst = _armature_against_offset(layout, keep, np.abs(Vt[-1, b:]))
        if worst is not None:
            reasons[layout.labels[worst]] = ARMATURE_ALONG_GRAVITY
        else:
            worst = keep[int(np.argmax(np.abs(Vt[-1, b:])))]
            reasons[layout.labels[worst]] = ("the data cannot tell it from the other columns (e.g. the joint never "
                                             "reverses: Coulomb friction = offset)")
        keep.remove(worst)
    return layout.without(keep, reasons), keep


#: Why the armature of a joint along gravity is left out.
ARMATURE_ALONG_GRAVITY = (
    "a joint along gravity (a vertical lift): the weight it carries has the column g + z̈, so the armature's z̈ "
    "and the offset's constant span only two directions with it; the offset is kept (a counterweight, spring or "
    "brake force is constant) and the armature is merged into the carried mass, which the data give as m + armature")


def _armature_against_offset(layout: DriveLayout, keep: list[int], weight: np.ndarray) -> int | None:
    """The armature column among ``keep`` whose joint's offset column shares the null direction
    (``weight``: its components on ``keep``), or None."""
    big = [k for k, w in zip(keep, weight) if w > 1e-3 * weight.max()]
    for k in big:
        if layout.terms[k] == "armature" and any(layout.terms[o] == "offset" and layout.joints[o] == layout.joints[k]
                                                 for o in big):
            return k
    return None


def drive_summary(model: RobotModel | None, layout: DriveLayout | None) -> list[str]:
    """Lines for a command's output: the fitted drive terms (``layout``'s columns of ``model``)
    per joint with their σ, what was left out."""
    if model is None or layout is None or (layout.count == 0 and not layout.merged):
        return ["drive terms: none (rigid body only)"]
    theta, sigma = layout_values(model, layout)
    T = layout.transmission
    lines = ["drive terms (value ± σ):" if T is None else "drive terms per motor (value ± σ, motor side):"]
    names = layout.joint_names
    for j, name in enumerate(names):
        parts = [f"{t} {x:.4g} {u} (model file)" if f"{t}[{name}]" in layout.known else f"{t} {x:.4g} ± {s:.2g} {u}"
                 for t, jj, u, x, s in zip(layout.terms, layout.joints, layout.units, theta, sigma)
                 if jj == j]
        if name in layout.merged:
            merged = list(layout.merged[name])  # base-parameter compositions: identified.json has them whole
            more = f", … ({len(merged) - 2} more)" if len(merged) > 2 else ""
            parts.append("armature not separable (merged into " + ", ".join(shorten(m, 60) for m in merged[:2])
                         + more + ")")
        if parts:
            lines.append(f"  {'motor ' if T is not None else ''}{name}: " + "; ".join(parts))
    for label, reason in layout.dropped.items():
        lines.append(f"  {label} left out: {reason}")
    return lines + (_joint_side_lines(layout, theta) if T is not None else [])


def _joint_side_lines(layout: DriveLayout, theta: np.ndarray) -> list[str]:
    """The joint side of a per-motor fit, a line per joint (:func:`joint_side`)."""
    side, names = joint_side(layout, theta), layout.joint_names
    lines = ["  joint side (through R): coulomb from each motor, offset, viscous and armature (coupling entries)"]
    for j in names:
        coulomb = ", ".join(f"{x:.4g} N·m (motor {m})" for m, row in side["coulomb"].items() for jj, x in row.items()
                            if jj == j)
        cross = [f"{k} {x:.4g}" for k, x in side["armature"][j].items() if k != j]
        lines.append(f"    {j}: coulomb {coulomb or 0}; offset {side['offset'][j]:.4g} N·m; viscous "
                     f"{side['viscous'][j].get(j, 0.0):.4g} N·m·s/rad; armature {side['armature'][j].get(j, 0.0):.4g} "
                     "kg·m²" + (f" (with {', '.join(cross)})" if cross else ""))
    return lines


def filtered_coulomb(raw, data, velocity_scale: float = COULOMB_VELOCITY_SCALE,
                     transmission: Transmission | None = None) -> np.ndarray | None:
    """The Coulomb columns of preprocessed data, parallel-filtered (Gautier 1997), shape (S, n).

    The torque was low-pass filtered, so its friction part is the filtered tanh(v/v_s), not
    tanh of the filtered v: the smoothed sign has content far above the cut-off. This redoes
    the preprocessing grid on ``raw``, computes tanh(v/v_s) at the full rate of the velocity of
    :func:`~pe_drake.identification.friction_velocity.friction_velocity` (not the torque's
    cut-off, which smears the stick at reversals), filters it with the torque's filter and picks
    the samples of ``data`` (``preprocess(raw, ...)``'s result).

    Args:
        velocity_scale: v_s [rad/s].
        transmission: the motors' columns instead, tanh(θ̇_i / (|R_ii| v_s)) of θ̇ = R q̇.

    Returns:
        The columns at data's samples, or None when ``data`` was not preprocessed.
    """
    p = data.preprocessing
    if p is None:
        return None
    grid = resample_uniform(raw.t, {"q": raw.q, "v": raw.v})
    lowpass = design_lowpass(p.cutoff_hz, grid.rate_hz, len(grid.t), p.filter_order, file=raw.source)
    idx = np.clip(np.rint((data.t - grid.t[0]) / grid.dt).astype(int), 0, len(grid.t) - 1)
    v = friction_velocity(grid.signals["q"], grid.signals["v"], grid.rate_hz, p.cutoff_hz, velocity_scale,
                          p.filter_order, file=raw.source).v
    if transmission is not None:  # a motor turns several joints: every joint's full-rate velocity at once
        w, scale = coulomb_velocities(v, velocity_scale, transmission)
        return lowpass.apply(coulomb_column(w, scale))[idx]
    out = np.empty((len(idx), raw.num_joints))
    for j in range(raw.num_joints):  # a joint at a time: a long log's full-rate columns one by one
        out[:, j] = lowpass.apply(coulomb_column(v[:, j], velocity_scale))[idx]
    return out


def filtered_presliding(raw, data, model: RobotModel) -> np.ndarray | None:
    """A model's pre-sliding (Dahl) friction F_c·z(q; F_c/σ0) at data's samples, (S, n) [N·m],
    filtered as the diagnosis fits it (unfiltered ``data``: the state along its own q), or None
    when the model names no pre-sliding friction."""
    fc, sigma0 = model.presliding, model.presliding_stiffness
    joints = [j for j in range(len(model.joints)) if fc is not None and fc[j] > 0 and sigma0[j] > 0]
    if not joints:
        return None
    out = np.zeros(data.q.shape)
    p = data.preprocessing
    if p is None:
        for j in joints:
            out[:, j] = fc[j] * dahl_state(data.q[:, j], fc[j] / sigma0[j])
        return out
    grid = resample_uniform(raw.t, {"q": raw.q})
    lowpass = design_lowpass(p.cutoff_hz, grid.rate_hz, len(grid.t), p.filter_order, file=raw.source)
    idx = np.clip(np.rint((data.t - grid.t[0]) / grid.dt).astype(int), 0, len(grid.t) - 1)
    for j in joints:
        z = dahl_state(lowpass.apply(grid.signals["q"][:, j]), fc[j] / sigma0[j])
        out[:, j] = fc[j] * lowpass.apply(z)[idx]
    return out
