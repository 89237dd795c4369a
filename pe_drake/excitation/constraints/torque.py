"""Joint torque limits from the a-priori model: |τ_j(t)| ≤ ``robot.limits.effort_max[j]``.

τ(q, v, v̇) = Y(q, v, v̇) φ_model (Eq. 1 with the a-priori parameters, gravity included, joint
damping left out as everywhere in the regressor). ∂τ_j/∂(q, v, v̇) is the regressor adjoint
(Eq. 47) with the weights Z(t) = e_j ⊗ φ_model: one reverse pass per joint for all samples.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from pe_drake.exceptions import ConfigError, InfeasibleError
from pe_drake.excitation.constraints.base import SampledConstraint, SampledValues
from pe_drake.multibody.regressor import RegressorModel

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


class TorqueLimitError(InfeasibleError):
    """The nominal posture already needs more torque than a joint's limit."""


class TorqueConstraint(SampledConstraint):
    """−effort_j ≤ τ_j(q, v, v̇) ≤ effort_j at each sample (N·m or N).

    Raises:
        ConfigError: a joint without an effort limit (give ``robot.effort_limits``).
    """

    name = "torque"

    def __init__(self, robot: Robot, model: RegressorModel | None = None):
        effort = np.asarray(robot.limits.effort_max, float)
        missing = [j for j, e in zip(robot.joint_names, effort) if not np.isfinite(e) or e <= 0]
        if missing:
            raise ConfigError(
                f"torque limits requested but joint(s) {', '.join(missing)} have no effort limit in the "
                "model file; set robot.effort_limits {joint: N·m} in the config"
            )
        super().__init__([f"tau.{j}" for j in robot.joint_names], -effort, effort)
        self.robot = robot
        self.model = model or RegressorModel(robot)
        self.phi = robot.phi_model

    def evaluate(self, q: np.ndarray, v: np.ndarray, vd: np.ndarray, derivatives: bool = True) -> SampledValues:
        kin = self.model.kinematics(q, v, vd)
        Y = self.model.regressor(kin)
        tau = Y @ self.phi
        if not derivatives:
            return SampledValues(tau, np.empty(0))
        K, n = tau.shape
        d_q, d_v, d_vd = np.empty((3, K, n, n))
        for j in range(n):
            Z = np.zeros_like(Y)
            Z[:, j, :] = self.phi
            d_q[:, j], d_v[:, j], d_vd[:, j] = self.model.pullback(kin, Z)
        return SampledValues(tau, d_q, d_v, d_vd)

    def check_posture(self, q: np.ndarray) -> None:
        """Refuses a posture that needs more than the limit to hold still (gravity)."""
        q = np.atleast_2d(np.asarray(q, float))
        zero = np.zeros_like(q)
        tau = self.evaluate(q, zero, zero, derivatives=False).value
        over = np.abs(tau) - self.upper
        if np.any(over > 0):
            k, j = np.unravel_index(int(np.argmax(over)), over.shape)
            raise TorqueLimitError(
                f"holding the nominal posture needs {tau[k, j]:.4g} N·m at joint {self.robot.joint_names[j]}, "
                f"beyond its limit of {self.upper[j]:.4g} N·m; choose another robot.nominal_positions "
                "or a larger effort limit"
            )
