"""Capsule models of a robot for self-collision avoidance (paper, Eq. 53).

The robot's shape is approximated by capsules (a segment swept by a sphere), so that the
distance between two bodies is the distance between two segments minus the two radii. A
capsule file (YAML) lists the capsules fixed to links and the pairs never to check::

    capsules:
      - name: left_hand              # unique; used in reports and in ignored_pairs
        link: left_rubber_hand       # the body the capsule is fixed to
        radius: 0.053                # [m]
        length: 0.142                # [m], between the centres of the two end spheres
        xyz: [0.044, -0.022, 0.008]  # [m], centre of the capsule in the link frame
        rpy: [0.0, 1.5708, 0.0]      # [rad], capsule frame G in the link frame B
    ignored_pairs:                   # capsule names, or link names (all its capsules)
      - [left_forearm, left_hand]

As in Drake's ``Capsule``, the axis of a capsule is the z axis of its frame G and the capsule
is centred on G's origin. :func:`register_capsules` registers them as Drake collision geometry
and filters the pairs that never change distance or touch by design; SceneGraph then holds the
pairs to check (:func:`capsule_pairs`).
"""

# No `from __future__ import annotations`: yaml_load_typed reads the dataclass field types.
import dataclasses
import itertools
import math
from pathlib import Path

import numpy as np

from pe_drake.yaml_check import load_yaml_typed
from pe_drake.exceptions import ConfigError, UnknownNameError


@dataclasses.dataclass
class CapsuleSpec:
    """One capsule of a capsule file (the YAML schema; see the module docstring).

    ``name`` defaults to the link name (``<link>_<i>`` for a second capsule); ``length`` is
    between the centres of the end spheres [m]; the capsule axis is the z axis of ``rpy``.
    """

    name: str = ""
    link: str = ""
    radius: float = 0.0
    length: float = 0.0
    xyz: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    rpy: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])


@dataclasses.dataclass
class CapsuleFile:
    """A capsule file: the capsules and the pairs (capsule or link names) never checked.

    ``collision_margin`` [m] is the margin the file was made for, used when the config sets none.
    """

    capsules: list[CapsuleSpec] = dataclasses.field(default_factory=list)
    ignored_pairs: list[list[str]] = dataclasses.field(default_factory=list)
    collision_margin: float | None = None


@dataclasses.dataclass(frozen=True)
class CapsuleInfo:
    """A capsule registered in a plant, fixed to body B."""

    name: str
    link: str  # B's name
    body_index: int  # B's Drake ``BodyIndex``
    radius: float  # [m]
    length: float  # [m]
    X_BG: np.ndarray  # pose of the capsule frame G in B, (4, 4) [m]
    p_BS: np.ndarray  # the segment's ends p_L^(s), p_L^(e) of Eq. 53 in B, (2, 3) [m]
    geometry_id: object  # Drake ``GeometryId`` of the collision geometry


def load_capsule_file(path: str | Path) -> CapsuleFile:
    """Reads a capsule file and checks its numbers and names (links are checked later).

    Raises:
        ConfigError: missing file, unknown key, a radius or length that is not a positive
            finite number, a pose that is not 3 finite numbers, a duplicate name, or an
            ignored pair that is not two names. The message names the file and the capsule.
    """
    path = Path(path)
    data = load_yaml_typed(path, CapsuleFile, what="capsule")
    if not data.capsules:
        raise ConfigError(f"capsule file '{path}' lists no capsules")

    per_link: dict[str, int] = {}
    for k, spec in enumerate(data.capsules):
        if not spec.link:
            raise ConfigError(f"capsule file '{path}': capsule #{k} ('{spec.name}') has no link")
        if not spec.name:
            count = per_link.get(spec.link, 0)
            spec.name = spec.link if count == 0 else f"{spec.link}_{count}"
        per_link[spec.link] = per_link.get(spec.link, 0) + 1
        where = f"capsule file '{path}': capsule '{spec.name}' (link '{spec.link}')"
        for field in ("radius", "length"):
            value = getattr(spec, field)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ConfigError(f"{where}: {field} must be a positive finite number [m], got {value!r}")
        for field in ("xyz", "rpy"):
            value = getattr(spec, field)
            if len(value) != 3 or not all(math.isfinite(v) for v in value):
                raise ConfigError(f"{where}: {field} must be 3 finite numbers, got {value!r}")
    names = [c.name for c in data.capsules]
    for name in names:
        if names.count(name) > 1:
            raise ConfigError(
                f"capsule file '{path}': capsule name '{name}' is used {names.count(name)} times")
    margin = data.collision_margin
    if margin is not None and (isinstance(margin, bool) or not isinstance(margin, (int, float))
                               or not math.isfinite(margin) or margin < 0):
        raise ConfigError(f"capsule file '{path}': collision_margin must be a finite number >= 0 [m], got {margin!r}")
    for pair in data.ignored_pairs:
        if len(pair) != 2 or pair[0] == pair[1]:
            raise ConfigError(
                f"capsule file '{path}': ignored_pairs entry {pair!r} must be two different names")
    return data


def register_capsules(plant, scene_graph, path: str | Path) -> tuple[CapsuleInfo, ...]:
    """Registers a capsule file's capsules as collision geometry and filters pairs.

    Call before ``plant.Finalize()``. Excluded from checking: capsules on bodies welded together,
    capsules on bodies joined by one joint (adjacent), and the file's ``ignored_pairs``.

    Raises:
        ConfigError: see :func:`load_capsule_file`; or a plant without a SceneGraph, or a
            finalized plant.
        UnknownNameError: a capsule's link, or an ignored-pair name, that does not exist.
    """
    from pydrake.geometry import Capsule, CollisionFilterDeclaration, GeometrySet
    from pydrake.math import RigidTransform, RollPitchYaw
    from pydrake.multibody.plant import CoulombFriction
    from pydrake.multibody.tree import BodyIndex

    data = load_capsule_file(path)
    if plant.is_finalized():
        raise ConfigError("register_capsules must be called before plant.Finalize()")
    if not plant.geometry_source_is_registered():
        raise ConfigError("the plant has no SceneGraph: build it with AddMultibodyPlantSceneGraph")

    bodies = [plant.get_body(BodyIndex(b)) for b in range(1, plant.num_bodies())]
    by_name = {}
    for body in bodies:
        by_name.setdefault(body.name(), body)
    infos = []
    for spec in data.capsules:
        if spec.link not in by_name:
            where = f"capsule '{spec.name}' of '{path}'"
            raise UnknownNameError("link", spec.link, sorted(by_name), where=where)
        body = by_name[spec.link]
        X_BG = RigidTransform(RollPitchYaw(spec.rpy), np.asarray(spec.xyz, float))
        geometry_id = plant.RegisterCollisionGeometry(
            body, X_BG, Capsule(spec.radius, spec.length), f"capsule::{spec.name}", CoulombFriction(0.5, 0.5)
        )
        X = X_BG.GetAsMatrix4()
        half = 0.5 * spec.length * X[:3, 2]
        p_BS = np.array([X[:3, 3] - half, X[:3, 3] + half])
        infos.append(CapsuleInfo(spec.name, spec.link, int(body.index()), float(spec.radius),
                                 float(spec.length), X, p_BS, geometry_id))

    ignored = _resolve_ignored_pairs(data, infos, path)
    group = _welded_groups(plant)
    adjacent = _adjacent_groups(plant, group)
    manager = scene_graph.collision_filter_manager()
    for a, b in itertools.combinations(range(len(infos)), 2):
        ga, gb = group[infos[a].body_index], group[infos[b].body_index]
        if ga == gb or frozenset((ga, gb)) in adjacent or frozenset((a, b)) in ignored:
            manager.Apply(CollisionFilterDeclaration().ExcludeBetween(
                GeometrySet(infos[a].geometry_id), GeometrySet(infos[b].geometry_id)))
    return tuple(infos)


def capsule_pairs(scene_graph, capsules: tuple[CapsuleInfo, ...]) -> tuple[tuple[int, int], ...]:
    """The capsule pairs SceneGraph checks (not filtered), as index pairs (i < j)."""
    inspector = scene_graph.model_inspector()
    return tuple(
        (a, b)
        for a, b in itertools.combinations(range(len(capsules)), 2)
        if not inspector.CollisionFiltered(capsules[a].geometry_id, capsules[b].geometry_id))


def _resolve_ignored_pairs(data: CapsuleFile, infos: list[CapsuleInfo], path) -> set[frozenset[int]]:
    """ignored_pairs entries → index pairs; a name means a capsule or every capsule of a link."""
    members: dict[str, set[int]] = {}
    for k, c in enumerate(infos):
        members.setdefault(c.name, set()).add(k)
        members.setdefault(c.link, set()).add(k)
    out: set[frozenset[int]] = set()
    for pair in data.ignored_pairs:
        for name in pair:
            if name not in members:
                raise UnknownNameError("capsule", name, sorted(members),
                                       where=f"ignored_pairs of '{path}' (capsule or link names)")
        out.update(frozenset((a, b)) for a in members[pair[0]] for b in members[pair[1]] if a != b)
    return out


def _welded_groups(plant) -> dict[int, int]:
    """{body index: index of its welded group}; the group of the world is 0."""
    from pydrake.multibody.tree import BodyIndex

    group: dict[int, int] = {}
    for b in range(plant.num_bodies()):
        if b in group:
            continue
        g = len(set(group.values()))
        for body in plant.GetBodiesWeldedTo(plant.get_body(BodyIndex(b))):
            group[int(body.index())] = g
        group[b] = g
    return group


def _adjacent_groups(plant, group: dict[int, int]) -> set[frozenset[int]]:
    """Pairs of welded groups connected by a joint that moves."""
    out = set()
    for j in plant.GetJointIndices():
        joint = plant.get_joint(j)
        if joint.num_velocities() > 0:
            parent, child = int(joint.parent_body().index()), int(joint.child_body().index())
            out.add(frozenset((group[parent], group[child])))
    return out


def segment_closest_points(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray,
                           b1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest points of segments [a0, a1] and [b0, b1] (..., 3), batched over leading axes.

    The points are ``a0 + s·(a1 - a0)`` and ``b0 + t·(b1 - b0)`` (Ericson, *Real-Time
    Collision Detection*, 5.1.9). Both segments must have a positive length (capsules do);
    for parallel segments one of the closest pairs is returned. s, t in [0, 1], shape (...).
    """
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0
    a = np.maximum(np.einsum("...i,...i->...", d1, d1), 1e-300)
    e = np.maximum(np.einsum("...i,...i->...", d2, d2), 1e-300)
    b = np.einsum("...i,...i->...", d1, d2)
    c = np.einsum("...i,...i->...", d1, r)
    f = np.einsum("...i,...i->...", d2, r)
    denom = a * e - b * b  # >= 0; ~0 for parallel segments
    general = denom > 1e-12 * a * e
    s = np.where(general, np.clip((b * f - c * e) / np.where(general, denom, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e
    s = np.where(t < 0.0, np.clip(-c / a, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a, 0.0, 1.0), s))
    return s, np.clip(t, 0.0, 1.0)


def fit_capsule(points: np.ndarray, axis: np.ndarray | None = None, cover: float = 0.98,
                through: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """A capsule around a point cloud (N, 3) [m], e.g. a link mesh's vertices in the link frame.

    The axis is ``axis`` or the principal axis of the points; the axis line passes through
    ``through`` or the centre that minimises the radius; the radius covers the fraction
    ``cover`` of the points; the segment is the shortest that contains every covered point.
    Returns (p0, p1, radius) [m].
    """
    from scipy.optimize import minimize

    P = np.asarray(points, float)
    centre = P.mean(axis=0)
    if axis is None:
        axis = np.linalg.svd(P - centre, full_matrices=False)[2][0]
    u = np.asarray(axis, float) / np.linalg.norm(axis)
    e1 = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    Q = (P - centre) @ np.c_[e1, e2]

    def radius(c):
        return np.quantile(np.linalg.norm(Q - c, axis=1), cover)

    if through is not None:
        c = (np.asarray(through, float) - centre) @ np.c_[e1, e2]
    else:
        c0 = 0.5 * (np.quantile(Q, 0.01, axis=0) + np.quantile(Q, 0.99, axis=0))
        c = minimize(radius, c0, method="Nelder-Mead", options={"xatol": 1e-5, "fatol": 1e-7}).x
    origin = centre + c[0] * e1 + c[1] * e2
    r = float(radius(c))
    t = (P - origin) @ u
    d = np.linalg.norm(Q - c, axis=1)
    inside = d <= r
    h = np.sqrt(np.maximum(r * r - d[inside] ** 2, 0.0))
    lo, hi = np.min(t[inside] + h), np.max(t[inside] - h)
    if hi < lo:
        lo = hi = 0.5 * (lo + hi)
    return origin + lo * u, origin + hi * u, r


def capsule_pose(p0: np.ndarray, p1: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """xyz [m], rpy [rad] (zero yaw) and length [m] of the capsule whose segment is [p0, p1]."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    d = p1 - p0
    length = float(np.linalg.norm(d))
    u = d / length if length > 0 else np.array([0.0, 0.0, 1.0])
    # R = Ry(pitch)·Rx(roll) maps z to (cos(roll)·sin(pitch), -sin(roll), cos(roll)·cos(pitch)).
    roll = -math.asin(max(-1.0, min(1.0, u[1])))
    pitch = math.atan2(u[0], u[2])
    return 0.5 * (p0 + p1), np.array([roll, pitch, 0.0]), length


def joints_apart(plant, bodies) -> np.ndarray:
    """How many moving joints separate each pair of ``bodies`` (body indices), shape (B, B).

    Bodies welded together count as one; no path gives the body count."""
    group = _welded_groups(plant)
    neighbours: dict[int, set[int]] = {}
    for pair in _adjacent_groups(plant, group):
        a, b = tuple(pair) if len(pair) == 2 else (next(iter(pair)),) * 2
        neighbours.setdefault(a, set()).add(b)
        neighbours.setdefault(b, set()).add(a)
    far = plant.num_bodies()
    groups = [group[int(b)] for b in bodies]
    hops = {}
    for g in set(groups):  # breadth-first from each group
        seen, frontier, k = {g: 0}, [g], 0
        while frontier:
            k += 1
            frontier = sorted({n for f in frontier for n in neighbours.get(f, ()) if n not in seen})
            seen.update({n: k for n in frontier})
        hops[g] = seen
    return np.array([[hops[ga].get(gb, far) for gb in groups] for ga in groups], int)
