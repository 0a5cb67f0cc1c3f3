"""The shared fixtures that make a run score its episodes without drawing: they must still take effect, or every test
using them pays for a report it never reads (a stale patch of `finalize` did so unnoticed)."""
from __future__ import annotations

from pathlib import Path

from compare.cli import main
from run_data import TINY


def test_no_report_fixture_builds_no_report(tmp_path: Path, synthetic_flying: None) -> None:
    out = tmp_path / "run"
    assert main(["run", str(TINY), "--pilots", "rrt_mpc", "--out", str(out), "--no-progress", "--videos",
                 "none"]) == 0
    assert (out / "metrics.csv").is_file() and (out / "summary.json").is_file()
    assert not (out / "report.pdf").exists() and not (out / "viewer.html").exists()
