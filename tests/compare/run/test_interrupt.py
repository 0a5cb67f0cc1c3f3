"""Interrupting a run: Ctrl-C or SIGTERM stops it promptly, workers included, with one
line saying what was kept and how to resume; the temporary file of a write cut short goes on the next run
or report."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import compare.run.cells
from compare.cli import INTERRUPTED_EXIT, main
from compare.results.episodes import open_episodes
from compare.results.store import part_files
from run_data import TINY
from uam_fdm.files.atomic import TEMP_MARK, atomic_open, remove_stale_temporaries

SEEDS = "0,1,2,3,4,5,6,7"


def test_ctrl_c_keeps_the_finished_episodes_and_says_how_to_resume(
        tmp_path: Path, capsys: pytest.CaptureFixture, synthetic_flying: None,
        monkeypatch: pytest.MonkeyPatch) -> None:
    fly = compare.run.cells.CellRunner.run
    flown = []

    def interrupted_on_the_third(self: compare.run.cells.CellRunner, c: compare.run.cells.Cell) -> Path:
        if len(flown) == 2:
            raise KeyboardInterrupt
        flown.append(c)
        return fly(self, c)

    monkeypatch.setattr(compare.run.cells.CellRunner, "run", interrupted_on_the_third)
    out = tmp_path / "run"
    argv = ["run", str(TINY), "--pilots", "rrt_mpc", "--seeds", SEEDS, "--out", str(out), "--no-progress",
            "--videos", "none"]
    assert main(argv) == INTERRUPTED_EXIT
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.startswith("uam-compare: interrupted")]
    assert lines == [f"uam-compare: interrupted: 2 of 8 episodes kept in {out}; to fly the rest: uam-compare "
                     f"run {TINY} --pilots rrt_mpc --seeds {SEEDS} --out {out} --no-progress --videos none "
                     f"--resume"], err
    assert len(part_files(out)) == 2 and not (out / "metrics.csv").exists()  # each cell's part, as it ended
    monkeypatch.setattr(compare.run.cells.CellRunner, "run", fly)  # the synthetic flight: resume flies the other 6
    assert main([*argv, "--resume"]) == 0
    assert len(open_episodes(out).entries) == 8 and part_files(out) == []  # compacted


def test_a_killed_writer_leaves_a_temporary_that_the_next_report_removes(tmp_path: Path) -> None:
    target = tmp_path / "episodes" / "a.npz"
    with pytest.raises(RuntimeError), atomic_open(target, "wb") as f:
        f.write(b"half")
        raise RuntimeError  # a writer that fails cleans up after itself ...
    assert not any(tmp_path.rglob(f"*{TEMP_MARK}*"))
    stale = target.parent / f".a.npz{TEMP_MARK}k3j2h1g0.tmp"  # ... one that was killed cannot
    stale.write_bytes(b"half")
    keep = [target.parent / ".hidden-by-the-user", target.parent / "notes.partial.txt"]
    for p in keep:
        p.write_text("mine")
    assert remove_stale_temporaries(tmp_path) == [stale]
    assert not stale.exists() and all(p.exists() for p in keep)


def test_report_removes_stale_temporaries(tmp_path: Path, capsys: pytest.CaptureFixture,
                                          synthetic_flying: None) -> None:
    out = tmp_path / "run"
    assert main(["run", str(TINY), "--pilots", "rrt_mpc", "--out", str(out), "--no-progress",
                 "--videos", "none"]) == 0
    stale = out / "store" / "parts" / f".tiny__ep000__rrt_mpc__s1.parquet{TEMP_MARK}abcdefgh.tmp"
    stale.write_bytes(b"\x00" * 100)
    assert main(["report", str(out)]) == 0
    assert not stale.exists()


@pytest.mark.parametrize("how", ["ctrl-c", "sigterm"])
def test_a_parallel_run_stops_promptly_with_its_workers(tmp_path: Path, how: str) -> None:
    """The real command line in its own process group, 2 workers flying the learned pilot: Ctrl-C (SIGINT to the
    whole group, as a terminal sends it) or SIGTERM (to the parent alone, as `kill` sends it) once an episode
    is saved. The command must end within seconds, print one line and no traceback, and leave no process."""
    out = tmp_path / "run"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "compare", "run", str(TINY), "--pilots", "ppo", "--seeds", SEEDS, "--jobs", "2",
         "--out", str(out), "--no-progress", "--videos", "none"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, start_new_session=True,
        # as from a terminal, even when these tests run where SIGINT is ignored (a shell's background job):
        # Python then keeps ignoring it and never raises KeyboardInterrupt
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 120.0
        while not part_files(out) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert proc.poll() is None, proc.communicate()
        assert part_files(out), "no episode was saved within 120 s"
        if how == "ctrl-c":
            os.killpg(proc.pid, signal.SIGINT)
        else:
            proc.send_signal(signal.SIGTERM)
        # a guard against a hang, not a measure (how promptly it stops: perf/responsiveness.py)
        _, err = proc.communicate(timeout=120.0)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == INTERRUPTED_EXIT, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    lines = [ln for ln in err.splitlines() if ln.startswith("uam-compare: interrupted")]
    kept = len(open_episodes(out).entries)
    assert len(lines) == 1 and f": {kept} of 8 episodes kept in {out}; " in lines[0] and lines[0].endswith("--resume")
    assert 1 <= kept < 8
    deadline = time.monotonic() + 5.0  # workers terminated: none left running in the command's process group
    while _running_in_group(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert _running_in_group(proc.pid) == []


def _running_in_group(pgid: int) -> list[int]:
    """Processes of a process group that are still alive (not zombies awaiting their reaper), from /proc."""
    alive = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # ended while we looked
            continue
        state, group = fields[0], int(fields[2])
        if group == pgid and state not in ("Z", "X"):
            alive.append(int(stat.parent.name))
    return alive
