"""Plug-in pilots: named as module:Class or by an entry point, checked before anything flies, flown by the
same runner beside ours (in worker processes too), shown with their own label, colour and fairness line."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from pypdf import PdfReader

from compare.cli import main
from compare.flying import pilots
from compare.results.episodes import open_episodes
from compare.scenarios.scenario import load_scenario, with_pilots
from uam_fdm.errors import ConfigError

ROOT = Path(__file__).resolve().parents[3]
EXAMPLES = ROOT / "examples"
HERE = ROOT / "tests"  # plugin_fixtures.py
TINY = ROOT / "tests" / "data" / "tiny_scenario.yaml"
CLIMB = "straight_climb:StraightClimbPilot"


@pytest.fixture
def on_path(monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLES))
    monkeypatch.syspath_prepend(str(HERE))


def test_a_class_named_module_colon_class_becomes_a_pilot(on_path):
    entry = pilots.pilot(CLIMB)
    assert entry.name == CLIMB and entry.label == "Straight climb" and entry.color == "tab:green"
    assert entry.description.startswith("Straight-line-then-climb pilot: climb vertically")
    assert entry.description.endswith(f"(plug-in {CLIMB})")
    assert "Straight climb (straight_climb:StraightClimbPilot) decides at the scenario's control rate" in entry.given
    assert "ignores the forecast turbulence level" in entry.given  # its own sentence, from the class
    assert not entry.default and not entry.needs_policy and entry.report_type is None
    assert entry.wall_s_per_flight_s == 0.2
    assert pilots.pilot(CLIMB) is entry  # resolved once per process
    assert pilots.ordered(["apf", CLIMB, "ppo"]) == ["ppo", "apf", CLIMB]


def test_a_plugin_entry_is_taken_as_given_under_its_reference(on_path):
    entry = pilots.pilot("plugin_fixtures:ENTRY")
    assert (entry.name, entry.label, entry.color, entry.default) == ("plugin_fixtures:ENTRY", "Entered field",
                                                                     "tab:olive", False)


@pytest.mark.parametrize(("name", "reason"), [
    ("no_such_module_xyz:Pilot", r"cannot import module 'no_such_module_xyz' .*PYTHONPATH"),
    ("plugin_fixtures:Missing", r"module 'plugin_fixtures' has no 'Missing'"),
    ("plugin_fixtures:NOT_A_CLASS", r"is a int, not a Pilot class or a PilotEntry"),
    ("plugin_fixtures:NoAct", r"NoAct is not a pilot: it lacks act"),
    ("astar", r"unknown pilot 'astar' \(registered: ppo, rrt_mpc, apf\).*module:Class"),
])
def test_a_broken_plugin_is_a_clear_error(on_path, name, reason):
    with pytest.raises(ValueError, match=reason):
        pilots.pilot(name)
    assert pilots.registered(name) is None  # readers never import a pilot named in a data file


def test_a_plugin_pilots_own_name_need_not_be_the_name_it_flies_under(on_path):
    sc = load_scenario(TINY)
    request = pilots.BuildRequest(sc.vehicle, sc.vehicle_name, sc.source)
    pilot = pilots.build("plugin_fixtures:NamedWrong", request)
    assert pilot.name == "apf"
    with pytest.raises(ValueError, match="unknown pilot"):  # a registered name still must match
        pilots.build("no_such", request)


def test_an_entry_point_names_a_plugin(on_path, tmp_path, monkeypatch):
    dist = tmp_path / "my_pilots-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: my-pilots\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(f"[{pilots.PLUGIN_GROUP}]\nclimb = {CLIMB}\nbad__name = {CLIMB}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    entry = pilots.pilot("climb")
    assert entry.name == "climb" and entry.label == "Straight climb"
    assert entry.description.endswith(f"(plug-in {CLIMB})")
    with pytest.raises(ValueError, match="bad__name.*without '__'"):
        pilots.pilot("bad__name")
    with pytest.raises(ValueError, match="installed plug-ins: bad__name, climb"):
        pilots.pilot("nothing")


def test_a_scenario_file_may_name_a_plugin_and_a_broken_one_names_the_key(on_path, tmp_path):
    text = TINY.read_text()
    good, bad = tmp_path / "good.yaml", tmp_path / "bad.yaml"
    good.write_text(text + f"pilots: [{CLIMB}, ppo]\n")
    bad.write_text(text + "pilots: [ppo, nowhere_module:Pilot]\n")
    assert load_scenario(good).pilots == ("ppo", CLIMB)
    with pytest.raises(ConfigError, match=r"bad.yaml: pilots\[1\]: .*cannot import module 'nowhere_module'"):
        load_scenario(bad)
    assert with_pilots(load_scenario(TINY), (CLIMB, "apf")).pilots == ("ppo", "rrt_mpc", "apf", CLIMB)


def test_cli_flies_a_plugin_beside_ours_in_worker_processes(on_path, tmp_path):
    out = tmp_path / "run"
    args = ["run", str(TINY), "--pilot", CLIMB, "--pilot", "apf", "--pilots", f"apf,{CLIMB}", "--jobs", "2",
            "--out", str(out), "--no-progress", "--videos", "none"]
    assert main(args) == 0
    with open(out / "metrics.csv", newline="") as f:
        rows = {r["method"]: r for r in csv.DictReader(f)}
    assert sorted(rows) == sorted(["apf", CLIMB])
    climb = rows[CLIMB]
    assert climb["success"] == "1" and climb["collision"] == "0", climb
    assert float(climb["min_clearance_m"]) > 1.0 and climb["plan_time_s"] == "nan"  # it does not plan
    # it climbed over the buildings: higher than the tallest building near its line (30 m), lower than the ceiling
    episodes = open_episodes(out)
    [climbed] = [e for e in episodes.entries if e.key.method == CLIMB]
    z = episodes.load(climbed).trajectory.states[:, 2]
    assert 30.0 < z.max() < 60.0
    info = json.loads((out / "run.json").read_text())
    assert info["methods"][CLIMB]["label"] == "Straight climb"
    assert "The plug-in pilot Straight climb (straight_climb:StraightClimbPilot)" in info["fairness"]
    assert (out / "report.pdf").is_file()
    text = " ".join(p.extract_text() for p in PdfReader(out / "report.pdf").pages)
    assert "Straight climb" in text


def test_cli_rejects_an_unknown_plugin_before_flying(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", str(TINY), "--pilot", "nowhere_module:Pilot", "--out", str(out), "--no-progress"]) == 2
    assert "--pilot: pilot 'nowhere_module:Pilot': cannot import module" in capsys.readouterr().err
    assert not out.exists()
