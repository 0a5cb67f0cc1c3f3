"""What runs in a worker: fly one cell and say how it ended, whatever the pilot does (but die or hang).

Shared by every backend, so a pilot's exception reads the same wherever the cell flew.
"""
from __future__ import annotations

import os
import time

from compare.flying import pilots
from compare.results.failures import error_failure
from compare.run.backends.base import CellFlown, CellJob, CellOutcome, WorkerSetup
from compare.run.cells import CellRunner


def fly_cell(runner: CellRunner, task: CellJob, backend: str, worker: str, to_bytes: bool) -> CellOutcome:
    """Fly `task` with `runner`: its part of the run store written into the run folder (or its content, `to_bytes`),
    or the failed cell of an exception raised by the pilot or the runner (its type, message and frame).

    Args:
        runner: the process's cell runner.
        task: the cell and its limit.
        backend: the backend's name, for a failure record.
        worker: which process this is, for the records.
        to_bytes: return the part's content rather than writing it (the driver writes it).
    """
    t0 = time.perf_counter()
    data = None
    try:
        if to_bytes:
            _, data = runner.part(task.cell)
        else:
            runner.run(task.cell)
    # one cell's failure, whatever the pilot raised (SystemExit included: a pilot does not end the run);
    # KeyboardInterrupt is the user's and stops the run
    except (Exception, SystemExit) as exc:
        return error_failure(task.key, exc, time.perf_counter() - t0, backend, worker, task.limit_s)
    return CellFlown(task.key, time.perf_counter() - t0, worker, data)


def prepare_process(setup: WorkerSetup) -> None:
    """Settings of a process that only flies cells: one OpenMP and one torch thread (the pilots evaluate small
    networks one observation at a time, and the run's parallelism is its workers)."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    if any(pilots.pilot(m).uses_torch for sc in setup.scenarios for m in sc.pilots):
        import torch  # only in a process that flies a torch pilot: PyTorch takes seconds to import

        torch.set_num_threads(1)


def new_runner(setup: WorkerSetup) -> CellRunner:
    """A cell runner for `setup` (its caches are filled as cells fly)."""
    return CellRunner(setup.scenarios, setup.out_dir, setup.policies, setup.store)


_POOL_RUNNER: CellRunner | None = None  # a local pool worker's, made once by its initializer


def init_pool_worker(setup: WorkerSetup) -> None:
    """Initializer of a local worker process: settings, then the one runner it flies every cell with."""
    global _POOL_RUNNER
    prepare_process(setup)
    _POOL_RUNNER = new_runner(setup)


def fly_in_pool_worker(task: CellJob) -> CellOutcome:
    """Fly `task` in a local worker process (its part written by the worker)."""
    assert _POOL_RUNNER is not None, "init_pool_worker was not called"
    return fly_cell(_POOL_RUNNER, task, "local", f"pid {os.getpid()}", to_bytes=False)
