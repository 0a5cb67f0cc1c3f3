"""What the slots of a navigation batch share, built once: the vehicle and its compiled dynamics, the atmospheres,
the cities with their sensors and map-error bank, and the turbulence pool (`NavWorld`); and the air of one episode
in those pools (`SlotAir`). `rl.env.world.NavBatch` steps N episodes in a `NavWorld`.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rl.sensing.observation import obs_size
from rl.sensing.perception import Perception
from rl.sensing.route import flight_levels, grid_shape, max_levels
from rl.sensing.senses import clearance_sensor
from rl.sensing.sensor import BoxSensor
from rl.sensing.truth import MapErrorBank, TruthSensing
from rl.task.config import FixedEpisodes, NavConfig
from uam_fdm.air.atmosphere import Atmosphere
from uam_fdm.air.wind import (
    GustStack,
    TurbulenceLevel,
    WindConditions,
    gust_stack,
    probe_heights_up_to,
    turbulence_airspeed_m_s,
)
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.vehicle.dynamics import VehicleDynamics
from uam_fdm.vehicle.params import VehicleParams, load_vehicle


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
