"""N vehicles navigating cities, stepped together: the engine under `UAMNavEnv` and `UAMNavVecEnv`.

Each of the N slots is an independent episode with its own random generator, so slot i of a batch
seeded with s behaves exactly like a single environment seeded with s + i (tested). A step is one
control period: actions -> velocity commands -> one batched call into the compiled model (the
low-level controller and 10 RK4 physics substeps for every vehicle) -> collision, bounds and goal
checks -> sensing -> observations and rewards.

Collision is checked at every physics substep: the clearance field is 1-Lipschitz, so a vehicle
whose clearance at the start of the period exceeds its largest displacement within the period
cannot have touched anything; only the others are measured substep by substep (exactly, with the
sensor's box distances). The outcome of a step follows the comparison runner's order: non-finite
state, collision, out of bounds, arrival, then the time limit.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from rl.cities import EVAL_SEEDS, TRAIN_SEEDS, CityDistribution, TaskDistribution
from rl.observation import action_to_command, build_observations, obs_size
from rl.reward import TERMS, RewardConfig, reward_terms
from rl.sensor import BoxSensor
from uam_fdm.agent import Task
from uam_fdm.atmosphere import Atmosphere, AtmosphereConditions
from uam_fdm.city import BuildingMap
from uam_fdm.dynamics import VehicleDynamics
from uam_fdm.model import hover_state
from uam_fdm.params import VehicleParams, load_vehicle
from uam_fdm.wind import GustSeries, TurbulenceLevel, WindConditions, WindField, gust_series

OUTCOMES = ("success", "collision", "out_of_bounds", "nonfinite", "timeout")


@dataclass(frozen=True)
class NavConfig:
    """Everything that defines the navigation task (all defaults are the shipped policy's).

    Attributes:
        vehicle: preset name or vehicle YAML path.
        physics_hz, control_hz: physics and decision rates [Hz].
        k_buildings: buildings in the observation.
        sensing_range_m: range of the building sensing [m].
        city_split: "train" or "eval": which seed range the city pool comes from.
        city_pool_size: number of cities in the pool; city_pool_offset: first seed within the range.
        cities: city generator parameter ranges; tasks: start/goal distribution.
        turbulence: turbulence level (none/light/moderate/severe).
        steady_wind_max_m_s: steady horizontal wind speed drawn uniformly in [0, this] [m/s].
        wind_pool_size: turbulence series shared by all episodes (each episode starts at a random
            sample of one); wind_series_s: length of each [s].
        reward: reward weights.
    """

    vehicle: str = "small_quad"
    physics_hz: float = 500.0
    control_hz: float = 50.0
    k_buildings: int = 5
    sensing_range_m: float = 30.0
    city_split: str = "train"
    city_pool_size: int = 128
    city_pool_offset: int = 0
    cities: CityDistribution = field(default_factory=CityDistribution)
    tasks: TaskDistribution = field(default_factory=TaskDistribution)
    turbulence: str = "light"
    steady_wind_max_m_s: float = 3.0
    wind_pool_size: int = 16
    wind_series_s: float = 400.0
    reward: RewardConfig = field(default_factory=RewardConfig)

    def __post_init__(self) -> None:
        if self.city_split not in ("train", "eval"):
            raise ValueError(f"city_split must be 'train' or 'eval', got {self.city_split!r}")
        TurbulenceLevel.parse(self.turbulence)
        if self.k_buildings < 1 or self.sensing_range_m <= 0 or self.city_pool_size < 1 or self.wind_pool_size < 1:
            raise ValueError("k_buildings, sensing_range_m, city_pool_size and wind_pool_size must be positive")

    def city_seeds(self) -> list[int]:
        """The pool's city seeds."""
        rng = TRAIN_SEEDS if self.city_split == "train" else EVAL_SEEDS
        seeds = list(rng[self.city_pool_offset: self.city_pool_offset + self.city_pool_size])
        if len(seeds) < self.city_pool_size:
            raise ValueError(f"city pool {self.city_pool_offset}+{self.city_pool_size} exceeds the {self.city_split} range")
        return seeds

    def to_dict(self) -> dict:
        """Plain-data form (for the policy's config file)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> NavConfig:
        d = dict(d)
        d["cities"] = CityDistribution(**{k: tuple(v) if isinstance(v, list) else v for k, v in d["cities"].items()})
        d["tasks"] = TaskDistribution(**{k: tuple(v) if isinstance(v, list) else v for k, v in d["tasks"].items()})
        d["reward"] = RewardConfig(**d["reward"])
        return cls(**d)


@dataclass(frozen=True)
class FixedEpisodes:
    """Episodes from a scenario instead of sampled ones: cities and (city index, task) pairs, cycled."""

    cities: tuple[BuildingMap, ...]
    tasks: tuple[tuple[int, Task], ...]


class NavWorld:
    """What the slots share (built once): vehicle, compiled dynamics, atmosphere, cities, sensor, wind pool."""

    def __init__(self, config: NavConfig, fixed: FixedEpisodes | None = None,
                 dynamics: VehicleDynamics | None = None, atmosphere: Atmosphere | None = None) -> None:
        self.config = config
        self.vehicle: VehicleParams = dynamics.params if dynamics is not None else load_vehicle(config.vehicle)
        self.dynamics = dynamics or VehicleDynamics(self.vehicle, config.physics_hz, config.control_hz)
        self.atmosphere = atmosphere or Atmosphere.from_jsbsim(AtmosphereConditions(0.0, 0.0), z_max_m=400.0)
        self.fixed = fixed
        if fixed is not None:
            self.cities = list(fixed.cities)
        else:
            self.cities = [config.cities.city(s) for s in config.city_seeds()]
        self.sensor = BoxSensor(self.cities, config.k_buildings, config.sensing_range_m,
                                self.vehicle.collision_radius_m)
        self.lo = np.array([c.bounds_min_m for c in self.cities])
        self.hi = np.array([c.bounds_max_m for c in self.cities])
        level = TurbulenceLevel.parse(config.turbulence)
        self.turbulent = level is not TurbulenceLevel.NONE
        if self.turbulent:
            cond = WindConditions((0.0, 0.0, 0.0), level)
            series = [gust_series(cond, 7919 * (j + 1), config.wind_series_s, 20.0,
                                  self.vehicle.controller.max_speed_m_s) for j in range(config.wind_pool_size)]
            self.gusts = np.stack([s.gust_enu_m_s for s in series])
            self.gust_dt = series[0].dt_s
            self.gust_series = series
        else:
            self.gusts = np.zeros((1, 2, 3))
            self.gust_dt = math.inf
            self.gust_series = []
        self.obs_size = obs_size(config.k_buildings)


class NavBatch:
    """N navigation episodes stepped together (see the module docstring).

    Args:
        world: the shared world.
        n: number of slots.
    """

    def __init__(self, world: NavWorld, n: int) -> None:
        self.world, self.n = world, int(n)
        p = world.vehicle
        nx = world.dynamics.layout.nx
        self.x = np.zeros((n, nx))
        self.xi = np.zeros((n, 3))
        self.t = np.zeros(n)
        self.city = np.zeros(n, dtype=np.int64)
        self.goal = np.zeros((n, 3))
        self.start = np.zeros((n, 3))
        self.goal_radius = np.ones(n)
        self.timeout = np.ones(n)
        self.yaw = np.zeros(n)
        self.steady = np.zeros((n, 3))
        self.gust_idx = np.zeros(n, dtype=np.int64)
        self.gust_k0 = np.zeros(n, dtype=np.int64)
        self.dist = np.zeros(n)
        self.clear = np.zeros(n)
        self.episode_return = np.zeros(n)
        self.episode_len = np.zeros(n, dtype=np.int64)
        self.episode_count = np.zeros(n, dtype=np.int64)
        self.rngs: list[np.random.Generator] = [np.random.Generator(np.random.PCG64(i)) for i in range(n)]
        self._obs = np.zeros((n, world.obs_size), dtype=np.float32)
        self._radius = p.collision_radius_m
        self.lo = np.zeros((n, 3))
        self.hi = np.zeros((n, 3))
        self._period = 1.0 / world.dynamics.control_hz
        self.city_of_slot: np.ndarray | None = None  # evaluation: slot i always flies in city city_of_slot[i]

    # -- episodes ----------------------------------------------------------------------------------
    def seed(self, seeds: Sequence[int]) -> None:
        """Re-seed every slot's generator (slot i <- seeds[i])."""
        self.rngs = [np.random.Generator(np.random.PCG64(int(s))) for s in seeds]
        self.episode_count[:] = 0

    def reset_slots(self, idx: Sequence[int]) -> None:
        """Start a new episode in each slot of `idx` (drawn from the slot's own generator)."""
        w, cfg = self.world, self.world.config
        p = w.vehicle
        for i in idx:
            rng = self.rngs[i]
            if w.fixed is not None:
                ci, task = w.fixed.tasks[int(self.episode_count[i] + i) % len(w.fixed.tasks)]
            else:
                ci = int(rng.integers(len(w.cities)))
                if self.city_of_slot is not None:
                    ci = int(self.city_of_slot[i])
                task = cfg.tasks.sample(w.cities[ci], rng, p.collision_radius_m, p.controller.max_speed_m_s)
            speed = rng.uniform(0.0, cfg.steady_wind_max_m_s)
            heading = rng.uniform(-math.pi, math.pi)
            self.steady[i] = (speed * math.cos(heading), speed * math.sin(heading), 0.0)
            self.gust_idx[i] = int(rng.integers(w.gusts.shape[0]))
            if w.turbulent:
                span = w.gusts.shape[1] - 2 - math.ceil((task.timeout_s + 1.0) / w.gust_dt)
                if span < 1:
                    raise ValueError(f"wind_series_s {cfg.wind_series_s} s is too short for a {task.timeout_s} s episode")
                self.gust_k0[i] = int(rng.integers(span))
            self.city[i] = ci
            self.lo[i], self.hi[i] = w.lo[ci], w.hi[ci]
            self.start[i], self.goal[i] = task.start_m, task.goal_m
            self.goal_radius[i], self.timeout[i], self.yaw[i] = task.goal_radius_m, task.timeout_s, task.start_yaw_rad
            self.x[i] = hover_state(p, task.start_m, task.start_yaw_rad,
                                    density_ratio=w.atmosphere.density_ratio(task.start_m[2]))
            self.xi[i] = 0.0
            self.t[i] = 0.0
            self.dist[i] = float(np.linalg.norm(self.goal[i] - self.start[i]))
            self.episode_return[i] = 0.0
            self.episode_len[i] = 0
            self.episode_count[i] += 1
        idx = np.asarray(idx, dtype=np.int64)
        if len(idx):
            self._sense(idx)

    def task(self, i: int) -> Task:
        """Slot i's current task."""
        return Task(tuple(self.start[i]), tuple(self.goal[i]), float(self.goal_radius[i]), float(self.timeout[i]),
                    float(self.yaw[i]))

    def wind_field(self, i: int) -> WindField:
        """Slot i's wind as a `WindField` (the same numbers the batch uses), for flying the episode elsewhere."""
        w = self.world
        if not w.turbulent:
            return WindField(self.steady[i])
        s = w.gust_series[int(self.gust_idx[i])]
        k0 = int(self.gust_k0[i])
        g = GustSeries(s.t_s[: len(s.t_s) - k0], s.gust_enu_m_s[k0:], s.dt_s, s.turbulence, s.seed,
                       s.airspeed_m_s, s.height_agl_m)
        return WindField(self.steady[i], g)

    @property
    def observations(self) -> np.ndarray:
        return self._obs

    # -- stepping ----------------------------------------------------------------------------------
    def _wind(self, t_mid: np.ndarray) -> np.ndarray:
        w = self.world
        if not w.turbulent:
            return self.steady.copy()
        # Same arithmetic as WindField.wind_enu_m_s on the series started at sample k0.
        s = t_mid / w.gust_dt
        i = s.astype(np.int64)
        f = (s - i)[:, None]
        row = self.gust_k0 + i
        lo = w.gusts[self.gust_idx, row] + self.steady
        hi = w.gusts[self.gust_idx, row + 1] + self.steady
        return lo + f * (hi - lo)

    def _sense(self, idx: np.ndarray) -> None:
        w = self.world
        r = w.sensor.query(self.x[idx, 0:3], self.city[idx])
        self.clear[idx] = r.clearance_m
        self._obs[idx] = build_observations(
            self.x[idx], self.goal[idx], self.lo[idx], self.hi[idx], r.nearest_m, r.distance_m,
            w.config.sensing_range_m, w.vehicle.controller.max_speed_m_s)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        """Advance every slot one decision period.

        Returns:
            observations (N, obs) after the step (before any reset), rewards (N,), terminated (N,),
            truncated (N,), infos (per slot: `reward_terms`, `outcome` when the episode ended,
            `clearance_m`, `distance_to_goal_m`, `t_s`).
        """
        w = self.world
        dyn, p = w.dynamics, w.vehicle
        cmd = action_to_command(actions, p, self.yaw)
        env = np.empty((self.n, 4))
        env[:, 0:3] = self._wind(self.t + 0.5 * self._period)
        if self.n == 1:  # the scalar lookup (same arithmetic) is much cheaper for one vehicle
            env[0, 3] = w.atmosphere.density_ratio_clamped(float(self.x[0, 2]))
        else:
            env[:, 3] = w.atmosphere.density_ratio_clamped(self.x[:, 2])
        r = dyn.period_velocity_batch(self.x, self.xi, cmd, env)
        states = r.states  # (N, nsub, nx)
        pos = states[:, :, 0:3]
        finite = np.isfinite(states).all(axis=(1, 2))
        all_finite = bool(finite.all())
        # Collision at every substep: skip vehicles that provably cannot have reached an obstacle.
        rel = pos - self.x[:, None, 0:3]
        disp = np.sqrt(np.einsum("nki,nki->nk", rel, rel).max(axis=1))
        if not all_finite:
            disp = np.where(finite, disp, 0.0)
        near = np.flatnonzero(finite & (self.clear - disp <= 0.0))
        collided = np.zeros(self.n, dtype=bool)
        if len(near):
            nsub = pos.shape[1]
            c = w.sensor.clearance(pos[near].reshape(-1, 3), np.repeat(self.city[near], nsub))
            collided[near] = np.any(c.reshape(len(near), nsub) < 0.0, axis=1)
        inside = ((pos >= self.lo[:, None, :]) & (pos <= self.hi[:, None, :])).all(axis=(1, 2))
        self.t = self.t + self._period
        if all_finite:
            self.x, self.xi = r.final_state, r.ctrl_state
        else:
            self.x = np.where(finite[:, None], r.final_state, self.x)
            self.xi = np.where(finite[:, None], r.ctrl_state, self.xi)
        nonfinite = ~finite
        collision = finite & collided
        out = finite & ~collided & ~inside
        g = self.x[:, 0:3] - self.goal
        d_after = np.sqrt(np.add.reduce(g * g, axis=1))
        arrived = finite & ~collided & inside & (d_after <= self.goal_radius)
        self._sense(np.arange(self.n))
        crashed = nonfinite | collision | out
        terms = reward_terms(w.config.reward, self.dist, d_after, self.clear, arrived, crashed)
        terms["progress"] = np.where(finite, terms["progress"], 0.0)
        reward = sum(terms[k] for k in TERMS)
        self.dist = d_after
        terminated = crashed | arrived
        truncated = ~terminated & (self.t >= self.timeout - 1e-9)
        self.episode_return += reward
        self.episode_len += 1
        infos = []
        for i in range(self.n):
            info = {"reward_terms": {k: float(terms[k][i]) for k in TERMS}, "clearance_m": float(self.clear[i]),
                    "distance_to_goal_m": float(d_after[i]), "t_s": float(self.t[i])}
            if terminated[i] or truncated[i]:
                info["outcome"] = ("nonfinite" if nonfinite[i] else "collision" if collision[i] else
                                   "out_of_bounds" if out[i] else "success" if arrived[i] else "timeout")
                info["is_success"] = bool(arrived[i])
                info["city"] = w.cities[int(self.city[i])].name
            infos.append(info)
        return self._obs.copy(), reward.astype(np.float32), terminated, truncated, infos

