"""The joint-torque regressor Y(q, v, vdot) (Eq. 1) and its analytic derivative (Eqs. 45–47).

τ = Y(q, v, vdot) φ, with φ the 10 inertial parameters of every body moved by an excited joint
(order of :data:`pe_drake.multibody.robot.PARAMETER_NAMES`, bodies in ``Robot.body_names``),
gravity included. From the body poses X_WB at each sample, everything is batched numpy over the
samples in world-origin coordinates, where every derivative with respect to q_l is a spatial
cross product with S_l: the forward pass and its adjoint are derived in docs/derivations.md.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.multibody.forward_kinematics import ForwardKinematics, body_index
from pe_drake.multibody.spatial import (
    cross3,
    cross_force,
    cross_force_matrix,
    cross_motion,
    force_transform_matrix,
    inertia_times,
    inertia_times_diagonal,
    rotate,
    summed_cross_force_of,
)

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Rows of the ground-wrench regressor, in the order of a spatial force [n; f] (Drake's):
#: fx, fy, fz, mx, my, mz (the CSV order) are its entries 3, 4, 5, 0, 1, 2. A swap of the
#: halves, so the permutation is its own inverse.
WRENCH_FROM_SPATIAL = np.array([3, 4, 5, 0, 1, 2])


@dataclasses.dataclass
class Kinematics:
    """Kinematic quantities of one batch of samples (world coordinates at the world origin).

    Attributes:
        v, vd: joint velocities and accelerations, (T, n).
        S: joint motion axes S_i, (T, n, 6).
        VJ, AJ: spatial velocity and acceleration (gravity as a base acceleration) of each
            joint's child body, (T, n, 6).
        VB, AB: the same per body in body coordinates at Bo, (T, nb, 6).
        F_B: per-body regressor blocks in body coordinates, (T, nb, 6, 10): F = Γ(A) + V ×* Γ(V).
        F_W: the same in world coordinates at the world origin, (T, nb, 6, 10).
        G_V: Γ(V), the unit-parameter inertias times V, (T, nb, 6, 10).
        X_force: per-body force transforms X* (body at Bo → world at the origin), (T, nb, 6, 6);
            their transposes take world-origin motion vectors to the body.
        VB_cross: [VB ×*], the force cross-product matrix of each body's velocity, (T, nb, 6, 6).
        X_motion: X*ᵀ (world-origin motion vectors to each body), contiguous, (T, nb, 6, 6).
    """

    v: np.ndarray
    vd: np.ndarray
    S: np.ndarray
    VJ: np.ndarray
    AJ: np.ndarray
    VB: np.ndarray
    AB: np.ndarray
    F_B: np.ndarray
    F_W: np.ndarray
    G_V: np.ndarray
    X_force: np.ndarray
    VB_cross: np.ndarray
    X_motion: np.ndarray


class RegressorModel:
    """Batched regressor of a :class:`~pe_drake.multibody.robot.Robot` and its adjoint.

    Args:
        batched: use the batched forward kinematics where the joint types allow (False:
            Drake's per-sample queries, e.g. as a reference in tests).
        keep_last_poses: keep the last :meth:`poses` and :meth:`twists` (see
            :func:`shared_model`).
    """

    def __init__(self, robot: Robot, *, batched: bool = True, keep_last_poses: bool = False):
        self.robot = robot
        self.n = robot.n
        self.nb = robot.num_bodies
        self.num_params = 10 * self.nb
        self.moves = robot.joint_moves_body.astype(float)  # (n, nb): joint i moves body j
        self.strict_anc = robot.joint_strict_ancestors.astype(float)  # (n, n): l before i
        self.anc_incl = self.strict_anc + np.eye(self.n)
        self.joint_of_body = robot.joint_of_body
        # owner[i, j] = 1 if body j is rigidly attached to joint i's child body.
        self.owner = np.zeros((self.n, self.nb))
        self.owner[self.joint_of_body, np.arange(self.nb)] = 1.0
        self._mask = np.repeat(self.moves, 10, axis=1)  # (n, 10·nb)
        self.prismatic = np.array([j.kind == "prismatic" for j in robot.joints])
        self._any_prismatic = bool(self.prismatic.any())
        self.axis_M = np.array([j.axis_M for j in robot.joints])  # (n, 3)
        self.X_CM = np.array([j.X_CM for j in robot.joints])  # (n, 4, 4)
        self._joint_child = [j.child_body for j in robot.joints]
        plant = robot.plant
        self._bodies_needed = sorted(set(self._joint_child) | set(int(b) for b in robot.body_indices))
        self._slot = {b: k for k, b in enumerate(self._bodies_needed)}
        self._body_objs = [plant.get_body(body_index(b)) for b in self._bodies_needed]
        g = np.asarray(plant.gravity_field().gravity_vector())
        self.A0 = np.concatenate([np.zeros(3), -g])  # base acceleration = -gravity

        self._fk = ForwardKinematics.build(robot, self._bodies_needed) if batched else None
        self._keep = keep_last_poses
        self._poses_key: tuple | None = None
        self._poses: np.ndarray | None = None
        self._joint_child_slots = [self._slot[int(b)] for b in self._joint_child]
        self._twists_key: tuple | None = None
        self._twists: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def batched_kinematics(self) -> bool:
        """True when :meth:`poses` uses the batched forward kinematics (every joint type of
        the robot handled), False when it falls back to Drake's per-sample queries."""
        return self._fk is not None

    def poses(self, q: np.ndarray) -> np.ndarray:
        """X_WB of the needed bodies, (T, len(bodies_needed), 4, 4).

        Batched over samples (Drake's per-sample queries for joint types the batched forward
        kinematics does not handle, or with ``batched=False``). With ``keep_last_poses`` the
        last result is kept and returned read-only (:func:`shared_model`).
        """
        if not self._keep:
            return self._fk(q) if self._fk is not None else self.drake_poses(q)
        key = (q.shape, q.tobytes())
        if key != self._poses_key:
            self._poses = self._fk(q) if self._fk is not None else self.drake_poses(q)
            self._poses.setflags(write=False)  # shared by the constraints: read only
            self._poses_key = key
        return self._poses

    def slots(self, bodies) -> list[int]:
        """Positions of the given body indices in the output of :meth:`poses`."""
        return [self._slot[int(b)] for b in bodies]

    def joint_twists(self, X_WC: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World axis ω and moment m = o × ω of each excited joint, each (K, n, 3), from the
        poses X_WC (K, n, 4, 4) of the joints' child bodies.

        A point c moved by joint k has ∂c/∂q_k = ω_k × c + m_k (a prismatic joint: ω = 0,
        m = its axis).
        """
        X_WM = X_WC @ self.X_CM  # (K, n, 4, 4)
        axis_W = rotate(X_WM[:, :, :3, :3], self.axis_M)
        o_W = X_WM[:, :, :3, 3]
        omega = np.where(self.prismatic[None, :, None], 0.0, axis_W)
        moment = np.where(self.prismatic[None, :, None], axis_W, cross3(o_W, axis_W))
        return omega, moment

    def twists(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`joint_twists` at postures q (K, n), from :meth:`poses`; kept (read-only)
        with the poses when the model keeps them."""
        X = self.poses(q)
        if not self._keep:
            return self.joint_twists(X[:, self._joint_child_slots])
        if self._twists_key != self._poses_key:
            self._twists = self.joint_twists(X[:, self._joint_child_slots])
            for array in self._twists:
                array.setflags(write=False)
            self._twists_key = self._poses_key
        return self._twists

    def drake_poses(self, q: np.ndarray) -> np.ndarray:
        """X_WB of the needed bodies, (T, len(bodies_needed), 4, 4), from Drake."""
        plant, ctx = self.robot.plant, self.robot.plant_context
        out = np.empty((q.shape[0], len(self._body_objs), 4, 4))
        for t in range(q.shape[0]):
            plant.SetPositions(ctx, q[t])
            for k, body in enumerate(self._body_objs):
                out[t, k] = plant.EvalBodyPoseInWorld(ctx, body).GetAsMatrix4()
        return out

    def kinematics(self, q: np.ndarray, v: np.ndarray, vd: np.ndarray) -> Kinematics:
        """Everything the regressor and its derivative need, for T samples q, v, vd, each (T, n)."""
        q, v, vd = (np.atleast_2d(np.asarray(x, float)) for x in (q, v, vd))
        X = self.poses(q)
        # Joint frames M in world: X_WM = X_WC X_CM.
        X_WM = X[:, self._joint_child_slots] @ self.X_CM
        u = (X_WM[..., :3, :3] @ self.axis_M[..., None])[..., 0]  # axis in world
        o = X_WM[..., :3, 3]
        S = np.concatenate([u, cross3(o, u)], axis=-1)
        if self._any_prismatic:
            S = np.where(self.prismatic[None, :, None], np.concatenate([np.zeros_like(u), u], axis=-1), S)
        Xb = X[:, [self._slot[int(b)] for b in self.robot.body_indices]]
        R, p = Xb[..., :3, :3], Xb[..., :3, 3]

        # Velocity of each joint's child body: VJ_i = Σ_{k ≤ i} S_k v_k.
        Sv = S * v[..., None]
        VJ = self.anc_incl.T @ Sv
        # Acceleration: AJ_i = A0 + Σ_{k ≤ i} (S_k vd_k + v_k VJ_k ×m S_k).
        dA = S * vd[..., None] + cross_motion(VJ, Sv)
        AJ = self.A0 + self.anc_incl.T @ dA

        # Motion vectors to the body are X*ᵀ; V and A of each body in one batched matmul, as
        # rows (vᵀ X* = (X*ᵀ v)ᵀ). Row forms with contiguous operands throughout: numpy's
        # batched matmul of transposed views took twice as long (issue 38).
        X_force = force_transform_matrix(R, p)
        X_motion = np.ascontiguousarray(X_force.swapaxes(-1, -2))  # X*ᵀ
        VAB = np.stack([VJ, AJ], -2)[:, self.joint_of_body] @ X_force
        VB, AB = VAB[..., 0, :], VAB[..., 1, :]
        G_V = inertia_times(VB)  # M_k V for each unit parameter k, (T, nb, 6, 10)
        # One 6 × 6 matrix per body applied to its 10 parameter columns (a batched matmul is
        # several times faster than the vector formulas on (T, nb, 10, 6) arrays).
        VB_cross = cross_force_matrix(VB)
        F_B = inertia_times(AB) + VB_cross @ G_V
        # F_W = X* F_B, computed as its transpose F_Bᵀ X*ᵀ: the (10, 6) layout is the one the
        # regressor (Y = S·F) and its adjoint read as a (10·nb, 6) matrix without a copy.
        F_W = (F_B.swapaxes(-1, -2) @ X_motion).swapaxes(-1, -2)
        return Kinematics(v, vd, S, VJ, AJ, VB, AB, F_B, F_W, G_V, X_force, VB_cross, X_motion)

    def regressor(self, kin: Kinematics, columns: np.ndarray | None = None) -> np.ndarray:
        """Y, shape (T, n, 10·nb): Y[t, i, 10j+k] = [joint i moves body j] S_i · F_jk; with
        ``columns`` (e.g. the base parameters' independent ones) only Y[..., columns]."""
        F, mask = _forces_by_parameter(kin), self._mask
        if columns is not None:
            F, mask = F[:, columns], mask[:, columns]
        # (F_Wᵀ Sᵀ)ᵀ: F_W is stored as its transpose (see kinematics), so no copy of it.
        return (F @ kin.S.swapaxes(-1, -2)).swapaxes(-1, -2) * mask

    def wrench_regressor(self, kin: Kinematics, columns: np.ndarray | None = None) -> np.ndarray:
        """Ground-wrench rows Y_0, shape (T, 6, 10·nb) (``columns`` as in :meth:`regressor`).

        Y_0[t, :, 10j:10j+10] is body j's world-frame force block F_j (moment about the world
        origin), rows fx, fy, fz, mx, my, mz. Y_0 φ is the wrench the ground (the weld of the root
        link) applies to the moving bodies, gravity included; the bodies no excited joint moves
        add a constant (:func:`pe_drake.multibody.wrench.static_wrench`).
        """
        T = kin.F_W.shape[0]
        F = kin.F_W[:, :, WRENCH_FROM_SPATIAL, :]  # (T, nb, 6, 10)
        Y_0 = F.transpose(0, 2, 1, 3).reshape(T, 6, self.num_params)
        return Y_0 if columns is None else Y_0[..., columns]

    def __call__(self, q: np.ndarray, v: np.ndarray, vd: np.ndarray) -> np.ndarray:
        """Y(q, v, vdot), shape (T, n, 10·nb)."""
        return self.regressor(self.kinematics(q, v, vd))

    def columns(self, q: np.ndarray, v: np.ndarray, vd: np.ndarray, columns, chunk: int = 2000,
                out: np.ndarray | None = None) -> np.ndarray:
        """Y(q, v, vdot)[..., columns], shape (T, n, len(columns)), ``chunk`` samples at a time
        (the kinematics hold tens of kB per sample), into ``out`` when given."""
        columns = np.asarray(columns)
        if out is None:
            out = np.empty((q.shape[0], q.shape[1] if q.ndim > 1 else 1, columns.size))
        for s in range(0, q.shape[0], chunk):
            k = slice(s, min(s + chunk, q.shape[0]))
            out[k] = self(q[k], v[k], vd[k])[..., columns]
        return out

    def pullback(
        self, kin: Kinematics, Z: np.ndarray | None, Z_wrench: np.ndarray | None = None,
        columns: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Gradient of f = Σ_t Z^(t) : Y^(t) + Z_0^(t) : Y_0^(t) with respect to q, v and vdot (Eq. 47).

        Args:
            Z: weights of the joint-torque rows, shape (T, n, 10·nb) (Eq. 46), or None.
            Z_wrench: weights of the ground-wrench rows (:meth:`wrench_regressor`), shape
                (T, 6, 10·nb), or None.
            columns: Z and Z_wrench hold only these columns (last axis len(columns)); the
                other weights are zero (the base parameters' columns: Eq. 46's Z is zero
                outside them, so neither the full Z nor its products are formed).

        Returns:
            (∂f/∂q, ∂f/∂v, ∂f/∂vdot), each (T, n).
        """
        T, n, nb = kin.S.shape[0], self.n, self.nb
        S = kin.S

        # f = Σ_j Σ_k w_jk · F_jk, with w_jk = Σ_i [i moves j] Z_ijk S_i (a motion vector).
        if Z is not None:
            F, mask = _forces_by_parameter(kin), self._mask
            if columns is not None:
                F, mask = F[:, columns], mask[:, columns]
            Zm = Z.reshape(T, n, -1) * mask
            w = Zm.transpose(0, 2, 1) @ S
            if columns is not None:
                w = _scattered(w, columns, self.num_params, axis=1)
            w = w.reshape(T, nb, 10, 6)
            S_bar = Zm @ F  # ∂f/∂S_i through w
        else:
            w, S_bar = np.zeros((T, nb, 10, 6)), np.zeros((T, n, 6))
        if Z_wrench is not None:
            if columns is not None:
                Z_wrench = _scattered(Z_wrench, columns, self.num_params, axis=2)
            # The wrench rows weigh F_jk directly: w_jk is the row weights, in [n; f] order.
            w = w + Z_wrench.reshape(T, 6, nb, 10).transpose(0, 2, 3, 1)[..., WRENCH_FROM_SPATIAL]
        return self._pullback_forces(kin, w, S_bar)

    def _pullback_forces(
        self, kin: Kinematics, w: np.ndarray, S_bar: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Gradient of f = Σ_jk w_jk · F_jk (+ the part already in S_bar) with respect to q, v, vdot.

        Args:
            w: weights of the world-frame force blocks, (T, nb, 10, 6) (motion vectors).
            S_bar: ∂f/∂S_i collected so far, (T, n, 6).
        """
        S, v, vd, VJ = kin.S, kin.v, kin.vd, kin.VJ

        # Body-coordinate adjoints of A_j and V_j (F = Γ(A)φ + V ×* Γ(V)φ, φ = e_k).
        # The adjoint of "motion to the body" (X*ᵀ) is X* itself.
        # Row-vector forms (w X* = (X*ᵀ wᵀ)ᵀ) keep every operand contiguous: no copies.
        wB = w @ kin.X_force  # (T, nb, 10, 6)
        a_bar_B = inertia_times_diagonal(wB)
        wB_x_V = wB @ kin.VB_cross  # w ×m V = -[V ×m] w, as rows: w (-[V ×m])ᵀ = w [V ×*]
        # Σ_k w_k ×* (M_k V) and Σ_k w_k ×* F_k from the 6 × 6 products Γ(V) wB and F_B wB.
        v_bar_B = inertia_times_diagonal(wB_x_V) - summed_cross_force_of(kin.G_V @ wB)
        # Rotating body j with joint l leaves f invariant if w, V, A and M all rotate: the
        # derivative through M is minus that through w, V and A (docs/derivations.md, §4).
        Q_B = (
            summed_cross_force_of(kin.F_B @ wB)
            + cross_force(kin.VB, v_bar_B)
            + cross_force(kin.AB, a_bar_B)
        )
        # The three body forces to world coordinates in one batched matmul.
        world = np.stack([a_bar_B, v_bar_B, Q_B], -2) @ kin.X_motion  # rows: fᵀ X*ᵀ = (X* f)ᵀ
        a_bar, v_bar_body, Q = world[..., 0, :], world[..., 1, :], world[..., 2, :]
        q_bar = -np.sum(S * (self.moves @ Q), axis=-1)

        # Bodies → the joint whose child body carries them.
        AJ_bar = self.owner @ a_bar
        VJ_bar = self.owner @ v_bar_body

        # AJ_i = A0 + Σ_{k ≤ i} (S_k vd_k + v_k VJ_k ×m S_k)
        c_bar = self.anc_incl @ AJ_bar
        vd_bar = np.sum(S * c_bar, axis=-1)
        v_bar = np.sum(cross_motion(VJ, S) * c_bar, axis=-1)
        S_bar += vd[..., None] * c_bar - v[..., None] * cross_force(VJ, c_bar)
        VJ_bar += v[..., None] * cross_force(S, c_bar)

        # VJ_i = Σ_{k ≤ i} S_k v_k
        VJ_agg = self.anc_incl @ VJ_bar
        v_bar += np.sum(S * VJ_agg, axis=-1)
        S_bar += v[..., None] * VJ_agg

        # S_i(q): ∂S_i/∂q_l = S_l ×m S_i for l strictly before i.
        q_bar += np.sum(S * (self.strict_anc @ cross_force(S, S_bar)), axis=-1)
        return q_bar, v_bar, vd_bar


def _scattered(x: np.ndarray, columns: np.ndarray, size: int, axis: int) -> np.ndarray:
    """x, given at ``columns`` of ``axis``, as an array with ``size`` entries there (zeros
    elsewhere)."""
    shape = list(x.shape)
    shape[axis] = size
    out = np.zeros(shape)
    index = [slice(None)] * x.ndim
    index[axis] = columns
    out[tuple(index)] = x
    return out


def _forces_by_parameter(kin: Kinematics) -> np.ndarray:
    """F_W as (T, 10·nb, 6): row 10j + k is body j's force for unit parameter k (a view when
    F_W is the transposed view :meth:`RegressorModel.kinematics` returns)."""
    T, nb = kin.F_W.shape[:2]
    return kin.F_W.swapaxes(-1, -2).reshape(T, 10 * nb, 6)


def shared_model(robot: Robot) -> RegressorModel:
    """One :class:`RegressorModel` per robot that keeps its last poses, so the sampled
    constraints (balance, collision, environment) evaluating the same postures run the forward
    kinematics once. Stored as ``robot.shared_kinematics`` (set that attribute before building
    the constraints to use another model, e.g. one with ``batched=False``)."""
    model = getattr(robot, "shared_kinematics", None)
    if model is None:
        model = robot.shared_kinematics = RegressorModel(robot, keep_last_poses=True)
    return model
