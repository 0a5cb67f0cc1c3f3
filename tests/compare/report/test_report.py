"""The PDF report from a synthetic run folder (no simulation): pages, text, PNGs, atomic writes, rebuilds."""
from __future__ import annotations

import csv
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from pypdf import PdfReader

from compare.flying.episode_loop import Trajectory
from compare.report.figures import (
    CURVE_FIELDS,
    MAX_PLOT_POINTS,
    PILOT_COLORS,
    RewardCurve,
    crop_map,
    curriculum_stages,
    downsample_indices,
    moving_average,
    pilot_colors,
    reward_curve_figure,
    seed_curves_figure,
    smoothing_window,
    trace_from_episode,
)
from compare.report.flight_figures import episode_paths_figure, episode_snapshots_figure, episode_timeseries_figure
from compare.report.report import build_report, read_reward_curve
from compare.results.trajectory import EpisodeKey, EpisodeMeta, SavedEpisode, load_episode, save_episode
from synthetic_run import (
    CURVE_COLUMNS,
    GOAL,
    LABELS,
    METRIC_COLUMNS,
    SCENARIO,
    START,
    UPDATE_STEPS,
    synthetic_power_W,
    toy_map,
    trajectory,
    write_reward_curve,
    write_run,
)

# 2 first pages (the headline, about this run) + 7 metrics pages of the one vehicle (per pilot, forest, paired
# forest and table, difficulty, per scenario with its conditions, per episode) + 2 episodes x 3 + 1 training
# + 2 failures (table, paths)
FIRST_PAGES = 2
METRICS_PAGES = 7
EPISODES = FIRST_PAGES + METRICS_PAGES  # the first episode page
TRAINING = EPISODES + 6
FULL_PAGES = TRAINING + 3


def _texts(pdf: Path) -> list[str]:
    return [p.extract_text() or "" for p in PdfReader(pdf).pages]


def _hidden(folder: Path) -> list[str]:
    return [p.name for p in folder.rglob("*") if p.name.startswith(".") or p.name.endswith(".tmp")]


@pytest.fixture(scope="module")
def full_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The synthetic run folder and its report (how long the report takes: perf/responsiveness.py)."""
    root = tmp_path_factory.mktemp("report")
    run_dir = root / "run"
    write_run(run_dir, root / "policy")
    return run_dir, build_report(run_dir)


def test_full_report_pages_text_and_pngs(full_run: tuple[Path, Path]) -> None:
    run_dir, pdf = full_run
    assert pdf == run_dir / "report.pdf" and pdf.read_bytes()[:5] == b"%PDF-"
    texts = _texts(pdf)
    assert len(texts) == FULL_PAGES
    assert all(f"page {k + 1}" in t for k, t in enumerate(texts))
    # page 1: the headline, per vehicle and pilot, and the pilots' paired difference
    head = texts[0].replace("\n", " ")
    for needle in ("uam-compare report", "uam-compare run toy", "2026-11-21", "4 of 4 planned", "small_quad",
                   "50 [9, 91]", "100 [34, 100]", "Paired differences on the same tasks", "n/a (n < 10)"):
        assert needle in head, needle
    about = texts[1]
    for needle in ("About this run", "toy-quad", "1500", "0.999", "turbulence light", "Neither knows the wind",
                   "numpy"):
        assert needle in about, needle
    assert all("small_quad: " in t for t in texts[FIRST_PAGES:EPISODES])  # the run's one vehicle
    # its summary.json predates per-vehicle summaries (it may pool vehicles): recomputed from metrics.csv
    pilots = texts[2].replace("\n", " ")
    assert "per pilot, mean [95 % CI]" in pilots and "predates per-vehicle summaries" in pilots
    assert "50 [9, 91]" in pilots and "30.0 (n=1, no CI)" in pilots  # PPO: 1 of 2 (Wilson), its one success
    assert "paired differences" in texts[4] and "4.0 (n=1, no CI)" in texts[5] and "MDD" in texts[5]
    assert "where does each pilot break?" in texts[6] and "leg length [m]" in texts[6]
    assert "per scenario" in texts[7] and "The scenarios and their conditions" in texts[7]
    assert "Each pilot per scenario" in texts[7] and "per episode" in texts[8]
    episode_pages = texts[EPISODES:TRAINING]
    assert all(f"Episode {SCENARIO} #" in t for t in episode_pages)
    assert "#0 seed 0" in episode_pages[0] and "#1 seed 0" in episode_pages[3]
    assert "rotor power [kW]" in episode_pages[1]          # episode 0 saved its shaft power per step
    assert "mean rotor speed [rad/s]" in episode_pages[4]  # episode 1 did not
    assert all("x east [m]" in texts[EPISODES + i] for i in (0, 2, 3, 5))
    assert "clearance [m]" in episode_pages[1] and "time [s]" in episode_pages[1]
    assert "reward convergence" in texts[TRAINING] and "success rate [%]" in texts[TRAINING]
    for needle in ("Plain PPO from scratch", "validation", "difficulty 0.25", "difficulty 1.00", "kept checkpoint",
                   "moving average"):
        assert needle in texts[TRAINING], needle
    failures = texts[TRAINING + 1]
    assert "Failures" in failures and "collision" in failures and "synthetic collision" in failures
    assert "Failures" in texts[TRAINING + 2]
    whole = "\n".join(texts)
    for label in LABELS.values():
        assert label in whole
    pngs = sorted(p.name for p in (run_dir / "figures").glob("*.png"))
    assert len(pngs) == FULL_PAGES
    assert {"title.png", "about.png", "training_reward_curve.png", "failures_paths.png",
            f"episode_{SCENARIO}__ep000__s0_snapshots.png"} <= set(pngs)
    assert _hidden(run_dir) == []


def test_rebuild_incomplete_run_without_reward_curve_or_metrics(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    write_run(run_dir, None)
    (run_dir / "metrics.csv").unlink()
    (run_dir / "episodes" / f"{EpisodeKey(SCENARIO, 1, 'rrt_mpc', 0).stem}.npz").unlink()
    out = build_report(run_dir, tmp_path / "out" / "r.pdf")
    assert out == tmp_path / "out" / "r.pdf"
    texts = _texts(out)
    assert len(texts) == FULL_PAGES - METRICS_PAGES + 1  # one metrics note page instead
    head = texts[0].replace("\n", " ")
    assert "3 of 4 planned" in head and "interrupted" in head and "No headline: metrics.csv was not found" in head
    assert "Metrics" in texts[2] and "metrics.csv was not found in the run folder" in texts[2]
    assert "reward convergence" in texts[9] and "No PPO policy folder" in texts[9]
    assert "Failures" in texts[10] and "synthetic collision" in texts[10]
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
    # the first pages, the metrics pages (no summary.json: computed from metrics.csv), 3 episode pages, training
    # note, "No failures"
    assert len(texts) == FIRST_PAGES + METRICS_PAGES + 3 + 2
    assert "summary.json is missing" in texts[2] and "100 [21, 100]" in texts[2]  # 1 of 1 (Wilson)
    assert "holds no reward_curve.csv here" in texts[-2].replace("\n", " ")
    assert "No failures" in texts[-1]


def test_report_reads_an_old_run_folder(tmp_path: Path) -> None:
    """A run folder as the first versions wrote it: one ppo policy_dir (no policies per vehicle), no wind shear,
    notes or fingerprints in run.json, no tracker columns in metrics.csv, no shaft power in the episode files."""
    run_dir = tmp_path / "run"
    write_run(run_dir, tmp_path / "policy")
    info = json.loads((run_dir / "run.json").read_text())
    info["methods"]["ppo"] = {"label": LABELS["ppo"], "description": "Learned pilot.",
                              "policy_dir": str(tmp_path / "policy"), "decision_hz": 10.0}
    assert "shear" not in info["scenarios"][0]["wind"] and "fingerprints" not in info and "notes" not in info
    (run_dir / "run.json").write_text(json.dumps(info))
    for path in (run_dir / "episodes").glob("*.npz"):
        ep = load_episode(path)
        save_episode(path, ep.meta, replace(ep.trajectory, shaft_power_W=None))
        assert load_episode(path).trajectory.shaft_power_W is None
    texts = _texts(build_report(run_dir))
    assert len(texts) == FULL_PAGES
    # the policy folder lies beside the run folder: shown relative to it, not as this machine's path
    assert "policy ../policy; decides at 10 Hz" in texts[1].replace("\n", " ")
    assert str(tmp_path) not in "".join(texts).replace("\n", "")
    assert "the same at every height" in texts[1] and "4 of 4 planned" in texts[0]
    assert "50 [9, 91]" in texts[2] and "4.0 (n=1, no CI)" in texts[5]
    for page in (texts[EPISODES + 1], texts[EPISODES + 4]):  # the time series: mean rotor speed, and why
        assert "mean rotor speed [rad/s]" in page and "shaft power not in this episode file" in page.replace("\n", " ")
    assert "reward convergence" in texts[TRAINING] and "kept checkpoint" in texts[TRAINING]


def test_power_is_the_saved_per_step_column(tmp_path: Path) -> None:
    """The time series draws the shaft power the episode file saved per step (not a formula of the rotor speeds)."""
    run_dir = tmp_path / "run"
    write_run(run_dir, None)
    saved = load_episode(run_dir / "episodes" / f"{EpisodeKey(SCENARIO, 0, 'ppo', 0).stem}.npz")
    t = np.asarray(saved.trajectory.t_s)
    np.testing.assert_array_equal(saved.trajectory.shaft_power_W, synthetic_power_W(t))
    trace = trace_from_episode(saved, LABELS["ppo"], PILOT_COLORS["ppo"])
    assert len(trace.t_s) < len(t)  # reduced for drawing: the samples kept are the saved ones
    np.testing.assert_array_equal(trace.rotor_kw, synthetic_power_W(trace.t_s) / 1e3)
    fig = episode_timeseries_figure("Episode x", [trace])
    ax_p = fig.axes[2]
    (line,) = ax_p.get_lines()
    np.testing.assert_array_equal(line.get_ydata(), synthetic_power_W(trace.t_s) / 1e3)
    assert ax_p.get_ylabel() == "rotor power [kW]"
    # an episode file without the column (saved before it was recorded): mean rotor speed, and the panel says why
    old = load_episode(run_dir / "episodes" / f"{EpisodeKey(SCENARIO, 1, 'ppo', 0).stem}.npz")
    old_trace = trace_from_episode(old, LABELS["ppo"], PILOT_COLORS["ppo"])
    assert old_trace.rotor_kw is None
    fig = episode_timeseries_figure("Episode x", [trace, old_trace])
    assert fig.axes[2].get_ylabel() == "mean rotor speed [rad/s]"
    assert "shaft power not in this episode file" in fig.axes[2].get_title()


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
    colors = pilot_colors(["rrt_mpc", "new_a", "ppo", "new_b"])
    assert colors["ppo"] == PILOT_COLORS["ppo"] and colors["rrt_mpc"] == PILOT_COLORS["rrt_mpc"]
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
    for pilot, traj in (("ppo", broken), ("rrt_mpc", stub)):
        meta = EpisodeMeta(EpisodeKey(SCENARIO, 0, pilot, 0), "toy", "small_quad", START, GOAL, 3.0, 60.0,
                           0.42, 4, 0.0, traj.outcome, 0.0, "", None)
        traces.append(trace_from_episode(SavedEpisode(meta, traj), LABELS[pilot], PILOT_COLORS[pilot]))
    assert len(traces[0].t_s) == 400 and np.all(np.isfinite(traces[0].pos_m))
    assert len(traces[1].t_s) == 1
    for fig in (episode_paths_figure("Episode x", traces, toy_map()),
                episode_timeseries_figure("Episode x", traces),
                episode_snapshots_figure("Episode x", traces, None)):
        fig.savefig(tmp_path / "f.png", dpi=40)


# ---- the training page and the seeds figure -----------------------------------------------------------
def _labelled(ax) -> dict:
    return {line.get_label(): line for line in ax.get_lines()}


def test_curve_columns_match_the_trainer() -> None:
    from rl.policies.folder import CURVE_COLUMNS as TRAIN_COLUMNS

    assert tuple(CURVE_COLUMNS) == TRAIN_COLUMNS
    assert set(TRAIN_COLUMNS) == {"timesteps", "mean_episode_reward", "success_rate", *CURVE_FIELDS}


def test_read_reward_curve_new_format(tmp_path: Path) -> None:
    info = write_reward_curve(tmp_path, updates=100, eval_every=25)
    curve = read_reward_curve(tmp_path / "reward_curve.csv")
    assert len(curve.timesteps) == 100 and curve.timesteps[0] == UPDATE_STEPS
    assert list(np.flatnonzero(curve.has_validation)) == info["validation_rows"] == [24, 49, 74, 99]
    assert np.all(np.isnan(curve.collision_rate[~curve.has_validation]))
    assert np.all(curve.eval_episodes[curve.has_validation] == 200)
    assert np.isnan(curve.mean_episode_reward[19]) and curve.train_episodes[19] == 0  # no episode ended
    assert np.all(np.isfinite(curve.difficulty)) and np.all(np.diff(curve.wall_s) > 0)
    stages = curriculum_stages(curve)
    assert [d for *_, d in stages] == [0.25, 0.5, 0.75, 1.0]
    assert stages[0][0] == 0.0 and stages[-1][1] == curve.timesteps[-1]
    assert all(a[1] == b[0] for a, b in zip(stages, stages[1:]))  # the stages tile the run


def test_read_reward_curve_old_format_and_bad_files(tmp_path: Path) -> None:
    old = tmp_path / "old.csv"
    # the format before one row per update (a row per evaluation only), with a half-written last line
    old.write_text("timesteps,mean_episode_reward,success_rate,collision_rate,eval_episodes,wall_s\n"
                   "0,nan,0.9150,0.0000,200,86.8\n2000128,180.9,0.9150,0.0,200,184.8\n4000000,129.5,0.795\n40",
                   encoding="utf-8")
    curve = read_reward_curve(old)
    assert list(curve.timesteps) == [0, 2000128, 4000000, 40]
    assert np.isnan(curve.mean_episode_reward[0]) and curve.success_rate[2] == 0.795
    assert np.isnan(curve.wall_s[2]) and curve.wall_s[1] == 184.8
    for name in ("train_success_rate", "train_episodes", "difficulty"):
        assert np.all(np.isnan(getattr(curve, name))), name
    assert curriculum_stages(curve) == []
    reward_curve_figure("t", curve, "note", kept_timesteps=2000128).savefig(tmp_path / "old.png", dpi=30)
    assert read_reward_curve(tmp_path / "absent.csv") is None
    bad = tmp_path / "bad.csv"
    bad.write_text("steps,reward\n1,2\n", encoding="utf-8")
    with pytest.raises(ValueError, match="bad.csv"):
        read_reward_curve(bad)
    bad.write_text("timesteps,mean_episode_reward\n", encoding="utf-8")
    with pytest.raises(ValueError, match="at least one row"):
        read_reward_curve(bad)
    # the three-column constructor still works; absent columns are NaN
    short = RewardCurve(np.arange(3.0), np.zeros(3), np.full(3, np.nan))
    assert short.difficulty.shape == (3,) and np.all(np.isnan(short.wall_s))
    with pytest.raises(ValueError, match="difficulty"):
        RewardCurve(np.arange(3.0), np.zeros(3), np.zeros(3), difficulty=np.ones(2))


def test_moving_average_and_window() -> None:
    assert smoothing_window(1220) == 25 and smoothing_window(100) == 3 and smoothing_window(10) == 1
    assert smoothing_window(200) == 5  # 4 rounded up to odd: centred
    v = np.array([0.0, 3.0, np.nan, 9.0, 12.0])
    out = moving_average(v, 3)
    np.testing.assert_allclose(out, [1.5, 1.5, 6.0, 10.5, 10.5])  # NaN skipped, ends cut short
    assert np.isnan(moving_average(np.array([1.0, np.nan, np.nan, np.nan]), 3)[2])
    np.testing.assert_array_equal(moving_average(v, 1)[[0, 1, 3]], v[[0, 1, 3]])


def test_training_page_draws_return_validation_stages_and_kept(tmp_path: Path) -> None:
    info = write_reward_curve(tmp_path, updates=400, eval_every=50, kept_update=350)
    curve = read_reward_curve(tmp_path / "reward_curve.csv")
    fig = reward_curve_figure("PPO training: reward convergence", curve, "from x",
                              kept_timesteps=info["kept_timesteps"], subtitle="Plain PPO from scratch")
    ax, ax2 = fig.axes
    lines, lines2 = _labelled(ax), _labelled(ax2)
    raw = lines["training return, per update"]
    smooth = next(line for label, line in lines.items() if label.startswith("training return, moving average"))
    assert "9 updates" in smooth.get_label()  # 2 % of 400, odd
    assert len(raw.get_xdata()) == 399  # the update without a finished episode is left out
    np.testing.assert_allclose(smooth.get_ydata(), moving_average(curve.mean_episode_reward, 9)[
        np.isfinite(moving_average(curve.mean_episode_reward, 9))])
    assert np.std(np.diff(smooth.get_ydata())) < np.std(np.diff(raw.get_ydata()))  # smoother
    assert smooth.get_linewidth() > raw.get_linewidth() and raw.get_alpha() < 1
    val = next(line for label, line in lines2.items() if label.startswith("validation success"))
    assert val.get_marker() == "o"
    np.testing.assert_allclose(val.get_xdata(), curve.timesteps[info["validation_rows"]] / 1e6)
    np.testing.assert_allclose(val.get_ydata(), 100 * curve.success_rate[info["validation_rows"]])
    train = next(line for label, line in lines2.items() if label.startswith("training success"))
    assert train.get_linewidth() < val.get_linewidth() and np.nanmax(train.get_ydata()) <= 100.0
    assert ax2.get_ylim() == (-2.0, 102.0)
    kept = next(line for label, line in lines.items() if label.startswith("kept checkpoint"))
    assert kept.get_xdata()[0] == pytest.approx(350 * UPDATE_STEPS / 1e6)
    texts = [t.get_text() for t in ax2.texts]
    assert texts == ["difficulty 0.25", "difficulty 0.50", "difficulty 0.75", "difficulty 1.00"]
    assert len(ax2.patches) == 3  # bands for the stages below full difficulty
    assert "Plain PPO from scratch" in ax.get_title() and "from x" in ax.get_title()
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any("curriculum stages" in t for t in legend) and any("validation" in t for t in legend)
    fig.savefig(tmp_path / "page.png", dpi=40)
    # no curve: the note only
    empty = reward_curve_figure("t", None, "No reward curve: x does not exist.")
    assert not empty.axes and any("does not exist" in t.get_text() for t in empty.texts)


def test_seed_curves_figure_and_script(tmp_path: Path) -> None:
    import importlib.util

    curves, dirs = [], []
    for seed, updates in ((0, 300), (1, 260), (2, 320)):
        folder = tmp_path / f"s{seed}"
        write_reward_curve(folder, updates=updates, seed=seed, rate=0.8 + 0.2 * seed, eval_every=40)
        curves.append(read_reward_curve(folder / "reward_curve.csv"))
        dirs.append(folder)
    fig = seed_curves_figure(curves, ["a", "b", "c"])
    ax_r, ax_s = fig.axes
    for ax, column in ((ax_r, "mean_episode_reward"), (ax_s, "success_rate")):
        lines = _labelled(ax)
        assert {"a", "b", "c", "mean of 3 seeds"} <= set(lines)
        mean = lines["mean of 3 seeds"]
        grid = mean.get_xdata()
        # the common grid covers what every seed covers: up to the shortest run's last point
        ends = [c.timesteps[np.isfinite(getattr(c, column))][-1] for c in curves]
        assert grid[-1] == pytest.approx(min(ends) / 1e6)
        per_seed = np.array([np.interp(grid, lines[k].get_xdata(), lines[k].get_ydata()) for k in "abc"])
        np.testing.assert_allclose(mean.get_ydata(), per_seed.mean(axis=0))
        band = ax.collections[0]
        assert band.get_label() == "min–max across 3 seeds"
        verts = band.get_paths()[0].vertices
        assert verts[:, 1].max() == pytest.approx(per_seed.max())
        assert verts[:, 1].min() == pytest.approx(per_seed.min())
        assert lines["a"].get_linewidth() < mean.get_linewidth()
    smooth_a = curves[0].smoothed()
    np.testing.assert_allclose(_labelled(ax_r)["a"].get_ydata(), smooth_a[np.isfinite(smooth_a)])
    with pytest.raises(ValueError, match="labels"):
        seed_curves_figure(curves, ["a"])
    with pytest.raises(ValueError, match="at least one"):
        seed_curves_figure([], [])

    script = Path(__file__).resolve().parents[3] / "docs" / "seed_curves.py"
    spec = importlib.util.spec_from_file_location("seed_curves", script)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = tmp_path / "figs" / "seeds.png"
    assert mod.main([*map(str, dirs), "--out", str(out), "--dpi", "40"]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and _hidden(tmp_path / "figs") == []
    assert mod.seed_label(dirs[1]) == "seed 1"
    assert mod.main([str(tmp_path / "nowhere"), "--out", str(out)]) == 2


def test_failed_cells_are_listed_and_said_to_be_in_no_rate(tmp_path: Path) -> None:
    from compare.results.failures import FailedCell, FailureKind, write_failure

    run_dir = tmp_path / "run"
    write_run(run_dir, None)
    write_failure(run_dir, FailedCell(EpisodeKey(SCENARIO, 2, "rrt_mpc", 0), FailureKind.CRASH,
                                      "the worker process was killed by SIGKILL", 12.5, "ray",
                                      "node 10.0.0.7 pid 4242"))
    text = " ".join(t.replace("\n", " ") for t in _texts(build_report(run_dir)))
    assert "Failed cells: no episode" in text
    assert "killed by SIGKILL" in text and "ray node 10.0.0.7 pid 4242" in text
    assert "1 cell failed (crash 1; rrt_mpc 1): these cells produced no episode, so they are in no rate" in text
