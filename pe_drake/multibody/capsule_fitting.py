"""Capsule files fitted automatically to a URDF's or SDF's link shapes (for robots that ship none).

Each link gets capsules from its ``<collision>`` shapes, else its ``<visual>`` ones: one exact
capsule per primitive (at most :data:`MAX_PRIMITIVE_CAPSULES`), else one capsule fitted to the
pooled mesh vertices (:func:`~pe_drake.multibody.capsules.fit_capsule`), mirror-symmetric for a
mirror-symmetric link. A shape that cannot be read is listed in
:attr:`FittedCapsules.unchecked`: that part of the robot is not checked for collisions.
"""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np

from pe_drake.exceptions import ConfigError, DataError
from pe_drake.io_utils import atomic_write_text
from pe_drake.multibody.capsules import (capsule_pairs, capsule_pose, fit_capsule, joints_apart,
                                         load_capsule_file, segment_closest_points)
from pe_drake.multibody.link_geometry import Shape, primitive_points, primitive_segment, read_link_shapes
from pe_drake.multibody.collada_up_axis import oriented_vertices, up_axis_note
from pe_drake.multibody.mesh_policy import mesh_file_refusal
from pe_drake.multibody.meshes import resolve_mesh_path
from pe_drake.multibody.model_files import loadable_model_path
from pe_drake.multibody.robot import Robot

#: Name of the fitted capsule file written to a command's output folder.
FITTED_CAPSULES_NAME = "fitted_capsules.yaml"
#: How a fitted capsule file starts.
FITTED_HEADER = "# Capsules fitted automatically by pe_drake"
#: Self-collision margin used with fitted capsules when the config sets none [m].
FITTED_COLLISION_MARGIN = 0.01
#: A link with at most this many primitive shapes (and no mesh) gets one capsule per shape.
MAX_PRIMITIVE_CAPSULES = 3
#: A link's points are mirror-symmetric when 90 % of the mirrored points lie within this fraction
#: of the cloud's size of a point.
SYMMETRY_TOLERANCE = 0.03
#: Pairs at most this many joints apart may touch by design (a link and its grandparent: an
#: elbow's upper arm and wrist); pairs farther apart are always checked (issue 21).
TOUCHING_JOINTS = 2
#: A capsule is shrunk to clear a farther pair at the nominal posture down to this fraction of
#: its fitted radius, no further.
SHRINK_FLOOR = 0.5


class CapsuleFittingError(ConfigError):
    """No link of a model has a shape capsules can be fitted to (``unchecked`` says why)."""

    def __init__(self, message: str, unchecked: tuple[str, ...]):
        self.unchecked = tuple(unchecked)
        super().__init__(message)


@dataclasses.dataclass(frozen=True)
class FittedCapsules:
    """What :func:`fit_capsule_file` wrote; ``unchecked`` is what is not checked for collisions."""

    path: Path
    links: tuple[str, ...]  # links that got a capsule
    ignored_pairs: tuple = ()  # (capsule, capsule, reason) not checked although not adjacent
    unchecked: tuple[str, ...] = ()  # one line each: "link X: mesh Y could not be read: reason"
    sources: dict[str, str] = dataclasses.field(default_factory=dict)  # "primitive", "mesh", both
    # {capsule: (fitted, used radius)} [m]: made thinner to keep farther links checked
    shrunk: dict[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    notes: tuple[str, ...] = ()  # how the meshes were read, when not as written

    def summary(self, first: int = 3) -> str:
        """A one-line account: capsule count and sources, then the unchecked parts."""
        kinds = sorted(set(self.sources.values()))
        text = f"{len(self.links)} link(s) with capsules (from {', '.join(kinds) or 'nothing'})"
        if self.unchecked:
            shown = "; ".join(self.unchecked[:first])
            more = f"; ... {len(self.unchecked) - first} more" if len(self.unchecked) > first else ""
            text += f"; {len(self.unchecked)} part(s) NOT checked: {shown}{more} (full list: report.json 'unchecked')"
        return "; ".join([text, *self.notes])

    def pairs_summary(self, first: int = 4) -> str:
        """The ignored pairs (the first few) and the shrunk capsules; "" when there are none."""
        parts = []
        if self.ignored_pairs:
            shown = ", ".join(f"{a}/{b}" for a, b, _ in self.ignored_pairs[:first])
            more = f", ... {len(self.ignored_pairs) - first} more" if len(self.ignored_pairs) > first else ""
            parts.append(f"{len(self.ignored_pairs)} pair(s) touching by design ignored: {shown}{more} "
                         "(full list: report.json 'ignored_pairs')")
        if self.shrunk:
            parts.append(f"{len(self.shrunk)} capsule(s) shrunk to keep links more than {TOUCHING_JOINTS} joints "
                         "apart checked: " + ", ".join(f"{n} {a:.3f} -> {b:.3f} m" for n, (a, b) in self.shrunk.items()))
        return "; ".join(parts)

    def ignored_records(self) -> list[dict]:
        """The ignored pairs for ``report.json``: [{"pair": [a, b], "reason": ...}]."""
        return [{"pair": [a, b], "reason": why} for a, b, why in self.ignored_pairs]


def _mesh_points(shape: Shape, model_path: Path) -> np.ndarray:
    """A mesh shape's vertices in the link frame; DataError for a missing or unreadable file."""
    path = resolve_mesh_path(shape.filename, model_path, mesh=False)
    if path is None:
        raise DataError("file not found")
    refusal = mesh_file_refusal(path)  # an oversize file or a pipe: said so, not "not found"
    if refusal is not None:
        raise DataError(refusal)
    v = oriented_vertices(path, model_path) * shape.scale  # a COLLADA mesh as the model means it
    return v @ shape.X_LG[:3, :3].T + shape.X_LG[:3, 3]


@dataclasses.dataclass
class _LinkFit:
    """The capsules of one link: segments (p0, p1, radius, comment), source, problems."""

    capsules: list = dataclasses.field(default_factory=list)
    source: str = ""
    problems: list = dataclasses.field(default_factory=list)  # shapes of the used group, not read
    replaced: list = dataclasses.field(default_factory=list)  # collision shapes not read


def _fit_link(shapes: list[Shape], model_path: Path, cover: float) -> _LinkFit:
    """Capsules from a link's collision shapes, else from its visual ones."""
    fit = _LinkFit()
    for tag in ("collision", "visual"):
        group = [s for s in shapes if s.tag == tag]
        primitives = [s for s in group if s.kind != "mesh"]
        meshes, problems = [], []
        for s in (s for s in group if s.kind == "mesh"):
            try:
                meshes.append((s, _mesh_points(s, model_path)))
            except DataError as err:
                reason = str(err).split("': ", 1)[-1] if str(err).startswith("file '") else str(err)
                problems.append(f"{tag} {s.describe()} could not be read: {reason}")
        if not meshes and not primitives:
            fit.replaced += problems
            continue
        fit.problems = problems
        if not meshes and len(primitives) <= MAX_PRIMITIVE_CAPSULES:
            for s in primitives:
                p0, p1, r = primitive_segment(s)
                fit.capsules.append((p0, p1, r, f"{tag} {s.describe()}: encloses it"))
            fit.source = "primitive"
            break
        P = np.vstack([p for _, p in meshes] + [primitive_points(s) for s in primitives])
        if len(P) < 4:
            fit.replaced += problems + [f"{tag} shapes have fewer than 4 vertices"]
            continue
        # primitive surface points are extremes, not a sampled surface: cover them all
        p0, p1, r = _fit_points(P, cover=cover if meshes else 1.0)
        worst = max(_radial_distance(P, p0, p1).max() - r, 0.0)
        names = ", ".join(Path(s.filename).name if s.kind == "mesh" else s.describe() for s in group)
        fit.capsules.append((p0, p1, r, f"{tag} {names}: worst vertex {worst * 1e3:.0f} mm out"))
        fit.source = "mesh" if not primitives else ("primitive" if not meshes else "primitive+mesh")
        break
    return fit


def fit_capsule_file(model_path: str | Path, out_path: str | Path, links: list[str] | None = None,
                     cover: float = 0.98) -> FittedCapsules:
    """Fits capsules to the links of a URDF or SDF and writes a capsule file.

    Args:
        out_path: the capsule file to write (YAML, format of :mod:`pe_drake.multibody.capsules`).
        links: only these links (default: every link with a shape).
        cover: fraction of each mesh's vertices inside its capsule.

    Raises:
        ConfigError: not a URDF/SDF, or unreadable XML.
        CapsuleFittingError: no link has a usable shape (its ``unchecked`` says why).
    """
    model_path = Path(model_path)
    shapes = read_link_shapes(model_path)
    lines = [
        f"{FITTED_HEADER} to the links of {model_path.name}: a primitive",
        "# collision shape (cylinder, sphere, box, capsule) gives the capsule enclosing it; meshes give",
        "# one capsule per link along the principal axis of the collision (else visual) mesh vertices,",
        f"# radius covering {cover:.0%} of them, mirror-symmetric for a mirror-symmetric link",
        "# (pe_drake.multibody.capsule_fitting).",
        "# Check them in `pe-drake view` and edit as needed; give the edited file as robot.capsules.",
        "capsules:",
    ]
    fitted, unchecked, sources = [], [], {}
    for name, link_shapes in shapes.items():
        if (links is not None and name not in links) or not link_shapes:
            continue
        fit = _fit_link(link_shapes, model_path, cover)
        if not fit.capsules:
            why = "; ".join(fit.replaced + fit.problems) or "no usable shape"
            unchecked.append(f"link {name}: {why}")
            continue
        if fit.problems:  # a shape of the group the capsules came from: that part is unchecked
            unchecked.append(f"link {name}: " + "; ".join(fit.problems) + " (capsule fitted to its other shapes)")
        if fit.replaced:
            lines.append(f"  # {name}: " + "; ".join(fit.replaced) + "; its visual shapes used instead")
        for k, (p0, p1, r, comment) in enumerate(fit.capsules):
            xyz, rpy, length = capsule_pose(p0, p1)
            length = max(length, 1e-3)  # a sphere: Drake needs a positive length
            cap = name if k == 0 else f"{name}_{k}"
            lines += [f"  # {comment}",
                      f"  - {{name: {cap}, link: {name}, radius: {r:.4f}, length: {length:.4f},\n"
                      f"     xyz: [{xyz[0]:.4f}, {xyz[1]:.4f}, {xyz[2]:.4f}], "
                      f"rpy: [{rpy[0]:.4f}, {rpy[1]:.4f}, {rpy[2]:.4f}]}}"]
        fitted.append(name)
        sources[name] = fit.source
    if not fitted:
        first = "; ".join(unchecked[:3]) + (f"; ... {len(unchecked) - 3} more" if len(unchecked) > 3 else "")
        raise CapsuleFittingError(
            f"no link of '{model_path.name}' has a shape capsules can be fitted to "
            f"({len(unchecked)} link(s) with unusable shapes: {first or 'no shapes'}); give robot.capsules",
            tuple(unchecked),
        )
    atomic_write_text(out_path, "\n".join(lines) + "\n")
    note = up_axis_note(model_path)
    return FittedCapsules(Path(out_path), tuple(fitted), unchecked=tuple(unchecked),
                          sources=sources, notes=(note,) if note else ())


def _mirror_symmetric(P: np.ndarray) -> bool:
    """Whether a link's points are mirror-symmetric about the link frame's x-z plane (y → -y).

    A quantile, not the worst point: meshes are not sampled symmetrically vertex by vertex.
    """
    from scipy.spatial import cKDTree

    size = float(np.linalg.norm(P.max(axis=0) - P.min(axis=0)))
    gaps = cKDTree(P).query(P * [1.0, -1.0, 1.0])[0]
    return size > 0 and float(np.quantile(gaps, 0.9)) <= SYMMETRY_TOLERANCE * size


def _fit_points(P: np.ndarray, cover: float) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`fit_capsule`, made mirror-symmetric for a mirror-symmetric link (issue 21).

    A plain fit drifts off the plane of symmetry, so the axis is turned into the plane (or
    across it, whichever is nearer) and the best line that is its own mirror image is sought.
    """
    from scipy.optimize import minimize_scalar

    p0, p1, r = fit_capsule(P, cover=cover)
    if not _mirror_symmetric(P):
        return p0, p1, r
    u, mid = p1 - p0, 0.5 * (p0 + p1) * [1.0, 0.0, 1.0]
    if abs(u[1]) > np.linalg.norm(u) * math.sqrt(0.5):  # across the plane: any line along y is symmetric
        p0, p1, r = fit_capsule(P, axis=[0.0, 1.0, 0.0], cover=cover)
        half = max(abs(p0[1]), abs(p1[1]))
        return np.r_[p0[0], -half, p0[2]], np.r_[p1[0], half, p1[2]], r
    u = u * [1.0, 0.0, 1.0] if np.any(u[[0, 2]]) else np.array([0.0, 0.0, 1.0])
    w = np.cross(u, [0.0, 1.0, 0.0])
    w /= np.linalg.norm(w)  # in the plane, across the axis: the one free offset of the line
    size = float(np.linalg.norm(P.max(axis=0) - P.min(axis=0)))
    best = minimize_scalar(lambda s: fit_capsule(P, axis=u, cover=cover, through=mid + s * w)[2],
                           bounds=(-0.5 * size, 0.5 * size), method="bounded", options={"xatol": 1e-5})
    return fit_capsule(P, axis=u, cover=cover, through=mid + best.x * w)


def _radial_distance(points: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    d = p1 - p0
    L2 = max(float(d @ d), 1e-300)
    s = np.clip((points - p0) @ d / L2, 0.0, 1.0)
    return np.linalg.norm(points - (p0 + s[:, None] * d), axis=1)


def fit_capsules(config, folder: str | Path) -> tuple:
    """Fits capsules when a config needs them but names no capsule file (ConfigError: no model).

    Writes ``folder/fitted_capsules.yaml`` (:func:`ignore_touching_pairs` applied) and switches
    self-collision on at :data:`FITTED_COLLISION_MARGIN` when the config leaves it off.

    Returns:
        (the config pointing ``robot.capsules`` at the fitted file, what was fitted), or
        (``config`` itself, None) when the robot has a capsule file or nothing needs one.
    """
    robot, env = config.robot, config.environment
    needs = config.excitation.collision_margin >= 0 or bool(env.boxes) or (env.floor and not robot.support_points)
    if robot.capsules or not needs or not robot.model:
        return config, None
    model = resolve_mesh_path(robot.model, Path(robot.model), mesh=False)
    if model is None:
        raise ConfigError(f"cannot find the model '{robot.model}' to fit capsules to; give robot.capsules")
    model = loadable_model_path(model, robot.packages, trust_xacro=robot.trust_xacro)  # xacro expanded, robot.packages resolved
    fitted = fit_capsule_file(model, Path(folder) / FITTED_CAPSULES_NAME)
    margin = config.excitation.collision_margin
    config = dataclasses.replace(
        config,
        robot=dataclasses.replace(robot, capsules=str(fitted.path)),
        excitation=dataclasses.replace(config.excitation, collision_margin=margin if margin >= 0 else FITTED_COLLISION_MARGIN),
    )
    ignored, shrunk = ignore_touching_pairs(config, fitted.path, config.excitation.collision_margin)
    # The margin travels with the file: passed back as robot.capsules, it gives the same check.
    with open(fitted.path, "a") as f:
        f.write("# The self-collision margin these capsules were fitted for and their ignored pairs chosen with [m];\n"
                "# used when the config sets no excitation.collision_margin.\n"
                f"collision_margin: {config.excitation.collision_margin!r}\n")
    return config, dataclasses.replace(fitted, ignored_pairs=tuple(tuple(p) for p in ignored), shrunk=shrunk)


def with_file_margin(config):
    """The config with the capsule file's ``collision_margin`` when the config sets none (< 0).

    A fitted file without a margin (its header says so) gets :data:`FITTED_COLLISION_MARGIN`.
    """
    if config.excitation.collision_margin >= 0 or not config.robot.capsules:
        return config
    path = Path(config.robot.capsules)
    margin = load_capsule_file(path).collision_margin
    if margin is None and path.read_text(errors="replace").startswith(FITTED_HEADER):
        margin = FITTED_COLLISION_MARGIN
    if margin is None:
        return config
    return dataclasses.replace(config, excitation=dataclasses.replace(config.excitation, collision_margin=float(margin)))


def ignore_touching_pairs(config, path: Path, margin: float, samples: int = 200, share: float = 0.95) -> tuple:
    """Decides which pairs of a fitted capsule file touch by design and which capsules shrink.

    Only links at most :data:`TOUCHING_JOINTS` joints apart may touch by design (issue 21):
    closer than ``margin`` at the nominal posture, or in ``share`` of random postures. A farther
    pair closer than ``margin`` at the nominal posture has a capsule too fat for its mesh: the
    fatter one shrinks (down to :data:`SHRINK_FLOOR`) and only a pair that still touches is
    ignored. Mirror-named capsules keep equal radii, and a pair touching in random postures is
    ignored only when its mirror pair is too.

    Returns:
        (the pairs ignored, as [capsule, capsule, reason]; the capsules shrunk, as
        {name: (fitted radius, new radius)} [m]); the file is rewritten with both.
    """
    robot = Robot("fit", config.robot)
    caps = robot.capsules
    pairs = capsule_pairs(robot.scene_graph, caps)
    if not pairs:
        return [], {}
    rng = np.random.default_rng(0)
    lim = robot.limits
    q = np.vstack([robot.nominal_posture(), rng.uniform(lim.q_lower, lim.q_upper, (samples, robot.n))])
    ia, ib = np.array(pairs).T
    fitted = np.array([c.radius for c in caps])
    axes = _pair_distances(robot, pairs, q) + fitted[ia] + fitted[ib]  # axis to axis, (1 + samples, P)
    hops = joints_apart(robot.plant, [c.body_index for c in caps])[ia, ib]
    radii, stuck = _shrunk_radii(caps, pairs, axes[0], hops > TOUCHING_JOINTS, fitted, margin)
    d = axes - radii[ia] - radii[ib]
    reasons = {}
    for p, (a, b) in enumerate(pairs):
        names = (caps[a].name, caps[b].name)
        if p in stuck:
            reasons[names] = (f"{hops[p]} joints apart, closer than the margin at the nominal posture "
                              f"even with both radii at {SHRINK_FLOOR:.0%}")
        elif hops[p] <= TOUCHING_JOINTS and (d[0, p] < margin or np.mean(d[1:, p] < margin) >= share):
            reasons[names] = "closer than the margin at the nominal posture" if d[0, p] < margin else (
                f"closer than the margin in {np.mean(d[1:, p] < margin):.0%} of random postures")
    # A pair ignored by chance (random postures) stays checked unless its mirror pair is ignored
    # too: the two sides draw different postures. One touching at the nominal posture is
    # ignored regardless: checked, the start posture would collide.
    checked = {(caps[a].name, caps[b].name) for a, b in pairs}
    added = [[a, b, why] for (a, b), why in reasons.items() if not why.endswith("of random postures")
             or _mirror_pair(a, b, checked) is None or _mirror_pair(a, b, reasons) is not None]
    shrunk = {c.name: (float(fitted[k]), float(radii[k])) for k, c in enumerate(caps) if radii[k] < fitted[k]}
    _rewrite_capsule_file(path, added, shrunk)
    return added, shrunk


def mirror_name(name: str) -> str:
    """A link's left/right counterpart: "left"/"right" swapped (any case), else "l_"/"r_"."""
    swap = {"left": "right", "right": "left", "Left": "Right", "Right": "Left", "LEFT": "RIGHT", "RIGHT": "LEFT"}
    out = re.sub("left|right|Left|Right|LEFT|RIGHT", lambda m: swap[m.group(0)], name)
    if out == name:
        out = re.sub(r"^([lr])_", lambda m: ("r" if m.group(1) == "l" else "l") + "_", name)
    return out


def _mirror_pair(a: str, b: str, pairs) -> tuple | None:
    """The mirror of pair (a, b) as it is spelled in ``pairs`` (either order), or None."""
    ma, mb = mirror_name(a), mirror_name(b)
    return next((p for p in ((ma, mb), (mb, ma)) if p in pairs), None)


def _shrunk_radii(caps, pairs, axis, far, fitted, margin) -> tuple:
    """(radii, far pairs that still do not clear) with which every far pair clears ``margin``
    + 1 mm at axis distances ``axis``."""
    radii = fitted.copy()
    floor = SHRINK_FLOOR * fitted
    index = {c.name: k for k, c in enumerate(caps)}
    mirror = [index.get(mirror_name(c.name), k) for k, c in enumerate(caps)]
    order = sorted(np.flatnonzero(far), key=lambda p: axis[p])
    for p in order:
        a, b = pairs[p]
        need = radii[a] + radii[b] - (axis[p] - margin - 1e-3)
        for c in sorted((a, b), key=lambda c: -radii[c]):
            cut = min(max(need, 0.0), radii[c] - floor[c])
            if cut > 0:
                radii[c] = radii[mirror[c]] = min(radii[c] - cut, radii[mirror[c]])
                need -= cut
    ia, ib = np.array(pairs).T
    stuck = {int(p) for p in order if axis[p] - radii[ia[p]] - radii[ib[p]] < margin}
    return radii, stuck


def _rewrite_capsule_file(path: Path, ignored: list, shrunk: dict) -> None:
    """Writes the shrunk radii and the ignored pairs into a fitted capsule file."""
    text = path.read_text()
    for name, (before, after) in shrunk.items():
        text = re.sub(rf"(\{{name: {re.escape(name)}, link: [^,]+, radius: )[^,]+,",
                      lambda m: f"{m.group(1)}{after:.4f},", text)
        text = text.replace(f"  - {{name: {name}, link:", f"  # shrunk from radius {before:.4f} m to keep links more than "
                            f"{TOUCHING_JOINTS} joints away checked\n  - {{name: {name}, link:", 1)
    if ignored:
        lines = ["ignored_pairs:", "  # touching by design (pe_drake.multibody.capsule_fitting.ignore_touching_pairs)"]
        lines += [f"  - [{a}, {b}]  # {why}" for a, b, why in ignored]
        text += "\n".join(lines) + "\n"
    path.write_text(text)


def _pair_distances(robot: Robot, pairs, q: np.ndarray) -> np.ndarray:
    """Surface distance of capsule pairs at postures q (K, n), shape (K, P) [m]."""
    caps = robot.capsules
    X = robot.body_poses(q)  # (K, bodies, 4, 4)
    ends = np.stack([X[:, c.body_index, None, :3, :3] @ c.p_BS[..., None] for c in caps], axis=1)[..., 0]
    ends = ends + np.stack([X[:, c.body_index, None, :3, 3] for c in caps], axis=1)  # (K, C, 2, 3)
    ia, ib = np.array(pairs).T
    a0, a1, b0, b1 = ends[:, ia, 0], ends[:, ia, 1], ends[:, ib, 0], ends[:, ib, 1]
    s, t = segment_closest_points(a0, a1, b0, b1)
    gap = (a0 + s[..., None] * (a1 - a0)) - (b0 + t[..., None] * (b1 - b0))
    radii = np.array([caps[i].radius + caps[j].radius for i, j in pairs])
    return np.linalg.norm(gap, axis=-1) - radii
