"""Simulated measurements: a perturbed "true" robot tracking a trajectory in Drake.

The true robot is the truth's :class:`~pe_drake.multibody.robot_model.RobotModel` in a
continuous plant (:meth:`~pe_drake.multibody.robot_model.RobotModel.plant`): Coulomb friction
is a ``DoorHinge`` the integrator sees, where a discrete plant would need a far smaller step.

**Sign convention of the recorded torque.** ``tau`` is the torque the actuator applies; the
effects are loads it overcomes, so once tracking has converged::

    tau(t) = ID_rb(q, v, vd) + viscous·v + coulomb·tanh(v/v_s) + F_c·z + armature·vd + offset

An offset o is a constant torque -o on the joint; ``tau = Y·phi + f_v·v + f_c·sign(v) + o``
recovers it with its sign. The command tau_k is held over [t_k, t_k + h), so it leads the motion
by h/2: the log records (tau_{k-1} + tau_k)/2, centred on t_k (``record_command: true`` keeps the
raw command). A torque delay d then gives ``tau_recorded(t) = tau(t - d)`` (d > 0: the torque
log lags the positions); noise comes last.

Control: computed torque + PD with zero-order hold on the a-priori (or true) rigid-body model,
plus the model file's friction fed forward at the desired velocity where the simulated robot
keeps it (README, "Identify, validate, export"); a friction the truth sets is left to feedback.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from pe_drake.config import check_finite
from pe_drake.exceptions import ConfigError, DataError, PeDrakeError
from pe_drake.excitation.fourier import FourierTrajectory
from pe_drake.identification.measurements import Measurement
from pe_drake.multibody.drive_columns import coulomb_column
from pe_drake.multibody.inertia import PARAMETER_NAMES
from pe_drake.multibody.model_plant import APPLIED_FORCE_PORT
from pe_drake.multibody.robot import Robot
from pe_drake.multibody.sensors import MeasurementType
from pe_drake.multibody.wrench import weld_reaction
from pe_drake.simulation.contact import without_contact
from pe_drake.simulation.truth import Truth, load_truth, make_truth


class SimulationError(PeDrakeError):
    """The simulation diverged (NaN or infinite state)."""


class SimulationOutput(NamedTuple):
    """What :func:`simulate` returns: the log and the JSON-ready truth record."""

    measurement: Measurement
    truth: dict[str, Any]


@dataclasses.dataclass(frozen=True, eq=False)
class TrackingLog:
    """The true state and the controller's commands at the K control instants, (K, n)."""

    t: np.ndarray  # (K,) [s]
    q_d: np.ndarray  # desired positions [rad]
    q: np.ndarray  # true positions [rad]
    v: np.ndarray  # true velocities [rad/s]
    tau: np.ndarray  # commands tau_k, each held over [t_k, t_k + h) [N·m]
    wall_time: float  # [s]


def build_true_robot(robot: Robot, truth: Truth) -> Robot:
    """The robot as built of a truth in Drake, without contact forces (``robot``'s config is
    reloaded: bodies added by its own ``before_finalize`` are not carried over)."""
    true = truth.model.plant(robot)
    without_contact(true)
    return true


def _force_input(true: Robot):
    """(port, context) of the applied generalized force the controller sets: the diagram's
    exported input when a system adds its torque (Dahl, prismatic Coulomb), else the plant's."""
    if true.diagram.HasInputPort(APPLIED_FORCE_PORT):
        return true.diagram.GetInputPort(APPLIED_FORCE_PORT), true.context
    return true.plant.get_applied_generalized_force_input_port(), true.plant_context


def simulate(robot: Robot, trajectory: FourierTrajectory, truth: Truth | str | Path | None = None,
             duration: float | None = None, measurement: str = "joint_torque") -> SimulationOutput:
    """Simulates a run of the true robot tracking a trajectory; returns what it logs.

    Args:
        truth: a :class:`~pe_drake.simulation.truth.Truth` of the robot, or the path of a
            TRUTH.yaml (None: the model alone, no noise, the default controller).
        duration: simulated time [s]; default one period of the trajectory.
        measurement: what the robot logs: "joint_torque" (tau), "base_wrench" (the ground
            wrench alone) or "both".

    Raises:
        ConfigError: a bad truth or duration.
        UnknownNameError: a truth names a joint or link the robot does not have.
        DataError: a trajectory for a different number of joints.
    """
    if not isinstance(truth, Truth):
        truth = load_truth(truth, robot) if truth is not None else make_truth(robot)
    duration = _check_run(robot, trajectory, truth, duration)
    true = build_true_robot(robot, truth)
    log = track_trajectory(robot, true, trajectory, truth, duration)
    sensors = MeasurementType(measurement)
    data = record_log(robot, truth, log)
    applied = log.tau - truth.model.per_joint_model().offset
    wrench = recorded_wrench(true, truth, log.q, log.v, applied) if sensors.wrench else None
    data = data.replace(tau=data.tau if sensors.torques else None, wrench=wrench)
    record = _truth_dict(robot, truth, duration, log)
    return SimulationOutput(data, {**record, "measurement": sensors.kind})


def _check_run(robot: Robot, trajectory: FourierTrajectory, truth: Truth, duration: float | None) -> float:
    """The duration [s] after checking the trajectory's joints and the torque delay."""
    if trajectory.num_joints != robot.n:
        raise DataError(f"the trajectory has {trajectory.num_joints} joints, robot '{robot.name}' "
                        f"has {robot.n} excited joints ({', '.join(robot.joint_names)})")
    duration = trajectory.period if duration is None else duration
    duration = check_finite("duration [s]", duration, positive=True)
    delay = truth.model.torque_delay
    if abs(delay) >= duration:
        raise ConfigError(f"effects.torque_delay {delay} s is not shorter than the duration {duration} s")
    return duration


def _controller_plant(robot: Robot, true: Robot, model: str):
    """(plant, context) the computed-torque law evaluates: the a-priori or the true model."""
    if model == "prior":
        return robot.plant, robot.plant.CreateDefaultContext()
    plant, ctx = true.plant, true.plant_context
    ctl_ctx = plant.CreateDefaultContext()
    for b in robot.body_names:  # the default context lacks the perturbed inertias
        body = plant.GetBodyByName(b)
        body.SetSpatialInertiaInBodyFrame(ctl_ctx, body.CalcSpatialInertiaInBodyFrame(ctx))
    return plant, ctl_ctx


def _start_simulator(true: Robot, truth: Truth, q0: np.ndarray, v0: np.ndarray, h: float):
    """A Drake Simulator of the true robot at (q0, v0) with the truth's integrator."""
    from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator  # lazy: pydrake stays out of `import pe_drake`

    plant, ctx = true.plant, true.plant_context
    plant.SetPositions(ctx, q0)
    plant.SetVelocities(ctx, v0)
    port, port_context = _force_input(true)
    port.FixValue(port_context, np.zeros(len(q0)))
    simulator = Simulator(true.diagram, true.context)
    integrator = ResetIntegratorFromFlags(simulator, truth.integrator, h)
    if not integrator.get_fixed_step_mode():  # fixed-step schemes step at 1 / rate_hz
        integrator.set_target_accuracy(truth.integration_accuracy)
    simulator.Initialize()
    return simulator


def track_trajectory(robot: Robot, true: Robot, trajectory: FourierTrajectory, truth: Truth,
                     duration: float) -> TrackingLog:
    """Runs the computed-torque controller on the true robot (module docstring) for
    ``duration`` [s].

    Raises:
        SimulationError: the state became NaN or infinite.
    """
    from pydrake.multibody.tree import MultibodyForces  # lazy: pydrake stays out of `import pe_drake`

    plant, ctx = true.plant, true.plant_context
    ctl_plant, ctl_ctx = _controller_plant(robot, true, truth.control.model)
    forces = MultibodyForces(ctl_plant)
    rate = truth.control.rate_hz
    h = 1.0 / rate
    count = int(math.floor(duration * rate + 1e-9)) + 1
    t = np.arange(count) * h
    q_d, v_d, vd_d = trajectory.evaluate(t)
    kp, kd = truth.control.kp, truth.control.kd
    # the model file's friction the simulated robot keeps, fed forward at v_d (module docstring)
    joint = truth.model.per_joint_model()  # through a transmission, the motors' terms per joint
    kept = truth.model.transmission is None  # with one the model file's friction is not simulated
    damping = np.where(kept & np.isclose(joint.viscous, robot.joint_damping), robot.joint_damping, 0.0)
    friction = np.where(kept & np.isclose(joint.coulomb, robot.joint_friction), robot.joint_friction, 0.0)
    v_s = truth.model.velocity_scale
    simulator = _start_simulator(true, truth, q_d[0], v_d[0], h)
    port, port_context = _force_input(true)
    q_log, v_log, tau_log = (np.empty((count, robot.n)) for _ in range(3))
    wall = time.perf_counter()
    for k in range(count):
        q = plant.GetPositions(ctx)
        v = plant.GetVelocities(ctx)
        a_ref = vd_d[k] + kp * (q_d[k] - q) + kd * (v_d[k] - v)
        ctl_plant.SetPositions(ctl_ctx, q)
        ctl_plant.SetVelocities(ctl_ctx, v)
        tau_g = ctl_plant.CalcGravityGeneralizedForces(ctl_ctx)
        tau = ctl_plant.CalcInverseDynamics(ctl_ctx, a_ref, forces) - tau_g
        tau = tau + damping * v_d[k] + friction * coulomb_column(v_d[k], v_s)
        q_log[k], v_log[k], tau_log[k] = q, v, tau
        if k + 1 < count:
            # The offset is a constant load the actuator must overcome (module docstring).
            port.FixValue(port_context, tau - joint.offset)
            simulator.AdvanceTo(t[k + 1])
            if not np.isfinite(plant.GetPositionsAndVelocities(ctx)).all():
                raise SimulationError(f"the simulated state became NaN/inf at t = {t[k + 1]:.4g} "
                                      "s; check the truth file's values (gains, friction, "
                                      "payload) and the model's inertias")
    return TrackingLog(t, q_d, q_log, v_log, tau_log, time.perf_counter() - wall)


def record_log(robot: Robot, truth: Truth, log: TrackingLog) -> Measurement:
    """What the sensors log: the centred (or raw) command delayed by the torque delay, encoder
    quantization and white noise (q, tau and v drawn in that order from the truth's seed,
    independently of the inertial perturbation)."""
    tau_rec = log.tau
    if not truth.record_command:  # centred on t_k: the held command leads by h/2 (module docstring)
        tau_rec = log.tau.copy()
        tau_rec[1:] = 0.5 * (log.tau[:-1] + log.tau[1:])
    delay, t = truth.model.torque_delay, log.t
    if delay != 0:
        tau_rec = np.column_stack([np.interp(t - delay, t, tau_rec[:, j]) for j in range(tau_rec.shape[1])])
    rng = np.random.default_rng(np.random.SeedSequence(truth.seed).spawn(2)[1])
    noise = truth.noise
    q_rec = log.q.copy()
    if noise.encoder_counts_per_rev > 0:
        step = 2 * math.pi / noise.encoder_counts_per_rev
        revolute = np.array([info.kind == "revolute" for info in robot.joints])
        q_rec[:, revolute] = np.round(q_rec[:, revolute] / step) * step
    if noise.q_std > 0:
        q_rec = q_rec + rng.normal(0.0, noise.q_std, q_rec.shape)
    if noise.tau_std > 0:
        tau_rec = tau_rec + rng.normal(0.0, noise.tau_std, tau_rec.shape)
    v_rec = None
    if truth.record_velocity:
        v_rec = log.v + (rng.normal(0.0, noise.v_std, log.v.shape) if noise.v_std > 0 else 0.0)
    return Measurement(log.t, q_rec, tau_rec, v_rec, None, robot.joint_names, "")


def recorded_wrench(true_robot: Robot, truth: Truth, q: np.ndarray, v: np.ndarray,
                    applied: np.ndarray) -> np.ndarray:
    """The logged ground wrench, the reaction at the root link's weld (the feet), (K, 6)
    [N, N·m] in ``wrench.*`` column order, with the truth's sensor noise and offset; ``applied``
    the generalized forces over [t_k, t_k + h), (K, n) [N·m]."""
    # The reaction jumps at t_k when the held command changes: centred on t_k like the torque
    # (unless the truth records the raw command).
    wrench = weld_reaction(true_robot, q, v, applied, centred=not truth.record_command)
    noise = truth.noise
    # Its own random stream: the q, tau and v noise stays as it was.
    rng = np.random.default_rng(np.random.SeedSequence(truth.seed).spawn(3)[2])
    std = np.repeat([noise.force_std, noise.moment_std], 3)
    offset = np.asarray(noise.wrench_offset, float) if noise.wrench_offset else np.zeros(6)
    return wrench + offset + rng.normal(size=wrench.shape) * std


def _truth_dict(robot: Robot, truth: Truth, duration: float, log: TrackingLog) -> dict[str, Any]:
    """The JSON-ready record of every true value of a run (``<out>.truth.json``)."""
    joints, bodies = list(robot.joint_names), robot.body_names
    tracking_rms = np.sqrt(np.mean((log.q - log.q_d) ** 2, axis=0))
    m, p = truth.model, truth.model.payload

    def per_joint(values):
        return {j: float(x) for j, x in zip(joints, values)}

    def source(term):
        return {j: "truth" if j in truth.friction_set.get(term, ()) else "model file" for j in joints}

    return {
        "robot": robot.name, "joints": joints, "bodies": list(bodies),
        "parameter_names": list(PARAMETER_NAMES),
        "parameters_frame": "about the body origin, in the body frame; payload lumped into its link",
        "phi_true": {b: m.phi_total[10 * i : 10 * i + 10].tolist() for i, b in enumerate(bodies)},
        "phi_model": {b: robot.phi_model[10 * i : 10 * i + 10].tolist() for i, b in enumerate(bodies)},
        "seed": truth.seed, "inertia_perturbation": truth.inertia_perturbation,
        "torque_equation": ("tau_recorded(t) = [ID_rigid_body_true(q, v, vd) + viscous*v + "
                            "coulomb*tanh(v/coulomb_velocity_scale) + presliding*z + armature*vd + "
                            "torque_offset](t - torque_delay) + noise"),
        "effects": {
            "viscous": {"unit": "N·m·s/rad", "values": per_joint(m.viscous),
                        "model_file_damping": per_joint(robot.joint_damping), "source": source("viscous"),
                        "note": "the simulated value: the truth's where it sets the joint, else the model file's"},
            "coulomb": {"unit": "N·m", "values": per_joint(m.coulomb),
                        "model_file_friction": per_joint(robot.joint_friction), "source": source("coulomb"),
                        "velocity_scale": m.velocity_scale, "velocity_scale_unit": "rad/s",
                        "model": "coulomb * tanh(v / velocity_scale)"},
            "armature": {"unit": "kg·m²", "values": per_joint(m.armature)},
            "presliding_friction": {"unit": "N·m", "values": per_joint(m.presliding),
                                    "stiffness": per_joint(m.presliding_stiffness),
                                    "stiffness_unit": "N·m/rad",
                                    "model": "Dahl: dz/dt = v (1 - z sgn v) * stiffness / presliding, "
                                             "torque presliding * z"},
            "torque_offset": {"unit": "N·m", "values": per_joint(m.offset),
                              "convention": "added to the recorded torque (a constant load -offset "
                                            "acts on the joint)"},
            "torque_delay": {"unit": "s", "value": m.torque_delay,
                             "convention": "tau_recorded(t) = tau(t - delay)"},
            **({"transmission": {**m.transmission.to_dict(),
                                 "drive_side": "viscous, coulomb, armature and torque_offset are per motor (named by "
                                               "its joint), motor side, acting on the joints through R^T",
                                 "plant_notes": m.plant_notes()}} if m.transmission is not None else {}),
            "payload": {"link": m.payload_link, "mass": p.mass if p else 0.0,
                        "com": (p.com if p else np.zeros(3)).tolist(),
                        "inertia_about_com": (p.inertia_vector if p else np.zeros(6)).tolist(),
                        "phi_about_link_origin": (p.phi if p else np.zeros(10)).tolist(),
                        "units": "kg, m, kg·m²"},
        },
        "noise": {**dataclasses.asdict(truth.noise),
                  "units": {"q_std": "rad", "v_std": "rad/s", "tau_std": "N·m", "force_std": "N",
                            "moment_std": "N·m", "wrench_offset": "N, N·m (fx, fy, fz, mx, my, mz)"}},
        "control": {**dataclasses.asdict(truth.control), "law": "computed torque + PD, zero-order hold",
                    "units": {"rate_hz": "Hz", "kp": "1/s²", "kd": "1/s"}},
        "record_velocity": truth.record_velocity,
        "torque_recorded": "command tau_k" if truth.record_command else "(tau_{k-1} + tau_k) / 2",
        "simulation": {"duration": duration, "samples": len(log.t),
                       "rate_hz": truth.control.rate_hz, "integrator": truth.integrator,
                       "accuracy": truth.integration_accuracy,
                       "tracking_error_rms": per_joint(tracking_rms), "tracking_error_unit": "rad",
                       "wall_time_s": log.wall_time},
    }


def truth_path_for(out: str | Path) -> Path:
    """``<out stem>.truth.json`` beside the output CSV."""
    out = Path(out)
    return out.parent / f"{out.stem}.truth.json"
