"""The ground wrench of a robot whose root link is welded to the world.

The weld of a standing humanoid's pelvis stands for the feet on the ground; the wrench it
transmits is what foot force/torque sensors measure: w = Y_0(q, v, v̇) φ + w_static
(docs/derivations.md §4a). Components are those of :data:`WRENCH_COLUMNS`: force [N] and moment
about the world origin [N·m], world frame, applied by the ground to the robot.
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

    Those bodies only weigh; a constant sensor offset adds to this term and cannot be told from it.
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

    Drake's reaction-force output is indexed by that position, not by the JointIndex.
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
    """The ground wrench (:data:`WRENCH_COLUMNS` order, shape (6,)) from ``reactions``, the value
    of ``plant.get_reaction_forces_output_port()`` (per joint F_CJc_Jc on the child body)."""
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


def weld_reaction(robot: Robot, q: np.ndarray, v: np.ndarray, applied: np.ndarray,
                  centred: bool = False) -> np.ndarray:
    """Drake's reaction at the root weld at states (q, v) (T, n) under applied forces: the ground
    wrench per sample, (T, 6) in :data:`WRENCH_COLUMNS` order [N, N·m].

    Uses ``robot.plant_context`` (a simulated robot's context keeps its true inertias).

    Args:
        applied: generalized forces applied at the joints, (T, n) [N·m or N], held over the
            sample period that starts at each sample.
        centred: average, at sample k, the reactions under applied[k − 1] and applied[k]
            (centred on t_k, like the logged torque of ``simulate``).
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
    """Drake's reaction at the root weld while the robot moves with (q, v, v̇), (T, 6).

    The joints are driven by the inverse-dynamics torques, so Drake's forward dynamics
    reproduces v̇: an independent oracle for the wrench rows. Use states without contact.
    """
    q, v, vd = (np.atleast_2d(np.asarray(x, float)) for x in (q, v, vd))
    return weld_reaction(robot, q, v, robot.inverse_dynamics(q, v, vd, include_damping=True))
