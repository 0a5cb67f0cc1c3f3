"""The scenario keys of what a vehicle senses and how wrong its map is: `sensing`, `map_error`, `unmapped`."""
from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest
import yaml

import compare.scenarios.scenario as scenario_module
from cli_checks import fails
from compare.scenarios.fingerprint import scenario_fingerprint
from compare.scenarios.scenario import Scenario, load_scenario, scenario_from_dict
from scenario_box import BASE  # a 100 x 100 x 50 m box with one 20 x 20 x 30 m building (id 0) in the middle
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.city.map_error import MAP_ERROR_PRESETS, MapErrorResult
from uam_fdm.errors import ConfigError
from uam_fdm.sensing.config import MAX_LIDAR_RAYS_PER_SCAN
from uam_fdm.sensing.specs import sensing_preset
from uam_fdm.vehicle.params import load_vehicle

UNMAPPED = [{"center": [50.0, 85.0], "size": [10.0, 6.0], "height": 20.0}]


def _load(tmp_path: Path, **extra: Any) -> Scenario:
    path = tmp_path / "scen.yaml"
    path.write_text(yaml.safe_dump({**copy.deepcopy(BASE), **extra}, sort_keys=False))
    return load_scenario(path)


def _error(tmp_path: Path, **extra: Any) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        _load(tmp_path, **extra)
    assert info.value.source == str(tmp_path / "scen.yaml")
    return info.value


def test_without_the_new_keys_the_prior_is_the_city_and_sensing_is_perfect(tmp_path: Path) -> None:
    sc = _load(tmp_path)
    assert sc.prior_map is sc.city and sc.unmapped_ids == ()
    assert sc.map_error == MAP_ERROR_PRESETS["exact"]
    assert sc.sensing == sensing_preset("perfect", load_vehicle("small_quad").mass_kg) and sc.sensing.perfect
    assert "sensing" not in scenario_fingerprint(sc)


@pytest.mark.parametrize("level", ["perfect", "nominal", "degraded"])
def test_sensing_presets_load(tmp_path: Path, level: str) -> None:
    sc = _load(tmp_path, sensing=level)
    assert sc.sensing == sensing_preset(level, sc.vehicle.mass_kg) and sc.sensing.label == level
    assert ("sensing" in scenario_fingerprint(sc)) == (level != "perfect")


def test_sensing_overrides_load_and_are_recorded(tmp_path: Path) -> None:
    sc = _load(tmp_path, sensing={"preset": "degraded", "latency_s": 0.05, "lidar": {"dropout": 0.3, "channels": 16},
                                  "gnss": {"satellites": 3, "urban_canyon": True}})
    base = sensing_preset("degraded", sc.vehicle.mass_kg)
    assert sc.sensing.latency_s == 0.05 and sc.sensing.lidar.dropout == 0.3 and sc.sensing.gnss.satellites == 3
    assert sc.sensing.lidar.part == base.lidar.part and sc.sensing.imu == base.imu
    # only what differs from the preset counts as changed (the preset's lidar already has 16 channels; its
    # GNSS already sees the urban canyon)
    assert sc.sensing.overridden == ("latency_s", "gnss.satellites", "lidar.dropout")
    assert sc.sensing.label == "degraded+"
    assert _load(tmp_path, sensing={"imu": {"rate_hz": 400}}).sensing.level == "nominal"  # the mapping's default


@pytest.mark.parametrize(("value", "key", "quoted"), [
    ("noisy", "sensing", "'noisy'"),
    ({"preset": "good"}, "sensing.preset", "perfect, nominal, degraded"),
    ({"imu": {"gyro_noise_density_rad_s_rthz": -0.1}}, "sensing.imu.gyro_noise_density_rad_s_rthz", "-0.1"),
    ({"baro": {"noise_m": float("inf")}}, "sensing.baro.noise_m", "inf"),
    ({"baro": {"rate_hz": 0}}, "sensing.baro.rate_hz", "0"),
    ({"heading": {"correlation_time_s": -5}}, "sensing.heading.correlation_time_s", "-5"),
    ({"gnss": {"nlos_probability": 1.2}}, "sensing.gnss.nlos_probability", "1.2"),
    ({"gnss": {"max_outage_s": 3600}}, "sensing.gnss.max_outage_s", "3600"),
    ({"gnss": {"satellites": -1}}, "sensing.gnss.satellites", "-1"),
    ({"gnss": {"min_satellites": 3}}, "sensing.gnss.min_satellites", "3"),
    ({"gnss": {"urban_canyon": "yes"}}, "sensing.gnss.urban_canyon", "'yes'"),
    ({"gnss": {"part": "u-blox F10"}}, "sensing.gnss.part", "unknown key"),
    ({"lidar": {"dropout": -0.01}}, "sensing.lidar.dropout", "-0.01"),
    ({"lidar": {"channels": 10**9}}, "sensing.lidar.channels", "1000000000"),
    ({"lidar": {"horizontal_resolution_deg": 1e-6}}, "sensing.lidar.horizontal_resolution_deg", "1e-06"),
    ({"lidar": {"channels": 500, "horizontal_resolution_deg": 0.1}}, "sensing.lidar.channels", "1.8e+06 rays"),
    ({"lidar": {"min_range_m": 150.0}}, "sensing.lidar.min_range_m", "150"),
    ({"lidar": {"vertical_fov_deg": [10, -10]}}, "sensing.lidar.vertical_fov_deg", "[10, -10]"),
    ({"latency_s": -0.01}, "sensing.latency_s", "-0.01"),
    ({"latency_s": 2.0}, "sensing.latency_s", "2.0"),
    ({"preset": "perfect", "latency_s": 0.1}, "sensing", "perfect"),
    ({"camera": {}}, "sensing.camera", "unknown key"),
])
def test_bad_sensing_values_name_file_key_and_value(tmp_path: Path, value: Any, key: str, quoted: str) -> None:
    err = _error(tmp_path, sensing=value)
    assert err.key == key and quoted in err.reason, err


def test_a_lidar_of_a_billion_rays_fails_validate_before_the_map_is_built(
        tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "scen.yaml"
    path.write_text(yaml.safe_dump({**copy.deepcopy(BASE), "sensing": {"lidar": {"horizontal_resolution_deg": 1e-6,
                                                                                 "channels": 2778}}}))

    def must_not_run(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("the map was built before the sensing key was refused")

    monkeypatch.setattr(scenario_module, "map_from_config", must_not_run)
    line = fails(["validate", str(path)], capsys, tmp_path, str(path), "sensing.lidar.channels", "2778 channels",
                 f"at most {MAX_LIDAR_RAYS_PER_SCAN:,}")
    assert "1e+12 rays per scan" in line


def test_map_error_presets_load_and_change_the_prior_only(tmp_path: Path) -> None:
    sc = _load(tmp_path, map_error={"preset": "outdated", "seed": 4})
    assert sc.map_error.level == "outdated" and sc.map_error.seed == 4
    assert sc.prior_map is not sc.city and len(sc.city.buildings) == 1
    assert sc.prior_map.buildings[0].height_m != sc.city.buildings[0].height_m  # +-5 m
    assert abs(sc.prior_map.buildings[0].height_m - 30.0) <= 5.0 and sc.city.buildings[0].height_m == 30.0
    again = _load(tmp_path, map_error={"preset": "outdated", "seed": 4})
    assert again.prior_map.buildings == sc.prior_map.buildings  # reproducible
    default_seed = _load(tmp_path, map_error="outdated", seeds=[4, 9])  # the draws use the first seed
    assert default_seed.prior_map.buildings == sc.prior_map.buildings
    assert scenario_fingerprint(sc)["map"] != scenario_fingerprint(_load(tmp_path))["map"]


def test_unmapped_buildings_are_in_the_city_not_in_the_prior(tmp_path: Path) -> None:
    sc = _load(tmp_path, unmapped=UNMAPPED)
    assert sc.unmapped_ids == (1,) and sorted(sc.city.building_ids) == [0, 1]
    assert list(sc.prior_map.building_ids) == [0] and sc.prior_map.buildings == sc.city.buildings[:1]
    empty = _load(tmp_path, unmapped=[])
    assert empty.prior_map is empty.city and empty.unmapped_ids == ()


def test_unmapped_errors_name_the_key(tmp_path: Path) -> None:
    err = _error(tmp_path, unmapped=[UNMAPPED[0], {"center": [20.0, 20.0], "size": [0, 5], "height": 10.0}])
    assert err.key == "unmapped[1].size" and "[0, 5]" in err.reason
    err = _error(tmp_path, unmapped={"center": [20.0, 20.0]})
    assert err.key == "unmapped" and "list" in err.reason
    # a start inside an unmapped building: the start must be clear of the true city
    err = _error(tmp_path, unmapped=[{"center": [10.0, 50.0], "size": [4.0, 4.0], "height": 20.0}])
    assert err.key == "episodes[0].start" and "inside building 1" in err.reason


def test_bad_map_error_names_file_key_and_value(tmp_path: Path) -> None:
    err = _error(tmp_path, map_error="old")
    assert err.key == "map_error" and "'old'" in err.reason and "exact, outdated, wrong" in err.reason
    err = _error(tmp_path, map_error={"preset": "wrong", "missing_fraction": -0.1})
    assert err.key == "map_error.missing_fraction" and "-0.1" in err.reason


def test_a_start_touching_a_prior_building_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The prior check itself (generated errors keep clear, so a prior built to touch the start stands in)."""
    def prior_over_the_start(world: BuildingMap, unmapped: Any, *args: Any) -> MapErrorResult:
        blocking = Building(0, (10.0, 50.0), (4.0, 4.0), 20.0)
        prior = BuildingMap([blocking], world.bounds_min_m, world.bounds_max_m)
        return MapErrorResult(truth=world, prior=prior, unmapped_ids=())

    monkeypatch.setattr(scenario_module, "apply_map_error", prior_over_the_start)
    with pytest.raises(ConfigError) as info:
        scenario_from_dict({**copy.deepcopy(BASE), "map_error": "outdated"}, "s.yaml", tmp_path)
    assert info.value.key == "episodes[0].start" and "prior map" in info.value.reason
