"""Executors for many independent solves: this process, a local process pool, or Ray.

Multi-start (:mod:`pe_drake.excitation.multistart`), the sequential motions' starts and the
random baseline's draws all run as tasks ``fn(state, payload)`` on an :class:`Executor` made
by :func:`open_executor`::

    with open_executor(robot, "local", workers=2, constraints_factory=constraints_from_config) as ex:
        done = ex.map(task_function, payloads)     # TaskFinished objects, in payload order
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

from pe_drake.config import EXECUTORS
from pe_drake.exceptions import ConfigError
from pe_drake.excitation.parallel.base import (
    HUNG_AFTER_S,
    ConstraintsFactory,
    Executor,
    InProcessExecutor,
    RobotSpec,
    TaskFinished,
    TaskLost,
    TaskStarted,
    WorkerError,
    WorkerState,
    check_hung_after,
    check_workers,
    default_workers,
)
from pe_drake.excitation.parallel.local import LocalExecutor
from pe_drake.excitation.parallel.ray import RayExecutor, cluster_cpus
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.sensors import measurement_base_parameters

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


__all__ = [
    "HUNG_AFTER_S", "ConstraintsFactory", "Executor", "ExecutorOptions", "InProcessExecutor",
    "LocalExecutor", "RayExecutor", "RobotSpec", "TaskFinished", "TaskLost", "TaskStarted",
    "WorkerError", "WorkerState", "default_workers", "open_executor",
]


@dataclasses.dataclass(frozen=True)
class ExecutorOptions:
    """Where independent solves run (the options of :func:`open_executor` a caller chooses).

    Attributes:
        workers: tasks at once; None: the cores available (the Ray cluster's CPUs), at most the
            tasks.
        executor: "local", "ray", or an open :class:`Executor` to reuse (its workers keep their
            robot, constraints and ``hung_after_s``).
        address: the Ray cluster ("ray" only; "": ``ray.init()``'s default).
        hung_after_s: a task without progress for this long [s] is declared hung, its worker
            stopped; 0: never.
        progress_interval: time between the progress events of a running solve [s].
    """

    workers: int | None = None
    executor: str | Executor = "local"
    address: str = ""
    hung_after_s: float = HUNG_AFTER_S
    progress_interval: float = 2.0


def open_executor(
    robot: Robot, executor: str = "local", workers: int | None = None, *, tasks: int | None = None,
    address: str = "", base=None, measurement: str = "joint_torque",
    constraints_factory: ConstraintsFactory | None = None, start_method: str | None = None,
    hung_after_s: float = HUNG_AFTER_S,
) -> Executor:
    """An executor whose workers each hold a copy of ``robot``.

    Args:
        robot: workers rebuild it from its name and config (hooks of this instance are lost).
        executor: "local" (process pool on this machine) or "ray".
        workers: tasks at once (default: the cores available, or the Ray cluster's CPUs),
            capped at ``tasks``. "local" with one worker runs in this process.
        tasks: the most tasks one :meth:`Executor.map` will get (caps the default workers).
        address: the Ray cluster ("ray" only).
        base: the base parameters every task uses (default: computed here once, for the
            rows of C of ``measurement``).
        constraints_factory: ``f(robot, excitation_config) -> [SampledConstraint, ...]``;
            a module-level function (it is pickled by name).
        start_method: for "local" (default "forkserver" where available, else "spawn").
        hung_after_s: see :class:`ExecutorOptions`; not checked when the tasks run in this
            process (one local worker).

    Raises:
        ConfigError: an unknown executor, bad workers or ``hung_after_s``, more Ray workers than
            the cluster's CPUs, Ray missing or unreachable.
    """
    if executor not in EXECUTORS:
        raise ConfigError(f"executor '{executor}' is not one of {', '.join(EXECUTORS)}")
    check_hung_after(hung_after_s)
    if address and executor != "ray":
        raise ConfigError(f"an address ({address}) is only used by the ray executor, not '{executor}'")
    cores = cluster_cpus(address) if executor == "ray" else default_workers()
    if workers is None:
        workers = cores if tasks is None else max(1, min(cores, tasks))
    check_workers(workers)
    if executor == "ray" and workers > cores:  # an actor without a free CPU would wait forever
        raise ConfigError(f"{workers} Ray workers need {workers} CPUs; the cluster has {cores}: lower workers or add nodes")
    model = RegressorModel(robot)
    if base is None:  # the rows' own base parameters: the torques' would select wrong columns
        base = measurement_base_parameters(robot, measurement, model)
    local = WorkerState(robot, base, constraints_factory, model=model)
    spec = RobotSpec(robot.name, robot.config, base, constraints_factory).with_capsule_text()
    if executor == "ray":
        return RayExecutor(spec, local, workers, address, hung_after_s)
    if workers == 1:
        return InProcessExecutor(local)
    return LocalExecutor(spec, local, workers, start_method, hung_after_s)
