"""Map configurations: every source, and a clear ConfigError for every kind of bad input."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from uam_fdm.city.buildings import Building
from uam_fdm.city.mapfile import load_map_file, load_named_map, map_from_config
from uam_fdm.errors import ConfigError

BOUNDS = {"min": [0, 0, 0], "max": [200, 200, 120]}
GOOD = {"center": [50, 60], "size": [20, 10], "height": 30, "yaw_deg": 90}


def test_explicit_buildings() -> None:
    cfg = yaml.safe_load("""
map:
  buildings:
    - {center: [50, 60], size: [20, 10], height: 30, yaw_deg: 90}
    - {center: [150, 150], size: [30, 30], height: 80.5}
  no_fly:
    - {center: [100, 20], size: [40, 20], z_range: [0, 200]}
bounds: {min: [0, 0, 0], max: [200, 200, 120]}
""")
    bmap = map_from_config(cfg["map"], cfg["bounds"], "s.yaml", Path("."))
    b0, b1 = bmap.buildings
    assert b0 == Building(0, (50.0, 60.0), (20.0, 10.0), 30.0, math.radians(90.0))
    assert b1.id == 1 and b1.yaw_rad == 0.0 and b1.height_m == 80.5
    # Yaw 90: the 20 m width lies along y, so 15 m east of the centre is 10 m from the wall.
    assert abs(bmap.clearance_one(65.0, 60.0, 10.0) - 10.0) < 1e-9
    assert bmap.in_no_fly(np.array([[100.0, 20.0, 50.0]])).tolist() == [True]
    assert bmap.bounds_max_m.tolist() == [200.0, 200.0, 120.0]


def test_generator_named_and_default_bounds() -> None:
    gen = map_from_config({"generator": {"preset": "canyon", "seed": 4}}, None, "s.yaml", Path("."))
    assert gen.bounds_max_m.tolist() == [700.0, 700.0, 300.0] and len(gen.buildings) > 50
    again = map_from_config({"generator": {"preset": "canyon", "seed": 4}}, None, "s.yaml", Path("."))
    assert again.buildings == gen.buildings and gen.name == "gen-canyon-4"  # not the shipped "canyon"
    labelled = map_from_config({"generator": {"preset": "canyon", "seed": 4, "name": "gen-4"}}, None, "s.yaml",
                               Path("."))
    assert labelled.name == "gen-4" and labelled.buildings == gen.buildings
    assert map_from_config({"generator": {"seed": 4}}, None, "s.yaml", Path(".")).name == "gen-4"
    named = map_from_config({"named": "suburb"}, None, "s.yaml", Path("."))
    assert named.buildings == load_named_map("suburb").buildings and named.name == "suburb"
    wider = map_from_config({"named": "suburb"}, {"min": [0, 0, 0], "max": [800, 800, 400]}, "s.yaml", Path("."))
    assert wider.bounds_max_m[2] == 400.0
    with pytest.raises(ConfigError, match="outside these bounds"):
        map_from_config({"named": "suburb"}, {"min": [0, 0, 0], "max": [300, 300, 100]}, "s.yaml", Path("."))


def test_shipped_map_file_format_loads(tmp_path: Path) -> None:
    path = tmp_path / "x.yaml"
    path.write_text("name: tiny\nbounds: {min: [0, 0, 0], max: [100, 100, 50]}\n"
                    "map:\n  buildings:\n  - {center: [50, 50], size: [10, 10], height: 20}\n")
    bmap = load_map_file(path)
    assert bmap.name == "tiny" and len(bmap.buildings) == 1
    path.write_text("name: tiny\nbounds: {min: [0, 0, 0], max: [100, 100, 50]}\ncolour: red\nmap: {named: suburb}\n")
    with pytest.raises(ConfigError) as exc:
        load_map_file(path)
    assert exc.value.key == "colour" and exc.value.source == str(path)


def test_the_documented_message() -> None:
    items = [GOOD] * 3 + [{"center": [50, 60], "size": [0, 5], "height": 10}]
    with pytest.raises(ConfigError) as exc:
        map_from_config({"buildings": items}, BOUNDS, "maps/x.yaml", Path("."))
    assert str(exc.value) == "maps/x.yaml: map.buildings[3].size: must be two positive numbers, got [0, 5]"


@pytest.mark.parametrize("building, key, reason", [
    ({"center": [50, 60], "size": [-3, 5], "height": 10}, "map.buildings[0].size", "two positive numbers"),
    ({"center": [50, 60], "size": [3, 5], "height": 0}, "map.buildings[0].height", "positive"),
    ({"center": [50, 60], "size": [3, 5], "height": -2.5}, "map.buildings[0].height", "positive"),
    ({"center": [float("nan"), 60], "size": [3, 5], "height": 10}, "map.buildings[0].center", "finite"),
    ({"center": [50, 60], "size": [3, float("inf")], "height": 10}, "map.buildings[0].size", "positive"),
    ({"center": [50, 60], "size": [3, 5], "height": float("nan")}, "map.buildings[0].height", "positive"),
    ({"center": [50, 60], "size": [3, 5], "height": 10, "yaw_deg": float("nan")}, "map.buildings[0].yaw_deg",
     "finite"),
    ({"center": [50], "size": [3, 5], "height": 10}, "map.buildings[0].center", "2 finite numbers"),
    ({"center": ["a", 60], "size": [3, 5], "height": 10}, "map.buildings[0].center", "2 finite numbers"),
    ({"center": [50, 60], "size": [3, 5], "height": True}, "map.buildings[0].height", "positive"),
    ({"center": [50, 60], "size": [3, 5]}, "map.buildings[0].height", "missing"),
    ({"center": [50, 60], "size": [3, 5], "height": 10, "colour": "red"}, "map.buildings[0].colour", "unknown key"),
    ({"center": [195, 60], "size": [20, 10], "height": 10}, "map.buildings[0]", "leaves the bounds"),
    ({"center": [100, 100], "size": [300, 10], "height": 10, "yaw_deg": 90}, "map.buildings[0]", "leaves the bounds"),
    ([50, 60, 20], "map.buildings[0]", "must be a mapping"),
])
def test_bad_buildings(building: object, key: str, reason: str) -> None:
    with pytest.raises(ConfigError) as exc:
        map_from_config({"buildings": [building]}, BOUNDS, "scn.yaml", Path("."))
    assert exc.value.source == "scn.yaml" and exc.value.key == key and reason in exc.value.reason, str(exc.value)


def test_nan_from_yaml_is_caught() -> None:
    cfg = yaml.safe_load("buildings: [{center: [.nan, 5], size: [1, 1], height: 3}]")
    with pytest.raises(ConfigError, match=r"map\.buildings\[0\]\.center: must be 2 finite numbers, got \[nan, 5\]"):
        map_from_config(cfg, BOUNDS, "scn.yaml", Path("."))


@pytest.mark.parametrize("map_cfg, bounds, key, reason", [
    ({"buildings": [GOOD], "colour": 1}, BOUNDS, "map.colour", "unknown key"),
    ({}, BOUNDS, "map", "exactly one of"),
    ({"buildings": [GOOD], "named": "suburb"}, BOUNDS, "map", "exactly one of"),
    ({"buildings": [GOOD]}, None, "bounds", "missing"),
    ({"buildings": GOOD}, BOUNDS, "map.buildings", "must be a list"),
    ({"buildings": [GOOD], "height_key": "h"}, BOUNDS, "map.height_key", "only applies"),
    ({"named": "atlantis"}, None, "map.named", "unknown map"),
    ({"generator": {"preset": "suburb"}}, None, "map.generator.seed", "missing"),
    ({"generator": {"seed": 1, "colour": 2}}, None, "map.generator.colour", "unknown key"),
    ({"generator": {"seed": 1, "name": ""}}, None, "map.generator.name", "non-empty string"),
    ({"buildings": [GOOD]}, {"min": [0, 0, 0]}, "bounds.max", "missing"),
    ({"buildings": [GOOD]}, {"min": [0, 0, 0], "max": [200, 200]}, "bounds.max", "3 finite numbers"),
    ({"buildings": [GOOD]}, {"min": [0, 0, -5], "max": [200, 200, 100]}, "bounds.min", ">= 0"),
    ({"buildings": [GOOD]}, {"min": [0, 0, 0], "max": [200, 0, 100]}, "bounds.max", "must exceed"),
    ({"buildings": [GOOD]}, {"min": [0, 0, 0], "max": [200, 200, 100], "pad": 1}, "bounds.pad", "unknown key"),
    ({"buildings": [GOOD]}, [0, 0, 0, 200, 200, 100], "bounds", "must be a mapping"),
    ({"buildings": [GOOD], "no_fly": [{"center": [1, 2], "size": [3, 4], "z_range": [5, 5]}]}, BOUNDS,
     "map.no_fly[0].z_range", "top > bottom"),
    ({"buildings": [GOOD], "no_fly": [{"center": [1, 2], "size": [3, 4]}]}, BOUNDS, "map.no_fly[0].z_range",
     "missing"),
    ({"geojson": 5}, BOUNDS, "map.geojson", "file path"),
])
def test_bad_map_configs(map_cfg: dict, bounds: object, key: str, reason: str) -> None:
    with pytest.raises(ConfigError) as exc:
        map_from_config(map_cfg, bounds, "scn.yaml", Path("."))
    assert exc.value.source == "scn.yaml" and exc.value.key == key and reason in exc.value.reason, str(exc.value)
    assert isinstance(exc.value, ValueError)


def test_not_a_mapping() -> None:
    with pytest.raises(ConfigError) as exc:
        map_from_config(["buildings"], BOUNDS, "scn.yaml", Path("."))
    assert exc.value.key == "map"
