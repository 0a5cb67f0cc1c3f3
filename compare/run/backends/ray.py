"""The Ray backend: each cell a Ray task, on a local Ray instance or a cluster.

Imported only for `--backend ray` (it imports Ray). A task flies one cell with a `CellRunner` kept per
worker process (built once, on the process's first cell of the run) and returns the content of the cell's part
of the run store, which this process (the driver) writes into the run folder: workers need no access to it. A
task that raises outside the pilot, whose worker dies (WorkerCrashedError, a lost node, Ray's
out-of-memory killer) or that gives no result within its wall-time limit (cancelled with
`ray.cancel(force=True)`, which kills its worker; Ray starts another) is a failed cell. Tasks are never
retried: a crash is recorded, and `--resume` flies the cell again.

Workers import `compare` and the plug-in pilots' modules: the import roots this process found them under
go to the workers as PYTHONPATH (runtime_env), which is enough on this machine; on a cluster every node
needs the package and the plug-ins installed (or those paths present, e.g. on shared storage).
"""
from __future__ import annotations

import importlib.util
import logging
import os
import shutil
import signal
import socket
import tempfile
import threading
import time
from collections import deque
from collections.abc import Iterator, Sequence
from pathlib import Path

import ray
import ray.exceptions

from compare.flying import pilots
from compare.results.failures import FailedCell, FailureKind, error_failure
from compare.results.store import part_path, write_part
from compare.run.backends.base import CellFlown, CellJob, CellOutcome, WorkerSetup
from compare.run.backends.worker import fly_cell, new_runner, prepare_process
from compare.run.cells import CellRunner

log = logging.getLogger(__name__)

NAME = "ray"


class RayBackend:
    """Flies cells as Ray tasks; at most one cell per CPU in flight, so a cell's time limit runs from its start."""

    name = NAME

    def __init__(self, setup: WorkerSetup, jobs: int, address: str | None) -> None:
        """Start a local Ray instance with `jobs` CPUs (`address` None) or connect to the cluster at `address`
        (then at most `jobs` cells in flight when `jobs` > 1, else one per CPU of the cluster).

        Raises:
            ValueError: the cluster at `address` cannot be reached.
        """
        self.setup = setup
        self._temp_dir: Path | None = None
        self._connected = False
        self._running: dict[ray.ObjectRef, tuple[CellJob, float]] = {}
        if ray.is_initialized():  # a caller's own Ray session (e.g. a notebook): use it, leave it running
            log.info("using the Ray session already connected")
        else:
            self._init(jobs, address)
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.slots = max(1, cpus if address is None or jobs <= 1 else min(jobs, cpus))
        self._setup_ref = ray.put(setup)
        self._remote = _fly_remote.options(runtime_env={"env_vars": {"PYTHONPATH": worker_pythonpath(setup)}})

    def _init(self, jobs: int, address: str | None) -> None:
        if address is not None:
            _check_reachable(address)  # Ray itself retries an unreachable head node for minutes
        in_main = threading.current_thread() is threading.main_thread()
        previous = signal.getsignal(signal.SIGTERM) if in_main else None
        try:
            if address is None:
                # Ray's session files (sockets, logs) in a folder of ours, removed on close
                self._temp_dir = Path(tempfile.mkdtemp(prefix="uam-ray-"))
                ray.init(address="local", num_cpus=jobs, include_dashboard=False, logging_level=logging.ERROR,
                         _temp_dir=str(self._temp_dir))
            else:
                ray.init(address=address, logging_level=logging.ERROR)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            self._remove_temp_dir()
            where = f"--address {address}" if address is not None else "--backend ray"
            raise ValueError(f"{where}: cannot start or reach Ray ({exc})") from exc
        finally:
            if previous is not None:  # ray.init makes SIGTERM exit the process; the run stops on it as on Ctrl-C
                signal.signal(signal.SIGTERM, previous)
        self._connected = True

    def fly(self, tasks: Sequence[CellJob]) -> Iterator[CellOutcome]:
        """Fly `tasks`, yielding each outcome as it ends (each cell's part written here first)."""
        pending = deque(tasks)
        running = self._running
        while pending or running:
            while pending and len(running) < self.slots:
                task = pending.popleft()
                running[self._remote.remote([self._setup_ref], task)] = (task, time.monotonic())
            deadlines = [t0 + t.limit_s for t, t0 in running.values() if t.limit_s is not None]
            wait_s = max(0.0, min(deadlines) - time.monotonic()) if deadlines else None
            ready, _ = ray.wait(list(running), num_returns=1, timeout=wait_s)
            for ref in ready:
                task, t0 = running.pop(ref)
                yield self._collect(ref, task, time.monotonic() - t0)
            now = time.monotonic()
            for ref, (task, t0) in list(running.items()):
                if task.limit_s is not None and now - t0 > task.limit_s:
                    running.pop(ref)
                    ray.cancel(ref, force=True)  # kills its worker process; Ray starts another when needed
                    reason = (f"no result within {task.limit_s:g} s (the cell's wall-time limit, see --cell-timeout); "
                              f"its Ray task was cancelled and its worker process killed")
                    yield FailedCell(task.key, FailureKind.HANG, reason, now - t0, NAME, "", task.limit_s)

    def _collect(self, ref: ray.ObjectRef, task: CellJob, elapsed_s: float) -> CellOutcome:
        """The outcome of a finished task; an episode's content is written into the run folder here."""
        try:
            outcome = ray.get(ref)
        except ray.exceptions.RayTaskError as exc:  # raised in the task outside the pilot (e.g. unpickling it)
            return error_failure(task.key, exc, elapsed_s, NAME, "", task.limit_s)
        except ray.exceptions.RayError as exc:  # the worker or its node died, out of memory, no runtime env, ...
            text = str(exc).strip().splitlines()
            reason = f"Ray: {type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")
            return FailedCell(task.key, FailureKind.CRASH, reason, elapsed_s, NAME, "", task.limit_s)
        if isinstance(outcome, CellFlown) and outcome.data is not None:
            write_part(part_path(self.setup.out_dir, task.key), outcome.data, root=self.setup.out_dir)
            return CellFlown(outcome.key, outcome.elapsed_s, outcome.worker)
        return outcome

    def close(self) -> None:
        """Cancel the cells in flight, then stop the local Ray instance (or disconnect from the cluster)."""
        for ref in list(self._running):
            ray.cancel(ref, force=True)
        self._running.clear()
        if self._connected:
            ray.shutdown()
            self._connected = False
        self._remove_temp_dir()

    def _remove_temp_dir(self) -> None:
        if self._temp_dir is not None:
            shutil.rmtree(self._temp_dir, ignore_errors=True)
            self._temp_dir = None


def _check_reachable(address: str, timeout_s: float = 10.0) -> None:
    """Raise ValueError unless a TCP connection to `address` ("host:port" or "ray://host:port") opens within
    `timeout_s` [s]; other forms (e.g. "auto") are left to Ray."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as exc:
        raise ValueError(f"--address {address}: no Ray head node answers there ({exc.strerror or exc}); start one "
                         f"with `ray start --head` on that machine, or check the address and port") from exc


def worker_pythonpath(setup: WorkerSetup) -> str:
    """PYTHONPATH for the workers: the folders this process imports `compare` and each plug-in pilot's module
    from, then this process's own PYTHONPATH (a folder that does not exist on a node is skipped there)."""
    modules = ["compare"] + sorted({m.partition(":")[0] for sc in setup.scenarios for m in sc.pilots
                                    if pilots.is_reference(m)})
    roots: list[str] = []
    for name in modules:
        root = _import_root(name)
        if root is not None and root not in roots:
            roots.append(root)
    for entry in os.environ.get("PYTHONPATH", "").split(os.pathsep):
        if entry and entry not in roots:
            roots.append(entry)
    return os.pathsep.join(roots)


def _import_root(module_name: str) -> str | None:
    """The sys.path folder this process finds module `module_name` in (None: not a file, e.g. built in)."""
    try:
        spec = importlib.util.find_spec(module_name)
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.origin or not Path(spec.origin).is_file():
        return None
    path = Path(spec.origin).resolve().parent  # the folder of a module file, or a package's own folder
    if spec.submodule_search_locations is not None:  # a package: its parent holds it
        path = path.parent
    for _ in module_name.split(".")[1:]:
        path = path.parent
    return str(path)


_RUNNERS: dict[str, CellRunner] = {}  # a Ray worker process's runner per run (by the setup's object id)


@ray.remote(num_cpus=1, max_retries=0)
def _fly_remote(setup_box: list[ray.ObjectRef], task: CellJob) -> CellOutcome:
    """A Ray task: fly one cell, return its part's content or its failure. The setup arrives boxed in a
    list, so Ray passes the reference rather than the scenarios on every call; it is fetched once per process."""
    ref = setup_box[0]
    key = ref.hex()
    if key not in _RUNNERS:
        setup = ray.get(ref)
        prepare_process(setup)
        _RUNNERS.clear()  # one run at a time per worker process
        _RUNNERS[key] = new_runner(setup)
    worker = f"node {ray.util.get_node_ip_address()} pid {os.getpid()}"
    return fly_cell(_RUNNERS[key], task, NAME, worker, to_bytes=True)
