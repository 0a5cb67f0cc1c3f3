"""The report of a sweep run: two pages per vehicle with the rates against density altitude and wind, then against
the map's missing share, the GNSS sky and the lidar's range, every pilot's line in its colour, the steps outside the
learned pilot's trained conditions marked; the command's table and last JSON line. A synthetic run (the real
sweep-quick's scenarios, made-up flights), nothing simulated."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from matplotlib.lines import Line2D
from pypdf import PdfReader

from compare.cli import main
from compare.report.figures import pilot_colors
from compare.report.metrics_pages import PilotStyle
from compare.report.sweep_pages import sweep_figure
from compare.results.metrics import read_metrics_csv
from compare.results.run_info import AirEnvelope, read_run_info
from compare.results.sensing_facts import SensingEnvelope
from compare.results.sweep_rates import sweep_rates
from compare.results.trajectory import EpisodeKey, EpisodeMeta, save_episode
from compare.run.campaign import PolicyFacts, RunConfig, finalize, plan_cells, write_run_files
from compare.scenarios.sweep import build_sweep
from synthetic_run import trajectory

ENVELOPE = AirEnvelope((0.0, 0.0), 3.0, ("light",))  # the shipped quad's: sea level, light, wind to 3 m/s
SENSING = SensingEnvelope(True, True, 30.0, 100.0, 0.25)  # trained at every level of the small quad


def _outcome(pilot: str, sc, episode: int) -> str:
    """The learned pilot breaks in thin air and strong wind (collisions) and with half the map missing, the
    classical one in wind and with a 20 m lidar."""
    da_m, wind_m_s = sc.atmosphere.elevation_m, math.hypot(*sc.wind.steady_enu_m_s)
    if pilot == "ppo" and (da_m > 2000.0 or wind_m_s > 7.0 or sc.map_error.missing_fraction >= 0.5):
        return "collision" if episode == 0 else "timeout"
    if pilot == "rrt_mpc" and ((wind_m_s > 11.0 and episode == 1) or sc.sensing.lidar.max_range_m < 30.0):
        return "timeout"
    return "success"


@pytest.fixture(scope="module")
def sweep_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    run_dir = tmp_path_factory.mktemp("sweep") / "run"
    task_set = build_sweep("sweep-quick", vehicles=("small_quad",))
    scenarios = list(task_set.scenarios)
    opts = RunConfig(run_dir, pilots=("ppo", "rrt_mpc"), command="uam-compare sweep --quick")
    cells, notes = plan_cells(scenarios, opts, None)
    policy = PolicyFacts(Path("/nonexistent/policy"), "small_quad", scenarios[0].vehicle.fingerprint(), 50.0, 10.0,
                         ENVELOPE, SENSING)
    write_run_files(scenarios, opts, cells, notes, {}, [policy])
    for c in cells:
        sc = scenarios[c.scenario]
        ep = sc.episodes[c.episode]
        outcome = _outcome(c.pilot, sc, c.episode)
        key = EpisodeKey(sc.name, c.episode, c.pilot, c.seed)
        meta = EpisodeMeta(key, sc.city.name or sc.name, "small_quad", tuple(ep.task.start_m), tuple(ep.task.goal_m),
                           3.0, ep.task.timeout_s, 0.42, 4, 1000.0, outcome, 0.0, f"synthetic {outcome}")
        save_episode(run_dir / "episodes" / f"{key.stem}.npz", meta,
                     trajectory(60, 20.0, 5.0, 1.0 if outcome == "success" else 0.5, outcome, c.episode))
    finalize(run_dir, report=False)  # metrics.csv and summary.json; the report comes with the command
    return run_dir


def test_the_command_prints_the_steps_and_ends_with_json(sweep_run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["report", str(sweep_run)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert any(line.startswith("small_quad, sweep over density altitude") for line in lines)
    thin = next(line for line in lines if line.strip().startswith("3.00 km") and "ppo" in line)
    assert "*" in thin and "success   0.0% [0%, 66%]" in thin  # 0 of 2: Wilson [0, 0.66]
    sea = next(line for line in lines if line.strip().startswith("0.00 km") and "ppo" in line)
    assert "*" not in sea and "success 100.0%" in sea
    out = json.loads(lines[-1])
    steps = out["sweep"]["small_quad"]
    assert [s["x"] for s in steps["wind"] if s["method"] == "rrt_mpc"] == [0, 2, 4, 6, 8, 10, 12]
    da = [s for s in steps["density altitude"] if s["method"] == "ppo"]
    assert len(da) == 7 and da[0]["outside_trained_air"] == [] and da[-1]["outside_trained_air"] == [
        "density altitude 4497 m"]
    assert da[-1]["collision"] == {"rate": 0.5, "ci95": pytest.approx([0.0945, 0.9055], abs=1e-3)}
    assert out["suite"]["name"] == "sweep-quick"
    # the sensed axes, at nominal sensing: their steps, units and labels; outside the training past its levels
    missing = [s for s in steps["map missing"] if s["method"] == "ppo"]
    assert [(s["x"], s["unit"], s["label"]) for s in missing] == [
        (0.0, "fraction", "0 %"), (0.1, "fraction", "10 %"), (0.25, "fraction", "25 %"), (0.5, "fraction", "50 %")]
    assert [s["success"]["rate"] for s in missing] == [1.0, 1.0, 1.0, 0.0]
    assert [s["outside_trained_air"] for s in missing] == [[], [], [], ["50 % of the buildings unmapped"]]
    gnss = [s for s in steps["GNSS"] if s["method"] == "rrt_mpc"]
    assert [s["label"] for s in gnss] == ["open sky", "urban canyon", "urban canyon, outages to 10 s",
                                          "urban canyon, outages to 30 s", "urban canyon, outages to 60 s"]
    assert [s["x"] for s in gnss] == [0, 1, 2, 3, 4] and {s["unit"] for s in gnss} == {"step"}
    assert [s["outside_trained_air"] for s in steps["GNSS"] if s["method"] == "ppo"][-1] == ["GNSS outages to 60 s"]
    assert gnss[-1]["outside_trained_air"] == []  # a pilot without a policy is never outside
    lidar = [s for s in steps["lidar range"] if s["method"] == "rrt_mpc"]
    assert [s["x"] for s in lidar] == [20, 40, 60, 100] and [s["success"]["rate"] for s in lidar] == [0, 1, 1, 1]
    table = next(k for k, line in enumerate(lines) if line.startswith("small_quad, sweep over GNSS"))
    rows = lines[table + 1:table + 11]
    assert sum(" * " in r for r in rows) == 1  # ppo's 60 s step only
    assert "  urban canyon, outages to 60 s * ppo " in rows[4] and "open sky   rrt_mpc " in rows[5]


def test_the_report_has_a_sweep_page_per_vehicle(sweep_run: Path) -> None:
    if not (sweep_run / "report.pdf").exists():
        main(["report", str(sweep_run)])
    text = "\n".join(p.extract_text() or "" for p in PdfReader(sweep_run / "report.pdf").pages)
    assert "Robustness sweep: small_quad" in text
    assert "shaded steps lie outside the air its policy was trained in" in text
    assert "shaded steps lie outside the sensing and map its policy was trained in" in text
    assert "density altitude [km]" in text and "steady wind [m/s]" in text
    assert "buildings missing from the map [%]" in text and "lidar range [m]" in text
    assert (sweep_run / "figures" / "sweep_small_quad.png").is_file()
    assert (sweep_run / "figures" / "sweep_small_quad_sensing.png").is_file()


def test_the_sweep_figure_draws_each_pilot_in_its_colour_and_marks_outside_steps(sweep_run: Path) -> None:
    info = read_run_info(sweep_run)
    rates = sweep_rates(info, read_metrics_csv(sweep_run / "metrics.csv"))
    colors = pilot_colors(["ppo", "rrt_mpc"])
    style = PilotStyle(("ppo", "rrt_mpc"), {"ppo": "PPO", "rrt_mpc": "RRT* + MPC"}, colors)
    fig = sweep_figure("small_quad", rates, style)
    success_da, success_wind = fig.axes[0], fig.axes[1]
    lines = [ln for ln in success_da.get_lines() if isinstance(ln, Line2D) and ln.get_linestyle() == "-"]
    assert {ln.get_label() for ln in lines} == {"PPO", "RRT* + MPC"}
    assert {ln.get_label(): ln.get_color() for ln in lines} == {"PPO": colors["ppo"], "RRT* + MPC": colors["rrt_mpc"]}
    ppo = next(ln for ln in lines if ln.get_label() == "PPO")
    assert list(ppo.get_xdata()) == pytest.approx([0.0, 0.75, 1.5, 2.25, 3.0, 3.75, 4.5], abs=0.03)  # dodged
    mpc = next(ln for ln in lines if ln.get_label() == "RRT* + MPC")
    assert mpc.get_xdata()[0] > ppo.get_xdata()[0]  # side by side, not on top of each other
    assert list(ppo.get_ydata()) == [1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0]
    # shaded: six outside steps on the density axis (all but sea level), five on the wind axis (over 3 m/s)
    assert len(success_da.patches) == 6 and len(success_wind.patches) == 5
    assert len(success_da.collections) == 2  # one Wilson band per pilot
