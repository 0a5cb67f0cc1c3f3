"""Every scenario of the `full` set lies inside the envelope its vehicle's learned pilot is trained on
(`rl.task.vehicles.task_for(vehicle, envelope=True)`): its air, its legs (length, heights, clearance,
distance to the flight volume's side, goal radius) and its city's scale (the shipped map's generator parameters
inside one city distribution of the task's).

The small quad's envelope keeps its shipped cities (a policy is being trained on them): they are 260-420 m across,
and the canyon's blocks, fill and heights, the suburb's sparse fill and the tallest roofs lie beyond them too. Those
gaps are pinned here, so that a change on either side shows; the quad's legs, air and street widths are inside."""
from __future__ import annotations

import math

import pytest

from compare.run.trained_air import air_envelope, scenario_outside
from compare.scenarios.scenario import Scenario
from compare.scenarios.sets import resolve_scenarios
from rl.task.cities import CityDistribution, CityMixture
from rl.task.vehicles import task_for
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.city.generator import SHIPPED_MAPS, CityGenConfig

FULL = resolve_scenarios("full")

QUAD_CITY_GAPS = {  # what of the shipped maps lies outside the small quad's (unchanged) cities
    "canyon": ("extent 700 m", "block 150 m", "fill 0.85", "median height 110 m", "roofs to 250 m"),
    "downtown": ("extent 1000 m", "roofs to 204 m"),
    "suburb": ("extent 800 m", "fill 0.4"),
}


def _edge_m(city: BuildingMap, p: tuple[float, float, float]) -> float:
    """Horizontal distance [m] from p to the nearest side of the city's flight volume."""
    lo, hi = city.bounds_min_m, city.bounds_max_m
    return float(min(p[0] - lo[0], hi[0] - p[0], p[1] - lo[1], hi[1] - p[1]))


def _outside(p: CityGenConfig, city: BuildingMap, d: CityDistribution) -> tuple[str, ...]:
    """What of a map made with generator parameters `p` lies outside distribution `d`'s ranges (one phrase each):
    extent, street width, block and lot sizes (per axis), lot occupancy, footprint fill, median height and the
    tallest roof."""
    def within(v: float, r: tuple[float, float]) -> bool:
        return r[0] <= v <= r[1]

    lot_range = (d.block_size_m[0] / d.lots_per_block[1], d.block_size_m[1] / d.lots_per_block[0])
    tallest = max(b.height_m for b in city.buildings)
    checks = [
        *((f"extent {v:g} m", within(v, d.extent_m)) for v in dict.fromkeys(p.extent_m)),
        (f"street {p.street_width_m:g} m", within(p.street_width_m, d.street_width_m)),
        *((f"block {v:g} m", within(v, d.block_size_m)) for v in dict.fromkeys(p.block_size_m)),
        *((f"lot {b / n:g} m", within(b / n, lot_range)) for b, n in dict.fromkeys(zip(p.block_size_m,
                                                                                         p.lots_per_block))),
        (f"density {p.density:g}", within(p.density, d.density)),
        (f"fill {p.fill_range[0]:g}", within(p.fill_range[0], d.fill_low)),
        (f"median height {p.height_median_m:g} m", within(p.height_median_m, d.height_median_m)),
        (f"roofs to {tallest:.0f} m", tallest <= d.height_range_m[1]),
    ]
    return tuple(phrase for phrase, inside in checks if not inside)


def _city_outside(sc: Scenario) -> tuple[str, ...]:
    """What of the scenario's map lies outside the nearest of its task's city distributions (empty: inside one)."""
    nav = task_for(sc.vehicle_name, envelope=True)
    assert sc.city.name in SHIPPED_MAPS, "the full set flies the shipped maps, whose generator parameters are known"
    params = SHIPPED_MAPS[sc.city.name][0]
    parts = nav.cities.components if isinstance(nav.cities, CityMixture) else (nav.cities,)
    return min((_outside(params, sc.city, d) for d in parts), key=len)


@pytest.mark.parametrize("sc", FULL, ids=lambda sc: sc.name)
def test_the_air_of_every_scenario_is_inside_the_envelope(sc: Scenario) -> None:
    nav = task_for(sc.vehicle_name, envelope=True)
    assert scenario_outside(sc, air_envelope(nav.air)) == ()


@pytest.mark.parametrize("sc", FULL, ids=lambda sc: sc.name)
def test_every_leg_of_the_full_set_is_one_the_envelope_draws(sc: Scenario) -> None:
    """Length, heights, clearance beyond the collision sphere and distance to the flight volume's side within
    the envelope's draws (the side: at least its margin, e.g. canyon-uam's goal 16.8 m from it), goal radius."""
    tasks = task_for(sc.vehicle_name, envelope=True).tasks
    radius = sc.vehicle.collision_radius_m
    for ep in sc.episodes:
        a, b = ep.task.start_m, ep.task.goal_m
        assert tasks.distance_m[0] <= math.dist(a, b) <= tasks.distance_m[1], ep
        assert ep.task.goal_radius_m == tasks.goal_radius_m
        for p in (a, b):
            assert tasks.altitude_m[0] <= p[2] <= tasks.altitude_m[1], p
            assert sc.city.clearance_one(*p, radius) >= tasks.min_clearance_m, p
            assert _edge_m(sc.city, p) >= tasks.bounds_margin_m, p


@pytest.mark.parametrize("sc", FULL, ids=lambda sc: sc.name)
def test_every_map_of_the_full_set_is_a_city_the_envelope_draws(sc: Scenario) -> None:
    """The UAM's within one of its two city scales; the small quad's with the gaps of its unchanged cities."""
    expected = QUAD_CITY_GAPS[sc.city.name] if sc.vehicle_name == "small_quad" else ()
    assert _city_outside(sc) == expected
