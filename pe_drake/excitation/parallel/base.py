"""What every executor shares: the worker's state, the task wrapper, errors and events.

An executor runs ``fn(state, payload)`` for many payloads, where ``fn`` is a module-level
function and ``state`` a :class:`WorkerState` built once per worker. Drake plants do not
pickle, so a worker rebuilds the robot from a :class:`RobotSpec`; tasks carry only seeds,
configs, starting points and C0 arrays.

Results come back in payload order; BLAS runs single-threaded in each task, so a task's result
depends only on its payload (on Ray, rarely, to ~5e-10 rad: README, "Running on a cluster").
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import pickle
import tempfile
import time
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pe_drake.config import ExcitationConfig
from pe_drake.exceptions import ConfigError, PeDrakeError
from pe_drake.excitation.problem import ExcitationProblem
from pe_drake.io_utils import atomic_write_text
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.robot import Robot
from pe_drake.threads import single_threaded_blas

#: Builds the sampled constraints (balance, collision, ...) for a robot and an excitation
#: config; e.g. :func:`pe_drake.excitation.constraints.constraints_from_config`.
ConstraintsFactory = Callable[[Any, ExcitationConfig], list]
#: Receives :class:`TaskStarted`, :class:`TaskFinished` and the events tasks emit.
Progress = Callable[[Any], None]


class WorkerError(PeDrakeError):
    """A task failed in a worker, or the worker running it died.

    Attributes:
        task: index of the failed task (the first of ``tasks``, every task that was running),
            or None when a worker failed before running any task.
        exception_type: name of the exception raised in the worker ("" when it died).
        remote_traceback: the worker's formatted traceback ("" when it died).
    """

    def __init__(self, message: str, task: int | None = None, exception_type: str = "",
                 remote_traceback: str = "", tasks: Sequence[int] = ()):
        self.task = task
        self.tasks = tuple(tasks) or (() if task is None else (task,))
        self.exception_type = exception_type
        self.remote_traceback = remote_traceback
        super().__init__(message)


class RemoteTraceback(Exception):
    """Carries a worker's traceback as the cause of a :class:`WorkerError`."""

    def __init__(self, tb: str):
        super().__init__(tb)
        self.tb = tb

    def __str__(self) -> str:
        return "\n" + self.tb


@dataclasses.dataclass(frozen=True)
class TaskStarted:
    """Task ``index`` was handed to a worker."""

    index: int


@dataclasses.dataclass(frozen=True)
class TaskFinished:
    """Task ``index`` finished with ``value``.

    Attributes:
        worker: where it ran ("main", "pid 1234", or "10.0.0.2 pid 1234" on Ray).
        wall_time: its run time in the worker [s].
    """

    index: int
    value: Any
    worker: str
    wall_time: float


@dataclasses.dataclass(frozen=True)
class TaskLost:
    """Task ``index`` was lost with its worker (it died, or hung), for ``reason``; returned
    instead of a :class:`TaskFinished` by ``Executor.map(..., keep_lost=True)``.

    Attributes:
        worker: where it ran ("pid 1234"; "" when it was not known).
        wall_time: from handing it out to declaring it lost [s].
    """

    index: int
    reason: str
    worker: str = ""
    wall_time: float = 0.0


#: Default of ``parallel.hung_after_s``: a start's solver reports progress every few seconds,
#: so ten minutes of silence is a worker stuck, not a slow solve.
HUNG_AFTER_S = 600.0


def check_hung_after(value: Any, name: str = "hung_after_s") -> float:
    """``value`` as seconds without progress after which a worker is declared hung (0: never);
    ConfigError if it is not a finite non-negative number."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0 or value == float("inf"):
        raise ConfigError(f"{name} must be a non-negative number of seconds (0: never), got {value!r}")
    return float(value)


def hung_reason(worker: str, seconds: float, label: str) -> str:
    return f"worker {worker or '(not known)'} gave no progress for {seconds:g} s: declared hung, {label} failed"


class ProgressClock:
    """When each running task last showed progress (handed out, began, emitted an event)."""

    def __init__(self, hung_after_s: float):
        self.hung_after_s = hung_after_s
        self.last: dict[int, float] = {}
        self.began: dict[int, float] = {}

    def start(self, k: int) -> None:
        self.last[k] = self.began[k] = time.monotonic()

    def touch(self, k: int | None) -> None:
        if k in self.last:
            self.last[k] = time.monotonic()

    def stop(self, k: int) -> float:
        """Forgets task ``k``; its time since it was handed out [s]."""
        self.last.pop(k, None)
        return time.monotonic() - self.began.pop(k, time.monotonic())

    def hung(self, running) -> list[int]:
        """The running tasks silent for longer than ``hung_after_s`` (none when it is 0)."""
        if not self.hung_after_s:
            return []
        now = time.monotonic()
        return sorted(k for k in running if now - self.last.get(k, now) > self.hung_after_s)


@dataclasses.dataclass(frozen=True)
class RobotSpec:
    """What a worker needs to rebuild the robot (all picklable).

    Attributes:
        base: the :class:`~pe_drake.multibody.base_parameters.BaseParameters` every task uses
            (computed once in the parent, so C0 and every result use the same columns).
        capsules_text: the capsule file's content (see :meth:`with_capsule_text`), or "".
    """

    name: str
    config: Any
    base: Any
    constraints_factory: ConstraintsFactory | None = None
    capsules_text: str = ""

    def with_capsule_text(self) -> RobotSpec:
        """This spec carrying its capsule file's content, for workers on other machines:
        capsules fitted to the meshes are written to a folder of this machine only."""
        path = Path(self.config.capsules) if self.config.capsules else None
        if path is None or not path.is_file():
            return self
        return dataclasses.replace(self, capsules_text=path.read_text())

    def build(self, emit: Callable[[Any], None] | None = None) -> WorkerState:
        """The robot and its state, built in the calling process."""
        import logging

        import pydrake.common  # noqa: F401  (lazy: pydrake resets the logger level at import)

        logging.getLogger("drake").setLevel(logging.ERROR)
        config = self.config
        path = Path(config.capsules) if config.capsules else None
        if self.capsules_text and not (path.is_file() and path.read_text() == self.capsules_text):
            # Another machine: the file is missing there, or a stale one from an earlier run
            # sits at the same path. One file per content, shared by the node's workers.
            digest = hashlib.sha256(self.capsules_text.encode()).hexdigest()[:16]
            local = Path(tempfile.gettempdir()) / f"pe_drake_capsules_{digest}.yaml"
            # A file found there is used only if it is a regular file (no symlink) holding this
            # very content: on a shared machine another user could plant one that turns the
            # collision check off.
            if local.is_symlink() or not local.is_file() or local.read_text() != self.capsules_text:
                local = Path(tempfile.mkstemp(prefix=f"pe_drake_capsules_{digest}_", suffix=".yaml")[1])
                atomic_write_text(local, self.capsules_text)
            config = dataclasses.replace(config, capsules=str(local))
        return WorkerState(Robot(self.name, config), self.base, self.constraints_factory, emit)


class WorkerState:
    """A robot, its regressor model, the base parameters every task uses and constraint sets,
    living in one process; ``emit`` sends an event to the caller's progress callback."""

    def __init__(self, robot: Robot, base, constraints_factory=None, emit=None, model=None):
        self.robot = robot
        self.model = model if model is not None else RegressorModel(robot)
        self.base = base
        self.constraints_factory = constraints_factory
        self.emit = emit or (lambda event: None)
        self._constraints: dict[str, list] = {}
        self._problems: dict[str, dict] = {}

    def constraints(self, config: ExcitationConfig) -> list:
        """The factory's constraints for ``config``, built once per distinct config."""
        if self.constraints_factory is None:
            return []
        key = repr(config)
        if key not in self._constraints:
            self._constraints[key] = list(self.constraints_factory(self.robot, config))
        return self._constraints[key]

    def problem(self, config: ExcitationConfig, C0: np.ndarray | None = None):
        """The :class:`~pe_drake.excitation.problem.ExcitationProblem` on this robot and base,
        built once per distinct config; other prior data C0 share it
        (:meth:`~pe_drake.excitation.problem.ExcitationProblem.with_prior`)."""
        key = repr(config)
        if key not in self._problems:
            self._problems[key] = {None: ExcitationProblem(self.robot, config, base=self.base, model=self.model)}
        by_prior = self._problems[key]
        digest = None if C0 is None else hashlib.sha256(np.ascontiguousarray(C0, float).tobytes()).hexdigest() + str(np.shape(C0))
        if digest not in by_prior:
            by_prior[digest] = by_prior[None].with_prior(C0)
        return by_prior[digest]


def worker_name(host: str = "") -> str:
    """This process, as reported per task: "pid N", or "<host> pid N" on a cluster node."""
    return f"{host} pid {os.getpid()}" if host else f"pid {os.getpid()}"


def run_task(state: WorkerState, fn: Callable, payload: Any, worker: str) -> tuple:
    """Runs one task in a worker; never raises: returns ("ok", value, worker, wall_time) or
    ("error", exception, type name, traceback, worker)."""
    begin = time.perf_counter()
    try:
        # One BLAS thread: the matrices are small, and a task's result must not depend on
        # how many tasks share the machine.
        with single_threaded_blas():
            value = fn(state, payload)
    except BaseException as err:  # reported to the caller, who stops the other workers
        return ("error", *pack_error(err), worker)
    return ("ok", value, worker, time.perf_counter() - begin)


def pack_error(err: BaseException) -> tuple[Any, str, str]:
    """(the exception if it pickles else None, its type name, its formatted traceback)."""
    tb = "".join(traceback.format_exception(type(err), err, err.__traceback__))
    try:
        exc = pickle.loads(pickle.dumps(err))
    except Exception:
        exc = None
    return exc, type(err).__name__, tb


def task_error(packed: tuple, index: int, label: str) -> WorkerError:
    """A :class:`WorkerError` for a task that raised in a worker, its traceback as the cause."""
    exc, type_name, tb, worker = packed
    text = str(exc) if exc is not None else tb.strip().splitlines()[-1]
    err = WorkerError(f"{label} failed in worker {worker}: {type_name}: {text}", index, type_name, tb)
    err.__cause__ = RemoteTraceback(tb)
    return err


def default_workers() -> int:
    """The cores this process may use (at least 1)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


def check_workers(workers: Any) -> int:
    """``workers`` as a positive int, or ConfigError."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"workers must be a positive integer, got {workers!r}")
    return workers


class Executor:
    """Runs tasks on workers that each hold a robot; a context manager.

    Attributes:
        name: "main" (this process), "local" (a process pool) or "ray".
        local: a :class:`WorkerState` in this process (for building problems here).
        hung_after_s: see :class:`~pe_drake.excitation.parallel.ExecutorOptions`.
    """

    name = "main"

    def __init__(self, local: WorkerState, workers: int, hung_after_s: float = HUNG_AFTER_S):
        self.local = local
        self.base = local.base
        self.workers = workers
        self.hung_after_s = check_hung_after(hung_after_s)

    def problem(self, config: ExcitationConfig, C0: np.ndarray | None = None):
        """An :class:`~pe_drake.excitation.problem.ExcitationProblem` in this process."""
        return self.local.problem(config, C0)

    def map(self, fn: Callable, payloads: Sequence[Any], progress: Progress | None = None,
            labels: Sequence[str] | None = None,
            keep_lost: bool = False) -> list[TaskFinished | TaskLost]:
        """``fn(state, p)`` for every payload, spread over the workers.

        Args:
            fn: a module-level function ``fn(state: WorkerState, payload) -> value``.
            progress: receives :class:`TaskStarted`, :class:`TaskFinished`,
                :class:`TaskLost` and whatever the tasks emit (``state.emit``), in this process.
            labels: names of the tasks in error messages (default "task k").
            keep_lost: a task lost with its worker comes back as a :class:`TaskLost` and the
                other tasks go on (False: :class:`WorkerError`).

        Returns:
            One :class:`TaskFinished` (or :class:`TaskLost`) per payload, in order.

        Raises:
            WorkerError: a task raised, or (unless ``keep_lost``) a worker died or hung; every
                worker is stopped first, as on Ctrl-C.
        """
        raise NotImplementedError

    def close(self) -> None:
        """Stops every worker (idempotent)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class RemoteExecutor(Executor):
    """An executor whose workers live elsewhere (processes, actors): :meth:`map` runs
    :meth:`run` on :meth:`targets` and stops every worker on an error or Ctrl-C."""

    def targets(self):
        """What :meth:`run` sends the tasks to (the pool, the actors), created on first use."""
        raise NotImplementedError

    def run(self, targets, fn, payloads, say, labels, keep_lost) -> list:
        """The tasks on ``targets``, results in payload order (see :meth:`Executor.map`)."""
        raise NotImplementedError

    def terminate(self) -> None:
        """Stops every worker now, running tasks included."""
        raise NotImplementedError

    def map(self, fn, payloads, progress=None, labels=None, keep_lost=False) -> list:
        payloads = list(payloads)
        if not payloads:
            return []
        say = progress or (lambda event: None)
        labels = [f"task {k}" for k in range(len(payloads))] if labels is None else labels
        try:
            return self.run(self.targets(), fn, payloads, say, [str(s) for s in labels], keep_lost)
        except BaseException:
            self.terminate()  # nothing keeps running after an error or Ctrl-C
            raise


class InProcessExecutor(Executor):
    """Runs the tasks one after the other in this process; a task's exception propagates."""

    def __init__(self, local: WorkerState):
        super().__init__(local, 1, 0.0)  # nothing here could stop a task that hangs

    def map(self, fn, payloads, progress=None, labels=None, keep_lost=False) -> list[TaskFinished]:
        say = progress or (lambda event: None)
        self.local.emit = say
        out = []
        for k, payload in enumerate(payloads):
            say(TaskStarted(k))
            begin = time.perf_counter()
            with single_threaded_blas():
                value = fn(self.local, payload)
            done = TaskFinished(k, value, "main", time.perf_counter() - begin)
            say(done)
            out.append(done)
        return out
