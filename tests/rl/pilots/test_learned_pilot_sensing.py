"""The learned pilot on its sensors: it flies with the reduced lidar the env's slots carry (and says so), observes its
estimate and its lidar view, and an episode flown by the env's sensing slot and by the runner with `PolicyPilot` is
the same bit for bit: observations, actions and true states at every decision."""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pytest

from compare.flying.episode_loop import PilotError, run_episode
from rl.env.world import NavBatch, NavWorld, SlotAir
from rl.pilots.learned import Policy, PolicyPilot, load_policy
from rl.policies.folder import SHIPPED_POLICIES
from rl.policies.reader import ObsNorm
from rl.sensing.truth import MapDraw
from rl.task.config import learned_lidar, learned_pilot_sensing
from rl.training.evaluation import eval_config
from uam_fdm.pilot import Observation, ResetInfo, Task, Truth, VelocityCommand, World, flown_sensing
from uam_fdm.sensing import onboard as onboard_module
from uam_fdm.sensing.specs import SensingConfig, sensing_preset

LEVELS = ("nominal", "degraded")


@dataclass
class _Recorded(Policy):
    """The policy, keeping the actions it gives (one row a call)."""

    actions: list[np.ndarray] = field(default_factory=list)

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        act = super().act_batch(obs)
        self.actions.extend(np.array(a) for a in act)
        return act


@pytest.fixture(scope="module")
def policy() -> Policy:
    return load_policy(SHIPPED_POLICIES["small_quad"])


@pytest.fixture(scope="module")
def world(policy: Policy) -> NavWorld:
    """The policy's held-out task (3 cities, its envelope's air) at both sensing levels."""
    return NavWorld(replace(eval_config(policy.nav, 3), sensing=LEVELS))


@pytest.fixture(scope="module")
def wrong_maps(world: NavWorld) -> NavWorld:
    """The same task where every prior map is a `wrong` draw (buildings missing, cranes and masts unmapped)."""
    return NavWorld(replace(world.config, map_error=("wrong",), map_error_draws=2), dynamics=world.dynamics,
                    wind_from=world, atmosphere=world.atmospheres)


@dataclass(frozen=True)
class _Episode:
    """One episode: city index, task, air and map (prior and truth)."""

    city: int
    task: Task
    air: SlotAir
    map: MapDraw


def _episode(world: NavWorld, seed: int) -> _Episode:
    """A held-out task and map drawn for a slot seeded `seed`, in light turbulence and a steady wind."""
    drawn = NavBatch(world, 1)
    drawn.seed([seed])
    drawn.reset_slots([0])
    ci = int(drawn.city[0])
    light = [level.value for level in world.levels].index("light")
    air = SlotAir((1.5, -1.0, 0.0), world.level_stacks[light][0], 120, light, 5)
    return _Episode(ci, drawn.task(0), air, world.maps.draw(ci, int(drawn.map_level[0]), int(drawn.map_draw[0])))


def _fly_env(world: NavWorld, policy: Policy, episode: _Episode, level: int,
             sensing_seed: int) -> tuple[NavBatch, list[np.ndarray], list[np.ndarray], list[np.ndarray], str]:
    """The episode in one slot of the env at sensing level index `level`: the observations it decided on, the
    actions, the true states after each decision, and the outcome."""
    b = NavBatch(world, 1)
    b.place([(0, episode.city, episode.task, episode.air)], maps=[episode.map], sensing=[(level, sensing_seed)])
    assert b.sensing(0) == LEVELS[level]
    obs = b.observations.copy()
    seen, actions, states = [], [], []
    for _ in range(100_000):
        act = policy.act_batch(obs)
        seen.append(obs[0].astype(float))
        actions.append(act[0])
        obs, _, term, trunc, info = b.step(act)
        states.append(b.x[0].copy())
        if term[0] or trunc[0]:
            return b, seen, actions, states, info[0]["outcome"]
    raise AssertionError("the env's episode never ended")  # pragma: no cover


def _assert_env_equals_runner(world: NavWorld, policy: Policy, seed: int, level: int, sensing_seed: int) -> str:
    """A sensing slot of the env and `run_episode` + `PolicyPilot` (the scenario's sensing: the level's preset; the
    pilot's world: the prior map; the truth: the map's truth) from the same task, air, map and sensing seed: the same
    raw observation, action and true state at every decision, and the same outcome (returned)."""
    episode = _episode(world, seed)
    b, seen, actions, states, outcome = _fly_env(world, policy, episode, level, sensing_seed)
    assert len(states) > 30  # a real flight, not a start
    recorded = _Recorded(policy.folder, policy.network, policy.obs_norm, policy.nav)
    sensing = sensing_preset(LEVELS[level], world.vehicle.mass_kg)
    given = World(world.vehicle, world.dynamics, episode.map.prior, b.atmosphere(0), b.turbulence(0), sensing=sensing)
    traj = run_episode(given, PolicyPilot(recorded), episode.task, b.wind_field(0), 0,
                       truth=Truth(episode.map.truth, sensing, sensing_seed))
    assert traj.decisions is not None
    observed = traj.decisions.observations
    assert len(observed) == len(seen) == len(recorded.actions)
    for k, (a, e) in enumerate(zip(observed, seen, strict=True)):
        assert a is not None and np.array_equal(a, e), f"observation {k} differs"
        assert np.array_equal(recorded.actions[k], actions[k]), f"action {k} differs"
    per_decision = world.config.action_repeat * world.dynamics.n_substeps
    flown = traj.states[per_decision::per_decision]
    np.testing.assert_array_equal(flown, np.array(states)[:len(flown)])
    np.testing.assert_array_equal(traj.states[-1], states[-1])
    assert traj.outcome == outcome
    assert traj.estimate_m is not None  # it flew on its estimate ...
    assert not np.array_equal(traj.estimate_m, traj.states[:, 0:3])  # ... which is not the truth
    return outcome


@pytest.mark.parametrize(("level", "seed", "sensing_seed"), [(0, 7, 1234), (1, 8, 99)])
def test_env_slot_and_runner_fly_the_same_episode_on_sensors(world, policy, level, seed, sensing_seed):
    _assert_env_equals_runner(world, policy, seed, level, sensing_seed)


@pytest.mark.parametrize(("level", "seed", "outcome"), [(1, 7, "success"), (0, 9, "collision")])
def test_env_slot_and_runner_fly_the_same_episode_on_sensors_over_a_wrong_map(wrong_maps, policy, level, seed,
                                                                              outcome):
    """The same where the prior map lacks buildings the lidar sees (one episode ends in a collision)."""
    drawn = _episode(wrong_maps, seed).map
    assert drawn.prior is not drawn.truth
    assert _assert_env_equals_runner(wrong_maps, policy, seed, level, 321) == outcome


@dataclass(frozen=True)
class _Blind:
    """A network fed all but the last observation element (the shipped one, reading the uncertainty's layout)."""

    inner: Any

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.inner.act(obs[:, :-1])


def test_the_estimates_uncertainty_is_observed_the_same_by_env_and_runner(world, policy):
    """`observe.uncertainty`: the estimate's position sigma along its longest axis / clearance scale, the same in the
    env's slot and the runner's pilot at every decision (the shipped network acts on the rest)."""
    nav = replace(policy.nav, observe=replace(policy.nav.observe, uncertainty=True))
    unsure = NavWorld(replace(world.config, observe=nav.observe), dynamics=world.dynamics, wind_from=world,
                      atmosphere=world.atmospheres)
    n = policy.obs_norm
    norm = ObsNorm(np.append(n.mean, 0.0), np.append(n.var, 1.0), n.count, n.epsilon, n.clip_obs)
    blind = Policy(policy.folder, _Blind(policy.network), norm, nav)  # type: ignore[arg-type]
    _assert_env_equals_runner(unsure, blind, 8, 1, 99)
    _, seen, _, _, _ = _fly_env(unsure, blind, _episode(unsure, 8), 1, 99)
    sigma = np.array([o[-1] for o in seen]) * nav.scales.clearance_m
    assert np.all(sigma > 0.0) and np.ptp(sigma) > 0.0  # the filter's sigma, moving with its fixes


@pytest.mark.parametrize(("level", "seed"), [(0, 9), (1, 7)])
def test_routes_redrawn_around_sensed_columns_are_the_same_in_env_and_runner(wrong_maps, policy, level, seed):
    """With the route redrawn every second around what the lidar sensed (`RouteConfig.refresh_s`), over priors that
    lack buildings and cranes: env and runner still fly the same episode bit for bit, and routes were redrawn."""
    nav = replace(policy.nav, route=replace(policy.nav.route, refresh_s=1.0))
    refreshed = NavWorld(replace(wrong_maps.config, route=nav.route), dynamics=wrong_maps.dynamics,
                         wind_from=wrong_maps, atmosphere=wrong_maps.atmospheres)
    redrawing = Policy(policy.folder, policy.network, policy.obs_norm, nav)
    _assert_env_equals_runner(refreshed, redrawing, seed, level, 321)
    b, *_ = _fly_env(refreshed, redrawing, _episode(refreshed, seed), level, 321)
    assert b.route_redraws[0] > 0


class _Watched(PolicyPilot):
    """The learned pilot, keeping the world it is given and its observations."""

    def __init__(self, policy: Policy) -> None:
        super().__init__(policy)
        self.given: World | None = None
        self.seen: list[Observation] = []

    def reset(self, world: World, task: Task, seed: int) -> ResetInfo:
        self.given = world
        return super().reset(world, task, seed)

    def act(self, obs: Observation) -> VelocityCommand:
        self.seen.append(obs)
        return super().act(obs)


def test_the_learned_pilot_carries_the_envs_reduced_lidar(world, policy, monkeypatch):
    """Its `Onboard` is built with the reduced lidar, exactly the env's config at a preset level, and the reduction
    applied to a scenario's overridden config; its `World.sensing` says so; it receives 8 x 36 beam scans."""
    built: list[SensingConfig] = []

    class Spied(onboard_module.Onboard):
        def __init__(self, config: SensingConfig, *args, **kwargs) -> None:
            built.append(config)
            super().__init__(config, *args, **kwargs)

    monkeypatch.setattr(onboard_module, "Onboard", Spied)
    mass = world.vehicle.mass_kg
    preset = sensing_preset("degraded", mass)
    overridden = replace(preset, latency_s=0.05, overridden=("latency_s",))
    city = world.cities[0]
    b = NavBatch(world, 1)
    b.seed([3])
    b.reset_slots([0])
    for scenario, carried in ((preset, learned_pilot_sensing("degraded", mass)), (overridden, None)):
        pilot = _Watched(policy)
        given = World(world.vehicle, world.dynamics, city, b.atmosphere(0), b.turbulence(0), sensing=scenario)
        task = replace(b.task(0), timeout_s=0.8)
        run_episode(given, pilot, task, b.wind_field(0), 0, truth=Truth(city, scenario, 5))
        config = built.pop()
        assert config == pilot.sensing_flown(scenario) == learned_lidar(scenario)
        if carried is not None:
            assert config == carried  # what the env's slots carry (`OnboardSlots`)
        assert (config.lidar.channels, config.lidar.columns) == (8, 36)
        assert config.latency_s == scenario.latency_s and config.gnss == scenario.gnss  # the rest: the scenario's
        assert config.label == "degraded+" and "lidar.channels" in config.overridden
        assert pilot.given is not None and pilot.given.sensing == config and given.sensing is scenario
        scans = [scan for o in pilot.seen for scan in o.sensors.lidar]
        assert scans and max(len(scan.ranges_m) for scan in scans) <= 8 * 36
    assert learned_lidar(learned_lidar(preset)) == learned_lidar(preset)  # applied twice: the same
    assert learned_lidar(sensing_preset("perfect", mass)) == sensing_preset("perfect", mass)


class _Straight:
    """A pilot without `sensing_flown`: it flies at the goal and keeps what it is given."""

    name = "straight"

    def __init__(self) -> None:
        self.world: World | None = None
        self.seen: list[Observation] = []
        self.task: Task | None = None

    def reset(self, world: World, task: Task, seed: int) -> ResetInfo:
        self.world, self.task = world, task
        return ResetInfo(True)

    def act(self, obs: Observation) -> VelocityCommand:
        self.seen.append(obs)
        assert self.task is not None
        return VelocityCommand(0.2 * (np.asarray(self.task.goal_m) - obs.x[0:3]))

    def episode_report(self) -> None:
        return None


def test_a_pilot_without_the_hook_flies_with_the_scenarios_sensors(world, monkeypatch):
    built: list[SensingConfig] = []
    real = onboard_module.Onboard

    def spied(config: SensingConfig, *args, **kwargs):
        built.append(config)
        return real(config, *args, **kwargs)

    monkeypatch.setattr(onboard_module, "Onboard", spied)
    scenario = sensing_preset("nominal", world.vehicle.mass_kg)
    city = world.cities[0]
    b = NavBatch(world, 1)
    b.seed([3])
    b.reset_slots([0])
    given = World(world.vehicle, world.dynamics, city, b.atmosphere(0), b.turbulence(0), sensing=scenario)
    pilot = _Straight()
    assert flown_sensing(pilot, scenario) is scenario
    run_episode(given, pilot, replace(b.task(0), timeout_s=0.5), b.wind_field(0), 0, truth=Truth(city, scenario, 5))
    assert built == [scenario] and pilot.world is given  # the scenario's sensors, the world unchanged
    scans = [s for o in pilot.seen for s in o.sensors.lidar]
    assert scans and all(len(s.ranges_m) <= scenario.lidar.rays_per_scan for s in scans)
    assert max(len(s.ranges_m) for s in scans) > 288  # the full part's scans, not the learned pilot's


def test_a_pilot_stating_other_sensors_than_the_levels_is_refused(world):
    class Wrong(_Straight):
        def sensing_flown(self, scenario: SensingConfig) -> SensingConfig:
            return sensing_preset("degraded", 1.0)

    scenario = sensing_preset("nominal", world.vehicle.mass_kg)
    city = world.cities[0]
    given = World(world.vehicle, world.dynamics, city, world.atmospheres[0], sensing=scenario)
    b = NavBatch(world, 1)
    b.seed([3])
    b.reset_slots([0])
    with pytest.raises(PilotError, match="pilot 'straight': sensing_flown gave .* the scenario's level 'nominal'"):
        run_episode(given, Wrong(), b.task(0), b.wind_field(0), 0, truth=Truth(city, scenario, 5))
