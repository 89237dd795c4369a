"""The robot as built: one value every stage fits, simulates, diagnoses and writes.

A :class:`RobotModel` is the rigid-body parameters (10 per body about its origin, in its frame)
plus the drive terms of :mod:`pe_drake.multibody.drive_columns` per joint (each a total: the
model file's friction included), a payload welded to a link, a time delay of the torque log and
pre-sliding (Dahl) friction. The torque the actuator applies (the simulator's sign convention)::

    tau_recorded(t) = [Y(q, v, vd) phi + D(v, vd) theta + F_c z](t - torque_delay)

**Through a transmission** (θ_m = R q, τ = Rᵀ τ_m) the drive terms are each motor's, motor side
(named by their joint). :meth:`RobotModel.plant` holds the off-diagonal entries of the reflected
rotor inertia Rᵀ diag(I_m) R as a system of its diagram, which the plant's own inverse dynamics
and mass matrix do not see (:meth:`RobotModel.plant_notes`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pe_drake.exceptions import ConfigError
from pe_drake.io_utils import atomic_write_text
from pe_drake.multibody.drive_columns import (
    COULOMB_VELOCITY_SCALE,
    NONNEGATIVE,
    TERMS,
    UNITS,
    DriveLayout,
    drive_columns,
    model_tables,
    read_drive_block,
)
from pe_drake.multibody.inertia import PARAMETER_NAMES, inertia_matrix, validity_problems
from pe_drake.multibody.model_plant import PAYLOAD_BODY_NAME, model_plant
from pe_drake.multibody.packages import found_packages
from pe_drake.multibody.payload import PayloadInertia
from pe_drake.multibody.regressor import shared_model
from pe_drake.multibody.robot import load_robot
from pe_drake.multibody.transmission import Transmission
from pe_drake.multibody.urdf import joint_dynamics, payload_link_text, urdf_with_inertias, verify_urdf_text

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: The drive terms of a model, in the order of :data:`~pe_drake.multibody.drive_columns.TERMS`.
DRIVE_TERMS = TERMS["all"]
#: Keys of the file's per-joint tables, by term, in file order; a missing table loads as 0.
FILE_KEYS = {"viscous": "viscous", "coulomb": "coulomb", "armature": "armature", "offset": "torque_offset"}
TORQUE_EQUATION = ("tau_recorded(t) = [ID(q, v, vd) + viscous*v + coulomb*tanh(v/v_s) + armature*vd "
                   "+ offset + joint_stiffness*q](t - time_delay)")


def _per_joint(x, n: int, field: str) -> np.ndarray:
    x = np.zeros(n) if x is None or np.size(x) == 0 else np.asarray(x, float).reshape(-1)
    if x.shape != (n,):
        raise ValueError(f"RobotModel.{field} must have one value per joint ({n}), got shape {x.shape}")
    return x


@dataclasses.dataclass(frozen=True, eq=False)
class RobotModel:
    """The robot as built (module docstring); per-joint arrays are (n,), absent ones 0.

    Attributes:
        joints: the excited joints, velocity order, length n.
        bodies: the bodies they move, the order of ``phi``, length nb.
        phi: standard parameters of the bodies alone (payload apart), shape (10·nb,).
        drive: {term: per-joint value} of :data:`DRIVE_TERMS` [drive_columns.UNITS].
        sigma: {term: σ per joint} of the identified drive terms (NaN: not estimated, 0: the
            model file's).
        payload: a rigid payload welded to ``payload_link`` (its frame), or None.
        torque_delay: the torque log lags the positions by this [s].
        presliding, presliding_stiffness: Dahl F_c [N·m] and σ0 [N·m/rad].
        holding_torque: the friction a stopped joint holds [N·m]; not applied by :meth:`plant`
            or :meth:`torque`.
        transmission: θ_m = R q of the motors; with one, ``drive`` and ``sigma`` are per motor.
        spring: torque k·q [N·m/rad or N/m], k ≥ 0, its rest angle in the offset.
    """

    joints: tuple[str, ...]
    bodies: tuple[str, ...]
    phi: np.ndarray
    drive: Mapping[str, np.ndarray] = dataclasses.field(default_factory=dict)
    sigma: Mapping[str, np.ndarray] = dataclasses.field(default_factory=dict)
    velocity_scale: float = COULOMB_VELOCITY_SCALE
    payload: PayloadInertia | None = None
    payload_link: str = ""
    torque_delay: float = 0.0
    presliding: np.ndarray | None = None
    presliding_stiffness: np.ndarray | None = None
    holding_torque: np.ndarray | None = None
    physical: bool | None = None
    notes: tuple[str, ...] = ()
    transmission: Transmission | None = None
    spring: np.ndarray | None = None

    def __post_init__(self) -> None:
        n, set_ = len(self.joints), object.__setattr__
        set_(self, "joints", tuple(self.joints))
        set_(self, "bodies", tuple(self.bodies))
        set_(self, "phi", np.asarray(self.phi, float).reshape(-1))
        if self.phi.shape != (10 * len(self.bodies),):
            raise ValueError(f"RobotModel.phi must have 10 values per body ({10 * len(self.bodies)}), got {self.phi.shape}")
        for field in ("drive", "sigma"):
            table = getattr(self, field)
            unknown = set(table) - set(DRIVE_TERMS)
            if unknown:
                raise ValueError(f"RobotModel.{field}: unknown drive term(s) {', '.join(sorted(unknown))} "
                                 f"(valid: {', '.join(DRIVE_TERMS)})")
            set_(self, field, {t: _per_joint(table[t], n, f"{field}['{t}']") for t in DRIVE_TERMS if t in table})
        for field in ("presliding", "presliding_stiffness", "holding_torque", "spring"):
            set_(self, field, _per_joint(getattr(self, field), n, field))
        if self.payload_link and self.payload_link not in self.bodies:
            raise ValueError(f"RobotModel.payload_link '{self.payload_link}' is not one of {', '.join(self.bodies)}")
        if (self.payload is None) != (not self.payload_link):
            raise ValueError("RobotModel.payload and payload_link go together (both or neither)")
        if not (math.isfinite(self.velocity_scale) and self.velocity_scale > 0):
            raise ValueError(f"RobotModel.velocity_scale must be positive [rad/s], got {self.velocity_scale!r}")
        if self.physical is None:
            set_(self, "physical", not validity_problems(self.bodies, self.phi))
        if self.transmission is not None and self.transmission.joints != self.joints:
            raise ValueError(f"RobotModel.transmission is of joints {', '.join(self.transmission.joints)}, "
                             f"not {', '.join(self.joints)}")

    @classmethod
    def from_robot(cls, robot: Robot) -> RobotModel:
        """The model file's own model: its inertials, ``<dynamics damping friction>`` and its
        actuators' reflected rotor inertia as armature."""
        armature = np.zeros(robot.n)
        for a in robot.plant.GetJointActuatorIndices():
            actuator = robot.plant.get_joint_actuator(a)
            if actuator.joint().name() in robot.joint_names:
                armature[robot.joint_names.index(actuator.joint().name())] = actuator.default_reflected_inertia()
        drive = {"coulomb": robot.joint_friction, "viscous": robot.joint_damping, "offset": np.zeros(robot.n),
                 "armature": armature}
        return cls(robot.joint_names, robot.body_names, robot.phi_model, drive)

    def term(self, name: str) -> np.ndarray:
        """The per-joint (per-motor with a transmission) value of drive term ``name``, (n,)."""
        if name not in DRIVE_TERMS:
            raise ValueError(f"unknown drive term '{name}' (valid: {', '.join(DRIVE_TERMS)})")
        return self.drive.get(name, np.zeros(len(self.joints)))

    coulomb = property(lambda self: self.term("coulomb"), doc="Coulomb friction f_c [N·m], (n,).")
    viscous = property(lambda self: self.term("viscous"), doc="viscous friction [N·m·s/rad], (n,).")
    offset = property(lambda self: self.term("offset"), doc="torque offset [N·m], (n,).")
    armature = property(lambda self: self.term("armature"), doc="rotor inertia [kg·m²], (n,).")

    @property
    def sliding_friction(self) -> np.ndarray:
        """Dry friction once a joint slides [N·m], (n,): f_c plus a pre-sliding friction's F_c,
        what a file without the Dahl transition holds (URDF ``friction``, MJCF ``frictionloss``)."""
        return self.coulomb + self.presliding

    @property
    def phi_total(self) -> np.ndarray:
        """``phi`` with the payload added to its link, (10·nb,)."""
        phi = self.phi.copy()
        if self.payload is not None:
            b = self.bodies.index(self.payload_link)
            phi[10 * b : 10 * b + 10] += self.payload.phi
        return phi

    def layout(self) -> DriveLayout:
        """Every drive term of every joint as drive columns."""
        cols = [(t, j) for j in range(len(self.joints)) for t in DRIVE_TERMS]
        return DriveLayout(tuple(t for t, _ in cols), tuple(j for _, j in cols), self.joints,
                           tuple(UNITS[t][0] for t, _ in cols), self.velocity_scale, transmission=self.transmission)

    def theta(self) -> np.ndarray:
        """The values of :meth:`layout`'s columns, shape (4·n,)."""
        return np.array([self.term(t)[j] for j in range(len(self.joints)) for t in DRIVE_TERMS])

    def check_robot(self, robot: Robot) -> None:
        """Raises ValueError when ``robot`` has other joints or bodies than the model."""
        if tuple(robot.joint_names) != self.joints or tuple(robot.body_names) != self.bodies:
            raise ValueError(f"the model is of joints {', '.join(self.joints)} and bodies {', '.join(self.bodies)}; "
                             f"robot '{robot.name}' has {', '.join(robot.joint_names)} and {', '.join(robot.body_names)}")

    def nonnegative(self, why: str = "is taken as 0") -> RobotModel:
        """This model with negative friction and armature (an unconstrained fit's) set to 0, noted
        "<term>[<joint>] = <value> < 0 ``why``": what Drake and the URDF can hold."""
        drive, notes = dict(self.drive), list(self.notes)
        for t in NONNEGATIVE:
            x = self.term(t).copy()
            for j in np.flatnonzero(x < 0):
                notes.append(f"{t}[{self.joints[j]}] = {x[j]:.3g} < 0 {why}")
            drive[t] = np.maximum(x, 0.0)
        return dataclasses.replace(self, drive=drive, notes=tuple(notes))

    def torque(self, robot: Robot, q: np.ndarray, v: np.ndarray, vd: np.ndarray, *, coulomb: bool = True,
               offset: bool = True, spring: bool | None = None) -> np.ndarray:
        """Inverse dynamics Y(q, v, vd)·phi_total + D(v, vd)·theta, (T, n) [N·m] (no delay, no
        Dahl state); q, v, vd each (T, n) or (n,).

        Args:
            coulomb, offset: include the Coulomb friction and the offsets. Without them the torque
                is what a simulator file holds as inverse dynamics (rigid + armature + viscous).
            spring: include the joint springs k·q (default: as ``offset``; MuJoCo's joint
                ``stiffness`` holds them, a URDF does not).
        """
        self.check_robot(robot)
        q, v, vd = (np.atleast_2d(np.asarray(x, float)) for x in (q, v, vd))
        model, phi, layout, theta = shared_model(robot), self.phi_total, self.layout(), self.theta()
        left_out = [t for t, keep in (("coulomb", coulomb), ("offset", offset)) if not keep]
        theta = np.where(np.isin(np.array(layout.terms), left_out), 0.0, theta)
        out = np.empty(q.shape)
        for s in range(0, q.shape[0], 2000):
            k = slice(s, s + 2000)
            out[k] = model(q[k], v[k], vd[k]) @ phi + drive_columns(v[k], vd[k], layout) @ theta
        return out + q * self.spring if (offset if spring is None else spring) else out

    def plant(self, robot: Robot):
        """The model in Drake, a continuous :class:`~pe_drake.multibody.robot.Robot` without the
        offsets; ConfigError on a negative friction or armature (:meth:`nonnegative`)."""
        return model_plant(self, robot)

    def per_joint_model(self) -> RobotModel:
        """This model with per-joint drive terms, what a URDF and Drake's joint elements hold:
        a motor turning one joint gives it R_ii²·F_v and |R_ii|·F_c, the offsets are Rᵀ o, the
        armature diag(Rᵀ diag(I) R); a coupled motor's friction and the off-diagonal rotor
        inertia are left out, noted."""
        T = self.transmission
        if T is None:
            return self
        ratio, single = np.diag(T.R), np.count_nonzero(T.R, axis=1) == 1  # motor i turns joint i only
        drive = {"viscous": np.where(single, ratio**2 * self.viscous, 0.0),
                 "coulomb": np.where(single, np.abs(ratio) * self.coulomb, 0.0),
                 "offset": T.R.T @ self.offset, "armature": np.diag(T.reflected(self.armature)).copy()}
        lost = [f"motor {self.joints[i]}" for i in np.flatnonzero(~single)
                if self.coulomb[i] != 0 or self.viscous[i] != 0]
        notes = self.plant_notes() + ([f"the friction of the coupled {', '.join(lost)} acts on several joints: not a "
                                       "per-joint term (pe_drake's Drake plant applies it as a generalized force)"]
                                      if lost else [])
        return dataclasses.replace(self, drive=drive, sigma={}, transmission=None, notes=(*self.notes, *notes))

    def rotor_coupling(self) -> np.ndarray:
        """The off-diagonal part of the reflected rotor inertia Rᵀ diag(I) R (of the armatures
        ≥ 0), (n, n) [kg·m²]; zeros without a coupled transmission."""
        n = len(self.joints)
        if self.transmission is None:
            return np.zeros((n, n))
        block = self.transmission.reflected(np.maximum(self.armature, 0.0))
        return block - np.diag(np.diag(block))

    def plant_notes(self) -> list[str]:
        """What :meth:`plant` holds apart from the plant itself, in words (empty when nothing)."""
        cross = self.rotor_coupling()
        if not np.any(cross):
            return []
        pairs = [f"{self.joints[j]}-{self.joints[k]} {cross[j, k]:.3g} kg·m²"
                 for j in range(len(self.joints)) for k in range(j + 1, len(self.joints)) if cross[j, k] != 0]
        return [f"the coupled rotor inertia's off-diagonal entries (R^T diag(I) R: {', '.join(pairs)}) are not a per-joint "
                "rotor inertia: not in a URDF or the exported files; pe_drake's simulator applies them as a force "
                "system of its Drake diagram"]

    def to_dict(self) -> dict[str, Any]:
        """The model as JSON-ready data (augmented_model.json's schema; :meth:`from_dict` reads it)."""
        def per_joint(x):
            return {j: float(v) for j, v in zip(self.joints, x)}

        p = self.payload
        out = {"joints": list(self.joints), "parameter_names": list(PARAMETER_NAMES),
               "phi": {b: self.phi[10 * k : 10 * k + 10].tolist() for k, b in enumerate(self.bodies)},
               "phi_frame": "about each body origin, in the body frame [kg, kg·m, kg·m²]"}
        for t, key in FILE_KEYS.items():
            out[key], out[f"{key}_unit"] = per_joint(self.term(t)), UNITS[t][0]
            if t == "coulomb":
                out["coulomb_velocity_scale"] = self.velocity_scale
        out.update({
            "payload": {"link": self.payload_link, "mass": p.mass, "com": np.asarray(p.com, float).tolist(),
                        "inertia_about_com": p.inertia_vector.tolist()} if p is not None else None,
            "time_delay": self.torque_delay, "time_delay_unit": "s",
            "presliding_friction": per_joint(self.presliding), "presliding_stiffness": per_joint(self.presliding_stiffness),
            "presliding_units": "N·m, N·m/rad (Dahl model)",
            "holding_torque": per_joint(self.holding_torque),
            "holding_torque_unit": "N·m (the friction a stopped joint holds: H·z, z the Dahl state; not applied "
                                   "by validate or simulate)",
            "joint_stiffness": per_joint(self.spring),
            "joint_stiffness_unit": "N·m/rad (N/m on a prismatic joint): torque k·q, its rest angle in torque_offset",
            "torque_equation": TORQUE_EQUATION,
            "notes": list(self.notes),
        })
        if self.sigma:
            out["sigma"] = {FILE_KEYS[t]: per_joint(s) for t, s in self.sigma.items()}
        if self.transmission is not None:  # the per-joint tables above are then per motor
            out["transmission"] = {**self.transmission.to_dict(), "drive_side": "motor: the drive tables are per "
                                   "motor (named by its joint), motor side, acting on the joints through R^T"}
        return out

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], bodies=None, *, base=None, phi_prior=None) -> RobotModel:
        """Reads :meth:`to_dict`'s data, an augmented_model.json or an identify identified.json.

        Args:
            bodies: the robot's body names (an OLS/WLS identified.json does not name them).
            base, phi_prior: for an identified.json with base parameters only, the
                :class:`~pe_drake.multibody.base_parameters.BaseParameters` of its measurement and
                φ0 (10·nb,): ``phi`` is then φ0 + K⁺(φ_B − K φ0), the same torques but not
                physically consistent in general.

        Raises:
            KeyError, TypeError, ValueError: a malformed file (the caller names it).
        """
        if "base_parameters" in d:
            return _from_identified(cls, d, bodies, base, phi_prior)
        joints = tuple(d["joints"])
        phi_table = d["phi"]
        body_names = tuple(bodies) if bodies is not None else tuple(phi_table)
        phi = np.array([float(x) for b in body_names for x in phi_table[b]])
        p = d.get("payload")
        payload = (PayloadInertia(float(p["mass"]), np.asarray(p["com"], float),
                                  inertia_matrix(np.asarray(p["inertia_about_com"], float))) if p else None)

        def table(key):
            t = d.get(key) or {}
            return np.array([float(t.get(j, 0.0)) for j in joints])

        sigma = {t: [float("nan") if d["sigma"][k].get(j) is None else d["sigma"][k][j] for j in joints]
                 for t, k in FILE_KEYS.items() if k in (d.get("sigma") or {})}
        return cls(joints, body_names, phi, {t: table(k) for t, k in FILE_KEYS.items()},
                   sigma, float(d.get("coulomb_velocity_scale", COULOMB_VELOCITY_SCALE)), payload,
                   p["link"] if p else "", float(d.get("time_delay") or 0.0), table("presliding_friction"),
                   table("presliding_stiffness"), table("holding_torque"), None, tuple(d.get("notes", ())),
                   Transmission.from_dict(d["transmission"]) if d.get("transmission") else None, table("joint_stiffness"))

    def urdf_text(self, robot: Robot, title: str = "") -> str:
        """The robot's URDF with this model's inertials, ``<dynamics damping friction>``, rotor
        inertias and payload link of :meth:`per_joint_model`; a negative friction or armature
        is written as 0; ``friction`` holds a pre-sliding friction's sliding level. Offsets, delay and
        pre-sliding are in :meth:`effects_yaml`.

        Raises:
            ConfigError: the robot was not loaded from a URDF.
            PhysicallyInvalidError: a body that is not physically valid.
        """
        text = urdf_with_inertias(robot.model_path, self.bodies, self.phi)
        m = self.per_joint_model().nonnegative() if self.drive else None
        if m is not None:
            text = joint_dynamics(text, dict(zip(self.joints, map(float, m.viscous))),
                                  {j: float(a) for j, a in zip(self.joints, m.armature) if a > 0},
                                  dict(zip(self.joints, map(float, m.sliding_friction))))
        if self.payload is not None:
            head, sep, tail = text.rpartition("</robot>")
            text = head + payload_link_text(PAYLOAD_BODY_NAME, self.payload_link, self.payload) + sep + tail
        return text.replace("with identified inertial parameters (pe_drake)", title) if title else text

    def effects_yaml(self, header: str = "") -> str:
        """What a URDF cannot hold, as a TRUTH.yaml ``effects`` section after the comment lines
        ``header`` (:meth:`per_joint_model`'s terms; negative values left out)."""
        m = self.per_joint_model().nonnegative()

        def table(x, every: bool = False):
            items = {j: float(v) for j, v in zip(self.joints, x) if every or v != 0}
            return "{" + ", ".join(f"{j}: {v!r}" for j, v in items.items()) + "}"

        return (
            header + "effects:\n"
            # every joint's friction: the simulator keeps the model file's where a joint is left out
            f"  viscous: {table(m.viscous, True)}            # [N·m·s/rad]\n"
            f"  coulomb: {table(m.coulomb, True)}            # [N·m], f_c·tanh(v / v_s)\n"
            f"  coulomb_velocity_scale: {self.velocity_scale!r}   # v_s [rad/s]\n"
            f"  armature: {table(m.armature)}          # [kg·m²]\n"
            f"  torque_offset: {table(m.offset)}   # [N·m]\n"
            f"  torque_delay: {float(self.torque_delay)!r}   # [s], the torque log lags the positions (time_delay)\n"
            f"  presliding_friction: {table(self.presliding)}   # Dahl F_c [N·m]\n"
            f"  presliding_stiffness: {table(self.presliding_stiffness)}   # Dahl σ0 [N·m/rad]\n"
            + (f"  # joint springs k·q [N·m/rad], not a TRUTH.yaml effect: {table(self.spring)}\n" if np.any(self.spring) else "")
        )

    def write_urdf(self, path: str | Path, robot: Robot, title: str = "", *,
                   tolerance: float = 1e-6) -> float:
        """Writes :meth:`urdf_text` once Drake reads back every body's inertia and this model's
        torque without Coulomb friction and offsets on 20 random states; returns the largest
        torque difference [N·m] (0 without drive terms and payload).

        Raises:
            PhysicallyInvalidError: a body that is not physically valid (nothing is written).
            ConfigError: the URDF does not reproduce the model (nothing is written).
        """
        text, path = self.urdf_text(robot, title), Path(path)
        verify_urdf_text(text, self.bodies, self.phi)
        if not self.drive and self.payload is None:
            atomic_write_text(path, text)
            return 0.0
        tmp = path.with_name(f".{path.name}.check.urdf")
        tmp.write_text(text)
        # the file sits in an output (or staging) folder: its package:// URIs resolve as the input
        # model's did, not by the upward search from its own folder
        packages = {**robot.config.packages, **found_packages(text, robot.model_path, robot.config.packages)}
        try:
            loaded = load_robot(dataclasses.replace(robot.config, model=str(tmp.resolve()), capsules="",
                                                    packages=packages))
        finally:
            tmp.unlink(missing_ok=True)
        rng, shape = np.random.default_rng(0), (20, robot.n)
        q = rng.uniform(robot.limits.q_lower, robot.limits.q_upper, shape)
        v, vd = rng.uniform(-1, 1, shape), rng.uniform(-3, 3, shape)
        want = self.per_joint_model().nonnegative().torque(robot, q, v, vd, coulomb=False, offset=False)
        got = loaded.inverse_dynamics(q, v, vd, include_damping=True)
        err = float(np.max(np.abs(got - want)))
        if not math.isfinite(err) or err > tolerance * max(float(np.max(np.abs(want))), 1.0):
            raise ConfigError(f"the URDF '{path}' does not reproduce the model: torques differ by up to {err:.3g} N·m")
        atomic_write_text(path, text)
        return err


def _from_identified(cls, d: Mapping[str, Any], bodies, base, phi_prior) -> RobotModel:
    """An identify identified.json (:meth:`RobotModel.from_dict`)."""
    joints = tuple(d["joints"])
    std = d.get("standard_parameters")
    bodies = tuple(bodies) if bodies is not None else tuple(std or ())
    if std is not None:
        phi = np.array([float(std[b][k]) for b in bodies for k in PARAMETER_NAMES])
    elif base is None or phi_prior is None:
        raise ValueError("an identified.json with base parameters only needs the robot's base parameters")
    else:
        phi = base.closest_standard(np.array([float(e["value"]) for e in d["base_parameters"]]), phi_prior)
    drive, sigma, transmission, v_s = {}, {}, None, COULOMB_VELOCITY_SCALE
    if d.get("drive_terms"):
        layout, theta, sd, merged = read_drive_block(d["drive_terms"], joints)
        # a merged armature's value is the physical fit's (with standard parameters); else in φ_B
        drive, sigma = model_tables(layout, theta, sd, merged if std is not None else {})
        transmission, v_s = layout.transmission, layout.velocity_scale
    notes = tuple(d.get("physical_fit_notes", ())) + ((d["note"],) if d.get("note") else ())
    return cls(joints, bodies, phi, drive, sigma, v_s, notes=notes, transmission=transmission)
