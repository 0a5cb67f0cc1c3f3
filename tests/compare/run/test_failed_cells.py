"""Robust campaigns: one cell's failure (its pilot raised, its worker died, it hung) is a
failed cell with its reason, the run goes on and reports the rest; `--resume` flies only the cells without
an episode and leaves the saved episodes as they are. The faults are plug-in pilots (fault_pilots.py)."""
from __future__ import annotations

import csv
import json
import os
from pathlib import Path

import pytest

import compare.run.campaign
import compare.run.cells
from compare.cli import main
from compare.results.episodes import open_episodes
from compare.results.failures import (
    FAILED_DIR,
    FailedCell,
    FailureKind,
    error_failure,
    exit_reason,
    failure_path,
    read_failure,
    read_failures,
    write_failure,
)
from compare.results.store import read_episode_table, samples_files
from compare.results.trajectory import EpisodeKey
from compare.run.campaign import RunConfig, cell_limit_s
from compare.run.cells import Cell
from compare.scenarios.scenario import load_scenario
from run_data import TINY

FAULTS = {"raise": "fault_pilots:RaisingPilot", "exit": "fault_pilots:ExitingPilot",
          "kill": "fault_pilots:KilledPilot", "hang": "fault_pilots:HangingPilot"}


@pytest.fixture
def faults(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, no_report: None) -> Path:
    """The folder whose files arm the fault pilots (inherited by worker processes); the run scores without
    building the PDF report and the viewer (fast)."""
    folder = tmp_path / "faults"
    folder.mkdir()
    monkeypatch.setenv("FAULT_DIR", str(folder))
    return folder


def _argv(out: Path, pilots: list[str], *extra: str) -> list[str]:
    argv = ["run", str(TINY), "--pilot", "apf"]
    for p in pilots:
        argv += ["--pilot", p]
    return [*argv, "--pilots", ",".join(["apf", *pilots]), "--out", str(out), "--no-progress", "--videos", "none",
            *extra]


def _methods_in_metrics(out: Path) -> list[str]:
    with open(out / "metrics.csv", newline="") as f:
        return sorted(r["method"] for r in csv.DictReader(f))


def test_a_pilot_that_raises_is_a_failed_cell_in_process(tmp_path: Path, faults: Path, capsys: pytest.CaptureFixture,
                                                         caplog: pytest.LogCaptureFixture) -> None:
    (faults / "raise").touch()
    out = tmp_path / "run"
    assert main(_argv(out, [FAULTS["raise"]])) == 0
    captured = capsys.readouterr()
    stem = f"tiny__ep000__{FAULTS['raise']}__s0"
    assert f"cell {stem} failed (error): FaultInjected: injected fault in act (at fault_pilots.py:" in caplog.text
    [failed] = read_failures(out)
    assert failed.key == EpisodeKey("tiny", 0, FAULTS["raise"], 0) and failed.kind is FailureKind.ERROR
    assert failed.reason.startswith("FaultInjected: injected fault in act (at fault_pilots.py:")
    assert failed.reason.endswith(" in go_off)")  # the innermost frame: where it was raised
    assert (failed.backend, failed.worker, failed.limit_s) == ("local", "in-process", None)
    assert "Traceback" in failed.detail and "episode_loop.py" in failed.detail and failed.elapsed_s > 0.0
    assert failure_path(out, failed.key) == out / FAILED_DIR / f"{stem}.json"
    # not an episode: no file, no metrics row; the rest of the run is scored and reported
    assert [e.key.stem for e in open_episodes(out).entries] == ["tiny__ep000__apf__s0"]
    assert _methods_in_metrics(out) == ["apf"]
    assert list(json.loads((out / "summary.json").read_text())["methods"]) == ["apf"]
    assert (f"{out / FAILED_DIR}{os.sep}  1 cell failed (error 1; {FAULTS['raise']} 1)" in captured.out), captured.out
    assert "1 cell failed (error 1; fault_pilots:RaisingPilot 1), listed in" in caplog.text  # finalize's warning


def test_errors_crashes_and_hangs_in_worker_processes_are_failed_cells(tmp_path: Path, faults: Path,
                                                                        capsys: pytest.CaptureFixture) -> None:
    """Two workers, every fault armed once over two seeds: each fault pilot fails one cell and flies the other
    (in a worker that replaced the one that died or was killed), and the potential field flies both."""
    for fault in FAULTS:
        (faults / fault).touch()
    out = tmp_path / "run"
    assert main(_argv(out, list(FAULTS.values()), "--seeds", "0,1", "--jobs", "2", "--cell-timeout", "20")) == 0
    failed = {f.key.method: f for f in read_failures(out)}
    assert sorted(failed) == sorted(FAULTS.values())
    assert all(f.backend == "local" and f.limit_s == 20.0 for f in failed.values())
    raised, exited, killed, hung = (failed[FAULTS[k]] for k in ("raise", "exit", "kill", "hang"))
    assert raised.kind is FailureKind.ERROR and raised.reason.startswith("FaultInjected: injected fault in act")
    assert raised.worker.startswith("pid ")
    assert exited.kind is FailureKind.CRASH and exited.reason == exit_reason(3)
    assert "exited with code 3" in exited.reason
    assert killed.kind is FailureKind.CRASH and "killed by SIGKILL" in killed.reason
    assert hung.kind is FailureKind.HANG and "no result within 20 s" in hung.reason and hung.elapsed_s >= 20.0
    # the run went on: every other cell flew and is scored
    assert _methods_in_metrics(out) == sorted(["apf", "apf", *FAULTS.values()])
    assert len(open_episodes(out).entries) == 6 and not any(faults.iterdir())  # every fault went off
    assert "4 cells failed (error 1, crash 2, hang 1; " in capsys.readouterr().out


def test_resume_flies_only_the_missing_cells_and_keeps_the_saved_episodes(
        tmp_path: Path, faults: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch) -> None:
    (faults / "raise").touch()
    out = tmp_path / "run"
    argv = _argv(out, [FAULTS["raise"]], "--seeds", "0,1")
    assert main(argv) == 0
    [failed] = read_failures(out)
    [first] = samples_files(out)
    samples = (first.stat().st_ino, first.stat().st_mtime_ns, first.read_bytes())
    saved = {f"{r['scenario']}__ep{r['episode']:03d}__{r['method']}__s{r['seed']}": r for r in read_episode_table(out)}
    assert len(saved) == 3 and failed.key.stem not in saved
    fly = compare.run.cells.CellRunner.run
    flown: list[Cell] = []

    def counted(self: compare.run.cells.CellRunner, c: Cell) -> Path:
        flown.append(c)
        return fly(self, c)

    monkeypatch.setattr(compare.run.cells.CellRunner, "run", counted)
    capsys.readouterr()
    assert main([*argv, "--resume"]) == 0  # the fault is spent: the failed cell flies now
    printed = capsys.readouterr().out
    assert "failed (" not in printed and json.loads(printed.splitlines()[-1])["failed_cells"] == 0
    assert [(c.pilot, c.seed) for c in flown] == [(failed.key.method, failed.key.seed)]
    assert read_failures(out) == [] and not failure_path(out, failed.key).exists()  # its record went with it
    after = {f"{r['scenario']}__ep{r['episode']:03d}__{r['method']}__s{r['seed']}": r for r in read_episode_table(out)}
    assert repr({k: v for k, v in after.items() if k in saved}) == repr(saved)  # rows (NaN and all) and samples:
    assert (first.stat().st_ino, first.stat().st_mtime_ns, first.read_bytes()) == samples  # the file not rewritten
    assert set(after) - set(saved) == {failed.key.stem}
    assert after[failed.key.stem]["samples_file"] == "samples-0002-000.parquet"  # its samples appended apart
    assert _methods_in_metrics(out) == sorted(["apf", "apf", FAULTS["raise"], FAULTS["raise"]])
    flown.clear()
    assert main([*argv, "--resume"]) == 0  # nothing left to fly
    assert flown == []


def test_default_cell_limit_comes_from_the_cell(tmp_path: Path) -> None:
    sc = load_scenario(TINY)
    timeout_s = sc.episodes[0].task.timeout_s
    cell = Cell(0, 0, 0, "rrt_mpc")
    limit = compare.run.campaign.CELL_LIMIT_BASE_S + compare.run.campaign.CELL_LIMIT_FACTOR * timeout_s * 1.0
    assert cell_limit_s([sc], cell, RunConfig(tmp_path)) is None  # in this process: nothing could stop it
    assert cell_limit_s([sc], cell, RunConfig(tmp_path, jobs=2)) == pytest.approx(limit)
    assert cell_limit_s([sc], Cell(0, 0, 0, "apf"), RunConfig(tmp_path, backend="ray")) == pytest.approx(
        compare.run.campaign.CELL_LIMIT_BASE_S + compare.run.campaign.CELL_LIMIT_FACTOR * timeout_s * 0.2)
    assert cell_limit_s([sc], cell, RunConfig(tmp_path, cell_timeout_s=7.5)) == 7.5
    assert not RunConfig(tmp_path, cell_timeout_s=7.5).in_process  # a limit needs a worker process


def test_failed_cell_records_round_trip(tmp_path: Path) -> None:
    key = EpisodeKey("s", 3, "pkg.mod:Pilot", 7)
    try:
        raise ValueError("bad value\nsecond line")
    except ValueError as exc:
        failure = error_failure(key, exc, 1.5, "ray", "node 10.0.0.2 pid 9", 60.0)
    assert failure.reason.startswith("ValueError: bad value (at test_failed_cells.py:")
    assert failure.reason.endswith("in test_failed_cell_records_round_trip)")
    path = write_failure(tmp_path, failure)
    assert path == tmp_path / "failed" / "s__ep003__pkg.mod:Pilot__s7.json"
    assert read_failure(path) == failure
    crash = FailedCell(key, FailureKind.CRASH, exit_reason(-9), 2.0, "local")
    assert read_failure(write_failure(tmp_path, crash)) == crash  # replaced atomically
    assert read_failures(tmp_path) == [crash]
    (tmp_path / "failed" / "broken.json").write_text("{")
    assert read_failures(tmp_path) == [crash]  # an unreadable record is skipped (with a warning)
    with pytest.raises(ValueError, match="broken.json: not a failed-cell record"):
        read_failure(tmp_path / "failed" / "broken.json")
    assert exit_reason(-11) == "the worker process was killed by SIGSEGV (signal 11)"


def test_bad_cell_timeout_is_refused_before_flying(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "never"
    assert main(["run", str(TINY), "--cell-timeout", "0", "--out", str(out)]) == 2
    assert "--cell-timeout 0: must be > 0 s" in capsys.readouterr().err and not out.exists()
