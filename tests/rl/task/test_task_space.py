"""The space of a task: cities from a mixture of distributions (`CityMixture`: a component per city
seed, by the stated weights, read back from config.json, bad values named), the envelope tasks per vehicle (the
small quad's space unchanged, the UAM's in two city scales with goals near the flight volume's side, observing
it) and the start/goal margin from that side."""
from __future__ import annotations

import json
from collections import Counter
from dataclasses import asdict, replace

import numpy as np
import pytest

from rl.task.cities import CityDistribution, CityMixture, cities_from_dict
from rl.task.config import NavConfig
from rl.task.vehicles import ENVELOPE_AIR, SHIPPED_SCALE_CITIES, UAM_DISTRICTS, UAM_TASK, task_for
from uam_fdm.city.buildings import BuildingMap

SMALL = CityDistribution(extent_m=(200.0, 260.0))
MIXTURE = CityMixture((CityDistribution(), SMALL), (0.25, 0.75))


def test_a_city_seed_names_its_component_and_its_city_on_every_call() -> None:
    seeds = range(40)
    first = [MIXTURE.component(s) for s in seeds]
    assert first == [MIXTURE.component(s) for s in seeds] and set(first) == {0, 1}
    again = CityMixture((CityDistribution(), SMALL), (0.25, 0.75))  # a new object: the same draws
    assert [again.component(s) for s in seeds] == first
    for s in (0, 1, 2, 3):
        part = MIXTURE.components[first[s]]
        assert MIXTURE.distribution(s) is part and MIXTURE.params(s) == part.params(s)
        assert MIXTURE.city(s).buildings == part.city(s).buildings and MIXTURE.city(s).name == f"gen-{s}"
    assert CityDistribution().distribution(7) == CityDistribution()


@pytest.mark.parametrize("weights", [(0.25, 0.75), (0.5, 0.5), (0.9, 0.1)])
def test_the_components_take_their_stated_shares_of_the_cities(weights: tuple[float, float]) -> None:
    n = 4000
    share = Counter(CityMixture(MIXTURE.components, weights).component(s) for s in range(n))[1] / n
    assert abs(share - weights[1]) < 4.0 * np.sqrt(weights[0] * weights[1] / n)  # within 4 sigma


def test_a_mixture_survives_its_config_file_and_the_default_task_writes_as_before() -> None:
    nav = NavConfig(cities=MIXTURE)
    again = NavConfig.from_dict(json.loads(json.dumps(nav.to_dict())))
    assert again == nav and isinstance(again.cities, CityMixture)
    assert again.cities.components[1].extent_m == (200.0, 260.0)  # tuples again, as written
    # one distribution is still written as it always was (policies trained before the mixture read unchanged)
    assert set(NavConfig().to_dict()["cities"]) == set(asdict(CityDistribution()))
    envelope = task_for("uam_multicopter", envelope=True)
    assert NavConfig.from_dict(json.loads(json.dumps(envelope.to_dict()))) == envelope


@pytest.mark.parametrize("change, message", [
    ({"weights": [0.5, 0.6]}, r"cities.weights must sum to 1, got \[0.5, 0.6\]"),
    ({"weights": [1.0]}, r"cities.weights must be 2 positive numbers"),
    ({"weights": [1.5, -0.5]}, r"cities.weights must be 2 positive numbers"),
    ({"weights": "0.5"}, r"cities.weights must be a list of numbers"),
    ({"components": []}, r"cities.components must be one or more city distributions"),
    ({"shares": [1.0]}, r"unknown cities settings \['shares'\]"),
])
def test_bad_mixtures_are_named(change: dict, message: str) -> None:
    d = NavConfig(cities=MIXTURE).to_dict()
    d["cities"] = {**d["cities"], **change}
    with pytest.raises(ValueError, match=message):
        NavConfig.from_dict(d)


@pytest.mark.parametrize("key, value, message", [
    ("street_width_m", [30.0, 15.0], r"cities.components\[1\].street_width_m must be a range \[low, high\] with "
                                     r"low <= high in \(0, inf\), got \(30.0, 15.0\)"),
    ("density", [0.5, 1.5], r"cities.components\[1\].density must be a range .* in \[0, 1\]"),
    ("ceiling_m", 0.0, r"cities.components\[1\].ceiling_m must be a number in \(0, inf\), got 0.0"),
    ("lots_per_block", [0, 2], r"cities.components\[1\].lots_per_block must be a range \[low, high\] of integers"),
    ("extent_m", 400.0, r"cities.components\[1\].extent_m must be a range"),
    ("wings", 2, r"unknown cities.components\[1\] settings \['wings'\]"),
])
def test_bad_city_settings_are_named_with_their_key(key: str, value: object, message: str) -> None:
    d = NavConfig(cities=MIXTURE).to_dict()
    d["cities"]["components"][1][key] = value
    with pytest.raises(ValueError, match=message):
        NavConfig.from_dict(d)
    one = NavConfig().to_dict()
    one["cities"][key] = value
    with pytest.raises(ValueError, match=message.replace(r"cities.components\[1\]", "cities")):
        NavConfig.from_dict(one)
    with pytest.raises(ValueError, match=r"cities must be a mapping"):
        cities_from_dict([1, 2])


def test_the_envelope_of_the_small_quad_keeps_its_space_and_the_uams_widens_it() -> None:
    quad = task_for("small_quad", envelope=True)
    assert quad == replace(NavConfig(), air=ENVELOPE_AIR["small_quad"])  # a policy is being trained on it
    uam = task_for("uam_multicopter", envelope=True)
    assert uam.air == ENVELOPE_AIR["uam_multicopter"]
    assert isinstance(uam.cities, CityMixture) and uam.cities.components == (UAM_DISTRICTS, SHIPPED_SCALE_CITIES)
    assert uam.cities.weights == (0.5, 0.5)
    assert uam.observe.geofence and not uam.observe.air and uam.observe.history == 0
    assert uam.tasks.bounds_margin_m == 15.0 < UAM_TASK.tasks.bounds_margin_m
    assert uam.tasks.distance_m[0] <= 265.0 and uam.tasks.min_clearance_m <= 9.0  # the full set's shortest, nearest
    # the rest of the task is the shipped one's (scales, rates, reward, senses)
    assert replace(uam, air=UAM_TASK.air, cities=UAM_TASK.cities, tasks=UAM_TASK.tasks,
                   observe=UAM_TASK.observe) == UAM_TASK


def _edge_m(city: BuildingMap, p: tuple[float, float, float]) -> float:
    """Horizontal distance [m] from p to the nearest side of the city's flight volume."""
    lo, hi = city.bounds_min_m, city.bounds_max_m
    return float(min(p[0] - lo[0], hi[0] - p[0], p[1] - lo[1], hi[1] - p[1]))


def test_the_uam_envelope_draws_starts_and_goals_down_to_its_margin_from_the_side() -> None:
    """Starts and goals lie no nearer the side than the margin (15 m), and some of them near it: the full set's
    canyon-uam flies to 16.8 m from the side; the shipped UAM task kept 80 m."""
    nav = task_for("uam_multicopter", envelope=True)
    rng = np.random.Generator(np.random.PCG64(5))
    edges, clear, lengths = [], [], []
    for seed in range(6):  # cities of both components
        city = nav.cities.city(seed)
        for _ in range(60):
            t = nav.tasks.sample(city, rng, 6.0, 30.5, max_vertical_speed_m_s=2.5)
            edges += [_edge_m(city, t.start_m), _edge_m(city, t.goal_m)]
            clear += [city.clearance_one(*t.start_m, 6.0), city.clearance_one(*t.goal_m, 6.0)]
            lengths.append(float(np.linalg.norm(np.subtract(t.goal_m, t.start_m))))
    assert {nav.cities.component(s) for s in range(6)} == {0, 1}
    edges_a = np.array(edges)
    assert edges_a.min() >= 15.0 and np.mean(edges_a < 30.0) > 0.02
    assert min(clear) >= 8.0 and 250.0 <= min(lengths) and max(lengths) <= 1500.0
    shipped = UAM_TASK.tasks.sample(nav.cities.city(1), rng, 6.0, 30.5, max_vertical_speed_m_s=2.5)
    assert min(_edge_m(nav.cities.city(1), p) for p in (shipped.start_m, shipped.goal_m)) >= 80.0
