"""Scale-out on Ray: `run --backend ray` on a local Ray instance of 2 CPUs started for the
test gives the metrics of a local run apart from the wall-clock columns, with each episode file written by
this process from what the workers send back, and a pilot's fault recorded as a failed cell; without Ray,
or with --address but no Ray backend, a clear error before anything flies."""
from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from compare.cli import main
from compare.results.episodes import open_episodes
from compare.results.failures import FailureKind, read_failures
from compare.run.backends import RAY_FIX
from run_data import TINY, deterministic_rows

RAISING, EXITING = "fault_pilots:RaisingPilot", "fault_pilots:ExitingPilot"


def _rows(out: Path) -> list[dict]:
    return deterministic_rows(out / "metrics.csv")


def test_ray_gives_the_local_metrics_and_records_faults(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture, no_report: None) -> None:
    faults = tmp_path / "faults"
    faults.mkdir()
    monkeypatch.setenv("FAULT_DIR", str(faults))  # the local Ray instance starts from this environment
    common = ["--no-progress", "--videos", "none"]
    local = tmp_path / "local"
    assert main(["run", str(TINY), "--out", str(local), *common]) == 0
    for fault in ("raise", "exit"):
        (faults / fault).touch()
    ours = set(Path(tempfile.gettempdir()).glob("uam-ray-*"))
    out = tmp_path / "ray"
    assert main(["run", str(TINY), "--pilot", RAISING, "--pilot", EXITING, "--backend", "ray", "--jobs", "2",
                 "--out", str(out), *common]) == 0
    # the same episodes: metrics.csv identical apart from the measured wall-clock columns
    assert [r for r in _rows(out) if r["method"] in ("ppo", "rrt_mpc")] == _rows(local)
    assert [e.key.stem for e in open_episodes(out).entries] == ["tiny__ep000__ppo__s0", "tiny__ep000__rrt_mpc__s0"]
    failed = {f.key.method: f for f in read_failures(out)}
    assert sorted(failed) == [EXITING, RAISING] and all(f.backend == "ray" for f in failed.values())
    assert failed[RAISING].kind is FailureKind.ERROR and failed[RAISING].worker.startswith("node ")
    assert failed[RAISING].reason.startswith("FaultInjected: injected fault in act (at fault_pilots.py:")
    assert failed[EXITING].kind is FailureKind.CRASH and "WorkerCrashedError" in failed[EXITING].reason
    assert "2 cells failed (error 1, crash 1; " in capsys.readouterr().out
    assert set(Path(tempfile.gettempdir()).glob("uam-ray-*")) == ours  # Ray's session folder went with it
    assert list(out.rglob(".*partial*")) == []


def test_without_ray_a_clear_error_before_anything_flies(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` now fails as if it were not installed
    out = tmp_path / "never"
    assert main(["run", str(TINY), "--backend", "ray", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "--backend ray: Ray is not installed" in err and RAY_FIX in err and not out.exists()


def test_address_needs_the_ray_backend(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "never"
    assert main(["run", str(TINY), "--address", "10.0.0.5:6379", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "--address 10.0.0.5:6379: a Ray cluster's address, only with --backend ray" in err and not out.exists()


def test_ray_is_imported_only_when_asked_for() -> None:
    code = ("import sys, compare.cli, compare.run.campaign, compare.run.backends.local, compare.run.backends.worker; "
            "print('ray' in sys.modules)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "False"


def test_an_unreachable_cluster_is_a_clear_error_before_anything_is_written(tmp_path: Path,
                                                                            capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "never"
    assert main(["run", str(TINY), "--backend", "ray", "--address", "127.0.0.1:1", "--out", str(out),
                 "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "--address 127.0.0.1:1: no Ray head node answers there" in err and not out.exists()
