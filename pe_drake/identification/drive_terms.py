"""Drive terms of the identification model: joint friction, torque offsets and rotor inertia.

The torque an actuator applies is the rigid-body torque plus what the drive itself needs
(friction, offset, armature). Per joint j, each term is linear in its value θ and adds one column to the
regressor, on the row of joint j only (``drive_columns``):

=============  =====================  ===============  ===========  ==========
term           column                 unit (revolute)  (prismatic)  sign of θ
=============  =====================  ===============  ===========  ==========
``coulomb``    tanh(v_j / v_s)        N·m              N            θ ≥ 0
``viscous``    v_j                    N·m·s/rad        N·s/m        θ ≥ 0
``offset``     1                      N·m              N            any
``armature``   v̇_j                   kg·m²            kg           θ ≥ 0
=============  =====================  ===============  ===========  ==========

so τ = Y_B φ_B + D θ with W = [Y_B | D]: the drive block is extra columns, whatever way the
normal equations of W are accumulated. The smoothed sign and its v_s are the diagnosis's
(:mod:`pe_drake.diagnosis.effects`) and the simulator's ``DoorHinge``.

**The model file's friction** (a URDF's ``<dynamics damping>`` and ``friction``) is part of the
a-priori model (issue 21). A viscous or Coulomb column the fit has estimates the joint's *total*
friction (least squares gives the same total whether the model file's value is subtracted
first or not, and the physical fit's bound θ ≥ 0 is on the total), which is what identified.json,
model.urdf (``damping``, ``friction``) and drive_effects.yaml hold. A term the fit does not have
(``--drive-terms none``, or a joint the model file gives friction the chosen terms leave out)
keeps the model file's value (:func:`model_file_terms`): it is subtracted from the measured
torque before the fit and is a drive term with ``"source": "model file"`` and σ = 0. The
diagnosis names only what the model file lacks and gives the same total in its details.

The ground wrench does not see joint friction (it acts between two links of the robot), so
the drive columns are zero in base-wrench rows.

The armature column v̇_j of a joint whose axis is fixed in the world (the first joint of a
fixed-base arm) is exactly the column of the base parameter that holds the link inertia
about that axis: the two are one base parameter (:func:`drive_layout` tests this on random
states, like the diagnosis's ``separability``), and the armature is reported as merged into it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from pe_drake.exceptions import ConfigError, shorten
from pe_drake.identification.preprocessing import design_lowpass, differentiate, resample_uniform
from pe_drake.multibody.regressor import RegressorModel

#: The ``--drive-terms`` choices: no drive terms, Coulomb + viscous + offset, and those with
#: the armature where the robot's kinematics let it be told from the link inertias.
DRIVE_TERMS = ("none", "friction", "all")
#: What ``identify`` models unless told otherwise.
DEFAULT_DRIVE_TERMS = "all"
#: Terms of each choice, in column order per joint.
TERMS = {"none": (), "friction": ("coulomb", "viscous", "offset"), "all": ("coulomb", "viscous", "offset", "armature")}
#: Smoothing velocity v_s of the Coulomb column tanh(v/v_s) [rad/s or m/s]; the diagnosis and
#: the simulator use the same value.
COULOMB_VELOCITY_SCALE = 0.01
#: Terms whose value is physically ≥ 0.
NONNEGATIVE = ("coulomb", "viscous", "armature")
#: ‖(I − P_B) c‖ / ‖c‖ below which an armature column counts as inside span(Y_B) on random
#: states: rounding gives ~1e-14, a separable column O(0.1-1).
SEPARABILITY_TOLERANCE = 1e-6
_UNITS = {"coulomb": ("N·m", "N"), "viscous": ("N·m·s/rad", "N·s/m"), "offset": ("N·m", "N"),
          "armature": ("kg·m²", "kg")}


@dataclasses.dataclass(frozen=True)
class DriveTermOptions:
    """Which drive terms ``identify`` adds.

    Attributes:
        terms: "none", "friction" (Coulomb, viscous, offset per joint) or "all" (also the
            armature of every joint where it is separable from the link inertias).
        velocity_scale: v_s of the Coulomb column tanh(v/v_s) [rad/s or m/s].

    Raises:
        ConfigError: an unknown choice or a non-positive v_s.
    """

    terms: str = DEFAULT_DRIVE_TERMS
    velocity_scale: float = COULOMB_VELOCITY_SCALE

    def __post_init__(self) -> None:
        if self.terms not in DRIVE_TERMS:
            raise ConfigError(f"drive terms '{self.terms}' is not one of {', '.join(DRIVE_TERMS)}")
        v = self.velocity_scale
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise ConfigError(f"the Coulomb velocity scale must be a positive number [rad/s], got {v!r}")


def drive_options(value: DriveTermOptions | str | None) -> DriveTermOptions:
    """``value`` as options: None → the default, a string → that choice."""
    if value is None:
        return DriveTermOptions()
    if isinstance(value, str):
        return DriveTermOptions(value)
    return value


@dataclasses.dataclass(frozen=True)
class DriveLayout:
    """The drive columns of a fit and the armatures left out.

    Attributes:
        terms: term of each column ("coulomb", "viscous", "offset", "armature"), length d.
        joints: joint index of each column, length d.
        joint_names: the robot's excited joints, length n.
        units: unit of each column's value.
        velocity_scale: v_s of the Coulomb columns [rad/s].
        merged: {joint name: {base parameter: coefficient}} of the armatures that are not
            separable from the rigid-body base parameters (only their sum is identifiable).
        dropped: {label: reason} of columns this data set cannot tell apart (e.g. the Coulomb
            column of a joint that never reverses, which equals its offset column).
    """

    terms: tuple[str, ...]
    joints: tuple[int, ...]
    joint_names: tuple[str, ...]
    units: tuple[str, ...]
    velocity_scale: float = COULOMB_VELOCITY_SCALE
    merged: dict[str, dict[str, float]] = dataclasses.field(default_factory=dict)
    dropped: dict[str, str] = dataclasses.field(default_factory=dict)

    @property
    def count(self) -> int:
        return len(self.terms)

    @property
    def labels(self) -> tuple[str, ...]:
        return tuple(f"{t}[{self.joint_names[j]}]" for t, j in zip(self.terms, self.joints))

    def without(self, keep: Sequence[int], reasons: dict[str, str]) -> DriveLayout:
        """The layout with only the columns ``keep``; ``reasons`` of the others go to ``dropped``."""
        keep = list(keep)
        return dataclasses.replace(
            self, terms=tuple(self.terms[k] for k in keep), joints=tuple(self.joints[k] for k in keep),
            units=tuple(self.units[k] for k in keep), dropped={**self.dropped, **reasons})

    def lower_bounds(self) -> np.ndarray:
        """0 for friction and armature, -inf for offsets, shape (d,)."""
        return np.array([0.0 if t in NONNEGATIVE else -np.inf for t in self.terms])


def drive_layout(robot, base, options: DriveTermOptions, model=None, *, rows=None, samples: int = 200,
                 seed: int = 1) -> DriveLayout:
    """The drive columns of ``options`` for ``robot`` (armature: where separable).

    Args:
        robot: a :class:`~pe_drake.multibody.robot.Robot`.
        base: the :class:`~pe_drake.multibody.base_parameters.BaseParameters` of ``rows``.
        options: the choice of terms.
        model: a :class:`~pe_drake.multibody.regressor.RegressorModel` to reuse.
        rows: the :class:`~pe_drake.multibody.sensors.SensorRows` fitted (default: the joint
            torques); the ground wrench's rows separate every armature the torques cannot.
        samples, seed: random states of the armature's separability test.
    """
    terms = TERMS[options.terms]
    names = tuple(robot.joint_names)
    merged = armature_merges(robot, base, model, rows=rows, samples=samples, seed=seed) if "armature" in terms else {}
    cols = [(t, j) for j in range(robot.n) for t in terms if not (t == "armature" and names[j] in merged)]
    units = tuple(_UNITS[t][0 if robot.joints[j].kind == "revolute" else 1] for t, j in cols)
    return DriveLayout(tuple(t for t, _ in cols), tuple(j for _, j in cols), names, units,
                       float(options.velocity_scale), merged)


def armature_merges(robot, base, model=None, *, rows=None, samples: int = 200,
                    seed: int = 1) -> dict[str, dict[str, float]]:
    """{joint: {base parameter: coefficient}} of the armature columns inside span(Y_B).

    Random states within the robot's limits (as the base parameters use) decide whether
    *any* motion separates the column v̇_j from the rigid-body columns. ``rows`` (a
    :class:`~pe_drake.multibody.sensors.SensorRows`, torque channels first) are the rows of
    Y_B (default: the joint torques); the armature's column is zero in ground-wrench rows.
    """
    model = model or RegressorModel(robot)
    rng = np.random.default_rng(seed)
    q = rng.uniform(robot.limits.q_lower, robot.limits.q_upper, (samples, robot.n))
    v = rng.uniform(-1, 1, (samples, robot.n)) * np.minimum(robot.limits.v_max, 3.0)
    vd = rng.uniform(-1, 1, (samples, robot.n)) * np.minimum(robot.limits.vd_max, 10.0)
    Y = model(q, v, vd) if rows is None else rows.rows(rows.kinematics(q, v, vd), scaled=False)
    channels = Y.shape[1]
    Y_B = base.reduce(Y).reshape(-1, base.count)
    scale = np.linalg.norm(Y_B, axis=0)
    scale[scale == 0] = 1.0
    A = Y_B / scale
    out = {}
    for j, name in enumerate(robot.joint_names):
        col = np.zeros((samples, channels))
        col[:, j] = vd[:, j]
        col = col.ravel()
        beta, *_ = np.linalg.lstsq(A, col, rcond=None)
        if np.linalg.norm(col - A @ beta) <= SEPARABILITY_TOLERANCE * np.linalg.norm(col):
            coef = beta / scale
            big = np.flatnonzero(np.abs(coef) > 1e-6 * np.abs(coef).max())
            out[name] = {base.base_names[k]: float(coef[k]) for k in big}
    return out


def coulomb_column(v: np.ndarray, velocity_scale: float) -> np.ndarray:
    """tanh(v / v_s), same shape as v."""
    return np.tanh(np.asarray(v, float) / velocity_scale)


def drive_columns(v: np.ndarray, vd: np.ndarray, layout: DriveLayout, coulomb: np.ndarray | None = None,
                  rows: int | None = None) -> np.ndarray:
    """The drive block D of the regressor, shape (S, rows, d): column k on joint row j_k only.

    Args:
        v, vd: joint velocities and accelerations, each (S, n).
        layout: the columns (:func:`drive_layout`).
        coulomb: the Coulomb columns to use, (S, n) (e.g. tanh(v/v_s) computed at the full
            rate and filtered like the torque); default tanh(v/v_s) of ``v``.
        rows: channels per sample (n torques, then the ground wrench, whose rows stay zero);
            default n.
    """
    S, n = v.shape
    out = np.zeros((S, n if rows is None else rows, layout.count))
    sign = coulomb_column(v, layout.velocity_scale) if coulomb is None else np.asarray(coulomb, float)
    for k, (term, j) in enumerate(zip(layout.terms, layout.joints)):
        if term == "coulomb":
            out[:, j, k] = sign[:, j]
        elif term == "viscous":
            out[:, j, k] = v[:, j]
        elif term == "offset":
            out[:, j, k] = 1.0
        else:
            out[:, j, k] = vd[:, j]
    return out


@dataclasses.dataclass(frozen=True, eq=False)
class DriveFit:
    """Identified drive terms.

    Attributes:
        layout: the columns.
        theta: values, shape (d,) (units of ``layout.units``).
        sigma: their standard deviations, shape (d,).
        merged_armature: {joint: value [kg·m²]} the physical fit gave the armatures that are
            not separable (already inside the base parameters; the URDF's rotor inertia).
        known: labels of the terms taken from the model file, not estimated (:func:`model_file_terms`).
    """

    layout: DriveLayout
    theta: np.ndarray
    sigma: np.ndarray
    merged_armature: dict[str, float] = dataclasses.field(default_factory=dict)
    known: tuple[str, ...] = ()

    def with_known(self, known: DriveFit | None) -> DriveFit:
        """This fit with the model file's terms ``known`` appended (their σ is 0)."""
        if known is None or not known.layout.count:
            return self
        a, b = self.layout, known.layout
        layout = dataclasses.replace(a, terms=a.terms + b.terms, joints=a.joints + b.joints, units=a.units + b.units)
        return DriveFit(layout, np.r_[self.theta, known.theta], np.r_[self.sigma, known.sigma],
                        self.merged_armature, self.known + b.labels)

    def torque(self, v: np.ndarray, vd: np.ndarray, coulomb: np.ndarray | None = None) -> np.ndarray:
        """D θ at the samples, shape (S, n) [N·m], a block of samples at a time (D of an hour at
        200 Hz is 0.85 GB)."""
        out = np.empty(np.shape(v))
        for s in range(0, out.shape[0], 20000):
            k = slice(s, s + 20000)
            out[k] = drive_columns(v[k], vd[k], self.layout, None if coulomb is None else coulomb[k]) @ self.theta
        return out

    def per_joint(self, term: str) -> np.ndarray:
        """The value of ``term`` on every joint (0 where not modelled), shape (n,)."""
        out = np.zeros(len(self.layout.joint_names))
        for t, j, x in zip(self.layout.terms, self.layout.joints, self.theta):
            if t == term:
                out[j] = x
        return out

    def as_dict(self) -> dict[str, Any]:
        """identified.json's ``drive_terms`` block: {joint: {term: {value, sigma, sigma_percent, unit}}}."""
        table: dict[str, Any] = {name: {} for name in self.layout.joint_names}
        for t, j, u, x, s in zip(self.layout.terms, self.layout.joints, self.layout.units, self.theta, self.sigma):
            table[self.layout.joint_names[j]][t] = {
                "value": float(x), "sigma": float(s), "sigma_percent": percent_or_none(x, s), "unit": u}
            if f"{t}[{self.layout.joint_names[j]}]" in self.known:
                table[self.layout.joint_names[j]][t]["source"] = "model file"
        for name, coef in self.layout.merged.items():
            table[name]["armature"] = {"value": None, "identifiable": False, "merged_into": coef,
                                       "note": "in the span of the rigid-body base columns: only the sum with "
                                               "these base parameters is identifiable"}
            if name in self.merged_armature:  # included in the base parameters
                table[name]["armature"]["physical_fit_value"] = self.merged_armature[name]
        return {
            "joints": table,
            "velocity_scale": self.layout.velocity_scale,
            "coulomb_model": "coulomb * tanh(v / velocity_scale)",
            "torque_equation": "tau = Y_B(q, v, vd) phi_B + coulomb*tanh(v/v_s) + viscous*v + offset + armature*vd",
            "friction": "viscous and coulomb are each joint's total friction; 'source: model file' marks a value "
                        "kept from the model file's <dynamics> (not estimated)",
            "dropped": dict(self.layout.dropped),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], joint_names: Sequence[str], kinds: Sequence[str] | None = None) -> DriveFit:
        """Reads :meth:`as_dict`'s block back.

        Raises:
            KeyError, TypeError, ValueError: a malformed block (the caller names the file).
        """
        names = tuple(joint_names)
        table = d["joints"]
        unknown = set(table) - set(names)
        if unknown:
            raise ValueError(f"drive terms for joints {', '.join(sorted(unknown))} not in {', '.join(names)}")
        terms, joints, units, theta, sigma, merged, merged_values, known = [], [], [], [], [], {}, {}, []
        for j, name in enumerate(names):
            for t, entry in table.get(name, {}).items():
                if t not in _UNITS:
                    raise ValueError(f"unknown drive term '{t}' (valid: {', '.join(_UNITS)})")
                if entry.get("value") is None:
                    merged[name] = dict(entry.get("merged_into", {}))
                    if entry.get("physical_fit_value") is not None:
                        merged_values[name] = float(entry["physical_fit_value"])
                    continue
                if entry.get("source") == "model file":
                    known.append(f"{t}[{name}]")
                terms.append(t)
                joints.append(j)
                units.append(str(entry.get("unit", _UNITS[t][0])))
                theta.append(float(entry["value"]))
                sigma.append(float("nan") if entry.get("sigma") is None else float(entry["sigma"]))
        layout = DriveLayout(tuple(terms), tuple(joints), names, tuple(units),
                             float(d.get("velocity_scale", COULOMB_VELOCITY_SCALE)), merged,
                             dict(d.get("dropped", {})))
        return cls(layout, np.array(theta, float), np.array(sigma, float), merged_values, tuple(known))


def model_file_terms(robot, layout: DriveLayout) -> DriveFit | None:
    """The model file's friction that ``layout`` does not estimate, as a fit with σ = 0 (module
    docstring), or None when there is none.

    Args:
        robot: the a-priori robot (``joint_damping``, ``joint_friction``).
        layout: the drive columns the fit estimates.
    """
    fitted = set(zip(layout.terms, layout.joints))
    cols = [(t, j, float(x)) for j in range(robot.n)
            for t, x in (("coulomb", robot.joint_friction[j]), ("viscous", robot.joint_damping[j]))
            if x != 0 and (t, j) not in fitted]
    if not cols:
        return None
    units = tuple(_UNITS[t][0 if robot.joints[j].kind == "revolute" else 1] for t, j, _ in cols)
    known = DriveLayout(tuple(t for t, _, _ in cols), tuple(j for _, j, _ in cols), layout.joint_names, units,
                        layout.velocity_scale)
    return DriveFit(known, np.array([x for _, _, x in cols]), np.zeros(len(cols)), {}, known.labels)


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
    """The drive columns this data set can tell apart from the others.

    Args:
        W_base: the base regressor's rows, shape (rows, b).
        D: the drive columns on the same rows, shape (rows, d).
        layout: their layout.

    Returns:
        (the layout of the kept columns, their indices into D).
    """
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
        worst = keep[int(np.argmax(np.abs(Vt[-1, b:])))]
        reasons[layout.labels[worst]] = ("the data cannot tell it from the other columns (e.g. the joint never "
                                         "reverses: Coulomb friction = offset)")
        keep.remove(worst)
    return layout.without(keep, reasons), keep


def drive_summary(fit: DriveFit | None) -> list[str]:
    """Lines for a command's output: the drive terms per joint with their σ, what was left out."""
    if fit is None or (fit.layout.count == 0 and not fit.layout.merged):
        return ["drive terms: none (rigid body only)"]
    lines = ["drive terms (value ± σ):"]
    names = fit.layout.joint_names
    for j, name in enumerate(names):
        parts = [f"{t} {x:.4g} {u} (model file)" if f"{t}[{name}]" in fit.known else f"{t} {x:.4g} ± {s:.2g} {u}"
                 for t, jj, u, x, s in zip(fit.layout.terms, fit.layout.joints, fit.layout.units, fit.theta, fit.sigma)
                 if jj == j]
        if name in fit.layout.merged:
            merged = list(fit.layout.merged[name])  # base-parameter compositions: identified.json has them whole
            more = f", … ({len(merged) - 2} more)" if len(merged) > 2 else ""
            parts.append("armature not separable (merged into " + ", ".join(shorten(m, 60) for m in merged[:2])
                         + more + ")")
        if parts:
            lines.append(f"  {name}: " + "; ".join(parts))
    for label, reason in fit.layout.dropped.items():
        lines.append(f"  {label} left out: {reason}")
    return lines


def filtered_coulomb(raw, data, velocity_scale: float = COULOMB_VELOCITY_SCALE) -> np.ndarray | None:
    """The Coulomb columns of preprocessed data, parallel-filtered (Gautier 1997), shape (S, n).

    The torque was low-pass filtered, so its friction part is the filtered tanh(v/v_s), not
    tanh of the filtered v: the smoothed sign has content far above the cut-off. This redoes
    :func:`~pe_drake.identification.preprocessing.preprocess`'s grid and filter on ``raw``
    (as the diagnosis's records do), computes tanh(v/v_s) at the full rate, filters it with the
    same filter and picks the samples of ``data``. On a simulated Panda run with 4 Hz cut-off,
    tanh of the filtered v biased the Coulomb values by up to −25 % and left 0.1-0.4 N·m of
    residual; with this column the fit reaches the noise floor.

    Args:
        raw: the measurement as read.
        data: ``preprocess(raw, ...)``'s result (its ``preprocessing`` names the filter).
        velocity_scale: v_s [rad/s].

    Returns:
        The columns at data's samples, or None when ``data`` was not preprocessed (exact data:
        tanh(v/v_s) of its v is the column).
    """
    p = data.preprocessing
    if p is None:
        return None
    grid = resample_uniform(raw.t, {"q": raw.q, "v": raw.v})
    lowpass = design_lowpass(p.cutoff_hz, grid.rate_hz, len(grid.t), p.filter_order, file=raw.source)
    idx = np.clip(np.rint((data.t - grid.t[0]) / grid.dt).astype(int), 0, len(grid.t) - 1)
    out = np.empty((len(idx), raw.num_joints))
    for j in range(raw.num_joints):  # a joint at a time: a long log's full-rate columns one by one
        v = grid.signals["v"]
        v = lowpass.apply(v[:, j]) if v is not None else differentiate(lowpass.apply(grid.signals["q"][:, [j]]), grid.dt)[:, 0]
        out[:, j] = lowpass.apply(coulomb_column(v, velocity_scale))[idx]
    return out


def urdf_dynamics(fit: DriveFit | None) -> tuple[dict[str, float], dict[str, float], list[str]]:
    """What of the drive terms a URDF can hold: ({joint: damping}, {joint: rotor inertia}, notes).

    Viscous friction becomes the joint's ``<dynamics damping>`` and the armature Drake's
    ``drake:rotor_inertia`` (gear ratio 1); negative values (a WLS fit is unconstrained) are
    left out. Drake ignores ``<dynamics friction>``, so Coulomb friction and offsets stay in
    identified.json.
    """
    if fit is None or fit.layout.count == 0:
        return {}, {}, []
    damping, rotor, notes = {}, {}, []
    for t, j, x in zip(fit.layout.terms, fit.layout.joints, fit.theta):
        name = fit.layout.joint_names[j]
        if t not in ("viscous", "armature"):
            continue
        if x < 0:
            notes.append(f"{t}[{name}] = {x:.3g} < 0 is not written to the URDF")
            continue
        (damping if t == "viscous" else rotor)[name] = float(x)
    rotor.update({name: x for name, x in fit.merged_armature.items() if x > 0})
    notes.append("Coulomb friction is in <dynamics friction> (Drake's parser ignores it, pe_drake reads it as the "
                 "model file's friction) and identified.json; torque offsets in identified.json only")
    return damping, rotor, notes


def urdf_friction(fit: DriveFit | None) -> dict[str, float]:
    """{joint: Coulomb friction [N·m]} for a URDF's ``<dynamics friction>``, negative values left
    out: so model.urdf's friction is the fit's, not a stale copy of the source URDF's."""
    if fit is None:
        return {}
    return {fit.layout.joint_names[j]: float(x) for t, j, x in zip(fit.layout.terms, fit.layout.joints, fit.theta)
            if t == "coulomb" and x >= 0}


def drive_effects_yaml(fit: DriveFit) -> str:
    """The drive terms as a TRUTH.yaml ``effects`` section, so that
    ``pe-drake simulate --robot model.urdf --truth drive_effects.yaml`` runs the identified model
    (viscous and armature repeat model.urdf's damping and rotor inertia; negative values, which
    the simulator refuses, are left out)."""
    def table(term: str, nonnegative: bool) -> str:
        # a fitted friction of 0 is written too: a joint left out keeps the model file's friction
        friction = term in ("viscous", "coulomb")
        values = {fit.layout.joint_names[j]: float(x) for t, j, x in zip(fit.layout.terms, fit.layout.joints, fit.theta)
                  if t == term and (x != 0 or friction) and not (nonnegative and x < 0)}
        if term == "armature":
            values.update({k: v for k, v in fit.merged_armature.items() if v > 0})
        return "{" + ", ".join(f"{j}: {v!r}" for j, v in values.items()) + "}"

    return (
        "# Drive terms identified by pe-drake identify (TRUTH.yaml schema of pe-drake simulate):\n"
        "#   pe-drake simulate --robot model.urdf --truth drive_effects.yaml ...\n"
        "effects:\n"
        f"  viscous: {table('viscous', True)}   # [N·m·s/rad]\n"
        f"  coulomb: {table('coulomb', True)}   # [N·m], f_c·tanh(v / v_s)\n"
        f"  coulomb_velocity_scale: {fit.layout.velocity_scale!r}   # v_s [rad/s]\n"
        f"  armature: {table('armature', True)}   # [kg·m²]\n"
        f"  torque_offset: {table('offset', False)}   # [N·m]\n"
    )
