"""Balance: the ground projection of the centre of mass stays near the support centre (Eq. 52).

The centre of mass of the a-priori model, over every body of the plant, must stay within r of the
support centre p_WSc (the centroid of ``robot.support_points`` in world) in the horizontal plane.
Per sample

    g(q) = sqrt(|e(q)|² + ε²) <= r,   e(q) = [p_WCcm(q) - p_WSc]_xy,

a distance in metres (well scaled for the solver's absolute constraint tolerance, unlike |e|²);
ε = ``smoothing`` keeps it smooth at e = 0, conservative by < ε²/(2r). ∂g/∂q = eᵀ·J_xy/g with J
the CoM Jacobian, from the batched forward kinematics and joint twists (Drake's per-sample
queries where those do not apply).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.exceptions import ConfigError, InfeasibleError, UnknownNameError
from pe_drake.excitation.constraints.base import SampledConstraint, SampledValues, check_postures
from pe_drake.multibody.regressor import shared_model
from pe_drake.multibody.spatial import cross3, rotate

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


class OutOfBalanceError(InfeasibleError):
    """The centre of mass projects too far from the support centre.

    Attributes: ``sample`` (the worst), its ``time`` [s] (None without times), the CoM's
    ``offset`` (x, y) [m] from the support centre there and its norm ``distance`` [m], the
    allowed ``radius`` [m], and ``violations``, the number of samples outside it.
    """

    def __init__(self, sample, time, offset, radius, violations):
        self.sample, self.time, self.offset = int(sample), time, np.asarray(offset, float)
        self.distance, self.radius = float(np.linalg.norm(offset)), float(radius)
        self.violations = int(violations)
        when = f"sample {sample}" + (f" (t = {time:.3f} s)" if time is not None else "")
        super().__init__(
            f"out of balance at {when}: the centre of mass is {self.distance * 1e3:.1f} mm from the "
            f"support centre (x {self.offset[0] * 1e3:+.1f} mm, y {self.offset[1] * 1e3:+.1f} mm), "
            f"beyond the balance radius of {self.radius * 1e3:.1f} mm ({violations} sample(s) "
            "violate it); start from a balanced posture (robot.nominal_positions) or increase "
            "excitation.balance_radius"
        )


def support_center(robot: Robot) -> np.ndarray:
    """p_WSc: centroid of the robot's support (contact) points in world, shape (3,) [m].

    Raises:
        ConfigError: no support points, or a support link moved by an excited joint (the
            feet must stay on the ground).
        UnknownNameError: a support link that is not a body of the plant.
    """
    points = robot.config.support_points
    if not points:
        raise ConfigError(
            f"robot '{robot.name}' has no support points: the balance constraint needs "
            "robot.support_points ({link: [[x, y, z], ...]} in the link frame [m]) in its config"
        )
    plant, ctx = robot.plant, robot.plant.CreateDefaultContext()
    all_names = list(robot.body_names_all[1:])  # [0] is the world
    p_W = []
    for link, pts in points.items():
        if link not in all_names:
            raise UnknownNameError("link", link, all_names, where="robot.support_points")
        if link in robot.body_names:
            k = robot.body_names.index(link)
            joints = [robot.joint_names[j] for j in np.flatnonzero(robot.joint_moves_body[:, k])]
            raise ConfigError(
                f"support link '{link}' is moved by the excited joint(s) {', '.join(joints)}; "
                "the balance constraint needs feet that stay on the ground"
            )
        P = np.asarray(pts, float).reshape(-1, 3)
        X = plant.EvalBodyPoseInWorld(ctx, plant.GetBodyByName(link)).GetAsMatrix4()
        p_W.append(P @ X[:3, :3].T + X[:3, 3])
    return np.vstack(p_W).mean(axis=0)


class BalanceConstraint(SampledConstraint):
    """Horizontal CoM offset from the support centre within ``radius`` (Eq. 52).

    Attributes:
        radius: r [m].
        smoothing: ε [m].
        p_WSc: support centre in world, shape (3,) [m].
    """

    name = "balance"

    def __init__(self, robot: Robot, radius: float = 0.01, *, smoothing: float = 1e-4):
        """Raises ConfigError: see :func:`support_center`; a radius/smoothing that is not a
        positive number, or radius <= smoothing."""
        for label, value in (("radius", radius), ("smoothing", smoothing)):
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ConfigError(f"balance {label} must be a positive number [m], got {value!r}")
        if radius <= smoothing:
            raise ConfigError(f"balance radius {radius} m must exceed the smoothing {smoothing} m")
        self.robot, self.radius, self.smoothing = robot, float(radius), float(smoothing)
        self.p_WSc = support_center(robot)
        self._plant = robot.plant
        self._context = robot.plant.CreateDefaultContext()  # ours: other constraints keep their caches
        self._setup_batched()
        super().__init__(["CoM distance from support centre"], [-np.inf], [self.radius])

    def _setup_batched(self) -> None:
        """Mass-weighted body CoMs for the batched forward kinematics; the bodies no excited
        joint moves contribute a constant first moment, computed once here."""
        from pydrake.multibody.tree import BodyIndex  # lazy: pydrake is heavy

        robot, plant = self.robot, self._plant
        model = shared_model(robot)
        self._model = model if model.batched_kinematics else None
        if self._model is None:
            return
        bodies = [plant.get_body(BodyIndex(b)) for b in range(1, plant.num_bodies())]
        moving = {int(b) for b in robot.body_indices}
        self._mass = sum(b.default_mass() for b in bodies)
        self._static_moment = sum(
            (b.default_mass() * plant.EvalBodyPoseInWorld(self._context, b).multiply(b.default_com())
             for b in bodies if int(b.index()) not in moving),
            np.zeros(3),
        )
        moving_bodies = [plant.get_body(BodyIndex(int(b))) for b in robot.body_indices]
        self._body_mass = np.array([b.default_mass() for b in moving_bodies])  # (nb,)
        self._body_com = np.array([b.default_com() for b in moving_bodies])  # (nb, 3) in B
        self._body_slots = model.slots(robot.body_indices)
        self._moves = robot.joint_moves_body.astype(float)  # (n, nb)
        self._moved_mass = self._moves * self._body_mass  # (n, nb): m_b where joint k moves b
        self._mass_moved = self._moves @ self._body_mass  # (n,): mass each joint moves

    def com(self, q: np.ndarray, jacobian: bool):
        """Centre of mass p_WCcm (K, 3) [m] of postures q (K, n) and, with ``jacobian``,
        ∂p_WCcm/∂q (K, 3, n) [m/rad] (else None)."""
        if self._model is None:
            return self.drake_com(q, jacobian)
        X = self._model.poses(q)  # (K, bodies, 4, 4)
        Xb = X[:, self._body_slots]
        c = rotate(Xb[..., :3, :3], self._body_com) + Xb[..., :3, 3]  # (K, nb, 3)
        p = (self._static_moment + self._body_mass @ c) / self._mass
        if not jacobian:
            return p, None
        # ∂c_b/∂q_k = ω_k × c_b + m_k for the bodies joint k moves, so the CoM's column k is
        # (ω_k × Σ_b m_b c_b + M_k m_k) / M over those bodies (M_k: their mass).
        omega, moment = self._model.twists(q)  # (K, n, 3) each
        first_moment = self._moved_mass @ c  # (K, n, 3)
        J = (cross3(omega, first_moment) + self._mass_moved[None, :, None] * moment) / self._mass
        return p, np.swapaxes(J, 1, 2)

    def drake_com(self, q: np.ndarray, jacobian: bool):
        """:meth:`com` from Drake's per-sample queries (joint types the batched forward
        kinematics does not handle; also the tests' reference)."""
        from pydrake.multibody.tree import JacobianWrtVariable

        plant, ctx = self._plant, self._context
        W = plant.world_frame()
        K = q.shape[0]
        p = np.empty((K, 3))
        J = np.empty((K, 3, q.shape[1])) if jacobian else None
        for k in range(K):
            plant.SetPositions(ctx, q[k])
            p[k] = plant.CalcCenterOfMassPositionInWorld(ctx)
            if jacobian:
                J[k] = plant.CalcJacobianCenterOfMassTranslationalVelocity(ctx, JacobianWrtVariable.kV, W, W)
        return p, J

    def com_offset(self, q: np.ndarray) -> np.ndarray:
        """Horizontal offset e (K, 2) [m] of the whole-robot CoM from the support centre at
        q (K, n) or (n,)."""
        q = check_postures(q, self.robot, "balance constraint")
        p, _ = self.com(q, jacobian=False)
        return p[:, :2] - self.p_WSc[:2]

    def evaluate(
        self, q: np.ndarray, v: np.ndarray, vd: np.ndarray, derivatives: bool = True
    ) -> SampledValues:
        """g = sqrt(|e|² + ε²) per sample (K, 1) [m] and ∂g/∂q (K, 1, n) (v, vd not used)."""
        q = check_postures(q, self.robot, "balance constraint")
        p, J = self.com(q, jacobian=derivatives)
        e = p[:, :2] - self.p_WSc[:2]
        g = np.sqrt(np.einsum("ki,ki->k", e, e) + self.smoothing**2)
        value = g[:, None]
        if not derivatives:
            return SampledValues(value=value, d_q=np.empty((q.shape[0], 1, 0)))
        d_q = (np.einsum("ki,kin->kn", e, J[:, :2]) / g[:, None])[:, None, :]
        return SampledValues(value=value, d_q=d_q)

    def margins(self, q: np.ndarray, v: np.ndarray, vd: np.ndarray) -> np.ndarray:
        """r - |e| per sample, shape (K, 1) [m]; < 0 is a violation."""
        return self.radius - np.linalg.norm(self.com_offset(q), axis=1, keepdims=True)

    def check_posture(self, q: np.ndarray, t: np.ndarray | None = None) -> None:
        """Refuses postures q (n,) or (K, n) whose CoM projects farther than ``radius`` from the
        support centre; ``t`` (K,) [s] for the message.

        Raises:
            OutOfBalanceError: with the worst sample (and time) and its offset in mm.
        """
        e = self.com_offset(q)
        dist = np.linalg.norm(e, axis=1)
        bad = dist > self.radius
        if not bad.any():
            return
        k = int(np.argmax(dist))
        time = None if t is None else float(np.asarray(t, float).reshape(-1)[k])
        raise OutOfBalanceError(k, time, e[k], self.radius, int(bad.sum()))

