"""The local executor: the standard library's process pool, one robot per worker process.

``concurrent.futures.ProcessPoolExecutor`` with an initializer that builds the worker's robot
once. What the standard pool does not do is added here: at most ``workers`` tasks are handed
out at a time, so the tasks in flight are exactly the ones running, and a worker that dies
(``BrokenProcessPool``) is reported with the task(s) it was running; on an error or Ctrl-C the
workers are terminated, not left to finish their tasks.

Start method: "forkserver" on Linux by default. Drake starts threads, and forking a process
that has threads can deadlock the child; the fork server is a clean, single-threaded process
that imports pe_drake once, so a worker starts about as fast as with "fork" and has no
inherited threads. "spawn" (the default elsewhere) re-imports everything per worker.
"""

from __future__ import annotations

import multiprocessing
import sys
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from pe_drake.exceptions import ConfigError
from pe_drake.excitation.parallel.base import (
    RemoteExecutor,
    RemoteTraceback,
    RobotSpec,
    TaskFinished,
    TaskStarted,
    WorkerError,
    WorkerState,
    pack_error,
    run_task,
    task_error,
    worker_name,
)
from pe_drake.excitation.solver_logs import remove_orphaned_log_folders

_STATE: WorkerState | None = None  # the worker process's robot (set by _init_worker)


def _init_worker(spec: RobotSpec, events) -> None:
    """Pool initializer: builds this worker's robot once."""
    global _STATE
    try:
        _STATE = spec.build(emit=lambda event: events.put(("event", event)))
    except BaseException as err:  # the pool only says "broken": send the reason first
        events.put(("init_error", (*pack_error(err), worker_name())))
        raise


def _run_in_worker(fn, payload) -> tuple:
    return run_task(_STATE, fn, payload, worker_name())


def default_start_method() -> str:
    """ "forkserver" where available (Linux, macOS), else "spawn"; see the module docstring."""
    methods = multiprocessing.get_all_start_methods()
    return "forkserver" if "forkserver" in methods and sys.platform != "win32" else "spawn"


class LocalExecutor(RemoteExecutor):
    """Worker processes on this machine (started at the first :meth:`map`, kept until close).

    Args:
        spec: what each worker builds (:class:`RobotSpec`).
        local: the parent's :class:`WorkerState`.
        workers: processes.
        start_method: "forkserver", "spawn" or "fork" (default :func:`default_start_method`).

    Raises:
        ConfigError: an unknown start method.
    """

    name = "local"

    def __init__(self, spec: RobotSpec, local: WorkerState, workers: int, start_method: str | None = None):
        super().__init__(local, workers)
        method = start_method or default_start_method()
        available = multiprocessing.get_all_start_methods()
        if method not in available:
            raise ConfigError(f"start method '{method}' is not available here; valid: {', '.join(available)}")
        self.start_method = method
        self._spec = spec
        self._ctx = multiprocessing.get_context(method)
        if method == "forkserver":
            # The server imports these once; each worker forks from it with them loaded.
            self._ctx.set_forkserver_preload(["pe_drake.excitation.parallel.local", "pe_drake.multibody.robot"])
        self._pool: ProcessPoolExecutor | None = None
        self._events = None

    def targets(self) -> ProcessPoolExecutor:
        if self._pool is None:
            # A SimpleQueue writes synchronously (no feeder thread): a task's events are in the
            # pipe before its result reaches the pool, so a drain after the result sees them all.
            self._events = self._ctx.SimpleQueue()
            self._pool = ProcessPoolExecutor(
                self.workers, mp_context=self._ctx, initializer=_init_worker, initargs=(self._spec, self._events)
            )
        return self._pool


    def run(self, pool, fn, payloads, say, labels) -> list[TaskFinished]:
        out: dict[int, TaskFinished] = {}
        running: dict[Any, int] = {}  # future -> task index
        pending = iter(range(len(payloads)))

        def submit_next() -> None:
            k = next(pending, None)
            if k is None:
                return
            try:
                running[pool.submit(_run_in_worker, fn, payloads[k])] = k
            except BrokenProcessPool as err:  # a worker died while idle (e.g. killed between calls)
                raise self._died(err, [k, *running.values()], labels) from err
            say(TaskStarted(k))

        for _ in range(self.workers):  # never more in flight than workers: in flight = running
            submit_next()
        while running:
            done, _ = wait(list(running), timeout=0.2, return_when=FIRST_COMPLETED)
            self._drain(say)
            for future in sorted(done, key=running.get):
                k = running.pop(future)
                try:
                    packed = future.result()
                except BrokenProcessPool as err:
                    raise self._died(err, [k, *running.values()], labels) from err
                if packed[0] == "error":
                    raise task_error(packed[1:], k, labels[k])
                out[k] = TaskFinished(k, packed[1], packed[2], packed[3])
                say(out[k])
                submit_next()
        return [out[k] for k in range(len(payloads))]

    def _drain(self, say) -> None:
        """Forwards the events the workers sent; raises if a worker could not build its robot."""
        while True:
            try:
                if self._events.empty():
                    return
                kind, data = self._events.get()
            except (OSError, ValueError, EOFError):  # closed
                return
            if kind == "init_error":
                exc, type_name, tb, worker = data
                err = WorkerError(f"worker {worker} could not build its robot: {type_name}: {exc}", None, type_name, tb)
                raise err from RemoteTraceback(tb)
            say(data)

    def _died(self, err: BaseException, tasks: list[int], labels: list[str]) -> WorkerError:
        self._drain(lambda event: None)  # a failed initializer explains the broken pool
        tasks = sorted(tasks)
        names = ", ".join(labels[k] for k in tasks)
        return WorkerError(
            f"a worker process died (killed, or crashed without a Python exception) while running {names}",
            tasks[0],
            tasks=tasks,
        )

    def terminate(self) -> None:
        """Stops every worker now, running tasks included (idempotent)."""
        pool = self._pool
        if pool is None:
            return
        if hasattr(pool, "terminate_workers"):  # Python >= 3.14
            pool.terminate_workers()
        else:
            # Before 3.14 the pool has no public handle on its processes (loky and the 3.14
            # pool terminate them the same way).
            procs = list((getattr(pool, "_processes", None) or {}).values())
            pool.shutdown(wait=False, cancel_futures=True)
            for p in procs:
                if p.is_alive():
                    p.terminate()
            for p in procs:
                p.join(timeout=5)
                if p.is_alive():  # pragma: no cover - terminate is normally enough
                    p.kill()
                    p.join()
        self.close()

    def close(self) -> None:
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
            remove_orphaned_log_folders()  # the IPOPT logs of workers that were killed
        if self._events is not None:
            self._events.close()
            self._events = None
