"""Episodes across map-error levels: exact is unchanged, the route follows the prior, the truth collides and is
sensed, draws are deterministic, batched == single."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from rl.env.world import NavBatch, NavWorld, SlotAir
from rl.sensing.route import RouteBank
from rl.sensing.senses import route_for
from rl.sensing.sensor import BoxSensor
from rl.sensing.truth import MapErrorBank
from rl.task.air import AirDistribution
from rl.task.config import NavConfig
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.pilot import Task

SMALL = NavConfig(city_pool_size=4, wind_pool_size=2, wind_series_s=150.0)
CALM = AirDistribution(turbulence=("none",), steady_wind_max_m_s=0.0)
MIXED = replace(SMALL, map_error=("exact", "outdated", "wrong"), map_error_draws=2)


@pytest.fixture(scope="module")
def plain() -> NavWorld:
    return NavWorld(SMALL)


@pytest.fixture(scope="module")
def mixed(plain) -> NavWorld:
    return NavWorld(MIXED, dynamics=plain.dynamics, wind_from=plain)


def _rollout(world: NavWorld, n: int, seed: int, steps: int) -> list[np.ndarray]:
    """Observations, rewards and states of a seeded batch under seeded random actions, resets included."""
    b = NavBatch(world, n)
    b.seed(range(seed, seed + n))
    b.reset_slots(range(n))
    rows = [b.observations.copy()]
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        obs, r, term, trunc, _ = b.step(rng.uniform(-1, 1, (n, 3)))
        rows += [obs, r, b.x.copy(), b.geometry.copy()]
        done = np.flatnonzero(term | trunc)
        if len(done):
            b.reset_slots(done)
            rows.append(b.observations.copy())
    return rows


def test_exact_setting_observes_as_without_it(plain):
    """("exact",) draws nothing whatever the banked draws: the same observations, rewards and states, bit for bit."""
    exact = NavWorld(replace(SMALL, map_error=("exact",), map_error_draws=7), dynamics=plain.dynamics,
                     wind_from=plain)
    assert exact.truth is None and not exact.maps.added
    a, b = _rollout(plain, 4, 10, 120), _rollout(exact, 4, 10, 120)
    assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))


def test_draws_are_deterministic_and_cover_the_levels(mixed, plain):
    again = NavWorld(MIXED, dynamics=plain.dynamics, wind_from=plain)
    a, b = _rollout(mixed, 8, 3, 60), _rollout(again, 8, 3, 60)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    batch = NavBatch(mixed, 16)
    batch.seed(range(16))
    batch.reset_slots(range(16))
    assert set(batch.map_level.tolist()) == {0, 1, 2}
    assert np.any(batch.geometry >= len(mixed.cities))  # some slots fly a truth with cranes and masts
    fresh = MapErrorBank(mixed.cities, MIXED.city_seeds(), MIXED.map_error, 2)
    for i in range(16):
        d = fresh.draw(int(batch.city[i]), int(batch.map_level[i]), int(batch.map_draw[i]))
        assert d.prior.buildings == mixed.maps.draw(int(batch.city[i]), int(batch.map_level[i]),
                                                     int(batch.map_draw[i])).prior.buildings
        task = batch.task(i)  # free in both the truth and the prior
        for m in (d.truth, d.prior):
            for p in (task.start_m, task.goal_m):
                assert m.clearance_one(*p, mixed.vehicle.collision_radius_m) >= MIXED.tasks.min_clearance_m


def test_batched_equals_single_across_levels(mixed):
    n, seed = 6, 40
    batched = _rollout(mixed, n, seed, 50)
    b = NavBatch(mixed, n)
    b.seed(range(seed, seed + n))
    b.reset_slots(range(n))
    singles = [NavBatch(mixed, 1) for _ in range(n)]
    for i, s in enumerate(singles):
        s.seed([seed + i])
        s.reset_slots([0])
    assert np.array_equal(b.geometry, [s.geometry[0] for s in singles])
    np.testing.assert_array_equal(b.observations, np.concatenate([s.observations for s in singles]))
    rng = np.random.default_rng(seed)
    for _ in range(50):
        act = rng.uniform(-1, 1, (n, 3))
        obs, r, term, trunc, _ = b.step(act)
        for i, s in enumerate(singles):
            o1, r1, t1, u1, _ = s.step(act[i:i + 1])
            assert np.array_equal(o1[0], obs[i]) and r1[0] == r[i] and t1[0] == term[i] and u1[0] == trunc[i]
            if t1[0] or u1[0]:
                s.reset_slots([0])
        done = np.flatnonzero(term | trunc)
        if len(done):
            b.reset_slots(done)
    assert len(batched) > 50


def _crossing(world: NavWorld):
    """A wrong-level draw, one of its buildings missing from the prior and a level leg straight through it whose
    line is clear of every other building of the prior (start and goal free in both maps)."""
    r_m = world.vehicle.collision_radius_m
    margin = world.config.route.margin_m + world.config.route.cell_m
    for ci, city in enumerate(world.cities):
        for d in range(world.maps.draws_of(0)):
            draw = world.maps.draw(ci, 0, d)
            missing = [b for b in city.buildings if b.id in world.maps.result(ci, 0, d).missing_ids]
            for b in sorted(missing, key=lambda b: -b.height_m):
                z = 8.0
                if b.height_m < z + 5.0:
                    continue
                half = 0.5 * math.hypot(*b.size_xy_m)
                for k in range(16):
                    u = np.array([math.cos(k * math.pi / 8), math.sin(k * math.pi / 8)])
                    c = np.asarray(b.center_xy_m)
                    start, goal = c - (half + 9.0) * u, c + (half + 9.0) * u
                    line = [np.append(start + t * (goal - start), z) for t in np.linspace(0, 1, 60)]
                    if not all(np.all(p[:2] > np.asarray(city.bounds_min_m[:2]) + 16)
                               and np.all(p[:2] < np.asarray(city.bounds_max_m[:2]) - 16) for p in (line[0], line[-1])):
                        continue
                    if min(draw.prior.clearance_one(*p, r_m) for p in line) < margin:
                        continue
                    if min(draw.truth.clearance_one(*p, r_m) for p in (line[0], line[-1])) < margin:
                        continue
                    return ci, draw, Task((*start, z), (*goal, z), 3.0, 60.0)
    pytest.skip("no crossing found")  # pragma: no cover (the pool below has one)


def test_route_follows_the_prior_and_the_truth_collides(plain):
    """A building the prior misses: the route observed runs straight through it, the vehicle senses it and crashes
    into it; the reward's progress is measured around it (the truth's route field)."""
    world = NavWorld(replace(SMALL, air=CALM, map_error=("wrong",), map_error_draws=4, city_pool_size=12),
                     dynamics=plain.dynamics)
    ci, draw, task = _crossing(world)
    b = NavBatch(world, 1)
    b.place([(0, ci, task, SlotAir((0.0, 0.0, 0.0), 0, 0, 0, 0))], [draw])
    r_m = world.vehicle.collision_radius_m
    prior_bank, truth_bank = RouteBank(1, world.route_cells), RouteBank(1, world.route_cells)
    prior_bank.set(0, route_for(draw.prior, task, r_m, world.config.route))
    truth_bank.set(0, route_for(draw.truth, task, r_m, world.config.route))
    start = np.array([task.start_m])
    straight = math.dist(task.start_m, task.goal_m)
    observed = b.memory.route_history_m[0, -1]  # the route distance the first observation holds
    assert observed == prior_bank.potential(start)[0]  # the pilot's route is the prior's
    assert b.route_m[0] == truth_bank.potential(start)[0]  # the reward's, the truth's
    assert observed < 1.05 * straight + 1.5 < b.route_m[0]  # straight through; the truth's detours
    # the building is sensed: the ray straight ahead (towards it and the goal) ends short of the goal
    assert b.observations[0].shape == (world.obs_size,)
    info: dict = {}
    for _ in range(300):
        _, _, term, trunc, infos = b.step(np.array([[1.0, 0.0, 0.0]]))
        info = infos[0]
        if term[0] or trunc[0]:
            break
    assert info["outcome"] == "collision"
    assert math.dist(b.x[0, 0:3], task.start_m) < straight / 2  # stopped at the building, before the middle


def test_the_clearance_sensor_is_exact_for_a_raised_box():
    """A crane's jib (a box lifted off the ground): the sensor's clearance and nearest point agree with the map's
    exact distance, above, below and beside it."""
    mast = Building(7, (50.0, 50.0), (2.0, 2.0), 50.0, 0.3)
    jib = Building(7, (65.0, 58.0), (40.0, 1.8), 50.0, 0.5, base_m=48.2)
    city = BuildingMap((mast, jib), (0.0, 0.0, 0.0), (120.0, 120.0, 100.0))
    sensor = BoxSensor([city], k=1, range_m=30.0, radius_m=0.4)
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(40, 90, 300), rng.uniform(40, 80, 300), rng.uniform(1, 70, 300)])
    ref = city.clearance(pts, 0.4, backend="fcl").distance_m
    got = sensor.query(pts, np.zeros(len(pts), dtype=np.int64))
    near = ref < 30.0
    np.testing.assert_allclose(got.clearance_m[near], ref[near], atol=1e-9)
    np.testing.assert_allclose(sensor.clearance(pts, np.zeros(len(pts), dtype=np.int64))[near], ref[near], atol=1e-9)
    under = np.array([[80.0, 66.0, 20.0]])  # under the jib's far end: the ground is nearer, not a column
    assert sensor.query(under, np.zeros(1, dtype=np.int64)).clearance_m[0] == 20.0 - 0.4
    one = sensor.query(pts[:1], np.zeros(1, dtype=np.int64))
    np.testing.assert_allclose(one.nearest_m[0], got.nearest_m[0], atol=1e-12)


def test_perfect_sensing_can_be_kept_to_exact_maps_with_every_draw_as_before(mixed) -> None:
    """With `exact_maps_at_perfect` an episode drawing `perfect` flies its city's exact map; every draw is made as
    without it, so the tasks, air and sensing are the same and the sensed episodes keep their maps."""
    cfg = replace(MIXED, sensing=("perfect", "nominal"))
    plain_world = NavWorld(cfg, dynamics=mixed.dynamics, wind_from=mixed)
    kept_world = NavWorld(replace(cfg, exact_maps_at_perfect=True), dynamics=mixed.dynamics, wind_from=mixed)
    n = 24
    plain, kept = NavBatch(plain_world, n), NavBatch(kept_world, n)
    for b in (plain, kept):
        b.seed(range(40, 40 + n))
        b.reset_slots(range(n))
    exact = kept_world.maps.levels.index("exact")
    moved = 0
    for i in range(n):
        assert plain.task(i) == kept.task(i) and plain.sensing(i) == kept.sensing(i)
        assert (plain.air[i], plain.sensing_seed[i]) == (kept.air[i], kept.sensing_seed[i])
        if kept.sensing(i) == "perfect":
            assert kept.map_level[i] == exact and kept.priors[i] is kept_world.cities[int(kept.city[i])]
            moved += int(plain.map_level[i] != exact)
        else:
            assert (kept.map_level[i], kept.map_draw[i]) == (plain.map_level[i], plain.map_draw[i])
    assert moved >= 3  # the draw met perfect sensing over a map with error, and the setting took it away
    with pytest.raises(ValueError, match="exact_maps_at_perfect needs true or false and 'exact' among map_error"):
        replace(cfg, map_error=("outdated", "wrong"), exact_maps_at_perfect=True)
