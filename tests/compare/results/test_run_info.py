"""run.json as a typed RunInfo: write → read gives the same object, older files read, bad values are named."""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from compare.results.run_info import (
    AirEnvelope,
    AtmosphereInfo,
    PilotInfo,
    PolicyRecord,
    RunInfo,
    ScenarioInfo,
    TaskSetInfo,
    WindInfo,
    read_run_info,
    run_info_to_json,
    write_run_info,
)
from synthetic_run import write_run
from uam_fdm.air.shear import WindShear


def full_info() -> RunInfo:
    scenario = ScenarioInfo(
        name="hot-high", source="/x/hot-high.yaml", description="Thin air.", map_name="suburb", vehicle="small_quad",
        vehicle_summary="1.5 kg, 4 rotors, collision radius 0.42 m",
        atmosphere=AtmosphereInfo(1500.0, 15.0, 0.9987),
        wind=WindInfo((2.0, 1.0, 0.0), "light", WindShear("power", 10.0, exponent=0.28)),
        episodes=3, seeds=(0, 7), pilots=("ppo", "rrt_mpc"), physics_hz=500.0, control_hz=50.0)
    return RunInfo(
        created_utc="2026-11-21T08:00:00Z", command="uam-compare run hot-high", scenarios=(scenario,),
        notes=("ppo decides at its policy's rate",),
        pilots={"ppo": PilotInfo("PPO policy", "Learned pilot.", (PolicyRecord("small_quad", "/p/quad", 10.0),)),
                "rrt_mpc": PilotInfo("RRT* + MPC", "Classical pilot.")},
        versions={"python": "3.11.7", "numpy": "2.1.0"}, fairness="Both fly the same model.",
        fingerprints={"code": {"uam-compare": "0.1.0"}, "scenarios": {"hot-high": {"map": "abc"}}})


def test_write_read_round_trip(tmp_path: Path) -> None:
    info = full_info()
    path = write_run_info(info, tmp_path)
    assert path == tmp_path / "run.json" and path.read_text().endswith("}\n")
    back = read_run_info(tmp_path)
    assert back == info
    assert json.loads(path.read_text()) == run_info_to_json(info)
    assert write_run_info(back, tmp_path / "again").read_bytes() == path.read_bytes()
    assert back.label("ppo") == "PPO policy" and back.label("a_star") == "a_star"
    assert back.policies() == (PolicyRecord("small_quad", "/p/quad", 10.0),) and back.policies("rrt_mpc") == ()
    assert back.scenario("hot-high") is back.scenarios[0] and back.scenario("nowhere") is None


def test_the_task_set_is_optional(tmp_path: Path) -> None:
    """A benchmark run records its task set last; without one, no key: older files rewrite as they were."""
    task_set = TaskSetInfo("benchmark-quick", "1+0123456789", "Held-out generated tasks per vehicle.")
    info = replace(full_info(), task_set=task_set)
    path = write_run_info(info, tmp_path)
    data = json.loads(path.read_text())
    assert list(data)[-1] == "suite" and data["suite"] == {"name": "benchmark-quick", "version": "1+0123456789",
                                                           "description": "Held-out generated tasks per vehicle."}
    assert read_run_info(tmp_path) == info
    assert "suite" not in json.loads(write_run_info(full_info(), tmp_path / "plain").read_text())
    write_run(tmp_path / "old", None)  # a run.json written before task sets: reads without one, rewrites unchanged
    old = read_run_info(tmp_path / "old")
    assert old.task_set is None
    again = write_run_info(old, tmp_path / "rewritten").read_text()
    assert again == write_run_info(read_run_info(tmp_path / "rewritten"), tmp_path / "twice").read_text()
    data["suite"] = {"name": 5}
    (tmp_path / "run.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match="suite.name: expected a string"):
        read_run_info(tmp_path)


def test_the_file_keeps_its_format(tmp_path: Path) -> None:
    """The keys and their order as every version wrote them (reports of older runs rely on it)."""
    data = json.loads(write_run_info(full_info(), tmp_path).read_text())
    assert list(data) == ["format_version", "created_utc", "command", "scenarios", "notes", "methods", "versions",
                          "fairness", "fingerprints"]
    assert list(data["scenarios"][0]) == ["name", "source", "description", "map_name", "vehicle", "vehicle_summary",
                                          "atmosphere", "wind", "episodes", "seeds", "methods", "physics_hz",
                                          "control_hz"]
    shear = {"law": "power", "reference_height_m": 10.0, "exponent": 0.28, "roughness_m": None}
    assert data["scenarios"][0]["wind"] == {"steady_enu_m_s": [2.0, 1.0, 0.0], "turbulence": "light", "shear": shear}
    assert data["methods"]["ppo"]["policies"] == [{"vehicle": "small_quad", "policy_dir": "/p/quad",
                                                   "decision_hz": 10.0}]
    assert "policies" not in data["methods"]["rrt_mpc"] and data["format_version"] == 1


def test_older_run_json_reads(tmp_path: Path) -> None:
    """The synthetic (older) run.json: no shear, notes or fingerprints; and ppo's one policy_dir of the first runs."""
    write_run(tmp_path / "run", None)
    info = read_run_info(tmp_path / "run")
    (s,) = info.scenarios
    assert s.wind == WindInfo((2.0, 1.0, 0.0), "light", None) and s.episodes == 2 and s.seeds == (0,)
    assert info.fingerprints is None and info.notes == () and info.policies() == ()
    data = json.loads((tmp_path / "run" / "run.json").read_text())
    data["methods"]["ppo"] = {"label": "PPO policy", "policy_dir": "/old/policy"}
    (tmp_path / "run" / "run.json").write_text(json.dumps(data))
    assert read_run_info(tmp_path / "run").policies() == (PolicyRecord(None, "/old/policy", None),)
    (tmp_path / "bare").mkdir()
    (tmp_path / "bare" / "run.json").write_text("{}")
    assert read_run_info(tmp_path / "bare") == RunInfo()


@pytest.mark.parametrize(("text", "message"), [
    ("[1, 2]", r"run\.json: <root>: expected a JSON object, got \[1, 2\]"),
    ("{not json", r"run\.json: not readable JSON"),
    ('{"scenarios": [{"name": "a", "seeds": [0, "one"]}]}',
     r"run\.json: scenarios\[0\]\.seeds\[1\]: expected an integer"),
    ('{"scenarios": [{"name": "a", "wind": {"steady_enu_m_s": [1, 2]}}]}',
     r"scenarios\[0\]\.wind\.steady_enu_m_s: expected 3 numbers"),
    ('{"scenarios": [{"name": "a", "wind": {"shear": {"law": "spiral"}}}]}', r"scenarios\[0\]\.wind\.shear: law"),
    ('{"methods": {"ppo": {"policies": [{"policy_dir": 3}]}}}',
     r"methods\.ppo\.policies\[0\]\.policy_dir: expected a string, got 3"),
    ('{"format_version": 2}', r"format_version 2, expected 1"),
])
def test_bad_run_json_names_the_file_and_key(tmp_path: Path, text: str, message: str) -> None:
    (tmp_path / "run.json").write_text(text)
    with pytest.raises(ValueError, match=message):
        read_run_info(tmp_path)


def test_missing_run_json_names_the_folder(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=rf"{tmp_path}: not a run folder \(no run\.json\)"):
        read_run_info(tmp_path)


def test_a_policys_trained_air_round_trips(tmp_path: Path) -> None:
    """The envelope a policy was trained in is written with it (only when known) and read back exactly."""
    env = AirEnvelope((-612.5, 4100.0), 8.0, ("none", "light", "moderate"))
    info = replace(full_info(), pilots={"ppo": PilotInfo("PPO policy", "", (PolicyRecord("small_quad", "/p", 10.0,
                                                                                         env),))})
    data = json.loads(write_run_info(info, tmp_path).read_text())
    assert data["methods"]["ppo"]["policies"][0]["trained_air"] == {
        "density_altitude_m": [-612.5, 4100.0], "steady_wind_max_m_s": 8.0, "turbulence": ["none", "light", "moderate"]}
    assert read_run_info(tmp_path).policies() == (PolicyRecord("small_quad", "/p", 10.0, env),)
    data["methods"]["ppo"]["policies"][0]["trained_air"] = {"density_altitude_m": [0.0]}
    (tmp_path / "run.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match="trained_air: expected density_altitude_m"):
        read_run_info(tmp_path)


def test_sensed_facts_and_a_policys_trained_sensing_round_trip(tmp_path: Path) -> None:
    """Below perfect sensing a scenario records its GNSS sky and lidar range, on a map with error the share of
    buildings missing; a policy its trained sensing. Written only when set, read back exactly, bad values named."""
    from compare.results.sensing_facts import SensedFacts, SensingEnvelope

    trained = SensingEnvelope(True, True, 30.0, 100.0, 0.25)
    base = full_info()
    sensed = replace(base.scenarios[0], sensing="nominal+", map_error="exact+",
                     sensed=SensedFacts(True, 60.0, 40.0), missing_fraction=0.5)
    info = replace(base, scenarios=(sensed,), pilots={"ppo": PilotInfo("PPO policy", "", (PolicyRecord(
        "small_quad", "/p", 10.0, None, trained),))})
    data = json.loads(write_run_info(info, tmp_path).read_text())
    s = data["scenarios"][0]
    assert s["sensed"] == {"gnss_urban_canyon": True, "gnss_max_outage_s": 60.0, "lidar_range_m": 40.0}
    assert s["missing_fraction"] == 0.5 and s["sensing"] == "nominal+"
    assert data["methods"]["ppo"]["policies"][0]["trained_sensing"] == {
        "sensed": True, "gnss_urban_canyon": True, "gnss_max_outage_s": 30.0, "lidar_range_m": 100.0,
        "missing_fraction_max": 0.25}
    back = read_run_info(tmp_path)
    assert back == info and back.scenarios[0].sensed.gnss_label() == "urban canyon, outages to 60 s"
    # at perfect sensing on an exact map nothing is written, and an exact map reads as nothing missing
    plain = json.loads(write_run_info(base, tmp_path / "plain").read_text())["scenarios"][0]
    assert "sensed" not in plain and "missing_fraction" not in plain
    assert read_run_info(tmp_path / "plain").scenarios[0].missing_fraction == 0.0
    # a run from before the facts: a wrong map's share is not known (None), not 0
    del s["sensed"], s["missing_fraction"]
    s["map_error"] = "wrong"
    (tmp_path / "run.json").write_text(json.dumps(data))
    older = read_run_info(tmp_path).scenarios[0]
    assert older.sensed is None and older.missing_fraction is None
    s["sensed"] = {"gnss_urban_canyon": "yes", "gnss_max_outage_s": 1.0, "lidar_range_m": 40.0}
    (tmp_path / "run.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"scenarios\[0\]\.sensed\.gnss_urban_canyon: expected true or false"):
        read_run_info(tmp_path)
    s["sensed"] = {"gnss_urban_canyon": True}
    (tmp_path / "run.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"scenarios\[0\]\.sensed: expected gnss_urban_canyon, gnss_max_outage_s"):
        read_run_info(tmp_path)
