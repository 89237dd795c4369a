"""The robot ``pe-drake simulate --model FILE`` simulates: an identified model instead of the URDF's.

``FILE`` is an ``identified.json`` or the diagnosis's ``augmented_model.json``. Drake needs
physically valid standard parameters per body: a physical fit and an augmented model carry them;
for an OLS/WLS fit (base parameters φ_B = K φ only, whose minimum-norm φ makes links invalid)
the simulated φ is the physically consistent fit of φ_B itself, rows L K φ = L φ_B with
L = diag(1/σ_B): it reproduces φ_B exactly when a valid φ can, and the prior decides only the
directions no motion identifies. An armature merged into a base parameter is a variable ≥ 0 of
that fit. A negative friction or armature cannot be simulated and becomes 0, noted.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.exceptions import DataError
from pe_drake.identification.identified_file import load_identified
from pe_drake.identification.physical_fit import physical_fit
from pe_drake.multibody.inertia import validity_problems
from pe_drake.multibody.robot_model import RobotModel
from pe_drake.multibody.sensors import measurement_base_parameters

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: A base parameter of the simulated model more than this many σ from the file's is reported.
ATTAINABLE_SIGMA = 1.0


def load_simulation_model(path: str | Path, robot: Robot) -> RobotModel:
    """Reads identified.json or augmented_model.json as the model to simulate (module docstring).

    Raises:
        DataError: a file that is not one of these, or one of another robot or joints.
        NoSolutionFound: no physically valid parameters near the file's base parameters.
    """
    result = load_identified(path, robot)  # checks the file belongs to the robot
    as_built = isinstance(result, RobotModel)  # the diagnosis's augmented model
    # the notes say what the simulator adjusted, not the file's
    model = dataclasses.replace(result if as_built else result.model, notes=())
    if as_built or result.phi is not None:  # standard parameters of its own
        if not model.physical:
            problems = validity_problems(robot.body_names, model.phi)
            raise DataError("the model's standard parameters are not physically valid, so Drake cannot simulate "
                            "them: " + "; ".join(f"{b}: {why}" for b, why in problems.items()), file=str(path))
        return model.nonnegative("is simulated as 0")
    merged = result.drive_layout.merged if result.drive_layout is not None else {}
    sigma_B = np.abs(result.phi_B) * np.asarray(result.sigma_percent, float) / 100.0
    return consistent_model(robot, model, result.base, sigma_B, merged, result.phi_B).nonnegative("is simulated as 0")


def consistent_model(robot: Robot, model: RobotModel, base=None, sigma_B: np.ndarray | None = None,
                     merged: dict[str, dict[str, float]] | None = None,
                     phi_B: np.ndarray | None = None) -> RobotModel:
    """``model`` with physically consistent standard parameters: itself when it has them, else the
    physically consistent fit of its base parameters φ_B = K·phi_total (module docstring).

    Args:
        base: the base parameters that identify it (default: the joint torques').
        sigma_B: σ of φ_B, (b,) (default, or where not finite or 0: 1e-4 of each value).
        merged: {joint: {base parameter: coefficient}} of the armatures inside φ_B: variables
            ≥ 0 of the fit, added to the model's armature.
        phi_B: the base parameters to fit (default K·phi_total; a file's own, to the last digit).
    """
    if model.physical:
        return model
    base = base if base is not None else measurement_base_parameters(robot, "joint_torque")
    phi_B = base.K @ model.phi_total if phi_B is None else np.asarray(phi_B, float)
    merged = merged or {}
    sigma = np.full(len(phi_B), np.nan) if sigma_B is None else np.asarray(sigma_B, float)
    # An exact fit reports σ ≈ 0 and an old file none: weigh those at 1e-4 of their value,
    # floored so that the whitened rows stay within the SDP solver's range.
    sigma = np.where(np.isfinite(sigma) & (sigma > 0), sigma, 1e-4 * np.abs(phi_B))
    sigma = np.maximum(sigma, 1e-9 * np.abs(phi_B).max(initial=1e-12))
    L = np.diag(1.0 / sigma)
    C = np.zeros((base.count, len(merged)))  # v̇_j = Σ_k C_kj · (base column k): φ_B holds a_j C_j
    for i, joint in enumerate(merged):
        for name, coef in merged[joint].items():
            C[base.base_names.index(name), i] = coef
    fit = physical_fit(L @ base.K, L @ phi_B, robot.phi_model, robot.body_names, extra=L @ C if merged else None,
                       extra_lower=np.zeros(len(merged)), extra_names=[f"armature[{j}]" for j in merged],
                       base_K=base.K, chi2_tolerance=0.0,
                       extra_in_base={i: C[:, i] for i in range(len(merged))})
    theta = np.asarray(fit.theta, float)
    misfit = np.abs(base.K @ fit.phi + C @ theta - phi_B) / sigma
    notes = list(model.notes)
    worst = int(np.argmax(misfit)) if misfit.size else 0
    if misfit.size and misfit[worst] > ATTAINABLE_SIGMA:
        notes.append(f"the model has base parameters only; no physically valid links reproduce them all: "
                     f"the simulated {base.base_names[worst]} is {misfit[worst]:.3g} σ from the file's")
    armature = model.armature.copy()
    for joint, a in zip(merged, theta):
        armature[robot.joint_names.index(joint)] += float(a)
    return dataclasses.replace(model, phi=fit.phi, payload=None, payload_link="", physical=True,
                               drive={**model.drive, "armature": armature}, notes=tuple(notes))
