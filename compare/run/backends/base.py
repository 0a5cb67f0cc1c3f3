"""What the backends share: the cells they are given, how each ended, and the `Backend` interface.

The campaign (`compare.run.campaign`) makes the tasks and reads the outcomes; every backend
(`compare.run.backends.local`, `compare.run.backends.ray`) and the worker code they share
(`compare.run.backends.worker`) import this module, which imports none of them.
"""
from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from compare.results.failures import FailedCell
from compare.results.trajectory import EpisodeKey
from compare.run.cells import Cell
from compare.scenarios.scenario import Scenario


@dataclass(frozen=True)
class WorkerSetup:
    """What every worker needs to fly a run's cells.

    Attributes:
        scenarios: the run's scenarios (a `Cell` indexes them).
        out_dir: the run folder (local workers write their parts of the run store into it).
        policies: the policy folder of the pilots that need one, by vehicle fingerprint.
        store: the samples each episode keeps: "control" or "full" (`compare.results.tables.kept_rows`).
    """

    scenarios: tuple[Scenario, ...]
    out_dir: Path
    policies: Mapping[str, Path]
    store: str = "control"


@dataclass(frozen=True)
class CellJob:
    """One cell to fly: the cell, its episode key and its wall-time limit [s] (None: none)."""

    cell: Cell
    key: EpisodeKey
    limit_s: float | None = None


@dataclass(frozen=True)
class CellFlown:
    """A cell that produced its episode.

    Attributes:
        key: the cell.
        elapsed_s: wall time of the cell in its worker [s].
        worker: which process flew it ("in-process", "pid 1234", a Ray node and pid).
        data: the cell's part of the run store for the driver to write (Ray workers); None once it is written.
    """

    key: EpisodeKey
    elapsed_s: float
    worker: str
    data: bytes | None = None


CellOutcome = CellFlown | FailedCell


class Backend(Protocol):
    """Flies cells and says how each ended."""

    name: str

    def fly(self, tasks: Sequence[CellJob]) -> Iterator[CellOutcome]:
        """Fly `tasks`, yielding one outcome per task as each ends."""
        ...

    def close(self) -> None:
        """End the workers at once (a cell in flight is lost: its part is not written); idempotent."""
        ...
