"""The pilot registry: the existing pilots keep their names, labels and colours; a third pilot (apf)
flies the tiny scenario through the same runner, deterministically, and shows up in metrics.csv,
summary.json, run.json and the report; an unknown pilot is refused naming the registered ones.
Also the outcome names (one enum) and the classical pilot's typed report."""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from pypdf import PdfReader

from compare.cli import main
from compare.flying import pilots
from compare.report.figures import PILOT_COLORS
from compare.results.trajectory import SavedEpisode
from compare.run.campaign import fairness
from compare.run.cells import Cell, CellRunner
from compare.scenarios.scenario import load_scenario, scenario_from_dict
from planners.report import ClassicalReport
from run_data import TINY
from uam_fdm.episode import OUTCOME_OF_CODE, Outcome
from uam_fdm.errors import ConfigError
from uam_fdm.pilot import Pilot


def _tiny_with(tmp_path: Path, names: list[str]) -> Path:
    data = yaml.safe_load(TINY.read_text())
    data["pilots"] = names
    path = tmp_path / "tiny-apf.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_the_registry_keeps_the_existing_pilots_and_adds_apf():
    assert pilots.PILOT_NAMES == ("ppo", "rrt_mpc", "apf") and pilots.DEFAULT_PILOTS == ("ppo", "rrt_mpc")
    assert {m: (s.label, s.color) for m, s in pilots.PILOTS.items()} == {
        "ppo": ("PPO policy", "tab:orange"), "rrt_mpc": ("RRT* + MPC", "tab:blue"),
        "apf": ("Potential field", "tab:purple")}
    assert PILOT_COLORS == {m: s.color for m, s in pilots.PILOTS.items()}
    assert [s.name for s in pilots.PILOTS.values() if s.needs_policy] == ["ppo"]
    assert pilots.PILOTS["rrt_mpc"].report_type is ClassicalReport and pilots.PILOTS["apf"].report_type is None
    assert pilots.ordered(["apf", "x", "rrt_mpc", "apf"]) == ["rrt_mpc", "apf", "x"]
    with pytest.raises(ValueError, match=r"unknown pilot 'astar' \(registered: ppo, rrt_mpc, apf\)"):
        pilots.pilot("astar")
    sc = load_scenario(TINY)
    pilot = pilots.build("apf", pilots.BuildRequest(sc.vehicle, sc.vehicle_name, sc.source))
    assert isinstance(pilot, Pilot) and pilot.name == "apf"


def test_a_scenario_naming_an_unknown_pilot_is_refused_listing_the_registered_ones(tmp_path):
    data = yaml.safe_load(TINY.read_text())
    with pytest.raises(ConfigError, match=r"pilots\[1\].*unknown pilot 'astar' \(registered: ppo, rrt_mpc, apf\)"):
        scenario_from_dict({**data, "pilots": ["apf", "astar"]}, "x.yaml", TINY.parent)
    assert scenario_from_dict({**data, "pilots": ["apf", "ppo"]}, "x.yaml", TINY.parent).pilots == ("ppo", "apf")
    assert scenario_from_dict(data, "x.yaml", TINY.parent).pilots == ("ppo", "rrt_mpc")  # apf is off by default


def test_apf_flies_the_tiny_scenario_deterministically(tmp_path):
    sc = load_scenario(_tiny_with(tmp_path, ["apf"]))
    saved = []
    for run in ("a", "b"):  # two runners: nothing carried over
        saved.append(SavedEpisode(*CellRunner([sc], tmp_path / run, {}).fly(Cell(0, 0, 0, "apf"))))  # physics rate
    a, b = saved
    for name in ("t_s", "states", "rotor_commands", "wind_enu_m_s", "clearance_m", "decision_t_s"):
        np.testing.assert_array_equal(getattr(a.trajectory, name), getattr(b.trajectory, name), err_msg=name)
    assert a.meta.outcome is b.meta.outcome and a.meta.report is None and a.meta.failure_reason is None
    assert a.meta.plan_time_s == 0.0 and a.meta.agent_seed == b.meta.agent_seed is not None
    # a decision every control period
    assert len(a.trajectory.t_s) - 1 == len(a.trajectory.decision_t_s) * round(sc.physics_hz / sc.control_hz)


def test_apf_appears_in_metrics_summary_run_json_and_report(tmp_path):
    out = tmp_path / "run"
    assert main(["run", str(_tiny_with(tmp_path, ["ppo", "apf"])), "--out", str(out), "--no-progress",
                 "--videos", "none"]) == 0
    with open(out / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["method"] for r in rows] == ["apf", "ppo"]
    apf = rows[0]
    assert apf["outcome"] in {o.value for o in Outcome} and apf["plan_time_s"] == "nan"  # it does not plan
    assert math.isnan(float(apf["mpc_solve_ms_median"])) and float(apf["compute_ms_mean"]) > 0.0
    summary = json.loads((out / "summary.json").read_text())
    assert list(summary["methods"]) == ["ppo", "apf"] and "ppo - apf" in summary["paired"]  # table order
    assert summary["methods"]["apf"]["episodes"] == 1 and summary["methods"]["apf"]["plan_time_s"]["n"] == 0
    run = json.loads((out / "run.json").read_text())
    assert list(run["methods"]) == ["ppo", "apf"]  # table order
    assert run["methods"]["apf"]["label"] == "Potential field" and "policies" not in run["methods"]["apf"]
    assert run["fairness"] == fairness(["ppo", "apf"]) and pilots.PILOTS["apf"].given in run["fairness"]
    assert any(n.startswith("ppo decides at its policy's rate") and n.endswith("apf at each scenario's control rate")
               for n in run["notes"]), run["notes"]
    text = "\n".join(page.extract_text() or "" for page in PdfReader(str(out / "report.pdf")).pages)
    assert "Potential field [apf]" in text and "PPO policy" in text


def test_fairness_statement_grammar():
    two, three = fairness(["rrt_mpc", "ppo"]), fairness(["apf", "rrt_mpc", "ppo"])
    assert two.startswith("Both pilots") and "Neither knows the wind" in two and "potential-field" not in two
    assert three.startswith("All pilots") and "None knows the wind" in three
    # what each pilot is given, in table order, then how clearance is measured
    given = [pilots.PILOTS[m].given for m in pilots.PILOT_NAMES]
    assert [three.index(g) for g in given] == sorted(three.index(g) for g in given)
    assert three.endswith("to the buildings and the ground.")


def test_outcome_names_are_the_files_names():
    assert [o.value for o in Outcome] == ["success", "collision", "out_of_bounds", "nonfinite", "timeout",
                                          "planner_failure", "solver_failure"]
    assert OUTCOME_OF_CODE[1:] == (Outcome.SUCCESS, Outcome.COLLISION, Outcome.OUT_OF_BOUNDS, Outcome.NONFINITE,
                                   Outcome.TIMEOUT)
    o = Outcome.PLANNER_FAILURE
    assert o == "planner_failure" and str(o) == f"{o}" == "planner_failure" and repr(o) == "'planner_failure'"
    assert json.dumps({o: [o]}) == '{"planner_failure": ["planner_failure"]}'
    assert Outcome.parse("timeout", "here") is Outcome.TIMEOUT
    with pytest.raises(ValueError, match=r"here: unknown outcome 'crashed', expected one of success, "):
        Outcome.parse("crashed", "here")


def test_classical_report_failure_reason_and_json_round_trip():
    report = ClassicalReport(plan_time_s=0.5, replan_time_s=0.1, replans_tracking=1, replans_clearance=0,
                             mpc_solves=100, mpc_failures=25, mpc_solve_ms_median=1.0, mpc_solve_ms_p95=2.0,
                             mpc_statuses={"ok": 75, "max_iterations": 25}, tracking_rms_m=math.nan,
                             tracking_max_m=0.5, planner_margin_m=1.0, mpc_margin_m=0.5, margin_source="table")
    assert report.failure_reason(Outcome.COLLISION) is Outcome.SOLVER_FAILURE  # a quarter of the solves failed
    assert report.failure_reason(Outcome.SUCCESS) is None and report.failure_reason(Outcome.PLANNER_FAILURE) is None
    assert ClassicalReport.from_json({**report.to_json(), "mpc_failures": 24}).failure_reason(Outcome.TIMEOUT) is None
    saved = json.loads(json.dumps(report.to_json()))
    assert saved["tracking_rms_m"] is None and saved["replans"] == 1
    back = ClassicalReport.from_json(saved)
    assert math.isnan(back.tracking_rms_m)
    assert back == ClassicalReport(**{**vars(report), "tracking_rms_m": back.tracking_rms_m})
    assert ClassicalReport.from_json({"wind_seed": 3}) is None  # nothing of the report
