"""The strict scenario loader: shipped sets load, defaults apply, every bad input is named precisely."""
from __future__ import annotations

import copy
import math
import pickle
import re
import warnings
from pathlib import Path
from typing import Any

import pytest
import yaml

from compare.scenarios.scenario import DEFAULT_PILOTS, Scenario, load_scenario, scenario_from_dict
from compare.scenarios.sets import SCENARIO_DIR, builtin_sets, resolve_scenarios
from scenario_box import BASE
from uam_fdm.air.wind import ShearLaw, TurbulenceLevel, WindShear
from uam_fdm.errors import ConfigError
from uam_fdm.vehicle.params import PRESET_DIR, load_vehicle

SHIPPED = sorted(SCENARIO_DIR.glob("*/*.yaml"))

QUAD_RADIUS_M = 0.42
QUAD_MAX_SPEED_M_S = 12.0


def _write(tmp_path: Path, data: Any, name: str = "scen.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _with(changes: dict[str, Any]) -> dict[str, Any]:
    """BASE with dotted keys (`a.b`, `episodes[0].start`) set, or deleted when the value is DELETE."""
    data = copy.deepcopy(BASE)
    for dotted, value in changes.items():
        parts = [int(p) if p.isdigit() else p for p in re.split(r"\.|\[|\]\.?", dotted) if p]
        parent = data
        for p in parts[:-1]:
            if isinstance(p, str) and p not in parent:
                parent[p] = {}
            parent = parent[p]
        if value is DELETE:
            del parent[parts[-1]]
        else:
            parent[parts[-1]] = value
    return data


DELETE = object()


# ---- shipped scenarios -------------------------------------------------------------------------------
def test_builtin_sets() -> None:
    # benchmark* and sweep* are generated
    assert builtin_sets() == ["benchmark", "benchmark-perfect", "benchmark-perfect-quick",
                              "benchmark-perfect-validation", "benchmark-perfect-validation-quick", "benchmark-quick",
                              "benchmark-validation", "benchmark-validation-quick", "default", "full", "sweep",
                              "sweep-quick"]


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_shipped_scenario_loads(path: Path) -> None:
    s = load_scenario(path)
    assert s.name == path.stem
    assert s.source == str(path)
    assert s.episodes and s.seeds and set(DEFAULT_PILOTS) <= set(s.pilots)  # both pilots on both vehicles
    for ep in s.episodes:
        a, b = ep.task.start_m, ep.task.goal_m
        distance = math.dist(a, b)
        if s.vehicle_name == "small_quad":
            assert 120.0 <= distance <= 250.0 and 8.0 <= a[2] <= 20.0 and 8.0 <= b[2] <= 20.0
        else:
            assert 250.0 <= distance <= 400.0 and 30.0 <= a[2] <= 40.0 and 30.0 <= b[2] <= 40.0
        margin = 5.0 if s.vehicle_name == "small_quad" else 15.0
        _, d, _ = s.city.nearest_obstacles_batch([a, b], 1)
        assert (d[:, 0] >= margin).all()


def test_default_set_contents() -> None:
    by_name = {s.name: s for s in resolve_scenarios("default")}
    assert sorted(by_name) == ["downtown-quad", "suburb-quad", "suburb-uam"]
    quad = by_name["suburb-quad"]
    assert quad.city.name == "suburb" and quad.vehicle_name == "small_quad"
    assert quad.wind.steady_enu_m_s == (2.0, 1.0, 0.0) and quad.wind.turbulence is TurbulenceLevel.LIGHT
    assert len(quad.episodes) == 3 and quad.seeds == (0,) and quad.pilots == DEFAULT_PILOTS
    assert len(by_name["downtown-quad"].episodes) == 2 and by_name["downtown-quad"].city.name == "downtown"
    uam = by_name["suburb-uam"]
    assert uam.vehicle_name == "uam_multicopter" and len(uam.episodes) == 1 and uam.pilots == DEFAULT_PILOTS


def test_full_set_contents() -> None:
    full = {s.name: s for s in resolve_scenarios("full")}
    for city in ("suburb", "downtown", "canyon"):
        for level in ("none", "light", "moderate"):
            s = full[f"{city}-quad-{level}"]
            assert s.city.name == city and s.wind.turbulence is TurbulenceLevel.parse(level)
            assert len(s.episodes) == 4 and s.seeds == (0, 1, 2) and s.pilots == ("ppo", "rrt_mpc", "apf")
        uam = full[f"{city}-uam"]
        assert uam.pilots == ("ppo", "rrt_mpc", "apf") and len(uam.episodes) == 2
        assert uam.episodes[0].task.goal_radius_m == 10.0
    for name, level in (("hot-high-quad", "light"), ("hot-high-quad-moderate", "moderate")):
        hot = full[name]
        assert (hot.atmosphere.elevation_m, hot.atmosphere.isa_offset_k) == (2500.0, 25.0)
        assert hot.wind.turbulence is TurbulenceLevel.parse(level)
        assert hot.episodes == full["suburb-quad-light"].episodes and hot.pilots == ("ppo", "rrt_mpc", "apf")
    assert len(full) == 14


# ---- defaults and structure --------------------------------------------------------------------------
def test_defaults_are_applied(tmp_path: Path) -> None:
    s = load_scenario(_write(tmp_path, BASE))
    assert s.name == "box" and s.description == "" and s.vehicle_name == "small_quad"
    assert s.vehicle.name == "small_quad" and s.vehicle.collision_radius_m == QUAD_RADIUS_M
    assert (s.atmosphere.elevation_m, s.atmosphere.isa_offset_k) == (0.0, 0.0)
    assert s.wind.steady_enu_m_s == (0.0, 0.0, 0.0) and s.wind.turbulence is TurbulenceLevel.NONE
    assert s.seeds == (0,) and s.pilots == ("ppo", "rrt_mpc")
    assert (s.physics_hz, s.control_hz) == (500.0, 50.0)
    (ep,) = s.episodes
    assert ep.index == 0
    assert ep.task.start_m == (10.0, 50.0, 10.0) and ep.task.goal_m == (90.0, 50.0, 10.0)
    assert ep.task.goal_radius_m == 3.0
    assert ep.task.timeout_s == pytest.approx(20.0 + 2.5 * 80.0 / QUAD_MAX_SPEED_M_S)
    assert s.raw == BASE and s.city.bounds_max_m.tolist() == [100.0, 100.0, 50.0]


@pytest.mark.parametrize(("shear", "expected"), [
    ({"law": "power", "exponent": 0.3}, WindShear(ShearLaw.POWER, 20.0, exponent=0.3)),
    ({"law": "log", "roughness_m": 1}, WindShear(ShearLaw.LOG, 20.0, roughness_m=1.0)),
    ({"law": "uniform"}, WindShear(ShearLaw.UNIFORM, 20.0)),
])
def test_wind_shear_keys(tmp_path: Path, shear: dict, expected: WindShear) -> None:
    s = load_scenario(_write(tmp_path, _with({"atmosphere.wind_mps": [4, 0, 0], "atmosphere.wind_shear": shear,
                                              "atmosphere.wind_reference_height_m": 20})))
    assert s.wind.shear == expected and s.wind.steady_enu_m_s == (4.0, 0.0, 0.0)
    assert load_scenario(_write(tmp_path, BASE)).wind.shear == WindShear()  # default: uniform, given at 10 m


def test_top_level_defaults_and_episode_overrides(tmp_path: Path) -> None:
    data = _with({"goal_radius_m": 4.0, "timeout_s": 70.0, "seeds": [3, 1, 2], "pilots": ["rrt_mpc", "ppo"],
                  "physics_hz": 400, "control_hz": 25, "description": "two flights",
                  "atmosphere": {"elevation_m": 1500, "isa_offset_k": -10, "wind_mps": [3, -1, 0],
                                 "turbulence": "Moderate"}})
    data["episodes"].append({"start": [50.0, 10.0, 20.0], "goal": [50.0, 90.0, 35.0], "goal_radius_m": 1.5,
                             "timeout_s": 30})
    s = load_scenario(_write(tmp_path, data))
    assert s.description == "two flights"
    assert s.seeds == (3, 1, 2)
    assert s.pilots == ("ppo", "rrt_mpc")  # canonical order
    assert (s.physics_hz, s.control_hz) == (400.0, 25.0)
    assert (s.atmosphere.elevation_m, s.atmosphere.isa_offset_k) == (1500.0, -10.0)
    assert s.wind.steady_enu_m_s == (3.0, -1.0, 0.0) and s.wind.turbulence is TurbulenceLevel.MODERATE
    first, second = s.episodes
    assert (first.task.goal_radius_m, first.task.timeout_s) == (4.0, 70.0)
    assert (second.index, second.task.goal_radius_m, second.task.timeout_s) == (1, 1.5, 30.0)


def test_vehicle_from_a_file_relative_to_the_scenario_and_inline(tmp_path: Path) -> None:
    preset = yaml.safe_load((PRESET_DIR / "small_quad.yaml").read_text())
    (tmp_path / "vehicles").mkdir()
    (tmp_path / "vehicles" / "my_quad.yaml").write_text(yaml.safe_dump({**preset, "name": "my_quad"}))
    s = load_scenario(_write(tmp_path, _with({"vehicle": "vehicles/my_quad.yaml"})))
    assert s.vehicle.name == "my_quad" and s.vehicle_name == "my_quad"
    assert s.vehicle.fingerprint() == load_vehicle("small_quad").fingerprint()
    inline = load_scenario(_write(tmp_path, _with({"vehicle": {**preset, "name": "inline_quad"}})))
    assert inline.vehicle_name == "inline_quad"


def test_raw_is_a_copy_and_scenarios_pickle(tmp_path: Path) -> None:
    data = copy.deepcopy(BASE)
    s = scenario_from_dict(data, "mem.yaml", tmp_path)
    data["episodes"][0]["start"][0] = 99.0
    assert s.raw["episodes"][0]["start"][0] == 10.0 and s.source == "mem.yaml"
    back = pickle.loads(pickle.dumps(s))
    assert isinstance(back, Scenario) and back.episodes == s.episodes
    assert back.city.clearance([[10.0, 50.0, 10.0]]).distance_m[0] == pytest.approx(10.0)


# ---- bad input: ConfigError naming the file, the key and the reason ----------------------------------
NO_FLY_MAP = {"buildings": BASE["map"]["buildings"],
              "no_fly": [{"center": [90.0, 50.0], "size": [6.0, 6.0], "z_range": [0.0, 40.0]}]}
BAD_VEHICLE = {**yaml.safe_load((PRESET_DIR / "small_quad.yaml").read_text()), "mass_kg": -1.0}

BAD_CASES: list[tuple[str, dict[str, Any], str, str]] = [
    # unknown keys, missing keys
    ("unknown-top", {"colour": "red"}, "colour", "unknown key"),
    ("unknown-atmosphere", {"atmosphere.pressure_pa": 101325}, "atmosphere.pressure_pa", "unknown key"),
    ("unknown-episode", {"episodes[0].speed": 3}, "episodes[0].speed", "unknown key"),
    ("unknown-bounds", {"bounds.middle": [1, 2, 3]}, "bounds.middle", "unknown key"),
    ("unknown-map", {"map.style": "gothic"}, "map.style", "unknown key"),
    ("missing-name", {"name": DELETE}, "name", "missing"),
    ("missing-map", {"map": DELETE}, "map", "missing"),
    ("missing-vehicle", {"vehicle": DELETE}, "vehicle", "missing"),
    ("missing-episodes", {"episodes": DELETE}, "episodes", "missing"),
    ("missing-goal", {"episodes[0].goal": DELETE}, "episodes[0].goal", "missing"),
    # name, description
    ("name-space", {"name": "a b"}, "name", "'a b'"),
    ("name-dunder", {"name": "a__b"}, "name", "'__'"),
    ("name-dots", {"name": ".."}, "name", "'..'"),
    ("name-int", {"name": 7}, "name", "must be a string, got 7"),
    ("description-int", {"description": 3}, "description", "must be a string, got 3"),
    # vehicle
    ("vehicle-unknown", {"vehicle": "jetpack"}, "vehicle", "small_quad, uam_multicopter"),
    ("vehicle-missing-file", {"vehicle": "nope.yaml"}, "vehicle", "not a preset"),
    ("vehicle-number", {"vehicle": 5}, "vehicle", "got 5"),
    ("vehicle-inline-bad", {"vehicle": BAD_VEHICLE}, "vehicle.mass_kg", "must be positive, got -1.0"),
    # map and bounds (delegated to uam_fdm.city.mapfile)
    ("map-named-unknown", {"map": {"named": "atlantis"}, "bounds": DELETE}, "map.named", "unknown map 'atlantis'"),
    ("bounds-missing", {"bounds": DELETE}, "bounds", "missing"),
    ("bounds-null", {"bounds": None}, "bounds", "must be a mapping"),
    ("building-outside", {"map.buildings[0].center": [99.0, 50.0]}, "map.buildings[0]", "leaves the bounds"),
    # atmosphere
    ("elevation-bool", {"atmosphere.elevation_m": True}, "atmosphere.elevation_m", "must be a number"),
    ("elevation-string", {"atmosphere.elevation_m": "100"}, "atmosphere.elevation_m", "must be a number"),
    ("elevation-inf", {"atmosphere.elevation_m": math.inf}, "atmosphere.elevation_m", "must be finite"),
    ("elevation-range", {"atmosphere.elevation_m": 20000}, "atmosphere.elevation_m", "20000.0 is outside"),
    ("isa-range", {"atmosphere.isa_offset_k": 80}, "atmosphere.isa_offset_k", "80.0 is outside"),
    ("wind-short", {"atmosphere.wind_mps": [1, 2]}, "atmosphere.wind_mps", "3 finite numbers"),
    ("wind-nan", {"atmosphere.wind_mps": [1, math.nan, 0]}, "atmosphere.wind_mps", "3 finite numbers"),
    ("wind-bool", {"atmosphere.wind_mps": [True, 0, 0]}, "atmosphere.wind_mps", "3 finite numbers"),
    ("wind-strong", {"atmosphere.wind_mps": [100, 0, 0]}, "atmosphere.wind_mps", "exceeds 60"),
    ("turbulence-unknown", {"atmosphere.turbulence": "hurricane"}, "atmosphere.turbulence", "'hurricane'"),
    ("turbulence-number", {"atmosphere.turbulence": 3}, "atmosphere.turbulence", "got 3"),
    ("shear-law-unknown", {"atmosphere.wind_shear": {"law": "cubic"}}, "atmosphere.wind_shear.law",
     "unknown shear law 'cubic' (known: uniform, power, log)"),
    ("shear-law-missing", {"atmosphere.wind_shear": {"exponent": 0.3}}, "atmosphere.wind_shear.law", "missing"),
    ("shear-not-mapping", {"atmosphere.wind_shear": "power"}, "atmosphere.wind_shear", "must be a mapping"),
    ("shear-unknown-key", {"atmosphere.wind_shear": {"law": "power", "exponent": 0.3, "alpha": 0.3}},
     "atmosphere.wind_shear.alpha", "unknown key"),
    ("shear-exponent-range", {"atmosphere.wind_shear": {"law": "power", "exponent": 0.9}},
     "atmosphere.wind_shear.exponent", "exponent=0.9 is outside the accepted range [0.0, 0.6]"),
    ("shear-exponent-negative", {"atmosphere.wind_shear": {"law": "power", "exponent": -0.1}},
     "atmosphere.wind_shear.exponent", "-0.1 is outside"),
    ("shear-exponent-string", {"atmosphere.wind_shear": {"law": "power", "exponent": "0.3"}},
     "atmosphere.wind_shear.exponent", "must be a number"),
    ("shear-exponent-missing", {"atmosphere.wind_shear": {"law": "power"}}, "atmosphere.wind_shear.exponent",
     "missing (required by the power law)"),
    ("shear-roughness-range", {"atmosphere.wind_shear": {"law": "log", "roughness_m": 10.0}},
     "atmosphere.wind_shear.roughness_m", "roughness_m=10.0 is outside the accepted range [0.001, 3.0] m"),
    ("shear-roughness-zero", {"atmosphere.wind_shear": {"law": "log", "roughness_m": 0}},
     "atmosphere.wind_shear.roughness_m", "0.0 is outside"),
    ("shear-wrong-parameter", {"atmosphere.wind_shear": {"law": "log", "roughness_m": 1.0, "exponent": 0.3}},
     "atmosphere.wind_shear.exponent", "does not apply to the log law, got 0.3"),
    ("shear-uniform-parameter", {"atmosphere.wind_shear": {"law": "uniform", "roughness_m": 1.0}},
     "atmosphere.wind_shear.roughness_m", "does not apply to the uniform law"),
    ("shear-reference-range", {"atmosphere.wind_reference_height_m": 500}, "atmosphere.wind_reference_height_m",
     "500.0 is outside the accepted range [1.0, 300.0] m above the field"),
    ("shear-reference-bool", {"atmosphere.wind_reference_height_m": True}, "atmosphere.wind_reference_height_m",
     "must be a number"),
    ("shear-reference-below-floor", {"atmosphere.wind_reference_height_m": 3.0,
                                     "atmosphere.wind_shear": {"law": "log", "roughness_m": 2.0}},
     "atmosphere.wind_reference_height_m", "reference_height_m=3.0 is below the log law's floor 4.0 m"),
    ("atmosphere-list", {"atmosphere": [0, 0]}, "atmosphere", "must be a mapping"),
    ("cannot-hover", {"atmosphere": {"elevation_m": 9000, "isa_offset_k": 50}}, "atmosphere", "cannot hover"),
    # episodes
    ("episodes-empty", {"episodes": []}, "episodes", "non-empty"),
    ("episodes-mapping", {"episodes": {"start": [1, 2, 3]}}, "episodes", "non-empty list"),
    ("episode-not-mapping", {"episodes": [[1, 2, 3]]}, "episodes[0]", "must be a mapping"),
    ("start-short", {"episodes[0].start": [1, 2]}, "episodes[0].start", "got [1, 2]"),
    ("start-string", {"episodes[0].start": [10, "50", 10]}, "episodes[0].start", "3 finite numbers"),
    ("start-in-building", {"episodes[0].start": [50.0, 50.0, 10.0]}, "episodes[0].start", "inside building 0"),
    ("start-touching-building", {"episodes[0].start": [39.7, 50.0, 10.0]}, "episodes[0].start",
     "0.30 m from building 0"),
    ("start-on-roof", {"episodes[0].start": [50.0, 50.0, 30.2]}, "episodes[0].start", "0.20 m from building 0"),
    ("goal-near-ground", {"episodes[0].goal": [90.0, 50.0, 0.3]}, "episodes[0].goal", "0.30 m from the ground"),
    ("start-outside", {"episodes[0].start": [-5.0, 50.0, 10.0]}, "episodes[0].start", "out of bounds"),
    ("start-radius-outside", {"episodes[0].start": [0.2, 50.0, 10.0]}, "episodes[0].start", "out of bounds"),
    ("goal-above-ceiling", {"episodes[0].goal": [90.0, 50.0, 49.8]}, "episodes[0].goal", "out of bounds"),
    ("goal-no-fly", {"map": NO_FLY_MAP}, "episodes[0].goal", "no-fly zone"),
    ("goal-equals-start", {"episodes[0].goal": [10.0, 50.0, 10.0]}, "episodes[0].goal", "within the goal radius"),
    ("goal-within-radius", {"episodes[0].goal": [12.0, 50.0, 10.0], "goal_radius_m": 2.5}, "episodes[0].goal",
     "2.00 m from the start"),
    # goal radius and timeouts
    ("goal-radius-zero", {"goal_radius_m": 0}, "goal_radius_m", "outside the accepted range"),
    ("goal-radius-string", {"goal_radius_m": "3"}, "goal_radius_m", "must be a number"),
    ("episode-goal-radius-bool", {"episodes[0].goal_radius_m": False}, "episodes[0].goal_radius_m",
     "must be a number"),
    ("timeout-zero", {"timeout_s": 0}, "timeout_s", "outside the accepted range"),
    ("timeout-huge", {"timeout_s": 1e6}, "timeout_s", "outside the accepted range"),
    ("episode-timeout-string", {"episodes[0].timeout_s": "fast"}, "episodes[0].timeout_s", "'fast'"),
    ("episode-timeout-null", {"episodes[0].timeout_s": None}, "episodes[0].timeout_s", "None"),
    # seeds, pilots, rates
    ("seeds-empty", {"seeds": []}, "seeds", "non-empty"),
    ("seeds-scalar", {"seeds": 3}, "seeds", "got 3"),
    ("seeds-duplicate", {"seeds": [0, 1, 0]}, "seeds[2]", "duplicate seed 0"),
    ("seeds-negative", {"seeds": [-1]}, "seeds[0]", "got -1"),
    ("seeds-float", {"seeds": [1.5]}, "seeds[0]", "got 1.5"),
    ("seeds-bool", {"seeds": [True]}, "seeds[0]", "got True"),
    ("pilots-empty", {"pilots": []}, "pilots", "non-empty"),
    ("pilots-unknown", {"pilots": ["ppo", "astar"]}, "pilots[1]", "unknown pilot 'astar'"),
    ("pilots-duplicate", {"pilots": ["ppo", "ppo"]}, "pilots[1]", "duplicate pilot 'ppo'"),
    ("pilots-not-a-name", {"pilots": ["ppo", 3]}, "pilots[1]", "a pilot is named by a string, got 3"),
    ("physics-zero", {"physics_hz": 0}, "physics_hz", "outside the accepted range"),
    ("physics-string", {"physics_hz": "500"}, "physics_hz", "must be a number"),
    ("physics-bool", {"physics_hz": True}, "physics_hz", "must be a number"),
    ("control-above-physics", {"control_hz": 1000}, "control_hz", "outside the accepted range"),
    ("rates-not-multiple", {"control_hz": 60}, "physics_hz", "integer multiple of control_hz 60"),
]


@pytest.mark.parametrize(("changes", "key", "reason"), [c[1:] for c in BAD_CASES], ids=[c[0] for c in BAD_CASES])
def test_bad_input_names_file_key_and_reason(tmp_path: Path, changes: dict, key: str, reason: str) -> None:
    path = _write(tmp_path, _with(changes))
    with pytest.raises(ConfigError) as exc:
        load_scenario(path)
    assert exc.value.source == str(path)
    assert exc.value.key == key
    assert reason in exc.value.reason
    assert str(path) in str(exc.value) and key in str(exc.value) and reason in str(exc.value)


def test_the_old_key_methods_still_reads_with_a_warning_and_both_keys_are_refused(tmp_path: Path) -> None:
    """`methods:`, the key `pilots:` before its rename, reads the same (until the next release) with a
    DeprecationWarning naming the file and the new key, and its errors name the key as written; a file that gives
    both is refused, naming the file. The new key reads without a warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        new = load_scenario(_write(tmp_path, _with({"pilots": ["apf", "ppo"]}), "new.yaml"))
    old_path = _write(tmp_path, _with({"methods": ["apf", "ppo"]}), "old.yaml")
    with pytest.warns(DeprecationWarning, match=rf"^{re.escape(str(old_path))}: the key 'methods' is renamed 'pilots'"):
        old = load_scenario(old_path)
    assert old.pilots == new.pilots == ("ppo", "apf")
    bad = _write(tmp_path, _with({"methods": ["ppo", "astar"]}), "old-bad.yaml")
    with pytest.warns(DeprecationWarning), pytest.raises(ConfigError) as exc:
        load_scenario(bad)
    assert (exc.value.source, exc.value.key) == (str(bad), "methods[1]") and "unknown pilot 'astar'" in str(exc.value)
    both = _write(tmp_path, _with({"methods": ["ppo"], "pilots": ["ppo"]}), "both.yaml")
    with pytest.raises(ConfigError) as exc:
        load_scenario(both)
    assert (exc.value.source, exc.value.key) == (str(both), "methods") and "keep only 'pilots'" in exc.value.reason


def test_bad_vehicle_file_is_reported_through_the_scenario(tmp_path: Path) -> None:
    (tmp_path / "bad_vehicle.yaml").write_text(yaml.safe_dump(BAD_VEHICLE))
    path = _write(tmp_path, _with({"vehicle": "bad_vehicle.yaml"}))
    with pytest.raises(ConfigError, match=r"scen\.yaml: vehicle: in vehicle file .*bad_vehicle\.yaml: mass_kg"):
        load_scenario(path)


RAW_CASES: list[tuple[str, str, str, str]] = [
    ("yaml-syntax", "name: [unclosed\n", "<yaml>", "not valid YAML"),
    ("duplicate-key", yaml.safe_dump(BASE, sort_keys=False) + "name: again\n", "<yaml>", "duplicate key 'name'"),
    ("root-list", "- name: box\n", "<root>", "must be a mapping"),
    ("root-empty", "", "<root>", "got NoneType"),
]


@pytest.mark.parametrize(("text", "key", "reason"), [c[1:] for c in RAW_CASES], ids=[c[0] for c in RAW_CASES])
def test_bad_yaml_text(tmp_path: Path, text: str, key: str, reason: str) -> None:
    path = tmp_path / "raw.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as exc:
        load_scenario(path)
    assert (exc.value.source, exc.value.key) == (str(path), key) and reason in exc.value.reason


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"nope\.yaml: <file>: cannot read"):
        load_scenario(tmp_path / "nope.yaml")


# ---- resolve_scenarios -------------------------------------------------------------------------------
def test_resolve_builtin_sets() -> None:
    assert [s.name for s in resolve_scenarios("default")] == ["downtown-quad", "suburb-quad", "suburb-uam"]
    assert len(resolve_scenarios("full")) == 14


def test_resolve_file_and_folder(tmp_path: Path) -> None:
    folder = tmp_path / "set"
    folder.mkdir()
    _write(folder, _with({"name": "second"}), "b.yaml")
    _write(folder, _with({"name": "first"}), "a.yml")
    (folder / "notes.txt").write_text("not a scenario")
    assert [s.name for s in resolve_scenarios(str(folder / "b.yaml"))] == ["second"]
    assert [s.name for s in resolve_scenarios(folder)] == ["first", "second"]


def test_resolve_rejects_duplicate_names_and_empty_folders(tmp_path: Path) -> None:
    _write(tmp_path, BASE, "a.yaml")
    _write(tmp_path, BASE, "b.yaml")
    with pytest.raises(ConfigError, match=r"b\.yaml: name: duplicate scenario name 'box'"):
        resolve_scenarios(tmp_path)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="holds no .yaml"):
        resolve_scenarios(tmp_path / "empty")


@pytest.mark.parametrize("spec", ["no-such-set", "missing/dir", "gone.yaml"])
def test_resolve_missing_path_lists_builtin_sets(tmp_path: Path, spec: str) -> None:
    sets = (r"\(benchmark, benchmark-perfect, benchmark-perfect-quick, benchmark-perfect-validation, "
            r"benchmark-perfect-validation-quick, benchmark-quick, benchmark-validation, benchmark-validation-quick, "
            r"default, full, sweep, sweep-quick\)")
    with pytest.raises(ValueError, match=rf"built-in scenario set {sets}") as exc:
        resolve_scenarios(str(tmp_path / spec) if "/" in spec or spec.endswith(".yaml") else spec)
    assert not isinstance(exc.value, ConfigError)


def test_failing_case_helper_is_sound(tmp_path: Path) -> None:
    """Each bad case differs from BASE, and BASE itself loads (so failures come from the change)."""
    assert load_scenario(_write(tmp_path, _with({}))).name == "box"
    for case_id, changes, _, _ in BAD_CASES:
        assert _with(changes) != BASE, case_id

