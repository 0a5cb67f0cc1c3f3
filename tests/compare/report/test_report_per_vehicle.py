"""The report of a two-vehicle run (synthetic, no simulation): per-vehicle sections and figures, nothing pooled,
paired differences with their MDD, success along task difficulty, bounded flight pages that say so, and a plug-in
pilot that cannot be imported here shown with its own label and colour."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from matplotlib.lines import Line2D
from pypdf import PdfReader

from compare.report import report as R
from compare.report.figures import PILOT_COLORS, pilot_colors
from compare.report.metrics_pages import PilotStyle, vehicle_pages
from compare.results.difficulty import ScenarioConditions
from compare.results.metrics import read_metrics_csv
from compare.results.summary import read_summary_json, summarize_run, write_summary_json
from synthetic_run import write_benchmark_run

GHOST = "ghostpkg.pilots:GhostPilot"  # a plug-in not installed where the report is built
PILOT_LABELS = {"ppo": "PPO policy", "rrt_mpc": "RRT* + MPC", GHOST: "Ghost pilot"}
VEHICLES = ("small_quad", "uam_multicopter")


def _page(texts: list[str], title: str) -> str:
    """The first page whose text holds `title` (a figure's title is not always its first text)."""
    return next(t for t in texts if title in t)


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str]]:
    run_dir = tmp_path_factory.mktemp("vehicles") / "run"
    # 3 scenarios x 4 episodes: 12 pairs per vehicle, enough (MIN_INTERVAL_N) for bootstrap intervals and MDDs
    rows = write_benchmark_run(run_dir, scenarios_per_vehicle=3, episodes=4, seeds=(0,), pilots=PILOT_LABELS,
                               samples=60)
    write_summary_json(summarize_run(rows, resamples=200), run_dir / "summary.json")
    with pytest.MonkeyPatch.context() as mp:  # draw few flights: the bound is what is tested, not the drawing
        mp.setattr(R, "DRAWN_SCENARIOS_PER_VEHICLE", 1)
        mp.setattr(R, "DRAWN_FLIGHTS_PER_SCENARIO", 1)
        mp.setattr(R, "MAX_FAILURE_ROWS", 5)
        pdf = R.build_report(run_dir)
    return run_dir, [p.extract_text() or "" for p in PdfReader(pdf).pages]


def test_summary_json_of_the_run_pools_nothing(run):
    run_dir, _ = run
    data = json.loads((run_dir / "summary.json").read_text())
    assert data["vehicles"] == list(VEHICLES) and "methods" not in data and "paired" not in data
    for vehicle in VEHICLES:
        part = data["by_vehicle"][vehicle]
        assert part["vehicles"] == [vehicle] and set(part["methods"]) == set(PILOT_LABELS)
        assert part["methods"]["ppo"]["episodes"] == 3 * 4
    assert all(len(s["vehicles"]) == 1 for s in data["by_scenario"].values())


def test_report_has_a_section_per_vehicle_and_no_pooled_table(run):
    run_dir, texts = run
    whole = "\n".join(texts)
    for vehicle in VEHICLES:
        for title in (f"{vehicle}: per pilot, mean [95 % CI]", f"{vehicle}: summary per pilot",
                      f"{vehicle}: paired differences", f"{vehicle}: paired differences and minimum detectable",
                      f"{vehicle}: where does each pilot break?", f"{vehicle}: per scenario",
                      f"{vehicle}: per episode"):
            assert title in whole, title
        assert f"Over the 3 scenarios of vehicle {vehicle}, never pooled with another vehicle" in whole
    assert "Metrics: per pilot" not in whole  # the old table over every vehicle at once
    assert "numbers from summary.json" in whole and "Wilson" in whole and "Newcombe" in whole
    assert "minimum detectable difference" in whole and "excludes 0" in whole
    assert whole.count("The scenarios and their conditions") >= 2 and "Each pilot per scenario" in whole
    names = {p.name for p in (run_dir / "figures").glob("*.png")}
    for vehicle in VEHICLES:
        assert {f"vehicle_{vehicle}_forest.png", f"vehicle_{vehicle}_difficulty.png",
                f"vehicle_{vehicle}_paired_1.png"} <= names
    # a per-vehicle page names only that vehicle's scenarios
    quad = _page(texts, "small_quad: per scenario")
    assert "bench-small_quad-02" in quad and "bench-uam_multicopter" not in quad


def test_paired_table_states_the_numbers_of_summary_json(run):
    run_dir, texts = run
    data = json.loads((run_dir / "summary.json").read_text())
    st = data["by_vehicle"]["uam_multicopter"]["paired"]["ppo - rrt_mpc"]["min_clearance_m"]
    page = "\n".join(t for t in texts if "uam_multicopter: paired differences and minimum" in t)  # two pages
    cell = f"{st['mean_diff']:.2f} [{st['ci_low']:.2f}, {st['ci_high']:.2f}]"
    assert cell in page and f"{st['mdd']:.2f}" in page
    succ = data["by_vehicle"]["uam_multicopter"]["paired"]["ppo - rrt_mpc"]["success"]
    assert f"{100 * succ['mdd_design']:.0f}" in page and succ["n"] == 12


def test_flight_pages_are_bounded_and_the_report_says_so(run):
    run_dir, texts = run
    flights = [t for t in texts if t.startswith("Flights\n")]
    assert len(flights) == 1
    note = flights[0].replace("\n", " ")
    assert "This run flew 24 tasks" in note and "first 1 scenarios of each vehicle and the first 1 tasks" in note
    assert "bench-small_quad-00 (1 of 4)" in note and "Not drawn" in note and "bench-uam_multicopter-02" in note
    assert sum("Episode bench-" in t for t in texts) == 3 * 2
    failures = [t for t in texts if "Failures" in t]
    rows = read_metrics_csv(run_dir / "metrics.csv")
    n_failed = sum(not r.success for r in rows)
    assert n_failed > 5 and f"The first 5 of {n_failed} failures" in failures[0].replace("\n", " ")
    assert "(flight not drawn)" in failures[0]


def test_plug_in_pilot_keeps_its_label_and_own_colour(run):
    run_dir, texts = run
    whole = "\n".join(texts)
    assert whole.count("Ghost pilot") >= 6  # run.json's label: the plug-in cannot be imported here
    colors = pilot_colors(list(PILOT_LABELS))
    assert colors["ppo"] == PILOT_COLORS["ppo"] and colors["rrt_mpc"] == PILOT_COLORS["rrt_mpc"]
    assert colors[GHOST] not in (colors["ppo"], colors["rrt_mpc"])
    # the summary figure draws it in that colour under that label
    summary = read_summary_json(run_dir / "summary.json")
    quad = summary.by_vehicle["small_quad"]
    rows = [r for r in read_metrics_csv(run_dir / "metrics.csv") if r.vehicle == "small_quad"]
    style = PilotStyle(tuple(PILOT_LABELS), PILOT_LABELS, colors)
    scenarios = {n: s for n, s in summary.by_scenario.items() if s.vehicle == "small_quad"}
    conditions = {n: ScenarioConditions(n, "small_quad", 0.1, "none", 1.2) for n in scenarios}
    pages = dict(vehicle_pages("small_quad", quad, scenarios, rows, conditions, style, "test."))
    forest = pages["vehicle_small_quad_forest"][0]
    success_panel = forest.axes[0]
    assert [t.get_text() for t in success_panel.get_yticklabels()] == list(PILOT_LABELS.values())
    drawn = {line.get_color() for line in success_panel.get_lines() if isinstance(line, Line2D)}
    assert colors[GHOST] in drawn
