"""What every export writes: the robot as identified, read from a model file in one place.

:func:`export_terms` is the only function of the export stage that reads a model: the rigid
parameters (physically valid per body; a model of base parameters only is first projected onto
the nearest physically consistent ones, as ``simulate --model`` does), the drive terms per joint
(Coulomb friction with its smoothing velocity, viscous friction, offset, armature), a payload as
its own body, and what was adjusted on the way. The writers (:mod:`pe_drake.export.mjcf`,
:mod:`pe_drake.export.drake_files`, :mod:`pe_drake.export.controller`) take an
:class:`ExportTerms` and nothing else from the model.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from pe_drake.identification.estimators import predict
from pe_drake.identification.identified_file import load_identified
from pe_drake.simulation.simulated_model import load_simulation_model
from pe_drake.multibody.drive_columns import COULOMB_VELOCITY_SCALE, coulomb_column
from pe_drake.multibody.payload import PayloadInertia
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.robot_model import DRIVE_TERMS



@dataclasses.dataclass(frozen=True, eq=False)
class ExportTerms:
    """The robot as identified, in the terms the exporters write.

    Attributes:
        source: the model file ("" for the model file's own parameters: the CAD model).
        phi: standard parameters of ``robot.body_names``, physically valid, payload not
            included, shape (10·nb,) [kg, kg·m, kg·m²].
        drive: {term: per-joint values, shape (n,)} for :data:`DRIVE_TERMS`
            [N·m, N·m·s/rad, N·m, kg·m²] (friction and armature ≥ 0).
        velocity_scale: v_s of the Coulomb friction f_c·tanh(v/v_s) [rad/s].
        payload_link: link carrying the payload ("" for none); payload: its inertia in that
            link's frame.
        notes: what was adjusted on the way (projection, negative terms set to 0).
        torque_delay: the model's torque delay [s] (0: none).
        presliding: the model's pre-sliding (Dahl) friction per joint [N·m], (n,) or empty.
        base_K: the identification's base parameters as rows of the standard ones, φ_B = K φ,
            shape (p, 10·nb), or None (a model without σ: the CAD model, an augmented model).
        base_sigma: σ of each base parameter, shape (p,) (inf: not identified), or None.
        base_names: the base parameters' names, length p.
        drive_sigma: {term: σ per joint} of the identified drive terms (0: not identified).
    """

    source: str
    phi: np.ndarray
    drive: dict[str, np.ndarray]
    velocity_scale: float
    payload_link: str = ""
    payload: PayloadInertia | None = None
    notes: tuple[str, ...] = ()
    torque_delay: float = 0.0
    presliding: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    base_K: np.ndarray | None = None
    base_sigma: np.ndarray | None = None
    drive_sigma: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    base_names: tuple[str, ...] = ()

    def phi_with_payload(self, body_names) -> np.ndarray:
        """φ with the payload added to its link, shape (10·nb,): what the robot's torques see."""
        phi = np.array(self.phi, float)
        if self.payload is not None:
            b = list(body_names).index(self.payload_link)
            phi[10 * b : 10 * b + 10] += self.payload.phi
        return phi


def export_terms(robot, model: str | Path | None) -> ExportTerms:
    """The terms to export: those of ``model`` (identified.json of any method or
    augmented_model.json), or with ``model`` None the robot's own (its model file's inertials,
    ``<dynamics damping friction>`` and rotor inertias).

    This adapter is the one place that knows the model types (see the module docstring).

    Raises:
        DataError: a model file of another robot, or not one of these files.
        NoSolutionFound: no physically valid parameters near a base-parameter model.
    """
    if model is None:
        armature = np.zeros(robot.n)
        for a in robot.plant.GetJointActuatorIndices():
            actuator = robot.plant.get_joint_actuator(a)
            if actuator.joint().name() in robot.joint_names:
                armature[robot.joint_names.index(actuator.joint().name())] = actuator.default_reflected_inertia()
        drive = {"coulomb": np.array(robot.joint_friction, float), "viscous": np.array(robot.joint_damping, float),
                 "offset": np.zeros(robot.n), "armature": armature}
        return ExportTerms("", np.array(robot.phi_model, float), drive, COULOMB_VELOCITY_SCALE)
    # physically consistent, friction and armature ≥ 0; a transmission's per-motor terms as the
    # joints hold them (a coupled motor's friction and rotor-inertia coupling left out, noted)
    sim = load_simulation_model(model, robot).per_joint_model()
    drive = {term: sim.term(term) for term in DRIVE_TERMS}
    link, payload, phi = sim.payload_link or "", sim.payload, np.asarray(sim.phi, float)
    result = load_identified(model, robot)
    K = sigma = None
    if result.method != "diagnose":  # an augmented model has no covariance
        K = np.asarray(result.base.K, float)
        sigma = np.abs(np.asarray(result.phi_B, float)) * np.asarray(result.sigma_percent, float) / 100.0
    drive_sigma = {}
    if result.drive is not None and result.drive.layout.transmission is None:  # σ of the motors' terms: not per joint
        spread = dataclasses.replace(result.drive, theta=np.asarray(result.drive.sigma, float))
        drive_sigma = {t: spread.per_joint(t) for t in DRIVE_TERMS}
    return ExportTerms(str(model), phi, {k: np.array(v, float) for k, v in drive.items()}, float(sim.velocity_scale),
                       link, payload, tuple(_exported(n) for n in sim.notes), float(sim.torque_delay),
                       np.array(sim.presliding, float),
                       K, sigma, drive_sigma, tuple(result.base.base_names))


def _exported(note: str) -> str:
    """A simulator's note in the export's words (the same adjustment: 'simulated' → 'exported')."""
    return note.replace(" is simulated as 0", " is written as 0").replace("the simulated ", "the exported ")


def model_torques(robot, terms: ExportTerms, q: np.ndarray, v: np.ndarray, vd: np.ndarray) -> np.ndarray:
    """pe_drake's rigid + armature + viscous torque of the model (payload included), (S, n):
    what an exported file must reproduce (Coulomb friction and offsets are checked apart).

    Args:
        q, v, vd: each (S, n) [rad or m, per s, per s²].
    """
    q, v, vd = np.atleast_2d(q), np.atleast_2d(v), np.atleast_2d(vd)
    Y = RegressorModel(robot)(q, v, vd)
    return Y @ terms.phi_with_payload(robot.body_names) + terms.drive["armature"] * vd + terms.drive["viscous"] * v


def projection_change(robot, model: str | Path, terms: ExportTerms, data) -> np.ndarray | None:
    """RMS [N·m] per joint of the change of the held-out prediction between the model file's own
    (its base parameters) and the exported terms (their consistent φ), or None for a model whose
    standard parameters are exported as they are.

    Args:
        data: a preprocessed run (:func:`~pe_drake.identification.estimators.prepare_measurement`).
    """
    result = load_identified(model, robot)
    if result.phi is not None:
        return None
    own = predict(robot, result, data)
    d = terms.drive
    exported = model_torques(robot, terms, data.q, data.v, data.vd) + d["offset"] \
        + d["coulomb"] * coulomb_column(data.v, terms.velocity_scale)
    return np.sqrt(np.mean((own - exported) ** 2, axis=0))


def random_states(robot, samples: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q, v, v̇), each (samples, n): q inside the limits, |v| up to the velocity limit, |v̇| up to
    the acceleration limit."""
    rng = np.random.default_rng(seed)
    lim = robot.limits
    q = rng.uniform(lim.q_lower, lim.q_upper, (samples, robot.n))
    v = rng.uniform(-1, 1, (samples, robot.n)) * lim.v_max
    vd = rng.uniform(-1, 1, (samples, robot.n)) * lim.vd_max
    return q, v, vd
