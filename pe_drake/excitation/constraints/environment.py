"""The robot's surroundings: a floor under a fixed-base arm and box obstacles.

Every checked capsule (a segment [p0, p1] swept by a sphere of radius r) keeps ``margin`` from
the floor plane n·p = h (n the unit normal: the base's z axis, so the floor is the mounting
plane) and from each box:

    floor:  n·p_e − r − h >= margin   for both segment ends e (exact: a segment's lowest point
            is an end);
    box:    min_s sd_box(p0 + s·(p1 − p0)) − r >= margin,

with sd_box the signed distance to the box (negative inside), convex in the point, so the
minimum over s ∈ [0, 1] is found by a golden-section search; by the envelope theorem its
derivative is n·∂p(s*)/∂q, n the box's outward normal at the closest point. Capsules whose
height never changes with q get no floor row; capsules welded to the world get no row at all.
As in :mod:`~pe_drake.excitation.constraints.collision`, each sample contributes one soft-min
row by default.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.exceptions import ConfigError, InfeasibleError
from pe_drake.excitation.constraints.base import SampledConstraint, SampledValues, check_postures, robot_capsules
from pe_drake.multibody.forward_kinematics import body_index
from pe_drake.multibody.regressor import shared_model
from pe_drake.multibody.spatial import cross3, rotate

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


@dataclasses.dataclass(frozen=True)
class Box:
    """An axis-aligned box obstacle in world: ``center`` (3,) [m] and full edge lengths
    ``size`` (x, y, z) [m], each > 0."""

    center: np.ndarray
    size: np.ndarray
    name: str = "box"

    @staticmethod
    def from_spec(spec, index: int = 0) -> Box:
        """A box from a config entry {center: [x, y, z], size: [sx, sy, sz]} (or an object
        with those attributes); ConfigError names the entry and the bad value."""
        get = spec.get if isinstance(spec, dict) else (lambda k, d=None: getattr(spec, k, d))
        where = f"environment.boxes[{index}]"
        values = {}
        for key in ("center", "size"):
            value = get(key)
            try:
                arr = np.asarray(value, float).reshape(-1)
            except (TypeError, ValueError):
                raise ConfigError(f"{where}.{key} must be 3 numbers [m], got {value!r}") from None
            if arr.shape != (3,) or not np.isfinite(arr).all():
                raise ConfigError(f"{where}.{key} must be 3 finite numbers [m], got {value!r}")
            values[key] = arr
        if np.any(values["size"] <= 0):
            raise ConfigError(f"{where}.size must be 3 positive edge lengths [m], got {list(values['size'])}")
        return Box(values["center"], values["size"], str(get("name", "") or f"box{index}"))


def box_signed_distance(p: np.ndarray, center: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance (...) of points p (..., 3) to an axis-aligned box (negative inside) and
    the unit outward normal ∂sd/∂p (..., 3); ``center``, ``half`` (sizes) broadcast to p [m]."""
    rel = p - center
    sign = np.where(rel >= 0, 1.0, -1.0)
    over = np.abs(rel) - half  # (..., 3)
    pos = np.maximum(over, 0.0)
    outside = np.sqrt(np.einsum("...i,...i->...", pos, pos))
    deepest = over.max(axis=-1)
    sd = np.where(outside > 0, outside, np.minimum(deepest, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        n_out = sign * pos / np.where(outside > 0, outside, 1.0)[..., None]
    face = np.argmax(over, axis=-1)
    n_in = sign * (np.arange(3) == face[..., None])
    normal = np.where((outside > 0)[..., None], n_out, n_in)
    return sd, normal


def segment_box_distance(p0: np.ndarray, p1: np.ndarray, center: np.ndarray, half: np.ndarray, iterations: int = 60):
    """min over s ∈ [0, 1] of the box signed distance of p0 + s(p1 − p0), batched: (distance,
    s*, normal at the closest point), shapes (...), (...), (..., 3)."""
    lo = np.zeros(p0.shape[:-1])
    hi = np.ones_like(lo)

    def f(s):
        return box_signed_distance(p0 + s[..., None] * (p1 - p0), center, half)[0]

    for _ in range(iterations):  # the bracket shrinks by 0.618 per step: 3e-13 after 60
        a = hi - _GOLDEN * (hi - lo)
        b = lo + _GOLDEN * (hi - lo)
        left = f(a) <= f(b)
        hi = np.where(left, b, hi)
        lo = np.where(left, lo, a)
    s = 0.5 * (lo + hi)
    # the ends may be better than the bracket's interior (minimum at a boundary)
    for end in (np.zeros_like(s), np.ones_like(s)):
        s = np.where(f(end) < f(s), end, s)
    d, normal = box_signed_distance(p0 + s[..., None] * (p1 - p0), center, half)
    return d, s, normal


class EnvironmentConstraint(SampledConstraint):
    """Capsules at least ``margin`` above the floor and outside each box, at every sample.

    Args:
        floor_height: offset h of the floor plane n·p = h in world [m], or None for no floor.
        aggregate: one soft-min row per sample (default) or one row per capsule end / box.
        floor_normal: unit normal n of the floor plane in world, pointing to the robot's side.

    Raises:
        ConfigError: no capsules, nothing to check, or bad numbers.
    """

    name = "environment"

    def __init__(
        self,
        robot: Robot,
        margin: float,
        floor_height: float | None = None,
        boxes: Sequence[Box] = (),
        *,
        aggregate: bool = True,
        smoothing: float = 0.002,
        floor_normal: Sequence[float] = (0.0, 0.0, 1.0),
    ):
        capsules = robot_capsules(robot, margin, "environment", " for the floor/box check: set robot.capsules, or "
                                  "environment: {floor: false} and no boxes")
        if floor_height is not None and not math.isfinite(floor_height):
            raise ConfigError(f"environment.floor_height must be a finite number [m], got {floor_height!r}")
        self.robot, self.margin, self.floor_height = robot, float(margin), floor_height
        normal = np.asarray(floor_normal, float).reshape(3)
        if not np.isfinite(normal).all() or np.linalg.norm(normal) < 1e-9:
            raise ConfigError(f"the floor normal must be a nonzero 3-vector, got {floor_normal!r}")
        self.floor_normal = normal / np.linalg.norm(normal)
        self.boxes = tuple(boxes)
        self.aggregate, self.smoothing = bool(aggregate), float(smoothing)
        moving = {int(b) for b in robot.body_indices}
        self.capsules = [c for c in capsules if c.body_index in moving]
        if not self.capsules:
            raise ConfigError(
                f"robot '{robot.name}': none of its {len(capsules)} collision capsule(s) is on a link the "
                "excited joints move, so nothing can be kept off the floor or the boxes: give the moving links "
                "capsules (robot.capsules) or collision geometry, or set environment: {floor: false} and no boxes")
        self._setup_bodies()
        self.floor_ends = self._floor_ends() if floor_height is not None else []
        labels = [f"{self.capsules[c].name}.{('start', 'end')[e]}/floor" for c, e in self.floor_ends]
        labels += [f"{c.name}/{b.name}" for b in self.boxes for c in self.capsules]
        if not labels:
            raise ConfigError(f"robot '{robot.name}': no capsule can reach the floor or a box; nothing to check")
        self.row_labels = labels
        if self.aggregate:
            super().__init__(["min environment clearance"], [self.margin], [np.inf])
        else:
            super().__init__(labels, np.full(len(labels), self.margin), np.full(len(labels), np.inf))

    def _setup_bodies(self) -> None:
        robot, plant = self.robot, self.robot.plant
        self._plant, self._context = plant, plant.CreateDefaultContext()
        self._bodies = sorted({c.body_index for c in self.capsules})
        self._frames = [plant.get_body(body_index(b)).body_frame() for b in self._bodies]
        self._slot = [self._bodies.index(c.body_index) for c in self.capsules]
        # Batched: capsule ends from the shared forward kinematics, Jacobians from the twists.
        model = shared_model(robot)
        self._model = model if model.batched_kinematics else None
        if self._model is not None:
            moving = [int(b) for b in robot.body_indices]
            self._capsule_slots = model.slots([c.body_index for c in self.capsules])
            self._p_BS = np.array([c.p_BS for c in self.capsules])  # (C, 2, 3)
            cols = [moving.index(c.body_index) for c in self.capsules]
            self._moves = robot.joint_moves_body[:, cols].T.astype(float)  # (C, n)

    def _floor_ends(self) -> list[tuple[int, int]]:
        """(capsule, end) pairs that get a floor row: ends whose height varies by more than the
        capsule's radius over the joint ranges (others turn in place where they are mounted)."""
        rng = np.random.default_rng(0)
        lim = self.robot.limits
        lo = np.where(np.isfinite(lim.q_lower), lim.q_lower, -np.pi)
        hi = np.where(np.isfinite(lim.q_upper), lim.q_upper, np.pi)
        q = rng.uniform(lo, hi, (64, self.robot.n))
        z = self.ends(q, jacobian=False)[0] @ self.floor_normal  # heights above the floor, (64, C, 2)
        span = z.max(axis=0) - z.min(axis=0)
        return [(c, e) for c in range(len(self.capsules)) for e in range(2) if span[c, e] > self.capsules[c].radius]

    def ends(self, q: np.ndarray, jacobian: bool):
        """p_W of every capsule's ends (K, C, 2, 3) and, with ``jacobian``, ∂p/∂q (K, C, 2, 3, n)."""
        if self._model is None:
            return self.drake_ends(q, jacobian)
        X = self._model.poses(q)
        Xc = X[:, self._capsule_slots]  # (K, C, 4, 4)
        p = rotate(Xc[:, :, None, :3, :3], self._p_BS) + Xc[:, :, None, :3, 3]
        if not jacobian:
            return p, None
        # ∂p/∂q_k = ω_k × p + m_k for the joints k that move the capsule's body.
        omega, moment = self._model.twists(q)  # (K, n, 3) each
        dp = cross3(omega[:, None, None], p[:, :, :, None]) + moment[:, None, None]  # (K, C, 2, n, 3)
        J = np.swapaxes(dp, -1, -2) * self._moves[None, :, None, None, :]
        return p, J

    def drake_ends(self, q: np.ndarray, jacobian: bool):
        """:meth:`ends` from Drake's per-sample queries (joint types the batched forward
        kinematics does not handle; also the tests' reference)."""
        from pydrake.multibody.tree import JacobianWrtVariable

        plant, ctx = self._plant, self._context
        world = plant.world_frame()
        K, C = q.shape[0], len(self.capsules)
        p = np.empty((K, C, 2, 3))
        J = np.empty((K, C, 2, 3, self.robot.n)) if jacobian else None
        for k in range(K):
            plant.SetPositions(ctx, q[k])
            for c, cap in enumerate(self.capsules):
                frame = self._frames[self._slot[c]]
                p_BS = cap.p_BS.T  # (3, 2)
                p[k, c] = plant.CalcPointsPositions(ctx, frame, p_BS, world).T
                if jacobian:
                    Jc = plant.CalcJacobianTranslationalVelocity(
                        ctx, JacobianWrtVariable.kQDot, frame, p_BS, world, world
                    )  # (6, n): the two ends' rows stacked
                    J[k, c] = Jc.reshape(2, 3, -1)
        return p, J

    def clearances(self, q: np.ndarray, derivatives: bool = False):
        """Clearance d (K, R) [m] of every row (capsule end above the floor, capsule outside a
        box) at q (K, n) or (n,), and with ``derivatives`` ∂d/∂q (K, R, n) (else None)."""
        q = check_postures(q, self.robot, "environment constraint")
        # The floor rows need only ∂z/∂q; the full Jacobian of every end is built for boxes.
        z_gradient_only = derivatives and not self.boxes and self._model is not None
        p, J = self.ends(q, derivatives and not z_gradient_only)
        radii = np.array([c.radius for c in self.capsules])
        d_rows, g_rows = [], []
        if self.floor_ends:
            cs, es = np.array(self.floor_ends).T
            nf = self.floor_normal
            d_rows.append(p[:, cs, es] @ nf - radii[cs] - self.floor_height)  # (K, F)
            if z_gradient_only:  # ∂(n·p)/∂q_k = n·(ω_k × p + m_k) = ω_k·(p × n) + m_k·n
                omega, moment = self._model.twists(q)  # (K, n, 3)
                pxn = np.cross(p[:, cs, es], nf)  # (K, F, 3)
                dz = np.einsum("kfi,kji->kfj", pxn, omega) + (moment @ nf)[:, None, :]
                g_rows.append(dz * self._moves[cs])  # (K, F, n)
            elif derivatives:
                g_rows.append(np.einsum("kfin,i->kfn", J[:, cs, es], nf))  # (K, F, n)
        for box in self.boxes:
            d, s, normal = segment_box_distance(p[:, :, 0], p[:, :, 1], box.center, 0.5 * box.size)
            d_rows.append(d - radii[None, :])
            if derivatives:
                dp = (1.0 - s)[..., None, None] * J[:, :, 0] + s[..., None, None] * J[:, :, 1]  # (K, C, 3, n)
                g_rows.append(np.einsum("kci,kcin->kcn", normal, dp))
        d = np.concatenate(d_rows, axis=1)
        return d, (np.concatenate(g_rows, axis=1) if derivatives else None)

    def evaluate(self, q: np.ndarray, v: np.ndarray, vd: np.ndarray, derivatives: bool = True) -> SampledValues:
        d, g = self.clearances(q, derivatives)
        K = d.shape[0]
        if not self.aggregate:
            return SampledValues(d, g if derivatives else np.empty((K, d.shape[1], 0)))
        h = self.smoothing
        d_min = d.min(axis=1, keepdims=True)
        w = np.exp(-(d - d_min) / h)
        total = w.sum(axis=1, keepdims=True)
        value = d_min - h * np.log(total)
        if not derivatives:
            return SampledValues(value, np.empty((K, 1, 0)))
        return SampledValues(value, np.einsum("kr,krn->kn", w / total, g)[:, None, :])

    def margins(self, q: np.ndarray, v: np.ndarray, vd: np.ndarray) -> np.ndarray:
        """Exact clearance beyond the margin: min over rows (aggregate) or per row, (K, 1|R) [m]."""
        d = self.clearances(q)[0]
        return (d.min(axis=1, keepdims=True) if self.aggregate else d) - self.margin

    def check_posture(self, q: np.ndarray) -> None:
        """Refuses a posture closer than ``margin`` to the floor or a box (InfeasibleError)."""
        d = self.clearances(q)[0]
        k, r = np.unravel_index(int(np.argmin(d)), d.shape)
        if d[k, r] < self.margin:
            raise InfeasibleError(
                f"the nominal posture puts '{self.row_labels[r]}' {d[k, r] * 1e3:.1f} mm apart, inside the "
                f"environment margin of {self.margin * 1e3:.1f} mm; choose another robot.nominal_positions, "
                "move the obstacle (environment.floor_height / boxes) or set environment: {floor: false}"
            )


def standing_plane(robot: Robot, normal: np.ndarray, mounting_plane: float, tolerance: float = 0.02) -> float:
    """Where a robot on a pedestal stands: the lowest point, along the floor normal n, of the
    capsules no excited joint moves, when the axis of one reaches more than ``tolerance`` [m]
    below the mounting plane; else ``mounting_plane``. (Baxter's root link is its torso: the
    plane through it would cut the arms' workspace in half.)
    """
    moving = {int(b) for b in robot.body_indices}
    fixed = [c for c in getattr(robot, "capsules", ()) or () if c.body_index not in moving]
    if not fixed:
        return mounting_plane
    plant = robot.plant
    context = plant.CreateDefaultContext()
    axis, surface = mounting_plane, mounting_plane  # lowest segment end, lowest surface point
    for c in fixed:
        X = plant.EvalBodyPoseInWorld(context, plant.get_body(body_index(c.body_index))).GetAsMatrix4()
        heights = (X[:3, :3] @ c.p_BS.T).T @ normal + X[:3, 3] @ normal
        axis, surface = min(axis, float(heights.min())), min(surface, float(heights.min()) - c.radius)
    # The round end of a base capsule overhangs its mounting plane by up to its radius: only
    # a segment reaching below the plane is a pedestal.
    return surface if axis < mounting_plane - tolerance else mounting_plane


def environment_from_config(robot: Robot, excitation, environment) -> EnvironmentConstraint | None:
    """The floor/box constraint a config asks for (:func:`floor_plane`), or None.

    The clearance is ``max(excitation.collision_margin, 0)``.

    Raises:
        ConfigError: a floor or boxes are asked for but the robot has no capsules.
    """
    plane = floor_plane(robot, environment)
    normal, floor = plane if plane is not None else (robot.base_pose.GetAsMatrix4()[:3, 2], None)
    boxes = [Box.from_spec(b, k) for k, b in enumerate(environment.boxes)]
    if floor is None and not boxes:
        return None
    margin = max(float(excitation.collision_margin), 0.0)
    return EnvironmentConstraint(robot, margin, floor, boxes, floor_normal=normal)


def floor_plane(robot: Robot, environment) -> tuple[np.ndarray, float] | None:
    """The floor plane n·p = h in world (unit normal n (3,), offset h [m]) that the optimizer
    checks and the playback draws, or None: no floor, or a robot on its feet (support points).

    The mounting plane: normal to the base's z axis (n = R_WB ẑ: up for an upright base, down
    for a ceiling mount), through the root link's origin p_WBo shifted along n by
    ``environment.floor_height − p_WBo,z`` (0 when null). With ``floor_height`` null, a robot
    whose fixed parts reach below that plane stands on them (:func:`standing_plane`).
    """
    if not environment.floor or getattr(robot.config, "support_points", None):
        return None
    X_WB = robot.base_pose.GetAsMatrix4()
    normal, p_WBo = X_WB[:3, 2], X_WB[:3, 3]
    offset = 0.0 if environment.floor_height is None else float(environment.floor_height) - p_WBo[2]
    floor = float(normal @ p_WBo) + offset
    if environment.floor_height is None:
        floor = min(floor, standing_plane(robot, normal, floor))
    return normal, floor
