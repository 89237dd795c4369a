"""Transmissions between motors and joints: gear ratios and a coupling (issue 36).

Motor angles are θ_m = R q, R = diag(ratios) plus the coupling entries, and the joint torques
are τ = Rᵀ τ_m (the power θ̇_mᵀ τ_m = q̇ᵀ τ); the config (``robot.transmission``) is in the
README. Motors are named by the joint their ratio belongs to; a joint not in ``ratios`` has
ratio 1. A coupled motor's friction and rotor inertia act on every joint it turns with.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.exceptions import ConfigError, UnknownNameError

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: R is refused when its condition number is above this: the joint angles would not follow
#: from the motor angles.
MAX_TRANSMISSION_COND = 1e8


@dataclasses.dataclass(frozen=True, eq=False)
class Transmission:
    """θ_m = R q and τ = Rᵀ τ_m for the robot's excited joints ``joints``."""

    joints: tuple[str, ...]
    R: np.ndarray  # (n, n) [rad of motor per rad or m of joint], row i the motor of joint i

    @classmethod
    def from_config(cls, ratios: Mapping[str, float], coupling: Mapping[str, Mapping[str, float]],
                    joints: Sequence[str]) -> Transmission:
        """R from the config's ``robot.transmission`` (module docstring).

        Raises:
            UnknownNameError: a joint that is not excited (the valid ones listed).
            ConfigError: a ratio that is zero or not finite, a coupling of a motor with its own
                joint, or an R that does not determine the joint angles.
        """
        joints = tuple(joints)
        R = np.eye(len(joints))
        for name, ratio in ratios.items():
            i = _index(name, joints, "robot.transmission.ratios")
            R[i, i] = _number(f"robot.transmission.ratios['{name}']", ratio, nonzero=True)
        for motor, row in coupling.items():
            i = _index(motor, joints, "robot.transmission.coupling")
            for joint, value in row.items():
                j = _index(joint, joints, f"robot.transmission.coupling['{motor}']")
                if i == j:
                    raise ConfigError(f"robot.transmission.coupling['{motor}'] names its own joint '{joint}': "
                                      "its ratio goes in robot.transmission.ratios")
                R[i, j] = _number(f"robot.transmission.coupling['{motor}']['{joint}']", value)
        cond = np.linalg.cond(R)
        if not np.isfinite(cond) or cond > MAX_TRANSMISSION_COND:
            raise ConfigError(f"robot.transmission: the motor angles do not determine the joint angles "
                              f"(cond(R) = {cond:.3g}); check the ratios and the coupling")
        return cls(joints, R)

    @property
    def identity(self) -> bool:
        """No gear and no coupling: motor and joint sides are the same."""
        return bool(np.array_equal(self.R, np.eye(len(self.joints))))

    @property
    def coupled(self) -> bool:
        return bool(np.any(self.R - np.diag(np.diag(self.R))))

    def motor_positions(self, q: np.ndarray) -> np.ndarray:
        """θ_m = R q per sample, (T, n) [rad] (also θ̇_m, θ̈_m from q̇, q̈)."""
        return np.asarray(q, float) @ self.R.T

    def joint_positions(self, theta: np.ndarray) -> np.ndarray:
        """q = R⁻¹ θ_m per sample, (T, n) (also q̇, q̈ from θ̇_m, θ̈_m)."""
        return np.linalg.solve(self.R, np.asarray(theta, float).T).T

    def joint_torques(self, tau_motor: np.ndarray) -> np.ndarray:
        """τ = Rᵀ τ_m per sample, (T, n) [N·m]."""
        return np.asarray(tau_motor, float) @ self.R

    def motor_torques(self, tau: np.ndarray) -> np.ndarray:
        """τ_m = R⁻ᵀ τ per sample, (T, n) [N·m]."""
        return np.linalg.solve(self.R.T, np.asarray(tau, float).T).T

    def reflected(self, motor_values: np.ndarray) -> np.ndarray:
        """Rᵀ diag(x) R, (n, n): a per-motor friction or rotor inertia x as the joints see it."""
        return self.R.T @ (np.asarray(motor_values, float)[:, None] * self.R)

    def to_dict(self) -> dict:
        """JSON-ready: the joints, R row by row and its meaning (:meth:`from_dict` reads it)."""
        return {"joints": list(self.joints), "R": self.R.tolist(),
                "meaning": "motor angles theta_m = R q (row i: the motor of joint i), joint torques tau = R^T tau_m"}

    @classmethod
    def from_dict(cls, d: Mapping) -> Transmission:
        """Reads :meth:`to_dict`'s data; KeyError, TypeError or ValueError for a malformed block."""
        joints = tuple(str(j) for j in d["joints"])
        R = np.asarray(d["R"], float)
        if R.shape != (len(joints), len(joints)) or not np.all(np.isfinite(R)):
            raise ValueError(f"transmission.R must be finite and {len(joints)} x {len(joints)}, got shape {R.shape}")
        return cls(joints, R)


def robot_transmission(robot: Robot) -> Transmission:
    """A robot's transmission from its config's ``robot.transmission`` (identity without one)."""
    t = getattr(getattr(robot, "config", None), "transmission", None)
    if t is None:
        return Transmission(tuple(robot.joint_names), np.eye(robot.n))
    return Transmission.from_config(t.ratios, t.coupling, robot.joint_names)


def _index(name: str, joints: tuple[str, ...], field: str) -> int:
    if name not in joints:
        raise UnknownNameError("joint", name, joints, field)
    return joints.index(name)


def _number(field: str, value, nonzero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not np.isfinite(value) or (nonzero and value == 0):
        raise ConfigError(f"{field} must be a finite{' non-zero' if nonzero else ''} number, got {value!r}")
    return float(value)

