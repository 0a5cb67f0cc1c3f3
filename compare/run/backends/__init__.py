"""Where a run's cells fly: one small interface, two backends.

`open_backend(kind, setup, jobs, address, isolate)` gives a `Backend` (the interface and the types it trades
in: `compare.run.backends.base`, which the backends import; this module imports them); its `fly(tasks)` yields one
`CellOutcome` per task as each ends (in the order they end): `CellFlown` once the cell's part of the run store is
in the run folder, or a `compare.results.failures.FailedCell` saying why there is none. A backend never
raises for one cell's failure; it raises only for an interrupt (KeyboardInterrupt) or when it cannot
start at all.

- "local" (`compare.run.backends.local`): in this process (one job, no isolation: a pilot's exception is a
  failed cell, a crash or hang stops the run), or a pool of worker processes (pebble's ProcessPool: each
  cell within its wall-time limit, a dead or killed worker replaced). Workers write the cells' parts of the
  run store.
- "ray" (`compare.run.backends.ray`): Ray tasks on a local Ray instance of `jobs` CPUs, or on the cluster at
  `address`. Workers send each cell's part back and this process writes it, so the run folder
  need only be on this machine's disk. Ray is imported only here, and only when asked for.

Every backend flies a cell with the same `CellRunner` and seeds from the cell alone (`compare.flying.seeding`),
so the episodes do not depend on the backend.
"""
from __future__ import annotations

import importlib.util
import sys
from collections.abc import Iterator
from contextlib import contextmanager

from compare.run.backends.base import Backend, WorkerSetup
from compare.run.backends.local import InProcessBackend, ProcessPoolBackend

BACKENDS = ("local", "ray")
RAY_FIX = 'pip install -e ".[ray]"'


def check_backend(kind: str, address: str | None) -> None:
    """Raise ValueError, before anything flies, for an unknown backend, an address without Ray, or Ray missing."""
    if kind not in BACKENDS:
        raise ValueError(f"--backend {kind!r}: choose from {', '.join(BACKENDS)}")
    if address is not None and kind != "ray":
        raise ValueError(f"--address {address}: a Ray cluster's address, only with --backend ray")
    if kind == "ray" and not ray_available():
        raise ValueError(f"--backend ray: Ray is not installed in this Python; install it with {RAY_FIX}")


def ray_available() -> bool:
    """Ray can be imported here (without importing it)."""
    if "ray" in sys.modules:  # imported already, or hidden (None)
        return sys.modules["ray"] is not None
    return importlib.util.find_spec("ray") is not None


@contextmanager
def open_backend(kind: str, setup: WorkerSetup, jobs: int, address: str | None = None,
                 isolate: bool = False) -> Iterator[Backend]:
    """The backend `kind` for a run, closed (its workers ended) when the block ends, normally or not.

    Args:
        kind: "local" or "ray", already checked (`check_backend`, which `compare.run.campaign.RunConfig.validate`
            calls before anything is read or flown).
        setup: the run's scenarios, folder and policies.
        jobs: worker processes (local), or the CPUs of the local Ray instance started when `address` is None
            (with `address`: at most this many cells in flight when > 1, else the cluster's CPUs).
        address: a running Ray cluster's address (None: start a local instance).
        isolate: local with one job: fly in one worker process (for the cell time limit) rather than here.

    Raises:
        ValueError: Ray cannot be imported, or the Ray cluster cannot be reached.
    """
    backend: Backend
    if kind == "ray":
        try:  # Ray is imported only when asked for (an optional extra, and slow to import)
            from compare.run.backends.ray import RayBackend
        except ImportError as exc:  # installed but broken
            raise ValueError(f"--backend ray: cannot import Ray ({exc}); reinstall it with {RAY_FIX}") from exc
        backend = RayBackend(setup, jobs, address)
    else:
        backend = ProcessPoolBackend(setup, jobs) if jobs > 1 or isolate else InProcessBackend(setup)
    try:
        yield backend
    finally:
        backend.close()
