"""The PDF report from a synthetic run folder (no simulation): pages, text, PNGs, atomic writes, rebuilds."""
from __future__ import annotations

import csv
import time
from pathlib import Path

import numpy as np
import pytest
from pypdf import PdfReader
from synthetic_run import GOAL, LABELS, METRIC_COLUMNS, SCENARIO, START, toy_map, trajectory, write_run

from compare.figures import (
    MAX_PLOT_POINTS,
    METHOD_COLORS,
    crop_map,
    downsample_indices,
    episode_paths_figure,
    episode_snapshots_figure,
    episode_timeseries_figure,
    method_colors,
    trace_from_episode,
)
from compare.report import build_report
from compare.runner import Trajectory
from compare.trajectory import EpisodeKey, EpisodeMeta, SavedEpisode

# 1 title + 3 metrics (per method, paired, per episode) + 2 episodes x 3 + 1 training
# + 2 failures (table, paths)
FULL_PAGES = 13


def _texts(pdf: Path) -> list[str]:
    return [p.extract_text() or "" for p in PdfReader(pdf).pages]


def _hidden(folder: Path) -> list[str]:
    return [p.name for p in folder.rglob("*") if p.name.startswith(".") or p.name.endswith(".tmp")]


@pytest.fixture(scope="module")
def full_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, float]:
    root = tmp_path_factory.mktemp("report")
    run_dir = root / "run"
    write_run(run_dir, root / "policy")
    t0 = time.perf_counter()
    pdf = build_report(run_dir)
    return run_dir, pdf, time.perf_counter() - t0


def test_full_report_pages_text_and_pngs(full_run: tuple[Path, Path, float]) -> None:
    run_dir, pdf, seconds = full_run
    print(f"build_report on the fixture: {seconds:.1f} s")
    assert pdf == run_dir / "report.pdf" and pdf.read_bytes()[:5] == b"%PDF-"
    texts = _texts(pdf)
    assert len(texts) == FULL_PAGES
    assert "uam-compare report" in texts[0]
    for needle in ("toy-quad", "1500", "0.999", "turbulence light", "uam-compare run toy", "2026-11-21",
                   "Neither knows the wind", "numpy", "4 of 4 planned"):
        assert needle in texts[0], needle
    assert all(t.startswith("Metrics") or "Metrics:" in t for t in texts[1:4])
    assert "mean [95 % CI]" in texts[1] and "50 [0, 100]" in texts[1] and "21.0" in texts[1]
    assert "paired differences" in texts[2] and "-4.0 [-8.0, 1.0]" in texts[2]
    episode_pages = texts[4:10]
    assert all(f"Episode {SCENARIO} #" in t for t in episode_pages)
    assert "#0 seed 0" in episode_pages[0] and "#1 seed 0" in episode_pages[3]
    assert "rotor power [kW]" in episode_pages[1]          # episode 0 saved km and σ
    assert "mean rotor speed [rad/s]" in episode_pages[4]  # episode 1 did not
    assert all("x east [m]" in texts[i] for i in (4, 6, 7, 9))
    assert "clearance [m]" in episode_pages[1] and "time [s]" in episode_pages[1]
    assert "reward convergence" in texts[10] and "success rate [%]" in texts[10]
    assert "Failures" in texts[11] and "collision" in texts[11] and "synthetic collision" in texts[11]
    assert "Failures" in texts[12]
    whole = "\n".join(texts)
    for label in LABELS.values():
        assert label in whole
    pngs = sorted(p.name for p in (run_dir / "figures").glob("*.png"))
    assert len(pngs) == FULL_PAGES
    assert {"title.png", "training_reward_curve.png", "failures_paths.png",
            f"episode_{SCENARIO}__ep000__s0_snapshots.png"} <= set(pngs)
    assert _hidden(run_dir) == []
    assert seconds < 25.0


def test_rebuild_incomplete_run_without_reward_curve_or_metrics(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    write_run(run_dir, None)
    (run_dir / "metrics.csv").unlink()
    (run_dir / "episodes" / f"{EpisodeKey(SCENARIO, 1, 'rrt_mpc', 0).stem}.npz").unlink()
    out = build_report(run_dir, tmp_path / "out" / "r.pdf")
    assert out == tmp_path / "out" / "r.pdf"
    texts = _texts(out)
    assert len(texts) == FULL_PAGES - 2  # one metrics note page instead of three
    assert "3 of 4 planned" in texts[0] and "interrupted" in texts[0]
    assert "Metrics" in texts[1] and "metrics.csv was not found" in texts[1]
    assert "reward convergence" in texts[8] and "No PPO policy folder" in texts[8]
    assert "Failures" in texts[9] and "synthetic collision" in texts[9]
    assert _hidden(tmp_path) == []


def test_reward_curve_file_absent_and_no_failures(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    write_run(run_dir, tmp_path / "policy")
    (tmp_path / "policy" / "reward_curve.csv").unlink()
    (run_dir / "summary.json").unlink()
    keep = {EpisodeKey(SCENARIO, 0, m, 0).stem for m in LABELS}
    for p in (run_dir / "episodes").glob("*.npz"):
        if p.stem not in keep:
            p.unlink()
    rows = list(csv.DictReader((run_dir / "metrics.csv").open()))
    with (run_dir / "metrics.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, METRIC_COLUMNS)
        w.writeheader()
        w.writerows(r for r in rows if r["episode"] == "0")
    texts = _texts(build_report(run_dir))
    # title, metrics per method (plain means: no summary.json, so no paired page), per episode,
    # 3 episode pages, training note, "No failures"
    assert len(texts) == 8
    assert "plain means" in texts[1]
    assert "reward_curve.csv does not exist" in texts[6].replace("\n", "")
    assert "No failures" in texts[7]


def test_missing_run_json_names_the_folder(tmp_path: Path) -> None:
    run_dir = tmp_path / "not-a-run"
    run_dir.mkdir()
    with pytest.raises(ValueError, match="not-a-run"):
        build_report(run_dir)
    assert list(run_dir.iterdir()) == []


def test_plot_helpers() -> None:
    idx = downsample_indices(10_001, keep=[7777])
    assert len(idx) <= MAX_PLOT_POINTS and idx[0] == 0 and idx[-1] == 10_000 and 7777 in idx
    assert np.all(np.diff(idx) > 0)
    assert np.array_equal(downsample_indices(50), np.arange(50))
    colors = method_colors(["rrt_mpc", "new_a", "ppo", "new_b"])
    assert colors["ppo"] == METHOD_COLORS["ppo"] and colors["rrt_mpc"] == METHOD_COLORS["rrt_mpc"]
    assert len({colors["new_a"], colors["new_b"], colors["ppo"], colors["rrt_mpc"]}) == 4
    cropped = crop_map(toy_map(), np.array([50.0, 50.0, 0.0]), np.array([125.0, 100.0, 50.0]))
    assert sorted(p.id for p in cropped.buildings) == [0, 1]  # 1 is cut by the box edge, 2 and 3 are outside
    for p in cropped.buildings:
        fp = p.footprint_xy_m()
        assert fp[:, 0].min() >= 50.0 - 1e-9 and fp[:, 0].max() <= 125.0 + 1e-9


def test_nonfinite_and_planner_failure_episodes_draw(tmp_path: Path) -> None:
    """A flight that went non-finite ends at its last finite position; a one-sample flight still draws."""
    broken = trajectory(500, 10.0, 0.0, 0.5, "nonfinite", 0)
    states = broken.states.copy()
    states[400:] = np.nan
    clearance = broken.clearance_m.copy()
    clearance[400:] = np.nan
    broken = Trajectory(**{**broken.__dict__, "states": states, "clearance_m": clearance})
    two = trajectory(2, 1.0, 0.0, 0.0, "planner_failure", 0)
    first = ("t_s", "states", "rotor_commands", "wind_enu_m_s", "clearance_m")
    stub = Trajectory(**{**two.__dict__, **{k: getattr(two, k)[:1] for k in first}})
    traces = []
    for method, traj in (("ppo", broken), ("rrt_mpc", stub)):
        meta = EpisodeMeta(EpisodeKey(SCENARIO, 0, method, 0), "toy", "small_quad", START, GOAL, 3.0, 60.0,
                           0.42, 4, 0.0, traj.outcome, 0.0, "", None)
        traces.append(trace_from_episode(SavedEpisode(meta, traj), LABELS[method], METHOD_COLORS[method]))
    assert len(traces[0].t_s) == 400 and np.all(np.isfinite(traces[0].pos_m))
    assert len(traces[1].t_s) == 1
    for fig in (episode_paths_figure("Episode x", traces, toy_map()),
                episode_timeseries_figure("Episode x", traces),
                episode_snapshots_figure("Episode x", traces, None)):
        fig.savefig(tmp_path / "f.png", dpi=40)
