"""The payload model: the 10 inertial parameters of a rigid object attached to one link.

A payload welded to link L adds to L's own parameters φ_L (:data:`PARAMETER_NAMES` order, about
L's origin, in L's frame), so its torques are L's 10 regressor columns,
τ_payload = Y[:, :, cols(L)] φ_L (Eq. 1).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.exceptions import ConfigError, UnknownNameError
from pe_drake.multibody.base_parameters import BaseParameters, compute_base_parameters
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.inertia import (PARAMETER_NAMES, PARAMS_PER_BODY, inertia_matrix,
                                        inertia_vector, parallel_axis, phi_from_com)

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


def link_position(robot: Robot, link: str | int) -> int:
    """Position of ``link`` (a name, or a position) in ``robot.body_names`` (UnknownNameError)."""
    if isinstance(link, (int, np.integer)):
        if not 0 <= int(link) < robot.num_bodies:
            raise UnknownNameError("link", str(link), list(robot.body_names), where="payload link")
        return int(link)
    if link not in robot.body_names:
        where = "payload link (a body an excited joint moves)"
        raise UnknownNameError("link", link, list(robot.body_names), where=where)
    return robot.body_names.index(link)


def link_columns(robot: Robot, link: str | int) -> np.ndarray:
    """Indices of ``link``'s 10 columns in the standard regressor Y (10·nb columns), shape (10,)."""
    j = link_position(robot, link)
    return np.arange(PARAMS_PER_BODY * j, PARAMS_PER_BODY * (j + 1))


def payload_parameter_names(link: str) -> tuple[str, ...]:
    """``<param>.<link>`` of the payload's 10 parameters (as the robot's standard names)."""
    return tuple(f"{p}.{link}" for p in PARAMETER_NAMES)


def payload_base_parameters(robot: Robot, link: str | int, model=None) -> BaseParameters:
    """The base parameters of ``link``'s 10 columns of Y alone, over random states.

    On a robot whose axes are all vertical (a SCARA) they are 4 at most: the payload's tilting
    inertias and the height of its centre of mass never produce a torque (issue 37). ``K`` maps
    the 10·nb standard parameters; only ``link``'s columns are non-zero."""
    mask = np.zeros(PARAMS_PER_BODY * robot.num_bodies)
    mask[link_columns(robot, link)] = 1.0
    model = model or RegressorModel(robot)
    return compute_base_parameters(robot, model=model, rows=lambda q, v, vd: model(q, v, vd) * mask)


def payload_parameter_map(base: BaseParameters, robot: Robot,
                          link: str | int) -> tuple[np.ndarray, np.ndarray]:
    """(K_L, K_L⁺) of φ_B = K_L φ_L: the payload's base parameters from its 10, and back."""
    K_L = base.K[:, link_columns(robot, link)]
    return K_L, np.linalg.pinv(K_L)


def undetermined_parameters(base: BaseParameters, robot: Robot, link: str | int) -> np.ndarray:
    """Positions (0..9) of ``link``'s parameters that no combination in ``base`` contains."""
    K_L = base.K[:, link_columns(robot, link)]
    return np.flatnonzero(np.abs(K_L).max(axis=0, initial=0.0) == 0.0)


def determined_std(J: np.ndarray, K_L: np.ndarray, cov_B: np.ndarray) -> np.ndarray:
    """σ of outputs g(φ_L) with Jacobian J (k, 10) from Cov(φ_B) of φ_B = K_L φ_L.

    NaN for an output the data do not determine (its row not a combination of K_L's rows)."""
    G, *_ = np.linalg.lstsq(K_L.T, J.T, rcond=None)  # J ≈ Gᵀ K_L
    determined = np.linalg.norm(G.T @ K_L - J, axis=1) <= 1e-9 * np.maximum(np.linalg.norm(J, axis=1), 1e-300)
    std = np.sqrt(np.maximum(np.einsum("ik,kl,il->i", G.T, cov_B, G.T), 0.0))
    return np.where(determined, std, np.nan)


@dataclasses.dataclass(frozen=True)
class PayloadInertia:
    """A rigid payload: mass [kg], centre of mass p_FoPcm_F (3,) [m], I_PPcm_F (3, 3) [kg·m²]."""

    mass: float
    com: np.ndarray
    inertia_about_com: np.ndarray

    @classmethod
    def from_phi(cls, phi: np.ndarray) -> PayloadInertia:
        """From the 10 parameters about the frame's origin (m, h = m·c, I_Fo)."""
        phi = np.asarray(phi, float)
        m = float(phi[0])
        c = phi[1:4] / m if m != 0 else np.zeros(3)
        return cls(m, c, inertia_matrix(phi[4:10]) - parallel_axis(m, c))

    @property
    def phi(self) -> np.ndarray:
        """The 10 parameters about the frame's origin, shape (10,)."""
        return phi_from_com(self.mass, self.com, self.inertia_about_com)

    @property
    def inertia_vector(self) -> np.ndarray:
        """[Ixx, Iyy, Izz, Ixy, Ixz, Iyz] of the inertia about the centre of mass [kg·m²]."""
        return inertia_vector(self.inertia_about_com)

    def principal(self) -> tuple[np.ndarray, np.ndarray]:
        """Principal moments (ascending) and axes R (a rotation) of I_cm = R diag(λ) Rᵀ."""
        lam, R = np.linalg.eigh(0.5 * (self.inertia_about_com + self.inertia_about_com.T))
        if np.linalg.det(R) < 0:
            R[:, 2] *= -1.0
        return lam, R

    def in_frame(self, X_FG: np.ndarray) -> PayloadInertia:
        """The same payload expressed in frame G, given G's pose X_FG (4, 4) in the frame F."""
        X_FG = np.asarray(X_FG, float)
        R_FG, p_FG = X_FG[:3, :3], X_FG[:3, 3]
        return PayloadInertia(self.mass, R_FG.T @ (self.com - p_FG), R_FG.T @ self.inertia_about_com @ R_FG)


def central_jacobian(phi: np.ndarray) -> np.ndarray:
    """d(m, c, [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] of I_cm)/dφ, shape (10, 10), at φ (m > 0).

    c = h/m and I_cm = I_o − (|h|² 1 − h hᵀ)/m: it carries Cov(φ) to the σ of m, c and I_cm.
    """
    phi = np.asarray(phi, float)
    m, h = float(phi[0]), phi[1:4]
    J = np.zeros((10, 10))
    J[0, 0] = 1.0
    J[1:4, 0] = -h / m**2
    J[1:4, 1:4] = np.eye(3) / m
    J[4:10, 4:10] = np.eye(6)
    P = parallel_axis(1.0, h)  # |h|² 1 − h hᵀ, quadratic in h
    J[4:10, 0] = inertia_vector(P) / m**2
    for k, e in enumerate(np.eye(3)):
        dP = parallel_axis(1.0, h + e) - P - parallel_axis(1.0, e)  # ∂P/∂h_k (P is quadratic)
        J[4:10, 1 + k] = -inertia_vector(dP) / m
    return J


def box_inertia(mass: float, size: np.ndarray) -> np.ndarray:
    """Inertia about the centre of a uniform box with edge lengths ``size`` [m], (3, 3) [kg·m²]."""
    a, b, c = np.asarray(size, float)
    return mass / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])


def payload_spatial_inertia(payload: PayloadInertia):
    """A payload's Drake ``SpatialInertia`` about its frame's origin; ConfigError if invalid."""
    from pydrake.multibody.tree import RotationalInertia, SpatialInertia  # lazy: pydrake stays out of `import pe_drake`

    I_PPcm = RotationalInertia(*(float(x) for x in payload.inertia_vector))
    if not I_PPcm.CouldBePhysicallyValid():
        raise ConfigError(f"the payload inertia {payload.inertia_vector.tolist()} [kg·m²] is not physically valid "
                          "(moments must be non-negative and satisfy the triangle inequality)")
    try:
        return SpatialInertia.MakeFromCentralInertia(float(payload.mass), np.asarray(payload.com, float), I_PPcm)
    except RuntimeError as err:
        raise ConfigError(f"the payload is not physically valid: {err}") from err
