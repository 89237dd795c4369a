"""The robot ``pe-drake simulate --model FILE`` simulates: an identified model instead of the URDF's.

``FILE`` is an ``identified.json`` (with its ``drive_terms`` block) or the diagnosis's
``augmented_model.json``, read with :func:`~pe_drake.identification.identified_file.load_identified`
(which checks it belongs to the robot and that its output folder is one run). The simulator
needs what Drake can build:

- **standard parameters that are physically valid per body.** A physical fit and an augmented
  model carry them (the augmented model's payload lumped into its link). An OLS/WLS fit has
  only base parameters φ_B = K φ; the minimum-norm φ = φ0 + K⁺(φ_B − K φ0) makes links invalid
  (on a Panda fit: 7 of 12 bodies with negative principal moments), so the simulated φ is the
  physically consistent fit of φ_B itself (:func:`~pe_drake.identification.physical_fit.physical_fit`
  on the rows L K φ = L φ_B, L = diag(1/σ_B), stage 1 only): it reproduces φ_B exactly when a
  valid φ can, and the prior decides only the directions no motion identifies. An armature
  that merges into the base parameters (joint 1 of a fixed arm) is a variable ≥ 0 of that fit,
  like in ``identify --method physical``;
- **drive terms as the simulator's effects** (:mod:`pe_drake.identification.simulation`):
  viscous friction as joint damping, Coulomb friction f_c·tanh(v/v_s) with the model's v_s,
  armature as rotor inertia, offsets as a constant load. A negative friction or armature (an
  unconstrained WLS fit of a joint without friction) cannot be simulated and becomes 0, noted.
  An augmented model's time delay and pre-sliding (Dahl) friction, which ``validate`` leaves
  out, are simulated too (``effects.torque_delay``, ``effects.presliding_*``).

A TRUTH.yaml given with ``--model`` adds its effects, noise and control on top
(:func:`truth_with_model`).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from pe_drake.exceptions import ConfigError, DataError
from pe_drake.identification.estimators import IdentificationResult
from pe_drake.identification.identified_file import load_identified
from pe_drake.identification.physical_fit import physical_fit
from pe_drake.identification.truth import Truth, per_joint_values
from pe_drake.io_utils import loads_json
from pe_drake.multibody.inertia import validity_problems

#: The drive terms the simulator has, as (DriveFit term, EffectsTruth field).
_TERMS = (("viscous", "viscous"), ("coulomb", "coulomb"), ("armature", "armature"), ("offset", "torque_offset"))
#: A base parameter of the simulated model more than this many σ from the file's is reported.
ATTAINABLE_SIGMA = 1.0


@dataclasses.dataclass(frozen=True, eq=False)
class SimulationModel:
    """An identified model as the simulator builds it.

    Attributes:
        source: the model file.
        phi: standard parameters per body, physically valid, shape (10·nb,).
        viscous, coulomb, armature, torque_offset: per joint, shape (n,) [N·m·s/rad, N·m,
            kg·m², N·m] (≥ 0 but the offsets).
        velocity_scale: v_s of the Coulomb friction tanh(v/v_s) [rad/s].
        notes: what was adjusted or left out, in words.
        torque_delay: the torque log lags the positions by this [s] (augmented models).
        presliding, presliding_stiffness: Dahl F_c [N·m] and σ0 [N·m/rad] per joint, (n,) or
            empty (augmented models).
    """

    source: str
    phi: np.ndarray
    viscous: np.ndarray
    coulomb: np.ndarray
    armature: np.ndarray
    torque_offset: np.ndarray
    velocity_scale: float
    notes: tuple[str, ...] = ()
    torque_delay: float = 0.0
    presliding: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    presliding_stiffness: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))

    def as_dict(self, joints) -> dict:
        """The model's record in the run's ``.truth.json``."""
        return {"file": self.source, "notes": list(self.notes),
                "drive_terms": {field: dict(zip(joints, map(float, getattr(self, field))))
                                for _, field in _TERMS},
                "torque_delay": self.torque_delay,
                "presliding_friction": dict(zip(joints, map(float, self.presliding))),
                "presliding_stiffness": dict(zip(joints, map(float, self.presliding_stiffness)))}


def load_simulation_model(path: str | Path, robot) -> SimulationModel:
    """Reads identified.json or augmented_model.json as the model to simulate (module docstring).

    Raises:
        DataError: a file that is not one of these, or one of another robot or joints.
        NoSolutionFound: no physically valid parameters near the file's base parameters.
    """
    model = simulation_model(load_identified(path, robot), robot, str(path))
    d = loads_json(Path(path).read_text(), str(path))  # load_identified has read it: it is JSON
    if "torque_equation" not in d or "base_parameters" in d:  # not an augmented model
        return model
    try:
        fc = [float((d.get("presliding_friction") or {}).get(j, 0.0)) for j in robot.joint_names]
        sigma0 = [float((d.get("presliding_stiffness") or {}).get(j, 0.0)) for j in robot.joint_names]
        delay = float(d.get("time_delay") or 0.0)
    except (TypeError, ValueError, AttributeError) as err:
        raise DataError(f"time_delay or presliding_*: {err}", file=str(path)) from err
    return dataclasses.replace(model, torque_delay=delay, presliding=np.array(fc), presliding_stiffness=np.array(sigma0))


def simulation_model(result: IdentificationResult, robot, source: str = "") -> SimulationModel:
    """An identified model (:func:`load_identified`'s result) as the simulator builds it."""
    notes = []
    drive = result.drive
    n = robot.n
    values = {t: (drive.per_joint(t) if drive is not None else np.zeros(n)) for t, _ in _TERMS}
    if result.phi is not None:
        phi = np.asarray(result.phi, float)
        problems = validity_problems(robot.body_names, phi)
        if problems:
            raise DataError("the model's standard parameters are not physically valid, so Drake cannot simulate "
                            "them: " + "; ".join(f"{b}: {why}" for b, why in problems.items()), file=source)
        merged = dict(drive.merged_armature) if drive is not None else {}  # not in phi (identified_file)
    else:
        phi, merged, fit_notes = _consistent_parameters(robot, result)
        notes += fit_notes
    for name, value in merged.items():
        values["armature"][robot.joint_names.index(name)] += value
    for term, _ in _TERMS[:3]:  # friction and armature are ≥ 0 in Drake
        for j in np.flatnonzero(values[term] < 0):
            notes.append(f"{term}[{robot.joint_names[j]}] = {values[term][j]:.3g} < 0 is simulated as 0")
            values[term][j] = 0.0
    scale = drive.layout.velocity_scale if drive is not None else 0.01
    return SimulationModel(source, phi, values["viscous"], values["coulomb"], values["armature"], values["offset"],
                           float(scale), tuple(notes))


def _consistent_parameters(robot, result: IdentificationResult) -> tuple[np.ndarray, dict[str, float], list[str]]:
    """(φ, {joint: merged armature}, notes): the physically consistent fit of a base-parameter-only
    model's φ_B, each base parameter weighted by 1/σ (module docstring)."""
    base, phi_B = result.base, np.asarray(result.phi_B, float)
    sigma = np.abs(phi_B) * np.asarray(result.sigma_percent, float) / 100.0
    scale = np.abs(phi_B).max(initial=1e-12)
    # An exact fit reports σ ≈ 0 and an old file none: weigh those at 1e-4 of their value,
    # floored so that the whitened rows stay within the SDP solver's range.
    sigma = np.where(np.isfinite(sigma) & (sigma > 0), sigma, 1e-4 * np.abs(phi_B))
    sigma = np.maximum(sigma, 1e-9 * scale)
    L = np.diag(1.0 / sigma)
    layout = result.drive.layout if result.drive is not None else None
    merged = list(layout.merged) if layout is not None else []
    C = np.zeros((base.count, len(merged)))  # v̇_j = Σ_k C_kj · (base column k): φ_B holds a_j C_j
    for i, joint in enumerate(merged):
        for name, coef in layout.merged[joint].items():
            C[base.base_names.index(name), i] = coef
    fit = physical_fit(L @ base.K, L @ phi_B, robot.phi_model, robot.body_names, extra=L @ C if merged else None,
                       extra_lower=np.zeros(len(merged)), extra_names=[f"armature[{j}]" for j in merged],
                       base_K=base.K, chi2_tolerance=0.0,
                       extra_in_base={i: C[:, i] for i in range(len(merged))})
    theta = np.asarray(fit.theta, float)
    misfit = np.abs(base.K @ fit.phi + C @ theta - phi_B) / sigma
    notes = []
    worst = int(np.argmax(misfit)) if misfit.size else 0
    if misfit.size and misfit[worst] > ATTAINABLE_SIGMA:
        notes.append(f"the model has base parameters only; no physically valid links reproduce them all: "
                     f"the simulated {base.base_names[worst]} is {misfit[worst]:.3g} σ from the file's")
    return fit.phi, {j: float(a) for j, a in zip(merged, theta)}, notes


def truth_with_model(truth: Truth, model: SimulationModel, joints) -> Truth:
    """The truth whose effects are the model's drive terms plus the truth's own (per joint, summed).

    Raises:
        ConfigError: the truth has Coulomb friction with another v_s than the model's.
    """
    e = truth.effects
    if np.any(per_joint_values(e.coulomb, joints) > 0) and not math.isclose(
            e.coulomb_velocity_scale, model.velocity_scale, rel_tol=1e-12):
        raise ConfigError(f"effects.coulomb_velocity_scale {e.coulomb_velocity_scale:g} rad/s of the truth file differs "
                          f"from the model's {model.velocity_scale:g} rad/s ('{model.source}'): one tanh(v/v_s) is "
                          "simulated; remove the truth's coulomb or set the model's v_s")
    tables = {field: {j: float(x) for j, x in zip(joints, per_joint_values(getattr(e, field), joints)
                                                   + getattr(model, field))}
              for _, field in _TERMS}
    if np.any(model.presliding > 0):
        if np.any(per_joint_values(e.presliding_friction, joints) > 0):
            raise ConfigError(f"both the truth file and the model '{model.source}' have pre-sliding friction: "
                              "one Dahl model per joint is simulated; remove the truth's presliding_*")
        tables["presliding_friction"] = {j: float(x) for j, x in zip(joints, model.presliding) if x > 0}
        tables["presliding_stiffness"] = {j: float(s) for j, x, s in zip(joints, model.presliding,
                                                                         model.presliding_stiffness) if x > 0}
    effects = dataclasses.replace(e, coulomb_velocity_scale=model.velocity_scale,
                                  torque_delay=e.torque_delay + model.torque_delay, **tables)
    return dataclasses.replace(truth, effects=effects)

