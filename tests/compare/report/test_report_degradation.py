"""The report of a run flown at several sensing and map-error levels: a degradation page per vehicle, success and
collisions against each level axis, every pilot's line in its colour with its Wilson band. A synthetic run (the real
benchmark-quick's small-quad scenarios at crossed levels, made-up flights), nothing simulated."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from matplotlib.lines import Line2D
from pypdf import PdfReader

from compare.cli import main
from compare.report.degradation_pages import degradation_figure, degradation_pages
from compare.report.figures import pilot_colors
from compare.report.metrics_pages import PilotStyle
from compare.results.level_rates import level_rates
from compare.results.metrics import read_metrics_csv
from compare.results.run_info import read_run_info
from compare.results.trajectory import EpisodeKey, EpisodeMeta, save_episode
from compare.run.campaign import RunConfig, finalize, plan_cells, write_run_files
from compare.scenarios.benchmark import build_task_set
from compare.scenarios.levels import with_levels
from synthetic_run import trajectory

SENSING = ("perfect", "nominal", "degraded")
MAPS = ("exact", "outdated")


def _outcome(pilot: str, sensing: str, map_error: str, episode: int) -> str:
    """The learned pilot collides at degraded sensing on the first leg; the classical one times out over outdated
    maps on the second."""
    if pilot == "ppo" and sensing == "degraded" and episode == 0:
        return "collision"
    if pilot == "rrt_mpc" and map_error == "outdated" and episode == 1:
        return "timeout"
    return "success"


@pytest.fixture(scope="module")
def levels_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    run_dir = tmp_path_factory.mktemp("degradation") / "run"
    quads = [sc for sc in build_task_set("benchmark-quick").scenarios if sc.vehicle_name == "small_quad"]
    scenarios = [with_levels(sc, SENSING[k % 3], MAPS[(k // 3) % 2]) for k, sc in enumerate(quads)]
    opts = RunConfig(run_dir, pilots=("ppo", "rrt_mpc"), command="uam-compare run benchmark-quick")
    cells, notes = plan_cells(scenarios, opts, None)
    write_run_files(scenarios, opts, cells, notes, {})
    for c in cells:
        sc = scenarios[c.scenario]
        ep = sc.episodes[c.episode]
        outcome = _outcome(c.pilot, sc.sensing.label, sc.map_error.label, c.episode)
        key = EpisodeKey(sc.name, c.episode, c.pilot, c.seed)
        meta = EpisodeMeta(key, sc.city.name or sc.name, "small_quad", tuple(ep.task.start_m), tuple(ep.task.goal_m),
                           3.0, ep.task.timeout_s, 0.42, 4, 1000.0, outcome, 0.0, f"synthetic {outcome}")
        save_episode(run_dir / "episodes" / f"{key.stem}.npz", meta,
                     trajectory(60, 20.0, 5.0, 1.0 if outcome == "success" else 0.5, outcome, c.episode))
    finalize(run_dir, report=False)
    return run_dir


def test_the_report_has_a_degradation_page_per_vehicle(levels_run: Path) -> None:
    assert main(["report", str(levels_run)]) == 0
    text = "\n".join(p.extract_text() or "" for p in PdfReader(levels_run / "report.pdf").pages)
    assert "Degradation: small_quad" in text and "sensing level" in text and "map-error level" in text
    assert (levels_run / "figures" / "degradation_small_quad.png").is_file()


def test_the_figure_draws_each_pilot_over_the_levels_in_order(levels_run: Path) -> None:
    info = read_run_info(levels_run)
    rows = read_metrics_csv(levels_run / "metrics.csv")
    colors = pilot_colors(["ppo", "rrt_mpc"])
    style = PilotStyle(("ppo", "rrt_mpc"), {"ppo": "PPO", "rrt_mpc": "RRT* + MPC"}, colors)
    (name, _), = degradation_pages(info, rows, style)
    assert name == "degradation_small_quad"
    rates = [r for r in level_rates(info, rows) if r.vehicle == "small_quad"]
    fig = degradation_figure("small_quad", rates, style)
    success_sensing, success_map, collision_sensing = fig.axes[0], fig.axes[1], fig.axes[2]
    lines = {ln.get_label(): ln for ln in success_sensing.get_lines() if isinstance(ln, Line2D)}
    assert {k: ln.get_color() for k, ln in lines.items()} == {"PPO": colors["ppo"], "RRT* + MPC": colors["rrt_mpc"]}
    assert [t.get_text().split("\n")[0] for t in success_sensing.get_xticklabels()] == list(SENSING)
    assert [t.get_text().split("\n")[0] for t in success_map.get_xticklabels()] == list(MAPS)
    ppo = {ln.get_label(): ln for ln in collision_sensing.get_lines()}["PPO"]
    assert list(ppo.get_ydata())[0] == 0.0 and list(ppo.get_ydata())[-1] > 0.0  # collisions only when degraded
    mpc = {ln.get_label(): ln for ln in success_map.get_lines()}["RRT* + MPC"]
    assert mpc.get_ydata()[0] == 1.0 and mpc.get_ydata()[1] < 1.0  # time-outs only over outdated maps


def test_a_run_at_one_level_has_no_degradation_page(levels_run: Path) -> None:
    info = read_run_info(levels_run)
    rows = [r for r in read_metrics_csv(levels_run / "metrics.csv")
            if r.sensing == "perfect" and r.map_error == "exact"]
    style = PilotStyle(("ppo", "rrt_mpc"), {}, pilot_colors(["ppo", "rrt_mpc"]))
    one = dataclasses.replace(info, scenarios=tuple(s for s in info.scenarios
                                                    if s.sensing == "perfect" and s.map_error == "exact"))
    assert degradation_pages(one, rows, style) == []
