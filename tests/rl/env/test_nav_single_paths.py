"""The one-vehicle fast paths give exactly (bit for bit) what the vectorised paths give for that row.

A single environment (`rl.env.gym_env.UAMNavEnv`, a `NavBatch` of one) takes plain-Python or fewer-call
paths where NumPy's per-call overhead dominated (`WindBank._wind_one`, `BatchSimulator._env_one`,
`episode._period_outcome_one`, `Perception._rays_one/_roofs_one`, `RouteBank._potential_one/
_direction_one`, `observation._build_observation_one`). Each is compared here with the vectorised
path on the same row inside a batch of many, over random inputs and the edge cases, including the
sign of zeros; tests/rl/env/test_nav_env.py checks a whole single env against the batched one.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from rl.sensing.observation import ObservationScales, build_observations, obs_size
from rl.sensing.perception import Perception, PerceptionConfig, PerceptionReading
from rl.sensing.route import RouteBank, grid_shape, route_field
from rl.task.cities import CityDistribution
from uam_fdm import episode
from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions
from uam_fdm.air.wind import GustStack, TurbulenceLevel, WindBank, WindShear
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.sim import BatchSimulator
from uam_fdm.vehicle.model import hover_state, make_env
from uam_fdm.vehicle.params import load_vehicle

R = 0.42  # collision radius [m]


def assert_same(a, b) -> None:
    """Equal shape, dtype and values, NaN where NaN, and the same sign bits elsewhere (so +0 != -0)."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype
    assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f")
    if a.dtype.kind == "f":
        ok = ~np.isnan(a)
        assert np.array_equal(np.signbit(a[ok]), np.signbit(b[ok]))


@pytest.fixture(scope="module")
def cities() -> list[BuildingMap]:
    return [CityDistribution().city(s) for s in (3, 4, 7)]


# ------------------------------------------------------------------------------------ wind, env

def _bank(n: int, rng, gusts: bool = True, shear: WindShear | None = None,
          heights: tuple[float, ...] = (5.0, 10.0, 20.0, 40.0)) -> WindBank:
    dt, m = 1.0 / 120.0, 600
    stacks = [GustStack(dt * np.arange(m), heights, rng.normal(0.0, 2.0, (m, len(heights), 3)), dt,
                        TurbulenceLevel.LIGHT, j, 10.0) for j in range(3)] if gusts else []
    bank = WindBank(stacks, n, shear)
    for i in range(n):
        bank.assign(i, rng.uniform(-5, 5, 3), int(rng.integers(max(1, len(stacks)))), int(rng.integers(300)))
    return bank


SHEARS = [None, WindShear("power", 10.0, 0.3), WindShear("log", 10.0, roughness_m=1.0)]


@pytest.mark.parametrize("heights", [(5.0, 10.0, 20.0, 40.0), (30.0,)])
@pytest.mark.parametrize("shear", SHEARS)
@pytest.mark.parametrize("gusts", [True, False])
def test_wind_one_equals_wind_batch(gusts, shear, heights):
    rng = np.random.default_rng(1)
    n = 64
    bank = _bank(n, rng, gusts, shear, heights)
    for rep in range(20):
        t = rng.uniform(0.0, 2.5, n)
        # on a sample, between samples, at the series' end (the clamp) and past it
        t[:5] = (0.0, 1.0 / 120.0, 0.5 / 120.0, 597.5 / 120.0, 640.0 / 120.0)
        z = rng.uniform(-5.0, 60.0, n)
        z[:6] = (5.0, 40.0, 0.0, 2.0, 10.0, np.sqrt(200.0))  # on rungs, below the floors, between rungs
        batch = bank.wind_enu_m_s(t, z)
        for i in range(n):
            assert_same(np.array(bank._wind_one(i, float(t[i]), float(z[i]))), batch[i])
            assert_same(bank.wind_enu_m_s(t[i:i + 1], z[i:i + 1], [i]), batch[i:i + 1])
            field = bank.field(i)
            if rep > 2 or t[i] > field.duration_s:
                continue  # field(i) refuses times past its stack; the bank extrapolates there
            assert_same(field.wind_enu_m_s(float(t[i]), float(z[i])), batch[i])
            assert_same(field.wind_enu_m_s_batch(t[i:i + 1], z[i:i + 1]), batch[i:i + 1])


def test_env_one_equals_env_batch():
    rng = np.random.default_rng(2)
    n = 32
    p = load_vehicle("small_quad")
    atm = Atmosphere.from_jsbsim(AtmosphereConditions(0.0, 0.0), z_max_m=400.0)

    class _Dyn:  # `env` needs only the control rate
        control_hz = 50.0

    sim = BatchSimulator(_Dyn(), atm, _bank(n, rng))
    z = rng.uniform(-5.0, 420.0, n)  # also beyond the density table (clamped)
    x = np.stack([hover_state(p, (0.0, 0.0, zi), 0.0) for zi in z])
    t = rng.uniform(0.0, 2.0, n)
    batch = sim.env(x, t)
    for i in range(n):
        assert_same(sim.env(x[i:i + 1], t[i:i + 1], np.array([i])), batch[i:i + 1])
        assert_same(sim.env(x[i:i + 1], float(t[i]), [i]), batch[i:i + 1])
    assert_same(sim.env(x[0:1], t[0:1]), batch[0:1])  # no idx: vehicle 0


def test_batch_caller_reads_read_only_and_empty_inputs(compiled_dynamics, vehicles):
    """The compiled call's fast address lookup falls back for arrays without a writable buffer."""
    dyn, p = compiled_dynamics["small_quad"], vehicles["small_quad"]
    rng = np.random.default_rng(3)
    x = np.stack([hover_state(p, (0.0, 0.0, 30.0), 0.0) for _ in range(3)])
    x += rng.normal(0, 0.01, x.shape)
    xi, cmd = rng.normal(0, 0.1, (3, 3)), rng.uniform(-2, 2, (3, 4))
    env = np.tile(make_env((1.0, -0.5, 0.0)), (3, 1))
    ref = dyn.period_velocity_batch(x, xi, cmd, env)
    frozen = [a.copy() for a in (x, xi, cmd, env)]
    for a in frozen:
        a.setflags(write=False)
    got = dyn.period_velocity_batch(*frozen)
    for a, b in ((ref.states, got.states), (ref.ctrl_state, got.ctrl_state), (ref.energy_J, got.energy_J)):
        assert_same(a, b)
    empty = dyn.period_velocity_batch(x[:0], xi[:0], cmd[:0], env[:0])
    assert empty.states.shape == (0, dyn.n_substeps, dyn.layout.nx)


# ------------------------------------------------------------------------------------- episode

def test_period_outcome_one_equals_batch():
    rng = np.random.default_rng(4)
    n, s, nx = 3000, 10, 17
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([100.0, 80.0, 60.0])
    pos = rng.uniform(-3.0, 103.0, (n, s, 3)) * np.array([1.0, 0.8, 0.6])
    states = np.concatenate([pos, rng.normal(size=(n, s, nx - 3))], axis=2)
    goal = rng.uniform(0.0, 60.0, (n, 3))
    radius = rng.uniform(0.5, 3.0, n)
    near = rng.random(n) < 0.3  # end within about the goal radius
    states[near, -1, 0:3] = goal[near] + rng.normal(0.0, 1.0, (near.sum(), 3))
    edge = np.flatnonzero(near)  # on the goal sphere, up to rounding; at the goal with radius 0 (0 <= 0)
    states[edge, :, 0:3] = np.clip(states[edge, :, 0:3], 1.0, 50.0)
    u = rng.normal(size=(len(edge), 3))
    states[edge, -1, 0:3] = goal[edge] + u / np.sqrt((u * u).sum(axis=1))[:, None] * radius[edge, None]
    states[edge[:5], -1, 0:3] = goal[edge[:5]]
    radius[edge[:5]] = 0.0
    states[rng.random(n) < 0.05, 3, 7] = np.nan
    states[rng.random(n) < 0.03, 7, 1] = np.inf
    states[rng.random(n) < 0.05, 2, 0:3] = np.array([0.0, 0.0, 0.0])  # on the bounds' corner: inside
    hit = rng.random(n) < 0.2
    batch = episode.period_outcome(states, hit, np.tile(lo, (n, 1)), np.tile(hi, (n, 1)), goal, radius)
    assert set(batch) == {episode.SUCCESS, episode.COLLISION, episode.OUT_OF_BOUNDS, episode.NONFINITE,
                          episode.RUNNING}
    for i in range(n):
        row = slice(i, i + 1)
        one = episode.period_outcome(states[row], hit[row], lo[None], hi[None], goal[row], radius[row])
        assert_same(one, batch[row])
        one = episode.period_outcome(states[row], [bool(hit[i])], lo, hi, goal[i], float(radius[i]))  # 1-D
        assert_same(one, batch[row])


# ---------------------------------------------------------------------------------- perception

def _queries(city: BuildingMap, rng, n: int):
    """Points inside and outside the bounds (up to 60 m), in and near inflated footprints, below and
    above the roofs, with headings along the axes, diagonal, and anywhere (also beyond ±pi)."""
    lo, hi = np.asarray(city.bounds_min_m), np.asarray(city.bounds_max_m)
    pts = [rng.uniform([lo[0] - 60, lo[1] - 60, 0.5], [hi[0] + 60, hi[1] + 60, 40.0], (n, 3))]
    for b in city.buildings[: n // 2]:
        co, si = math.cos(b.yaw_rad), math.sin(b.yaw_rad)
        hx, hy = 0.5 * b.size_xy_m[0] + R, 0.5 * b.size_xy_m[1] + R
        lx, ly = rng.uniform(-1.2, 1.2) * hx, rng.uniform(-1.2, 1.2) * hy  # inside or just outside
        z = rng.choice([rng.uniform(0.5, b.height_m), b.height_m + R, b.height_m + 2 * R])  # below, at, above
        cx, cy = b.center_xy_m
        pts.append(np.array([[cx + lx * co - ly * si, cy + lx * si + ly * co, z]]))
    pts = np.concatenate(pts)
    hd = rng.uniform(-10.0, 10.0, len(pts))
    hd[:9] = (0.0, -0.0, math.pi / 2, math.pi, -math.pi / 2, math.pi / 4, 2 * math.pi, -0.75 * math.pi, 1e-17)
    return pts, hd


@pytest.mark.parametrize("cfg", [PerceptionConfig(),  # two lookups per axis
                                 PerceptionConfig(n_rays=7, grid_cells=5, cell_m=4.5, raster_m=0.75),
                                 PerceptionConfig(n_rays=3, grid_cells=5, cell_m=2.0, raster_m=2.0)])  # three
def test_perception_one_equals_batch(cities, cfg):
    per = Perception(cities, R, cfg)
    rng = np.random.default_rng(5)
    pts, hd, ci = [], [], []
    for c, city in enumerate(cities):
        p, h = _queries(city, rng, 120)
        pts.append(p), hd.append(h), ci.append(np.full(len(p), c))
    pts, hd, ci = np.concatenate(pts), np.concatenate(hd), np.concatenate(ci)
    batch = per.observe(pts, hd, ci)
    assert (batch.ray_m == 0.0).any() and (batch.ray_m < cfg.ray_range_m).mean() > 0.1
    assert (batch.roof_m > 0).any() and (batch.roof_m == 0).any()
    for k in range(len(pts)):
        one = per.observe(pts[k:k + 1], hd[k:k + 1], ci[k:k + 1])
        assert_same(one.ray_m, batch.ray_m[k:k + 1])
        assert_same(one.roof_m, batch.roof_m[k:k + 1])
        assert_same(per.rays(pts[k], hd[k:k + 1], ci[k:k + 1]), batch.ray_m[k:k + 1])


def test_perception_one_in_an_empty_city():
    empty = BuildingMap([], (0.0, 0.0, 0.0), (50.0, 40.0, 100.0), name="empty")
    per = Perception([empty], R)
    pts = np.array([[10.0, 10.0, 5.0], [-30.0, 70.0, 1.0], [25.0, 20.0, 0.0]])
    batch = per.observe(pts, np.zeros(3), np.zeros(3, dtype=int))
    for k in range(3):
        one = per.observe(pts[k:k + 1], np.zeros(1), np.zeros(1, dtype=int))
        assert_same(one.ray_m, batch.ray_m[k:k + 1])
        assert_same(one.roof_m, batch.roof_m[k:k + 1])


# --------------------------------------------------------------------------------------- route

def _route_bank(cities, rng, n: int):
    """n slots with random goals (a few inside footprints) over the cities, and a city whose grid
    origin is exactly (0, 0) (bounds from -2 m at 4 m cells) so that -0.0 coordinates reach the clamp."""
    origin_city = BuildingMap([Building(1, (30.0, 20.0), (12.0, 8.0), 40.0)], (-2.0, -2.0, 0.0),
                              (80.0, 60.0, 100.0), name="origin")
    pool = list(cities) + [origin_city]
    shape = tuple(max(grid_shape(c)[k] for c in pool) for k in (0, 1))
    bank = RouteBank(n, shape)
    slot_city, goals = [], []
    for i in range(n):
        c = pool[i % len(pool)]
        lo, hi = np.asarray(c.bounds_min_m), np.asarray(c.bounds_max_m)
        if i % 7 == 3 and c.buildings:  # a goal inside a footprint: no clear disk (clear radius 0)
            b = c.buildings[i % len(c.buildings)]
            goal = np.array([*b.center_xy_m, 10.0])
        else:
            goal = rng.uniform(lo + [5, 5, 5], hi - [5, 5, 50])
        bank.set(i, route_field(c, goal, float(goal[2]), R))
        slot_city.append(c), goals.append(goal)
    return bank, slot_city, np.array(goals)


def _route_points(bank: RouteBank, slot_city, goals, rng):
    """Per slot: random points inside and outside the grid, at and near the goal, on cell centres and
    the grid's edge, -0.0 coordinates, and NaN coordinates."""
    pts, slots = [], []
    for i, (c, g) in enumerate(zip(slot_city, goals)):
        lo, hi = np.asarray(c.bounds_min_m), np.asarray(c.bounds_max_m)
        p = rng.uniform(lo - [40, 40, 0], hi + [40, 40, 0], (150, 3))
        p[:50, 0:2] = g[:2] + rng.normal(0.0, 3.0, (50, 2))  # in and around the goal's clear disk
        ox, oy = bank._origin[i]
        cell = 1.0 / bank._inv_cell[i]
        lx, ly = bank._last[i]
        extra = [g, g + [0.0, 0.0, 7.0], g + [1e-10, 0.0, 0.0], g + [0.3, -0.2, 0.0], g + [2.0, 2.5, 1.0],
                 [ox, oy, 5.0], [ox + 3 * cell, oy + 2 * cell, 5.0], [ox + lx * cell, oy + ly * cell, 5.0],
                 [ox + lx * cell + 1e-9, oy - 1e-9, 5.0], [-0.0, -0.0, 5.0], [-0.0, 10.0, -0.0],
                 [np.nan, 10.0, 5.0], [10.0, np.nan, 5.0], [10.0, 10.0, np.nan], [np.inf, 10.0, 5.0]]
        pts.append(np.vstack([p, extra]))
        slots.append(np.full(len(p) + len(extra), i))
    return np.concatenate(pts), np.concatenate(slots)


def test_route_one_equals_batch(cities):
    rng = np.random.default_rng(6)
    bank, slot_city, goals = _route_bank(cities, rng, 12)
    pts, slots = _route_points(bank, slot_city, goals, rng)
    with np.errstate(invalid="ignore"):
        pot, drc = bank.potential(pts, slots), bank.direction(pts, slots)
    assert np.isnan(pot).any() and (pot[~np.isnan(pot)] >= 0).all()
    assert (np.hypot(drc[:, 0], drc[:, 1]) == 0.0).any()  # at a goal
    for k in range(len(pts)):
        s = slots[k:k + 1]
        with np.errstate(invalid="ignore"):
            assert_same(bank.potential(pts[k:k + 1], s), pot[k:k + 1])
            assert_same(bank.direction(pts[k:k + 1], s), drc[k:k + 1])
    # without slots= (one point per slot), in a bank of one
    one = RouteBank(1, bank.max_cells)
    one.set(0, route_field(slot_city[0], goals[0], float(goals[0][2]), R))
    mask = slots == 0
    with np.errstate(invalid="ignore"):
        for k in np.flatnonzero(mask):
            assert_same(one.potential(pts[k]), pot[k:k + 1])
            assert_same(one.direction(pts[k:k + 1]), drc[k:k + 1])


# --------------------------------------------------------------------------------- observation

@pytest.mark.parametrize("scales", [ObservationScales(), ObservationScales(400.0, 80.0, 200.0, 120.0)])
def test_build_observation_one_equals_batch(scales):
    rng = np.random.default_rng(7)
    cfg = PerceptionConfig()
    vehicle = load_vehicle("small_quad")
    n, nx, hist = 300, 17, 20
    x = rng.normal(0.0, 1.0, (n, nx)) * np.r_[100, 100, 30, 8, 8, 3, np.ones(nx - 6)]
    x[:, 2] = np.abs(x[:, 2])
    goal = x[:, 0:3] + rng.normal(0.0, 80.0, (n, 3))
    goal[:10] = x[:10, 0:3]  # at the goal
    goal[10:15, 0:2] = x[10:15, 0:2]
    heading = rng.uniform(-10.0, 10.0, n)
    heading[:6] = (0.0, -0.0, math.pi / 2, math.pi, -math.pi / 4, 2 * math.pi)
    route = np.abs(rng.normal(0.0, 200.0, n))
    d = rng.normal(size=(n, 2))
    route_dir = d / np.hypot(d[:, 0], d[:, 1])[:, None]
    route_dir[:5] = 0.0
    clear = rng.normal(5.0, 20.0, n)
    clear[15:20] = (np.nan, 30.0, 31.0, -0.0, 0.0)
    nearest = rng.normal(0.0, 15.0, (n, 3))
    nearest[20:25] = 0.0
    prev = rng.uniform(-1, 1, (n, 3))
    history = route[:, None] + rng.normal(0.0, 5.0, (n, hist))
    t_frac = rng.uniform(0, 1, n)
    x[25:30, 3] = 1e6  # clipped at OBS_CLIP
    rays = np.minimum(np.abs(rng.normal(20.0, 20.0, (n, cfg.n_rays))), cfg.ray_range_m)
    rays[30:35] = 0.0
    roofs = np.maximum(rng.normal(10.0, 30.0, (n, cfg.grid_cells ** 2)), 0.0).round()
    batch = build_observations(x, goal, heading, route, route_dir, clear, nearest, prev, history, t_frac,
                               PerceptionReading(rays, roofs), cfg, vehicle, 10.0, scales)
    assert batch.shape == (n, obs_size(cfg)) and np.isnan(batch).any()
    for k in range(n):
        s = slice(k, k + 1)
        one = build_observations(x[s], goal[s], heading[s], route[s], route_dir[s], clear[s], nearest[s],
                                 prev[s], history[s], t_frac[s], PerceptionReading(rays[s], roofs[s]), cfg,
                                 vehicle, 10.0, scales)
        assert_same(one, batch[s])
