"""Exact measurements from a model, without a simulator: for tests and benchmarks.

The torques are the rigid-body inverse dynamics Y(q, v, v̇) φ of Eq. (1) along a Fourier
trajectory (Eq. 50), optionally with white noise: no tracking error, no integration and no
friction, so errors can be attributed to the estimator alone.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from pe_drake.excitation.fourier import FourierTrajectory
from pe_drake.identification.measurements import Measurement
from pe_drake.multibody.regressor import RegressorModel

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


def model_measurement(robot: Robot, trajectory: FourierTrajectory, phi: np.ndarray | None = None, *,
                      rate_hz: float = 200.0, duration: float | None = None,
                      tau_noise_std: float | np.ndarray = 0.0, seed: int = 0) -> Measurement:
    """A measurement of ``robot`` following ``trajectory`` with parameters ``phi`` (default: the
    a-priori model) for ``duration`` [s] (default: one period), exact v and vd, white torque noise
    ``tau_noise_std`` [N·m] (scalar or per joint)."""
    model = RegressorModel(robot)
    phi = robot.phi_model if phi is None else np.asarray(phi, float)
    duration = trajectory.period if duration is None else float(duration)
    t = np.arange(0.0, duration, 1.0 / rate_hz)
    q, v, vd = trajectory.evaluate(t)
    blocks = [slice(s, s + 2000) for s in range(0, len(t), 2000)]
    tau = np.concatenate([model(q[k], v[k], vd[k]) @ phi for k in blocks])
    rng = np.random.default_rng(seed)
    tau = tau + rng.normal(size=tau.shape) * np.broadcast_to(np.asarray(tau_noise_std, float), (robot.n,))
    return Measurement(t=t, q=q, tau=tau, v=v, vd=vd, joints=robot.joint_names, source="<model>")
