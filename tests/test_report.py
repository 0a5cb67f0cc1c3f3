"""The PDF report from a synthetic run folder (no simulation): pages, text, PNGs, atomic writes, rebuilds."""
from __future__ import annotations

import csv
import json
import time
from pathlib import Path

import numpy as np
import pytest
from pypdf import PdfReader

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
from compare.trajectory import EpisodeKey, EpisodeMeta, SavedEpisode, save_episode
from uam_fdm.city import Building, BuildingMap
from uam_fdm.citygen import map_yaml_text

SCENARIO = "toy-quad"
LABELS = {"ppo": "PPO policy", "rrt_mpc": "RRT* + MPC"}
START, GOAL = (20.0, 20.0, 10.0), (170.0, 160.0, 20.0)
METRIC_COLUMNS = ["scenario", "episode", "method", "seed", "map", "vehicle", "outcome", "success",
                  "collision", "failure_reason", "min_clearance_m", "time_below_2m_s", "time_below_5m_s",
                  "time_s", "path_length_m", "straight_line_m", "spl", "energy_kj", "compute_ms_mean",
                  "compute_ms_max", "plan_time_s"]
# 1 title + 3 metrics (per method, paired, per episode) + 2 episodes x 3 + 1 training
# + 2 failures (table, paths)
FULL_PAGES = 13


def _toy_map() -> BuildingMap:
    parts = [Building(0, (60.0, 60.0), (20.0, 15.0), 30.0, 0.2),
             Building(1, (120.0, 70.0), (18.0, 18.0), 45.0),
             Building(2, (80.0, 140.0), (25.0, 12.0), 20.0, -0.3),
             Building(3, (190.0, 30.0), (16.0, 30.0), 25.0)]
    return BuildingMap(parts, (0.0, 0.0, 0.0), (200.0, 200.0, 80.0), name="toy")


def _trajectory(n: int, duration_s: float, bend_m: float, stop_frac: float, outcome: str,
                seed: int) -> Trajectory:
    """A smooth synthetic flight from START towards GOAL (bent sideways by `bend_m`), cut at `stop_frac`."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, duration_s, n)
    s = stop_frac * t / duration_s
    a, b = np.array(START), np.array(GOAL)
    side = np.array([-(b - a)[1], (b - a)[0], 0.0]) / np.linalg.norm((b - a)[:2])
    pos = a + s[:, None] * (b - a) + (bend_m * np.sin(np.pi * s))[:, None] * side
    vel = np.gradient(pos, t, axis=0)
    rotors = 620.0 + 15.0 * rng.standard_normal((n, 4))
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    states = np.hstack([pos, vel, quat, np.zeros((n, 3)), rotors])
    clearance = 8.0 + 6.0 * np.cos(3.0 * s) - (9.0 * s if outcome == "collision" else 0.0)
    decisions = t[::10]
    return Trajectory(t_s=t, states=states, rotor_commands=rotors,
                      wind_enu_m_s=np.tile([2.0, 1.0, 0.0], (n, 1)), clearance_m=clearance,
                      decision_t_s=decisions, compute_s=np.full(len(decisions), 2e-3),
                      energy_J=1000.0 * duration_s, outcome=outcome, plan_time_s=0.3,
                      detail=f"synthetic {outcome}")


def _write_run(run_dir: Path, policy_dir: Path | None) -> None:
    """Two methods x two episodes x one seed; PPO's episode 1 ends in a collision."""
    (run_dir / "maps").mkdir(parents=True)
    (run_dir / "maps" / f"{SCENARIO}.yaml").write_text(map_yaml_text(_toy_map()), encoding="utf-8")
    # (episode, method): samples, duration [s], sideways bend [m], fraction of the way flown, outcome
    cells = {(0, "ppo"): (3000, 30.0, 25.0, 1.0, "success"),
             (0, "rrt_mpc"): (1500, 26.0, -10.0, 1.0, "success"),
             (1, "ppo"): (800, 12.0, 5.0, 0.45, "collision"),
             (1, "rrt_mpc"): (1200, 24.0, 15.0, 1.0, "success")}
    rows = []
    for (ep, method), (n, dur, bend, stop, outcome) in cells.items():
        key = EpisodeKey(SCENARIO, ep, method, 0)
        extra = {"torque_coeff_Nm_s2": 1.2e-7, "density_ratio": 0.95} if ep == 0 else {"mpc_failures": 0}
        meta = EpisodeMeta(key, "toy", "small_quad", START, GOAL, 3.0, 60.0, 0.42, 4, 1000.0 * dur, outcome,
                           0.3 if method == "rrt_mpc" else 0.0, f"synthetic {outcome}", extra)
        traj = _trajectory(n, dur, bend, stop, outcome, ep)
        save_episode(run_dir / "episodes" / f"{key.stem}.npz", meta, traj)
        ok = outcome == "success"
        rows.append([SCENARIO, ep, method, 0, "toy", "small_quad", outcome, int(ok), int(not ok),
                     "" if ok else "collision", 4.1, 0.0, 1.5, dur, 230.0, 206.2, 0.85 if ok else 0.0,
                     dur, 2.0, 3.5, 0.3 if method == "rrt_mpc" else "nan"])
    with (run_dir / "metrics.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(METRIC_COLUMNS)
        w.writerows(rows)
    stat = {"mean": 0.5, "ci_low": 0.0, "ci_high": 1.0, "n": 2}
    summary = {"bootstrap": {"resamples": 1000, "seed": 0, "level": 0.95},
               "metrics": ["success", "collision", "min_clearance_m", "time_s", "energy_kj"],
               "methods": {"ppo": {"episodes": 2, "failure_reasons": {"collision": 1}, "success": stat,
                                   "collision": stat, "min_clearance_m": {**stat, "mean": 4.1},
                                   "time_s": {"mean": 21.0, "ci_low": None, "ci_high": None, "n": 2}},
                           "rrt_mpc": {"episodes": 2, "failure_reasons": {}, "success": {**stat, "mean": 1.0},
                                       "energy_kj": {**stat, "mean": 25.0}}},
               "paired": {"ppo - rrt_mpc": {"episodes": 2, "time_s": {"mean_diff": -4.0, "ci_low": -8.0,
                                                                      "ci_high": 1.0, "n": 2}}}}
    (run_dir / "summary.json").write_text(json.dumps(summary), encoding="utf-8")
    if policy_dir is not None:
        policy_dir.mkdir(parents=True, exist_ok=True)
        steps = np.arange(1, 21) * 10_000
        lines = ["timesteps,mean_episode_reward,success_rate"]
        lines += [f"{s},{-50 + 60 * (1 - np.exp(-s / 6e4)):.3f},{'' if k % 4 else min(1.0, k / 16):}"
                  for k, s in enumerate(steps)]
        (policy_dir / "reward_curve.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    scenario = {"name": SCENARIO, "source": "/tmp/toy-quad.yaml", "description": "Synthetic test scenario.",
                "map_name": "toy", "vehicle": "small_quad",
                "vehicle_summary": "1.5 kg, 4 rotors, collision radius 0.42 m",
                "atmosphere": {"elevation_m": 1500.0, "isa_offset_k": 15.0, "density_kg_m3": 0.999},
                "wind": {"steady_enu_m_s": [2, 1, 0], "turbulence": "light"}, "episodes": 2, "seeds": [0],
                "methods": ["ppo", "rrt_mpc"], "physics_hz": 500, "control_hz": 50}
    run = {"format_version": 1, "created_utc": "2026-11-21T08:00:00Z", "command": "uam-compare run toy",
           "scenarios": [scenario],
           "methods": {"ppo": {"label": LABELS["ppo"], "policy_dir": str(policy_dir) if policy_dir else None,
                               "description": "Learned pilot."},
                       "rrt_mpc": {"label": LABELS["rrt_mpc"], "description": "Classical pilot."}},
           "versions": {"uam-compare": "0.1.0", "python": "3.11.7", "numpy": np.__version__},
           "fairness": "Both pilots know the map, the start and the goal. Neither knows the wind. " * 4}
    (run_dir / "run.json").write_text(json.dumps(run), encoding="utf-8")


def _texts(pdf: Path) -> list[str]:
    return [p.extract_text() or "" for p in PdfReader(pdf).pages]


def _hidden(folder: Path) -> list[str]:
    return [p.name for p in folder.rglob("*") if p.name.startswith(".") or p.name.endswith(".tmp")]


@pytest.fixture(scope="module")
def full_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, float]:
    root = tmp_path_factory.mktemp("report")
    run_dir = root / "run"
    _write_run(run_dir, root / "policy")
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
    _write_run(run_dir, None)
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
    _write_run(run_dir, tmp_path / "policy")
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
    cropped = crop_map(_toy_map(), np.array([50.0, 50.0, 0.0]), np.array([125.0, 100.0, 50.0]))
    assert sorted(p.id for p in cropped.buildings) == [0, 1]  # 1 is cut by the box edge, 2 and 3 are outside
    for p in cropped.buildings:
        fp = p.footprint_xy_m()
        assert fp[:, 0].min() >= 50.0 - 1e-9 and fp[:, 0].max() <= 125.0 + 1e-9


def test_nonfinite_and_planner_failure_episodes_draw(tmp_path: Path) -> None:
    """A flight that went non-finite ends at its last finite position; a one-sample flight still draws."""
    broken = _trajectory(500, 10.0, 0.0, 0.5, "nonfinite", 0)
    states = broken.states.copy()
    states[400:] = np.nan
    clearance = broken.clearance_m.copy()
    clearance[400:] = np.nan
    broken = Trajectory(**{**broken.__dict__, "states": states, "clearance_m": clearance})
    two = _trajectory(2, 1.0, 0.0, 0.0, "planner_failure", 0)
    first = ("t_s", "states", "rotor_commands", "wind_enu_m_s", "clearance_m")
    stub = Trajectory(**{**two.__dict__, **{k: getattr(two, k)[:1] for k in first}})
    traces = []
    for method, traj in (("ppo", broken), ("rrt_mpc", stub)):
        meta = EpisodeMeta(EpisodeKey(SCENARIO, 0, method, 0), "toy", "small_quad", START, GOAL, 3.0, 60.0,
                           0.42, 4, 0.0, traj.outcome, 0.0, "", None)
        traces.append(trace_from_episode(SavedEpisode(meta, traj), LABELS[method], METHOD_COLORS[method]))
    assert len(traces[0].t_s) == 400 and np.all(np.isfinite(traces[0].pos_m))
    assert len(traces[1].t_s) == 1
    for fig in (episode_paths_figure("Episode x", traces, _toy_map()),
                episode_timeseries_figure("Episode x", traces),
                episode_snapshots_figure("Episode x", traces, None)):
        fig.savefig(tmp_path / "f.png", dpi=40)
