"""Multi-start excitation optimization: many seeded starts, the best feasible one kept.

The criterion is non-convex (cond of Eq. 5 has many local minima), so several random initial
points are solved, each an independent task on an executor (:mod:`pe_drake.excitation.parallel`:
this process, a local process pool, or Ray). Start k's result depends only on its seed, starting
point and C0, so the kept start does not depend on the executor, the workers or the order in
which starts finish. Pass an open executor (``ExecutorOptions(executor=open_executor(...))``) to
reuse its workers over several calls, as :func:`pe_drake.excitation.sequential.optimize_sequence`
does.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from pe_drake.config import Config, ExcitationConfig, SolverConfig, validate_config
from pe_drake.exceptions import ConfigError
from pe_drake.excitation.limits import joint_limit_violation
from pe_drake.excitation.parallel import (
    ConstraintsFactory,
    Executor,
    ExecutorOptions,
    TaskFinished,
    TaskLost,
    TaskStarted,
    WorkerError,
    WorkerState,
    open_executor,
)
from pe_drake.excitation.program import build_excitation_program
from pe_drake.excitation.solve import solve_excitation
from pe_drake.multibody.robot import Robot

__all__ = ["MultiStartOptions", "MultiStartResult", "StartEvent", "StartSummary", "WorkerError",
           "best_index", "solve_multistart"]


@dataclasses.dataclass(frozen=True)
class StartEvent:
    """Progress of one start, sent to the ``progress`` callback.

    "started", "finished" and "failed" (its worker died or hung) come from the caller's
    process; "progress" (every ``progress_interval`` seconds of a solve) from the worker.

    Attributes:
        kind: "started", "progress", "finished" or "failed".
        value: criterion at the last evaluation (inf before the first).
        best_feasible: best criterion among the points checked that meet every constraint at
            the samples ("finished": the result's if it succeeded), else inf.
        violation: worst constraint violation at the last checked point, in its unit.
        elapsed: time since the start began [s].
        label: a tag set by the caller (e.g. "motion 2").
        message: the solver's message ("finished"), why the start failed ("failed").
        origin: where the start began when not at its seed's random point ("from motion 1").
        worker: where it ran ("finished" only; e.g. "pid 1234").
    """

    seed: int
    kind: str
    evaluations: int
    value: float
    best_feasible: float
    violation: float
    elapsed: float
    criterion: str = "soft_cond"
    label: str = ""
    message: str = ""
    origin: str = ""
    worker: str = ""

    def __str__(self) -> str:
        tag = f"{self.label} " if self.label else ""
        if self.kind == "started":
            origin = f" ({self.origin})" if self.origin else ""
            return f"  {tag}start seed {self.seed}: started{origin}"
        if self.kind == "failed":
            return f"  {tag}start seed {self.seed}: FAILED after {self.elapsed:.1f} s: {self.message}"
        text = (
            f"  {tag}start seed {self.seed}: eval {self.evaluations:5d}  "
            f"{self.criterion} {self.value:10.5g}  best feasible {self.best_feasible:10.5g}  "
            f"violation {self.violation:8.2e}  {self.elapsed:6.1f} s"
        )
        if self.kind == "finished":
            text += f"  done ({self.worker}): {self.message}"
        return text


@dataclasses.dataclass(frozen=True)
class StartSummary:
    """Outcome of one start (fields as in :class:`~pe_drake.excitation.solve.ExcitationResult`).

    Attributes:
        wall_time: time of the solve in its worker [s].
        worker: where it ran ("main", "pid 1234", "10.0.0.2 pid 1234").
        task_time: the whole task in its worker (problem, constraints, solve) [s].
        lost: the start has no result: its worker died or hung (``message`` says which).
    """

    seed: int
    success: bool
    fun: float
    cond: float
    cond_motion: float
    nit: int | None
    nfev: int
    wall_time: float
    message: str
    worker: str = "main"
    task_time: float = math.nan
    lost: bool = False


@dataclasses.dataclass
class MultiStartResult:
    """Outcome of :func:`solve_multistart`.

    Attributes:
        best: the kept :class:`~pe_drake.excitation.solve.ExcitationResult` (:func:`best_index`);
            ``seed`` its seed.
        starts: one summary per start, in the order of the seeds.
        results: every start's ExcitationResult, same order (``raw`` is None for results
            computed in a worker); None for a start lost with its worker.
        workers: starts run at once (1: solved one after the other).
        executor: "main" (this process), "local" (process pool) or "ray".
        wall_time: whole call, including worker start-up [s].
    """

    best: Any
    seed: int
    starts: list[StartSummary]
    results: list
    workers: int
    executor: str
    wall_time: float

    @property
    def success(self) -> bool:
        return bool(self.best.success)

    @property
    def solve_time(self) -> float:
        """Sum of the starts' solve times [s] (what a serial run would roughly take)."""
        return float(sum(s.wall_time for s in self.starts))


@dataclasses.dataclass
class _StartTask:
    seed: int
    config: ExcitationConfig
    solver: SolverConfig
    C0: np.ndarray | None
    x0: np.ndarray | None
    amplitude: float | None
    label: str
    interval: float
    origin: str = ""


class _Reporter:
    """The program's per-evaluation callback: emits a "progress" event every interval."""

    def __init__(self, task: _StartTask, emit: Callable[[Any], None]):
        self.task, self.emit = task, emit
        self.program = None
        self.count = 0
        self.best = math.inf
        self.value = math.inf
        self.start = self.last = time.perf_counter()

    def __call__(self, alpha: np.ndarray, value: float) -> None:
        self.count += 1
        self.value = float(value)
        now = time.perf_counter()
        if now - self.last < self.task.interval:
            return
        self.last = now
        violation = _violation(self.program, alpha)  # only here: it costs a constraint evaluation
        if violation < 1e-6:
            self.best = min(self.best, self.value)
        elapsed, task = now - self.start, self.task
        self.emit(_event(task, "progress", self.count, self.value, self.best, violation, elapsed))


def _violation(program, alpha: np.ndarray) -> float:
    """Worst violation of the joint limits and the sampled constraints at the K samples."""
    problem = program.problem
    violation = joint_limit_violation(problem, alpha)
    if program.constraints:
        q, v, vd = problem.constraint_basis.evaluate_alpha(np.asarray(alpha, float), problem.n)
        for c in program.constraints:
            violation = max(violation, float(-np.min(c.margins(q, v, vd))))
    return violation


def _event(task: _StartTask, kind: str, evaluations=0, value=math.inf, best=math.inf, violation=0.0, elapsed=0.0, **kw):
    return StartEvent(
        task.seed, kind, evaluations, value, best, violation, elapsed, task.config.criterion, task.label,
        origin=task.origin, **kw,
    )


def _solve_start(state: WorkerState, task: _StartTask):
    """Builds and solves one start in the current process (an executor task)."""
    problem = state.problem(task.config, task.C0)
    reporter = _Reporter(task, state.emit)
    program = build_excitation_program(problem, state.constraints(task.config), progress=reporter)
    reporter.program = program
    x0 = problem.initial_guess(task.seed, task.amplitude) if task.x0 is None else task.x0
    result = solve_excitation(program, task.solver, x0)
    return dataclasses.replace(result, raw=None)  # Drake results cannot be pickled


def _summary(seed: int, done: TaskFinished | TaskLost) -> StartSummary:
    if isinstance(done, TaskLost):
        return StartSummary(seed, False, math.inf, math.nan, math.nan, None, 0, done.wall_time, done.reason,
                            done.worker, done.wall_time, lost=True)
    r = done.value
    return StartSummary(
        seed, bool(r.success), float(r.fun), float(r.cond), float(r.cond_motion), r.nit, int(r.nfev),
        float(r.wall_time), r.message, done.worker, float(done.wall_time),
    )


def best_index(results: Sequence[Any], criterion: str = "soft_cond") -> int:
    """Index of the result to keep: the best figure among successful ones, else among all
    (ties: the lowest index); None entries (lost starts) are never kept.

    The figure is cond(C) for the cond-like criteria (soft_cond only bounds cond), else the
    criterion itself (``dopt``).

    Raises:
        ValueError: every entry is None.
    """
    kept = [k for k, r in enumerate(results) if r is not None]
    if not kept:
        raise ValueError("no start has a result")
    pool = [k for k in kept if results[k].success] or kept
    by_cond = criterion in ("cond", "soft_cond", "log_cond")

    def figure(k: int) -> float:
        value = results[k].cond if by_cond else results[k].fun
        return value if np.isfinite(value) else math.inf

    return min(pool, key=lambda k: (figure(k), k))


def _make_tasks(o: MultiStartOptions, config, solver_cfg) -> list[_StartTask]:
    """One task per seed; refuses what does not match (before any worker starts)."""
    seeds, initial_guesses, origins = [int(s) for s in o.seeds], o.initial_guesses, o.origins
    interval = o.run.progress_interval
    if not seeds:
        raise ConfigError("multi-start needs at least one seed")
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"multi-start seeds must differ, got {seeds}")
    if initial_guesses is not None and len(initial_guesses) != len(seeds):
        raise ConfigError(f"{len(initial_guesses)} initial guesses for {len(seeds)} seeds")
    if origins is not None and len(origins) != len(seeds):
        raise ConfigError(f"{len(origins)} origins for {len(seeds)} seeds")
    if not interval > 0:
        raise ConfigError(f"progress_interval must be positive [s], got {interval!r}")
    C0 = None if o.C0 is None else np.asarray(o.C0, float)
    guesses = [None] * len(seeds) if initial_guesses is None else initial_guesses
    guesses = [None if x is None else np.asarray(x, float) for x in guesses]
    origins = [""] * len(seeds) if origins is None else [str(x) for x in origins]
    return [
        _StartTask(s, config, solver_cfg, C0, x0, o.amplitude, o.label, interval, origin)
        for s, x0, origin in zip(seeds, guesses, origins)
    ]


def _check_guesses(problem, tasks: list[_StartTask]) -> None:
    for t in tasks:
        if t.x0 is not None and t.x0.shape != (problem.num_variables,):
            raise ConfigError(
                f"initial guess for seed {t.seed} has shape {t.x0.shape}, expected ({problem.num_variables},)"
            )


class _StartProgress:
    """Turns the executor's task events into :class:`StartEvent` objects for ``progress``."""

    def __init__(self, tasks: list[_StartTask], progress: Callable[[StartEvent], None] | None):
        self.tasks, self.progress = tasks, progress

    def __call__(self, event) -> None:
        if self.progress is None:
            return
        if isinstance(event, TaskStarted):
            self.progress(_event(self.tasks[event.index], "started"))
        elif isinstance(event, TaskLost):
            self.progress(_event(self.tasks[event.index], "failed", elapsed=event.wall_time, message=event.reason,
                                 worker=event.worker))
        elif isinstance(event, TaskFinished):
            r = event.value
            best, violation = (float(r.fun), 0.0) if r.success else (math.inf, math.nan)
            task, wall = self.tasks[event.index], float(event.wall_time)
            self.progress(_event(task, "finished", int(r.nfev), float(r.fun), best, violation, wall,
                                 message=r.message, worker=event.worker))
        else:
            self.progress(event)


@dataclasses.dataclass(frozen=True, eq=False)
class MultiStartOptions:
    """The starts of :func:`solve_multistart` and where they run.

    Attributes:
        seeds: one start per seed, from ``problem.initial_guess(seed, amplitude)`` unless
            ``initial_guesses`` (one per seed, None: the seed's random point) says otherwise.
        C0: prior data (Eq. 41), shape (m1, b), in the executor's base parameters.
        constraints_factory: a module-level ``f(robot, config) -> [SampledConstraint, ...]``,
            called once per worker; ignored with an open executor (its factory is used).
        amplitude: scale of the random initial coefficients [rad] (default config.amplitude).
        label: copied into the events (e.g. "motion 2").
        origins: one note per seed on where its initial guess comes from, for its events.
        run: where the starts run (``workers`` capped at the number of seeds).
    """

    seeds: Sequence[int] = (0, 1)
    C0: np.ndarray | None = None
    constraints_factory: ConstraintsFactory | None = None
    initial_guesses: Sequence[np.ndarray | None] | None = None
    amplitude: float | None = None
    label: str = ""
    origins: Sequence[str] | None = None
    run: ExecutorOptions = ExecutorOptions()


def solve_multistart(
    robot: Robot | None,
    config: ExcitationConfig | None = None,
    solver: str | SolverConfig = "ipopt",
    options: MultiStartOptions | None = None,
    *,
    progress: Callable[[StartEvent], None] | None = None,
) -> MultiStartResult:
    """Solves the excitation problem from several initial points, keeps the best.

    A start whose worker dies or hangs fails alone: the others go on, and the best of the
    finished ones is kept (``starts[k].lost``, ``results[k]`` None, a "failed" event).

    Args:
        robot: ignored (may be None) with an open executor in ``options.run``.
        progress: callback receiving :class:`StartEvent` objects (in this process).

    Raises:
        ConfigError: no seeds, duplicate seeds, initial guesses that do not match the seeds,
            an unknown executor, Ray missing.
        WorkerError: a start raised in a worker (``task`` is the start's index in ``seeds``),
            or every start was lost with its worker; every worker was stopped.
    """
    begin = time.perf_counter()
    config = config or ExcitationConfig()
    solver_cfg = solver if isinstance(solver, SolverConfig) else SolverConfig(name=solver)
    validate_config(Config(excitation=config, solver=solver_cfg))
    o = options or MultiStartOptions()
    tasks = _make_tasks(o, config, solver_cfg)
    own, label = not isinstance(o.run.executor, Executor), o.label
    executor = o.run.executor if not own else open_executor(
        robot, o.run.executor, o.run.workers, tasks=len(tasks), address=o.run.address,
        measurement=config.measurement, constraints_factory=o.constraints_factory, hung_after_s=o.run.hung_after_s)
    try:
        _check_guesses(executor.problem(config, tasks[0].C0), tasks)  # C0 is checked here too
        labels = [f"{label + ' ' if label else ''}start {k} (seed {t.seed})" for k, t in enumerate(tasks)]
        done = executor.map(_solve_start, tasks, _StartProgress(tasks, progress), labels, keep_lost=True)
    finally:
        if own:
            executor.close()
    results = [None if isinstance(d, TaskLost) else d.value for d in done]
    if all(r is None for r in results):
        raise WorkerError("every start was lost: " + "; ".join(d.reason for d in done), 0, tasks=range(len(done)))
    k = best_index(results, config.criterion)
    return MultiStartResult(
        best=results[k],
        seed=tasks[k].seed,
        starts=[_summary(t.seed, d) for t, d in zip(tasks, done)],
        results=results,
        workers=min(executor.workers, len(tasks)),
        executor=executor.name,
        wall_time=time.perf_counter() - begin,
    )
