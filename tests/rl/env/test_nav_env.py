"""The learned pilot's environment: API checks, determinism, batched == single, sensing, outcomes."""
from __future__ import annotations

from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import rl  # noqa: F401  (registers UAMNav-v0)
from rl.env.gym_env import UAMNavEnv
from rl.env.vec_env import UAMNavVecEnv
from rl.env.world import NavWorld
from rl.sensing.observation import ObservedContext, obs_size
from rl.sensing.sensor import BoxSensor
from rl.task.air import AirDistribution
from rl.task.cities import CityDistribution
from rl.task.config import FixedEpisodes, NavConfig
from rl.task.reward import TERMS, RewardConfig, reward_terms, stopping_distance
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.pilot import Task

SMALL = NavConfig(city_pool_size=4, wind_pool_size=2, wind_series_s=150.0)

CALM = AirDistribution(turbulence=("none",), steady_wind_max_m_s=0.0)  # no gusts, no wind


@pytest.fixture(scope="module")
def world() -> NavWorld:
    return NavWorld(SMALL)


def _actions(seed: int, n: int, k: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1, 1, size=(n, k, 3)).astype(np.float32)


def test_registered_and_checkers_pass(world):
    env = gym.make("UAMNav-v0", config=SMALL)
    assert env.observation_space.shape == (obs_size(SMALL.perception),)
    gym_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(UAMNavEnv(world=world), warn=True)


def test_seeded_rollout_repeats_exactly(world):
    acts = _actions(1, 200)[:, 0]

    def rollout():
        env = UAMNavEnv(world=world)
        obs, _ = env.reset(seed=123)
        rows = [obs]
        for a in acts:
            obs, r, term, trunc, info = env.step(a)
            rows.append(np.append(obs, [r, term, trunc]))
            if term or trunc:
                obs, _ = env.reset()
        return rows

    a, b = rollout(), rollout()
    assert all(np.array_equal(x, y) for x, y in zip(a, b))


@pytest.fixture(scope="module")
def airy_world(world) -> NavWorld:
    """A world whose episodes draw their field (of 3), turbulence level (of 3) and a wind up to 8 m/s, and whose
    observation holds the air, the geofence and two past decisions."""
    air = AirDistribution(elevation_m=(0.0, 3000.0), isa_offset_k=(-10.0, 30.0),
                          turbulence=("none", "light", "moderate"),
                          steady_wind_max_m_s=8.0, pool_size=3)
    observe = ObservedContext(air=True, geofence=True, history=2)
    return NavWorld(replace(SMALL, air=air, observe=observe), dynamics=world.dynamics)


def test_batched_equals_single_envs(world):
    _assert_batched_equals_single(world)


def test_batched_equals_single_envs_each_in_its_own_air(airy_world):
    """Each slot in its own field and turbulence level: the batch's per-slot density (`AtmosphereBank`) and
    gusts are the single env's, and the draws cover several fields and levels."""
    _assert_batched_equals_single(airy_world, seed=50)
    venv = UAMNavVecEnv(8, world=airy_world, seed=1)
    venv.reset()
    assert len(set(venv.batch.air.tolist())) > 1 and len(set(venv.batch.level.tolist())) > 1
    i = int(np.flatnonzero(venv.batch.air != venv.batch.air[0])[0])
    sigma = venv.batch.sim.env(venv.batch.x, venv.batch.t)[:, 3]  # the density ratio each slot flies
    assert sigma[0] == venv.batch.atmosphere(0).density_ratio_clamped(float(venv.batch.x[0, 2]))
    assert sigma[i] == venv.batch.atmosphere(i).density_ratio_clamped(float(venv.batch.x[i, 2]))
    assert sigma[0] != sigma[i]
    obs = venv.batch.observations  # the air elements: the density ratio each slot flies, less 1
    assert airy_world.obs_size == obs_size(SMALL.perception) + 2 + 4 + 12
    base = obs_size(SMALL.perception)
    np.testing.assert_allclose(obs[:, base], sigma - 1.0, rtol=1e-6)


def test_a_task_of_one_field_and_one_level_draws_as_before(world):
    """The air's draws happen only where there is a choice: the shipped tasks' episodes are unchanged."""
    one = NavWorld(replace(SMALL, air=AirDistribution(pool_size=8)), dynamics=world.dynamics)
    assert len(one.atmospheres) == 1 and one.levels == world.levels
    a, b = UAMNavVecEnv(4, world=world, seed=9), UAMNavVecEnv(4, world=one, seed=9)
    assert np.array_equal(a.reset(), b.reset())
    assert np.array_equal(a.batch.winds.series_index, b.batch.winds.series_index)


def _assert_batched_equals_single(world: NavWorld, seed: int = 40) -> None:
    n, steps = 4, 300
    acts = np.clip(_actions(2, steps, n) * 0.3 + np.array([0.5, 0.3, -0.9], dtype=np.float32), -1, 1)  # descend: ends
    venv = UAMNavVecEnv(n, world=world, seed=seed)
    singles = [UAMNavEnv(world=world) for _ in range(n)]
    obs_v = venv.reset()
    obs_s = np.stack([e.reset(seed=seed + i)[0] for i, e in enumerate(singles)])
    assert np.array_equal(obs_v, obs_s)
    dones = 0
    for t in range(steps):
        obs_v, rew_v, done_v, infos_v = venv.step(acts[t])
        for i, e in enumerate(singles):
            o, r, term, trunc, info = e.step(acts[t, i])
            assert r == rew_v[i] and (term or trunc) == done_v[i]
            if term or trunc:
                dones += 1
                assert np.array_equal(infos_v[i]["terminal_observation"], o)
                assert infos_v[i]["outcome"] == info["outcome"]
                o, _ = e.reset()
            assert np.array_equal(o, obs_v[i])
    assert dones > 0  # the comparison crossed automatic resets


def test_reward_terms_sum_and_info(world):
    env = UAMNavEnv(world=world)
    env.reset(seed=5)
    for a in _actions(3, 50)[:, 0]:
        _, r, term, trunc, info = env.step(a)
        assert set(info["reward_terms"]) == set(TERMS)
        assert r == pytest.approx(sum(info["reward_terms"].values()), rel=1e-5, abs=1e-6)
        if term or trunc:
            assert info["outcome"] in ("success", "collision", "out_of_bounds", "nonfinite", "timeout")
            break


def test_proximity_cost_per_metre_grows_with_speed():
    cfg = RewardConfig()
    one = np.ones(3)
    speed = np.array([0.0, cfg.proximity_speed_m_s, 2 * cfg.proximity_speed_m_s])
    t = reward_terms(cfg, one, one, one, one, speed, 0.1 * one, np.zeros(3, bool), np.zeros(3, bool))
    base = -cfg.proximity_per_s * 0.1 * (1 - 1 / cfg.proximity_m) ** 2
    assert t["proximity"] == pytest.approx(base * np.array([1.0, 2.0, 5.0]))
    # passing the same wall 1 m off: per metre, fast costs more than slow (per second alone it would cost less)
    per_m = t["proximity"][1:] / speed[1:]
    assert per_m[1] < per_m[0] < 0
    far = reward_terms(cfg, one, one, one, one + cfg.proximity_m, speed, 0.1 * one, np.zeros(3, bool),
                       np.zeros(3, bool))
    assert (far["proximity"] == 0).all()


def _box_world(tasks, timeout_s=30.0, turbulence="none"):
    city = BuildingMap([Building(0, (60.0, 50.0), (20.0, 40.0), 40.0)], (0, 0, 0), (120, 100, 60), name="one-box")
    cfg = NavConfig(city_pool_size=1, air=AirDistribution(turbulence=(turbulence,), steady_wind_max_m_s=0.0))
    fixed = FixedEpisodes((city,), tuple((0, Task(s, g, 3.0, timeout_s)) for s, g in tasks))
    return NavWorld(cfg, fixed=fixed), city


def test_outcomes_collision_arrival_truncation_bounds():
    world, _ = _box_world([((20.0, 50.0, 10.0), (100.0, 50.0, 10.0))], timeout_s=4.0)
    env = UAMNavEnv(world=world)
    env.reset(seed=0)
    info = {}
    for _ in range(400):  # fly east into the building
        _, r, term, trunc, info = env.step(np.array([1.0, 0.0, 0.0], dtype=np.float32))
        if term or trunc:
            break
    assert term and info["outcome"] == "collision" and info["reward_terms"]["collision"] < 0
    assert env.state[0] < 50.0 - 0.4 + 0.5  # stopped at the wall (x = 50), not beyond
    # straight down: the ground is an obstacle too
    env.reset(seed=0)
    for _ in range(400):
        _, _, term, trunc, info = env.step(np.array([0.0, 0.0, -1.0], dtype=np.float32))
        if term or trunc:
            break
    assert info["outcome"] == "collision" and env.state[2] < 1.0
    # hovering: truncated at the 4 s limit, 40 decisions at 10 Hz
    env.reset(seed=0)
    for k in range(1000):  # noqa: B007 - k counts the decisions (checked after the loop)
        _, _, term, trunc, info = env.step(np.zeros(3, dtype=np.float32))
        if term or trunc:
            break
    assert trunc and not term and info["outcome"] == "timeout" and k + 1 == 40
    # flying west leaves the flight volume
    env.reset(seed=0)
    for _ in range(400):
        _, _, term, trunc, info = env.step(np.array([-1.0, 0.0, 0.0], dtype=np.float32))
        if term or trunc:
            break
    assert info["outcome"] == "out_of_bounds"


def test_arrival():
    world, _ = _box_world([((20.0, 10.0, 10.0), (60.0, 10.0, 10.0))])
    env = UAMNavEnv(world=world)
    obs, _ = env.reset(seed=0)
    for _ in range(1500):
        # goal frame: straight ahead, climbing or sinking towards the goal's height
        obs, r, term, trunc, info = env.step(np.array([min(1.0, obs[0] * 4), 0.0, np.clip(obs[1] * 3, -1, 1)],
                                                      dtype=np.float32))
        if term or trunc:
            break
    assert info["outcome"] == "success" and info["is_success"] and info["reward_terms"]["arrival"] > 0


def test_sensor_matches_fcl():
    cities = [CityDistribution().city(s) for s in (3, 4)]
    sensor = BoxSensor(cities, k=4, range_m=30.0, radius_m=0.42)
    rng = np.random.default_rng(0)
    for ci, city in enumerate(cities):
        hi = np.asarray(city.bounds_max_m)
        pts = rng.uniform([0, 0, 0.5], [hi[0], hi[1], 60.0], size=(150, 3))
        r = sensor.query(pts, np.full(len(pts), ci))
        ref = city.clearance(pts, 0.42, backend="fcl").distance_m
        near = ref < 30.0
        np.testing.assert_allclose(r.clearance_m[near], ref[near], atol=1e-9)
        assert np.all(r.clearance_m[~near] >= 30.0 - 1e-9) or np.all(ref[~near] >= 30.0)
        # the k nearest within range are the city's own k nearest
        npts, dist, ids = city.nearest_obstacles_batch(pts, 4, 0.42)
        inside = dist <= 30.0
        assert np.array_equal(np.where(inside, ids, -1), r.building_id)
        np.testing.assert_allclose(np.where(inside, dist, 30.0), r.distance_m, atol=1e-9)


def test_render_rgb_array(world):
    env = UAMNavEnv(world=world, render_mode="rgb_array")
    env.reset(seed=1)
    for _ in range(5):
        env.step(np.zeros(3, dtype=np.float32))
    img = env.render()
    assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.uint8
    assert (img < 200).any(axis=2).mean() > 0.02  # buildings and axes drawn, not a blank canvas


def test_bad_config_rejected():
    with pytest.raises(ValueError, match="city_split"):
        NavConfig(city_split="test")
    with pytest.raises(ValueError, match="hurricane"):
        NavConfig(air=AirDistribution(turbulence=("hurricane",)))
    with pytest.raises(ValueError, match=r"air.elevation_m must be a range \[low, high\]"):
        AirDistribution(elevation_m=(2000.0, 1000.0))
    with pytest.raises(ValueError, match="names a level twice"):
        AirDistribution(turbulence=("light", "light"))


def test_a_validation_world_shares_the_training_worlds_turbulence_only_when_identical(world):
    """The same stacks a fresh build gives (same seeds and settings), shared instead of generated again;
    a world that would generate other stacks (here: longer series) builds its own."""
    shared = NavWorld(replace(SMALL, wind_pool_size=1, city_split="eval"), dynamics=world.dynamics,
                      atmosphere=world.atmosphere, wind_from=world)
    assert len(shared.gust_stacks) == 1 and shared.gust_stacks[0] is world.gust_stacks[0]
    fresh = NavWorld(replace(SMALL, wind_pool_size=1), dynamics=world.dynamics, atmosphere=world.atmosphere)
    np.testing.assert_array_equal(fresh.gust_stacks[0].gust_enu_m_s, world.gust_stacks[0].gust_enu_m_s)
    other = NavWorld(replace(SMALL, wind_pool_size=1, wind_series_s=160.0), dynamics=world.dynamics,
                     atmosphere=world.atmosphere, wind_from=world)
    assert other.gust_stacks[0] is not world.gust_stacks[0]
    assert other.gust_stacks[0].duration_s > world.gust_stacks[0].duration_s


def test_another_pilots_world_shares_the_cities_and_sensing_only_when_identical(world):
    """The potential field's world (the policy's tasks at 50 Hz decisions) holds the policy world's cities,
    clearance sensor and perception, not copies; a world of other cities is refused, naming them."""
    apf = NavWorld(replace(world.config, decision_hz=world.config.control_hz), dynamics=world.dynamics,
                   atmosphere=world.atmosphere, wind_from=world, geometry_from=world)
    assert apf.cities is world.cities and apf.perception is world.perception
    assert apf.clearance_sensor is world.clearance_sensor and apf.config.action_repeat == 1
    with pytest.raises(ValueError, match="city seeds differ"):
        NavWorld(replace(world.config, city_pool_offset=world.config.city_pool_offset + 1), dynamics=world.dynamics,
                 atmosphere=world.atmosphere, geometry_from=world)
    with pytest.raises(ValueError, match="perception differ"):
        NavWorld(replace(world.config, perception=replace(world.config.perception, n_rays=4)),
                 dynamics=world.dynamics, atmosphere=world.atmosphere, geometry_from=world)


def test_time_limit_adds_the_climb_time_only_when_asked():
    """The UAM's time limit adds per_climb x |Δz| / max vertical speed; the same draws, the same legs."""
    from dataclasses import replace

    from rl.task.cities import TaskDistribution

    city = CityDistribution().city(3)
    plain = TaskDistribution()
    climb = replace(plain, timeout_per_climb=2.0)
    for k in range(5):
        a = plain.sample(city, np.random.default_rng(k), 0.42, 12.0, max_vertical_speed_m_s=3.0)
        b = climb.sample(city, np.random.default_rng(k), 0.42, 12.0, max_vertical_speed_m_s=3.0)
        assert (a.start_m, a.goal_m) == (b.start_m, b.goal_m)
        d = float(np.linalg.norm(np.subtract(a.goal_m, a.start_m)))
        assert a.timeout_s == round(20.0 + 2.5 * d / 12.0, 2)
        assert b.timeout_s == round(20.0 + 2.5 * d / 12.0 + 2.0 * abs(a.goal_m[2] - a.start_m[2]) / 3.0, 2)


def test_a_time_limit_cut_shortens_the_same_legs_by_up_to_the_cut():
    from dataclasses import replace

    from rl.task.cities import TaskDistribution

    city = CityDistribution().city(3)
    plain = TaskDistribution()
    cut = replace(plain, timeout_cut_s=15.0)
    cuts = []
    for k in range(40):
        a = plain.sample(city, np.random.default_rng(k), 0.42, 12.0)
        b = cut.sample(city, np.random.default_rng(k), 0.42, 12.0)
        assert (a.start_m, a.goal_m) == (b.start_m, b.goal_m)
        cuts.append(a.timeout_s - b.timeout_s)
    assert 0.0 <= min(cuts) < 3.0 and 12.0 < max(cuts) <= 15.01  # spread over the whole cut
    for bad in (-1.0, 20.0):
        with pytest.raises(ValueError, match="timeout_cut_s"):
            replace(plain, timeout_cut_s=bad)


def test_braking_cost_starts_at_a_margin_of_the_stopping_distance():
    cfg = RewardConfig(braking_per_s=10.0, braking_margin=1.5)
    d = stopping_distance(np.array([0.0, 20.0]), 4.57, 1.25)
    assert d == pytest.approx([0.0, 20.0 ** 2 / (2 * 4.57) + 20.0 * 1.25])
    one = np.ones(4)
    stop = np.full(4, 60.0)
    ahead = np.array([200.0, 90.0, 60.0, 0.0])  # beyond the reach (1.5 x 60 m), at it, at d, at the wall
    t = reward_terms(cfg, one, one, 100 * one, 100 * one, 20 * one, 0.2 * one, np.zeros(4, bool), np.zeros(4, bool),
                     ahead, stop)
    assert t["braking"] == pytest.approx(-10.0 * 0.2 * np.array([0.0, 0.0, (1 - 1 / 1.5) ** 2, 1.0]))
    hover = reward_terms(cfg, one, one, one, one, 0 * one, 0.2 * one, np.zeros(4, bool), np.zeros(4, bool),
                         0 * one, 0 * one)  # at rest nothing is owed, even touching a wall
    assert (hover["braking"] == 0).all()
    with pytest.raises(ValueError, match="braking"):
        reward_terms(cfg, one, one, one, one, one, one, np.zeros(4, bool), np.zeros(4, bool))
    # off by default (the small quad's task): the term is zero and needs no distances
    assert (reward_terms(RewardConfig(), one, one, one, one, one, one, np.zeros(4, bool),
                         np.zeros(4, bool))["braking"] == 0).all()


def test_braking_term_in_the_env_charges_heading_at_a_wall():
    """Flying east at a box at speed costs braking; the same flight with the term off costs none."""
    city = BuildingMap([Building(0, (150.0, 50.0), (20.0, 40.0), 40.0)], (0, 0, 0), (220, 100, 60), name="wall")
    task = Task((20.0, 50.0, 10.0), (200.0, 50.0, 10.0), 3.0, 30.0)
    costs = []
    for per_s in (0.0, 10.0):
        cfg = NavConfig(city_pool_size=1, air=CALM,
                        reward=RewardConfig(braking_per_s=per_s))
        env = UAMNavEnv(world=NavWorld(cfg, fixed=FixedEpisodes((city,), ((0, task),))))
        env.reset(seed=0)
        total = 0.0
        for _ in range(300):
            _, _, term, trunc, info = env.step(np.array([1.0, 0.0, 0.0], dtype=np.float32))
            total += info["reward_terms"]["braking"]
            if term or trunc:
                break
        assert info.get("outcome") == "collision"
        costs.append(total)
    assert costs[0] == 0.0 and costs[1] < -1.0
