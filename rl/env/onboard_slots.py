"""What the slots of the training batch sense at a sensing level other than `perfect`: their navigation estimates
and their lidar view, as the comparison runner's `Onboard` gives them to a pilot (`compare.flying.episode_loop`).

`OnboardSlots` holds per non-perfect level of `NavConfig.sensing` one `BatchOnboard` (IMU, barometer, heading aid,
GNSS, navigation filter and the learned pilot's reduced lidar, `rl.task.config.learned_pilot_sensing`) and one
`LidarView` over all N slots; only the slots whose episode flies at that level are reset and advanced in them.
Per slot it does what the runner does for its one vehicle, in the same order:

* at a decision (`decide`): the current estimate, and the lidar scans at least the latency old, integrated into
  the lidar view on that estimate with its position sigma (`LidarView.integrate`); then (`obstacles`) the view read
  at the estimate in the goal frame the estimate gives (`LidarView.read`);
* every control period: the controller flies on the estimate (`offsets`: its error against the true state, for
  `BatchSimulator.step_velocity_batch(seen_offset=)`), then the period's true substep states are sensed and fused
  (`advance`).

The lidar and an urban canyon's GNSS see each slot's TRUE world (its city and the obstacles its map draw adds), the
lidar view starts from its PRIOR map (`rl.env.slot_maps`). A slot's numbers do not depend on the other slots or on N
(`BatchOnboard` and `LidarView` keep rows apart).
"""
from __future__ import annotations

from collections.abc import Hashable, Sequence

import numpy as np

from rl.env.slot_maps import PriorRoofBank, TrueWorlds
from rl.sensing.lidar_view import LidarView, ObstacleSenses
from rl.sensing.perception import Perception, PerceptionReading
from rl.task.config import learned_pilot_sensing
from uam_fdm.air.atmosphere import Atmosphere
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.sensing.batch_onboard import N_ESTIMATED, BatchOnboard
from uam_fdm.vehicle.dynamics import N_SEEN_OFFSET


class OnboardSlots:
    """The onboard sensing of N slots at the non-perfect levels of `levels`.

    Args:
        levels: the task's sensing levels (`NavConfig.sensing`); a slot's level is an index of it.
        n: slots.
        mass_kg: the vehicle's mass [kg] (it picks the parts, `uam_fdm.sensing.specs`).
        physics_dt_s: the physics step [s].
        atmospheres: the world's pool of atmospheres (a slot's field indexes it).
        n_worlds: the true worlds' count (geometry indices, `rl.sensing.truth.MapDraw.geometry`).
        perception: the world's perception over its cities as they stand (the exact level's prior).
        clearance_range_m: the observed clearance's range [m] (`ObservationScales.clearance_m`).
    """

    def __init__(self, levels: Sequence[str], n: int, mass_kg: float, physics_dt_s: float,
                 atmospheres: Sequence[Atmosphere], n_worlds: int, perception: Perception,
                 clearance_range_m: float) -> None:
        self.n = int(n)
        self.worlds = TrueWorlds(n_worlds, self.n)
        self.priors = PriorRoofBank(perception, self.n)
        self.onboard: dict[int, BatchOnboard] = {}
        self.view: dict[int, LidarView] = {}
        casters, cities = self.worlds.casters, self.worlds.cities
        for k, name in enumerate(levels):
            config = learned_pilot_sensing(name, mass_kg)
            if config.perfect:
                continue
            canyon = config.gnss.urban_canyon
            self.onboard[k] = BatchOnboard(config, physics_dt_s, self.n, atmospheres, cities=cities if canyon else (),
                                           casters=casters if canyon else (), lidar_casters=casters)
            self.view[k] = LidarView(self.priors, self.n, config.lidar, clearance_range_m)
        self.level = np.full(self.n, -1, dtype=np.int64)  # each slot's sensing level (-1: perfect)
        self.seed = np.zeros(self.n, dtype=np.int64)  # each sensing slot's episode sensing seed
        # each sensing slot's estimate position sigma along its longest axis at its last decision [m]
        self.sigma_m = np.zeros(self.n)

    def sensed(self, idx: np.ndarray) -> np.ndarray:
        """(M,) which of slots idx sense (fly at a non-perfect level)."""
        return self.level[idx] >= 0

    def start(self, slot: int, level: int, seed: int, geometry: int, truth: BuildingMap, prior: BuildingMap,
              ci: int, prior_key: Hashable) -> None:
        """Slot `slot`'s new episode at level index `level` with sensing seed `seed`: its true world (geometry
        index and map) and its prior map (city `ci` as it stands, or the draw cached as `prior_key`). A perfect
        level senses nothing. `reset` then starts its sensors."""
        if level not in self.onboard:
            self.level[slot] = -1
            self.worlds.release(slot)
            self.priors.release(slot)
            return
        self.level[slot], self.seed[slot] = level, seed
        self.worlds.assign(slot, geometry, truth)
        self.priors.assign(slot, ci, prior, prior_key)

    def reset(self, idx: np.ndarray, x0: np.ndarray, geometry: np.ndarray, field: np.ndarray) -> None:
        """Start the sensors of slots idx (M,) placed by `start`, from true states x0 (M, nx) at t = 0, in true
        worlds `geometry` (M,) and atmospheres `field` (M,) (indices of the world's pool)."""
        for level, onboard in self.onboard.items():
            rows = np.flatnonzero(self.level[idx] == level)
            if not len(rows):
                continue
            slots = idx[rows]
            canyon = onboard.config.gnss.urban_canyon
            onboard.reset(slots, self.seed[slots], x0[rows],
                          city=geometry[rows] if canyon else None, field=field[rows], truth=geometry[rows])
            self.view[level].reset(slots, slots)

    def offsets(self, idx: np.ndarray, x_true: np.ndarray) -> np.ndarray:
        """The estimates' errors (M, `N_SEEN_OFFSET`) of sensing slots idx against their true states x_true
        (M, nx), for the controller flying on the estimate (`BatchOnboard.controller_offset`)."""
        out = np.empty((len(idx), N_SEEN_OFFSET))
        for level, rows in self.by_level(idx):
            out[rows] = self.onboard[level].controller_offset(x_true[rows], idx[rows])
        return out

    def advance(self, idx: np.ndarray, x_start: np.ndarray, states: np.ndarray, t_start_s: np.ndarray) -> None:
        """Sense and fuse one flown control period of sensing slots idx (M,): true states at its start (M, nx),
        after each physics step (M, S, nx) (finite), its start on each slot's clock (M,) [s]."""
        for level, rows in self.by_level(idx):
            self.onboard[level].advance(x_start[rows], states[rows], t_start_s[rows], idx[rows])

    def decide(self, idx: np.ndarray, t_s: np.ndarray) -> np.ndarray:
        """The estimates (M, 13) a decision at t_s (M,) [s] of sensing slots idx acts on (position [m], velocity
        [m/s] world ENU, attitude body FLU -> ENU, body rates [rad/s]), after the scans handed over at t_s are
        integrated into the slots' lidar views on them. Call once per decision: scans are handed over once."""
        out = np.empty((len(idx), N_ESTIMATED))
        for level, rows in self.by_level(idx):
            slots = idx[rows]
            onboard = self.onboard[level]
            est = onboard.estimates(slots)
            sigma = est.sigma_max_m
            self.view[level].integrate(slots, onboard.lidar_scans(t_s[rows], slots), est.state, sigma)
            self.sigma_m[slots] = sigma
            out[rows] = est.state
        return out

    def obstacles(self, idx: np.ndarray, x_est: np.ndarray, heading_rad: np.ndarray) -> ObstacleSenses:
        """The lidar-measured obstacle senses of sensing slots idx (M,) at their estimates x_est (M, 3+) [m, ENU]
        in goal frames at headings (M,) [rad] (`LidarView.read`)."""
        parts = [(rows, self.view[level].read(idx[rows], x_est[rows], heading_rad[rows]))
                 for level, rows in self.by_level(idx)]
        if len(parts) == 1:
            return parts[0][1]
        m = len(idx)
        first = parts[0][1]
        rays = np.empty((m, first.reading.ray_m.shape[1]))
        roofs = np.empty((m, first.reading.roof_m.shape[1]))
        clearance, nearest = np.empty(m), np.empty((m, 3))
        for rows, s in parts:
            rays[rows], roofs[rows] = s.reading.ray_m, s.reading.roof_m
            clearance[rows], nearest[rows] = s.clearance_m, s.nearest_m
        return ObstacleSenses(PerceptionReading(rays, roofs), clearance, nearest)

    def by_level(self, idx: np.ndarray) -> list[tuple[int, np.ndarray]]:
        """(level, rows of idx at it) for each level some of sensing slots idx fly at."""
        lv = self.level[idx]
        if np.any(lv < 0):
            raise ValueError(f"slots {idx[lv < 0].tolist()} fly on the truth: they sense nothing")
        return [(int(k), np.flatnonzero(lv == k)) for k in np.unique(lv)]
