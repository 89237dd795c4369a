"""Simulated payload runs from inverse dynamics (no simulator): for tests and the benchmark.

A true arm that differs from the a-priori model (perturbed inertias, Coulomb and viscous
friction on every joint), a random box-shaped payload, and the loaded and unloaded runs of one
motion with white torque noise: exactly the model of :mod:`pe_drake.identification.payload`
plus the arm's errors, so what the fit gets wrong is attributable to it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from pe_drake.identification.measurements import Measurement
from pe_drake.multibody.drive_columns import coulomb_column
from pe_drake.multibody.inertia import perturb_inertias
from pe_drake.multibody.payload import PayloadInertia, box_inertia, link_columns
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.robot_model import RobotModel

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


def random_box_payload(rng: np.random.Generator, *, mass_range=(0.3, 3.0), size_range=(0.05, 0.25),
                       max_off_axis: float = 0.1, axial_range=(0.0, 0.15)) -> PayloadInertia:
    """A solid box of random mass, edges, orientation and placement, in the flange frame
    (z the flange axis): centre of mass at most ``max_off_axis`` from the z axis [m]."""
    m = float(rng.uniform(*mass_range))
    size = rng.uniform(*size_range, 3)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = rng.uniform(-np.pi, np.pi)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
    r, theta = max_off_axis * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
    com = np.array([r * np.cos(theta), r * np.sin(theta), rng.uniform(*axial_range)])
    return PayloadInertia(m, com, R @ box_inertia(m, size) @ R.T)


def random_true_arm(robot: Robot, rng: np.random.Generator, *, inertia_error: float = 0.05,
                    coulomb_range=(0.2, 1.0), viscous_range=(0.05, 0.3)) -> RobotModel:
    """The true arm as built: the a-priori model with every body's inertia perturbed by
    ``inertia_error`` (:func:`~pe_drake.multibody.inertia.perturb_inertias`) and Coulomb and
    viscous friction on every joint (v_s the default)."""
    phi = perturb_inertias(robot.phi_model, inertia_error, rng)
    drive = {"coulomb": rng.uniform(*coulomb_range, robot.n), "viscous": rng.uniform(*viscous_range, robot.n)}
    return RobotModel(robot.joint_names, robot.body_names, phi, drive)


def payload_run(robot: Robot, motion, arm: RobotModel, link: str, payload: PayloadInertia | None, *, rate_hz: float = 1000.0,
                t0: float = 0.0, noise_std=0.04, seed: int = 0, model: RegressorModel | None = None) -> Measurement:
    """One run of ``motion`` (anything with ``evaluate(t)`` and ``duration``/``period``) on the
    true arm (its φ, Coulomb and viscous friction), with ``payload`` on ``link`` (None:
    unloaded), sampled at ``t0 + k/rate_hz``.

    Returns:
        A :class:`Measurement` with exact q, v, vd and noisy torques.
    """
    model = model or RegressorModel(robot)
    duration = motion.duration if hasattr(motion, "duration") else motion.period
    t = np.arange(t0, duration, 1.0 / rate_hz)
    q, v, vd = motion.evaluate(t)
    phi = arm.phi.copy()
    if payload is not None:
        phi[link_columns(robot, link)] += payload.phi
    tau = np.concatenate([model(q[s : s + 2000], v[s : s + 2000], vd[s : s + 2000]) @ phi for s in range(0, t.size, 2000)])
    tau += arm.coulomb * coulomb_column(v, arm.velocity_scale) + arm.viscous * v
    rng = np.random.default_rng(seed)
    tau += rng.normal(size=tau.shape) * np.broadcast_to(np.asarray(noise_std, float), (robot.n,))
    return Measurement(t=t - t[0], q=q, tau=tau, v=v, vd=vd, joints=robot.joint_names,
                       source="<loaded>" if payload is not None else "<unloaded>")
