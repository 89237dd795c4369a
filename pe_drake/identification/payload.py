"""Payload (tool) identification: the 10 parameters of an object on one link, the arm frozen.

Every run r (loaded or not) gives rows of the linear model (Eq. 4 restricted to what is new)

    τ_r − Y_r φ_arm = Y_B,r δ_B + D_r θ + [r loaded] Y_L,r φ_L + ρ_r,

with φ_arm the arm's model, Y_L the payload link's 10 regressor columns, D the drive terms
(:mod:`~pe_drake.identification.payload_friction`) and δ_B what the arm model misses in its base
parameters (Eq. 2), shared by every run. Y_L lies in the span of the base columns, so δ_B and φ_L
are only separable with unloaded runs (of the same motion, not necessarily sample-aligned):
without them δ_B is fixed at 0 and the arm's model errors go into the payload.

The fit is weighted per joint (Gautier 1997) and physically consistent: J(φ_L) ⪰ 0 (Wensing et
al. 2017) and, given the object's box, its mass inside the box; an SDP (Clarabel). The σ are the
linearized least-squares covariance carried to mass, centre of mass and central inertia.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pe_drake.exceptions import ConfigError, DataError, check_joints
from pe_drake.identification.channels import CHUNK
from pe_drake.identification.least_squares import compress_joint_rows, weighted_fit_from_factors
from pe_drake.identification.payload_friction import FRICTION_TERMS, drive_names, friction_columns
from pe_drake.identification.physical_fit import SDP_TOLERANCES, InertiaBlock, scaled_factor, solve_sdp
from pe_drake.io_utils import atomic_write_text, finite_json
from pe_drake.multibody.base_parameters import BaseParameters, compute_base_parameters
from pe_drake.multibody.drive_columns import COULOMB_VELOCITY_SCALE
from pe_drake.multibody.inertia import pseudo_inertia, pseudo_inertia_basis
from pe_drake.multibody.payload import (PayloadInertia, central_jacobian, determined_std,
                                        link_position, payload_base_parameters,
                                        payload_parameter_map, payload_parameter_names,
                                        undetermined_parameters)
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.robot_model import RobotModel
from pe_drake.threads import single_threaded_blas

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


@dataclasses.dataclass(frozen=True)
class PayloadBox:
    """The object's bounding box in the payload link's frame L: centre p_LoBo_L [m], (3,), full
    edge lengths [m], (3,), each > 0, and axes R_LB, (3, 3) (default: L's axes)."""

    center: tuple[float, float, float]
    size: tuple[float, float, float]
    rotation: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))

    def __post_init__(self):
        size = np.asarray(self.size, float)
        R = np.asarray(self.rotation, float)
        if np.asarray(self.center, float).shape != (3,) or size.shape != (3,) or not np.all(np.isfinite(size)):
            raise ConfigError(f"payload box: center and size need 3 finite numbers, got {self.center}, {self.size}")
        if np.any(size <= 0):
            raise ConfigError(f"payload box: every edge length must be > 0 [m], got {list(self.size)}")
        if R.shape != (3, 3) or not np.allclose(R.T @ R, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
            raise ConfigError("payload box: rotation must be a 3×3 rotation matrix R_LB")


@dataclasses.dataclass(frozen=True)
class PayloadOptions:
    """How :func:`identify_payload` fits.

    Attributes:
        physical: keep the payload's pseudo-inertia ⪰ 0 (an SDP); False: plain weighted LS.
        box: the object's box (centre of mass and mass distribution inside it), or None.
        drive_terms: the per-joint nuisance terms, a subset of ``FRICTION_TERMS``.
        coulomb_velocity_scale: v_s of tanh(v/v_s) [rad/s].
        arm_correction: with unloaded runs, fit δ_B (the arm's base-parameter error).
        weighted: weigh joints by their residual σ_j (else every row by 1).
    """

    physical: bool = True
    box: PayloadBox | None = None
    drive_terms: tuple[str, ...] = FRICTION_TERMS
    coulomb_velocity_scale: float = COULOMB_VELOCITY_SCALE
    arm_correction: bool = True
    weighted: bool = True

    def __post_init__(self):
        if not (isinstance(self.coulomb_velocity_scale, (int, float)) and self.coulomb_velocity_scale > 0):
            raise ConfigError(f"coulomb_velocity_scale must be > 0 [rad/s], got {self.coulomb_velocity_scale!r}")
        bad = [t for t in self.drive_terms if t not in FRICTION_TERMS]
        if bad:
            raise ConfigError(f"unknown drive term(s) {bad}; valid: {', '.join(FRICTION_TERMS)}")


@dataclasses.dataclass(frozen=True, eq=False)
class PayloadResult:
    """An identified payload, in the link's frame L (about its centre of mass for the inertia).

    Attributes:
        payload: mass, p_LoPcm_L and I_PPcm_L.
        phi: the 10 parameters about Lo in L, (10,).
        cov_phi: their covariance, (10, 10) (linearized LS; the constraint assumed inactive).
        mass_std [kg], com_std (3,) [m], inertia_about_com_std (6,) [kg·m²]: σ of the
            reported values, [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] order.
        drive: {``<term>.<joint>``: value} of the nuisance drive terms.
        arm_correction: δ_B (b,) or None (no unloaded runs).
        noise_std: per-joint residual σ_j [N·m], (n,).
        constrained: the physical fit moved the estimate off the unconstrained one.
    """

    robot: str
    link: str
    payload: PayloadInertia
    phi: np.ndarray
    cov_phi: np.ndarray
    mass_std: float
    com_std: np.ndarray
    inertia_about_com_std: np.ndarray
    drive: dict[str, float]
    arm_correction: np.ndarray | None
    noise_std: np.ndarray
    loaded_runs: int
    unloaded_runs: int
    samples: int
    constrained: bool
    wall_time: float
    undetermined: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """The content of payload.json (the project's truth-file convention)."""
        p = self.payload
        valid = np.linalg.eigvalsh(pseudo_inertia(self.phi)).min() >= -1e-9 * max(p.mass, 1e-12)
        return {
            "robot": self.robot, "link": self.link,
            "frame": f"{self.link} (centre of mass from its origin; inertia about the centre of "
                     f"mass, {self.link}'s axes)",
            "mass": p.mass, "com": p.com.tolist(), "inertia_about_com": p.inertia_vector.tolist(),
            "inertia_order": ["Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz"],
            "mass_std": self.mass_std, "com_std": self.com_std.tolist(),
            "inertia_about_com_std": self.inertia_about_com_std.tolist(),
            "units": {"mass": "kg", "com": "m", "inertia_about_com": "kg*m^2"},
            "phi_about_link_origin": self.phi.tolist(), "physically_valid": bool(valid),
            "constrained": self.constrained, "drive_terms": self.drive,
            "noise_std": self.noise_std.tolist(), "loaded_runs": self.loaded_runs,
            "unloaded_runs": self.unloaded_runs, "samples": self.samples,
            "arm_correction_fitted": self.arm_correction is not None, "wall_time_s": self.wall_time,
            "not_determined": list(self.undetermined),
        }

    def write(self, path: str | Path) -> None:
        """Writes payload.json atomically."""
        atomic_write_text(path, json.dumps(finite_json(self.to_dict()), indent=2))


def arm_parameters(robot: Robot, arm_model=None) -> np.ndarray:
    """The arm's standard parameters: the robot's a-priori model (None), an array (10·nb,),
    an :class:`~pe_drake.identification.estimators.IdentificationResult` (its physical
    parameters, else the standard ones closest to the prior that reproduce its φ_B) or a
    :class:`~pe_drake.multibody.robot_model.RobotModel` (its parameters, payload included)."""
    if arm_model is None:
        return np.asarray(robot.phi_model, float)
    if isinstance(arm_model, (np.ndarray, list, tuple)):
        phi = np.asarray(arm_model, float)
        if phi.shape != (10 * robot.num_bodies,):
            raise ConfigError(f"arm model has shape {phi.shape}, expected ({10 * robot.num_bodies},)")
        return phi
    if isinstance(arm_model, RobotModel):
        return arm_model.phi_total
    if getattr(arm_model, "phi", None) is not None:
        return np.asarray(arm_model.phi, float)
    return arm_model.model.phi  # the standard parameters closest to the prior that give its φ_B


def identify_payload(robot: Robot, loaded_runs: Sequence, unloaded_runs: Sequence = (),
                     link: str = "", arm_model=None, options: PayloadOptions | None = None, *,
                     base: BaseParameters | None = None,
                     model: RegressorModel | None = None) -> PayloadResult:
    """Identifies the payload on ``link`` from loaded (and unloaded) runs (module docstring).

    Args:
        robot: the robot (without the payload).
        loaded_runs: preprocessed Measurements (with v and vd) carrying the payload.
        unloaded_runs: the same motions without it (any number; need not be sample-aligned).
        arm_model: see :func:`arm_parameters`.
        base, model: the robot's base parameters and regressor model, to reuse.

    Raises:
        DataError: no loaded run, runs without v/vd or torques, other joints, too few rows,
            data that does not excite the payload, a failed SDP.
        UnknownNameError: an unknown link.
    """
    start = time.perf_counter()
    options = options or PayloadOptions()
    if not loaded_runs:
        raise DataError("identify_payload needs at least one loaded run")
    link_position(robot, link)
    model = model or RegressorModel(robot)
    with_arm = bool(unloaded_runs) and options.arm_correction
    if with_arm and base is None:
        base = compute_base_parameters(robot, model=model)
    phi_arm = arm_parameters(robot, arm_model)
    runs = [(r, True) for r in loaded_runs] + [(r, False) for r in unloaded_runs]
    # φ_B = K_L φ_L: the combinations of the payload's parameters this robot's torques determine
    # (all 10 unless its axes leave some unexcitable, issue 37); the fit solves for those.
    pbase = payload_base_parameters(robot, link, model)
    K_L, K_plus = payload_parameter_map(pbase, robot, link)
    arm_base = base if with_arm else None
    with single_threaded_blas():  # small blocks: threads only add contention
        blocks = (block for run, loaded in runs for block in
                  _run_rows(robot, model, run, loaded, phi_arm, pbase, arm_base, options))
        R_joint, S = compress_joint_rows(blocks)
    n, p = robot.n, R_joint.shape[-1] - 1
    if S * n < 10 * p:
        raise DataError(f"{S} samples × {n} joints = {S * n} equations for {p} unknowns: record longer runs")
    x, cov, noise_std = weighted_fit_from_factors(R_joint, S, options.weighted)
    nb_arm, b = (base.count if with_arm else 0), pbase.count
    nd = len(options.drive_terms) * n
    constrained = False
    phi = K_plus @ x[-b:]
    if (options.physical and np.linalg.eigvalsh(pseudo_inertia(phi)).min() < 0) or options.box is not None or b < 10:
        w = 1.0 / noise_std if options.weighted else np.ones(n)
        x_phys, phi = _physical_fit(R_joint, w, x, K_L, K_plus, options.box)
        constrained = bool(np.linalg.norm(x_phys[-b:] - x[-b:]) > 1e-6 * np.linalg.norm(x[-b:]))
        x = x_phys
    cov_B = cov[-b:, -b:]
    std = determined_std(central_jacobian(phi), K_L, cov_B)
    undetermined = undetermined_parameters(pbase, robot, link)
    cov_phi = K_plus @ cov_B @ K_plus.T
    cov_phi[undetermined, :] = cov_phi[:, undetermined] = np.nan
    link_name = robot.body_names[link_position(robot, link)]
    return PayloadResult(
        robot=robot.name, link=link_name, payload=PayloadInertia.from_phi(phi),
        phi=phi, cov_phi=cov_phi, mass_std=float(std[0]), com_std=std[1:4], inertia_about_com_std=std[4:10],
        drive=dict(zip(drive_names(robot.joint_names, options.drive_terms), map(float, x[nb_arm : nb_arm + nd]))),
        arm_correction=x[:nb_arm] if with_arm else None, noise_std=noise_std,
        loaded_runs=len(loaded_runs), unloaded_runs=len(unloaded_runs), samples=S, constrained=constrained,
        wall_time=time.perf_counter() - start,
        undetermined=tuple(payload_parameter_names(link_name)[i] for i in undetermined),
    )


def _run_rows(robot: Robot, model, run, loaded: bool, phi_arm, pbase, base, options):
    """One run's columns [Y_B (with base) | D | the payload's base columns (loaded, else 0)] (s, n, p)
    and targets τ − Y φ_arm (s, n), chunk by chunk."""
    if run.v is None or run.vd is None or run.tau is None:
        raise DataError("a payload run needs q, v, vdot and tau (preprocess it first)", file=run.source)
    check_joints(robot, run.joints, file=run.source, what="the run")
    for s in range(0, run.num_samples, CHUNK):
        r = slice(s, min(s + CHUNK, run.num_samples))
        Y = model(run.q[r], run.v[r], run.vd[r])
        D = friction_columns(run.v[r], options.coulomb_velocity_scale, options.drive_terms)
        YL = pbase.reduce(Y) if loaded else np.zeros(Y.shape[:2] + (pbase.count,))
        parts = ([base.reduce(Y)] if base is not None else []) + [D, YL]
        yield np.concatenate(parts, axis=-1), run.tau[r] - Y @ phi_arm


def _physical_fit(R_joint, w, x_ls, K_L: np.ndarray, K_plus: np.ndarray, box: PayloadBox | None) -> tuple[np.ndarray, np.ndarray]:
    """min Σ_j w_j² ‖A_j x − y_j‖² s.t. J(φ_L) ⪰ 0 (and the box), K_L φ_L = the last b entries of x;
    returns (x, φ_L). Parameters K_L leaves out (no motion excites them) are kept small, so that
    φ_L is the least extended payload that explains the data."""
    Ra, z, D = scaled_factor(R_joint, w)
    p, b = len(D), K_L.shape[0]
    # variables [u (p), φ_L (10)], x = u / D
    Q = np.zeros((p + 10, p + 10))
    Q[:p, :p] = 2.0 * Ra.T @ Ra
    free = p + np.flatnonzero(np.abs(K_L).max(axis=0) == 0.0)
    Q[free, free] = 1e-6
    c = np.concatenate([-2.0 * Ra.T @ z, np.zeros(10)])
    rows = []
    for i in range(b):  # K_L φ_L = x[p - b + i]
        a = np.zeros(p + 10)
        a[p - b + i] = -1.0 / D[p - b + i]
        a[p:] = K_L[i]
        rows.append((a, 0.0, 0.0))
    for row, lo in box_constraint_rows(box) if box is not None else ():
        a = np.zeros(p + 10)
        a[p:] = row
        rows.append((a, lo, np.inf))
    guess = np.concatenate([x_ls * D, K_plus @ x_ls[p - b :]])
    sol = solve_sdp(Q, c, [InertiaBlock(p, np.ones(10))], guess, rows=rows, what="payload fit",
                    advice="is the box right? try physical=False", tolerances=SDP_TOLERANCES[:1])
    return sol[:p] / D, sol[p:]


def box_constraint_rows(box: PayloadBox) -> list[tuple[np.ndarray, float]]:
    """Linear inequalities a·φ_L ≥ lo of "all the mass inside the box": the centre of mass
    between each pair of faces, and ∫(s_i/2)² − x_B,i² dm ≥ 0 along each box axis (x_B the
    position in box coordinates); with J ⪰ 0 they hold for every density inside the box."""
    c0, size, R = (np.asarray(a, float) for a in (box.center, box.size, box.rotation))
    F = pseudo_inertia_basis()
    rows = []
    for i in range(3):
        e = R[:, i]
        a = np.zeros(10)
        a[1:4] = e
        a[0] = -e @ c0
        half = 0.5 * size[i]
        # e·(h − m c0) ≥ −m·half and ≤ m·half
        rows.append((a + half * np.eye(10)[0], 0.0))
        rows.append((-a + half * np.eye(10)[0], 0.0))
        # m half² − [eᵀΣe − 2 (e·c0)(e·h) + m (e·c0)²] ≥ 0, Σ = J[:3, :3] linear in φ
        second = np.array([e @ Fk[:3, :3] @ e for Fk in F])
        b = -second
        b[1:4] += 2.0 * (e @ c0) * e
        b[0] += half**2 - (e @ c0) ** 2
        rows.append((b, 0.0))
    return rows


def payload_errors(result: PayloadResult, truth: PayloadInertia) -> dict[str, float]:
    """Errors against a known payload: mass [%], centre of mass [m], central inertia relative
    to the largest principal moment of the truth [%], and the largest |error|/σ of each."""
    p = result.payload
    lam_max = float(np.linalg.eigvalsh(truth.inertia_about_com).max())
    dI = p.inertia_vector - truth.inertia_vector
    dc = p.com - truth.com
    return {
        "mass_percent": 100.0 * abs(p.mass - truth.mass) / truth.mass,
        "com_m": float(np.linalg.norm(dc)),
        "inertia_percent_of_max": 100.0 * float(np.abs(dI).max()) / lam_max,
        "mass_sigmas": abs(p.mass - truth.mass) / max(result.mass_std, 1e-300),
        "com_sigmas": float(np.max(np.abs(dc) / np.maximum(result.com_std, 1e-300))),
        "inertia_sigmas": float(np.max(np.abs(dI) / np.maximum(result.inertia_about_com_std, 1e-300))),
    }


def check_payload_trajectory(trajectory: dict, link: str, source: str = "trajectory.json") -> None:
    """Refuses a trajectory.json written for another payload link (its ``payload_link``).

    Raises:
        DataError: the file names another link (a file without ``payload_link`` is an arm
            motion: accepted, since any exciting motion also excites the payload).
    """
    recorded = trajectory.get("payload_link")
    if recorded and recorded != link:
        raise DataError(f"the motion was optimized for a payload on '{recorded}', not '{link}': pass "
                        f"--payload {recorded} or optimize a motion for '{link}'", file=source)
