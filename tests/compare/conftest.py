"""Fixtures shared by the comparison's tests."""
from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path

import pytest

import compare.run.campaign
import compare.run.cells
from compare.results.store import part_path, write_part
from compare.results.trajectory import EpisodeMeta
from synthetic_run import trajectory


def _score_only(mp: pytest.MonkeyPatch) -> None:
    """Patch `run` to score its episodes without building the report and the viewer: what `no_report` and
    `scoring_only` do.

    `run` finalizes through `campaign._finalize` under the folder's lock it already holds, not through `finalize`:
    `test_no_report_fixture_builds_no_report` keeps this patch from going stale unnoticed."""
    finalize = compare.run.campaign._finalize
    mp.setattr(compare.run.campaign, "_finalize", lambda run_dir, report=True: finalize(run_dir, False))


@pytest.fixture
def no_report(monkeypatch: pytest.MonkeyPatch) -> None:
    """`run` scores its episodes (metrics.csv, summary.json) without building the PDF report and the viewer (fast)."""
    _score_only(monkeypatch)


@pytest.fixture(scope="session")
def scoring_only() -> Callable[[], AbstractContextManager[None]]:
    """`no_report` for a fixture of a module or a session, which cannot take a test's fixture: `with scoring_only():
    main(["run", ...])` scores that run without building the PDF report and the viewer (fast), and no other."""
    @contextmanager
    def only() -> Iterator[None]:
        with pytest.MonkeyPatch.context() as mp:
            _score_only(mp)
            yield
    return only


@pytest.fixture
def synthetic_flying(monkeypatch: pytest.MonkeyPatch, no_report: None) -> None:
    """`run` flies each cell as a short synthetic flight and scores it without report or viewer (fast)."""
    def fly(self: compare.run.cells.CellRunner, c: compare.run.cells.Cell) -> Path:
        sc = self.scenarios[c.scenario]
        task, key = sc.episodes[c.episode].task, compare.run.cells.cell_key(self.scenarios, c)
        meta = EpisodeMeta(key, sc.city.name or sc.name, sc.vehicle_name, tuple(task.start_m), tuple(task.goal_m),
                           task.goal_radius_m, task.timeout_s, sc.vehicle.collision_radius_m, sc.vehicle.n_rotors,
                           1e4, "success", 0.0, "synthetic")
        return write_part(part_path(self.out_dir, key),
                          self.stored(c, meta, trajectory(200, 10.0, 0.0, 1.0, "success", 0)))
    monkeypatch.setattr(compare.run.cells.CellRunner, "run", fly)
