"""The ground wrench of a robot whose root link is welded to the world.

A humanoid standing still with only its upper body moving is a fixed-base robot for the
purpose of identification: the weld of the pelvis to the world stands for the feet on the
ground, and the wrench that weld transmits is what foot force/torque sensors or a force plate
measure. It is the sum of the Newton–Euler wrenches of every body (the six unactuated rows of
the floating-base equations, Y_0(q, v, vdot) φ; Ayusawa et al.'s references [7], [9]):

    w(t) = Y_0(q, v, vdot) φ + w_static,

with Y_0 the per-body world-frame force blocks side by side
(:meth:`pe_drake.multibody.regressor.RegressorModel.wrench_regressor`) and w_static the
constant weight of the bodies no excited joint moves (:func:`static_wrench`). Components are
those of :data:`WRENCH_COLUMNS`: force [N] and moment about the world origin [N·m], world
frame, applied by the ground to the robot.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from pe_drake.multibody.forward_kinematics import body_index
from pe_drake.multibody.inertia import spatial_inertia_to_phi

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: CSV columns of a measured ground wrench, in the order of the wrench rows [N, N·m].
WRENCH_COLUMNS = ("wrench.fx", "wrench.fy", "wrench.fz", "wrench.mx", "wrench.my", "wrench.mz")


def static_wrench(robot: Robot) -> np.ndarray:
    """The ground wrench that holds the bodies no excited joint moves, shape (6,) [N, N·m].

    Those bodies (pelvis, torso, legs, ... of a humanoid whose arms are excited) only weigh:
    force −m g, moment p_WScm × (−m g) about the world origin. Their parameters are not in
    φ; a constant sensor offset adds to this term and cannot be told from it.

    Args:
        robot: a :class:`~pe_drake.multibody.robot.Robot`.
    """
    plant = robot.plant
    ctx = plant.CreateDefaultContext()  # the static bodies' poses do not depend on q
    g = np.asarray(plant.gravity_field().gravity_vector(), float)
    moving = {int(b) for b in robot.body_indices}
    total = np.zeros(6)
    for k in range(1, plant.num_bodies()):
        if k in moving:
            continue
        body = plant.get_body(body_index(k))
        phi = spatial_inertia_to_phi(body.default_spatial_inertia())
        m, h_B = phi[0], phi[1:4]
        X_WB = plant.EvalBodyPoseInWorld(ctx, body)
        p_WBcm_m = m * X_WB.translation() + X_WB.rotation().matrix() @ h_B  # m p_WBcm
        f = -m * g
        total[:3] += f
        total[3:] += np.cross(p_WBcm_m, -g)
    return total


def root_weld_joint_position(robot: Robot) -> int:
    """Position of the root link's weld in ``plant.GetJointIndices()``.

    Drake's reaction-force output is indexed by that position, not by the JointIndex: they
    differ once joints were removed (every non-excited joint is replaced by a weld).
    """
    plant = robot.plant
    root = plant.GetBodyByName(robot.root_link).index()
    world = plant.world_body().index()
    for position, k in enumerate(plant.GetJointIndices()):
        joint = plant.get_joint(k)
        if joint.child_body().index() == root and joint.parent_body().index() == world:
            return position
    raise ValueError(f"no joint welds '{robot.root_link}' to the world")


def reaction_to_ground_wrench(robot: Robot, reactions) -> np.ndarray:
    """The ground wrench (:data:`WRENCH_COLUMNS` order) from Drake's reaction-force output.

    Args:
        robot: the :class:`~pe_drake.multibody.robot.Robot` whose plant produced ``reactions``.
        reactions: the value of ``plant.get_reaction_forces_output_port()``: per joint the
            spatial force F_CJc_Jc on the child body at the joint's child frame Jc, in Jc.

    Returns:
        Shape (6,): force [N] and moment about the world origin [N·m], world frame.
    """
    plant = robot.plant
    position = root_weld_joint_position(robot)
    joint = plant.get_joint(plant.GetJointIndices()[position])
    F = reactions[position]
    ctx = robot.plant_context
    X_WJc = joint.frame_on_child().CalcPoseInWorld(ctx)
    R = X_WJc.rotation().matrix()
    force = R @ np.asarray(F.translational())
    moment = R @ np.asarray(F.rotational()) + np.cross(X_WJc.translation(), force)
    return np.concatenate([force, moment])


def weld_reaction(robot: Robot, q: np.ndarray, v: np.ndarray, applied: np.ndarray, centred: bool = False) -> np.ndarray:
    """Drake's reaction at the root weld at states (q, v) under applied joint forces, (T, 6).

    Uses ``robot.plant_context`` (a simulated robot's context keeps its true inertias).

    Args:
        robot: a :class:`~pe_drake.multibody.robot.Robot`.
        q, v: each (T, n).
        applied: generalized forces applied at the joints, (T, n) [N·m or N] (held over the
            sample period that starts at each sample, as a zero-order-hold controller does).
        centred: average, at sample k, the reactions under applied[k − 1] and applied[k]
            (the acceleration jumps at t_k when the command changes; the average is the one
            centred on t_k, like the logged torque of ``simulate``).

    Returns:
        Ground wrench per sample, (T, 6), :data:`WRENCH_COLUMNS` order [N, N·m].
    """
    plant, ctx = robot.plant, robot.plant_context
    q, v, applied = (np.atleast_2d(np.asarray(x, float)) for x in (q, v, applied))
    port = plant.get_applied_generalized_force_input_port()
    reaction = plant.get_reaction_forces_output_port()
    saved = port.Eval(ctx).copy() if port.HasValue(ctx) else np.zeros(plant.num_velocities())
    out = np.empty((q.shape[0], 6))
    for t in range(q.shape[0]):
        plant.SetPositions(ctx, q[t])
        plant.SetVelocities(ctx, v[t])
        port.FixValue(ctx, applied[t])
        out[t] = reaction_to_ground_wrench(robot, reaction.Eval(ctx))
        if centred and t > 0:
            port.FixValue(ctx, applied[t - 1])
            out[t] = 0.5 * (out[t] + reaction_to_ground_wrench(robot, reaction.Eval(ctx)))
    port.FixValue(ctx, saved)
    return out


def weld_reaction_wrench(robot: Robot, q: np.ndarray, v: np.ndarray, vd: np.ndarray) -> np.ndarray:
    """Drake's reaction at the root weld while the robot moves with (q, v, vdot), (T, 6).

    The joints are driven by the inverse-dynamics torques (joint damping included), so that
    Drake's forward dynamics reproduces vdot; the reaction output of the weld is then the
    ground wrench. An independent oracle for the wrench rows. Collision geometry in contact
    adds contact forces to Drake's forward dynamics: use states where none touches.

    Args:
        robot: a :class:`~pe_drake.multibody.robot.Robot` (its own plant and context are used).
        q, v, vd: each (T, n).

    Returns:
        Ground wrench per sample, (T, 6), :data:`WRENCH_COLUMNS` order [N, N·m].
    """
    q, v, vd = (np.atleast_2d(np.asarray(x, float)) for x in (q, v, vd))
    return weld_reaction(robot, q, v, robot.inverse_dynamics(q, v, vd, include_damping=True))
