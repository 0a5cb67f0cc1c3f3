"""Geodesic route fields (rl/sensing/route.py): exactness, no local minima, detours, flying over, the bank."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rl.sensing.route import (
    LeveledRoute,
    RouteBank,
    RouteConfig,
    RouteField,
    flight_levels,
    grid_shape,
    leveled_route,
    max_levels,
    route_field,
)
from rl.task.cities import CityDistribution
from uam_fdm.city.buildings import Building, BuildingMap, Prism

RADIUS = 0.5
ALT = 20.0
CFG = RouteConfig()
REACH = RADIUS + CFG.margin_m


def _empty_city(w: float = 300.0, d: float = 260.0) -> BuildingMap:
    return BuildingMap([], (0.0, 0.0, 0.0), (w, d, 120.0), name="empty")


def _wall_city(height_m: float = 60.0, size_xy_m=(200.0, 20.0)) -> BuildingMap:
    """One wall centred at (150, 150), x along east, across a 300 m x 300 m city."""
    return BuildingMap([Building(1, (150.0, 150.0), size_xy_m, height_m)], (0, 0, 0), (300, 300, 120),
                       name="wall")


def _via_west_end(start: np.ndarray, goal: np.ndarray, size_xy_m) -> float:
    """Closed form: straight to the inflated wall's south-west corner, up its end, straight to the goal."""
    x0 = 150.0 - 0.5 * size_xy_m[0] - REACH
    y0, y1 = 150.0 - 0.5 * size_xy_m[1] - REACH, 150.0 + 0.5 * size_xy_m[1] + REACH
    a, b = np.array([x0, y0]), np.array([x0, y1])
    return float(np.linalg.norm(a - start[:2]) + (y1 - y0) + np.linalg.norm(goal[:2] - b))


def _bank_of(*fields: RouteField) -> RouteBank:
    shape = tuple(max(f.shape[k] for f in fields) for k in (0, 1))
    bank = RouteBank(len(fields), shape)
    for i, f in enumerate(fields):
        bank.set(i, f)
    return bank


def _cell_centres(f: RouteField) -> tuple[np.ndarray, np.ndarray]:
    ny, nx = f.shape
    return f.origin_m[0] + f.cell_m * np.arange(nx), f.origin_m[1] + f.cell_m * np.arange(ny)


def _free_points(city: BuildingMap, rng: np.random.Generator, n: int, inset_m: float = 5.0) -> np.ndarray:
    """n points at the flight level outside every footprint inflated by radius + margin."""
    lo, hi = np.asarray(city.bounds_min_m[:2]) + inset_m, np.asarray(city.bounds_max_m[:2]) - inset_m
    out = np.empty((0, 3))
    while len(out) < n:
        p = np.column_stack([rng.uniform(lo[0], hi[0], 4 * n), rng.uniform(lo[1], hi[1], 4 * n),
                             np.full(4 * n, ALT)])
        out = np.vstack([out, p[city.clearance(p, RADIUS).distance_m > CFG.margin_m]])
    return out[:n]


def _descend(bank: RouteBank, start: np.ndarray, goal: np.ndarray, max_steps: np.ndarray, cities=None,
             slots_city=None):
    """Step 1 m along `direction` until within 4 m of the goal or out of steps.

    Returns the end points, the steps taken and (with `cities`, point i in cities[slots_city[i]]) the
    smallest clearance [m] of the vehicle sphere along the way.
    """
    p = start.copy()
    steps = np.zeros(len(p), dtype=int)
    min_clear = np.full(len(p), np.inf)
    for _ in range(int(max_steps.max())):
        active = (np.hypot(*(p[:, :2] - goal[:, :2]).T) > 4.0) & (steps < max_steps)
        if not active.any():
            break
        p[active, :2] += bank.direction(p)[active]
        steps += active
        if cities is not None:
            for ci, city in enumerate(cities):
                sel = slots_city == ci
                min_clear[sel] = np.minimum(min_clear[sel], city.clearance(p[sel], RADIUS).distance_m)
    return p, steps, min_clear


def test_no_buildings_distance_is_euclidean():
    city = _empty_city()
    for goal in [(150.0, 130.0, 10.0), (3.1, 257.9, 0.0), (211.37, 64.02, 40.0)]:
        f = route_field(city, goal, ALT, RADIUS)
        xs, ys = _cell_centres(f)
        d = np.hypot(xs[None, :] - goal[0], ys[:, None] - goal[1])
        g = f.distance_m.astype(float)
        assert f.distance_m.dtype == np.float32 and not f.blocked.any()
        assert np.all(np.abs(g - d) <= 0.02 * d + f.cell_m), np.abs(g - d).max()
        near = d <= 1.5 * f.cell_m  # the source circle: exactly Euclidean
        assert np.allclose(g[near], d[near], atol=1e-4)
        # Between cell centres too, through the bank.
        bank = _bank_of(f)
        rng = np.random.default_rng(0)
        pts = np.column_stack([rng.uniform(0, 300, 200), rng.uniform(0, 260, 200), np.full(200, 5.0)])
        e = np.hypot(pts[:, 0] - goal[0], pts[:, 1] - goal[1])
        got = bank.distance(pts, slots=np.zeros(200, dtype=int))
        assert np.all(np.abs(got - e) <= 0.02 * e + f.cell_m)
        pot = bank.potential(pts, slots=np.zeros(200, dtype=int))
        assert np.allclose(pot, np.hypot(got, pts[:, 2] - goal[2]))


def test_no_local_minima_on_the_grid():
    """Every cell outside the goal circle has a 4-neighbour with a smaller G (blocked cells included)."""
    rng = np.random.default_rng(5)
    for seed in (0, 4, 7):
        city = CityDistribution().city(seed)
        goal = _free_points(city, rng, 1)[0]
        f = route_field(city, goal, ALT, RADIUS)
        g = np.pad(f.distance_m.astype(float), 1, constant_values=np.inf)
        lower = np.minimum.reduce([g[:-2, 1:-1], g[2:, 1:-1], g[1:-1, :-2], g[1:-1, 2:]])
        xs, ys = _cell_centres(f)
        outside = np.hypot(xs[None, :] - goal[0], ys[:, None] - goal[1]) > 1.5 * f.cell_m
        assert np.all(lower[outside] < f.distance_m[outside]), seed
        assert f.blocked.any() and not f.blocked.all()


def test_descent_reaches_the_goal_from_free_points():
    """256 descents (4 cities x 64 start/goal pairs, all in one bank): no local minima, no collision."""
    rng = np.random.default_rng(2024)
    dist = CityDistribution()
    cities, fields, starts, goals = [], [], [], []
    for seed in (1, 3, 5, 11):
        city = dist.city(seed)
        cities.append(city)
        pts = _free_points(city, rng, 128)
        for s, g in zip(pts[:64], pts[64:]):
            fields.append(route_field(city, g, ALT, RADIUS))
            starts.append(s)
            goals.append(g)
    bank = _bank_of(*fields)
    start, goal = np.array(starts), np.array(goals)
    g0 = bank.distance(start)
    assert np.all(g0 >= np.hypot(*(start[:, :2] - goal[:, :2]).T) - CFG.cell_m)  # never shorter than straight
    end, steps, clear = _descend(bank, start, goal, np.ceil(3 * g0).astype(int) + 1, cities,
                                 np.repeat(np.arange(4), 64))
    reached = np.hypot(*(end[:, :2] - goal[:, :2]).T) <= 4.0
    assert reached.all(), f"{(~reached).sum()} descents stalled, e.g. from {start[~reached][:3]}"
    assert np.all(steps <= 3 * g0)
    # Never into a building: the vehicle sphere at the flight level keeps a clearance >= 0 (stricter than
    # "at most one cell into the inflated footprint", which the margin and cell size would allow).
    assert np.all(clear >= 0.0), clear.min()
    assert np.all(clear >= CFG.margin_m - CFG.cell_m)


@pytest.mark.parametrize("size_xy_m, start, goal, cell_m", [
    ((200.0, 20.0), (140.0, 100.0), (140.0, 200.0), 4.0),
    ((220.0, 6.0), (80.0, 120.0), (80.0, 180.0), 2.0),  # a short detour needs a finer grid for 5 %
])
def test_detour_around_a_wall(size_xy_m, start, goal, cell_m):
    city = _wall_city(size_xy_m=size_xy_m)
    start, goal = np.array([*start, ALT]), np.array([*goal, ALT])
    f = route_field(city, goal, ALT, RADIUS, RouteConfig(cell_m=cell_m))
    bank = _bank_of(f)
    shortest = _via_west_end(start, goal, size_xy_m)
    g = float(bank.distance(start[None])[0])
    euclid = float(np.linalg.norm(goal[:2] - start[:2]))
    assert abs(g - shortest) <= 0.05 * shortest, (g, shortest)
    assert euclid < 0.6 * g
    # The route's way leads west, round the wall's near end, not north into it, and reaches the goal.
    d = bank.direction(start[None])[0]
    assert d[0] < -0.5
    end, _, clear = _descend(bank, start[None], goal[None], np.array([int(3 * g)]), [city],
                             np.zeros(1, dtype=int))
    assert np.hypot(*(end[0, :2] - goal[:2])) <= 4.0 and clear[0] >= 0.0


def test_low_buildings_are_flown_over():
    start, goal = np.array([[140.0, 100.0, ALT]]), (140.0, 200.0, ALT)
    euclid = 100.0
    low = _bank_of(route_field(_wall_city(height_m=10.0), goal, ALT, RADIUS))
    assert abs(float(low.distance(start)[0]) - euclid) <= 0.02 * euclid + CFG.cell_m
    # The threshold is height > ref_altitude - radius - margin.
    limit = ALT - REACH
    over = route_field(_wall_city(height_m=limit - 0.1), goal, ALT, RADIUS)
    under = route_field(_wall_city(height_m=limit + 0.1), goal, ALT, RADIUS)
    assert not over.blocked.any() and under.blocked.any()
    assert float(_bank_of(under).distance(start)[0]) > 2.0 * euclid
    # Flying lower makes the same low wall block.
    assert route_field(_wall_city(height_m=10.0), goal, 5.0, RADIUS).blocked.any()


def test_blocked_mask_matches_exact_geometry():
    """The vectorised rasterisation against BuildingMap.clearance at every cell centre (rotated boxes)."""
    rng = np.random.default_rng(9)
    boxes = [Building(i, tuple(rng.uniform(40, 260, 2)), tuple(rng.uniform(3, 40, 2)),
                      float(rng.uniform(10, 80)), float(rng.uniform(-math.pi, math.pi))) for i in range(40)]
    city = BuildingMap(boxes, (0, 0, 0), (300, 290, 120))
    f = route_field(city, (10.0, 10.0, ALT), 1000.0, RADIUS)  # far above: nothing blocks
    assert not f.blocked.any()
    f = route_field(city, (10.0, 10.0, ALT), 0.0, RADIUS)  # at the ground: everything blocks
    xs, ys = _cell_centres(f)
    # z = 5 m: below every roof (>= 10 m) and farther than the reach from the ground, so the 3-D clearance
    # within the reach is the horizontal distance to the nearest footprint.
    pts = np.column_stack([np.tile(xs, len(ys)), np.repeat(ys, len(xs)), np.full(len(xs) * len(ys), 5.0)])
    clear = city.clearance(pts, 0.0).distance_m.reshape(f.shape)
    exact = clear <= REACH
    ambiguous = np.abs(clear - REACH) < 1e-6
    assert 0.1 < exact.mean() < 0.9
    assert np.array_equal(f.blocked[~ambiguous], exact[~ambiguous])
    # Only buildings above the flight level minus the reach block.
    tall = BuildingMap([b for b in boxes if b.height_m > 40.0 - REACH], (0, 0, 0), (300, 290, 120))
    assert np.array_equal(route_field(city, (10.0, 10.0, ALT), 40.0, RADIUS).blocked,
                          route_field(tall, (10.0, 10.0, ALT), 0.0, RADIUS).blocked)


def test_goal_beside_a_building():
    """A goal inside the margin band (free for the vehicle, blocked on the grid) is still reached."""
    city = _wall_city()
    goal = np.array([150.0, 160.0 + RADIUS + 0.3, ALT])  # 0.3 m of clearance from the wall's north face
    f = route_field(city, goal, ALT, RADIUS)
    bank = RouteBank(3, f.shape)
    for i in range(3):
        bank.set(i, f)
    assert f.clear_radius_m == pytest.approx(0.3)
    assert float(bank.distance(goal[None], slots=[0])[0]) == pytest.approx(0.0, abs=1e-9)
    start = np.array([[150.0, 200.0, ALT], [100.0, 175.0, ALT], [30.0, 100.0, ALT]])
    g0 = bank.distance(start)
    end, steps, clear = _descend(bank, start, np.repeat(goal[None], 3, 0), np.ceil(3 * g0).astype(int) + 1,
                                 [city], np.zeros(3, dtype=int))
    assert np.all(np.hypot(*(end[:, :2] - goal[:2]).T) <= 4.0)
    assert np.all(clear >= 0.0)


def test_goal_inside_a_building_still_gives_a_field():
    """A goal inside a footprint (no valid task, but possible input): its disk is the source, G is finite."""
    city = _wall_city()
    f = route_field(city, (150.0, 150.0, ALT), ALT, RADIUS)
    assert f.clear_radius_m == 0.0 and np.all(np.isfinite(f.distance_m))
    bank = _bank_of(f)
    start = np.array([[150.0, 100.0, ALT]])
    end, _, _ = _descend(bank, start, np.array([[150.0, 150.0, ALT]]), np.array([1000]))
    assert np.hypot(end[0, 0] - 150.0, end[0, 1] - 150.0) <= 4.0


def test_deterministic():
    city = CityDistribution().city(3)
    goal = _free_points(city, np.random.default_rng(1), 1)[0]
    a = route_field(city, goal, ALT, RADIUS)
    b = route_field(city, goal, ALT, RADIUS)
    assert a.distance_m.tobytes() == b.distance_m.tobytes() and np.array_equal(a.blocked, b.blocked)
    assert not a.distance_m.flags.writeable and not a.blocked.flags.writeable
    pts = _free_points(city, np.random.default_rng(0), 8)
    qa, qb = _bank_of(*[a] * 8), _bank_of(*[b] * 8)
    for fn in ("distance", "potential", "direction"):
        assert getattr(qa, fn)(pts).tobytes() == getattr(qb, fn)(pts).tobytes()


def test_outside_queries_clamp_to_the_edge():
    city = CityDistribution().city(2)
    goal = _free_points(city, np.random.default_rng(2), 1)[0]
    bank = _bank_of(route_field(city, goal, ALT, RADIUS))
    hi = np.asarray(city.bounds_max_m)
    inside = np.array([[-0.0, 0.0, 5], [hi[0], 100.0, 5], [100.0, hi[1], 5], [hi[0], hi[1], 5]])
    outward = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    slot0 = np.zeros(4, dtype=int)
    ref = bank.distance(inside, slots=slot0)
    for far in (1e-3, 50.0, 1e4):
        out = inside.copy()
        out[:, :2] += far * outward
        got = bank.distance(out, slots=slot0)
        assert np.all(np.isfinite(got)) and np.all(np.isfinite(bank.direction(out, slots=slot0)))
        assert np.allclose(got, ref, atol=1e-3 if far < 1 else 10.0)  # continuous at the edge, bounded beyond
        assert np.all(np.isfinite(bank.potential(out, slots=slot0)))
    # A NaN point (a vehicle whose state blew up) answers NaN, its neighbours in the batch are unaffected.
    pts = np.array([[np.nan, 10.0, 5.0], [10.0, 10.0, 5.0]])
    got = bank.distance(pts, slots=[0, 0])
    assert np.isnan(got[0]) and got[1] == bank.distance(pts[1:], slots=[0])[0]
    assert np.isnan(bank.direction(pts, slots=[0, 0])[0]).all()


def test_bank_interpolates_each_slot_on_its_own_grid():
    small = BuildingMap([Building(1, (60.0, 60.0), (20.0, 20.0), 50.0, 0.3)], (0, 0, 0), (130, 110, 100))
    big = CityDistribution().city(0)
    fa = route_field(small, (10.0, 100.0, 5.0), ALT, RADIUS)
    fb = route_field(big, (200.0, 30.0, 30.0), ALT, RADIUS, RouteConfig(cell_m=5.0))
    assert fa.shape == grid_shape(small) and fb.shape == grid_shape(big, 5.0)
    bank = RouteBank(3, tuple(max(a, b) for a, b in zip(fa.shape, fb.shape)))
    bank.set(0, fa)
    bank.set(2, fb)
    for slot, f in ((0, fa), (2, fb)):
        xs, ys = _cell_centres(f)
        iy, ix = np.meshgrid(np.arange(f.shape[0]), np.arange(f.shape[1]), indexing="ij")
        pts = np.column_stack([xs[ix.ravel()], ys[iy.ravel()], np.zeros(ix.size)])
        s = np.full(len(pts), slot)
        assert np.allclose(bank.distance(pts, slots=s), f.distance_m.ravel(), rtol=0, atol=1e-4)
        mid = pts[:1] + [[0.5 * f.cell_m, 0.5 * f.cell_m, 0.0]]  # bilinear: the mean of four centres
        corners = float(f.distance_m[:2, :2].astype(float).mean())
        assert bank.distance(mid, slots=[slot])[0] == pytest.approx(corners)
    # All slots in one call: slot 1 was never set (NaN), the others are their own fields.
    pts = np.array([[12.0, 95.0, 5.0], [0.0, 0.0, 0.0], [195.0, 33.0, 30.0]])
    d = bank.distance(pts)
    assert np.isnan(d[1]) and d[0] < 10.0 and d[2] < 10.0
    assert bank.potential(pts)[2] == pytest.approx(d[2], abs=1e-9)
    with pytest.raises(ValueError):
        RouteBank(1, (10, 10)).set(0, fb)
    with pytest.raises(IndexError):
        bank.set(3, fa)
    with pytest.raises(ValueError):
        bank.distance(pts[:2])


def test_direction_is_unit_and_zero_at_the_goal():
    city = _empty_city()
    goal = np.array([123.4, 98.7, 20.0])
    bank = _bank_of(route_field(city, goal, ALT, RADIUS))
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(0, 300, 300), rng.uniform(0, 260, 300), np.full(300, 9.0)])
    slots = np.zeros(300, dtype=int)
    d = bank.direction(pts, slots=slots)
    assert np.allclose(np.hypot(d[:, 0], d[:, 1]), 1.0)
    to_goal = goal[:2] - pts[:, :2]
    cos = np.einsum("ij,ij->i", d, to_goal) / np.hypot(*to_goal.T)
    assert np.all(cos > math.cos(math.radians(6.0))), np.degrees(np.arccos(cos.min()))
    assert np.array_equal(bank.direction(goal[None], slots=[0]), np.zeros((1, 2)))
    near = goal[None] + [[1.0, -0.5, 3.0]]  # within half the clear radius: exactly the straight way
    assert np.allclose(bank.direction(near, slots=[0])[0], [-1.0, 0.5] / np.hypot(1.0, 0.5))
    assert bank.distance(goal[None], slots=[0])[0] == 0.0


def test_invalid_inputs():
    city = _empty_city()
    with pytest.raises(ValueError):
        route_field(city, (-10.0, 5.0, 5.0), ALT, RADIUS)
    with pytest.raises(ValueError):
        route_field(city, (10.0, 5.0), ALT, RADIUS)
    with pytest.raises(ValueError):
        RouteConfig(blocked_speed=0.0)
    with pytest.raises(ValueError):
        RouteConfig(cell_m=-1.0)
    prism_city = BuildingMap([Prism(1, ((10, 10), (30, 10), (20, 30)), 40.0)], (0, 0, 0), (100, 100, 100))
    with pytest.raises(ValueError):
        route_field(prism_city, (50.0, 50.0, 5.0), ALT, RADIUS)


def test_climb_weight_scales_the_height_term_in_both_paths():
    """sqrt(G² + (k Δz)²), the same in the batched and the one-point path; k = 1 is the plain potential."""
    city = _wall_city()
    f = route_field(city, (150.0, 150.0 + 40.0, ALT), ALT, RADIUS)
    plain, heavy = RouteBank(2, f.shape), RouteBank(2, f.shape, climb_weight=3.0)
    for bank in (plain, heavy):
        bank.set(0, f)
        bank.set(1, f)
    pts = np.array([[150.0, 100.0, ALT + 20.0], [60.0, 80.0, ALT - 7.0]])
    g = plain.distance(pts)
    dz = pts[:, 2] - ALT
    np.testing.assert_allclose(plain.potential(pts), np.sqrt(g ** 2 + dz ** 2), rtol=1e-12)
    np.testing.assert_allclose(heavy.potential(pts), np.sqrt(g ** 2 + (3.0 * dz) ** 2), rtol=1e-12)
    for i in range(2):
        assert heavy.potential(pts[i:i + 1], slots=[i])[0] == heavy.potential(pts)[i]  # one-point path, same doubles
    with pytest.raises(ValueError, match="climb_weight"):
        RouteConfig(climb_weight=0.0)


def test_flight_levels():
    assert flight_levels(30.0, 90.0, None) == (90.0,)
    assert flight_levels(90.0, 30.0, 60.0) == (30.0, 90.0)
    assert flight_levels(30.0, 90.0, 25.0) == pytest.approx((30.0, 50.0, 70.0, 90.0))
    assert flight_levels(40.0, 40.0, 10.0) == (40.0,)
    assert max_levels((30.0, 90.0), 60.0) == 2 and max_levels((30.0, 90.0), None) == 1
    with pytest.raises(ValueError, match="level_step_m"):
        RouteConfig(level_step_m=0.0)


def test_leveled_route_blocks_a_wall_only_at_the_altitudes_it_stands_in():
    """A 60 m wall across the way from a start at 20 m to a goal at 100 m: below its top the route goes
    round it, at the goal's level straight over; between the levels G is linear in altitude (clamped
    beyond them), in the batched and the one-point path alike, with one level the old single field."""
    city = _wall_city(height_m=60.0)
    goal = (140.0, 200.0, 100.0)
    route = leveled_route(city, goal, flight_levels(20.0, goal[2], 80.0), RADIUS)
    assert route.levels_m == (20.0, 100.0) and route.fields[0].blocked.any() and not route.fields[1].blocked.any()
    bank = RouteBank(2, route.fields[0].shape, levels=2)
    bank.set(0, route)
    bank.set(1, route.fields[1])  # a single field in a leveled bank: the same at every altitude
    xy = (140.0, 100.0)
    low, high = (_bank_of(f).distance(np.array([[*xy, 0.0]]))[0] for f in route.fields)
    assert low > 1.5 * high and high == pytest.approx(100.0, abs=2 * CFG.cell_m)
    z = np.array([0.0, 20.0, 40.0, 60.0, 100.0, 150.0])
    pts = np.column_stack([np.full(6, xy[0]), np.full(6, xy[1]), z])
    g = np.array([bank.distance(p[None], slots=[0])[0] for p in pts])
    expect = low + (high - low) * np.clip((z - 20.0) / 80.0, 0.0, 1.0)
    np.testing.assert_allclose(g, expect, rtol=1e-6)
    for p in pts:  # one-point path = batched path, the same doubles
        both = np.vstack([p, p])
        assert bank.potential(p[None], slots=[0])[0] == bank.potential(both, slots=[0, 0])[0]
        np.testing.assert_array_equal(bank.direction(p[None], slots=[0]), bank.direction(both, slots=[0, 0])[:1])
    # below the wall's top the way leads round it (sideways), at the goal's level straight on
    assert abs(bank.direction(pts[1:2], slots=[0])[0, 0]) > 0.5
    np.testing.assert_allclose(bank.direction(pts[4:5], slots=[0])[0], (0.0, 1.0), atol=0.05)
    np.testing.assert_array_equal(bank.distance(pts, slots=np.ones(6, dtype=int)),
                                  np.full(6, _bank_of(route.fields[1]).distance(pts[:1])[0]))
    with pytest.raises(ValueError, match="flight levels"):
        RouteBank(1, route.fields[0].shape).set(0, route)
    with pytest.raises(ValueError, match="evenly"):
        LeveledRoute((20.0, 30.0, 60.0), route.fields + route.fields[:1])
