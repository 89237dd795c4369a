"""The Ray executor: the same tasks on a Ray cluster (one machine or many).

One actor per worker holds its robot, built once from the
:class:`~pe_drake.excitation.parallel.base.RobotSpec`, and runs one task at a time, so a dead
actor names its task. The events a task emits are polled about every second (on the actor's
second thread); a task without any for ``hung_after_s`` (counted from its actor's first answer)
is declared hung. A dead or hung actor is replaced by a new one for the remaining tasks.

``ray`` is imported lazily (``pip install "pe_drake[ray]"``); every node needs the same
pe_drake installed in the Python that runs Ray.
"""

from __future__ import annotations

import os
import threading
import time
from typing import Any

from pe_drake.exceptions import ConfigError
from pe_drake.excitation.parallel.base import (
    HUNG_AFTER_S,
    ProgressClock,
    RemoteExecutor,
    RobotSpec,
    TaskFinished,
    TaskLost,
    TaskStarted,
    WorkerError,
    WorkerState,
    hung_reason,
    run_task,
    task_error,
    worker_name,
)
from pe_drake.excitation.solver_logs import remove_orphaned_log_folders

POLL_EVERY_S = 1.0  # how often a running actor is asked for its task's events


def import_ray():
    """The ``ray`` module, or ConfigError with the command that installs it."""
    try:
        import ray  # lazy: an optional, heavy package
    except ImportError as err:
        raise ConfigError(
            'the "ray" executor needs Ray: pip install "pe_drake[ray]" (or pip install ray)'
        ) from err
    return ray


class RobotActor:
    """A Ray actor's body: one robot, tasks run one at a time; :meth:`poll` (on the actor's
    second thread) hands over the events the running task emitted."""

    def __init__(self, spec: RobotSpec):
        import ray

        self.lock = threading.Lock()
        self.events: list = []
        self.state = spec.build(emit=self.keep)
        self.worker = worker_name(ray.util.get_node_ip_address())

    def keep(self, event) -> None:
        with self.lock:
            self.events.append(event)

    def poll(self) -> tuple[str, list]:
        """(this worker's name, the events since the last poll)."""
        with self.lock:
            events, self.events = self.events, []
        return self.worker, events

    def run(self, fn, payload) -> tuple:
        """(the packed result, the events not polled yet): the caller gets every event of
        the task before its result."""
        return run_task(self.state, fn, payload, self.worker), self.poll()[1]

    def pid(self) -> int:
        return os.getpid()


def cluster_cpus(address: str = "") -> int:
    """CPUs of the Ray cluster (connecting to it, or starting a local one, if needed)."""
    ray = import_ray()
    connect(address)
    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def connect(address: str = "") -> bool:
    """``ray.init(address)`` unless Ray is already initialized; True if it was called here.

    Without an address, Ray's own rule picks the cluster (``RAY_ADDRESS``, else one started on
    this machine); when there is none, the new local instance listens on 127.0.0.1 only.
    """
    ray = import_ray()
    if ray.is_initialized():
        return False
    options = {"logging_level": "warning", "log_to_driver": False}
    try:
        if address or existing_cluster(ray):
            ray.init(address=address or None, **options)
        else:
            start_local(ray, options)
    except (ConnectionError, RuntimeError, ValueError) as err:
        raise ConfigError(f"cannot connect to Ray at '{address or 'auto/local'}': {err}") from err
    return True


def existing_cluster(ray) -> bool:
    """Whether ``ray.init()`` would join a cluster rather than start one (Ray's own rule;
    True when this Ray has no such function: then ``ray.init()`` decides, as before)."""
    find = getattr(getattr(getattr(ray, "_private", None), "services", None), "canonicalize_bootstrap_address", None)
    return find is None or find(None) is not None


def start_local(ray, options: dict) -> None:
    """A new local Ray instance that only this machine can reach.

    Ray has no public switch for it (``_node_ip_address="127.0.0.1"`` is turned into the
    machine's address); with ``ray_constants.ENABLE_RAY_CLUSTER`` off, as on macOS, the node's
    servers listen on 127.0.0.1 only. It is turned off for this call only (BUILD_NOTES.md).
    """
    constants = getattr(getattr(ray, "_private", None), "ray_constants", None)
    saved = getattr(constants, "ENABLE_RAY_CLUSTER", None)
    if saved is not None:
        constants.ENABLE_RAY_CLUSTER = False
    try:
        ray.init(address="local", include_dashboard=False, **options)
    finally:
        if saved is not None:
            constants.ENABLE_RAY_CLUSTER = saved


class RayExecutor(RemoteExecutor):
    """One Ray actor per worker (each reserves one CPU), created at the first :meth:`map`, each
    holding its robot; ConfigError when Ray is missing or ``address`` cannot be reached."""

    name = "ray"

    def __init__(self, spec: RobotSpec, local: WorkerState, workers: int, address: str = "",
                 hung_after_s: float = HUNG_AFTER_S):
        super().__init__(local, workers, hung_after_s)
        self._ray = import_ray()
        self._own = connect(address)
        self.address = address
        self._spec = spec
        self._actors: list = []

    def targets(self) -> list:
        """The actors (created on first use)."""
        if not self._actors:
            self._actors = [self.new_actor() for _ in range(self.workers)]
        return self._actors

    def new_actor(self):
        # Two threads: one runs the task, the other answers poll() meanwhile.
        cls = self._ray.remote(num_cpus=1, max_restarts=0, max_concurrency=2)(RobotActor)
        return cls.remote(self._spec)

    def run(self, actors, fn, payloads, say, labels, keep_lost) -> list:
        ray = self._ray
        out: dict[int, TaskFinished | TaskLost] = {}
        running: dict[Any, tuple[int, int]] = {}  # object ref -> (task index, actor slot)
        polls: dict[Any, int] = {}  # poll ref -> task index
        asked: dict[int, float] = {}  # task index -> when its actor was last polled
        names: dict[int, str] = {}  # actor slot -> its worker's name, once it answered a poll
        clock = ProgressClock(self.hung_after_s)
        pending = iter(range(len(payloads)))

        def submit_next(slot: int) -> None:
            k = next(pending, None)
            if k is not None:
                running[actors[slot].run.remote(fn, payloads[k])] = (k, slot)
                clock.start(k)
                asked[k] = time.monotonic()
                say(TaskStarted(k))

        def lose(k: int, slot: int, reason: str) -> None:
            if not keep_lost:
                raise WorkerError(reason, k)
            self._ray.kill(actors[slot], no_restart=True)
            actors[slot] = self.new_actor()  # the remaining tasks get a fresh worker
            out[k] = TaskLost(k, reason, names.pop(slot, ""), clock.stop(k))
            say(out[k])
            submit_next(slot)

        for slot in range(len(actors)):
            submit_next(slot)
        while running:
            now = time.monotonic()
            for ref, (k, slot) in running.items():
                if now - asked[k] >= POLL_EVERY_S and k not in polls.values():
                    polls[actors[slot].poll.remote()] = k
                    asked[k] = now
            # A short timeout keeps Ctrl-C responsive.
            ready, _ = ray.wait([*polls, *running], num_returns=1, timeout=0.2)
            for ref in [r for r in ready if r in polls]:  # events before results
                k = polls.pop(ref)
                try:
                    name, events = ray.get(ref)
                except ray.exceptions.RayError:  # a dead actor: its task's ref says so
                    continue
                slots = [s for j, s in running.values() if j == k]
                up = all(s in names for s in slots)
                names.update((s, name) for s in slots)
                if events or not up:  # the actor's first answer: its task's clock starts now
                    clock.touch(k)
                    for event in events:
                        say(event)
            for ref in [r for r in ready if r in running]:
                k, slot = running.pop(ref)
                try:
                    packed, events = ray.get(ref)
                except ray.exceptions.RayActorError as err:
                    lose(k, slot, f"the Ray worker running {labels[k]} died: {err}")
                    continue
                except ray.exceptions.RayError as err:
                    raise WorkerError(f"Ray could not run {labels[k]}: {err}", k) from err
                for event in events:
                    say(event)
                if packed[0] == "error":
                    raise task_error(packed[1:], k, labels[k])
                out[k] = TaskFinished(k, packed[1], packed[2], packed[3])
                clock.stop(k)
                say(out[k])
                submit_next(slot)
            # An actor not up yet (waiting for a CPU, starting, building its robot) is not
            # declared hung: on a busy cluster it may wait long.
            for k in clock.hung(k for k, slot in running.values() if slot in names):
                ref, slot = next((r, s) for r, (j, s) in running.items() if j == k)
                del running[ref]
                lose(k, slot, hung_reason(names.get(slot, f"(Ray actor {slot})"), self.hung_after_s, labels[k]))
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
