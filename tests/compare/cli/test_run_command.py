"""End to end through the CLI: a tiny scenario flown by both pilots, every output checked for content;
parallel jobs give the same metrics; `report` rebuilds from saved episodes; golden metrics."""
from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pypdf import PdfReader

from compare.cli import main
from compare.results.episodes import open_episodes
from compare.results.metrics import COLUMNS, MAPPING_METRICS, TRACKER_METRICS
from compare.results.store import EPISODE_TABLE, read_episode_table, store_dir, write_episode_table
from rl.policies.folder import DEFAULT_POLICY_DIR
from run_data import GOLDEN, TINY, without_wall_clock


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "tiny"
    assert main(["run", str(TINY), "--out", str(out), "--no-progress"]) == 0
    return out


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_run_writes_every_output(tiny_run):
    for name in ("run.json", "metrics.csv", "summary.json", "report.pdf", "viewer.html", "maps/tiny.yaml"):
        assert (tiny_run / name).is_file(), name
    # one video per scenario by default: MP4 (a GIF where ffmpeg is missing), real time at 20 fps
    videos = sorted((tiny_run / "videos").iterdir())
    assert [v.stem for v in videos] == ["tiny__ep000__s0"] and videos[0].suffix in (".mp4", ".gif")
    if videos[0].suffix == ".mp4" and shutil.which("ffprobe"):
        probe = subprocess.run(["ffprobe", "-v", "error", "-count_frames", "-select_streams", "v:0", "-show_entries",
                                "stream=nb_read_frames,width,height", "-of", "json", str(videos[0])],
                               capture_output=True, text=True, check=True)
        stream = json.loads(probe.stdout)["streams"][0]
        duration = max(float(r["time_s"]) for r in read_episode_table(tiny_run))
        assert (stream["width"], stream["height"]) == (1280, 720)
        assert int(stream["nb_read_frames"]) == round(min(duration, 30.0) * 20)
    # one store: the episode table and one samples file, the cells' parts compacted into them, and their description
    assert sorted(p.name for p in store_dir(tiny_run).rglob("*") if p.is_file()) == [
        "SCHEMA.md", EPISODE_TABLE, "samples-0001-000.parquet", "schema.json"]
    assert not (tiny_run / "episodes").exists()
    episodes = open_episodes(tiny_run)
    assert [e.key.stem for e in episodes.entries] == ["tiny__ep000__ppo__s0", "tiny__ep000__rrt_mpc__s0"]
    for entry in episodes.entries:  # the model's shaft power per step, saved: its integral is the flight's energy
        ep = episodes.load(entry)
        t, power = ep.trajectory.t_s, ep.trajectory.shaft_power_W
        assert power.shape == t.shape and np.all(power > 0.0)
        # the control rate: every step 20 ms but the two around the physics step of least clearance
        assert np.sum(~np.isclose(np.diff(t), 0.02, rtol=0, atol=1e-9)) <= 2 and np.all(np.diff(t) < 0.02 + 1e-9)
        assert np.trapezoid(power, t) == pytest.approx(ep.meta.energy_J, rel=1e-2)  # 50 Hz samples of it
    assert list(tiny_run.rglob(".*tmp*")) == []  # no temporary files left behind
    rows = _rows(tiny_run / "metrics.csv")
    assert list(rows[0].keys()) == list(COLUMNS)
    assert [(r["method"], r["scenario"], r["seed"]) for r in rows] == [("ppo", "tiny", "0"), ("rrt_mpc", "tiny", "0")]
    for r in rows:
        assert r["success"] in ("0", "1")
        assert float(r["straight_line_m"]) == pytest.approx(np.linalg.norm([90.0, 5.0, 2.0]))
    # the tracker's columns: NaN for the learned pilot, finite and sane for the classical one
    ppo, mpc = rows
    assert all(ppo[k] == "nan" for k in TRACKER_METRICS)
    assert all(np.isfinite(float(mpc[k])) for k in TRACKER_METRICS), mpc
    assert all(mpc[k] == "nan" for k in MAPPING_METRICS)  # perfect sensing: nothing mapped, no replan in flight
    assert 0.0 < float(mpc["mpc_solve_ms_median"]) <= float(mpc["mpc_solve_ms_p95"]) < 1e3
    assert float(mpc["mpc_failures"]) == 0.0 and float(mpc["replans_tracking"]) == 0.0
    assert 0.0 <= float(mpc["tracking_rms_m"]) <= float(mpc["tracking_max_m"]) < 1.0
    assert float(mpc["planner_margin_m"]) >= 1.0 and float(mpc["mpc_margin_m"]) == 0.5 * float(mpc["planner_margin_m"])
    assert float(mpc["min_clearance_m"]) >= 0.5 * float(mpc["planner_margin_m"])
    summary = json.loads((tiny_run / "summary.json").read_text())
    assert set(summary["methods"]) == {"ppo", "rrt_mpc"} and "ppo - rrt_mpc" in summary["paired"]
    s = summary["methods"]["rrt_mpc"]["success"]
    assert s["ci_low"] <= s["mean"] <= s["ci_high"]
    run = json.loads((tiny_run / "run.json").read_text())
    assert run["command"].startswith("uam-compare run") and "Neither knows the wind" in run["fairness"]
    assert run["versions"]["casadi"] != "not installed"
    # the learned pilot decides at its policy's rate, not the scenario's: said in run.json and the report
    [policy] = run["methods"]["ppo"]["policies"]  # one vehicle, so one policy: the shipped one for it
    assert policy["vehicle"] == "small_quad" and policy["decision_hz"] == 10.0
    assert Path(policy["policy_dir"]) == DEFAULT_POLICY_DIR.resolve()
    assert any(n.startswith("ppo decides at its policy's rate: for small_quad at 10 Hz") for n in run["notes"]), \
        run["notes"]


def test_report_pdf_has_the_expected_pages(tiny_run):
    reader = PdfReader(str(tiny_run / "report.pdf"))
    text = "\n".join(page.extract_text() or "" for page in reader.pages)
    assert len(reader.pages) >= 7
    for heading in ("uam-compare report", "Metrics", "Episode tiny #0 seed 0", "reward convergence", "Failures",
                    "PPO policy", "RRT* + MPC", "clearance", "speed", "decides at 10 Hz", "tracker per scenario",
                    "MPC solve, median per episode"):
        assert heading in text, heading


def test_jobs_give_identical_metrics_and_report_rebuilds(tiny_run, tmp_path, capsys):
    out2 = tmp_path / "tiny-jobs2"
    assert main(["run", str(TINY), "--out", str(out2), "--jobs", "2", "--no-progress", "--videos", "none",
                 "--store", "full"]) == 0
    # the last line: the headline figures as one JSON object, per vehicle and pilot, rates with Wilson intervals
    last = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert last["run_dir"] == str(out2) and last["suite"] is None and last["failed_cells"] == 0
    ppo = last["vehicles"]["small_quad"]["ppo"]
    assert set(last["vehicles"]["small_quad"]) == {"ppo", "rrt_mpc"} and ppo["episodes"] == 1
    assert ppo["success"]["rate"] == 1.0 and ppo["success"]["ci95"] == pytest.approx([0.2065, 1.0], abs=1e-4)
    a, b = _rows(tiny_run / "metrics.csv"), _rows(out2 / "metrics.csv")
    assert without_wall_clock(a) == without_wall_clock(b)  # every physics step kept (--store full): the same metrics
    episodes = open_episodes(out2)
    for entry in episodes.entries:
        ep = episodes.load(entry)
        assert entry.row is not None and entry.row["store"] == "full"
        assert len(ep.trajectory.t_s) == round(ep.trajectory.t_s[-1] * 500) + 1  # 500 Hz
        assert np.trapezoid(ep.trajectory.shaft_power_W, ep.trajectory.t_s) == pytest.approx(ep.meta.energy_J,
                                                                                               rel=1e-3)
    # an interrupted run: one episode missing, no metrics or report yet -> `report` scores what exists
    for name in ("metrics.csv", "summary.json", "report.pdf"):
        (out2 / name).unlink()
    table = read_episode_table(out2)
    write_episode_table(store_dir(out2) / EPISODE_TABLE, [r for r in table if r["method"] != "ppo"])
    assert main(["report", str(out2)]) == 0
    rows = _rows(out2 / "metrics.csv")
    assert [r["method"] for r in rows] == ["rrt_mpc"]
    assert without_wall_clock(rows) == without_wall_clock([r for r in a if r["method"] == "rrt_mpc"])
    assert (out2 / "report.pdf").is_file()
    # --resume flies only the missing cell
    assert main(["run", str(TINY), "--out", str(out2), "--resume", "--no-progress", "--videos", "none"]) == 0
    assert without_wall_clock(_rows(out2 / "metrics.csv")) == without_wall_clock(a)


def test_golden_metrics(tiny_run):
    """Physics, planner or policy changes that move these numbers must be deliberate (update the file)."""
    golden = json.loads(GOLDEN.read_text())
    rows = {r["method"]: r for r in _rows(tiny_run / "metrics.csv")}
    for pilot, expected in golden["methods"].items():
        for column, value in expected.items():
            tol = golden["tolerances"].get(column, 0.0)
            got = rows[pilot][column]
            if isinstance(value, str):
                assert got == value, (pilot, column)
            else:
                assert float(got) == pytest.approx(value, abs=tol), (pilot, column)


def test_bad_inputs_exit_non_zero_before_flying(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text(TINY.read_text().replace("start: [20.0, 40.0, 10.0]", "start: [60.0, 40.0, 10.0]"))
    out = tmp_path / "never"
    assert main(["run", str(bad), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "bad.yaml" in err and "episodes[0].start" in err and not out.exists()
    assert main(["run", str(TINY), "--pilots", "ppo,astar", "--out", str(out)]) == 2
    assert "astar" in capsys.readouterr().err
    assert main(["validate", str(bad)]) == 2
    assert main(["validate", str(TINY)]) == 0
    assert main(["report", str(tmp_path)]) == 2
    assert "run.json" in capsys.readouterr().err


def test_python_m_compare_help():
    r = subprocess.run([sys.executable, "-m", "compare", "run", "--help"], capture_output=True, text=True, check=True)
    assert "--jobs" in r.stdout and "--pilots" in r.stdout
