"""The local backend: cells in this process, or in a pool of worker processes on this machine.

The pool is pebble's `ProcessPool` (spawned interpreters, no state copied from this process): a cell that
gives no result within its limit has its worker killed (TimeoutError) and a worker that dies
(ProcessExpired) is replaced, so one cell's crash or hang costs that cell only. At most one cell per worker
is in flight, so a cell's time is its own (it does not wait in a queue).
"""
from __future__ import annotations

import concurrent.futures
import multiprocessing
import time
from collections import deque
from collections.abc import Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, wait
from concurrent.futures.process import BrokenProcessPool

from pebble import ProcessExpired, ProcessPool

from compare.results.failures import FailedCell, FailureKind, error_failure, exit_reason
from compare.run.backends.base import CellJob, CellOutcome, WorkerSetup
from compare.run.backends.worker import fly_cell, fly_in_pool_worker, init_pool_worker, new_runner

NAME = "local"


class InProcessBackend:
    """Flies every cell in this process, one after the other. A pilot's exception is a failed cell; a crash or
    a hang (which need a separate process to survive) stops the run."""

    name = NAME

    def __init__(self, setup: WorkerSetup) -> None:
        self.setup = setup

    def fly(self, tasks: Sequence[CellJob]) -> Iterator[CellOutcome]:
        """Fly `tasks` in order (each cell's part written as it ends)."""
        runner = new_runner(self.setup)
        for task in tasks:
            yield fly_cell(runner, task, NAME, "in-process", to_bytes=False)

    def close(self) -> None:
        """Nothing to end."""


class ProcessPoolBackend:
    """Flies cells in `workers` worker processes, each cell within its wall-time limit."""

    name = NAME

    def __init__(self, setup: WorkerSetup, workers: int) -> None:
        self.setup, self.workers = setup, max(1, int(workers))
        self._pool: ProcessPool | None = None

    def fly(self, tasks: Sequence[CellJob]) -> Iterator[CellOutcome]:
        """Fly `tasks` (each with a limit: a cell without one could hold its worker forever), yielding each
        outcome as it ends."""
        pending = deque(tasks)
        running: dict[Future, tuple[CellJob, float, ProcessPool]] = {}
        while pending or running:
            pool = self._pool if self._pool is not None else self._start()
            while pending and len(running) < self.workers:
                task = pending.popleft()
                scheduled = pool.schedule(fly_in_pool_worker, args=(task,), timeout=task.limit_s)
                running[scheduled] = (task, time.monotonic(), pool)
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                task, t0, used = running.pop(future)
                outcome, pool_broke = _outcome(future, task, time.monotonic() - t0)
                if pool_broke and used is self._pool:  # all its tasks failed with it: a new pool for the rest
                    self._stop()
                yield outcome

    def close(self) -> None:
        """Stop the workers at once (SIGTERM, then SIGKILL after pebble's grace period)."""
        self._stop()

    def _start(self) -> ProcessPool:
        # spawn: fresh interpreters, no casadi/ompl/torch state copied from this process
        self._pool = ProcessPool(max_workers=self.workers, initializer=init_pool_worker, initargs=(self.setup,),
                                 context=multiprocessing.get_context("spawn"))
        return self._pool

    def _stop(self) -> None:
        if self._pool is not None:
            pool, self._pool = self._pool, None
            pool.stop()
            pool.join()


def _outcome(future: Future, task: CellJob, elapsed_s: float) -> tuple[CellOutcome, bool]:
    """How a pool task ended, and whether the pool broke with it."""
    try:
        return future.result(), False
    except concurrent.futures.TimeoutError:  # pebble killed the worker; a new one takes its place
        reason = (f"no result within {task.limit_s:g} s (the cell's wall-time limit, see --cell-timeout); its worker "
                  f"process was killed and replaced")
        return FailedCell(task.key, FailureKind.HANG, reason, elapsed_s, NAME, "", task.limit_s), False
    except ProcessExpired as exc:
        worker = f"pid {exc.pid}" if exc.pid else ""
        return FailedCell(task.key, FailureKind.CRASH, exit_reason(exc.exitcode), elapsed_s, NAME, worker,
                          task.limit_s), False
    except BrokenProcessPool as exc:  # e.g. a worker died before it could say which task it held
        reason = f"the worker pool broke while the cell was queued or in flight ({exc or 'no detail'})"
        return FailedCell(task.key, FailureKind.CRASH, reason, elapsed_s, NAME, "", task.limit_s), True
    except Exception as exc:  # raised outside the pilot (e.g. the task could not be sent): still this cell's
        return error_failure(task.key, exc, elapsed_s, NAME, "", task.limit_s), False
