"""Random legs, `episodes: {random: N, ...}`: drawn from the file's seed (same file, same legs), valid by
construction and then checked as explicit episodes are; bad keys and impossible requests named; the same draws as
the benchmark's legs."""
from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from compare.scenarios import benchmark
from compare.scenarios.levels import with_levels
from compare.scenarios.random_legs import MAX_RANDOM_LEGS, LegRanges, draw_leg
from compare.scenarios.scenario import Scenario, load_scenario, scenario_from_dict
from rl.task.vehicles import task_for
from scenario_box import BASE
from uam_fdm.city.generator import generate_city
from uam_fdm.errors import ConfigError
from uam_fdm.vehicle.params import load_vehicle

QUAD_RADIUS_M = 0.42
SUBURB: dict[str, Any] = {"name": "rnd", "map": {"named": "suburb"}, "vehicle": "small_quad", "seeds": [4],
                          "episodes": {"random": 6, "min_length_m": 120.0, "max_length_m": 250.0,
                                       "min_height_m": 8.0, "max_height_m": 25.0}}


def _load(tmp_path: Path, data: dict[str, Any], name: str = "rnd.yaml") -> Scenario:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return load_scenario(path)


def _box(**episodes: Any) -> dict[str, Any]:
    data = copy.deepcopy(BASE)
    data["episodes"] = {"random": 4, **episodes}
    return data


def _legs(sc: Scenario) -> list[tuple[tuple[float, ...], tuple[float, ...]]]:
    return [(ep.task.start_m, ep.task.goal_m) for ep in sc.episodes]


def test_the_same_file_draws_the_same_legs_and_more_legs_keep_the_first(tmp_path: Path) -> None:
    first = _load(tmp_path, SUBURB)
    assert _legs(first) == _legs(_load(tmp_path, SUBURB, "again.yaml"))
    more = copy.deepcopy(SUBURB)
    more["episodes"]["random"] = 9
    assert _legs(_load(tmp_path, more))[:6] == _legs(first)  # leg i comes from its own stream
    other = copy.deepcopy(SUBURB)
    other["episodes"]["seed"] = 5  # the seed of the draws, else the scenario's first seed
    assert _legs(_load(tmp_path, other)) != _legs(first)
    assert [ep.index for ep in first.episodes] == list(range(6))


def test_drawn_legs_are_valid_and_load_as_the_same_explicit_episodes(tmp_path: Path) -> None:
    sc = _load(tmp_path, SUBURB)
    for start, goal in _legs(sc):
        assert 120.0 <= math.dist(start, goal) <= 250.0
        assert 8.0 <= start[2] <= 25.0 and 8.0 <= goal[2] <= 25.0
        assert all(v == round(v, 1) for v in (*start, *goal))  # 0.1 m, as a file would write them
    points = np.array([p for leg in _legs(sc) for p in leg])
    assert (sc.city.clearance(points, QUAD_RADIUS_M).distance_m >= 2.0).all()  # the default clearance_m
    blocked = [not sc.city.segment_free(a, b, QUAD_RADIUS_M) for a, b in _legs(sc)]
    assert all(blocked)  # prefer_blocked: the suburb has blocked lines of this length everywhere
    explicit = copy.deepcopy(SUBURB)
    explicit["episodes"] = [{"start": list(a), "goal": list(b)} for a, b in _legs(sc)]
    assert [ep.task for ep in _load(tmp_path, explicit, "explicit.yaml").episodes] == [ep.task for ep in sc.episodes]


def test_defaults_keep_legs_inside_the_flight_volume_and_clear_of_buildings(tmp_path: Path) -> None:
    sc = _load(tmp_path, _box(random=12, prefer_blocked=False))
    assert len(sc.episodes) == 12
    points = np.array([p for leg in _legs(sc) for p in leg])
    assert sc.city.in_bounds(points, QUAD_RADIUS_M).all()
    assert (points[:, 2] >= QUAD_RADIUS_M + 2.0).all() and (points[:, 2] <= 50.0 - QUAD_RADIUS_M - 2.0).all()
    assert (sc.city.clearance(points, QUAD_RADIUS_M).distance_m >= 2.0).all()
    assert all(math.dist(a, b) > 3.0 for a, b in _legs(sc))  # beyond the goal radius


def test_no_fly_zones_and_unmapped_buildings_are_avoided_and_the_prior_map_is_clear(tmp_path: Path) -> None:
    data = _box(random=10, clearance_m=1.0)
    data["map"]["no_fly"] = [{"center": [20.0, 80.0], "size": [30.0, 30.0], "z_range": [0.0, 50.0]}]
    data["unmapped"] = [{"center": [80.0, 20.0], "size": [20.0, 20.0], "height": 40.0}]
    data["map_error"] = {"preset": "wrong", "cranes": 0}
    sc = _load(tmp_path, data)
    points = np.array([p for leg in _legs(sc) for p in leg])
    assert not sc.city.in_no_fly(points, QUAD_RADIUS_M).any()
    assert (sc.city.clearance(points, QUAD_RADIUS_M).distance_m >= 1.0).all()  # the truth: unmapped included
    assert sc.unmapped_ids  # the prior differs, and every start and goal is clear of it (checked by the loader)
    again = with_levels(sc, map_error="outdated")  # checked again from the mapping: the same legs
    assert _legs(again) == _legs(sc)


@pytest.mark.parametrize(("episodes", "key", "words"), [
    ({"random": 3, "lenght_m": 5}, "episodes.lenght_m", "unknown key (allowed: random, seed, min_length_m"),
    ({"start": [1, 2, 3], "goal": [4, 5, 6]}, "episodes", "or a mapping {random: N, ...}"),
    ({"random": 0}, "episodes.random", f"an integer in [1, {MAX_RANDOM_LEGS}], got 0"),
    ({"random": True}, "episodes.random", "got True"),
    ({"random": 2, "seed": -1}, "episodes.seed", "got -1"),
    ({"random": 2, "min_length_m": 60, "max_length_m": 40}, "episodes.max_length_m",
     "40 m is shorter than min_length_m 60 m"),
    ({"random": 2, "min_length_m": 2.0}, "episodes.min_length_m", "within the goal radius 3 m"),
    ({"random": 2, "max_height_m": 60}, "episodes.max_height_m", "m above the ground"),
    ({"random": 2, "min_height_m": 20, "max_height_m": 10}, "episodes.max_height_m", "below min_height_m 20 m"),
    ({"random": 2, "clearance_m": -1}, "episodes.clearance_m", "clearance_m=-1.0"),
    ({"random": 2, "margin_m": 60}, "episodes.margin_m", "leaves no room"),
    ({"random": 2, "prefer_blocked": "yes"}, "episodes.prefer_blocked", "true or false"),
    ({"random": 2, "min_length_m": 500}, "episodes.min_length_m", "longer than the flyable volume's diagonal"),
])
def test_bad_requests_name_the_file_key_and_value(tmp_path: Path, episodes: dict, key: str, words: str) -> None:
    data = copy.deepcopy(BASE)
    data["episodes"] = episodes
    with pytest.raises(ConfigError) as err:
        _load(tmp_path, data)
    assert err.value.source == str(tmp_path / "rnd.yaml") and err.value.key == key, str(err.value)
    assert words in err.value.reason, str(err.value)


def test_an_impossible_request_is_refused_after_bounded_draws(tmp_path: Path) -> None:
    # 130 m legs fit the box only corner to corner, where no end is 40 m from the building and the sides
    with pytest.raises(ConfigError, match=r"episodes: no valid leg 0 of random: 4 in \d+ draws from seed 0") as err:
        _load(tmp_path, _box(min_length_m=130.0, clearance_m=5.0, margin_m=2.0))
    assert "widen the lengths or heights" in err.value.reason


def test_a_drawn_leg_failing_a_later_check_is_named_as_drawn(tmp_path: Path) -> None:
    """Valid points, yet the default timeout of a 17.5 km leg exceeds an hour: the error names the drawn leg."""
    data = {"name": "long", "map": {"buildings": []}, "vehicle": "small_quad",
            "bounds": {"min": [0.0, 0.0, 0.0], "max": [20000.0, 100.0, 50.0]},
            "episodes": {"random": 1, "min_length_m": 17500.0, "max_length_m": 19000.0}}
    with pytest.raises(ConfigError) as err:
        scenario_from_dict(data, "long.yaml", tmp_path)
    assert err.value.key == "episodes" and err.value.reason.startswith("drawn leg 0: the default timeout")


def test_the_legs_are_the_benchmarks_draws() -> None:
    """`draw_leg` with a benchmark leg's stream and ranges draws the benchmark's leg (`benchmark.draw_leg`), so the
    benchmark can draw through it with its published versions unchanged."""
    vb = benchmark.DESIGN.vehicles[0]
    tasks = task_for(vb.vehicle).tasks
    radius = load_vehicle(vb.vehicle).collision_radius_m
    seed = vb.first_seed + 1
    city = generate_city(benchmark.city_params(task_for(vb.vehicle).cities, seed, 1), seed)
    for j in range(4):
        rng = np.random.Generator(np.random.PCG64([seed, benchmark._STREAM_LEG, j]))  # the benchmark's leg stream
        ranges = LegRanges(vb.leg_bins_m[j % len(vb.leg_bins_m)], vb.altitude_m, tasks.min_clearance_m,
                           tasks.bounds_margin_m)
        assert draw_leg(city, rng, ranges, radius, benchmark.MAX_LEG_DRAWS) == benchmark.draw_leg(
            city, tasks, vb, radius, seed, j)
