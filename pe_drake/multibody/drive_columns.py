"""The drive columns of the regressor: joint friction, torque offsets and rotor inertia.

Each drive term of joint j is linear in its value θ and adds one column on the row of joint j:

=============  =====================  ===============  ===========  ==========
term           column                 unit (revolute)  (prismatic)  sign of θ
=============  =====================  ===============  ===========  ==========
``coulomb``    tanh(v_j / v_s)        N·m              N            θ ≥ 0
``viscous``    v_j                    N·m·s/rad        N·s/m        θ ≥ 0
``offset``     1                      N·m              N            any
``armature``   v̇_j                   kg·m²            kg           θ ≥ 0
=============  =====================  ===============  ===========  ==========

so τ = Y_B φ_B + D θ with W = [Y_B | D]. The smoothed sign and its v_s are the diagnosis's and
the simulator's ``DoorHinge``.

The drive columns are zero in base-wrench rows: friction acts between two links. For the
armature this neglects the rotor's own momentum change, I_r·G·q̈ on the stator's link, 1/G of
the armature's I_r·G²·q̈ (1 % for G = 100).

**Through a transmission** (θ_m = R q, τ = Rᵀ τ_m, :mod:`pe_drake.multibody.transmission`) the
terms are per motor (named by its joint), motor side: motor i's column is the table's on
θ̇_i = (R q̇)_i, θ̈_i (Coulomb: tanh(θ̇_i / (|R_ii| v_s))) and reaches joint j's row times R_ij.

The armature column of a joint whose axis is fixed in the world (the first joint of a fixed-base
arm) is a column of the rigid-body base parameters: the armature is merged into that base
parameter (:func:`armature_merges` tests this on random states).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from pe_drake.config_sections import check_choice
from pe_drake.exceptions import ConfigError
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.transmission import Transmission, robot_transmission

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Terms of each ``--drive-terms`` choice, in column order per joint.
TERMS = {"none": (), "friction": ("coulomb", "viscous", "offset"), "all": ("coulomb", "viscous", "offset", "armature")}
#: Smoothing velocity v_s of the Coulomb column tanh(v/v_s) [rad/s or m/s].
COULOMB_VELOCITY_SCALE = 0.01
#: Terms whose value is physically ≥ 0.
NONNEGATIVE = ("coulomb", "viscous", "armature")
#: ‖(I − P_B) c‖ / ‖c‖ below which an armature column counts as inside span(Y_B) on random
#: states: rounding gives ~1e-14, a separable column O(0.1-1).
SEPARABILITY_TOLERANCE = 1e-6
#: Unit of each term's value on a revolute and a prismatic joint.
UNITS = {"coulomb": ("N·m", "N"), "viscous": ("N·m·s/rad", "N·s/m"), "offset": ("N·m", "N"),
         "armature": ("kg·m²", "kg")}


@dataclasses.dataclass(frozen=True)
class DriveTermOptions:
    """Which drive terms ``identify`` adds."""

    # "none", "friction" (Coulomb, viscous, offset per joint) or "all" (also the armature of
    # every joint where it is separable from the link inertias)
    terms: str = "all"
    velocity_scale: float = COULOMB_VELOCITY_SCALE  # v_s of tanh(v/v_s) [rad/s or m/s]

    def __post_init__(self) -> None:
        check_choice("drive terms", self.terms, tuple(TERMS))
        v = self.velocity_scale
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise ConfigError(f"the Coulomb velocity scale must be a positive number [rad/s], got {v!r}")


def drive_options(value: DriveTermOptions | str | None) -> DriveTermOptions:
    """``value`` as options: None → the default, a string → that choice."""
    if value is None:
        return DriveTermOptions()
    return DriveTermOptions(value) if isinstance(value, str) else value


@dataclasses.dataclass(frozen=True)
class DriveLayout:
    """The drive columns of a fit and the armatures left out."""

    terms: tuple[str, ...]  # term of each column, length d
    joints: tuple[int, ...]  # joint (or motor) index of each column, length d
    joint_names: tuple[str, ...]  # the robot's excited joints, length n
    units: tuple[str, ...]  # unit of each column's value
    velocity_scale: float = COULOMB_VELOCITY_SCALE  # v_s of the Coulomb columns [rad/s]
    # {joint: {base parameter: coefficient}} of the armatures not separable from the rigid-body
    # base parameters (only their sum is identifiable)
    merged: dict[str, dict[str, float]] = dataclasses.field(default_factory=dict)
    # {label: reason} of the columns this data set cannot tell apart (the Coulomb column of a
    # joint that never reverses equals its offset column)
    dropped: dict[str, str] = dataclasses.field(default_factory=dict)
    transmission: Transmission | None = None  # set when the terms act per motor
    known: tuple[str, ...] = ()  # labels of the model file's columns, not estimated (σ = 0)

    @property
    def count(self) -> int:
        return len(self.terms)

    @property
    def labels(self) -> tuple[str, ...]:
        """``term[joint]``, or ``term[motor joint]`` for the terms of a motor."""
        motor = "motor " if self.transmission is not None else ""
        return tuple(f"{t}[{motor}{self.joint_names[j]}]" for t, j in zip(self.terms, self.joints))

    def without(self, keep: Sequence[int], reasons: dict[str, str]) -> DriveLayout:
        """The layout with only the columns ``keep``; ``reasons`` of the others go to ``dropped``."""
        keep = list(keep)
        return dataclasses.replace(
            self, terms=tuple(self.terms[k] for k in keep), joints=tuple(self.joints[k] for k in keep),
            units=tuple(self.units[k] for k in keep), dropped={**self.dropped, **reasons})

    def lower_bounds(self) -> np.ndarray:
        """0 for friction and armature, -inf for offsets, shape (d,)."""
        return np.array([0.0 if t in NONNEGATIVE else -np.inf for t in self.terms])


def read_drive_block(d: Mapping[str, Any], joint_names: Sequence[str]
                     ) -> tuple[DriveLayout, np.ndarray, np.ndarray, dict[str, float]]:
    """identify's ``drive_terms`` block of identified.json: (the fitted columns, their values θ and
    σ (0 for the model file's), {joint: the physical fit's value} of the armatures merged into base
    parameters).

    Raises:
        KeyError, TypeError, ValueError: a malformed block (the caller names the file).
    """
    names = tuple(joint_names)
    T = Transmission.from_dict(d["transmission"]) if d.get("transmission") is not None else None
    if T is not None and T.joints != names:
        raise ValueError(f"the transmission is of joints {', '.join(T.joints)}, not {', '.join(names)}")
    table = d["joints"] if T is None else d["motors"]  # through a transmission the motors' (named by their joint)
    unknown = set(table) - set(names)
    if unknown:
        raise ValueError(f"drive terms for joints {', '.join(sorted(unknown))} not in {', '.join(names)}")
    terms, joints, units, theta, sigma, merged, merged_values, known = [], [], [], [], [], {}, {}, []
    for j, name in enumerate(names):
        for t, entry in table.get(name, {}).items():
            if t not in UNITS:
                raise ValueError(f"unknown drive term '{t}' (valid: {', '.join(UNITS)})")
            if entry.get("value") is None:  # an armature merged into the base parameters
                merged[name] = dict(entry.get("merged_into", {}))
                if entry.get("physical_fit_value") is not None:
                    merged_values[name] = float(entry["physical_fit_value"])
                continue
            model_file = entry.get("source") == "model file"
            known += [f"{t}[{name}]"] * model_file
            terms.append(t)
            joints.append(j)
            units.append(str(entry.get("unit", UNITS[t][0])))
            theta.append(float(entry["value"]))
            sigma.append(0.0 if model_file else float("nan") if entry.get("sigma") is None else float(entry["sigma"]))
    layout = DriveLayout(tuple(terms), tuple(joints), names, tuple(units),
                         float(d.get("velocity_scale", COULOMB_VELOCITY_SCALE)), merged,
                         dict(d.get("dropped", {})), transmission=T, known=tuple(known))
    return layout, np.array(theta, float), np.array(sigma, float), merged_values


def model_tables(layout: DriveLayout, theta: np.ndarray, sigma: np.ndarray,
                 merged_armature: dict[str, float]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """A fit's drive terms as a :class:`~pe_drake.multibody.robot_model.RobotModel`'s ``drive`` and
    ``sigma`` ({term: per-joint values}): the model file's terms σ = 0, the physical fit's merged
    armatures (``merged_armature``, {joint: value}, inside the base parameters) σ = NaN."""
    n = len(layout.joint_names)
    drive: dict[str, np.ndarray] = {}
    sd: dict[str, np.ndarray] = {}
    for t, j, x, s in zip(layout.terms, layout.joints, theta, sigma):
        drive.setdefault(t, np.zeros(n))[j] = float(x)
        sd.setdefault(t, np.full(n, np.nan))[j] = float(s)
    for name, value in merged_armature.items():
        j = layout.joint_names.index(name)
        drive.setdefault("armature", np.zeros(n))[j] = float(value)
        sd.setdefault("armature", np.full(n, np.nan))[j] = np.nan
    return drive, sd


def drive_layout(robot: Robot, base, options: DriveTermOptions, model=None, *,
                 rows=None) -> DriveLayout:
    """The drive columns of ``options`` for ``robot`` (armature: where separable); per motor,
    with a revolute joint's units, under a ``robot.transmission`` with R ≠ I.

    Args:
        base: the :class:`~pe_drake.multibody.base_parameters.BaseParameters` of ``rows``.
        model: a :class:`~pe_drake.multibody.regressor.RegressorModel` to reuse.
        rows: the :class:`~pe_drake.multibody.sensors.SensorRows` fitted (default: the joint
            torques); the ground wrench's rows separate every armature the torques cannot.

    Raises:
        ConfigError: a ``robot.transmission`` that does not determine the joint angles.
    """
    terms = TERMS[options.terms]
    names = tuple(robot.joint_names)
    transmission = robot_transmission(robot) if terms else None
    transmission = None if transmission is None or transmission.identity else transmission
    merged = armature_merges(robot, base, model, rows, transmission) if "armature" in terms else {}
    cols = [(t, j) for j in range(robot.n) for t in terms if not (t == "armature" and names[j] in merged)]
    units = tuple(UNITS[t][0 if transmission is not None or robot.joints[j].kind == "revolute" else 1] for t, j in cols)
    return DriveLayout(tuple(t for t, _ in cols), tuple(j for _, j in cols), names, units,
                       float(options.velocity_scale), merged, transmission=transmission)


def armature_merges(robot: Robot, base, model=None, rows=None,
                    transmission: Transmission | None = None) -> dict[str, dict[str, float]]:
    """{joint (or motor): {base parameter: coefficient}} of the armature columns inside span(Y_B).

    200 random states within the robot's limits decide whether *any* motion separates the column
    from the rigid-body columns. ``rows`` (a :class:`~pe_drake.multibody.sensors.SensorRows`,
    torque channels first) are the rows of Y_B (default: the joint torques).
    """
    model = model or RegressorModel(robot)
    rng, samples = np.random.default_rng(1), 200
    q = rng.uniform(robot.limits.q_lower, robot.limits.q_upper, (samples, robot.n))
    v = rng.uniform(-1, 1, (samples, robot.n)) * np.minimum(robot.limits.v_max, 3.0)
    vd = rng.uniform(-1, 1, (samples, robot.n)) * np.minimum(robot.limits.vd_max, 10.0)
    Y = model(q, v, vd) if rows is None else rows.rows(rows.kinematics(q, v, vd), scaled=False)
    channels = Y.shape[1]
    Y_B = base.reduce(Y).reshape(-1, base.count)
    scale = np.linalg.norm(Y_B, axis=0)
    scale[scale == 0] = 1.0
    A = Y_B / scale
    names = tuple(robot.joint_names)
    every = DriveLayout(("armature",) * robot.n, tuple(range(robot.n)), names, ("kg·m²",) * robot.n,
                        transmission=transmission)
    columns = drive_columns(v, vd, every, rows=channels)
    out = {}
    for j, name in enumerate(names):
        col = columns[:, :, j].ravel()
        beta, *_ = np.linalg.lstsq(A, col, rcond=None)
        if np.linalg.norm(col - A @ beta) <= SEPARABILITY_TOLERANCE * np.linalg.norm(col):
            coef = beta / scale
            big = np.flatnonzero(np.abs(coef) > 1e-6 * np.abs(coef).max())
            out[name] = {base.base_names[k]: float(coef[k]) for k in big}
    return out


def coulomb_column(v: np.ndarray, velocity_scale: float) -> np.ndarray:
    """tanh(v / v_s), same shape as v: the one Coulomb column (the smoothed sign of the
    simulator's ``DoorHinge``)."""
    return np.tanh(np.asarray(v, float) / velocity_scale)


def term_values(term: str, v: np.ndarray, vd: np.ndarray | None, velocity_scale: float | np.ndarray,
                coulomb: np.ndarray | None = None) -> np.ndarray:
    """The column of drive term ``term`` for every joint (module docstring's table), shape of
    v (S, n); vd is needed only for the armature, ``coulomb`` replaces tanh(v/v_s)."""
    if term == "coulomb":
        return coulomb_column(v, velocity_scale) if coulomb is None else np.asarray(coulomb, float)
    if term == "viscous":
        return np.asarray(v, float)
    if term == "offset":
        return np.ones(np.shape(v))
    if term == "armature":
        return np.asarray(vd, float)
    raise ValueError(f"unknown drive term '{term}' (valid: {', '.join(TERMS['all'])})")


def drive_columns(v: np.ndarray, vd: np.ndarray, layout: DriveLayout, coulomb: np.ndarray | None = None,
                  rows: int | None = None) -> np.ndarray:
    """The drive block D of the regressor, shape (S, rows, d): column k on joint row j_k only,
    or, through a transmission, motor j_k's term on every joint row j times R[j_k, j].

    Args:
        v, vd: joint velocities and accelerations, each (S, n).
        coulomb: the Coulomb columns to use, (S, n) (e.g. :func:`coulomb_columns` at the full
            rate, filtered like the torque); default :func:`coulomb_columns` of ``v``.
        rows: channels per sample (n torques, then the ground wrench, whose rows stay zero);
            default n.
    """
    S, n = v.shape
    out = np.zeros((S, n if rows is None else rows, layout.count))
    T = layout.transmission
    if coulomb is None and "coulomb" in layout.terms:
        coulomb = coulomb_columns(v, layout)
    if T is not None:  # the motors' velocities and accelerations
        v, vd = T.motor_positions(v), None if vd is None else T.motor_positions(vd)
    values = {t: term_values(t, v, vd, layout.velocity_scale, coulomb) for t in set(layout.terms)}
    for k, (term, j) in enumerate(zip(layout.terms, layout.joints)):
        if T is None:
            out[:, j, k] = values[term][:, j]
        else:  # τ = Rᵀ τ_m: motor j's term on joint i's row times R[j, i]
            out[:, :n, k] = values[term][:, [j]] * T.R[j]
    return out


def coulomb_columns(v: np.ndarray, layout: DriveLayout) -> np.ndarray:
    """The Coulomb columns of a layout, (S, n), per joint or per motor (module docstring): what
    :func:`drive_columns` takes as ``coulomb`` (filter them like the torque first)."""
    w, scale = coulomb_velocities(v, layout.velocity_scale, layout.transmission)
    return coulomb_column(w, scale)


def coulomb_velocities(v: np.ndarray, velocity_scale: float, transmission: Transmission | None) -> tuple[np.ndarray, np.ndarray]:
    """(velocities (S, n), v_s scalar or (n,)) whose tanh(v/v_s) are the Coulomb columns: the
    joints', or the motors' θ̇ = R q̇ and |R_ii|·v_s."""
    if transmission is None:
        return np.asarray(v, float), velocity_scale
    return transmission.motor_positions(v), np.abs(np.diag(transmission.R)) * velocity_scale

