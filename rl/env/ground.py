"""A user's own map and air to learn the navigation task on, instead of generated cities: a scenario's.

`TrainingGround.from_scenario(scenario)` takes from a checked scenario (`compare.scenarios.scenario.Scenario`, or
any object with its attributes, `ScenarioLike`) what the task needs: its city, the atmosphere it is flown in, its
steady wind and turbulence, its rates and its vehicle, and checks that the batch can fly them. Then
`ground.task(nav)` is a vehicle's task in that air and at those rates, `ground.legs(nav, n, seed, stream)` n legs
drawn in the city by the task's leg distribution (fixed episodes, each slot flying them in turn), and
`ground.world(nav, legs)` a `NavWorld` flying them in the scenario's atmosphere. The training loop
(`rl.training.loop`) trains and validates on two such worlds (legs of other streams, the same map); the scenario's
own episodes stay for the comparison (`uam-compare run FILE --policy POLICY_DIR`). `UAMNav-v0` takes a ground
(`scenario=`), a checked scenario or a scenario file (`load_ground`).

What the batch flies differently from the scenario: its steady wind is horizontal and uniform with height, of
any heading and a speed up to the scenario's, so the scenario's wind is among those trained on (a shear law is
not); and its obstacles must be boxes (the batched sensors').
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Protocol

import numpy as np

from rl.env.world import NavWorld
from rl.task.air import AirDistribution
from rl.task.config import FixedEpisodes, NavConfig
from rl.task.vehicles import TASKS
from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions
from uam_fdm.air.wind import WindConditions
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.pilot import Task
from uam_fdm.vehicle.dynamics import VehicleDynamics
from uam_fdm.vehicle.params import VehicleParams, load_vehicle

TRAINING_STREAM = 0x7A1
"""PCG64 stream tag of the training legs' draws."""
VALIDATION_STREAM = 0x7A2
"""... and of the validation legs' (the same map, other legs)."""
TRAINING_LEGS = 4096
"""Legs drawn for training in a scenario's map (each slot flies them in turn, from its own offset)."""


class _EpisodeLike(Protocol):
    @property
    def task(self) -> Task: ...


class ScenarioLike(Protocol):
    """What a training ground reads from a checked scenario (`compare.scenarios.scenario.Scenario` has it; the
    attributes as `TrainingGround`'s, and `vehicle_name`, `vehicle`, `atmosphere` and `episodes[i].task`)."""

    @property
    def source(self) -> str: ...
    @property
    def vehicle(self) -> VehicleParams: ...
    @property
    def vehicle_name(self) -> str: ...
    @property
    def city(self) -> BuildingMap: ...
    @property
    def air(self) -> Atmosphere: ...
    @property
    def atmosphere(self) -> AtmosphereConditions: ...
    @property
    def wind(self) -> WindConditions: ...
    @property
    def physics_hz(self) -> float: ...
    @property
    def control_hz(self) -> float: ...
    @property
    def episodes(self) -> Sequence[_EpisodeLike]: ...


@dataclass(frozen=True, eq=False)
class TrainingGround:
    """A scenario's map and air, to learn the task on.

    Attributes:
        source: the scenario file (as its loader named it).
        vehicle: the vehicle preset, one with a learned-pilot task (`rl.task.vehicles.TASKS`).
        city: the map (box buildings, bounds; ENU metres).
        air: the atmosphere table the scenario is flown in; conditions: its field elevation and ISA offset.
        wind: the steady wind (ENU, m/s) and turbulence level.
        physics_hz, control_hz: the scenario's rates [Hz].
        episodes: the scenario's own tasks (not trained on: the comparison flies them).
    """

    source: str
    vehicle: str
    city: BuildingMap
    air: Atmosphere
    conditions: AtmosphereConditions
    wind: WindConditions
    physics_hz: float
    control_hz: float
    episodes: tuple[Task, ...]

    @classmethod
    def from_scenario(cls, scenario: ScenarioLike) -> TrainingGround:
        """The ground of a checked scenario.

        Raises:
            ValueError: "<file>: <key>: <reason>" for what the batch cannot train on: a vehicle without a
                learned-pilot task (or a vehicle file reusing a preset's name with other parameters), an obstacle
                that is not a box.
        """
        source, name = scenario.source, scenario.vehicle_name
        if name not in TASKS:
            raise ValueError(f"{source}: vehicle: {name!r} has no learned-pilot task; a policy is trained for "
                             f"{' or '.join(sorted(TASKS))}")
        if scenario.vehicle.fingerprint() != load_vehicle(name).fingerprint():
            raise ValueError(f"{source}: vehicle: a vehicle file named {name!r} with other parameters than the "
                             f"preset's; a policy is trained for the preset itself")
        odd = [b for b in scenario.city.buildings if not isinstance(b, Building)]
        if odd:
            raise ValueError(f"{source}: map: obstacle {odd[0].id} is not a box (a footprint prism); training's "
                             f"batched sensors take box buildings only")
        return cls(source, name, scenario.city, scenario.air, scenario.atmosphere, scenario.wind,
                   float(scenario.physics_hz), float(scenario.control_hz),
                   tuple(e.task for e in scenario.episodes))

    def task(self, nav: NavConfig) -> NavConfig:
        """`nav` (the vehicle's task) at this ground's rates, in its air: its one field, its turbulence level and
        a steady wind of any heading up to its horizontal speed.

        Raises:
            ValueError: "<file>: <key>: ..." the vehicle is not `nav`'s, or the policy's decisions do not divide the
                scenario's control rate.
        """
        if nav.vehicle != self.vehicle:
            raise ValueError(f"{self.source}: vehicle: {self.vehicle!r}; the task is for {nav.vehicle!r}")
        ratio = self.control_hz / nav.decision_hz
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ValueError(f"{self.source}: control_hz: {self.control_hz:g} Hz is not a multiple of the "
                             f"policy's {nav.decision_hz:g} Hz decisions")
        c = self.conditions
        speed = math.hypot(self.wind.steady_enu_m_s[0], self.wind.steady_enu_m_s[1])
        air = AirDistribution((c.elevation_m, c.elevation_m), (c.isa_offset_k, c.isa_offset_k),
                              (self.wind.turbulence.value,), speed, 1)
        return replace(nav, physics_hz=self.physics_hz, control_hz=self.control_hz, air=air, city_pool_size=1)

    def legs(self, nav: NavConfig, n: int, seed: int, stream: int = TRAINING_STREAM) -> FixedEpisodes:
        """`n` legs drawn in the city by `nav.tasks` at full length for `nav`'s vehicle, from `PCG64([seed, stream])`
        alone (about 0.2 ms a leg).

        Raises:
            ValueError: "<file>: map: ..." the map leaves no room for the task's legs.
        """
        vehicle = load_vehicle(nav.vehicle)
        rng = np.random.Generator(np.random.PCG64([int(seed), int(stream)]))
        ctl, legs = vehicle.controller, nav.tasks
        d, z = legs.distance_m, legs.altitude_m
        no_room = ValueError(f"{self.source}: map: no free start and goal {d[0]:g}-{d[1]:g} m apart at {z[0]:g}-"
                             f"{z[1]:g} m and {legs.bounds_margin_m:g} m inside the bounds in {self.city.name or 'it'} "
                             f"(the {self.vehicle} task's legs)")
        span = np.asarray(self.city.bounds_max_m[:2]) - np.asarray(self.city.bounds_min_m[:2])
        if np.any(span <= 2 * legs.bounds_margin_m):
            raise no_room
        tasks = []
        for _ in range(n):
            try:
                task = legs.sample(self.city, rng, vehicle.collision_radius_m, ctl.max_speed_m_s,
                                   max_vertical_speed_m_s=ctl.max_vertical_speed_m_s)
            except RuntimeError:
                raise no_room from None
            tasks.append((0, task))
        return FixedEpisodes((self.city,), tuple(tasks))

    def world(self, nav: NavConfig, legs: FixedEpisodes, dynamics: VehicleDynamics | None = None,
              wind_from: NavWorld | None = None) -> NavWorld:
        """A world flying `legs` (this ground's `legs`) in its atmosphere, for `nav` (`task`'s).

        Args:
            dynamics: the compiled vehicle to share (default: built for `nav`); wind_from: a world whose
                turbulence stacks to share (`NavWorld`).
        """
        return NavWorld(nav, legs, dynamics=dynamics, atmosphere=self.air, wind_from=wind_from)


def load_ground(path: str | Path) -> TrainingGround:
    """The ground of the scenario file `path`, read and checked by the comparison's strict loader.

    The scenario format is `compare`'s (`compare.scenarios.scenario.load_scenario`, its one reader), which `rl`
    otherwise never imports: imported here, only when a file is given (`UAMNav-v0`'s `scenario=`), the one import
    against the packages' flow (tests/test_architecture.py, `AGAINST_THE_FLOW`).

    Raises:
        ValueError: naming the file, the key and the reason (a `ConfigError` of the loader, or `from_scenario`'s).
    """
    from compare.scenarios.scenario import load_scenario  # against the flow, on purpose: see above

    return TrainingGround.from_scenario(load_scenario(Path(path)))
