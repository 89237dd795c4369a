"""Sequential generation of exciting motions (paper, section IV-B, Table I).

Motion 1 is optimized without prior data (C0 = O in Eq. 41); motion i > 1 with the regressors
of the motions before it as prior data, C0 = [C^(1); ...; C^(i-1)] (C^(i): Ŷ_B of motion i at
the T cost samples), so each motion excites what the earlier ones left poorly excited. Each
motion's seeded starts run on an executor (:mod:`pe_drake.excitation.multistart`) and the best
feasible one is kept.

Warm start (on by default): the last start of motion i > 1 begins from the earlier motion whose
coefficients give the lowest criterion with the current prior, so a motion is never worse than
repeating an earlier one.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from pe_drake.config import ExcitationConfig, SolverConfig
from pe_drake.exceptions import ConfigError, NoSolutionFound
from pe_drake.excitation.constraints import constraints_from_config
from pe_drake.excitation.multistart import MultiStartOptions, solve_multistart
from pe_drake.excitation.parallel import Executor, ExecutorOptions, open_executor
from pe_drake.multibody.robot import Robot

#: Seeds of motion i (1-based) are ``seed + SEED_STRIDE·(i-1) + s`` for start s = 0, 1, ...:
#: fresh for every motion, and the same for motion i whatever the number of starts.
SEED_STRIDE = 1000


@dataclasses.dataclass
class SequenceMotion:
    """One motion of the sequence (a column of Table I).

    Attributes:
        index: i, from 1.
        result: the kept :class:`~pe_drake.excitation.solve.ExcitationResult` (``cond`` is that of
            [C0; C^(i)]).
        block: C^(i), this motion's base regressor at the T cost samples, shape (T·n, b).
        cond_motion: cond(C^(i)), the motion alone (Table I, first row).
        cond_total: cond of the concatenated C = [prior C0; C^(1); ...; C^(i)] (second row).
        seed: seed of the kept start (``seeds``: of every start).
        starts: one :class:`~pe_drake.excitation.multistart.StartSummary` per start.
        wall_time: time spent on this motion, all starts included [s].
    """

    index: int
    result: Any
    block: np.ndarray
    cond_motion: float
    cond_total: float
    seed: int
    seeds: list[int]
    starts: list
    wall_time: float

    @property
    def success(self) -> bool:
        return bool(self.result.success)


@dataclasses.dataclass
class SequenceResult:
    """Outcome of :func:`optimize_sequence`.

    Attributes:
        C: the concatenated regressor [prior C0; C^(1); ...], shape (m, b).
        base: the :class:`~pe_drake.multibody.base_parameters.BaseParameters` the columns follow.
        workers: starts run at once per motion; ``wall_time``: whole run [s].
    """

    motions: list[SequenceMotion]
    C: np.ndarray
    cond: float
    base: Any
    workers: int
    wall_time: float

    @property
    def success(self) -> bool:
        """Every motion holds every constraint (at 1 kHz)."""
        return bool(self.motions) and all(m.success for m in self.motions)


@dataclasses.dataclass(frozen=True)
class MotionEvent:
    """Sent to ``progress`` when motion ``index`` (from 1) of ``motions`` is "started" or
    "finished" (then with its :class:`SequenceMotion`)."""

    index: int
    motions: int
    kind: str
    seeds: tuple[int, ...]
    motion: SequenceMotion | None = None

    def __str__(self) -> str:
        if self.kind == "started":
            seeds = ", ".join(str(s) for s in self.seeds)
            return f"motion {self.index}/{self.motions}: {len(self.seeds)} start(s), seeds {seeds}"
        m = self.motion
        return (f"motion {self.index}/{self.motions} {'ok' if m.success else 'FAILED'}: "
                f"cond(C^({m.index})) {m.cond_motion:.4g}, cond(C) {m.cond_total:.4g}, "
                f"seed {m.seed}, {m.wall_time:.1f} s; {m.result.message}")


def motion_seeds(seed: int, motion: int, starts: int) -> list[int]:
    """Seeds of the starts of motion ``motion`` (from 1); see :data:`SEED_STRIDE`."""
    return [seed + SEED_STRIDE * (motion - 1) + s for s in range(starts)]


def _cond(C: np.ndarray) -> float:
    s = np.linalg.svd(C, compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else math.inf


@dataclasses.dataclass(frozen=True, eq=False)
class SequenceOptions:
    """The motions of :func:`optimize_sequence`, their starts and where they run.

    Attributes:
        motions: number of motions (the paper: 3).
        starts: random initial points per motion; the best feasible one is kept.
        seed: first seed (default ``config.seed``); see :func:`motion_seeds`.
        seeds: explicit seeds, one list per motion (overrides ``seed`` and ``starts``).
        C0: prior data from earlier experiments, shape (m0, b), or None (the paper: O).
        constraints_factory: ``f(robot, config) -> [SampledConstraint, ...]``, a module-level
            function (default :func:`~pe_drake.excitation.constraints.constraints_from_config`);
            ignored with an open executor.
        amplitude: scale of the random initial coefficients [rad] (default ``config.amplitude``).
        stop_on_failure: raise when a motion has no feasible start (else keep its best one).
        warm_start: the last start of motion i > 1 begins from the best earlier motion (its
            seed stays its label); with one start, motion 2 without prior data adds it as a
            second start (seed + 1) beside the random one.
        run: where the starts run (:class:`~pe_drake.excitation.parallel.ExecutorOptions`;
            ``workers`` capped at the starts per motion).
    """

    motions: int = 3
    starts: int = 1
    seed: int | None = None
    seeds: Sequence[Sequence[int]] | None = None
    C0: np.ndarray | None = None
    constraints_factory: Callable | None = None
    amplitude: float | None = None
    stop_on_failure: bool = True
    warm_start: bool = True
    run: ExecutorOptions = ExecutorOptions()


def optimize_sequence(
    robot: Robot | None, config: ExcitationConfig | None = None,
    solver: str | SolverConfig = "ipopt", options: SequenceOptions | None = None, *,
    progress: Callable[[Any], None] | None = None,
) -> SequenceResult:
    """Optimizes ``options.motions`` exciting motions one after the other (module docstring).

    Args:
        robot: ignored, may be None, with an open executor in ``options.run``.
        solver: "ipopt", "nlopt" or a :class:`SolverConfig`.
        progress: callback receiving :class:`MotionEvent` and
            :class:`~pe_drake.excitation.multistart.StartEvent` objects.

    Raises:
        ConfigError: a motion or start count below 1, seeds that do not match ``motions``,
            or a C0 with the wrong number of columns.
        NoSolutionFound: a motion has no feasible start (with ``stop_on_failure``); its
            ``result`` is the :class:`SequenceResult` so far, the failed motion included.
        WorkerError: a start failed in a worker, or its worker died.
    """
    begin = time.perf_counter()
    config = config or ExcitationConfig()
    o = options or SequenceOptions()
    motions, seeds = o.motions, _sequence_seeds(config, o.motions, o.starts, o.seed, o.seeds)
    own = not isinstance(o.run.executor, Executor)
    executor = o.run.executor if not own else open_executor(
        robot, o.run.executor, o.run.workers, tasks=max(len(row) for row in seeds), address=o.run.address,
        measurement=config.measurement, constraints_factory=o.constraints_factory or constraints_from_config,
        hung_after_s=o.run.hung_after_s)
    try:
        prior = _prior(o.C0, executor.problem(config).columns)  # base parameters and drive terms
        run = _SequenceRun(executor, config, solver, prior, progress or (lambda event: None))
        for i in range(1, motions + 1):
            motion = run.motion(i, motions, seeds[i - 1], o.amplitude, o.run.progress_interval, o.warm_start)
            if o.stop_on_failure and not motion.success:
                raise NoSolutionFound(
                    f"motion {i}: none of the {len(seeds[i - 1])} start(s) met every constraint "
                    f"({motion.result.message}); try more starts, more iterations or other seeds",
                    result=run.result(begin),
                )
    finally:
        if own:
            executor.close()
    return run.result(begin)


def _sequence_seeds(config, motions, starts, seed, seeds) -> list[list[int]]:
    for name, value in (("motions", motions), ("starts", starts)):
        if not isinstance(value, int) or value < 1:
            raise ConfigError(f"{name} must be a positive integer, got {value!r}")
    if seeds is not None:
        seeds = [[int(s) for s in row] for row in seeds]
        if len(seeds) != motions or any(not row for row in seeds):
            raise ConfigError(f"seeds must give a non-empty list for each of the {motions} motions")
        return seeds
    first = config.seed if seed is None else int(seed)
    return [motion_seeds(first, i, starts) for i in range(1, motions + 1)]


def _prior(C0, count: int) -> np.ndarray | None:
    if C0 is None:
        return None
    prior = np.asarray(C0, float)
    if prior.ndim != 2 or prior.shape[1] != count:
        raise ConfigError(
            f"prior data C0 has shape {prior.shape}; it needs {count} columns (the robot's base parameters and "
            "the excitation's drive terms)"
        )
    return prior


class _SequenceRun:
    """The motions so far and how to add the next one."""

    def __init__(self, executor: Executor, config, solver, prior, say):
        self.executor, self.config, self.solver, self.prior, self.say = executor, config, solver, prior, say
        self.blocks: list[np.ndarray] = []
        self.done: list[SequenceMotion] = []
        self.used = 1

    def result(self, begin: float) -> SequenceResult:
        C = np.vstack(([self.prior] if self.prior is not None else []) + self.blocks)
        return SequenceResult(self.done, C, _cond(C), self.executor.base, self.used, time.perf_counter() - begin)

    def _warm_start(self, C0_i, count: int):
        """Initial guesses and their origins: the last start from the best earlier motion."""
        if not self.done:
            return None, None
        current = self.executor.problem(self.config, C0_i)
        values = [current.value(m.result.x) for m in self.done]
        j = int(np.argmin(values))
        guesses = [None] * (count - 1) + [self.done[j].result.x]
        origins = [""] * (count - 1) + [f"from motion {j + 1}, {self.config.criterion} {values[j]:.5g}"]
        return guesses, origins

    def motion(self, i, motions, seeds, amplitude, interval, warm_start) -> SequenceMotion:
        start = time.perf_counter()
        self.say(MotionEvent(i, motions, "started", tuple(seeds)))
        parts = ([self.prior] if self.prior is not None else []) + self.blocks
        C0_i = np.vstack(parts) if parts else None  # Eq. (41): [C^(1); ...; C^(i-1)]
        if warm_start and len(seeds) == 1 and len(parts) == 1 and self.done:
            # Motion 2's prior is motion 1 alone: repeating it is a stationary point of the
            # stacked criterion (cond([C; C]) = cond(C)), so a lone warm start would end where it
            # began. The seed's random start is solved too, beside it.
            seeds = [seeds[0], seeds[0] + 1]
        guesses, origins = self._warm_start(C0_i, len(seeds)) if warm_start else (None, None)
        ms = solve_multistart(None, self.config, self.solver, MultiStartOptions(
            seeds, C0=C0_i, initial_guesses=guesses, amplitude=amplitude, label=f"motion {i}", origins=origins,
            run=ExecutorOptions(executor=self.executor, progress_interval=interval)), progress=self.say)
        self.used = max(self.used, ms.workers)
        block = self.executor.problem(self.config).regressor_block(ms.best.x)
        total = block if C0_i is None else np.vstack([C0_i, block])
        motion = SequenceMotion(i, ms.best, block, _cond(block), _cond(total), ms.seed, list(seeds),
                                ms.starts, time.perf_counter() - start)
        self.blocks.append(block)
        self.done.append(motion)
        self.say(MotionEvent(i, motions, "finished", tuple(seeds), motion))
        return motion
