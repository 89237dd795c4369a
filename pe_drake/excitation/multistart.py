"""Multi-start excitation optimization in parallel worker processes.

The excitation cost is non-convex (cond of Eq. 5 has many local minima), so several random
initial points are solved and the best feasible result is kept. Each start is an
independent IPOPT/NLopt solve, so starts run in separate processes.

Drake plants and contexts cannot be pickled (DRAKE_NOTES.md): every worker process builds its
own robot once, from the parent robot's name and :class:`~pe_drake.config.RobotConfig`, and
receives only configs, seeds, initial points and C0 arrays. The base parameters are computed
once in the parent and sent to the workers, so C0 and every result use the same columns.
Python threads would not help (the GIL is held in Drake's calls); a fork pool of 2 ran 4
tasks 1.9x faster than serial on a 2-core machine.

Processes start with ``fork`` on Linux (cheap) and ``spawn`` elsewhere; with ``spawn`` the
constraint factory must be a module-level function. Workers are daemonic and are terminated
and joined on any error (a worker exception, a worker killed by a signal, Ctrl-C), so no
process outlives the call.

Use it like::

    result = solve_multistart(robot, config.excitation, "ipopt", seeds=[0, 1, 2, 3], workers=2)
    result.best            # the ExcitationResult with the lowest criterion among feasible ones
    for s in result.starts:
        print(s.seed, s.cond, s.wall_time)

or keep one :class:`WorkerPool` open for several calls (:func:`pe_drake.excitation.sequential.optimize_sequence`
does that for its motions).
"""

from __future__ import annotations

import dataclasses
import math
import multiprocessing
import os
import pickle
import queue as queue_module
import sys
import time
import traceback
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from pe_drake.config import ExcitationConfig, SolverConfig
from pe_drake.exceptions import ConfigError, PeDrakeError

#: Builds the sampled constraints (balance, collision, ...) for a robot and an excitation
#: config; e.g. :func:`pe_drake.excitation.constraints.constraints_from_config`.
ConstraintsFactory = Callable[[Any, ExcitationConfig], list]


class WorkerError(PeDrakeError):
    """A worker process failed.

    Attributes:
        task: index of the task that failed, or None when the process died between tasks.
        exception_type: name of the exception raised in the worker (or "" when it died).
        remote_traceback: the worker's formatted traceback (or "").
    """

    def __init__(
        self, message: str, task: int | None = None, exception_type: str = "", remote_traceback: str = ""
    ):
        self.task = task
        self.exception_type = exception_type
        self.remote_traceback = remote_traceback
        super().__init__(message)


class _RemoteTraceback(Exception):
    """Carries a worker's traceback as the cause of a re-raised exception."""

    def __init__(self, tb: str):
        self.tb = tb

    def __str__(self) -> str:
        return "\n" + self.tb


# ---- events and results -------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class StartEvent:
    """Progress of one start, sent to the ``progress`` callback (throttled in the workers).

    Attributes:
        seed: seed of the start.
        kind: "started", "progress" or "finished".
        evaluations: cost evaluations so far.
        value: criterion at the last evaluation (inf before the first).
        best_feasible: best criterion among evaluated points meeting every constraint at the
            samples (inf if none yet).
        violation: worst constraint violation at the last evaluation, in the constraint's unit.
        elapsed: time since the start began [s].
        criterion: "cond", "log_cond" or "dopt".
        label: a tag set by the caller (e.g. "motion 2").
        message: the solver's message ("finished" only).
        origin: where the start began when not at its seed's random point (e.g. "from
            motion 1"); empty otherwise.
    """

    seed: int
    kind: str
    evaluations: int
    value: float
    best_feasible: float
    violation: float
    elapsed: float
    criterion: str = "cond"
    label: str = ""
    message: str = ""
    origin: str = ""

    def __str__(self) -> str:
        tag = f"{self.label} " if self.label else ""
        if self.kind == "started":
            origin = f" ({self.origin})" if self.origin else ""
            return f"  {tag}start seed {self.seed}: started{origin}"
        text = (
            f"  {tag}start seed {self.seed}: eval {self.evaluations:5d}  "
            f"{self.criterion} {self.value:10.5g}  best feasible {self.best_feasible:10.5g}  "
            f"violation {self.violation:8.2e}  {self.elapsed:6.1f} s"
        )
        if self.kind == "finished":
            text += f"  done: {self.message}"
        return text


@dataclasses.dataclass(frozen=True)
class StartSummary:
    """Outcome of one start.

    Attributes:
        seed: its seed.
        success: every constraint holds at 1 kHz (see ExcitationResult.success).
        fun: criterion value at its solution.
        cond: cond(C) at its solution (C includes C0).
        cond_motion: cond of the motion's own regressor.
        nit: solver iterations (None for NLopt).
        nfev: cost evaluations.
        wall_time: time of the solve in its process [s].
        message: the solver's message.
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


@dataclasses.dataclass
class MultiStartResult:
    """Outcome of :func:`solve_multistart`.

    Attributes:
        best: the kept :class:`~pe_drake.excitation.program.ExcitationResult`: the lowest criterion
            among the feasible starts, else the lowest among all (then ``success`` is False).
        seed: seed of ``best``.
        starts: one summary per start, in the order of the seeds.
        results: every start's ExcitationResult, same order (``raw`` is None for results
            computed in a worker process: Drake results cannot be pickled).
        workers: processes used (1: solved in this process).
        start_method: "fork" or "spawn", or "" when solved in this process.
        wall_time: whole call, including worker start-up [s].
    """

    best: Any
    seed: int
    starts: list[StartSummary]
    results: list
    workers: int
    start_method: str
    wall_time: float

    @property
    def success(self) -> bool:
        return bool(self.best.success)

    @property
    def solve_time(self) -> float:
        """Sum of the starts' solve times [s] (what a serial run would roughly take)."""
        return float(sum(s.wall_time for s in self.starts))


# ---- worker state ---------------------------------------------------------------------------------
@dataclasses.dataclass
class _RobotSpec:
    """What a worker needs to rebuild the robot and its regressor (all picklable)."""

    name: str
    config: Any  # RobotConfig
    base: Any  # BaseParameters
    constraints_factory: ConstraintsFactory | None


class _WorkerState:
    """A robot, its regressor model and constraint sets, living in one process."""

    def __init__(
        self,
        robot,
        base,
        constraints_factory: ConstraintsFactory | None,
        emit: Callable[[Any], None],
        model=None,
    ):
        from pe_drake.multibody.regressor import RegressorModel

        self.robot = robot
        self.model = model if model is not None else RegressorModel(robot)
        self.base = base
        self.constraints_factory = constraints_factory
        self.emit = emit
        self.in_worker = False
        self._constraints: dict[str, list] = {}

    def constraints(self, config: ExcitationConfig) -> list:
        """The factory's constraints for ``config``, built once per distinct config."""
        if self.constraints_factory is None:
            return []
        key = repr(config)
        if key not in self._constraints:
            self._constraints[key] = list(self.constraints_factory(self.robot, config))
        return self._constraints[key]

    def problem(self, config: ExcitationConfig, C0: np.ndarray | None):
        from pe_drake.excitation.problem import ExcitationProblem

        return ExcitationProblem(self.robot, config, C0=C0, base=self.base, model=self.model)


def _worker_main(spec: _RobotSpec, tasks, results) -> None:
    """Entry point of a worker process: build the robot, then run tasks until None."""
    import logging

    try:
        import pydrake.common  # noqa: F401  (pydrake resets the logger level at import)

        logging.getLogger("drake").setLevel(logging.ERROR)
        from pe_drake.multibody.robot import Robot

        robot = Robot(spec.name, spec.config)
        state = _WorkerState(
            robot, spec.base, spec.constraints_factory, lambda ev: results.put(("event", None, ev))
        )
        state.in_worker = True
    except BaseException as err:  # report, then let the parent stop the pool
        results.put(("error", None, _pack_error(err)))
        return
    while True:
        item = tasks.get()
        if item is None:
            return
        index, fn, payload = item
        try:
            out = _run_task(state, fn, payload)
        except BaseException as err:
            results.put(("error", index, _pack_error(err)))
            continue
        results.put(("result", index, out))


def _run_task(state: _WorkerState, fn: Callable, payload: Any) -> Any:
    from pe_drake.threads import single_threaded_blas

    # One BLAS thread per process: the matrices are small, and this keeps results identical
    # between the serial and the parallel path.
    with single_threaded_blas():
        return fn(state, payload)


def _pack_error(err: BaseException) -> tuple[Any, str, str]:
    tb = "".join(traceback.format_exception(type(err), err, err.__traceback__))
    try:
        exc = pickle.loads(pickle.dumps(err))
    except Exception:
        exc = None
    return exc, type(err).__name__, tb


def default_start_method() -> str:
    """ "fork" where available and safe (Linux), else "spawn"."""
    methods = multiprocessing.get_all_start_methods()
    return "fork" if sys.platform.startswith("linux") and "fork" in methods else "spawn"


def default_workers() -> int:
    """os.cpu_count() (at least 1)."""
    return max(1, os.cpu_count() or 1)


class WorkerPool:
    """Worker processes that each hold their own copy of a robot.

    With ``workers == 1`` nothing is started: tasks run in this process on the given robot.

    Args:
        robot: the :class:`~pe_drake.multibody.robot.Robot`; workers rebuild it from ``robot.name`` and
            ``robot.config`` (construction hooks of the parent's robot are not reproduced).
        workers: number of processes (default :func:`default_workers`).
        base: the base parameters every task uses (default: computed here once).
        constraints_factory: ``f(robot, excitation_config) -> [SampledConstraint, ...]``
            (default: none); with the "spawn" start method it must be a module-level function.
        start_method: "fork" or "spawn" (default :func:`default_start_method`).

    Raises:
        ConfigError: a worker count below 1 or an unknown start method.
    """

    def __init__(
        self,
        robot,
        workers: int | None = None,
        *,
        base=None,
        constraints_factory: ConstraintsFactory | None = None,
        start_method: str | None = None,
    ):
        from pe_drake.multibody.base_parameters import compute_base_parameters
        from pe_drake.multibody.regressor import RegressorModel

        workers = default_workers() if workers is None else workers
        if not isinstance(workers, int) or workers < 1:
            raise ConfigError(f"workers must be a positive integer, got {workers!r}")
        method = start_method or default_start_method()
        available = multiprocessing.get_all_start_methods()
        if method not in available:
            raise ConfigError(f"start method '{method}' is not available here; valid: {', '.join(available)}")
        self.robot = robot
        self.workers = workers
        self.start_method = method if workers > 1 else ""
        model = RegressorModel(robot)
        self.base = base if base is not None else compute_base_parameters(robot, model=model)
        self.constraints_factory = constraints_factory
        self._local = _WorkerState(robot, self.base, constraints_factory, lambda ev: None, model)
        self._procs: list = []
        self._tasks = self._results = None
        self._next = 0
        self.setup_time = 0.0
        #: processes the last :meth:`map` used (1: it ran in this process).
        self.last_processes = 1

    def problem(self, config: ExcitationConfig, C0: np.ndarray | None = None):
        """An :class:`~pe_drake.excitation.program.ExcitationProblem` on this process's robot, with
        the pool's base parameters."""
        return self._local.problem(config, C0)

    # ---- lifecycle ----------------------------------------------------------------------------
    def _start(self) -> None:
        if self._procs or self.workers == 1:
            return
        begin = time.perf_counter()
        ctx = multiprocessing.get_context(self.start_method)
        self._tasks, self._results = ctx.Queue(), ctx.Queue()
        spec = _RobotSpec(self.robot.name, self.robot.config, self.base, self.constraints_factory)
        for _ in range(self.workers):
            p = ctx.Process(target=_worker_main, args=(spec, self._tasks, self._results), daemon=True)
            p.start()
            self._procs.append(p)
        self.setup_time = time.perf_counter() - begin

    def close(self) -> None:
        """Stops and joins every worker (idempotent)."""
        procs, self._procs = self._procs, []
        if not procs:
            return
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join(timeout=5)
            if p.is_alive():  # pragma: no cover - terminate is normally enough
                p.kill()
                p.join()
        for q in (self._tasks, self._results):
            q.cancel_join_thread()  # never block on data nobody will read
            q.close()
        self._tasks = self._results = None

    def __enter__(self) -> WorkerPool:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):  # pragma: no cover - safety net; close() is the API
        try:
            self.close()
        except Exception:
            pass

    # ---- running tasks -----------------------------------------------------------------------
    def map(
        self, fn: Callable, payloads: Sequence[Any], progress: Callable[[Any], None] | None = None
    ) -> list:
        """``[fn(state, p) for p in payloads]``, spread over the workers.

        ``fn`` must be a module-level function (it is pickled by name); it receives the
        worker's state (``.robot``, ``.model``, ``.base``, ``.constraints(config)``,
        ``.problem(config, C0)``, ``.emit(event)``) and one payload. Events a task emits
        reach ``progress`` in this process.

        Raises:
            WorkerError: a worker died, or a task raised an exception that cannot be re-raised
                here (else that exception is re-raised, with the worker's traceback as cause).
        """
        payloads = list(payloads)
        if not payloads:
            return []
        if self.workers == 1 or (len(payloads) == 1 and not self._procs):
            # One task and no workers running yet: building a robot in a new process
            # would only add time.
            self.last_processes = 1
            self._local.emit = progress or (lambda ev: None)
            return [_run_task(self._local, fn, p) for p in payloads]
        self._start()
        self.last_processes = self.workers
        try:
            return self._map_parallel(fn, payloads, progress)
        except BaseException:
            self.close()  # no half-finished workers left behind on any error (or Ctrl-C)
            raise

    def _map_parallel(self, fn, payloads, progress) -> list:
        first = self._next
        self._next += len(payloads)
        for k, p in enumerate(payloads):
            self._tasks.put((first + k, fn, p))
        out: dict[int, Any] = {}
        while len(out) < len(payloads):
            try:
                kind, index, data = self._results.get(timeout=0.25)
            except queue_module.Empty:
                dead = [p for p in self._procs if not p.is_alive()]
                if dead:
                    codes = ", ".join(str(p.exitcode) for p in dead)
                    raise WorkerError(
                        f"{len(dead)} worker process(es) exited unexpectedly (exit code {codes}) "
                        "while tasks were pending"
                    ) from None
                continue
            if kind == "event":
                if progress is not None:
                    progress(data)
            elif kind == "result":
                out[index - first] = data
            else:
                exc, type_name, tb = data
                task = None if index is None else index - first
                where = "building the robot" if index is None else f"task {task}"
                if exc is not None:
                    raise exc from _RemoteTraceback(tb)
                raise WorkerError(f"worker failed in {where}: {type_name}", task, type_name, tb)
        return [out[k] for k in range(len(payloads))]


# ---- one start ------------------------------------------------------------------------------------
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
    """The program's per-evaluation callback: tracks the best feasible value, emits events."""

    def __init__(self, task: _StartTask, emit: Callable[[Any], None]):
        self.task, self.emit = task, emit
        self.program = None
        self.count = 0
        self.best = math.inf
        self.value = math.inf
        self.violation = 0.0
        self.start = time.perf_counter()
        self.last = self.start

    def event(self, kind: str, message: str = "") -> StartEvent:
        return StartEvent(
            seed=self.task.seed,
            kind=kind,
            evaluations=self.count,
            value=self.value,
            best_feasible=self.best,
            violation=self.violation,
            elapsed=time.perf_counter() - self.start,
            criterion=self.task.config.criterion,
            label=self.task.label,
            message=message,
            origin=self.task.origin,
        )

    def __call__(self, alpha: np.ndarray, value: float) -> None:
        from pe_drake.excitation.limits import joint_limit_violation

        self.count += 1
        self.value = float(value)
        violation = joint_limit_violation(self.program.problem, alpha)
        # The sampled constraints were evaluated at this alpha just before the cost (Drake
        # evaluates constraints and cost together); their last violation is kept there.
        for ev in getattr(self.program, "evaluators", []):
            violation = max(violation, getattr(ev, "last_violation", 0.0))
        self.violation = violation
        if violation < 1e-6:
            self.best = min(self.best, self.value)
        now = time.perf_counter()
        if now - self.last >= self.task.interval:
            self.last = now
            self.emit(self.event("progress"))


def _solve_start(state: _WorkerState, task: _StartTask):
    """Builds and solves one start in the current process."""
    from pe_drake.excitation.program import build_excitation_program
    from pe_drake.excitation.solve import solve_excitation

    problem = state.problem(task.config, task.C0)
    reporter = _Reporter(task, state.emit)
    program = build_excitation_program(problem, state.constraints(task.config), progress=reporter)
    reporter.program = program
    x0 = problem.initial_guess(task.seed, task.amplitude) if task.x0 is None else task.x0
    state.emit(reporter.event("started"))
    result = solve_excitation(program, task.solver, x0)
    state.emit(reporter.event("finished", result.message))
    if state.in_worker:
        result = dataclasses.replace(result, raw=None)  # Drake results cannot be pickled
    return result


def _summary(seed: int, r) -> StartSummary:
    return StartSummary(
        seed,
        bool(r.success),
        float(r.fun),
        float(r.cond),
        float(r.cond_motion),
        r.nit,
        int(r.nfev),
        float(r.wall_time),
        r.message,
    )


def best_index(results: Sequence[Any]) -> int:
    """Index of the result to keep: lowest criterion among successful ones, else among all
    (ties: the first)."""
    feasible = [k for k, r in enumerate(results) if r.success]
    pool = feasible or range(len(results))
    return min(pool, key=lambda k: (results[k].fun if np.isfinite(results[k].fun) else math.inf, k))


def solve_multistart(
    robot,
    config: ExcitationConfig | None = None,
    solver: str | SolverConfig = "ipopt",
    seeds: Sequence[int] = (0, 1),
    *,
    C0: np.ndarray | None = None,
    constraints_factory: ConstraintsFactory | None = None,
    initial_guesses: Sequence[np.ndarray] | None = None,
    amplitude: float | None = None,
    workers: int | None = None,
    pool: WorkerPool | None = None,
    progress: Callable[[StartEvent], None] | None = None,
    progress_interval: float = 2.0,
    label: str = "",
    origins: Sequence[str] | None = None,
) -> MultiStartResult:
    """Solves the excitation problem from several random initial points, keeps the best.

    Args:
        robot: the :class:`~pe_drake.multibody.robot.Robot` (ignored when ``pool`` is given).
        config: the excitation problem (default :class:`ExcitationConfig`).
        solver: "ipopt", "nlopt" or a :class:`SolverConfig`.
        seeds: one start per seed; start k begins at ``problem.initial_guess(seeds[k],
            amplitude)`` unless ``initial_guesses`` is given.
        C0: prior data (Eq. 41), shape (m1, b), in the pool's base parameters.
        constraints_factory: ``f(robot, config) -> [SampledConstraint, ...]``, called once
            per worker (e.g. :func:`pe_drake.excitation.constraints.constraints_from_config`); ignored
            when ``pool`` is given (the pool's factory is used).
        initial_guesses: explicit initial alphas, one per seed; a None entry keeps that
            seed's random point.
        amplitude: scale of the random initial coefficients [rad] (default config.amplitude).
        workers: processes (default os.cpu_count(); capped at the number of seeds).
        pool: an open :class:`WorkerPool` to reuse (its workers keep their robot).
        progress: callback receiving :class:`StartEvent` objects (in this process).
        progress_interval: seconds between "progress" events of a start.
        label: copied into the events (e.g. "motion 2").
        origins: one note per seed saying where an explicit initial guess comes from (e.g.
            "from motion 1"), copied into its events.

    Returns:
        A :class:`MultiStartResult`.

    Raises:
        ConfigError: no seeds, duplicate seeds, or initial guesses that do not match the seeds.
        WorkerError: a worker process failed.
    """
    from pe_drake.config import Config, validate_config

    begin = time.perf_counter()
    config = config or ExcitationConfig()
    solver_cfg = solver if isinstance(solver, SolverConfig) else SolverConfig(name=solver)
    validate_config(Config(excitation=config, solver=solver_cfg))
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ConfigError("multi-start needs at least one seed")
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"multi-start seeds must differ, got {seeds}")
    if initial_guesses is not None and len(initial_guesses) != len(seeds):
        raise ConfigError(f"{len(initial_guesses)} initial guesses for {len(seeds)} seeds")
    if origins is not None and len(origins) != len(seeds):
        raise ConfigError(f"{len(origins)} origins for {len(seeds)} seeds")
    if not progress_interval > 0:
        raise ConfigError(f"progress_interval must be positive [s], got {progress_interval!r}")
    C0 = None if C0 is None else np.asarray(C0, float)
    tasks = [
        _StartTask(
            seed=s,
            config=config,
            solver=solver_cfg,
            C0=C0,
            x0=None if initial_guesses is None or initial_guesses[k] is None else np.asarray(initial_guesses[k], float),
            amplitude=amplitude,
            label=label,
            interval=progress_interval,
            origin="" if origins is None else str(origins[k]),
        )
        for k, s in enumerate(seeds)
    ]
    own = pool is None
    if own:
        n = min(default_workers() if workers is None else workers, len(seeds))
        pool = WorkerPool(robot, n, constraints_factory=constraints_factory)
    try:
        # Validate C0 and the initial guesses here, before any process starts.
        problem = pool.problem(config, C0)
        for t in tasks:
            if t.x0 is not None and t.x0.shape != (problem.num_variables,):
                raise ConfigError(
                    f"initial guess for seed {t.seed} has shape {t.x0.shape}, "
                    f"expected ({problem.num_variables},)"
                )
        results = pool.map(_solve_start, tasks, progress)
    finally:
        if own:
            pool.close()
    k = best_index(results)
    return MultiStartResult(
        best=results[k],
        seed=seeds[k],
        starts=[_summary(s, r) for s, r in zip(seeds, results)],
        results=results,
        workers=pool.last_processes,
        start_method=pool.start_method if pool.last_processes > 1 else "",
        wall_time=time.perf_counter() - begin,
    )
