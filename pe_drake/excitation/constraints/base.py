"""The sampled-constraint interface every trajectory constraint implements.

A :class:`SampledConstraint` maps joint states at K sample times to m values per sample with
lower ≤ value ≤ upper, with analytic derivatives with respect to q (and v, vdot when it depends
on them). :mod:`pe_drake.excitation.program` chains these through the Fourier map (Eq. 49).
"""

from __future__ import annotations

import abc
import dataclasses
import math
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.exceptions import ConfigError

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


def robot_capsules(robot: Robot, margin, what: str, fix: str) -> tuple:
    """The robot's collision capsules, after checking the ``margin`` [m] of the ``what`` constraint.

    Raises:
        ConfigError: a margin that is not a finite number ≥ 0; a robot without capsules (the
            message ends with ``fix``: how to give it some).
    """
    if not isinstance(margin, (int, float)) or not math.isfinite(margin) or margin < 0:
        raise ConfigError(f"{what} margin must be a finite number >= 0 [m], got {margin!r}")
    capsules = tuple(getattr(robot, "capsules", ()) or ())
    if not capsules:
        raise ConfigError(f"robot '{robot.name}' has no collision capsules{fix}")
    return capsules


def check_postures(q: np.ndarray, robot: Robot, what: str) -> np.ndarray:
    """q as finite postures of the robot's excited joints, shape (K, n) (from (n,) or (K, n)).

    Raises:
        ConfigError: another shape, or NaN/infinity; ``what`` names the constraint.
    """
    q = np.asarray(q, float)
    if q.ndim == 1:
        q = q[None, :]
    if q.ndim != 2 or q.shape[1] != robot.n:
        raise ConfigError(
            f"{what}: q must have shape (K, {robot.n}) for the joints "
            f"{', '.join(robot.joint_names)}; got {np.shape(q)}"
        )
    if not np.isfinite(q).all():
        raise ConfigError(f"{what}: q contains NaN or infinity")
    return q


def state_margins(limits, constraints, q: np.ndarray, v: np.ndarray, vd: np.ndarray) -> dict[str, float]:
    """Smallest margin of the joint limits (per quantity, the worst joint) and of each sampled
    constraint over the states q, v, vd, each (K, n); negative is a violation."""
    margins = {
        "position": float(np.min(np.minimum(q - limits.q_lower, limits.q_upper - q))),
        "velocity": float(np.min(limits.v_max - np.abs(v))),
        "acceleration": float(np.min(limits.vd_max - np.abs(vd))),
    }
    for c in constraints:
        margins[c.name] = float(np.min(c.margins(q, v, vd)))
    return margins


@dataclasses.dataclass(frozen=True)
class SampledValues:
    """Values and derivatives of a sampled constraint.

    Attributes:
        value: shape (K, m).
        d_q: ∂value/∂q, shape (K, m, n).
        d_v: ∂value/∂v, shape (K, m, n), or None when independent of v.
        d_vd: ∂value/∂vdot, shape (K, m, n), or None when independent of vdot.
    """

    value: np.ndarray
    d_q: np.ndarray
    d_v: np.ndarray | None = None
    d_vd: np.ndarray | None = None


class SampledConstraint(abc.ABC):
    """lower ≤ g(q(t), v(t), vdot(t)) ≤ upper at each sample time.

    Attributes:
        name: short name used in reports ("balance", "collision", "torque").
        labels: one label per value row (e.g. the capsule pair), length m.
        lower, upper: shape (m,).
    """

    name: str = "constraint"

    def __init__(self, labels: list[str], lower: np.ndarray, upper: np.ndarray):
        self.labels = list(labels)
        self.lower = np.asarray(lower, float).reshape(-1)
        self.upper = np.asarray(upper, float).reshape(-1)

    @property
    def size(self) -> int:
        """m, values per sample."""
        return len(self.labels)

    @abc.abstractmethod
    def evaluate(self, q: np.ndarray, v: np.ndarray, vd: np.ndarray, derivatives: bool = True) -> SampledValues:
        """Values at K samples q, v, vd, each (K, n), and the derivatives unless
        ``derivatives`` is False (then d_q/d_v/d_vd may be empty arrays)."""

    def margins(self, q: np.ndarray, v: np.ndarray, vd: np.ndarray) -> np.ndarray:
        """Signed distance to the nearest bound at each sample, shape (K, m); < 0 is a
        violation (in the constraint's unit)."""
        g = self.evaluate(q, v, vd, derivatives=False).value
        return np.minimum(g - self.lower, self.upper - g)
