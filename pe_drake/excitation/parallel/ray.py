"""The Ray executor: the same tasks on a Ray cluster (one machine or many).

One actor per worker holds its robot (Drake plants do not pickle), built once from the
:class:`~pe_drake.excitation.parallel.base.RobotSpec`; tasks send it a module-level function
and a payload (seeds, configs, starting points, C0) and get the value back. At most one task
per actor is in flight, so a dead actor names the task it ran. Events the tasks emit
(per-evaluation progress) stay in the worker; the caller sees each task start and finish.

``ray`` is imported lazily (an optional extra: ``pip install "pe_drake[ray]"``). Without an
address, ``ray.init()`` starts a local instance or joins the cluster started on this machine
with ``ray start``; with one, it joins that cluster. Every node needs pe_drake installed
(same version) in the Python that runs Ray.
"""

from __future__ import annotations

from typing import Any

from pe_drake.exceptions import ConfigError
from pe_drake.excitation.parallel.base import (
    RemoteExecutor,
    RobotSpec,
    TaskFinished,
    TaskStarted,
    WorkerError,
    WorkerState,
    run_task,
    task_error,
    worker_name,
)
from pe_drake.excitation.solver_logs import remove_orphaned_log_folders


def import_ray():
    """The ``ray`` module.

    Raises:
        ConfigError: Ray is not installed (with the command that installs it).
    """
    try:
        import ray  # lazy: an optional, heavy package
    except ImportError as err:
        raise ConfigError(
            'the "ray" executor needs Ray: pip install "pe_drake[ray]" (or pip install ray)'
        ) from err
    return ray


class RobotActor:
    """A Ray actor's body: one robot, tasks run one at a time."""

    def __init__(self, spec: RobotSpec):
        import ray

        self.state = spec.build()
        self.worker = worker_name(ray.util.get_node_ip_address())

    def run(self, fn, payload) -> tuple:
        return run_task(self.state, fn, payload, self.worker)

    def pid(self) -> int:
        import os

        return os.getpid()


def cluster_cpus(address: str = "") -> int:
    """CPUs of the Ray cluster (connecting to it, or starting a local one, if needed)."""
    ray = import_ray()
    connect(address)
    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def connect(address: str = "") -> bool:
    """``ray.init(address)`` unless Ray is already initialized; True if it was called here."""
    ray = import_ray()
    if ray.is_initialized():
        return False
    try:
        ray.init(address=address or None, logging_level="warning", log_to_driver=False)
    except (ConnectionError, RuntimeError, ValueError) as err:
        raise ConfigError(f"cannot connect to Ray at '{address or 'auto/local'}': {err}") from err
    return True


class RayExecutor(RemoteExecutor):
    """One Ray actor per worker, each holding its robot (created at the first :meth:`map`).

    Args:
        spec: what each actor builds.
        local: the parent's :class:`~pe_drake.excitation.parallel.base.WorkerState`.
        workers: actors (each reserves one CPU of the cluster).
        address: the cluster's address ("" : ``ray.init()``'s default, see the module docstring).

    Raises:
        ConfigError: Ray is missing, or the cluster cannot be reached.
    """

    name = "ray"

    def __init__(self, spec: RobotSpec, local: WorkerState, workers: int, address: str = ""):
        super().__init__(local, workers)
        self._ray = import_ray()
        self._own = connect(address)
        self.address = address
        self._spec = spec
        self._actors: list = []

    def targets(self) -> list:
        """The actors (created on first use)."""
        if not self._actors:
            cls = self._ray.remote(num_cpus=1, max_restarts=0)(RobotActor)
            self._actors = [cls.remote(self._spec) for _ in range(self.workers)]
        return self._actors


    def run(self, actors, fn, payloads, say, labels) -> list[TaskFinished]:
        ray = self._ray
        out: dict[int, TaskFinished] = {}
        running: dict[Any, tuple[int, Any]] = {}  # object ref -> (task index, actor)
        pending = iter(range(len(payloads)))

        def submit_next(actor) -> None:
            k = next(pending, None)
            if k is not None:
                running[actor.run.remote(fn, payloads[k])] = (k, actor)
                say(TaskStarted(k))

        for actor in actors:
            submit_next(actor)
        while running:
            # A short timeout keeps Ctrl-C responsive.
            ready, _ = ray.wait(list(running), num_returns=1, timeout=0.2)
            for ref in ready:
                k, actor = running.pop(ref)
                try:
                    packed = ray.get(ref)
                except ray.exceptions.RayActorError as err:
                    raise WorkerError(f"the Ray worker running {labels[k]} died: {err}", k) from err
                except ray.exceptions.RayError as err:
                    raise WorkerError(f"Ray could not run {labels[k]}: {err}", k) from err
                if packed[0] == "error":
                    raise task_error(packed[1:], k, labels[k])
                out[k] = TaskFinished(k, packed[1], packed[2], packed[3])
                say(out[k])
                submit_next(actor)
        return [out[k] for k in range(len(payloads))]

    def terminate(self) -> None:
        """Kills every actor now, with the task it runs (idempotent)."""
        actors, self._actors = self._actors, []
        for actor in actors:
            self._ray.kill(actor, no_restart=True)

    def close(self) -> None:
        self.terminate()
        remove_orphaned_log_folders()  # the IPOPT logs of this machine's killed actors
        if self._own and self._ray.is_initialized():
            self._ray.shutdown()
            self._own = False
