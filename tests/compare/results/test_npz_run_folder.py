"""A run folder saved before the run store (one `.npz` per episode at the physics rate, written by the code of
commit 63dd56f: tests/data/npz_run_scenario.yaml says how) still reads: `report` rescores it to the same
metrics.csv and rebuilds its report and viewer, `view` and `animate` draw it, and nothing of the store is
written into it."""
from __future__ import annotations

import csv
import shutil
from pathlib import Path

import pytest

from compare.cli import main
from compare.playback.flights import flight_groups
from compare.results.episodes import open_episodes

FIXTURE = Path(__file__).resolve().parents[2] / "data" / "npz_run"


@pytest.fixture
def old_run(tmp_path: Path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(FIXTURE, out)
    return out


def test_an_npz_run_folder_reports_as_before(old_run: Path) -> None:
    episodes = open_episodes(old_run)
    assert [(e.key.stem, e.path.suffix, e.row) for e in episodes.entries] == [
        ("legacy__ep000__ppo__s0", ".npz", None), ("legacy__ep000__rrt_mpc__s0", ".npz", None)]
    saved = episodes.load(episodes.entries[1])
    assert saved.meta.report is not None and len(saved.trajectory.t_s) > 500  # the physics rate, as saved
    assert main(["report", str(old_run)]) == 0
    # rescored from the files: the metrics the old code wrote, to the last digit (wall-clock columns included:
    # they were measured when it flew and are read from the files), and the columns added since at what an old
    # flight was: perfect sensing (no estimation error, no receiver), an exact map
    new, old = _csv(old_run / "metrics.csv"), _csv(FIXTURE / "metrics.csv")
    assert [{k: r[k] for k in old[0]} for r in new] == old
    for r in new:
        assert (r["sensing"], r["map_error"], r["est_error_h_rms_m"], r["est_error_v_max_m"]) == (
            "perfect", "exact", "0.0", "0.0")
        assert r["gnss_availability"] == r["min_clearance_unmapped_m"] == "nan"
    assert (old_run / "report.pdf").is_file() and (old_run / "viewer.html").is_file()
    assert not (old_run / "store").exists()  # nothing to compact, nothing written


def _csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_an_npz_run_folder_views_and_animates(old_run: Path, tmp_path: Path) -> None:
    [group] = flight_groups(old_run)
    assert [p.pilot for p in group.flights] == ["ppo", "rrt_mpc"] and group.duration_s > 1.0
    assert main(["view", str(old_run), "--out", str(tmp_path / "v.html")]) == 0
    assert main(["animate", str(old_run), "--format", "gif", "--fps", "2", "--duration", "1", "--size", "320x240",
                 "--out", str(tmp_path / "a.gif")]) == 0
    assert (tmp_path / "v.html").stat().st_size > 0 and (tmp_path / "a.gif").stat().st_size > 0
