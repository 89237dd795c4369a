"""A :class:`~pe_drake.multibody.robot_model.RobotModel` as a Drake plant (:func:`model_plant`)."""

from __future__ import annotations

import numpy as np

from pe_drake.exceptions import ConfigError
from pe_drake.multibody.dahl import dahl_builder_hook
from pe_drake.multibody.drive_columns import NONNEGATIVE, coulomb_column, coulomb_velocities
from pe_drake.multibody.inertia import phi_to_spatial_inertia
from pe_drake.multibody.payload import payload_spatial_inertia
from pe_drake.multibody.robot import Robot, load_robot

#: Name of the payload body in the plant and the URDF.
PAYLOAD_BODY_NAME = "pe_drake_payload"
#: Input port of the plant's diagram that takes the actuator torque when a Dahl friction
#: system shares the plant's applied-generalized-force input.
APPLIED_FORCE_PORT = "applied_generalized_force"


def model_plant(model, robot: Robot):
    """A :class:`~pe_drake.multibody.robot_model.RobotModel` in Drake (its ``plant``).

    A continuous :class:`~pe_drake.multibody.robot.Robot` of ``robot``'s config with these
    inertias, damping, Coulomb ``DoorHinge``, rotor inertia, payload body and, with pre-sliding
    friction, the Dahl system whose diagram exports :data:`APPLIED_FORCE_PORT`. Offsets are not in
    the plant: add them to its torque.

    Through a transmission, a motor that turns one joint is that joint's damping R_ii²·F_v,
    ``DoorHinge`` |R_ii|·F_c and rotor inertia R_ii²·I; a coupled motor's friction is a generalized
    force of the friction system, and the off-diagonal rotor inertia C the diagram's rotor-coupling
    system (:mod:`~pe_drake.multibody.rotor_coupling`): the diagram's forward dynamics are exact,
    the plant's own inverse dynamics and mass matrix lack C.

    Raises:
        ValueError: other joints or bodies than the robot's.
        ConfigError: a negative friction or armature (:meth:`nonnegative` removes them).
    """
    from pydrake.math import RigidTransform  # lazy: pydrake stays out of `import pe_drake`
    from pydrake.multibody.tree import PrismaticSpring, RevoluteSpring

    model.check_robot(robot)
    for t in NONNEGATIVE:
        bad = [f"{j} {x:.3g}" for j, x in zip(model.joints, model.term(t)) if x < 0]
        if bad:
            raise ConfigError(f"{t} must be ≥ 0 in Drake, got {', '.join(bad)}")
    joint = model.per_joint_model()
    viscous, coulomb, armature, coupled = joint.viscous, joint.coulomb, joint.armature, coupled_friction(model)
    revolute = [info.kind == "revolute" for info in robot.joints]
    payload = payload_spatial_inertia(model.payload) if model.payload is not None else None

    def before_finalize(plant, scene_graph):
        for k, name in enumerate(model.joints):
            joint = plant.GetJointByName(name)
            joint.set_default_damping_vector([viscous[k]])
            if coulomb[k] > 0 and revolute[k]:  # a DoorHinge is revolute
                add_coulomb_friction(plant, joint, float(coulomb[k]), model.velocity_scale)
            if armature[k] > 0:
                set_armature(plant, joint, float(armature[k]))
            if model.spring[k] > 0:  # Drake's spring applies -k q: the actuator's torque has +k q
                plant.AddForceElement((RevoluteSpring if revolute[k] else PrismaticSpring)(joint, 0.0, model.spring[k]))
        if payload is not None:
            link = plant.GetBodyByName(model.payload_link)
            body = plant.AddRigidBody(PAYLOAD_BODY_NAME, link.model_instance(), payload)
            plant.WeldFrames(link.body_frame(), body.body_frame(), RigidTransform())

    fc, sigma0 = model.presliding, model.presliding_stiffness
    # Coulomb friction on a prismatic joint (which a DoorHinge cannot carry) goes to the
    # friction system of the Dahl hook, without pre-sliding.
    sliding = np.where(revolute, 0.0, coulomb)
    cross = model.rotor_coupling()
    hook = (dahl_builder_hook(fc, sigma0, APPLIED_FORCE_PORT, sliding, model.velocity_scale, coupled,
                              cross if np.any(cross) else None)
            if np.any(fc > 0) or np.any(sliding > 0) or coupled is not None or np.any(cross) else None)
    out = load_robot(robot.config, time_step=0.0, before_finalize=before_finalize, builder_hook=hook)
    for b, name in enumerate(model.bodies):
        phi_b = model.phi[10 * b : 10 * b + 10]
        if phi_b[0] > 0:  # massless frames keep the model file's (zero) inertia
            out.plant.GetBodyByName(name).SetSpatialInertiaInBodyFrame(out.plant_context, phi_to_spatial_inertia(phi_b))
    for system in getattr(hook, "systems", ()):  # the rotor coupling evaluates on the plant's parameters
        system.sync(out.plant_context)
    return out


def add_coulomb_friction(plant, joint, f_c: float, v_s: float) -> None:
    """f_c·tanh(v/v_s) as a Drake DoorHinge whose only non-zero term is its dynamic friction."""
    from pydrake.multibody.tree import DoorHinge, DoorHingeConfig  # lazy: pydrake stays out of `import pe_drake`

    config = DoorHingeConfig(spring_constant=0.0, catch_torque=0.0, static_friction_torque=0.0,
                             viscous_friction=0.0, dynamic_friction_torque=f_c,
                             motion_threshold=v_s)
    plant.AddForceElement(DoorHinge(joint, config))


def set_armature(plant, joint, armature: float) -> None:
    """Reflected rotor inertia on the joint's actuator (gear² taken out), or a new actuator."""
    actuators = [plant.get_joint_actuator(a) for a in plant.GetJointActuatorIndices()
                 if plant.get_joint_actuator(a).joint().index() == joint.index()]
    if actuators:
        gear = actuators[0].default_gear_ratio() or 1.0
        actuators[0].set_default_rotor_inertia(armature / gear**2)
    else:
        actuator = plant.AddJointActuator(f"pe_drake_armature_{joint.name()}", joint)
        actuator.set_default_gear_ratio(1.0)
        actuator.set_default_rotor_inertia(armature)


def coupled_friction(model):
    """f(v): the torque the coupled motors' friction applies to the joints, (n,), or None."""
    T = model.transmission
    single = np.count_nonzero(T.R, axis=1) == 1 if T is not None else None
    if T is None or single.all():
        return None
    f_c, f_v, R = np.where(single, 0.0, model.coulomb), np.where(single, 0.0, model.viscous), T.R

    def coupled(v):
        w, scale = coulomb_velocities(v, model.velocity_scale, T)
        return -(R.T @ (f_c * coulomb_column(w, scale) + f_v * w))

    return coupled
