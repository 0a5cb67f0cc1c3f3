"""Map error: the prior map the pilots get against the true world (presets, seeds, keep-clear, cranes, parsing)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.city.map_error import (
    CRANE_HEIGHT_M,
    MAP_ERROR_PRESETS,
    MapErrorConfig,
    apply_map_error,
    map_error_from_config,
    unmapped_from_config,
)
from uam_fdm.city.mapfile import load_named_map
from uam_fdm.errors import ConfigError


@pytest.fixture(scope="module")
def downtown() -> BuildingMap:
    return load_named_map("downtown")


def _grid_city() -> tuple[BuildingMap, np.ndarray]:
    """A 300 x 300 m city of 25 m blocks on a 50 m grid, and 16 street points 12 m up (starts and goals)."""
    blocks = [Building(i * 5 + j, (25.0 + 50.0 * i, 25.0 + 50.0 * j), (25.0, 25.0), 20.0 + 5.0 * ((i + j) % 4))
              for i in range(6) for j in range(5)]
    points = np.array([[50.0 * i, 50.0 * j + 25.0, 12.0] for i in range(1, 5) for j in range(4)])
    return BuildingMap(blocks, [0.0, 0.0, 0.0], [300.0, 300.0, 120.0]), points


def _by_id(bmap: BuildingMap) -> dict[int, list]:
    out: dict[int, list] = {}
    for p in bmap.buildings:
        out.setdefault(p.id, []).append(p)
    return out


def test_exact_and_nothing_unmapped_is_the_world_itself(downtown: BuildingMap) -> None:
    r = apply_map_error(downtown, (), MAP_ERROR_PRESETS["exact"], 3, [], 5.0)
    assert r.truth is downtown and r.prior is downtown
    assert r.unmapped_ids == () and r.missing_ids == () and r.generated_ids == ()


def test_outdated_preset_misses_a_tenth_and_moves_heights_by_at_most_5_m(downtown: BuildingMap) -> None:
    r = apply_map_error(downtown, (), MAP_ERROR_PRESETS["outdated"], 11, [], 5.0)
    n = len(downtown.building_ids)
    assert len(r.missing_ids) == round(0.10 * n) == 21
    assert r.truth is downtown  # nothing added to the world
    truth, prior = _by_id(r.truth), _by_id(r.prior)
    assert set(prior) == set(truth) - set(r.missing_ids)
    dz = np.array([prior[i][0].height_m - truth[i][0].height_m for i in prior])
    assert np.abs(dz).max() <= 5.0 and np.abs(dz).max() > 4.0  # uniform in +-5 m over ~190 buildings
    assert np.std(dz) > 2.0  # not one common offset
    assert all(prior[i][0].center_xy_m == truth[i][0].center_xy_m for i in prior)  # outdated does not move them
    assert r.shifted_ids == () and len(r.height_changed_ids) == len(prior)


def test_wrong_preset_misses_a_quarter_moves_footprints_and_adds_cranes_and_masts(downtown: BuildingMap) -> None:
    cfg = MAP_ERROR_PRESETS["wrong"]
    r = apply_map_error(downtown, (), cfg, 11, [], 5.0)
    assert len(r.missing_ids) == round(0.25 * len(downtown.building_ids))
    assert len(r.generated_ids) == cfg.cranes + cfg.masts == 7 and r.dropped == 0
    truth, prior = _by_id(r.truth), _by_id(r.prior)
    shifts = [math.dist(prior[i][0].center_xy_m, truth[i][0].center_xy_m) for i in prior]
    assert max(shifts) <= cfg.shift_m + 1e-9 and max(shifts) > 0.8 * cfg.shift_m
    # ids: the prior is the truth minus what only the truth has
    assert set(prior) <= set(truth)
    assert set(truth) - set(prior) == set(r.unmapped_ids) == set(r.missing_ids) | set(r.generated_ids)
    assert min(r.generated_ids) > int(downtown.building_ids.max())
    assert [len(truth[i]) for i in r.generated_ids] == [2, 2, 2, 1, 1, 1, 1]  # cranes: mast + jib; masts: one box


def test_a_crane_is_a_mast_and_an_elevated_jib_that_a_vehicle_can_hit(downtown: BuildingMap) -> None:
    r = apply_map_error(downtown, (), MapErrorConfig("x", cranes=2), 4, [], 5.0)
    assert len(r.generated_ids) == 2
    for cid in r.generated_ids:
        mast, jib = sorted(_by_id(r.truth)[cid], key=lambda b: b.base_m)
        assert mast.base_m == 0.0 and max(mast.size_xy_m) <= 2.5
        assert CRANE_HEIGHT_M[0] <= jib.height_m <= CRANE_HEIGHT_M[1] and jib.height_m == mast.height_m
        assert 1.5 <= jib.height_m - jib.base_m <= 2.0 and jib.base_m > 30.0  # lifted off the ground
        assert 30.0 <= jib.size_xy_m[0] <= 1.25 * 60.0
        c, s = math.cos(jib.yaw_rad), math.sin(jib.yaw_rad)
        tip = np.asarray(jib.center_xy_m) + 0.4 * jib.size_xy_m[0] * np.array([c, s])  # far from the mast
        z_mid = 0.5 * (jib.base_m + jib.height_m)
        hit = r.truth.clearance(np.array([[*tip, z_mid]]))
        assert hit.distance_m[0] < 0.0 and hit.building_id[0] == cid
        # just under it: free (a generated obstacle keeps 1 m from the others, so the jib is nearest)
        below = r.truth.clearance(np.array([[*tip, jib.base_m - 0.5]]))
        assert below.distance_m[0] == pytest.approx(0.5) and below.building_id[0] == cid
        assert cid not in r.prior.building_ids


def test_the_same_seed_gives_the_same_maps_and_other_seeds_differ(downtown: BuildingMap) -> None:
    cfg = MAP_ERROR_PRESETS["wrong"]
    a = apply_map_error(downtown, (), cfg, 21, [], 5.0)
    b = apply_map_error(downtown, (), cfg, 21, [], 5.0)
    c = apply_map_error(downtown, (), cfg, 22, [], 5.0)
    assert a.truth.buildings == b.truth.buildings and a.prior.buildings == b.prior.buildings
    assert a.missing_ids == b.missing_ids
    assert a.missing_ids != c.missing_ids
    assert a.truth.buildings != c.truth.buildings and a.prior.buildings != c.prior.buildings


def test_one_parameter_leaves_the_other_draws_as_they_were(downtown: BuildingMap) -> None:
    few = apply_map_error(downtown, (), MapErrorConfig("x", 0.2, 4.0, cranes=1), 8, [], 5.0)
    more = apply_map_error(downtown, (), MapErrorConfig("x", 0.2, 4.0, cranes=3, masts=2), 8, [], 5.0)
    assert few.missing_ids == more.missing_ids and few.prior.buildings == more.prior.buildings
    first = [b for b in few.truth.buildings if b.id in few.generated_ids]
    assert [b for b in more.truth.buildings if b.id == few.generated_ids[0]] == first  # the first crane stays


@pytest.mark.parametrize("seed", range(12))
def test_generated_errors_keep_clear_of_every_start_and_goal(seed: int) -> None:
    world, points = _grid_city()
    clearance = 7.0
    cfg = MapErrorConfig("x", missing_fraction=0.2, height_error_m=15.0, shift_m=10.0, cranes=4, masts=8)
    r = apply_map_error(world, (), cfg, seed, points, clearance)
    generated = BuildingMap([b for b in r.truth.buildings if b.id in r.generated_ids], world.bounds_min_m,
                            world.bounds_max_m)
    if r.generated_ids:
        assert generated.clearance(points).distance_m.min() >= clearance - 1e-9
    # no prior building nearer a point than clearance or than the true one (whichever is less)
    true_d = world.clearance(points).distance_m
    prior_d = r.prior.clearance(points).distance_m
    assert (prior_d >= np.minimum(clearance, true_d) - 1e-9).all()
    assert len(r.shifted_ids) > 0 and len(r.height_changed_ids) > 0  # the check did not just switch errors off


def test_unmapped_buildings_are_in_the_truth_only() -> None:
    world, _ = _grid_city()
    extra = (Building(100, (150.0, 150.0), (4.0, 4.0), 30.0),)
    r = apply_map_error(world, extra, MAP_ERROR_PRESETS["exact"], 0, [], 5.0)
    assert r.prior is world and r.unmapped_ids == (100,)
    assert 100 in r.truth.building_ids and len(r.truth.buildings) == len(world.buildings) + 1
    with pytest.raises(ValueError, match="ids"):
        apply_map_error(world, (Building(3, (150.0, 150.0), (4.0, 4.0), 30.0),), MAP_ERROR_PRESETS["exact"], 0, [],
                        5.0)


def test_unmapped_config_numbers_after_the_world_and_names_the_key() -> None:
    world, _ = _grid_city()
    parts = unmapped_from_config([{"center": [150.0, 150.0], "size": [4.0, 4.0], "height": 30.0, "yaw_deg": 90.0}],
                                 "s.yaml", world)
    assert parts[0].id == 30 and parts[0].yaw_rad == pytest.approx(math.pi / 2)
    with pytest.raises(ConfigError, match=r"s\.yaml: unmapped\[1\]\.size: .*\[0, 5\]"):
        unmapped_from_config([{"center": [1, 1], "size": [1, 1], "height": 3},
                              {"center": [150, 150], "size": [0, 5], "height": 30}], "s.yaml", world)
    with pytest.raises(ConfigError, match=r"unmapped\[0\]: footprint .* leaves the bounds"):
        unmapped_from_config([{"center": [299.0, 150.0], "size": [4.0, 4.0], "height": 30.0}], "s.yaml", world)


def test_map_error_config_presets_and_overrides() -> None:
    assert map_error_from_config("wrong", "s.yaml") == MAP_ERROR_PRESETS["wrong"]
    cfg = map_error_from_config({"preset": "outdated", "height_error_m": 2.0, "cranes": 1, "seed": 9}, "s.yaml")
    assert (cfg.level, cfg.missing_fraction, cfg.height_error_m, cfg.cranes, cfg.seed) == ("outdated", 0.1, 2.0, 1, 9)
    assert cfg.overridden == ("height_error_m", "cranes") and cfg.label == "outdated+"
    assert map_error_from_config({"missing_fraction": 0.3}, "s.yaml").level == "exact"
    assert map_error_from_config({"preset": "outdated", "height_error_m": 5.0}, "s.yaml").overridden == ()


@pytest.mark.parametrize(("value", "key", "quoted"), [
    ("stale", "map_error", "'stale'"),
    ({"preset": "bad"}, "map_error.preset", "exact, outdated, wrong"),
    ({"missing_fraction": 1.5}, "map_error.missing_fraction", "1.5"),
    ({"height_error_m": -2.0}, "map_error.height_error_m", "-2.0"),
    ({"shift_m": float("nan")}, "map_error.shift_m", "nan"),
    ({"cranes": 2.5}, "map_error.cranes", "2.5"),
    ({"masts": True}, "map_error.masts", "True"),
    ({"seed": -1}, "map_error.seed", "-1"),
    ({"colour": 1}, "map_error.colour", "unknown key"),
])
def test_map_error_config_errors_name_file_key_and_value(value: object, key: str, quoted: str) -> None:
    with pytest.raises(ConfigError) as info:
        map_error_from_config(value, "s.yaml")
    assert info.value.source == "s.yaml" and info.value.key == key and quoted in info.value.reason
