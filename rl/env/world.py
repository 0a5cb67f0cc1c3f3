"""N vehicles navigating cities, stepped together: the engine under `UAMNavEnv` and `UAMNavVecEnv`.

Each of the N slots is an independent episode with its own random generator, so slot i of a batch
seeded with s behaves exactly like a single environment seeded with s + i (tested).

A step is one **decision** (10 Hz by default): the action becomes a velocity command that is held
for `control_hz / decision_hz` control periods; each control period is one batched call into the
compiled model through `uam_fdm.sim.BatchSimulator` (the low-level controller and the RK4 physics
substeps for every vehicle), followed by the episode rules of `uam_fdm.episode` (the comparison
runner's own): collision at every physics substep, bounds, arrival, then the time limit. A vehicle
whose episode ends inside a decision stops there; the others fly the rest of the decision. The
learned pilot in the runner (`rl.pilots.learned.PolicyPilot`) holds its command the same way, so an episode
flown through the env and through the runner is bit-identical (tested).

Collision at every substep is exact and cheap: the clearance field is 1-Lipschitz, so a vehicle
whose clearance at the start of a period exceeds its largest displacement within the period
cannot have touched anything; only the others are measured substep by substep. Within a decision
the clearance is carried as that lower bound (clearance minus displacement) and measured exactly
once per decision, for the observation and the reward.

Map error (`NavConfig.map_error`, `rl.sensing.truth`): each episode draws a level and a draw of its city's bank;
it collides with and senses the draw's truth (`NavBatch.geometry`: the truth's index in the world's sensing) and
follows a route field drawn from its prior. At the `exact` level alone nothing is drawn and every number is as
before the setting existed (tested).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from rl.sensing.observation import (
    TURBULENCE_VALUE,
    PilotMemory,
    Surroundings,
    action_to_command,
    goal_heading,
    obs_size,
)
from rl.sensing.perception import Perception
from rl.sensing.route import RouteBank, flight_levels, grid_shape, max_levels
from rl.sensing.senses import clearance_sensor, nearest_surface, observe_slots, route_for
from rl.sensing.sensor import BoxSensor
from rl.sensing.truth import MapDraw, MapErrorBank, TruthSensing
from rl.task.config import FixedEpisodes, NavConfig
from rl.task.reward import TERMS, reward_terms, stopping_distance
from uam_fdm import episode
from uam_fdm.air.atmosphere import Atmosphere, AtmosphereBank
from uam_fdm.air.wind import (
    GustStack,
    TurbulenceLevel,
    WindBank,
    WindConditions,
    WindField,
    gust_stack,
    probe_heights_up_to,
    turbulence_airspeed_m_s,
)
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.pilot import Task
from uam_fdm.sim import BatchSimulator
from uam_fdm.vehicle.dynamics import VehicleDynamics
from uam_fdm.vehicle.ground_effect import height_above_surface
from uam_fdm.vehicle.ground_effect import range_m as ground_effect_range_m
from uam_fdm.vehicle.model import hover_state
from uam_fdm.vehicle.params import GRAVITY_M_S2, VehicleParams, load_vehicle


@dataclass(frozen=True)
class SlotAir:
    """The air of one episode in a slot (indices into its world's pools).

    Attributes:
        wind_m_s: steady wind (east, north, up) [m/s].
        series: the turbulence series, an index of `NavWorld.gust_stacks` (0 when the world has no turbulence).
        start: the series' first sample for this episode.
        level: the turbulence level, an index of `NavWorld.levels`.
        field: the atmosphere, an index of `NavWorld.atmospheres`.
    """

    wind_m_s: tuple[float, float, float]
    series: int
    start: int
    level: int
    field: int


class NavWorld:
    """What the slots share (built once): vehicle, compiled dynamics, atmosphere, cities, sensors, wind pool."""

    def __init__(self, config: NavConfig, fixed: FixedEpisodes | None = None,
                 dynamics: VehicleDynamics | None = None, atmosphere: Atmosphere | Sequence[Atmosphere] | None = None,
                 wind_from: NavWorld | None = None, geometry_from: NavWorld | None = None) -> None:
        """`atmosphere`: the one atmosphere every episode flies (e.g. a scenario's), or the pool of fields
        (e.g. another world's `atmospheres`, shared instead of tabulated again); None: the pool of
        `config.air.fields()`. `wind_from`: a world whose turbulence stacks this one would generate too
        (same level, seed, series length, probe heights and airspeed; checked stack by stack), e.g. the
        training world for its validation world: those are shared instead of generated again.
        `geometry_from`: a world of the same cities, sensing and vehicle size (e.g. a policy's evaluation world,
        for another pilot flying its tasks at another decision rate): its cities, clearance sensor and
        perception are shared instead of built again (a 1,000-city UAM world holds about 6 GB of them), and so is
        its map-error bank and the truth's sensing.

        Fixed episodes fly their cities as they stand (the `exact` level: a scenario's map error is the runner's).

        Raises:
            ValueError: `geometry_from` has other cities, sensing or vehicle size (naming what differs).
        """
        self.config = config
        self.vehicle: VehicleParams = dynamics.params if dynamics is not None else load_vehicle(config.vehicle)
        self.dynamics = dynamics or VehicleDynamics(self.vehicle, config.physics_hz, config.control_hz)
        if abs(self.dynamics.control_hz - config.control_hz) > 1e-9:
            raise ValueError(f"dynamics run at {self.dynamics.control_hz} Hz control, the task at {config.control_hz}")
        if atmosphere is None:
            self.atmospheres = [Atmosphere.from_jsbsim(c, z_max_m=400.0) for c in config.air.fields()]
        else:
            self.atmospheres = [atmosphere] if isinstance(atmosphere, Atmosphere) else list(atmosphere)
        self.fixed = fixed
        radius = self.vehicle.collision_radius_m
        if geometry_from is not None:
            _check_same_geometry(self, geometry_from)
            self.cities: list[BuildingMap] = geometry_from.cities
            self.clearance_sensor: BoxSensor = geometry_from.clearance_sensor
            self.perception: Perception = geometry_from.perception
            self.maps: MapErrorBank = geometry_from.maps
            self.truth: TruthSensing | None = geometry_from.truth
        else:
            seeds = list(range(len(fixed.cities))) if fixed is not None else config.city_seeds()
            self.cities = list(fixed.cities) if fixed is not None else [config.cities.city(s) for s in seeds]
            self.clearance_sensor = clearance_sensor(self.cities, config.scales, radius)
            self.perception = Perception(self.cities, radius, config.perception)
            levels = ("exact",) if fixed is not None else config.map_error
            self.maps = MapErrorBank(self.cities, seeds, levels, config.map_error_draws)
            # the truths' sensing: None when every truth is its city as it stands (the cities' sensors alone)
            self.truth = TruthSensing(self.clearance_sensor, self.perception, self.maps.added, config.scales, radius,
                                      config.perception) if self.maps.added else None
        self.lo = np.array([c.bounds_min_m for c in self.cities])
        self.hi = np.array([c.bounds_max_m for c in self.cities])
        shapes = np.array([grid_shape(c, config.route.cell_m) for c in self.cities])
        self.route_cells = (int(shapes[:, 0].max()), int(shapes[:, 1].max()))  # the largest city's route grid
        self.route_levels = route_levels(config, fixed)
        self.levels = config.air.levels
        self.turbulent = any(level is not TurbulenceLevel.NONE for level in self.levels)
        self.gust_stacks: list[GustStack] = []
        self.level_stacks: list[list[int]] = []  # per turbulence level: its stacks' indices in gust_stacks
        if self.turbulent:
            self._make_gust_stacks(wind_from)
        self.obs_size = obs_size(config.perception, config.observe)

    @property
    def atmosphere(self) -> Atmosphere:
        """The one atmosphere of a world that flies a single field.

        Raises:
            ValueError: the world flies a pool of fields (each episode's is `NavBatch.atmosphere(i)`).
        """
        if len(self.atmospheres) != 1:
            raise ValueError(f"this world flies {len(self.atmospheres)} fields; an episode's is NavBatch.atmosphere(i)")
        return self.atmospheres[0]

    def _make_gust_stacks(self, wind_from: NavWorld | None) -> None:
        """The turbulence stacks: `wind_pool_size` per turbulent level (one zero stack for none), each at its
        own seed, shared with `wind_from` where it holds the same stack."""
        config = self.config
        heights = probe_heights_up_to(float(self.hi[:, 2].max()))
        # one airspeed for the pool: every episode's steady wind is at most steady_wind_max_m_s
        airspeed = turbulence_airspeed_m_s(self.vehicle.controller.max_speed_m_s, config.air.steady_wind_max_m_s)
        wanted: list[tuple[TurbulenceLevel, int]] = []
        for k, level in enumerate(self.levels):
            n = 1 if level is TurbulenceLevel.NONE else config.wind_pool_size
            self.level_stacks.append(list(range(len(wanted), len(wanted) + n)))
            wanted += [(level, 7919 * (j + 1) + 104_729 * k) for j in range(n)]  # level 0: the earlier seeds
        donor = {}
        if wind_from is not None and wind_from.config.wind_series_s == config.wind_series_s:
            donor = {(g.turbulence, g.seed): g for g in wind_from.gust_stacks
                     if g.heights_m == heights and g.airspeed_m_s == airspeed}
        self.gust_stacks = [donor.get((level, seed)) or gust_stack(WindConditions((0.0, 0.0, 0.0), level), seed,
                                                                   config.wind_series_s, airspeed, heights)
                            for level, seed in wanted]


class NavBatch:
    """N navigation episodes stepped together (see the module docstring).

    Args:
        world: the shared world.
        n: number of slots.
    """

    def __init__(self, world: NavWorld, n: int) -> None:
        self.world, self.n = world, int(n)
        cfg = world.config
        nx = world.dynamics.layout.nx
        self.x = np.zeros((n, nx))
        self.xi = np.zeros((n, 3))
        self.t = np.zeros(n)
        self.city = np.zeros(n, dtype=np.int64)
        self.geometry = np.zeros(n, dtype=np.int64)  # each slot's truth: an index of the world's truth sensing
        self.map_level = np.zeros(n, dtype=np.int64)  # each slot's map-error level: an index of world.maps.levels
        self.map_draw = np.zeros(n, dtype=np.int64)  # and its draw
        self._truth_maps: list[BuildingMap] = [world.cities[0]] * n  # each slot's truth (ground effect)
        # the truths' sensing, by geometry index (the cities' own sensors when no truth adds to its city)
        self._sensor: BoxSensor | TruthSensing = world.truth or world.clearance_sensor
        self._perception: Perception | TruthSensing = world.truth or world.perception
        self.goal = np.zeros((n, 3))
        self.start = np.zeros((n, 3))
        self.goal_radius = np.ones(n)
        self.timeout = np.ones(n)
        self.yaw = np.zeros(n)
        self.route_m = np.zeros(n)
        self.clear = np.zeros(n)
        self.nearest = np.zeros((n, 3))
        self.episode_return = np.zeros(n)
        self.episode_len = np.zeros(n, dtype=np.int64)
        self.episode_count = np.zeros(n, dtype=np.int64)
        self.rngs: list[np.random.Generator] = [np.random.Generator(np.random.PCG64(i)) for i in range(n)]
        self.winds = WindBank(world.gust_stacks, n)
        # each slot in its own field when the world has several (the same numbers as its Atmosphere's)
        pool = world.atmospheres
        self.atmospheres: Atmosphere | AtmosphereBank = AtmosphereBank(pool, n) if len(pool) > 1 else pool[0]
        self.air = np.zeros(n, dtype=np.int64)  # each slot's field: an index of world.atmospheres
        self.level = np.zeros(n, dtype=np.int64)  # each slot's turbulence level: an index of world.levels
        self.sim = BatchSimulator(world.dynamics, self.atmospheres, self.winds)
        self.routes = RouteBank(n, world.route_cells, cfg.route.climb_weight, world.route_levels)
        self.memory = PilotMemory.empty(n, cfg.decision_hz, cfg.observe.history)
        self._obs = np.zeros((n, world.obs_size), dtype=np.float32)
        self._radius = world.vehicle.collision_radius_m
        self._ground_effect_range_m = ground_effect_range_m(world.vehicle) if world.vehicle.ground_effect else -np.inf
        self.lo = np.zeros((n, 3))
        self.hi = np.zeros((n, 3))
        self._period = 1.0 / world.dynamics.control_hz
        self.city_of_slot: np.ndarray | None = None  # evaluation: slot i always flies in city city_of_slot[i]
        self.difficulty = 1.0  # the training curriculum's task difficulty (see TaskDistribution.sample)
        # called after every control period with the slots that flew it (a recorder of flights at control rate)
        self.on_period: Callable[[np.ndarray], None] | None = None

    # -- episodes ----------------------------------------------------------------------------------
    def seed(self, seeds: Sequence[int]) -> None:
        """Re-seed every slot's generator (slot i <- seeds[i])."""
        self.rngs = [np.random.Generator(np.random.PCG64(int(s))) for s in seeds]
        self.episode_count[:] = 0

    def reset_slots(self, idx: Sequence[int] | np.ndarray) -> None:
        """Start a new episode in each slot of `idx` (drawn from the slot's own generator)."""
        w, cfg = self.world, self.world.config
        p = w.vehicle
        for i in idx:
            rng = self.rngs[i]
            if w.fixed is not None:
                ci, task = w.fixed.tasks[int(self.episode_count[i] + i) % len(w.fixed.tasks)]
                draw = w.maps.exact(ci)
            else:
                ci = int(rng.integers(len(w.cities)))
                if self.city_of_slot is not None:
                    ci = int(self.city_of_slot[i])
                draw = self._draw_map(rng, ci)
                task = cfg.tasks.sample(draw.truth, rng, p.collision_radius_m, p.controller.max_speed_m_s,
                                        difficulty=self.difficulty,
                                        max_vertical_speed_m_s=p.controller.max_vertical_speed_m_s, also=draw.prior)
            self._place(int(i), ci, task, self._draw_air(rng, task), draw)
        self._begin(np.asarray(idx, dtype=np.int64))

    def place(self, episodes: Sequence[tuple[int, int, Task, SlotAir]],
              maps: Sequence[MapDraw] | None = None) -> None:
        """Start the given episodes: (slot, city index, task, its air) each, drawing nothing from any
        generator (e.g. a fixed set of tasks flown again and again, `rl.training.recording`).

        `maps`: each episode's map (`world.maps.draw`); None: every city as it stands (the exact level)."""
        for k, (i, ci, task, air) in enumerate(episodes):
            self._place(int(i), int(ci), task, air, self.world.maps.exact(int(ci)) if maps is None else maps[k])
        self._begin(np.array([e[0] for e in episodes], dtype=np.int64))

    def _draw_map(self, rng: np.random.Generator, ci: int) -> MapDraw:
        """A slot's map in city ci drawn from its generator: a map-error level, then a draw of it.

        Draws only where there is a choice, so a task of one level with one draw (exact) draws as it always did."""
        maps = self.world.maps
        level = int(rng.integers(len(maps.levels))) if len(maps.levels) > 1 else 0
        n = maps.draws_of(level)
        return maps.draw(ci, level, int(rng.integers(n)) if n > 1 else 0)

    def _draw_air(self, rng: np.random.Generator, task: Task) -> SlotAir:
        """A slot's air for `task` drawn from its generator: steady wind, turbulence level and series, field.

        Draws only where there is a choice, so a task of one field and one level draws as it always did."""
        w, cfg = self.world, self.world.config
        speed = rng.uniform(0.0, cfg.air.steady_wind_max_m_s)
        heading = rng.uniform(-np.pi, np.pi)
        level = int(rng.integers(len(w.levels))) if len(w.levels) > 1 else 0
        stacks = w.level_stacks[level] if w.turbulent else []
        series = stacks[int(rng.integers(len(stacks)))] if stacks else int(rng.integers(1))
        start = 0
        if w.turbulent:
            start = int(rng.integers(self.wind_start_span(task)))
        field = int(rng.integers(len(w.atmospheres))) if len(w.atmospheres) > 1 else 0
        return SlotAir((float(speed * np.cos(heading)), float(speed * np.sin(heading)), 0.0), series, start, level,
                       field)

    def wind_start_span(self, task: Task) -> int:
        """How many starting samples of a turbulence series leave room for `task`'s whole episode.

        Raises:
            ValueError: the series is too short for the task's time limit.
        """
        span = self.winds.samples - 2 - int(np.ceil((task.timeout_s + 1.0) / self.winds.dt_s))
        if span < 1:
            raise ValueError(f"wind_series_s {self.world.config.wind_series_s} s is too short for a "
                             f"{task.timeout_s} s episode")
        return span

    def _place(self, i: int, ci: int, task: Task, air: SlotAir, draw: MapDraw) -> None:
        """Slot i's state at the start of `task` in city `ci`, map `draw` and air `air` (`_begin` completes it)."""
        w, cfg = self.world, self.world.config
        p = w.vehicle
        self.winds.assign(i, air.wind_m_s, air.series, air.start)
        self.air[i], self.level[i] = air.field, air.level
        if isinstance(self.atmospheres, AtmosphereBank):
            self.atmospheres.assign(i, air.field)
        self.city[i] = ci
        self.geometry[i], self.map_level[i], self.map_draw[i] = draw.geometry, draw.level, draw.draw
        self._truth_maps[i] = draw.truth
        self.lo[i], self.hi[i] = w.lo[ci], w.hi[ci]
        self.start[i], self.goal[i] = task.start_m, task.goal_m
        self.goal_radius[i], self.timeout[i], self.yaw[i] = task.goal_radius_m, task.timeout_s, task.start_yaw_rad
        self.x[i] = hover_state(p, task.start_m, task.start_yaw_rad,
                                density_ratio=w.atmospheres[air.field].density_ratio(task.start_m[2]))
        self.xi[i] = 0.0
        self.t[i] = 0.0
        self.routes.set(i, route_for(draw.prior, task, p.collision_radius_m, cfg.route))
        self.episode_return[i] = 0.0
        self.episode_len[i] = 0
        self.episode_count[i] += 1

    def _begin(self, idx: np.ndarray) -> None:
        """The first sensing and observation of slots idx, just placed."""
        if len(idx):
            pos = self.x[idx, 0:3]
            self.route_m[idx] = self.routes.potential(pos, idx)
            self.clear[idx], self.nearest[idx] = nearest_surface(self._sensor, pos, self.geometry[idx])
            self.memory.start(idx, pos, self.goal[idx], self.route_m[idx])
            self._observe(idx)

    def task(self, i: int) -> Task:
        """Slot i's current task."""
        return Task(tuple(self.start[i]), tuple(self.goal[i]), float(self.goal_radius[i]), float(self.timeout[i]),
                    float(self.yaw[i]))

    def wind_field(self, i: int) -> WindField:
        """Slot i's wind as a `WindField` (the same numbers the batch uses), for flying the episode elsewhere."""
        return self.winds.field(i)

    def atmosphere(self, i: int) -> Atmosphere:
        """Slot i's atmosphere (the same numbers the batch uses), for flying the episode elsewhere."""
        return self.world.atmospheres[int(self.air[i])]

    def turbulence(self, i: int) -> TurbulenceLevel:
        """Slot i's turbulence level (its forecast, as a scenario states it)."""
        return self.world.levels[int(self.level[i])]

    @property
    def observations(self) -> np.ndarray:
        return self._obs

    # -- stepping ----------------------------------------------------------------------------------
    def _observe(self, idx: np.ndarray) -> None:
        """Recompute the observations of slots idx from their current state and memory."""
        w = self.world
        cfg = w.config
        self._obs[idx] = observe_slots(idx, self.x[idx], self.goal[idx], self.route_m[idx], self.clear[idx],
                                       self.nearest[idx], self.t[idx] / self.timeout[idx], self.geometry[idx],
                                       self._perception,
                                       self.routes, self.memory, cfg.perception, cfg.scales, cfg.decision_hz, w.vehicle,
                                       cfg.observe, self._surroundings(idx) if cfg.observe.size() else None)

    def _surroundings(self, idx: np.ndarray) -> Surroundings:
        """What the pilot interface tells slots idx about their air and flight volume."""
        z = self.x[idx, 2]
        a = self.atmospheres
        sigma = a.density_ratio_clamped(z, idx) if isinstance(a, AtmosphereBank) else a.density_ratio_clamped(z)
        turbulence = np.array([TURBULENCE_VALUE[self.world.levels[k]] for k in self.level[idx]])
        return Surroundings(np.asarray(sigma, dtype=float), turbulence, self.lo[idx], self.hi[idx])

    def _collided(self, idx: np.ndarray, sel, states: np.ndarray, finite: np.ndarray,
                  clear_lb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Collision at any substep of slots idx, and a lower bound of their clearance after the period.

        Args:
            idx: (M,) the slots; sel: the same as an index (idx, or a full slice when M = N).
            states: (M, S, nx) substep states; finite: (M,) all finite.
            clear_lb: (M,) a lower bound of the clearance at the period's start [m].

        Returns:
            (hit (M,), the clearance's lower bound at the period's end (M,) [m]).
        """
        pos = states[:, :, 0:3]
        rel = pos - self.x[sel, None, 0:3]
        disp = np.sqrt(np.einsum("nki,nki->nk", rel, rel).max(axis=1))
        disp = np.where(finite, disp, 0.0)
        lb = clear_lb - disp  # 1-Lipschitz: no substep can be closer than this
        near = np.flatnonzero(finite & (lb <= 0.0))
        hit = np.zeros(len(idx), dtype=bool)
        if len(near):
            nsub = pos.shape[1]
            c = self._sensor.clearance(pos[near].reshape(-1, 3), np.repeat(self.geometry[idx[near]], nsub))
            c = c.reshape(len(near), nsub)
            hit[near] = episode.collided(c)
            lb[near] = c[:, -1]
        return hit, lb

    def _heights(self, idx: np.ndarray, pos: np.ndarray, clear_lb: np.ndarray) -> np.ndarray:
        """Heights above the surface below (M,) [m] of slots idx at positions pos (M, 3) for ground effect:
        the runner's rule (`height_above_surface`) in each slot's truth; a slot whose clearance's lower
        bound puts every surface out of ground-effect range gets its altitude, as in the runner."""
        w = self.world
        h = pos[:, 2].copy()
        for k in np.flatnonzero(clear_lb + self._radius < self._ground_effect_range_m):
            h[k] = height_above_surface(self._truth_maps[idx[k]], pos[k:k + 1], clear_lb[k:k + 1], w.vehicle)[0]
        return h

    def _braking_reach(self, pos: np.ndarray, vel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Free distance along each slot's horizontal velocity and its stopping distance (N,) [m]
        (the reward's braking term): deceleration g tan(max tilt), lag 1 / velocity gain."""
        ctl = self.world.vehicle.controller
        v_h = np.hypot(vel[:, 0], vel[:, 1])
        ahead = self._perception.free_distance(pos, np.arctan2(vel[:, 1], vel[:, 0]), self.geometry)
        decel = GRAVITY_M_S2 * np.tan(np.radians(ctl.max_tilt_deg))
        return ahead, stopping_distance(v_h, decel, 1.0 / ctl.velocity_gain_1_s)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        """Advance every slot one decision.

        Returns:
            observations (N, obs) after the step (before any reset), rewards (N,), terminated (N,),
            truncated (N,), infos (per slot: `reward_terms`, `outcome` when the episode ended,
            `clearance_m`, `distance_to_goal_m`, `route_m`, `t_s`).
        """
        w, cfg = self.world, self.world.config
        act = np.minimum(np.maximum(np.asarray(actions, dtype=np.float64).reshape(self.n, 3), -1.0), 1.0)
        cmd = action_to_command(act, self.memory.heading_rad, w.vehicle, self.yaw)
        code = np.full(self.n, episode.RUNNING, dtype=np.int64)
        elapsed = np.zeros(self.n)
        route_before, clear_before = self.route_m.copy(), self.clear.copy()
        clear_lb = self.clear.copy()
        for _ in range(cfg.action_repeat):
            idx = np.flatnonzero(code == episode.RUNNING)
            if not len(idx):
                break
            # every slot still flying (the common case): plain slices instead of gathers, same numbers
            sel = slice(None) if len(idx) == self.n else idx
            r = self.sim.step_velocity_batch(self.x[sel], self.xi[sel], cmd[sel], self.t[sel],
                                             None if len(idx) == self.n else idx,
                                             self._heights(idx, self.x[sel, 0:3], clear_lb[sel]))
            finite = np.isfinite(r.states).all(axis=(1, 2))
            hit, clear_lb[sel] = self._collided(idx, sel, r.states, finite, clear_lb[sel])
            c = episode.period_outcome(r.states, hit, self.lo[sel], self.hi[sel], self.goal[sel], self.goal_radius[sel])
            self.t[sel] = self.t[sel] + self._period
            elapsed[sel] += self._period
            if finite.all():
                self.x[sel], self.xi[sel] = r.final_state, r.ctrl_state
            else:
                ok = idx[finite]
                self.x[ok], self.xi[ok] = r.final_state[finite], r.ctrl_state[finite]
            c[(c == episode.RUNNING) & episode.timed_out(self.t[sel], self.timeout[sel])] = episode.TIMEOUT
            code[sel] = c
            if self.on_period is not None:
                self.on_period(idx)
        everyone = np.arange(self.n)
        pos = self.x[:, 0:3]
        self.clear, self.nearest = nearest_surface(self._sensor, pos, self.geometry)
        self.route_m = self.routes.potential(pos, everyone)
        arrived = code == episode.SUCCESS
        crashed = (code == episode.COLLISION) | (code == episode.OUT_OF_BOUNDS) | (code == episode.NONFINITE)
        vel = self.x[:, 3:6]
        speed = np.sqrt(np.add.reduce(vel * vel, axis=1))
        ahead = stop = None
        if cfg.reward.braking_per_s > 0.0:
            ahead, stop = self._braking_reach(pos, vel)
        terms = reward_terms(cfg.reward, route_before, self.route_m, clear_before, self.clear, speed, elapsed,
                             arrived, crashed, ahead, stop)
        reward = terms[TERMS[0]].copy()
        for k in TERMS[1:]:
            reward += terms[k]
        m = self.memory
        m.record(everyone, act, self.route_m, vel)
        m.heading_rad[:] = goal_heading(pos, self.goal, m.heading_rad)
        self._observe(everyone)
        terminated = arrived | crashed
        truncated = code == episode.TIMEOUT
        self.episode_return += reward
        self.episode_len += 1
        g = self.goal - pos
        dist = np.sqrt(np.add.reduce(g * g, axis=1))
        infos = []
        for i in range(self.n):
            info = {"reward_terms": {k: float(terms[k][i]) for k in TERMS}, "clearance_m": float(self.clear[i]),
                    "distance_to_goal_m": float(dist[i]), "route_m": float(self.route_m[i]), "t_s": float(self.t[i])}
            if code[i] != episode.RUNNING:
                info["outcome"] = episode.OUTCOME_OF_CODE[int(code[i])]
                info["is_success"] = bool(arrived[i])
                info["city"] = w.cities[int(self.city[i])].name
            infos.append(info)
        return self._obs.copy(), reward.astype(np.float32), terminated, truncated, infos


def route_levels(config: NavConfig, fixed: FixedEpisodes | None) -> int:
    """The most flight levels a task of this configuration (or of these fixed episodes) needs."""
    step = config.route.level_step_m
    if fixed is not None:
        return max([len(flight_levels(t.start_m[2], t.goal_m[2], step)) for _, t in fixed.tasks] + [1])
    return max_levels(config.tasks.altitude_m, step)


def _check_same_geometry(world: NavWorld, other: NavWorld) -> None:
    """Raise ValueError naming what differs where `world` (being built) would share `other`'s cities and sensing."""
    a, b = world.config, other.config
    same = {"cities": (a.cities, b.cities), "city seeds": (a.city_seeds() if world.fixed is None else None,
                                                          b.city_seeds() if other.fixed is None else None),
            "fixed episodes": (world.fixed, other.fixed), "perception": (a.perception, b.perception),
            "observation scales": (a.scales, b.scales),
            "map error": ((a.map_error, a.map_error_draws) if world.fixed is None else None,
                          (b.map_error, b.map_error_draws) if other.fixed is None else None),
            "collision radius": (world.vehicle.collision_radius_m, other.vehicle.collision_radius_m)}
    differ = [name for name, (x, y) in same.items() if x != y]
    if differ:
        raise ValueError(f"cannot share another world's cities and sensing: {', '.join(differ)} differ")

