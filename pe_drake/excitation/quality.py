"""What a motion will tell you before you record it: expected parameter and torque errors.

cond(C) depends on the chosen base parameters and their units; for a torque noise σ_j per joint
and P recorded periods this module gives the expected standard deviation of every base parameter
(Cov = (CᵀΣ⁻¹C)⁻¹ / P, the covariance of ``pe-drake identify --method wls``; basis-dependent),
and basis-free figures: the expected RMS error of the torques predicted on a fixed, seeded
reference set of motions (row c_v has variance c_v Cov c_vᵀ, invariant under φ_B → Tφ_B) and
its ratio, and that of the D-efficiency det(CᵀΣ⁻¹C)^(1/2b), to random motions under the same
constraints ("this motion predicts torques k× better than random motions").

Assumptions (stated in every report): C is the measurement's rows of one period sampled at
``rate_hz`` (default :data:`DATA_RATE_HZ`), base parameters then drive terms as columns; the
noise is independent between samples, σ_j per joint (identified.json's ``noise_std``) and the
config's force/moment σ on wrench rows; P periods give P times the information of one.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import re
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.config_sections import noise_vector
from pe_drake.exceptions import ConfigError
from pe_drake.excitation.criteria import singular_values_and_vectors
from pe_drake.excitation.fourier import FourierBasis, sample_times
from pe_drake.multibody.drive_columns import drive_columns
from pe_drake.threads import single_threaded_blas

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Rate of the samples the identification fits [Hz] (its preprocessing decimates to it:
#: ``pe_drake.identification.intake.DEFAULT_RATE_HZ``; a test keeps the two equal).
DATA_RATE_HZ = 200.0
#: The fixed reference set of validation motions: count, seed, harmonics, period [s],
#: samples per motion, fraction of the binding joint limit used.
REFERENCE_MOTIONS = 8
REFERENCE_SEED = 2017
REFERENCE_HARMONICS = 5
REFERENCE_PERIOD_S = 10.0
REFERENCE_SAMPLES = 100
REFERENCE_LIMIT_FRACTION = 0.9
#: The regressors are sampled at most this fast [Hz] and their information scaled to the data
#: rate: for a band-limited periodic motion CᵀC over one period is proportional to the sample
#: count beyond a few samples per period of its highest harmonic.
SAMPLE_RATE_HZ = 50.0
#: A base parameter whose a-priori value is below this fraction of the largest one gets no %
#: (a zero or rounding-level product of inertia would show as 1e8 %).
PERCENT_FLOOR = 1e-6
#: Random motions compared with the optimized one, and the seed of the first.
RANDOM_MOTIONS = 5
RANDOM_SEED = 1000
#: A random draw that violates a sampled constraint is shrunk by this factor toward its
#: offsets, at most RANDOM_SHRINK_STEPS times, before it is rejected.
RANDOM_SHRINK = 0.8
RANDOM_SHRINK_STEPS = 10


@dataclasses.dataclass(frozen=True)
class MotionQuality:
    """The figures of one motion ("optimized" or "random <seed>").

    Attributes:
        cond: cond(C) in pe_drake's base parameters (depends on the basis and units).
        d_efficiency: geometric mean of the singular values of Σ^(-1/2)C over P periods
            (its ratios between motions are basis-free; the value itself is not).
        std: expected standard deviation of each base parameter, then of each drive term of
            ``excitation.drive_terms``, shape (b + d,) [SI units of each].
        prediction_rms: expected RMS error of the predicted torques on the reference set,
            per joint, shape (n,) [N·m or N].
        prediction_rms_total: the same over all joints [N·m or N].
    """

    label: str
    cond: float
    d_efficiency: float
    std: np.ndarray
    prediction_rms: np.ndarray
    prediction_rms_total: float


@dataclasses.dataclass(frozen=True)
class QualityReport:
    """Quality figures of a motion, of random motions under the same constraints, and ratios.

    Attributes:
        noise_std: σ_j per joint [N·m or N].
        periods: P, periods recorded.
        rate_hz: rate of the samples assumed [Hz].
        samples_per_period: samples of one period at ``rate_hz`` (the regressors are evaluated
            at up to :data:`SAMPLE_RATE_HZ` and their information scaled to it).
        base_names: pe_drake's base parameters, length b.
        prior: their a-priori values (the model's), shape (b,).
        std_percent: the motion's std in % of |prior| (inf where the prior is ~0), shape (b,).
        drive_names: the drive terms in C (``excitation.drive_terms``), e.g.
            "coulomb[panda_joint1]"; their std is ``motion.std[b:]``.
        drive_units: their units.
        random_rejected: random draws that failed the constraints even when shrunk.
        prediction_ratio: best random prediction RMS / the motion's ("k× better"; nan
            without random motions).
        d_efficiency_ratio: the motion's D-efficiency / the best random one's.
    """

    joints: tuple[str, ...]
    noise_std: np.ndarray
    periods: int
    rate_hz: float
    samples_per_period: int
    base_names: tuple[str, ...]
    prior: np.ndarray
    std_percent: np.ndarray
    motion: MotionQuality
    random: list[MotionQuality]
    random_rejected: int
    prediction_ratio: float
    d_efficiency_ratio: float
    drive_names: tuple[str, ...] = ()
    drive_units: tuple[str, ...] = ()

    @property
    def drive_std(self) -> np.ndarray:
        """Expected standard deviation of each drive term, shape (d,) [``drive_units``]."""
        return self.motion.std[len(self.base_names):]

    def worst_drive_terms(self) -> list[int]:
        """Index of the drive term with the largest std of each kind (coulomb, viscous, ...)."""
        kinds = dict.fromkeys(name.split("[")[0] for name in self.drive_names)
        return [max((k for k, name in enumerate(self.drive_names) if name.startswith(kind + "[")),
                    key=lambda k: self.drive_std[k]) for kind in kinds]

    def to_dict(self) -> dict:
        """JSON-ready content (report.json's ``quality`` section)."""

        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        def motion(m: MotionQuality) -> dict:
            return {"label": m.label, "cond_pe_drake_basis": num(m.cond),
                    "d_efficiency": num(m.d_efficiency),
                    "prediction_rms": dict(zip(self.joints, map(float, m.prediction_rms))),
                    "prediction_rms_total": float(m.prediction_rms_total)}

        return {
            "assumptions": {
                "noise_std": dict(zip(self.joints, map(float, self.noise_std))),
                "periods": self.periods,
                "rate_hz": self.rate_hz,
                "samples_per_period": self.samples_per_period,
                "estimator": "weighted least squares, noise independent between samples",
                "data": "this motion alone (earlier motions given as prior data are not included)",
                "reference_set": {"motions": REFERENCE_MOTIONS, "seed": REFERENCE_SEED,
                                  "harmonics": REFERENCE_HARMONICS, "period_s": REFERENCE_PERIOD_S,
                                  "limit_fraction": REFERENCE_LIMIT_FRACTION},
            },
            "base_parameter_std": [
                {"name": n, "prior": float(p), "std": float(s), "std_percent": num(pc)}
                for n, p, s, pc in zip(self.base_names, self.prior, self.motion.std, self.std_percent)
            ],
            "drive_term_std": [
                {"name": n, "std": float(s), "unit": u}
                for n, s, u in zip(self.drive_names, self.drive_std, self.drive_units)
            ],
            "motion": motion(self.motion),
            "random": [motion(m) for m in self.random],
            "random_rejected": self.random_rejected,
            "prediction_ratio_vs_best_random": num(self.prediction_ratio),
            "d_efficiency_ratio_vs_best_random": num(self.d_efficiency_ratio),
        }

    def figure_note(self) -> str:
        """A few short lines for the trajectory figure."""
        sigma = "/".join(f"{s:.3g}" for s in np.unique(self.noise_std))
        lines = [
            f"noise σ {sigma} N·m, {self.periods} period(s) at {self.rate_hz:g} Hz:",
            f"torque-prediction RMS {self.motion.prediction_rms_total:.3g} N·m (reference motions)",
        ]
        if self.random:
            lines.append(f"{_times(self.prediction_ratio)} than {len(self.random)} random motions")
            lines.append(f"D-efficiency {self.d_efficiency_ratio:.3g}× theirs")
        finite = np.where(np.isfinite(self.std_percent), self.std_percent, -np.inf)
        k = int(np.argmax(finite))
        if np.isfinite(finite[k]):
            lines.append(f"largest base-parameter std {self.std_percent[k]:.3g} %")
        return "\n".join(lines)

    def summary_lines(self, worst: int = 3) -> list[str]:
        """A few lines for the printed summary (the ``worst`` base parameters by % std)."""
        sigma = ", ".join(f"{s:.3g}" for s in np.unique(self.noise_std))
        lines = [
            f"expected quality for torque noise σ = {sigma} N·m, {self.periods} period(s) at "
            f"{self.rate_hz:g} Hz (weighted least squares):",
            f"  torque prediction RMS on the reference motions: {self.motion.prediction_rms_total:.3g} N·m",
        ]
        finite = np.where(np.isfinite(self.std_percent), self.std_percent, -np.inf)
        order = np.argsort(-finite)[:worst]
        lines.append(
            "  largest base-parameter std (pe_drake's base parameters): "
            + ("; ".join(f"{short_composition(self.base_names[k])} {self.std_percent[k]:.3g} %"
                         for k in order if np.isfinite(finite[k]))
               # % of the a-priori values: none to compare with when the model has no inertials
               or "not available (no a-priori base parameter to express σ in % of)")
        )
        if self.drive_names:
            lines.append(f"  drive terms ({len(self.drive_names)}), largest std of each kind: " + "; ".join(
                f"{self.drive_names[k]} {self.drive_std[k]:.3g} {self.drive_units[k]}" for k in self.worst_drive_terms()))
        if self.random:
            best = min(m.prediction_rms_total for m in self.random)
            lines.append(
                f"  vs the best of {len(self.random)} random motions under the same constraints "
                f"(RMS {best:.3g} N·m): predicts torques {_times(self.prediction_ratio)}, "
                f"D-efficiency {self.d_efficiency_ratio:.3g}×"
            )
        elif self.random_rejected:
            # the progress line announced the comparison: say why it is missing
            lines.append(f"  vs random motions: none compared, all {self.random_rejected} random draws failed the "
                         "same constraints even when shrunk")
        return lines


def _times(ratio: float) -> str:
    """"2.5× better" or, below 1, "8.55× worse" ("0.117× better" read as a gain)."""
    return f"{ratio:.3g}× better" if not ratio < 1 else f"{1 / ratio:.3g}× worse"


#: A term of a printed base-parameter composition below this fraction of its largest
#: coefficient is left out (a 1e-10 product of inertia from a rounded URDF angle).
NEGLIGIBLE_COEFFICIENT = 1e-6
#: Longest base-parameter composition printed in a summary line [characters].
MAX_COMPOSITION_CHARS = 120


def short_composition(name: str, max_chars: int = MAX_COMPOSITION_CHARS,
                      negligible: float = NEGLIGIBLE_COEFFICIENT) -> str:
    """A base parameter's composition ("hy.link1 - 0.0183 m.link2 + …") for a printed line:
    terms below ``negligible`` of the largest coefficient dropped, then cut after
    ``max_chars`` with "… (N more)". report.json keeps the full name."""
    pieces = re.split(r" (?=[+-] )", name)  # "- 1.1e-10 x" splits; the exponent's "-" does not
    coefficients = []
    for piece in pieces:
        m = re.match(r"([+-])?\s*(\d[\d.]*(?:e[+-]?\d+)?)\s+\S", piece)
        coefficients.append(float(m.group(2)) if m else 1.0)
    top = max(coefficients, default=1.0)
    kept = [p for p, c in zip(pieces, coefficients) if c >= negligible * top]
    dropped = len(pieces) - len(kept)
    if kept and kept[0].startswith(("+ ", "- ")):
        kept[0] = kept[0][2:] if kept[0][0] == "+" else "-" + kept[0][2:]
    text, shown = "", 0
    for piece in kept:
        candidate = f"{text} {piece}" if text else piece
        if len(candidate) > max_chars and shown:
            break
        text, shown = candidate, shown + 1
    more = len(kept) - shown + dropped
    return text + (f" … ({more} more)" if more else "")


def whitened(C: np.ndarray, noise_std: np.ndarray) -> np.ndarray:
    """Σ^(-1/2)C: rows of joint j (row index t·n + j) divided by σ_j."""
    n = len(noise_std)
    return C / np.tile(noise_std, C.shape[0] // n)[:, None]


def parameter_covariance(C: np.ndarray, noise_std: np.ndarray, periods: float = 1) -> np.ndarray:
    """Expected covariance of the weighted least-squares base parameters, (CᵀΣ⁻¹C)⁻¹ / P.

    Args:
        C: base regressor of one period, shape (S·n, b), rows sample-major.
        noise_std: σ_j, shape (n,).
        periods: P, the recorded information in units of CᵀΣ⁻¹C (may be fractional).

    Returns shape (b, b), infinite when C is rank deficient.
    """
    s, Vt = singular_values_and_vectors(whitened(C, noise_std), vectors=True)
    if s[-1] <= s[0] * 1e-12:
        return np.full((C.shape[1], C.shape[1]), np.inf)
    return (Vt.T / s**2) @ Vt / periods


def prediction_rms(
    C: np.ndarray, C_ref: np.ndarray, noise_std: np.ndarray, periods: float = 1, row_std: np.ndarray | None = None
) -> tuple[np.ndarray, float]:
    """Expected RMS error of the torques predicted with the identified parameters.

    The error of row c_v is c_v(φ̂ − φ) with variance c_v Cov c_vᵀ (the identified model
    against the true one: the noise of a new measurement is not included).

    Args:
        C: the motion's base regressor of one period, (S·n, b).
        C_ref: the reference motions' base regressor, (S_ref·n, b), rows sample-major.
        noise_std: σ_j, (n,).
        periods: P, as in :func:`parameter_covariance`.
        row_std: σ of the rows of one sample of C (default ``noise_std``; with the ground
            wrench, its six rows' σ follow).

    Returns (per joint, shape (n,); over all joints).
    """
    n = len(noise_std)
    s, Vt = singular_values_and_vectors(whitened(C, noise_std if row_std is None else row_std), vectors=True)
    if s[-1] <= s[0] * 1e-12:
        return np.full(n, np.inf), math.inf
    A = (C_ref @ Vt.T) / s  # C_ref V S⁻¹: row sums of squares are c_v (CᵀΣ⁻¹C)⁻¹ c_vᵀ
    var = np.sum(A**2, axis=1).reshape(-1, n) / periods
    return np.sqrt(var.mean(axis=0)), float(np.sqrt(var.mean()))


def d_efficiency(C: np.ndarray, noise_std: np.ndarray, periods: float = 1) -> float:
    """det(P·CᵀΣ⁻¹C)^(1/2b): the geometric mean of the singular values of √P·Σ^(-1/2)C."""
    s = singular_values_and_vectors(whitened(C, noise_std), vectors=False)[0]
    if s[-1] <= 0:
        return 0.0
    return float(math.sqrt(periods) * np.exp(np.mean(np.log(s))))


def motion_regressor(problem, alpha: np.ndarray, rate_hz: float = DATA_RATE_HZ) -> np.ndarray:
    """Rows of C (the measurement's; columns the base parameters, then the drive terms),
    unweighted, of one period of motion ``alpha`` sampled at ``rate_hz``: shape (S·r, columns)
    with S = round(period·rate_hz) samples, rows sample-major."""
    samples = max(int(round(problem.period * rate_hz)), 1)
    basis = FourierBasis(problem.harmonics, problem.omega, sample_times(problem.period, samples))
    q, v, vd = basis.evaluate_alpha(np.asarray(alpha, float), problem.n)
    rows = problem.rows
    Y = problem.base.reduce(rows.rows(rows.kinematics(q, v, vd), scaled=False))
    if problem.drive.count:  # zero on the wrench rows (drive_columns' rows)
        Y = np.concatenate([Y, drive_columns(v, vd, problem.drive.layout, rows=rows.num_rows)], axis=2)
    return Y.reshape(-1, problem.columns)


def row_noise(problem, noise_std: np.ndarray) -> np.ndarray:
    """σ of the rows of one sample of :func:`motion_regressor`: the joint torques' ``noise_std``
    (n,), then the ground wrench's force and moment σ of the config (3 each), as measured."""
    m = problem.rows.measurement
    parts = [np.asarray(noise_std, float)] if m.torques else []
    if m.wrench:
        parts.append(np.repeat([m.force_std, m.moment_std], 3))
    return np.concatenate(parts)


def torque_rows(problem, q: np.ndarray, v: np.ndarray, vd: np.ndarray) -> np.ndarray:
    """The joint-torque rows of the problem's columns (base parameters, then drive terms) at
    the samples, unweighted: shape (S·n, columns)."""
    Y = problem.base.reduce(problem.model(q, v, vd))
    if problem.drive.count:
        Y = np.concatenate([Y, drive_columns(v, vd, problem.drive.layout)], axis=2)
    return Y.reshape(-1, problem.columns)


def reference_states(robot: Robot, count: int = REFERENCE_MOTIONS, seed: int = REFERENCE_SEED):
    """The fixed reference set: ``count`` random Fourier motions within the robot's limits.

    Motion k draws a, b ~ N(0, 1/k_h²) (k_h = 1..REFERENCE_HARMONICS) from
    ``default_rng([seed, k])`` around the nominal posture, scaled so that the binding limit is
    used to REFERENCE_LIMIT_FRACTION. It depends on the robot only, so two configs of a robot
    are judged on the same motions; the sampled constraints are not imposed.

    Returns (q, v, vd), each (count·REFERENCE_SAMPLES, n).
    """
    omega = 2 * math.pi / REFERENCE_PERIOD_S
    basis = FourierBasis(REFERENCE_HARMONICS, omega, sample_times(REFERENCE_PERIOD_S, REFERENCE_SAMPLES))
    lim, q0 = robot.limits, robot.nominal_posture()
    harm = np.arange(1, REFERENCE_HARMONICS + 1)
    out = []
    for k in range(count):
        rng = np.random.default_rng([seed, k])
        a = rng.normal(size=(robot.n, REFERENCE_HARMONICS)) / harm
        b = rng.normal(size=(robot.n, REFERENCE_HARMONICS)) / harm
        dq, v, vd = basis.q(a, b, np.zeros(robot.n)), basis.v(a, b), basis.vd(a, b)
        room_up = REFERENCE_LIMIT_FRACTION * (lim.q_upper - q0)
        room_lo = REFERENCE_LIMIT_FRACTION * (q0 - lim.q_lower)
        use = max(
            np.max(np.maximum(dq, 0) / room_up),
            np.max(np.maximum(-dq, 0) / room_lo),
            np.max(np.abs(v) / (REFERENCE_LIMIT_FRACTION * lim.v_max)),
            np.max(np.abs(vd) / (REFERENCE_LIMIT_FRACTION * lim.vd_max)),
        )
        out.append((q0 + dq / use, v / use, vd / use))
    return tuple(np.concatenate(parts) for parts in zip(*out))


def reference_regressor(problem) -> np.ndarray:
    """Rows of :func:`reference_states` for the problem's robot, (S_ref·n, columns)."""
    q, v, vd = reference_states(problem.robot)
    return torque_rows(problem, q, v, vd)


def _margin_ok(problem, alpha: np.ndarray, constraints: Sequence) -> bool:
    q, v, vd = problem.constraint_basis.evaluate_alpha(alpha, problem.n)
    lim, tol = problem.robot.limits, 1e-9
    if np.any(q < lim.q_lower - tol) or np.any(q > lim.q_upper + tol):
        return False
    if np.any(np.abs(v) > lim.v_max + tol) or np.any(np.abs(vd) > lim.vd_max + tol):
        return False
    return all(np.min(c.margins(q, v, vd)) >= 0 for c in constraints)


def random_feasible_motions(
    problem, constraints: Sequence = (), count: int = RANDOM_MOTIONS, seed: int = RANDOM_SEED
) -> tuple[list[tuple[int, np.ndarray]], int]:
    """Random motions of the problem's Fourier series that pass the same constraints.

    Draw ``seed + d`` is the optimizer's random start (``problem.initial_guess``) scaled to
    use the binding joint limit fully at the K samples; one that fails a sampled constraint
    is shrunk toward its offsets by RANDOM_SHRINK until it passes, else rejected. At most
    4·count draws are made.

    Returns ([(seed, alpha), ...] of at most ``count`` motions, number of rejected draws).
    """
    found, rejected, n = [], 0, problem.n
    for d in range(4 * count):
        if len(found) == count:
            break
        alpha = np.array(problem.initial_guess(seed + d, amplitude=10.0), float)
        alpha[:-n] /= 0.9  # initial_guess uses 90 % of the binding limit
        for _ in range(RANDOM_SHRINK_STEPS):
            if _margin_ok(problem, alpha, constraints):
                found.append((seed + d, alpha))
                break
            alpha[:-n] *= RANDOM_SHRINK
        else:
            rejected += 1
    return found, rejected


def _figures(label: str, C: np.ndarray, C_ref: np.ndarray, noise: np.ndarray, row_std: np.ndarray,
             periods: float) -> MotionQuality:
    """The figures of one motion: C its measurement rows (σ ``row_std`` per sample), C_ref the
    reference motions' joint-torque rows (σ ``noise`` per joint)."""
    s = singular_values_and_vectors(C, vectors=False)[0]
    rms, total = prediction_rms(C, C_ref, noise, periods, row_std)
    std = np.sqrt(np.maximum(np.diag(parameter_covariance(C, row_std, periods)), 0.0))
    cond = float(s[0] / s[-1]) if s[-1] > 0 else math.inf
    return MotionQuality(label, cond, d_efficiency(C, row_std, periods), std, rms, total)


def excitation_quality(
    problem, alpha: np.ndarray, constraints: Sequence = (), *,
    noise_std: float | Sequence[float] | None = None, periods: int = 1,
    rate_hz: float = DATA_RATE_HZ, random_motions: int = RANDOM_MOTIONS, seed: int = RANDOM_SEED,
    one_blas_thread: bool = True,
) -> QualityReport:
    """The quality figures of motion ``alpha`` and of random motions under the same constraints.

    Args:
        problem: the :class:`~pe_drake.excitation.problem.ExcitationProblem`.
        alpha: the motion's coefficients, shape ((2N+1)·n,).
        constraints: the sampled constraints the random motions must pass (the optimizer's).
        noise_std: σ [N·m], one value or one per joint (default :data:`DEFAULT_NOISE_STD`).
        periods: P, periods to be recorded.
        rate_hz: rate of the fitted samples [Hz].
        random_motions: random motions to compare with (0: none), from draw ``seed``.
        one_blas_thread: run on one BLAS thread (False: BLAS's own threads).

    Raises:
        ConfigError: a bad noise_std, periods or rate.
    """
    # One BLAS thread: OpenBLAS's threads on these few-thousand-row matrices only spin (issue 38).
    with single_threaded_blas() if one_blas_thread else contextlib.nullcontext():
        return _quality(problem, alpha, constraints, noise_std, periods, rate_hz, random_motions, seed)


def _quality(problem, alpha, constraints, noise_std, periods, rate_hz, random_motions, seed) -> QualityReport:
    """:func:`excitation_quality`'s work (its arguments)."""
    noise = noise_vector(noise_std, problem.robot.joint_names)
    if isinstance(periods, bool) or not isinstance(periods, (int, np.integer)) or periods < 1:
        raise ConfigError(f"periods must be a positive integer, got {periods!r}")
    if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and rate_hz > 0):
        raise ConfigError(f"rate_hz must be a positive number [Hz], got {rate_hz!r}")
    C_ref = reference_regressor(problem)
    sample_hz = min(float(rate_hz), SAMPLE_RATE_HZ)
    weight = periods * rate_hz / sample_hz  # periods, in units of the sampled period's information
    C = motion_regressor(problem, alpha, sample_hz)
    row_std = row_noise(problem, noise)
    motion = _figures("optimized", C, C_ref, noise, row_std, weight)
    random, rejected = [], 0
    if random_motions > 0:
        draws, rejected = random_feasible_motions(problem, constraints, random_motions, seed)
        for s, a in draws:
            random.append(_figures(f"random {s}", motion_regressor(problem, a, sample_hz), C_ref, noise, row_std,
                                   weight))
    prior = problem.base.base_values(problem.robot.phi_model)
    floor = PERCENT_FLOOR * float(np.max(np.abs(prior))) if prior.size else 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        percent = np.where(np.abs(prior) > max(floor, 1e-300), 100.0 * motion.std[: prior.size] / np.abs(prior), np.inf)
    best_rms = min((m.prediction_rms_total for m in random), default=math.nan)
    best_d = max((m.d_efficiency for m in random), default=math.nan)
    return QualityReport(
        joints=tuple(problem.robot.joint_names), noise_std=noise, periods=int(periods),
        rate_hz=float(rate_hz), samples_per_period=max(int(round(problem.period * rate_hz)), 1),
        base_names=tuple(problem.base.base_names), prior=prior, std_percent=percent,
        motion=motion, random=random, random_rejected=rejected,
        prediction_ratio=best_rms / motion.prediction_rms_total if random else math.nan,
        d_efficiency_ratio=motion.d_efficiency / best_d if random and best_d > 0 else math.nan,
        drive_names=problem.drive.layout.labels, drive_units=problem.drive.layout.units,
    )
