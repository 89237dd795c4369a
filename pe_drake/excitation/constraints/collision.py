"""Self-collision avoidance between capsules (paper, Eq. 53).

Every capsule pair left after filtering (:func:`pe_drake.multibody.capsules.capsule_pairs`) keeps
at least ``margin`` between its surfaces at every sample:

    d_ij(q) = d_line(p_Li^(s), p_Li^(e), p_Lj^(s), p_Lj^(e)) - r_i - r_j >= margin.

Distances are exact segment-segment distances (Drake's capsule distance is accurate to ~2e-6 m
only, which shows in finite differences). With the closest points c_i, c_j and the unit normal
n = (c_i - c_j)/|c_i - c_j|, the envelope theorem gives, for an excited joint k with world axis
ω_k through o_k (Plücker moment m_k = o_k × ω_k; for a prismatic joint ω_k = 0, m_k its axis),

    ∂d_ij/∂q_k = [k moves i]·(ω_k·(c_i × n) + n·m_k) - [k moves j]·(ω_k·(c_j × n) + n·m_k).

By default each sample contributes ONE row, a smooth lower bound of the minimum pair distance
(soft-min, ``h`` = ``smoothing``):

    g(q) = -h·log Σ_ij exp(-d_ij(q)/h) <= min_ij d_ij(q),   g(q) >= margin,

so g >= margin implies every pair is ``margin`` apart, at most h·log P conservative; it keeps
K dense rows instead of K·P and stays C¹ when the closest pair changes. ``aggregate=False``
gives the exact per-pair rows.

Pruning: a pair whose soft-min weight exp(-(d_ij - d_min)/h) is below e^-30 changes nothing at
double precision. Bounding spheres (segment midpoints m, fixed half-lengths l, radii r) bound

    |m_i - m_j| - l_i - l_j - r_i - r_j  <=  d_ij  <=  |m_i - m_j| - r_i - r_j,

so a pair whose lower bound exceeds its sample's smallest upper bound by 30·h is dropped there
before any segment distance is computed. The exact minimum (:meth:`CollisionConstraint.margins`)
uses the same bounds with no slack.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.exceptions import ConfigError, InfeasibleError
from pe_drake.excitation.constraints.base import SampledConstraint, SampledValues, check_postures, robot_capsules
from pe_drake.multibody.capsules import capsule_pairs, segment_closest_points
from pe_drake.multibody.regressor import shared_model
from pe_drake.multibody.spatial import cross3, rotate

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Pairs farther than this many smoothing lengths h beyond the closest pair of their sample
#: are left out of the soft-min: their weight exp(-(d - d_min)/h) is below e^-30 ≈ 1e-13.
PRUNE_SMOOTHINGS = 30.0


def _closest_points(a: np.ndarray, b: np.ndarray):
    """Closest points c_a, c_b of segments a and b (ends on axis -2: shape (..., 2, 3)), their
    difference c_a − c_b and its length (the distance between the capsules' axes)."""
    s, t = segment_closest_points(a[..., 0, :], a[..., 1, :], b[..., 0, :], b[..., 1, :])
    c_a = a[..., 0, :] + s[..., None] * (a[..., 1, :] - a[..., 0, :])
    c_b = b[..., 0, :] + t[..., None] * (b[..., 1, :] - b[..., 0, :])
    diff = c_a - c_b
    return c_a, c_b, diff, np.sqrt(np.einsum("...i,...i->...", diff, diff))


class PostureInCollisionError(InfeasibleError):
    """Two capsules are closer than the collision margin.

    Attributes: the two capsule names ``pair``, the worst ``sample`` and its ``time`` [s] (None
    without times), their ``distance`` there [m] (negative: penetration), the required
    ``margin`` [m], and ``violations``, the number of samples closer than it.
    """

    def __init__(self, pair, sample, time, distance, margin, violations):
        self.pair, self.sample, self.time = tuple(pair), int(sample), time
        self.distance, self.margin = float(distance), float(margin)
        self.violations = int(violations)
        when = f"sample {sample}" + (f" (t = {time:.3f} s)" if time is not None else "")
        state = "penetrate by" if distance < 0 else "are"
        amount = f"{abs(distance) * 1e3:.1f} mm" + ("" if distance < 0 else " apart")
        super().__init__(
            f"capsules '{pair[0]}' and '{pair[1]}' {state} {amount} at {when}, "
            f"{(margin - distance) * 1e3:.1f} mm inside the collision margin of {margin * 1e3:.1f} mm "
            f"({violations} sample(s) violate it); move the posture away from the contact or "
            "reduce excitation.collision_margin"
        )


class CollisionConstraint(SampledConstraint):
    """Capsule pairs at least ``margin`` apart at every sample (Eq. 53).

    Attributes:
        pairs: index pairs (i, j) into ``robot.capsules`` that are checked.
        pair_names: their names, "capsule_i/capsule_j".
        margin: required distance between capsule surfaces [m].
        aggregate: one soft-min row per sample (True) or one row per pair (False).
        smoothing: soft-min length scale h [m].
    """

    name = "collision"

    def __init__(self, robot: Robot, margin: float, *, aggregate: bool = True, smoothing: float = 0.002):
        """Raises ConfigError: no capsules, no pair left to check, or a bad margin/smoothing."""
        capsules = robot_capsules(robot, margin, "collision", ": set robot.capsules to a capsule file in its config "
                                  "(format: pe_drake/multibody/capsules.py)")
        if aggregate and (not math.isfinite(smoothing) or smoothing <= 0):
            raise ConfigError(f"collision smoothing must be a positive number [m], got {smoothing!r}")
        self.robot, self.capsules, self.margin = robot, capsules, float(margin)
        self.aggregate, self.smoothing = bool(aggregate), float(smoothing)
        self.pairs = capsule_pairs(robot.scene_graph, capsules)
        if not self.pairs:
            raise ConfigError(
                f"robot '{robot.name}': every capsule pair is filtered (welded, adjacent or ignored); "
                "nothing to check"
            )
        self.pair_names = [f"{capsules[a].name}/{capsules[b].name}" for a, b in self.pairs]
        self._setup()
        if self.aggregate:
            super().__init__(["min capsule distance"], [self.margin], [np.inf])
        else:
            P = len(self.pairs)
            super().__init__(self.pair_names, np.full(P, self.margin), np.full(P, np.inf))

    def _setup(self) -> None:
        from pydrake.multibody.tree import BodyIndex

        robot = self.robot
        plant = robot.plant
        self._plant = plant
        self._context = plant.CreateDefaultContext()  # ours: other constraints keep their caches
        moving_bodies = [int(b) for b in robot.body_indices]
        joint_bodies = [j.child_body for j in robot.joints]
        poses = plant.get_body_poses_output_port().Eval(self._context)  # once, at set-up

        # Each moving capsule is re-expressed in the child body H of the nearest excited joint
        # upstream (welded to its own body B), so a sample needs the n joint bodies' poses
        # only. Static capsules (welded to the world) get their world ends once and for all.
        C = len(self.capsules)
        moves = np.zeros((C, robot.n), bool)  # moves[c, k]: joint k moves capsule c
        host = np.full(C, -1)
        p_HS = np.zeros((C, 2, 3))
        for c, cap in enumerate(self.capsules):
            X_WB = poses[cap.body_index].GetAsMatrix4()
            if cap.body_index in moving_bodies:
                col = moving_bodies.index(cap.body_index)
                moves[c] = robot.joint_moves_body[:, col]
                host[c] = robot.joint_of_body[col]
                X_HB = np.linalg.solve(poses[joint_bodies[host[c]]].GetAsMatrix4(), X_WB)
            else:
                X_HB = X_WB  # H = world
            p_HS[c] = cap.p_BS @ X_HB[:3, :3].T + X_HB[:3, 3]
        self._host, self._p_HS = host, p_HS
        self._moving_caps = np.flatnonzero(host >= 0)
        self._static_caps = np.flatnonzero(host < 0)
        self._joint_bodies = joint_bodies
        self._joint_body_index = [BodyIndex(b) for b in joint_bodies]
        # Poses of all samples at once from the regressor's batched forward kinematics
        # (~10× faster than Drake's per-sample queries), when it handles the robot.
        self._kinematics = shared_model(robot)
        self._joint_slots = self._kinematics.slots(joint_bodies)
        self._host_joints = sorted(set(host[self._moving_caps].tolist()))
        pa = np.array([a for a, _ in self.pairs])
        pb = np.array([b for _, b in self.pairs])
        self._pa, self._pb = pa, pb
        self._radii = np.array([self.capsules[a].radius + self.capsules[b].radius for a, b in self.pairs])
        half = np.array([0.5 * np.linalg.norm(c.p_BS[1] - c.p_BS[0]) for c in self.capsules])
        self._half_length_sum = half[pa] + half[pb]  # l_i + l_j of the bounding spheres
        self._mask_a = moves[pa].astype(float)  # (P, n)
        self._mask_b = moves[pb].astype(float)

    def _joint_body_poses(self, q: np.ndarray, all_joints: bool) -> np.ndarray:
        """X_WH (K, n, 4, 4) of the joints' child bodies; with ``all_joints`` False only those
        hosting capsules are filled (per-body reads: cheaper than copying every body's pose)."""
        if self._kinematics.batched_kinematics:
            return self._kinematics.poses(q)[:, self._joint_slots]
        plant, ctx = self._plant, self._context
        K = q.shape[0]
        which = range(len(self._joint_bodies)) if all_joints else self._host_joints
        bodies = [(i, plant.get_body(self._joint_body_index[i])) for i in which]
        X = np.zeros((K, len(self._joint_bodies), 4, 4))
        for k in range(K):
            plant.SetPositions(ctx, q[k])
            for i, body in bodies:
                X[k, i] = plant.EvalBodyPoseInWorld(ctx, body).GetAsMatrix4()
        return X

    def _capsule_ends(self, X_WH: np.ndarray) -> np.ndarray:
        """p_WS of every capsule's segment ends, shape (K, C, 2, 3) [m]."""
        K = X_WH.shape[0]
        p_WS = np.empty((K, len(self.capsules), 2, 3))
        p_WS[:, self._static_caps] = self._p_HS[self._static_caps]
        m = self._moving_caps
        X = X_WH[:, self._host[m]]  # (K, Cm, 4, 4)
        p_WS[:, m] = rotate(X[:, :, None, :3, :3], self._p_HS[m]) + X[:, :, None, :3, 3]
        return p_WS

    def _pair_geometry(self, q: np.ndarray, joints: bool):
        X_WH = self._joint_body_poses(q, all_joints=joints)
        p_WS = self._capsule_ends(X_WH)
        c_a, c_b, diff, centre_distance = _closest_points(p_WS[:, self._pa], p_WS[:, self._pb])  # (K, P, ...)
        return centre_distance - self._radii, c_a, c_b, diff, centre_distance, X_WH

    def _near_pair_geometry(self, q: np.ndarray, tolerance: float, joints: bool):
        """Exact distances of the pair-samples that may lie within ``tolerance`` of their
        sample's closest pair (the bounding-sphere test of the module docstring).

        Returns:
            k, p: sample and pair of each kept entry (sorted by sample; every sample keeps
            at least the pair with its smallest upper bound); starts: the first entry of
            each sample; then d, c_a, c_b, diff, centre_distance per entry as in
            :meth:`_pair_geometry`; and X_WH, the joint bodies' poses.
        """
        X_WH = self._joint_body_poses(q, all_joints=joints)
        p_WS = self._capsule_ends(X_WH)
        mid = 0.5 * (p_WS[:, :, 0] + p_WS[:, :, 1])  # (K, C, 3)
        gap = mid[:, self._pa] - mid[:, self._pb]
        upper = np.sqrt(np.einsum("kpi,kpi->kp", gap, gap)) - self._radii  # >= d (K, P)
        lower = upper - self._half_length_sum  # <= d
        k, p = np.nonzero(lower <= upper.min(axis=1, keepdims=True) + tolerance)
        c_a, c_b, diff, centre_distance = _closest_points(p_WS[k, self._pa[p]], p_WS[k, self._pb[p]])  # (M, ...)
        starts = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
        return k, p, starts, centre_distance - self._radii[p], c_a, c_b, diff, centre_distance, X_WH

    def _twists_and_normals(self, q, X_WH, diff, centre_distance):
        """The joints' world axes and moments (K, n, 3) and the pairs' unit normals c_a − c_b."""
        if self._kinematics.batched_kinematics:  # shared with balance and the floor rows
            omega, moment = self._kinematics.twists(q)
        else:
            omega, moment = self._kinematics.joint_twists(X_WH)
        length = centre_distance[..., None]
        with np.errstate(invalid="ignore", divide="ignore"):
            normal = np.where(length > 1e-12, diff / length, 0.0)
        return omega, moment, normal

    def _soft_min(self, q: np.ndarray, derivatives: bool) -> SampledValues:
        """The aggregate row over the pairs kept by the bounding-sphere test."""
        K = q.shape[0]
        if K == 0:
            return SampledValues(value=np.empty((0, 1)), d_q=np.empty((0, 1, q.shape[1] if derivatives else 0)))
        h = self.smoothing
        k, p, starts, d, c_a, c_b, diff, centre_distance, X_WH = self._near_pair_geometry(
            q, PRUNE_SMOOTHINGS * h, derivatives
        )
        d_min = np.minimum.reduceat(d, starts)  # (K,)
        w = np.exp(-(d - d_min[k]) / h)
        total = np.add.reduceat(w, starts)
        value = (d_min - h * np.log(total))[:, None]  # (K, 1)
        if not derivatives:
            return SampledValues(value=value, d_q=np.empty((K, 1, 0)))
        omega, moment, normal = self._twists_and_normals(q, X_WH, diff, centre_distance)
        # Σ_p w_p ∂d_p/∂q_j = ω_j·A_j + m_j·B_j per sample: the weighted vectors go back to
        # their (sample, pair) places (zero where pruned), then one product per sample
        # contracts over the pairs.
        weight = (w / total[k])[:, None]
        P = len(self.pairs)
        wn, wca, wcb = np.zeros((3, K, P, 3))
        wn[k, p] = weight * normal
        wca[k, p] = weight * cross3(c_a, normal)
        wcb[k, p] = weight * cross3(c_b, normal)
        A = np.swapaxes(wca, 1, 2) @ self._mask_a - np.swapaxes(wcb, 1, 2) @ self._mask_b  # (K, 3, n)
        B = np.swapaxes(wn, 1, 2) @ (self._mask_a - self._mask_b)
        d_q = (omega * np.swapaxes(A, 1, 2)).sum(axis=2) + (moment * np.swapaxes(B, 1, 2)).sum(axis=2)
        return SampledValues(value=value, d_q=d_q[:, None, :])

    def distances(self, q: np.ndarray) -> np.ndarray:
        """Exact distance between the surfaces of each checked pair at q (K, n) or (n,): shape
        (K, P) [m], negative when the capsules overlap; columns follow ``pairs``."""
        q = check_postures(q, self.robot, "collision constraint")
        return self._pair_geometry(q, joints=False)[0]

    def evaluate(
        self, q: np.ndarray, v: np.ndarray, vd: np.ndarray, derivatives: bool = True
    ) -> SampledValues:
        """Soft-min distance per sample (K, 1), or every pair distance (K, P) [m], and ∂/∂q
        (v, vd are not used)."""
        q = check_postures(q, self.robot, "collision constraint")
        if self.aggregate:
            return self._soft_min(q, derivatives)
        K, n = q.shape
        d, c_a, c_b, diff, centre_distance, X_WH = self._pair_geometry(q, joints=derivatives)
        if not derivatives:
            return SampledValues(value=d, d_q=np.empty((K, d.shape[1], 0)))
        omega, moment, normal = self._twists_and_normals(q, X_WH, diff, centre_distance)
        # ∂d/∂q_k = mask_a·(ω_k·(c_a × n) + n·m_k) - mask_b·(ω_k·(c_b × n) + n·m_k)
        ca_n, cb_n = cross3(c_a, normal), cross3(c_b, normal)  # (K, P, 3)
        mask_a, mask_b = self._mask_a, self._mask_b  # (P, n)
        omega_T = np.swapaxes(omega, 1, 2)  # (K, 3, n)
        n_dot_m = normal @ np.swapaxes(moment, 1, 2)  # (K, P, n)
        d_q = (ca_n @ omega_T + n_dot_m) * mask_a - (cb_n @ omega_T + n_dot_m) * mask_b
        return SampledValues(value=d, d_q=d_q)

    def margins(self, q: np.ndarray, v: np.ndarray, vd: np.ndarray) -> np.ndarray:
        """Exact clearance beyond the margin, min over pairs (K, 1) (aggregate) or per pair
        (K, P) [m]; < 0 is a violation."""
        if not self.aggregate:
            return self.distances(q) - self.margin
        q = check_postures(q, self.robot, "collision constraint")
        if q.shape[0] == 0:
            return np.empty((0, 1))
        _, _, starts, d = self._near_pair_geometry(q, 0.0, False)[:4]  # exact minimum
        return np.minimum.reduceat(d, starts)[:, None] - self.margin

    def check_posture(self, q: np.ndarray, t: np.ndarray | None = None) -> None:
        """Refuses postures q (n,) or (K, n) where a pair is closer than ``margin``; ``t`` (K,)
        [s] for the message.

        Raises:
            PostureInCollisionError: naming the worst pair, its sample (and time) and distance.
        """
        d = self.distances(q)
        bad = d < self.margin
        if not bad.any():
            return
        k, p = np.unravel_index(np.argmin(d), d.shape)
        a, b = self.pairs[p]
        time = None if t is None else float(np.asarray(t, float).reshape(-1)[k])
        pair = (self.capsules[a].name, self.capsules[b].name)
        violations = int(bad.any(axis=1).sum())
        raise PostureInCollisionError(pair, k, time, d[k, p], self.margin, violations)

