"""World poses of chosen bodies for T configurations at once (:class:`ForwardKinematics`): the
batched kinematics the regressor starts from, numpy over the samples where Drake would be called
once per sample."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from pe_drake.multibody.spatial import skew

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


class ForwardKinematics:
    """World poses of chosen bodies for T configurations at once.

    Each joint gives X_PC(q) = X_PF · X_FM(q) · X_MC (Drake's joint frames F on the parent, M on
    the child); bodies without an excited joint on their path from the world have a constant pose.
    """

    def __init__(self, steps, outputs):
        #: per moving step: (parent: ("const", X_WP) or ("var", step), X_PF, kind, axis, q index, X_MC)
        self.steps = steps
        #: per requested body: ("const", X_WB) or ("var", step)
        self.outputs = outputs
        # Every step's local pose X_PF · X_FM(q) · X_MC is computed for all steps at once:
        # X_FM = [R(θ) p; 0 1] with R = c I + s [a]× + (1 − c) a aᵀ (Rodrigues; θ = 0 for
        # welds and prismatic joints) and p = d a (d = 0 for welds and revolute joints).
        axes = np.array([a if a is not None else np.zeros(3) for _, _, _, a, _, _ in steps]).reshape(-1, 3)
        kinds = [k for _, _, k, _, _, _ in steps]
        self._revolute = np.array([k == "revolute" for k in kinds])
        self._prismatic = np.array([k == "prismatic" for k in kinds])
        self._q_index = np.array([max(iq, 0) for _, _, _, _, iq, _ in steps], dtype=int)
        # X_FM is linear in (1, c, s, d): E0 + c·E1 + s·E2 + d·E3, so the local pose is
        # L0 + c·L1 + s·L2 + d·L3 with L_i = X_PF · E_i · X_MC computed once.
        ns = len(steps)
        E = np.zeros((4, ns, 4, 4))
        outer = axes[:, :, None] * axes[:, None, :]
        E[0, :, :3, :3] = outer
        E[0, :, 3, 3] = 1.0
        E[1, :, :3, :3] = np.eye(3) - outer
        E[2, :, :3, :3] = skew(axes)
        E[3, :, :3, 3] = axes
        X_PF = np.array([X_PF for _, X_PF, _, _, _, _ in steps]).reshape(-1, 4, 4)
        X_MC = np.array([X_MC for _, _, _, _, _, X_MC in steps]).reshape(-1, 4, 4)
        self._L = X_PF @ E @ X_MC  # (4, ns, 4, 4)
        self._var_outputs = [k for k, (kind, _) in enumerate(outputs) if kind == "var"]
        self._var_steps = [value for kind, value in outputs if kind == "var"]
        self._outputs_are_steps = len(outputs) == ns and all(
            kind == "var" and value == k for k, (kind, value) in enumerate(outputs))

    @staticmethod
    def build(robot: Robot, bodies):
        from pydrake.multibody.tree import ModelInstanceIndex, PrismaticJoint, RevoluteJoint, WeldJoint

        plant = robot.plant
        child_joint = {}
        for m in range(plant.num_model_instances()):
            for k in plant.GetJointIndices(ModelInstanceIndex(m)):  # skips removed joints
                joint = plant.get_joint(k)
                child_joint[int(joint.child_body().index())] = joint
        steps, memo = [], {}

        def visit(b: int):
            """('const', X_WB) or ('var', slot) of body b."""
            if b in memo:
                return memo[b]
            joint = child_joint.get(b)
            if joint is None:  # the world (or a free body: not in our fixed-base robots)
                if b != 0:
                    raise NotImplementedError
                memo[b] = ("const", np.eye(4))
                return memo[b]
            parent = visit(int(joint.parent_body().index()))
            X_PF = joint.frame_on_parent().GetFixedPoseInBodyFrame().GetAsMatrix4()
            X_MC = joint.frame_on_child().GetFixedPoseInBodyFrame().inverse().GetAsMatrix4()
            if isinstance(joint, WeldJoint):
                X = X_PF @ joint.X_FM().GetAsMatrix4() @ X_MC
                if parent[0] == "const":
                    memo[b] = ("const", parent[1] @ X)
                else:
                    steps.append((parent, X, "weld", None, -1, np.eye(4)))
                    memo[b] = ("var", len(steps) - 1)
                return memo[b]
            if isinstance(joint, RevoluteJoint):
                kind, axis = "revolute", np.asarray(joint.revolute_axis(), float)
            elif isinstance(joint, PrismaticJoint):
                kind, axis = "prismatic", np.asarray(joint.translation_axis(), float)
            else:
                raise NotImplementedError
            steps.append((parent, X_PF, kind, axis / np.linalg.norm(axis), joint.position_start(), X_MC))
            memo[b] = ("var", len(steps) - 1)
            return memo[b]

        try:
            outputs = [visit(int(b)) for b in bodies]
        except NotImplementedError:
            return None
        return ForwardKinematics(steps, outputs)

    def __call__(self, q: np.ndarray) -> np.ndarray:
        T, ns = q.shape[0], len(self.steps)
        angle = np.where(self._revolute, q[:, self._q_index], 0.0)[..., None, None]  # (T, ns, 1, 1)
        shift = np.where(self._prismatic, q[:, self._q_index], 0.0)[..., None, None]
        L0, L1, L2, L3 = self._L
        local = L0 + np.cos(angle) * L1
        local += np.sin(angle) * L2
        local += shift * L3  # (T, ns, 4, 4)
        X = np.empty((T, ns, 4, 4))
        for k, ((kind, parent), *_rest) in enumerate(self.steps):
            X_WP = parent if kind == "const" else X[:, parent]  # a fixed pose, or an earlier step's
            np.matmul(X_WP, local[:, k], out=X[:, k])
        if self._outputs_are_steps:
            return X
        out = np.empty((T, len(self.outputs), 4, 4))
        for k, (kind, value) in enumerate(self.outputs):
            if kind == "const":
                out[:, k] = value
        out[:, self._var_outputs] = X[:, self._var_steps]
        return out


def body_index(b: int):
    """Drake's ``BodyIndex`` of the integer ``b``."""
    from pydrake.multibody.tree import BodyIndex

    return BodyIndex(int(b))
