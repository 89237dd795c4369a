"""Unknown drive gains from a payload of known mass (Gautier & Briot 2014).

A robot that logs motor currents i_j measures τ_j = k_j i_j with unknown gains k_j. With runs
with and without a payload of known mass M on link L, every run's rows are

    k_j i_j − Y_B,j φ_B − D_j θ − [loaded] Y_L,j[:, 1:] φ_L[1:] = [loaded] M · Y_L,j[:, 0],

linear in x = [k, φ_B, θ, φ_L[1:]]: without M only ratios are identifiable, and the known mass
fixes the common scale. The arm's base parameters, the drive terms and the payload's first and
second moments are identified with the gains, so the runs must excite the arm. The physical fit
keeps k ≥ 0 and the payload's pseudo-inertia ⪰ 0.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from pe_drake.exceptions import ConfigError, DataError
from pe_drake.identification.least_squares import compress_joint_rows, weighted_fit_from_factors
from pe_drake.identification.payload import PayloadOptions
from pe_drake.identification.payload_friction import drive_names, friction_columns
from pe_drake.identification.physical_fit import InertiaBlock, factored_sdp
from pe_drake.multibody.base_parameters import compute_base_parameters
from pe_drake.multibody.inertia import pseudo_inertia
from pe_drake.multibody.payload import PayloadInertia, link_columns, link_position
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.threads import single_threaded_blas

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


@dataclasses.dataclass(frozen=True, eq=False)
class DriveGainResult:
    """Identified drive gains (τ = k·i) with the arm and payload identified alongside.

    Attributes:
        gains: k (n,) [N·m per unit of the logged signal]; gains_std: σ (n,).
        sigma_percent: 100·σ/k (n,).
        not_separable: joints whose gain the data does not determine (σ above the threshold).
        payload: the payload (mass = the given M) in the link's frame.
        phi_B: the arm's base parameters (b,); drive: {``<term>.<joint>``: value} in N·m units.
        constrained: the physical fit (k ≥ 0, J ⪰ 0) moved the estimate.
    """

    joints: tuple[str, ...]
    gains: np.ndarray
    gains_std: np.ndarray
    sigma_percent: np.ndarray
    not_separable: tuple[str, ...]
    payload: PayloadInertia
    phi_B: np.ndarray
    drive: dict[str, float]
    constrained: bool
    samples: int
    wall_time: float

    def to_dict(self) -> dict[str, Any]:
        def per_joint(x):
            return dict(zip(self.joints, map(float, x)))

        return {"gains": per_joint(self.gains), "gains_std": per_joint(self.gains_std),
                "gains_sigma_percent": per_joint(self.sigma_percent),
                "not_separable": list(self.not_separable), "payload_mass_given": self.payload.mass,
                "payload_com": self.payload.com.tolist(),
                "payload_inertia_about_com": self.payload.inertia_vector.tolist(),
                "drive_terms": self.drive, "constrained": self.constrained, "samples": self.samples,
                "wall_time_s": self.wall_time}


def identify_drive_gains(robot: Robot, loaded_runs: Sequence, unloaded_runs: Sequence, link: str, payload_mass: float, *,
                         options: PayloadOptions | None = None, max_sigma_percent: float = 5.0,
                         model: RegressorModel | None = None) -> DriveGainResult:
    """Identifies the drive gains, the arm and the payload (module docstring).

    Args:
        loaded_runs, unloaded_runs: Measurements whose ``tau`` holds the logged motor signal
            (currents), with v and vd.
        payload_mass: M > 0 [kg], known.
        options: drive terms and Coulomb v_s (its box is not used).
        max_sigma_percent: a gain with a larger relative σ is reported as not separable.

    Raises:
        ConfigError: a non-positive mass.
        DataError: no loaded run, or data that does not determine the unknowns.
    """
    start = time.perf_counter()
    if not (isinstance(payload_mass, (int, float)) and payload_mass > 0):
        raise ConfigError(f"the known payload mass must be > 0 [kg], got {payload_mass!r}")
    if not loaded_runs:
        raise DataError("identify_drive_gains needs at least one loaded run")
    options = options or PayloadOptions()
    link_position(robot, link)
    model = model or RegressorModel(robot)
    base = compute_base_parameters(robot, model=model)
    runs = [(r, True) for r in loaded_runs] + [(r, False) for r in unloaded_runs]
    with single_threaded_blas():
        R_joint, S = compress_joint_rows(block for run, loaded in runs for block in
                                         _gain_rows(robot, model, base, run, loaded, link, payload_mass, options))
    x, cov, noise = weighted_fit_from_factors(R_joint, S, True)
    n, b = robot.n, base.count
    x, cov = _errors_in_variables(R_joint, S, x, noise, n)
    constrained = False
    if np.any(x[:n] <= 0) or np.linalg.eigvalsh(pseudo_inertia(np.r_[payload_mass, x[-9:]])).min() < 0:
        x = _physical(R_joint, 1.0 / noise, x, n, payload_mass)
        constrained = True
    k, k_std = x[:n], np.sqrt(np.maximum(np.diag(cov)[:n], 0.0))
    sigma_percent = 100.0 * k_std / np.maximum(np.abs(k), 1e-300)
    nd = len(options.drive_terms) * n
    return DriveGainResult(
        joints=tuple(robot.joint_names), gains=k, gains_std=k_std, sigma_percent=sigma_percent,
        not_separable=tuple(j for j, s in zip(robot.joint_names, sigma_percent) if not s <= max_sigma_percent),
        payload=PayloadInertia.from_phi(np.concatenate([[payload_mass], x[-9:]])), phi_B=x[n : n + b],
        drive=dict(zip(drive_names(robot.joint_names, options.drive_terms), map(float, x[n + b : n + b + nd]))),
        constrained=constrained, samples=S, wall_time=time.perf_counter() - start)


def _gain_rows(robot: Robot, model, base, run, loaded: bool, link: str, M: float, options, chunk: int = 2000):
    """Columns [diag(i) | −Y_B | −D | −Y_L[:, 1:]] (s, n, p) and targets M·Y_L[:, 0] (s, n)."""
    if run.v is None or run.vd is None or run.tau is None:
        raise DataError("a drive-gain run needs q, v, vdot and the motor signal in tau (preprocess it first)",
                        file=run.source)
    cols = link_columns(robot, link)
    n = robot.n
    for s in range(0, run.num_samples, chunk):
        r = slice(s, min(s + chunk, run.num_samples))
        Y = model(run.q[r], run.v[r], run.vd[r])
        current = np.zeros((Y.shape[0], n, n))
        current[:, np.arange(n), np.arange(n)] = run.tau[r]
        YL = Y[..., cols] if loaded else np.zeros(Y.shape[:2] + (10,))
        D = friction_columns(run.v[r], options.coulomb_velocity_scale, options.drive_terms)
        yield np.concatenate([current, -base.reduce(Y), -D, -YL[..., 1:]], axis=-1), M * YL[..., 0]


def _errors_in_variables(R_joint, S: int, x, noise, n: int, iterations: int = 3):
    """(x, Cov(x)) corrected for the attenuation of the gains by the noise of the logged signal
    in their own columns (errors in variables): E[i_meas²] = i² + σ_i², with σ_i = σ_j / k_j, so
    S·σ_i² is taken off the diagonal of each gain's normal equation (weighted by 1/σ_j)."""
    w = 1.0 / noise
    N = np.einsum("jab,jac->bc", R_joint * w[:, None, None], R_joint * w[:, None, None])
    p = N.shape[0] - 1
    for _ in range(iterations):
        Nc = N.copy()
        sigma_i2 = (noise / np.maximum(np.abs(x[:n]), 1e-300)) ** 2
        Nc[np.arange(n), np.arange(n)] -= S * sigma_i2 * w**2
        scale = np.sqrt(np.maximum(np.diag(Nc[:p, :p]), 1e-300))
        A = Nc[:p, :p] / np.outer(scale, scale)
        x = np.linalg.solve(A, Nc[:p, p] / scale) / scale
    cov = np.linalg.inv(A) / np.outer(scale, scale)
    return x, cov


def _physical(R_joint, w, x_ls, n: int, M: float) -> np.ndarray:
    """min Σ_j w_j² ‖A_j x − y_j‖² s.t. k ≥ 0 and J(M, φ_L[1:]) ⪰ 0."""
    lower = np.full(len(x_ls), -np.inf)
    lower[:n] = 0.0
    # Clarabel's own tolerances (1e-8), as this fit has always been solved with.
    return factored_sdp(R_joint, w, x_ls, [InertiaBlock(len(x_ls) - 9, np.ones(9), fixed_mass=M)], lower=lower,
                        what="drive-gain fit", tolerances=(1e-8,))
