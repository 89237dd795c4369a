"""The local executor: ``concurrent.futures.ProcessPoolExecutor``, one robot per worker process.

Added to the standard pool: at most ``workers`` tasks are handed out at a time (the tasks in
flight are the ones running), a worker that dies is reported with its task, and on an error or
Ctrl-C the workers are terminated, not left to finish.

Start method: "forkserver" by default. Drake starts threads, and forking a process with threads
can deadlock the child; the fork server is single-threaded and imports pe_drake once.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
import sys
from collections import deque
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from pe_drake.exceptions import ConfigError
from pe_drake.excitation.parallel.base import (
    HUNG_AFTER_S,
    ProgressClock,
    RemoteExecutor,
    RemoteTraceback,
    RobotSpec,
    TaskFinished,
    TaskLost,
    TaskStarted,
    WorkerError,
    WorkerState,
    hung_reason,
    pack_error,
    run_task,
    task_error,
    worker_name,
)
from pe_drake.excitation.solver_logs import remove_orphaned_log_folders

#: How long idle workers may take to leave a closed pool before they are killed [s].
CLOSE_TIMEOUT_S = 10.0
#: How long a broken pool's manager thread may take to stop and reap its workers [s] (it
#: SIGTERMs them, which ends them at once; :meth:`LocalExecutor.terminate` kills stragglers).
REAP_TIMEOUT_S = 10.0

_STATE: WorkerState | None = None  # the worker process's robot (set by _init_worker)
_EVENTS = None  # the queue to the parent (set by _init_worker)
_TASK: int | None = None  # the task this worker runs: its events are tagged with it


def _init_worker(spec: RobotSpec, events) -> None:
    """Pool initializer: builds this worker's robot once."""
    global _STATE, _EVENTS
    _EVENTS = events
    try:
        _STATE = spec.build(emit=lambda event: events.put(("event", _TASK, event)))
    except BaseException as err:  # the pool only says "broken": send the reason first
        events.put(("init_error", None, (*pack_error(err), worker_name())))
        raise


def _run_in_worker(fn, payload, task: int | None = None) -> tuple:
    global _TASK
    _TASK = task
    # Which process runs the task: the parent stops that one if the task hangs, and tells
    # a dead worker's task from the ones the broken pool took down with it.
    _EVENTS.put(("begin", task, os.getpid()))
    return run_task(_STATE, fn, payload, worker_name())


def default_start_method() -> str:
    """ "forkserver" where available (Linux, macOS), else "spawn"; see the module docstring."""
    methods = multiprocessing.get_all_start_methods()
    return "forkserver" if "forkserver" in methods and sys.platform != "win32" else "spawn"


class LocalExecutor(RemoteExecutor):
    """Worker processes on this machine (started at the first :meth:`map`, kept until close);
    ConfigError for an unknown start method or a bad ``hung_after_s``."""

    name = "local"

    def __init__(self, spec: RobotSpec, local: WorkerState, workers: int, start_method: str | None = None,
                 hung_after_s: float = HUNG_AFTER_S):
        super().__init__(local, workers, hung_after_s)
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
        self.began = False  # a task began on the current pool (see PoolRun.died)

    def targets(self) -> ProcessPoolExecutor:
        if self._pool is None:
            # A SimpleQueue writes synchronously (no feeder thread): a task's events are in the
            # pipe before its result reaches the pool, so a drain after the result sees them all.
            # One queue per pool: a worker killed while writing may leave its lock held.
            self._events = self._ctx.SimpleQueue()
            self.began = False
            self._pool = ProcessPoolExecutor(
                self.workers, mp_context=self._ctx, initializer=_init_worker, initargs=(self._spec, self._events)
            )
        return self._pool

    def run(self, pool, fn, payloads, say, labels, keep_lost) -> list:
        return PoolRun(self, fn, payloads, say, labels, keep_lost).run()

    def drain(self, on_message) -> None:
        """Passes the messages the workers sent to ``on_message(kind, task, data)``; raises if
        a worker could not build its robot."""
        while self._events is not None:
            try:
                if self._events.empty():
                    return
                kind, task, data = self._events.get()
            except (OSError, ValueError, EOFError):  # closed
                return
            if kind == "init_error":
                exc, type_name, tb, worker = data
                err = WorkerError(f"worker {worker} could not build its robot: {type_name}: {exc}", None, type_name, tb)
                raise err from RemoteTraceback(tb)
            on_message(kind, task, data)

    def processes(self) -> dict:
        """{pid: Process} of the current pool (the standard pool keeps them in ``_processes``)."""
        return dict(getattr(self._pool, "_processes", None) or {})

    def wait_until_reaped(self, timeout: float = REAP_TIMEOUT_S) -> None:
        """After the pool broke: waits until its manager thread has reaped every worker, so that
        their exit codes are read by that one thread alone (two threads polling one "forkserver"
        worker race for its single status, and the loser records 255: a worker stopped with
        SIGTERM would look as if it had died on its own)."""
        pool = self._pool
        manager = getattr(pool, "_executor_manager_thread", None)
        if pool is not None and getattr(pool, "_broken", False) and manager is not None:
            manager.join(timeout)  # it SIGTERMs the other workers and joins them, then ends

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
            procs = list(self.processes().values())
            pool.shutdown(wait=False, cancel_futures=True)
            for p in procs:
                if p.is_alive():
                    p.terminate()
            _reap(procs, 5.0)  # terminate is normally enough
        self.close()

    def close(self) -> None:
        procs = list(self.processes().values())
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)
            _reap(procs, CLOSE_TIMEOUT_S)
            manager = getattr(pool, "_executor_manager_thread", None)
            if manager is not None:
                manager.join(CLOSE_TIMEOUT_S)
            remove_orphaned_log_folders()  # the IPOPT logs of workers that were killed
        if self._events is not None:
            self._events.close()
            self._events = None


def _reap(procs: list, timeout: float) -> None:
    """Waits up to ``timeout`` [s] for the idle workers to leave, then kills the rest.

    A stopped idle worker (SIGSTOP, a debugger) never reads the pool's shutdown message
    (issue 34); SIGKILL ends a stopped process too.
    """
    deadline = time.monotonic() + timeout
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
    for p in procs:
        if p.is_alive():
            p.kill()
            p.join(5)


class PoolRun:
    """One :meth:`LocalExecutor.run`: hands out the tasks, at most one per worker, and keeps
    every finished one when a worker dies or hangs.

    A dead worker breaks the whole standard pool; the other workers' tasks are run again on a
    new pool and only the dead (or hung) worker's task is lost. The dead one is told by its exit
    status: the pool and :meth:`LocalExecutor.terminate` stop the others with SIGTERM.
    """

    def __init__(self, ex: LocalExecutor, fn, payloads, say, labels, keep_lost: bool):
        self.ex, self.fn, self.payloads, self.say, self.labels = ex, fn, payloads, say, labels
        self.keep_lost = keep_lost
        self.out: dict[int, TaskFinished | TaskLost] = {}
        self.queue = deque(range(len(payloads)))
        self.running: dict = {}  # future -> task index
        self.pids: dict[int, int] = {}  # task index -> pid of the worker running it
        self.clock = ProgressClock(ex.hung_after_s)
        self.restarts = 0

    def run(self) -> list:
        while self.queue or self.running:
            if not self.fill():
                self.restart(self.died())
                continue
            done, _ = wait(list(self.running), timeout=0.2, return_when=FIRST_COMPLETED)
            self.ex.drain(self.on_message)
            if not all([self.collect(f) for f in sorted(done, key=self.running.get)]):
                self.restart(self.died())
            elif hung := self.clock.hung(self.running.values()):
                self.restart(self.stop_hung(hung))
        return [self.out[k] for k in range(len(self.payloads))]

    def fill(self) -> bool:
        """Hands out tasks until every worker has one; False if the pool is broken."""
        while self.queue and len(self.running) < self.ex.workers:
            k = self.queue[0]
            try:
                future = self.ex.targets().submit(_run_in_worker, self.fn, self.payloads[k], k)
            except BrokenProcessPool:  # a worker died while idle (e.g. killed between calls)
                return False
            self.queue.popleft()
            self.running[future] = k
            self.clock.start(k)
            self.say(TaskStarted(k))
        return True

    def on_message(self, kind: str, k, data) -> None:
        self.clock.touch(k)
        if kind == "begin":
            self.pids[k] = data
            self.ex.began = True
        else:
            self.say(data)

    def collect(self, future) -> bool:
        """Keeps a finished task's result; False if the pool broke under it."""
        k = self.running[future]
        try:
            packed = future.result()
        except BrokenProcessPool:
            return False
        del self.running[future]
        self.clock.stop(k)
        if packed[0] == "error":
            raise task_error(packed[1:], k, self.labels[k])
        self.out[k] = TaskFinished(k, packed[1], packed[2], packed[3])
        self.say(self.out[k])
        return True

    def died(self) -> dict[int, tuple[str, str]]:
        """{task: (reason, worker)} for the tasks whose worker died on its own."""
        procs = self.ex.processes()
        self.ex.drain(self.on_message)  # a failed initializer explains the broken pool (raises)
        self.ex.wait_until_reaped()  # before our own joins, which would race the pool's
        self.ex.terminate()  # every process has exited after this: their exit codes are known
        codes = {pid: p.exitcode for pid, p in procs.items()}
        dead = {pid: code for pid, code in codes.items() if code not in (None, 0, -signal.SIGTERM)}
        if not self.ex.began:  # a new pool that breaks before any task: a new one would too
            how = ", ".join(f"pid {pid}: {exit_text(code)}" for pid, code in dead.items()) or "exit status not known"
            tasks = sorted(self.running.values()) or [self.queue[0]]
            raise WorkerError(f"a worker process died before running any task ({how}) while "
                              f"{', '.join(self.labels[k] for k in tasks)} waited for it", tasks[0], tasks=tasks)
        lost = {}
        for k in sorted(self.running.values()):
            pid = self.pids.get(k)
            if pid in dead:
                lost[k] = (f"worker pid {pid} died ({exit_text(dead[pid])}) while running {self.labels[k]}", f"pid {pid}")
            elif not dead and pid is not None:
                # Nobody died by its own hand (e.g. SIGTERM from outside): the task that broke
                # the pool is not known, so no task is run again (it could break it again).
                lost[k] = (f"a worker process died (killed, or crashed without a Python exception) while "
                           f"running {self.labels[k]}", f"pid {pid}")
        return lost

    def stop_hung(self, hung: list[int]) -> dict[int, tuple[str, str]]:
        lost = {}
        for k in hung:
            pid = self.pids.get(k)
            if pid is not None:
                os.kill(pid, signal.SIGKILL)  # stuck: it may not even see a SIGTERM
            worker = "" if pid is None else f"pid {pid}"
            lost[k] = (hung_reason(worker, self.ex.hung_after_s, self.labels[k]), worker)
        self.ex.terminate()  # the standard pool cannot lose one worker: the others go too
        return lost

    def restart(self, lost: dict[int, tuple[str, str]]) -> None:
        """After the pool was stopped: tasks that finished meanwhile are kept, ``lost`` ones
        are reported (or raised), the others are handed out again on a new pool."""
        self.ex.terminate()
        for future, k in sorted(self.running.items(), key=lambda item: item[1]):
            if future.done() and not future.cancelled() and future.exception() is None:
                self.collect(future)  # it finished before the pool went down
        if lost and not self.keep_lost:
            tasks = sorted(lost)
            raise WorkerError("; ".join(lost[k][0] for k in tasks), tasks[0], tasks=tasks)
        again = []
        for k in sorted(self.running.values()):
            wall = self.clock.stop(k)
            self.pids.pop(k, None)
            if k in lost:
                self.out[k] = TaskLost(k, lost[k][0], lost[k][1], wall)
                self.say(self.out[k])
            else:
                again.append(k)
        self.running.clear()
        self.queue.extendleft(reversed(again))
        self.restarts += 1
        if self.restarts > len(self.payloads) + self.ex.workers:  # a pool that keeps breaking
            raise WorkerError(f"the worker pool broke {self.restarts} times; gave up", None)


def exit_text(code: int) -> str:
    """A process's exit code for people: "killed by SIGKILL", "exit code 3"."""
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"
