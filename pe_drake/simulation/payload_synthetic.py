"""Simulated payload runs from inverse dynamics (no simulator): for tests and the benchmark.

A true arm with perturbed inertias and friction, a random box payload, and loaded and unloaded
runs with white torque noise: exactly the model of :mod:`pe_drake.identification.payload` plus
the arm's errors, so what the fit gets wrong is attributable to it.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.identification.measurements import Measurement
from pe_drake.multibody.inertia import perturb_inertias
from pe_drake.multibody.payload import PayloadInertia, box_inertia
from pe_drake.multibody.robot_model import RobotModel

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


def random_box_payload(rng: np.random.Generator) -> PayloadInertia:
    """A solid box of random orientation, mass 0.3-3 kg and edges 0.05-0.25 m in the flange frame
    (z the flange axis), its centre of mass within 0.1 m of the z axis, 0-0.15 m along it."""
    m = float(rng.uniform(0.3, 3.0))
    size = rng.uniform(0.05, 0.25, 3)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = rng.uniform(-np.pi, np.pi)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
    r, theta = 0.1 * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
    com = np.array([r * np.cos(theta), r * np.sin(theta), rng.uniform(0.0, 0.15)])
    return PayloadInertia(m, com, R @ box_inertia(m, size) @ R.T)


def random_true_arm(robot: Robot, rng: np.random.Generator) -> RobotModel:
    """The true arm as built: the a-priori model with every body's inertia perturbed by 5 %,
    Coulomb friction 0.2-1 N·m and viscous friction 0.05-0.3 N·m·s/rad on every joint."""
    phi = perturb_inertias(robot.phi_model, 0.05, rng)
    drive = {"coulomb": rng.uniform(0.2, 1.0, robot.n), "viscous": rng.uniform(0.05, 0.3, robot.n)}
    return RobotModel(robot.joint_names, robot.body_names, phi, drive)


def payload_run(robot: Robot, motion, arm: RobotModel, link: str, payload: PayloadInertia | None, *,
                rate_hz: float = 1000.0, t0: float = 0.0, noise_std=0.04,
                seed: int = 0) -> Measurement:
    """One run of ``motion`` (anything with ``evaluate(t)`` and ``duration``/``period``) on the
    true arm with ``payload`` on ``link`` (None: unloaded), sampled at ``t0 + k/rate_hz``: exact
    q, v, vd and noisy torques."""
    duration = motion.duration if hasattr(motion, "duration") else motion.period
    t = np.arange(t0, duration, 1.0 / rate_hz)
    q, v, vd = motion.evaluate(t)
    if payload is not None:
        arm = dataclasses.replace(arm, payload=payload, payload_link=link)
    tau = arm.torque(robot, q, v, vd)
    rng = np.random.default_rng(seed)
    tau += rng.normal(size=tau.shape) * np.broadcast_to(np.asarray(noise_std, float), (robot.n,))
    return Measurement(t=t - t[0], q=q, tau=tau, v=v, vd=vd, joints=robot.joint_names,
                       source="<loaded>" if payload is not None else "<unloaded>")
