"""The conventional baseline (reference [16], section IV-B, Table II): random feasible motions
and a greedy selection, on the same robot, Fourier series, samples and constraints.

1. Rejection sampling (:func:`generate_candidates`): random coefficients drawn and scaled into
   the joint limits as the optimizer's initial point (:meth:`ExcitationProblem.initial_guess`);
   a draw with a negative margin of any sampled constraint at the K samples is rejected.
2. Greedy selection (:func:`greedy_select`): the lowest cond alone first, then repeatedly the
   candidate that minimizes cond of the concatenated C (Eq. 41).

For C = [C_1; C_2], CᵀC = R_1ᵀR_1 + R_2ᵀR_2, so candidates keep their b×b R factor instead of
their (T·n)×b regressor: the concatenation has the same singular values.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence

import numpy as np
import scipy.linalg

from pe_drake.config import Config, ExcitationConfig, validate_config
from pe_drake.exceptions import ConfigError, InfeasibleError
from pe_drake.excitation.constraints import constraints_from_config
from pe_drake.excitation.constraints.base import state_margins
from pe_drake.excitation.parallel import Executor, ExecutorOptions, TaskFinished, open_executor
from pe_drake.multibody.robot import Robot


@dataclasses.dataclass(frozen=True)
class RandomMotion:
    """One random motion that satisfies every constraint at the K samples.

    Attributes:
        seed: seed of the draw (``problem.initial_guess(seed, amplitude)`` reproduces alpha).
        alpha: its Fourier coefficients, shape ((2N+1)·n,).
        cond: cond of its own base regressor Ŷ_B at the T cost samples.
        margins: minimum margin per constraint at the K samples ("position", "velocity",
            "acceleration" [rad, rad/s, rad/s²] and each sampled constraint in its unit).
    """

    seed: int
    alpha: np.ndarray
    cond: float
    margins: dict[str, float]


@dataclasses.dataclass
class CandidateSet:
    """The accepted random motions and what it took to find them.

    Attributes:
        candidates: accepted motions, in draw order.
        R: their regressors' R factors, shape (M, b, b) (see the module docstring).
        draws: random draws made (accepted + rejected).
        rejected: {reason: count}; the reason is the first constraint a draw violated.
        amplitude: scale of the random coefficients [rad]; ``wall_time`` [s].
        workers: chunks of draws run at once.
    """

    candidates: list[RandomMotion]
    R: np.ndarray
    draws: int
    rejected: dict[str, int]
    amplitude: float
    wall_time: float
    workers: int


@dataclasses.dataclass(frozen=True)
class GreedySelection:
    """A greedy selection (Table II): the candidates' ``indices`` in selection order, cond of
    each alone and of the concatenated C after each (C0 included if given)."""

    indices: list[int]
    cond_each: list[float]
    cond_total: list[float]


@dataclasses.dataclass
class BaselineResult:
    """Outcome of :func:`random_baseline`: the candidates, the greedy selection over them and
    the selected motions in selection order; ``generation_time``, ``selection_time`` [s]."""

    candidate_set: CandidateSet
    selection: GreedySelection
    selected: list[RandomMotion]
    generation_time: float
    selection_time: float

    @property
    def wall_time(self) -> float:
        return self.generation_time + self.selection_time


@dataclasses.dataclass(frozen=True)
class DrawEvent:
    """Progress of :func:`generate_candidates` after each chunk of draws (``elapsed`` [s])."""

    drawn: int
    accepted: int
    wanted: int
    elapsed: float

    def __str__(self) -> str:
        rate = self.accepted / self.drawn if self.drawn else 0.0
        return (f"  random candidates: {self.accepted} accepted of {self.drawn} drawn "
                f"({100 * rate:.0f} %, {self.wanted} wanted)  {self.elapsed:6.1f} s")


def _cond(s: np.ndarray) -> float:
    return float(s[0] / s[-1]) if s[-1] > 0 else math.inf


def _r_factor(block: np.ndarray) -> np.ndarray:
    """An upper-triangular factor with the singular values of ``block`` (itself if short)."""
    block = np.asarray(block, float)
    if block.shape[0] <= block.shape[1]:
        return block
    return scipy.linalg.qr(block, mode="r", check_finite=False)[0][: block.shape[1]]


def greedy_select(blocks: Sequence[np.ndarray], motions: int, C0: np.ndarray | None = None) -> GreedySelection:
    """Greedy choice of ``motions`` blocks minimizing cond of their concatenation.

    The first pick has the lowest cond alone (or, with ``C0``, the lowest cond of [C0; block]);
    each next pick minimizes cond of [C0; picks so far; block]. Ties go to the lower index.

    Args:
        blocks: candidate regressors (or their R factors), each (m_i, b).
        C0: prior data, shape (m0, b), or None.

    Raises:
        ConfigError: fewer blocks than motions, motions below 1, or column counts that differ.
    """
    if not isinstance(motions, int) or motions < 1:
        raise ConfigError(f"motions must be a positive integer, got {motions!r}")
    if len(blocks) < motions:
        raise ConfigError(f"cannot select {motions} motions from {len(blocks)} candidates")
    R = [_r_factor(b) for b in blocks]
    b = R[0].shape[1]
    if any(r.shape[1] != b for r in R) or (C0 is not None and np.shape(C0)[1] != b):
        raise ConfigError("every block (and C0) must have the same number of columns")
    alone = [_cond(np.linalg.svd(r, compute_uv=False)) for r in R]
    current = None if C0 is None else _r_factor(C0)
    chosen: list[int] = []
    totals: list[float] = []
    for _ in range(motions):
        best, best_cond = -1, math.inf
        for k, r in enumerate(R):
            if k in chosen:
                continue
            stack = r if current is None else np.vstack([current, r])
            c = _cond(np.linalg.svd(stack, compute_uv=False))
            if best < 0 or c < best_cond:
                best, best_cond = k, c
        chosen.append(best)
        totals.append(best_cond)
        stack = R[best] if current is None else np.vstack([current, R[best]])
        current = _r_factor(stack)
    return GreedySelection(chosen, [alone[k] for k in chosen], totals)


def _draw(
    problem, constraints, seed: int, amplitude: float
) -> tuple[str, RandomMotion | None, np.ndarray | None]:
    """One draw: ("", candidate, R) if accepted, else (reason, None, None)."""
    alpha = problem.initial_guess(seed, amplitude)
    q, v, vd = problem.constraint_basis.evaluate_alpha(alpha, problem.n)
    margins = state_margins(problem.robot.limits, (), q, v, vd)
    if min(margins.values()) < 0:
        return "joint limits", None, None
    for c in constraints:  # in order: a violated one stops the checks (cheap ones first)
        margins[c.name] = float(np.min(c.margins(q, v, vd)))
        if margins[c.name] < 0:
            return c.name, None, None
    R = _r_factor(problem.regressor_block(alpha))
    return "", RandomMotion(int(seed), alpha, _cond(np.linalg.svd(R, compute_uv=False)), margins), R


@dataclasses.dataclass
class _DrawChunk:
    config: ExcitationConfig
    seeds: list[int]
    amplitude: float


def _draw_chunk(state, chunk: _DrawChunk) -> list[tuple[str, RandomMotion | None, np.ndarray | None]]:
    """Executor task: a chunk of draws (see :mod:`pe_drake.excitation.parallel`)."""
    problem = state.problem(chunk.config, None)
    constraints = state.constraints(chunk.config)
    return [_draw(problem, constraints, s, chunk.amplitude) for s in chunk.seeds]


class _DrawProgress:
    """Counts draws as chunks finish; sends :class:`DrawEvent` objects to ``progress``."""

    def __init__(self, wanted: int, begin: float, progress: Callable[[DrawEvent], None] | None):
        self.wanted, self.begin, self.progress = wanted, begin, progress
        self.drawn = self.accepted = 0

    def __call__(self, event) -> None:
        if isinstance(event, TaskFinished):
            self.drawn += len(event.value)
            self.accepted += sum(1 for reason, _, _ in event.value if not reason)
            if self.progress is not None:
                self.progress(DrawEvent(self.drawn, self.accepted, self.wanted, time.perf_counter() - self.begin))


def _draw_rounds(executor: Executor, config, count, seed, amplitude, max_draws, chunk_size, on_event) -> list:
    """Draws in rounds until ``count`` are accepted or ``max_draws`` are made; outcomes in draw
    order (draw d has seed ``seed + d`` whatever chunk or worker runs it)."""
    outcomes: list = []
    next_draw = 0
    while next_draw < max_draws:
        accepted = sum(1 for reason, _, _ in outcomes if not reason)
        if accepted >= count:
            break
        # Enough draws for the rest at the acceptance seen so far (all at once at first).
        rate = accepted / len(outcomes) if outcomes else 1.0
        size = math.ceil(1.1 * (count - accepted) / max(rate, 0.02))
        size = min(max(size, executor.workers * chunk_size), max_draws - next_draw)
        seeds = [seed + d for d in range(next_draw, next_draw + size)]
        chunks = [_DrawChunk(config, seeds[k : k + chunk_size], amplitude) for k in range(0, len(seeds), chunk_size)]
        labels = [f"draws from seed {c.seeds[0]}" for c in chunks]
        for finished in executor.map(_draw_chunk, chunks, on_event, labels):
            outcomes.extend(finished.value)
        next_draw += size
    return outcomes


def generate_candidates(
    robot: Robot, config: ExcitationConfig | None = None, count: int = 200, *,
    constraints_factory: Callable | None = None, seed: int = 0, amplitude: float | None = None,
    max_draws: int | None = None, workers: int = 1, executor: str | Executor = "local",
    address: str = "", progress: Callable[[DrawEvent], None] | None = None, chunk_size: int = 16,
) -> CandidateSet:
    """Random motions satisfying every constraint at the K samples (rejection sampling).

    Draw d uses seed ``seed + d``; accepted draws are kept in draw order and the first
    ``count`` are returned, so the set does not depend on ``workers``.

    Args:
        robot: the :class:`~pe_drake.multibody.robot.Robot` (ignored with an open executor).
        config: N, ω, T, K and the amplitude (default :class:`ExcitationConfig`).
        constraints_factory: ``f(robot, config) -> [SampledConstraint, ...]`` (default
            :func:`pe_drake.excitation.constraints.constraints_from_config`); ignored with an
            open executor.
        amplitude: scale of the random coefficients [rad] (default ``config.amplitude``).
        max_draws: give up after this many draws (default 50 × count).
        workers, executor, address: see :class:`~pe_drake.excitation.parallel.ExecutorOptions`.
        chunk_size: draws per task sent to a worker.

    Raises:
        ConfigError: a count, amplitude, max_draws or chunk size that is not positive.
        InfeasibleError: fewer than ``count`` draws accepted within ``max_draws``.
    """
    begin = time.perf_counter()
    config = config or ExcitationConfig()
    validate_config(Config(excitation=config))
    amplitude = config.amplitude if amplitude is None else amplitude
    max_draws = 50 * count if max_draws is None else max_draws
    for name, value in (("count", count), ("max_draws", max_draws), ("chunk_size", chunk_size)):
        if not isinstance(value, int) or value < 1:
            raise ConfigError(f"{name} must be a positive integer, got {value!r}")
    if not isinstance(amplitude, (int, float)) or not math.isfinite(amplitude) or amplitude <= 0:
        raise ConfigError(f"amplitude must be a positive number [rad], got {amplitude!r}")
    own = not isinstance(executor, Executor)
    if own:
        executor = open_executor(robot, executor, workers, address=address,
                                 measurement=config.measurement,
                                 constraints_factory=constraints_factory or constraints_from_config)
    try:
        on_event = _DrawProgress(count, begin, progress)
        outcomes = _draw_rounds(executor, config, count, seed, float(amplitude), max_draws,
                                chunk_size, on_event)
    finally:
        if own:
            executor.close()
    kept, R, rejected, draws = [], [], {}, 0
    for reason, cand, r in outcomes:
        if len(kept) == count:
            break
        draws += 1
        if reason:
            rejected[reason] = rejected.get(reason, 0) + 1
        else:
            kept.append(cand)
            R.append(r)
    if len(kept) < count:
        raise InfeasibleError(
            f"only {len(kept)} of {draws} random draws met every constraint (wanted {count}; rejected: "
            + ", ".join(f"{k} {v}" for k, v in rejected.items())
            + f"); lower the amplitude ({amplitude} rad), raise max_draws, or loosen the constraints"
        )
    return CandidateSet(kept, np.array(R), draws, rejected, float(amplitude), time.perf_counter() - begin, executor.workers)


@dataclasses.dataclass(frozen=True, eq=False)
class BaselineOptions:
    """The random baseline's draws, its selection and where the draws run.

    Attributes:
        motions: how many motions to select (the paper: 3) from ``candidates`` accepted ones.
        C0: prior data the selection starts from, shape (m0, b), or None.
        constraints_factory, seed, amplitude, max_draws: see :func:`generate_candidates`.
        run: where the draws run (``workers``, ``executor``, ``address``).
    """

    motions: int = 3
    candidates: int = 200
    C0: np.ndarray | None = None
    constraints_factory: Callable | None = None
    seed: int = 0
    amplitude: float | None = None
    max_draws: int | None = None
    run: ExecutorOptions = ExecutorOptions(workers=1)


def random_baseline(robot: Robot | None, config: ExcitationConfig | None = None,
                    options: BaselineOptions | None = None, *,
                    progress: Callable[[DrawEvent], None] | None = None) -> BaselineResult:
    """Random feasible candidates (:func:`generate_candidates`), then the greedy selection."""
    o = options or BaselineOptions()
    motions, candidates = o.motions, o.candidates
    if not isinstance(motions, int) or motions < 1:
        raise ConfigError(f"motions must be a positive integer, got {motions!r}")
    if isinstance(candidates, int) and candidates < motions:
        raise ConfigError(f"{candidates} candidates cannot supply {motions} motions")
    cset = generate_candidates(
        robot, config, candidates, constraints_factory=o.constraints_factory, seed=o.seed, amplitude=o.amplitude,
        max_draws=o.max_draws, workers=o.run.workers, executor=o.run.executor, address=o.run.address, progress=progress,
    )
    begin = time.perf_counter()
    selection = greedy_select(list(cset.R), motions, o.C0)
    return BaselineResult(cset, selection, [cset.candidates[k] for k in selection.indices],
                          cset.wall_time, time.perf_counter() - begin)
