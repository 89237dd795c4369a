"""The physically consistent fit: an SDP over the standard parameters and the drive terms.

Constraints: J(φ_b) ⪰ ε m_b,prior 1 for every body (Wensing, Kim & Slotine 2017), θ_k ≥ 0
for friction and armature, and the user's bounds m_lo ≤ Σ_b m_b ≤ m_hi, m_b ∈ [lo_b, hi_b],
m_b·box_lo ≤ h_b ≤ m_b·box_hi. Data term f(φ, θ) = ‖A φ + E θ − y‖² (A, E: the whitened
standard-parameter regressor and drive columns). In two stages:

1. min f + μ_1 ‖N_D(φ − φ_prior)‖²: the best physically valid fit (μ_1 = ``NULL_WEIGHT``
   (1e-4) × μ only chooses among equally good fits);
2. min ‖N_D(φ − φ_prior)‖² + λ‖D⁻¹(φ − φ_prior)‖² s.t. f ≤ f_1 + Δχ²: among the fits that the
   data cannot tell from stage 1's (identify passes Δχ² = 4 in correlation-corrected units,
   a two-σ move), the one nearest the a-priori model.

D is a per-variable scale (the a-priori magnitudes per body block: mass, first moments,
inertias), N_D the projector onto the φ-part of the null space of [K·D | c_k] (K: the base
composition, φ_B = K φ; c_k: the base-parameter expression of a merged armature): the
directions of φ no motion can identify, where the prior decides. μ is the smallest non-zero
eigenvalue of f's Hessian and λ = ``prior_weight`` (1e-6) only makes stage 2 strictly convex.
A single stage with the pull in the objective either lets masses drift or biases what the data
determine (BUILD_NOTES.md has the figures). Bodies whose a-priori mass is zero stay at zero.
The CoM box is linear in the first moments h = m c (link frame, [m]): box_lo·m ≤ h ≤ box_hi·m.

:func:`physical_fit` serves ``identify --method physical`` and the diagnosis; the payload and
drive-gain fits use :func:`factored_sdp`. All go through :func:`solve_sdp`, the package's one
SDP, and :func:`add_pseudo_inertia_constraint`, its one pseudo-inertia LMI.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from pe_drake.exceptions import ConfigError, NoSolutionFound, UnknownNameError
from pe_drake.multibody.inertia import pseudo_inertia, pseudo_inertia_basis

#: Stage 1's pull toward the a-priori parameters in the unidentifiable directions, relative to
#: μ = the smallest non-zero eigenvalue of the data term's Hessian (module docstring).
NULL_WEIGHT = 1e-4
#: Stage 2's default misfit budget Δχ² over the unconstrained optimum (identify passes the 95 %
#: confidence region of its estimate instead, module docstring).
CHI2_TOLERANCE = 1.0
#: Weight of the isotropic pull toward the a-priori parameters, relative to μ (module docstring).
PRIOR_WEIGHT = 1e-6
#: The fit keeps J(φ_b) ⪰ PSD_MARGIN · m_b,prior · I so that the result passes Drake's
#: validity test despite the SDP solver's tolerance.
PSD_MARGIN = 1e-7
#: A mass that moved by more than this fraction of its a-priori value is reported ("moved far").
FAR_FROM_PRIOR = 0.5
#: A variable within this fraction of its bound's scale counts as on the bound (the solver's
#: tolerance is 1e-10; its result sits within ~1e-7 of an active bound).
ON_BOUND = 1e-5


@dataclasses.dataclass(frozen=True)
class LinkBox:
    """Where a link's centre of mass may be, in the link's frame: center, edge lengths [m]."""

    center: tuple[float, float, float]
    size: tuple[float, float, float]

    def __post_init__(self) -> None:
        if len(self.center) != 3 or len(self.size) != 3:
            raise ConfigError(f"a CoM box needs 3 numbers for center and size, got {self.center}, {self.size}")
        if any(not np.isfinite(x) for x in (*self.center, *self.size)) or min(self.size) < 0:
            raise ConfigError(f"a CoM box needs finite center and non-negative size [m], got {self.center}, {self.size}")

    @property
    def lower(self) -> np.ndarray:
        return np.asarray(self.center, float) - 0.5 * np.asarray(self.size, float)

    @property
    def upper(self) -> np.ndarray:
        return np.asarray(self.center, float) + 0.5 * np.asarray(self.size, float)


@dataclasses.dataclass(frozen=True)
class PhysicalBounds:
    """The user's bounds of the physical fit (config ``identification``): (lo, hi) of the moving
    bodies' total mass [kg] or None, {body: (lo, hi)} [kg], {body: :class:`LinkBox` of its CoM}."""

    total_mass: tuple[float, float] | None = None
    mass_bounds: dict[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    boxes: dict[str, LinkBox] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        pairs = ([("total_mass", self.total_mass)] if self.total_mass is not None else []) + [
            (f"mass_bounds['{k}']", v) for k, v in self.mass_bounds.items()]
        for name, pair in pairs:
            if len(pair) != 2 or not all(np.isfinite(x) for x in pair) or not 0 <= pair[0] <= pair[1]:
                raise ConfigError(f"identification.{name} must be [lo, hi] with 0 <= lo <= hi [kg], got {list(pair)}")

    @property
    def empty(self) -> bool:
        return self.total_mass is None and not self.mass_bounds and not self.boxes

    def check(self, body_names: Sequence[str]) -> None:
        """Raises UnknownNameError for a bound on a body the robot does not have."""
        for table, where in ((self.mass_bounds, "identification.mass_bounds"), (self.boxes, "identification.boxes")):
            for name in table:
                if name not in body_names:
                    raise UnknownNameError("link", name, body_names, where)


class PhysicalFit(NamedTuple):
    """Result of :func:`physical_fit`: φ (10·nb,) physically valid, the drive terms θ (d,), and
    the parameters on a bound or far from the a-priori model, in words."""

    phi: np.ndarray
    theta: np.ndarray
    notes: tuple[str, ...]


def physical_fit(A: np.ndarray, y: np.ndarray, prior: np.ndarray, body_names: Sequence[str], *,
                 extra: np.ndarray | None = None, extra_lower: np.ndarray | None = None,
                 extra_names: Sequence[str] = (), bounds: PhysicalBounds | None = None,
                 base_K: np.ndarray | None = None,
                 extra_in_base: dict[int, np.ndarray] | None = None,
                 scale: np.ndarray | None = None, prior_weight: float = PRIOR_WEIGHT,
                 chi2_tolerance: float = CHI2_TOLERANCE, margin: float = PSD_MARGIN,
                 rows: int | None = None) -> PhysicalFit:
    """The SDP of the module docstring.

    Args:
        A: weighted standard-parameter regressor, shape (rows, 10·nb).
        y: weighted measurements, shape (rows,).
        prior: a-priori parameters, shape (10·nb,).
        extra: weighted drive columns E, shape (rows, d), or None.
        extra_lower: lower bound of each drive term (0 or -inf), shape (d,).
        base_K: the base composition K (b, 10·nb) whose null space gets the a-priori pull;
            None: the numerical null space of A.
        extra_in_base: {k: c_k} for drive columns inside span(Y_B): column k = Y_B c_k
            (a merged armature): a merged combination's excess over the a-priori links goes
            to the drive term (≥ 0), not into the links.
        scale: per-variable scale D of φ, shape (10·nb,); default the a-priori magnitudes per
            body block.
        prior_weight: λ / μ.
        chi2_tolerance: Δχ² of stage 2; 0 skips it.
        margin: ε of the pseudo-inertia constraint.
        rows: the rows ``A`` stands for when it is folded; default ``len(y)``.

    Raises:
        NoSolutionFound: the solver failed (e.g. bounds that contradict each other or the data).
        UnknownNameError: a bound on an unknown body.
    """
    bounds = bounds or PhysicalBounds()
    bounds.check(body_names)
    p = A.shape[1]
    E = np.zeros((A.shape[0], 0)) if extra is None else np.asarray(extra, float)
    d = E.shape[1]
    lower = np.full(d, -np.inf) if extra_lower is None else np.asarray(extra_lower, float)
    # a model without inertials (issue 37): every body is fitted, pulled toward zero
    active = [b for b in range(len(body_names)) if prior[10 * b] > 0] or list(range(len(body_names)))
    cols = np.concatenate([np.arange(10 * b, 10 * b + 10) for b in active])
    D = (_variable_scale(prior, active) if scale is None else np.asarray(scale, float))[cols]
    s_e, Rs, z, P_null, mu, Z = _data_term(A[:, cols] * D, E, y, base_K, cols, D, extra_in_base,
                                           len(y) if rows is None else rows)
    k = len(cols) + d
    H = Rs.T @ Rs
    x_prior = np.concatenate([prior[cols] / D, np.zeros(d)])
    # The data term as (x − x0)ᵀ H (x − x0) about its minimizer nearest the prior, x0: the
    # objective is then ~0 where the constraints are inactive, so the solver's relative
    # tolerance resolves the small pulls (about −‖z‖² they would drown in the signal energy).
    x0 = x_prior + Z @ np.linalg.lstsq(Rs @ Z, z - Rs @ x_prior, rcond=1e-13)[0]  # Z: what the data identify
    iso = np.diag(np.r_[np.ones(len(cols)), np.zeros(d)])
    pull = P_null + prior_weight * iso  # in units of μ, the least determined direction's curvature
    # Stage 1: the best physically valid fit (the pull only selects among equally good fits)
    Q = 2.0 * (H + NULL_WEIGHT * mu * pull)
    c = -2.0 * H @ x0 - 2.0 * NULL_WEIGHT * mu * pull @ x_prior
    # the margin is per kg of the prior's mass; a massless prior (no inertials): per 1 kg
    blocks = [InertiaBlock(10 * i, D[10 * i : 10 * i + 10], margin * (prior[10 * b] or 1.0)) for i, b in enumerate(active)]
    lower_x = np.r_[np.full(len(cols), -np.inf), lower / s_e]
    rows = _bound_rows(k, D, active, list(body_names), bounds)
    advice = "try --method wls" + (" or relax the identification bounds" if not bounds.empty else "")
    sol = solve_sdp(Q / mu, c / mu, blocks, x_prior, lower=lower_x, rows=rows, advice=advice)
    stage2_failed = False
    if chi2_tolerance > 0:
        # Stage 2: the parameters nearest the a-priori model (in the null-space metric) among
        # those whose whitened misfit exceeds stage 1's by at most chi2_tolerance.
        e = sol - x0
        bound = float(np.sum((Rs @ e) ** 2)) + chi2_tolerance  # as the cone measures it, not via H = RsᵀRs
        # ‖Rs (x − x0)‖ ≤ √bound as a Lorentz cone [√bound; Rs x − Rs x0]
        cone = (np.vstack([np.zeros((1, k)), Rs]), np.r_[np.sqrt(bound), -Rs @ x0])
        try:
            sol = solve_sdp(2.0 * pull, -2.0 * pull @ x_prior, blocks, sol, lower=lower_x, rows=rows, cone=cone,
                            advice=advice)
        except NoSolutionFound:  # e.g. noise-free data: whitened rows of 1e9; keep stage 1
            stage2_failed = True
    phi = np.zeros(p)
    phi[cols] = D * sol[: len(cols)]
    theta = s_e * sol[len(cols) :]
    notes = fit_notes(phi, prior, theta, lower, list(extra_names), list(body_names), bounds, margin)
    notes += ["the solver failed on the pull toward the a-priori model within the confidence region; the best "
              "physically valid fit is kept"] if stage2_failed else []
    return PhysicalFit(phi, theta, tuple(notes))


def _data_term(AD: np.ndarray, E: np.ndarray, y: np.ndarray, base_K, cols, D, extra_in_base, rows: int):
    """(drive scales s_e, R, z with ‖[A D | E s_e] x − y‖² = ‖R x − z‖² + const (QR), the
    null-space projector, μ, the identified directions' basis)."""
    norms = np.linalg.norm(E, axis=0)
    s_e = np.where(norms > 0, np.linalg.norm(y) / np.maximum(norms, 1e-300) / max(np.sqrt(rows), 1.0), 1.0)
    k = AD.shape[1] + E.shape[1]
    R = np.linalg.qr(np.column_stack([AD, E * s_e, y]), mode="r")
    Rs, z = R[:k, :k], R[:k, k]
    KD, inside = None, sorted((extra_in_base or {}).items())
    if base_K is not None:
        KD = np.column_stack([base_K[:, cols] * D] + [np.asarray(c, float) * s_e[i] for i, c in inside])
    P_null, mu = _null_pull(Rs.T @ Rs, KD, AD.shape[1])
    return s_e, Rs, z, P_null, mu, _identified_basis(KD, AD.shape[1], [AD.shape[1] + i for i, _ in inside], k)


def _identified_basis(KD: np.ndarray | None, p: int, inside: list[int], k: int) -> np.ndarray:
    """Orthonormal basis, shape (k, r), of the directions of x = (φ/D, θ/s_e) outside the null space
    of [K D | c_k s_k] (``inside``: the x-indices of the c_k): those the data can identify; the
    identity without K (a cut-off on the data factor's singular values alone kept rounding
    directions of merged armatures).
    """
    if KD is None:
        return np.eye(k)
    _, s, Vt = np.linalg.svd(KD)
    null = Vt[int(np.sum(s > 1e-10 * max(s.max(), 1e-300))) :]  # rank cut as in _null_pull
    if not len(null):
        return np.eye(k)
    N = np.zeros((k, len(null)))  # orthonormal columns: Vt's rows with zeros for the other θ
    N[:p], N[inside] = null[:, :p].T, null[:, p:].T
    return np.linalg.svd(N, full_matrices=True)[0][:, len(null) :]


class InertiaBlock(NamedTuple):
    """One body's J(φ_b) ⪰ margin [kg]·1 in the SDP's variables x: φ_b = scale ⊙ x[start :
    start + len(scale)] (10 values), or with a known ``fixed_mass`` [kg] the 9 after the mass."""

    start: int
    scale: np.ndarray
    margin: float = 0.0
    fixed_mass: float | None = None


def add_pseudo_inertia_constraint(prog, x, block: InertiaBlock) -> None:
    """J(φ_b) = Σ_i φ_b,i F_i ⪰ margin·1, linear in x (Wensing, Kim & Slotine 2017: J ⪰ 0 exactly
    when a non-negative mass density gives φ_b); the one place the package writes it."""
    F = pseudo_inertia_basis()
    F0 = -block.margin * np.eye(4)
    if block.fixed_mass is not None:
        F0, F = block.fixed_mass * F[0] + F0, F[1:]
    scale = block.scale
    prog.AddLinearMatrixInequalityConstraint([F0] + [F[j] * scale[j] for j in range(len(scale))],
                                             x[block.start : block.start + len(scale)])


#: Clarabel's gap and feasibility tolerances, tried in turn: the tight one first; when it stalls
#: (insufficient progress near the optimum) the looser one, still far below the data's σ.
SDP_TOLERANCES = (1e-10, 1e-8)


def solve_sdp(Q: np.ndarray, c: np.ndarray, blocks: Sequence[InertiaBlock], guess: np.ndarray, *,
              lower: np.ndarray | None = None, rows: Sequence[tuple[np.ndarray, float, float]] = (),
              cone: tuple[np.ndarray, np.ndarray] | None = None, what: str = "fit", advice: str = "",
              tolerances: Sequence[float] = SDP_TOLERANCES) -> np.ndarray:
    """The package's one physically consistent fit: min ½xᵀQx + cᵀx (Q (k, k) PSD) s.t. every
    :class:`InertiaBlock`, x ≥ ``lower`` (−inf: none), lo ≤ a·x ≤ hi for (a, lo, hi) in ``rows``
    and A x + b in the Lorentz cone (``cone`` = (A, b)); Clarabel (SCS when unavailable) from
    ``guess`` at ``tolerances`` in turn.

    Raises:
        NoSolutionFound: "the physically consistent {what} failed (…); {advice}".
    """
    from pydrake.solvers import ClarabelSolver, MathematicalProgram, ScsSolver, SolverOptions  # lazy: pydrake

    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(len(c), "x")
    prog.AddQuadraticCost(Q, c, x, is_convex=True)
    for block in blocks:
        add_pseudo_inertia_constraint(prog, x, block)
    for j in np.flatnonzero(np.isfinite(lower)) if lower is not None else ():
        prog.AddBoundingBoxConstraint(lower[j], np.inf, x[j])
    for a, lo, hi in rows:
        prog.AddLinearConstraint(np.asarray(a, float)[None, :], [lo], [hi], x)
    if cone is not None:
        prog.AddLorentzConeConstraint(cone[0], cone[1], x)
    solver = ClarabelSolver()
    if not solver.available():  # pragma: no cover - the drake wheel ships Clarabel
        solver = ScsSolver()
    for tolerance in tolerances:
        options = SolverOptions()
        if solver.solver_id() == ClarabelSolver.id():
            for key in ("tol_gap_abs", "tol_gap_rel", "tol_feas"):
                options.SetOption(solver.solver_id(), key, tolerance)
        result = solver.Solve(prog, guess, options)
        if result.is_success():
            break
    if not result.is_success():
        raise NoSolutionFound(f"the physically consistent {what} failed ({solver.solver_id().name()}: "
                              f"{result.get_solution_result().name})" + (f"; {advice}" if advice else ""), result)
    return result.GetSolution(x)


def scaled_factor(R_joint: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(R_a, z, D): Σ_j w_j² ‖A_j x − y_j‖² = ‖R_a u − z‖² + const in u = D x, D the column norms of
    the weighted rows, from the per-joint factors R_j of [A_j y_j], (n, p+1, p+1)."""
    p = R_joint.shape[-1] - 1
    Rw = (R_joint * w[:, None, None]).reshape(-1, p + 1)
    D = np.maximum(np.linalg.norm(Rw[:, :p], axis=0), 1e-300)
    R = np.linalg.qr(np.column_stack([Rw[:, :p] / D, Rw[:, p]]), mode="r")
    return R[:p, :p], R[:p, p], D


def factored_sdp(R_joint: np.ndarray, w: np.ndarray, x_ls: np.ndarray, blocks: Sequence[InertiaBlock], *,
                 lower: np.ndarray | None = None, what: str = "fit",
                 tolerances: Sequence[float] = SDP_TOLERANCES) -> np.ndarray:
    """min Σ_j w_j² ‖A_j x − y_j‖² under :func:`solve_sdp`'s constraints (given in x), from the
    per-joint factors R_j (n, p+1, p+1) and the unconstrained ``x_ls``; solved in u = D x."""
    Ra, z, D = scaled_factor(R_joint, w)
    d = 1.0 / D  # x = d ⊙ u
    scaled = [b._replace(scale=b.scale * d[b.start : b.start + len(b.scale)]) for b in blocks]
    u = solve_sdp(2.0 * Ra.T @ Ra, -2.0 * Ra.T @ z, scaled, x_ls * D, lower=None if lower is None else lower * D,
                  what=what, tolerances=tolerances)
    return u / D


def _null_pull(H: np.ndarray, KD: np.ndarray | None, p: int) -> tuple[np.ndarray, float]:
    """(projector onto the unidentifiable directions of the first p variables, μ)."""
    w = np.linalg.eigvalsh(H[:p, :p])
    tol = 1e-10 * max(w.max(), 1e-300)
    determined = w[w > tol]
    mu = float(determined.min()) if determined.size else 1.0

    if KD is None:
        w, V = np.linalg.eigh(H[:p, :p])
        N = V[:, w <= tol]
    else:  # the φ-part of the null space of [K D | c_k s_k]: orthonormal basis of its span
        _, s, Vt = np.linalg.svd(KD)
        rank = int(np.sum(s > 1e-10 * max(s.max(), 1e-300)))
        U, s2, _ = np.linalg.svd(Vt[rank:, :p].T, full_matrices=False)
        N = U[:, s2 > 1e-8 * max(s2.max(), 1e-300)] if s2.size else U[:, :0]
    P = np.zeros_like(H)
    P[:p, :p] = N @ N.T
    return P, mu


def _bound_rows(k: int, D: np.ndarray, active: list[int], names: list[str], bounds: PhysicalBounds) -> list:
    """The user's bounds on the scaled variables x, as rows (a, lo, hi) of lo ≤ a·x ≤ hi."""
    where = {b: i for i, b in enumerate(active)}
    rows = []

    def mass_row(b: int) -> np.ndarray:
        row = np.zeros(k)
        row[10 * where[b]] = D[10 * where[b]]
        return row

    if bounds.total_mass is not None:
        rows.append((sum((mass_row(b) for b in active), np.zeros(k)), bounds.total_mass[0], bounds.total_mass[1]))
    for name, (lo, hi) in bounds.mass_bounds.items():
        b = names.index(name)
        if b in where:
            rows.append((mass_row(b), lo, hi))
    for name, box in bounds.boxes.items():
        b = names.index(name)
        if b not in where:
            continue
        i0 = 10 * where[b]
        for axis in range(3):
            for limit, sign in ((box.lower[axis], 1.0), (box.upper[axis], -1.0)):
                row = np.zeros(k)  # sign·(h_axis − limit·m) ≥ 0
                row[i0 + 1 + axis] = sign * D[i0 + 1 + axis]
                row[i0] = -sign * limit * D[i0]
                rows.append((row, 0.0, np.inf))
    return rows


def fit_notes(phi: np.ndarray, prior: np.ndarray, theta: np.ndarray, lower: np.ndarray, extra_names: list[str],
              body_names: list[str], bounds: PhysicalBounds, margin: float = PSD_MARGIN) -> list[str]:
    """Parameters of a physical fit on a bound or far from the a-priori model, in words."""
    def mass_on_bound(what: str, m: float, lo: float, hi: float) -> list[str]:
        return [f"{what} {m:.4g} kg is on its {side} bound {value:g} kg"
                for value, side in ((lo, "lower"), (hi, "upper"))
                if abs(m - value) <= ON_BOUND * max(hi, 1.0)]

    masses = phi[0::10]
    total = bounds.total_mass
    notes = [] if total is None else mass_on_bound("total mass", float(masses.sum()), *total)
    for b, name in enumerate(body_names):
        m0, m = prior[10 * b], masses[b]
        if m0 <= 0:
            continue
        if name in bounds.mass_bounds:
            notes += mass_on_bound(f"{name}: mass", m, *bounds.mass_bounds[name])
        if name in bounds.boxes:
            box = bounds.boxes[name]
            com = phi[10 * b + 1 : 10 * b + 4] / max(m, 1e-300)
            for axis, label in enumerate("xyz"):
                for value, side in ((box.lower[axis], "lower"), (box.upper[axis], "upper")):
                    if abs(com[axis] - value) <= ON_BOUND * max(box.size[axis], 1e-3):
                        notes.append(f"{name}: CoM {label} = {com[axis]:.4g} m is on its box's {side} face")
        if abs(m - m0) > FAR_FROM_PRIOR * m0:
            notes.append(f"{name}: mass {m:.4g} kg moved far from the a-priori {m0:.4g} kg "
                         f"({100 * (m - m0) / m0:+.0f} %)")
        w = np.linalg.eigvalsh(pseudo_inertia(phi[10 * b : 10 * b + 10]))
        if w.min() <= 10 * margin * m0:
            notes.append(f"{name}: on the physical-validity boundary (its pseudo-inertia is singular: "
                         "a mass distribution flat or on a line)")
    for name, value, lo in zip(extra_names, theta, lower):
        if np.isfinite(lo) and value <= lo + ON_BOUND * max(float(np.max(np.abs(theta))) if len(theta) else 1.0, 1e-9):
            notes.append(f"{name} is on its bound {lo:g} (the unconstrained fit wants it negative)")
    return notes


def _variable_scale(prior: np.ndarray, active: list[int]) -> np.ndarray:
    """Per-variable scale (10·nb,) that makes the prior about 1 per body block (SDP numerics)."""
    scale = np.ones(prior.size)
    for b in active:
        m = prior[10 * b]
        if m <= 0:  # no a-priori inertia (a model without inertials): a generic link's magnitudes
            scale[10 * b : 10 * b + 10] = [1.0, 0.1, 0.1, 0.1] + [0.01] * 6  # [kg, kg·m, kg·m²]
            continue
        scale[10 * b] = m
        scale[10 * b + 1 : 10 * b + 4] = max(np.max(np.abs(prior[10 * b + 1 : 10 * b + 4])), 1e-3 * m)
        scale[10 * b + 4 : 10 * b + 10] = max(np.max(np.abs(prior[10 * b + 4 : 10 * b + 10])), 1e-6 * m)
    return scale


def bounds_from_config(config) -> PhysicalBounds:
    """The bounds of a config's ``identification`` section (:class:`~pe_drake.config.IdentificationConfig`)."""
    return PhysicalBounds(
        total_mass=tuple(config.total_mass) if config.total_mass else None,
        mass_bounds={k: (float(v[0]), float(v[1])) for k, v in config.mass_bounds.items()},
        boxes={k: LinkBox(tuple(map(float, b.center)), tuple(map(float, b.size))) for k, b in config.boxes.items()},
    )
