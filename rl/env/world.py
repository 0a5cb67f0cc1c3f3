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
observes a route field drawn on its prior (distance to go and direction: what the pilot knows), while the reward's
progress is measured on a route field drawn on the truth (`route_m`; training only: a potential drawn on the prior
would pay progress straight into a building the prior lacks). At the `exact` level alone nothing is drawn and every
number is as before the setting existed (tested).

Sensing (`NavConfig.sensing`, `rl.env.onboard_slots`): each episode draws a level. At `perfect` the policy observes
the true state and the truth's exact senses; with ("perfect",) alone nothing is drawn and every number is as before
the setting existed (tested). At another level the policy observes what the vehicle senses, as the runner hands it
to a pilot: the navigation estimate stands for the state in everything the observation uses (position, velocity,
goal frame, route distance and direction, the memory, the air at its altitude, the geofence) and the obstacle part
is the lidar's (`rl.sensing.lidar_view`); the velocity controller flies on the estimate. Everything that scores the
flight stays on the truth: collisions, bounds, arrival, the reward and `info`.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from rl.env.nav_world import NavWorld, SlotAir, route_levels
from rl.env.onboard_slots import OnboardSlots
from rl.sensing.observation import (
    TURBULENCE_VALUE,
    PilotMemory,
    Surroundings,
    action_to_command,
    goal_heading,
)
from rl.sensing.perception import Perception, PerceptionReading
from rl.sensing.route import RouteBank
from rl.sensing.route_refresh import RouteRefresh
from rl.sensing.senses import nearest_surface, observe_slots, route_for
from rl.sensing.sensor import BoxSensor
from rl.sensing.truth import MapDraw, TruthSensing
from rl.task.reward import TERMS, reward_terms, stopping_distance
from uam_fdm import episode
from uam_fdm.air.atmosphere import Atmosphere, AtmosphereBank
from uam_fdm.air.wind import TurbulenceLevel, WindBank, WindField
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.pilot import Task
from uam_fdm.sim import BatchSimulator
from uam_fdm.vehicle.dynamics import PeriodResult
from uam_fdm.vehicle.ground_effect import height_above_surface
from uam_fdm.vehicle.ground_effect import range_m as ground_effect_range_m
from uam_fdm.vehicle.model import hover_state
from uam_fdm.vehicle.params import GRAVITY_M_S2

_IDLE = -1  # a slot `step` leaves where it is (not an `uam_fdm.episode` code)
__all__ = ["NavBatch", "NavWorld", "SlotAir", "route_levels"]  # the world's parts: where they were always imported


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
        self.x_seen = np.zeros((n, nx))  # the state each slot's last decision acted on (`_seen`: the estimate's)
        self.xi = np.zeros((n, 3))
        self.t = np.zeros(n)
        self.city = np.zeros(n, dtype=np.int64)
        self.geometry = np.zeros(n, dtype=np.int64)  # each slot's truth: an index of the world's truth sensing
        self.map_level = np.zeros(n, dtype=np.int64)  # each slot's map-error level: an index of world.maps.levels
        self.map_draw = np.zeros(n, dtype=np.int64)  # and its draw
        self._truth_maps: list[BuildingMap] = [world.cities[0]] * n  # each slot's truth (ground effect)
        self.priors: list[BuildingMap] = [world.cities[0]] * n  # each slot's prior map: what a pilot is given
        # the truths' sensing, by geometry index (the cities' own sensors when no truth adds to its city)
        self._sensor: BoxSensor | TruthSensing = world.truth or world.clearance_sensor
        self._perception: Perception | TruthSensing = world.truth or world.perception
        self.goal = np.zeros((n, 3))
        self.start = np.zeros((n, 3))
        self.goal_radius = np.ones(n)
        self.timeout = np.ones(n)
        self.yaw = np.zeros(n)
        self.route_m = np.zeros(n)  # Φ at the true position on the truth's route field [m] (the reward's)
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
        self.routes = RouteBank(n, world.route_cells, cfg.route.climb_weight, world.route_levels)  # on the priors
        # the reward's potential on the truths, where a map can differ from its truth (else the one bank serves both)
        self._truth_routes = RouteBank(n, world.route_cells, cfg.route.climb_weight, world.route_levels) \
            if any(level != "exact" for level in cfg.map_error) else None
        self.memory = PilotMemory.empty(n, cfg.decision_hz, cfg.observe.history)
        self._obs = np.zeros((n, world.obs_size), dtype=np.float32)
        self._radius = world.vehicle.collision_radius_m
        self._ground_effect_range_m = ground_effect_range_m(world.vehicle) if world.vehicle.ground_effect else -np.inf
        self.lo = np.zeros((n, 3))
        self.hi = np.zeros((n, 3))
        self._period = 1.0 / world.dynamics.control_hz
        self.city_of_slot: np.ndarray | None = None  # evaluation: slot i always flies in city city_of_slot[i]
        self.sensing_level = np.full(n, -1, dtype=np.int64)  # each slot's: an index of config.sensing (-1: perfect)
        self.sensing_seed = np.zeros(n, dtype=np.int64)  # and its episode's sensing seed (0 at a perfect level)
        # the slots' navigation estimates and lidar views, when some level senses (`rl.env.onboard_slots`)
        self.onboard: OnboardSlots | None = None
        if any(level != "perfect" for level in cfg.sensing):
            self.onboard = OnboardSlots(cfg.sensing, n, world.vehicle.mass_kg, world.dynamics.dt_s, world.atmospheres,
                                        len(world.cities) + len(world.maps.added), world.perception,
                                        cfg.scales.clearance_m)
        # the sensing slots' routes redrawn around what their lidar sensed (`rl.sensing.route_refresh`)
        self._refresh = RouteRefresh(n, cfg.route, cfg.decision_hz, world.vehicle.collision_radius_m) \
            if self.onboard is not None and cfg.route.refresh_s > 0.0 else None
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
            air = self._draw_air(rng, task)
            sensing = self._draw_sensing(rng)
            if cfg.exact_maps_at_perfect and cfg.sensing[sensing[0]] == "perfect" and draw.prior is not draw.truth:
                # the task is free in the drawn truth, which holds every building of the city: free in the city too
                draw = w.maps.exact(ci)
            self._place(int(i), ci, task, air, draw, sensing)
        self._begin(np.asarray(idx, dtype=np.int64))

    def place(self, episodes: Sequence[tuple[int, int, Task, SlotAir]],
              maps: Sequence[MapDraw] | None = None, sensing: Sequence[tuple[int, int]] | None = None) -> None:
        """Start the given episodes: (slot, city index, task, its air) each, drawing nothing from any
        generator (e.g. a fixed set of tasks flown again and again, `rl.training.recording`).

        `maps`: each episode's map (`world.maps.draw`); None: every city as it stands (the exact level).
        `sensing`: each episode's sensing level (an index of `config.sensing`) and sensing seed; None: every
        episode flies on the truth (perfect sensing)."""
        for k, (i, ci, task, air) in enumerate(episodes):
            self._place(int(i), int(ci), task, air, self.world.maps.exact(int(ci)) if maps is None else maps[k],
                        (-1, 0) if sensing is None else sensing[k])
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

    def _draw_sensing(self, rng: np.random.Generator) -> tuple[int, int]:
        """A slot's sensing level (an index of `config.sensing`) and sensing seed drawn from its generator.

        Draws a level only where there is a choice and a seed only for a level that senses, so a task of
        perfect sensing alone draws as it always did."""
        levels = self.world.config.sensing
        level = int(rng.integers(len(levels))) if len(levels) > 1 else 0
        return level, int(rng.integers(2**31)) if levels[level] != "perfect" else 0

    def sensing(self, i: int) -> str:
        """Slot i's sensing level ("perfect" when its episode flies on the truth)."""
        k = int(self.sensing_level[i])
        return "perfect" if k < 0 else self.world.config.sensing[k]

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

    def _place(self, i: int, ci: int, task: Task, air: SlotAir, draw: MapDraw, sensing: tuple[int, int]) -> None:
        """Slot i's state at the start of `task` in city `ci`, map `draw`, air `air` and sensing (level index of
        `config.sensing`, -1: perfect; sensing seed) (`_begin` completes it)."""
        w, cfg = self.world, self.world.config
        p = w.vehicle
        self.winds.assign(i, air.wind_m_s, air.series, air.start)
        self.air[i], self.level[i] = air.field, air.level
        if isinstance(self.atmospheres, AtmosphereBank):
            self.atmospheres.assign(i, air.field)
        self.city[i] = ci
        self.geometry[i], self.map_level[i], self.map_draw[i] = draw.geometry, draw.level, draw.draw
        self._truth_maps[i], self.priors[i] = draw.truth, draw.prior
        self.lo[i], self.hi[i] = w.lo[ci], w.hi[ci]
        self.start[i], self.goal[i] = task.start_m, task.goal_m
        self.goal_radius[i], self.timeout[i], self.yaw[i] = task.goal_radius_m, task.timeout_s, task.start_yaw_rad
        self.x[i] = hover_state(p, task.start_m, task.start_yaw_rad,
                                density_ratio=w.atmospheres[air.field].density_ratio(task.start_m[2]))
        self.xi[i] = 0.0
        self.t[i] = 0.0
        level, seed = int(sensing[0]), int(sensing[1])
        if not -1 <= level < len(cfg.sensing) or seed < 0:
            raise ValueError(f"sensing {sensing}: the level must be an index of {cfg.sensing} (-1: perfect) and the "
                             f"seed non-negative")
        route = route_for(draw.prior, task, p.collision_radius_m, cfg.route)
        self.routes.set(i, route)
        if self._truth_routes is not None:
            self._truth_routes.set(i, route if draw.truth is draw.prior else
                                   route_for(draw.truth, task, p.collision_radius_m, cfg.route))
        if self._refresh is not None and level >= 0 and cfg.sensing[level] != "perfect":
            self._refresh.start(i, draw.prior, task, route)
        self.sensing_level[i], self.sensing_seed[i] = level, seed
        if self.onboard is not None:
            self.onboard.start(i, level, seed, draw.geometry, draw.truth, draw.prior, ci, (ci, draw.level, draw.draw))
        self.episode_return[i] = 0.0
        self.episode_len[i] = 0
        self.episode_count[i] += 1

    def _begin(self, idx: np.ndarray) -> None:
        """The first sensing and observation of slots idx, just placed."""
        if len(idx):
            pos = self.x[idx, 0:3]
            self.route_m[idx] = self._reward_routes.potential(pos, idx)
            self.clear[idx], self.nearest[idx] = nearest_surface(self._sensor, pos, self.geometry[idx])
            if self.onboard is not None:
                sensed = idx[self._sensing(idx)]
                self.onboard.reset(sensed, self.x[sensed], self.geometry[sensed], self.air[sensed])
            x, route = self._seen(idx)
            self.x_seen[idx] = x
            self.memory.start(idx, x[:, 0:3], self.goal[idx], route)
            self._observe(idx, x, route)

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
    def _sensing(self, idx: np.ndarray) -> np.ndarray:
        """(M,) which of slots idx fly on what they sense (a level other than perfect)."""
        return self.onboard.sensed(idx) if self.onboard is not None else np.zeros(len(idx), dtype=bool)

    @property
    def route_redraws(self) -> np.ndarray:
        """(N,) the routes redrawn around sensed columns in each slot's episode so far (`RouteConfig.refresh_s`;
        zeros when none is)."""
        return np.zeros(self.n, dtype=np.int64) if self._refresh is None else self._refresh.redraws.copy()

    @property
    def _reward_routes(self) -> RouteBank:
        """The route fields the reward's progress is measured on: the truths' (the priors' when no map differs)."""
        return self.routes if self._truth_routes is None else self._truth_routes

    def _seen(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The states (M, nx) and route distances Φ (M,) [m] a decision of slots idx acts on: the truth's at a
        perfect level, else the navigation estimate (its first 13 elements; the rotor speeds the ESCs report) and
        Φ at the estimated position (`OnboardSlots.decide`: call once per decision); Φ on the prior's route field."""
        x = self.x[idx]
        route = self.route_m[idx] if self._truth_routes is None else self.routes.potential(x[:, 0:3], idx)
        rows = np.flatnonzero(self._sensing(idx))
        if len(rows):
            assert self.onboard is not None
            s = idx[rows]
            x[rows, 0:13] = self.onboard.decide(s, self.t[s])
            if self._refresh is not None:  # the scans are in the views now: redraw the routes they block
                for level, at in self.onboard.by_level(s):
                    for slot, redrawn in self._refresh.decide(s[at], self.onboard.view[level], s[at],
                                                              x[rows[at], 0:3], self.onboard.sigma_m[s[at]]):
                        self.routes.set(slot, redrawn)
            route[rows] = self.routes.potential(x[rows, 0:3], s)
        return x, route

    def _observe(self, idx: np.ndarray, x: np.ndarray, route_m: np.ndarray) -> None:
        """Recompute the observations of slots idx from the states (M, nx) and route distances (M,) [m] they act
        on (`_seen`) and their memory: the truth's exact senses at a perfect level, else the lidar's."""
        sensed = self._sensing(idx)
        rows = np.flatnonzero(sensed)
        if not len(rows):
            self._obs[idx] = self._observations(idx, x, route_m, self.clear[idx], self.nearest[idx])
            return
        assert self.onboard is not None
        plain = np.flatnonzero(~sensed)
        if len(plain):
            s = idx[plain]
            self._obs[s] = self._observations(s, x[plain], route_m[plain], self.clear[s], self.nearest[s])
        s = idx[rows]
        senses = self.onboard.obstacles(s, x[rows], self.memory.heading_rad[s])
        self._obs[s] = self._observations(s, x[rows], route_m[rows], senses.clearance_m, senses.nearest_m,
                                          senses.reading, self.onboard.sigma_m[s])

    def _observations(self, idx: np.ndarray, x: np.ndarray, route_m: np.ndarray, clearance_m: np.ndarray,
                      nearest_m: np.ndarray, reading: PerceptionReading | None = None,
                      position_sigma_m: np.ndarray | None = None) -> np.ndarray:
        """`observe_slots` of slots idx at states x (M, nx), route distances (M,) [m], clearances (M,) [m] and
        nearest-surface vectors (M, 3) [m, world]; `reading`: their measured rays and height maps (None: the
        truth's perception); `position_sigma_m`: their estimates' position sigma (M,) [m] (None: the truth's, 0)."""
        w = self.world
        cfg = w.config
        return observe_slots(idx, x, self.goal[idx], route_m, clearance_m, nearest_m, self.t[idx] / self.timeout[idx],
                             self.geometry[idx], self._perception, self.routes, self.memory, cfg.perception,
                             cfg.scales, cfg.decision_hz, w.vehicle, cfg.observe,
                             self._surroundings(idx, x[:, 2]) if cfg.observe.size() else None, reading,
                             position_sigma_m)

    def _surroundings(self, idx: np.ndarray, z: np.ndarray) -> Surroundings:
        """What the pilot interface tells slots idx at altitudes z (M,) [m] about their air and flight volume."""
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

    def _fly(self, idx: np.ndarray, sel: np.ndarray | slice, cmd: np.ndarray, heights_m: np.ndarray) -> PeriodResult:
        """One control period of slots idx (`sel`: the same as an index) under commands cmd (N, 4) at heights above
        the surface (M,) [m]: the controller flies on the truth at a perfect level, else on the estimate."""
        whole = None if len(idx) == self.n else idx
        sensed = self._sensing(idx)
        if not sensed.any():
            return self.sim.step_velocity_batch(self.x[sel], self.xi[sel], cmd[sel], self.t[sel], whole, heights_m)
        assert self.onboard is not None
        if sensed.all():
            offset = self.onboard.offsets(idx, self.x[sel])
            return self.sim.step_velocity_batch(self.x[sel], self.xi[sel], cmd[sel], self.t[sel], whole, heights_m,
                                                seen_offset=offset)
        parts = []
        for rows in (np.flatnonzero(~sensed), np.flatnonzero(sensed)):
            s = idx[rows]
            seen = self.onboard.offsets(s, self.x[s]) if sensed[rows[0]] else None
            parts.append((rows, self.sim.step_velocity_batch(self.x[s], self.xi[s], cmd[s], self.t[s], s,
                                                             heights_m[rows], seen_offset=seen)))
        first = parts[0][1]
        m = len(idx)
        out = PeriodResult(np.empty((m,) + first.states.shape[1:]), np.empty((m,) + first.rotor_commands.shape[1:]),
                           np.empty((m,) + first.ctrl_state.shape[1:]), np.empty(m))
        for rows, r in parts:
            out.states[rows], out.rotor_commands[rows], out.ctrl_state[rows] = r.states, r.rotor_commands, r.ctrl_state
            np.asarray(out.energy_J)[rows] = r.energy_J
        return out

    def step(self, actions: np.ndarray, active: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        """Advance every slot one decision (with `active` (N,) bool, only those: the others, e.g. episodes an
        evaluation has seen end, stay where they are, flying and sensing nothing, and end nothing; the flying slots'
        numbers are the same).

        Returns:
            observations (N, obs) after the step (before any reset), rewards (N,), terminated (N,),
            truncated (N,), infos (per slot: `reward_terms`, `outcome` when the episode ended,
            `clearance_m`, `distance_to_goal_m`, `route_m`, `t_s`).
        """
        w, cfg = self.world, self.world.config
        act = np.minimum(np.maximum(np.asarray(actions, dtype=np.float64).reshape(self.n, 3), -1.0), 1.0)
        cmd = action_to_command(act, self.memory.heading_rad, w.vehicle, self.yaw)
        code = np.full(self.n, episode.RUNNING, dtype=np.int64)
        if active is not None:
            code[~np.asarray(active, dtype=bool).reshape(self.n)] = _IDLE
        elapsed = np.zeros(self.n)
        route_before, clear_before = self.route_m.copy(), self.clear.copy()
        clear_lb = self.clear.copy()
        for _ in range(cfg.action_repeat):
            idx = np.flatnonzero(code == episode.RUNNING)
            if not len(idx):
                break
            # every slot still flying (the common case): plain slices instead of gathers, same numbers
            sel = slice(None) if len(idx) == self.n else idx
            r = self._fly(idx, sel, cmd, self._heights(idx, self.x[sel, 0:3], clear_lb[sel]))
            finite = np.isfinite(r.states).all(axis=(1, 2))
            rows = np.flatnonzero(self._sensing(idx) & finite)
            if len(rows):  # the period sensed and fused, as the runner's `Onboard.advance` after it
                assert self.onboard is not None
                s = idx[rows]
                self.onboard.advance(s, self.x[s], r.states[rows], self.t[s])
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
        pos = self.x[:, 0:3]  # the truth: what scores the flight (the policy observes what it senses, `_seen`)
        self.clear, self.nearest = nearest_surface(self._sensor, pos, self.geometry)
        self.route_m = self._reward_routes.potential(pos, everyone)
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
        x_seen, route_seen = self._seen(everyone)
        self.x_seen[everyone] = x_seen
        m.record(everyone, act, route_seen, x_seen[:, 3:6])
        m.heading_rad[:] = goal_heading(x_seen[:, 0:3], self.goal, m.heading_rad)
        self._observe(everyone, x_seen, route_seen)
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
            if code[i] != episode.RUNNING and code[i] != _IDLE:
                info["outcome"] = episode.OUTCOME_OF_CODE[int(code[i])]
                info["is_success"] = bool(arrived[i])
                info["city"] = w.cities[int(self.city[i])].name
                level = int(self.sensing_level[i])
                info["sensing"] = "perfect" if level < 0 else w.config.sensing[level]
                info["map_error"] = w.maps.levels[int(self.map_level[i])]
            infos.append(info)
        return self._obs.copy(), reward.astype(np.float32), terminated, truncated, infos
