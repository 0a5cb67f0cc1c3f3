"""A reactive potential-field pilot: the baseline the learned pilot must beat on the same tasks.

It senses the k nearest buildings within a range (`rl.sensing.sensor.BoxSensor`) and the straight-line
goal direction, nothing else: attraction along the goal direction, repulsion from each sensed
building closer than `influence_m` (quadratic in the intrusion), a climb bias near buildings, and a
speed that falls from `speed_max` to `speed_min` (fractions of the vehicle's limits) as the nearest
building comes within `slow_m`. Its gains were tuned on validation cities at 50 Hz decisions
(docs/design_notes.md, "rl.pilots.potential_field"). It flies the environment's batch directly, at
whatever decision rate the batch runs.

As a `Pilot` (`PotentialFieldPilot`), flown by the comparison runner, each decision it senses the
k nearest buildings within its range (exact distances from the map) from the vehicle's position,
computes the field's world velocity (`PotentialFieldConfig.velocity`) and hands it to the vehicle's
low-level controller through the learned pilot's own path (`rl.sensing.observation.velocity_command`:
the goal-frame action, then the environment's `action_to_command`), so a command is the one the
evaluation environment would fly for the same field (`rl.training.evaluation.evaluate_potential_field`).

It decides every control period (its gains were tuned at 50 Hz decisions, the scenarios' default
control rate), does not plan (no planning time) and has nothing to report at the end of an episode.
Its distances are scaled as in the evaluation: by the learned pilot's task clearance scale for the
vehicle (`rl.task.vehicles`) over the small quad's; a vehicle without a task keeps the small quad's gains.
"""
from __future__ import annotations

import functools
import json
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rl.env.world import NavBatch
from rl.sensing.observation import ObservationScales, goal_heading, velocity_command, world_velocity_to_action
from rl.sensing.sensor import BoxSensor
from rl.task.cities import boxes_only
from rl.task.vehicles import TASKS
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.pilot import Observation, ResetInfo, Task, VelocityCommand, World
from uam_fdm.renamed import renamed
from uam_fdm.vehicle.params import VehicleParams


@dataclass(frozen=True)
class PotentialFieldConfig:
    """Gains of the reactive pilot (distances in metres; speeds as fractions of the vehicle's limits)."""

    k_buildings: int = 5
    range_m: float = 30.0
    repulsion: float = 2.0
    influence_m: float = 15.0
    climb: float = 2.0
    speed_max: float = 0.8
    speed_min: float = 0.2
    slow_m: float = 15.0
    vertical_gain: float = 4.0

    def scaled(self, factor: float) -> PotentialFieldConfig:
        """The same pilot with every distance (range, influence, slow-down) times `factor`: for a
        vehicle whose task is `factor` times larger (`gains_for_task`: the task's clearance scale over
        the small quad's 30 m). Scaled, not re-tuned."""
        return replace(self, range_m=self.range_m * factor, influence_m=self.influence_m * factor,
                       slow_m=self.slow_m * factor)

    def velocity(self, p_m: np.ndarray, goal_m: np.ndarray, nearest_m: np.ndarray,
                 distance_m: np.ndarray) -> np.ndarray:
        """World velocity commands (N, 3) as fractions of the vehicle's limits, in [-1, 1].

        Args:
            p_m, goal_m: positions and goals (N, 3) ENU [m].
            nearest_m: nearest points of the k nearest buildings (N, k, 3) [m] (p itself if none).
            distance_m: their signed distances (N, k) [m] (range_m if none).
        """
        g = goal_m - p_m
        goal_dir = g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-9)
        vec = nearest_m - p_m[:, None, :]
        away = -vec / (np.linalg.norm(vec, axis=2, keepdims=True) + 1e-9)
        w = np.clip((self.influence_m - distance_m) / self.influence_m, 0.0, 1.0)[..., None] ** 2
        cmd = goal_dir + self.repulsion * (w * away).sum(axis=1)
        cmd[:, 2] += self.climb * w[..., 0].max(axis=1)
        speed = self.speed_min + (self.speed_max - self.speed_min) * np.clip(distance_m.min(axis=1) / self.slow_m, 0, 1)
        cmd *= (speed / np.maximum(np.linalg.norm(cmd, axis=1), 1e-9))[:, None]
        cmd[:, 2] *= self.vertical_gain
        return np.clip(cmd, -1.0, 1.0)


class BatchedPotentialField:
    """The potential field flying a `NavBatch`: call it as `pilot(obs, batch) -> actions (N, 3)`.

    As the comparison runner flies it (`PotentialFieldPilot`), it knows what a pilot is given: each slot's position as
    its decision sees it (the navigation estimate below `perfect` sensing, `NavBatch.x_seen`) and its prior map (the
    city, or the map-error draw the slot flies with, `NavBatch.priors`), never the truth it collides with.

    Args:
        batch: the batch it will fly (its cities give the sensor).
        gains: the pilot's gains.
    """

    def __init__(self, batch: NavBatch, gains: PotentialFieldConfig = PotentialFieldConfig()) -> None:
        w = batch.world
        self.gains = gains
        self.sensor = BoxSensor(w.cities, gains.k_buildings, gains.range_m, w.vehicle.collision_radius_m)
        self._drawn: dict[int, tuple[BuildingMap, BoxSensor]] = {}  # drawn priors' sensors, by the prior's id

    def __call__(self, obs: np.ndarray, batch: NavBatch) -> np.ndarray:
        p = batch.x_seen[:, 0:3]
        cities = batch.world.cities
        drawn = np.array([batch.priors[i] is not cities[int(batch.city[i])] for i in range(batch.n)], dtype=bool)
        if not drawn.any():  # every slot's prior is its city: one query
            r = self.sensor.query(p, batch.city)
            nearest, distance = r.nearest_m, r.distance_m
        else:
            k = self.gains.k_buildings
            nearest, distance = np.empty((batch.n, k, 3)), np.empty((batch.n, k))
            own = np.flatnonzero(~drawn)
            if len(own):
                r = self.sensor.query(p[own], batch.city[own])
                nearest[own], distance[own] = r.nearest_m, r.distance_m
            for i in np.flatnonzero(drawn).tolist():  # a slot whose prior map is not its city senses its prior
                q = self._prior_sensor(batch.priors[i], batch.world.vehicle.collision_radius_m).query(p[i:i + 1],
                                                                                                      _CITY)
                nearest[i], distance[i] = q.nearest_m[0], q.distance_m[0]
        v = self.gains.velocity(p, batch.goal, nearest, distance)
        return world_velocity_to_action(v, batch.memory.heading_rad)

    def _prior_sensor(self, prior: BuildingMap, radius_m: float) -> BoxSensor:
        """The sensor of a drawn prior map (built at its first query, kept while the prior is)."""
        held = self._drawn.get(id(prior))
        if held is None or held[0] is not prior:
            held = self._drawn[id(prior)] = (prior, BoxSensor([prior], self.gains.k_buildings, self.gains.range_m,
                                                              radius_m))
        return held[1]


_CITY = np.zeros(1, dtype=np.int64)
TUNED = PotentialFieldConfig()
"""The gains tuned for the small quad."""


def gains_for_task(scales: ObservationScales, base: PotentialFieldConfig = TUNED) -> PotentialFieldConfig:
    """The potential field's gains for a learned-pilot task of observation scales `scales`: `base` (tuned
    for the small quad's task) with its distances scaled by the task's clearance scale over the small quad's."""
    return base.scaled(scales.clearance_m / ObservationScales().clearance_m)


GAINS_FILE = Path(__file__).parent / "data" / "potential_field_gains.json"
"""Gains tuned per vehicle on validation cities (`perf/apf_gains.py --write`), with their provenance."""


@functools.lru_cache(maxsize=4)
def tuned_gains(path: Path = GAINS_FILE) -> dict[str, PotentialFieldConfig]:
    """The gains tuned per vehicle preset (empty when none were tuned), read once per process.

    Raises:
        ValueError: the file is not a table of gains per vehicle (naming it and the vehicle).
    """
    if not path.is_file():
        return {}
    table = json.loads(path.read_text(encoding="utf-8"))
    known = {f.name for f in fields(PotentialFieldConfig)}
    out = {}
    for vehicle, entry in table.get("vehicles", {}).items():
        gains = entry.get("gains") if isinstance(entry, dict) else None
        if not isinstance(gains, dict) or set(gains) != known:
            raise ValueError(f"{path}: vehicles.{vehicle}.gains must hold exactly {sorted(known)}")
        out[vehicle] = PotentialFieldConfig(**gains)
    return out


def gains_for(vehicle: VehicleParams, base: PotentialFieldConfig = TUNED) -> PotentialFieldConfig:
    """The potential field's gains for `vehicle`: those tuned for its preset on validation cities
    (`tuned_gains`) when `base` is the default, else `gains_for_task` of its learned-pilot task (`base` itself
    for a vehicle without one)."""
    tuned = tuned_gains().get(vehicle.name) if base == TUNED else None
    if tuned is not None:
        return tuned
    task = TASKS.get(vehicle.name)
    return base if task is None else gains_for_task(task.scales, base)


class PotentialFieldPilot:
    """The potential-field pilot (implements `uam_fdm.pilot.Pilot`).

    Args:
        base: the gains tuned for the small quad (scaled per vehicle at reset, `gains_for`).
    """

    name = "apf"

    def __init__(self, base: PotentialFieldConfig = TUNED) -> None:
        self.base = base
        self._sensed: tuple[BuildingMap, float, PotentialFieldConfig, BoxSensor] | None = None

    def reset(self, world: World, task: Task, seed: int) -> ResetInfo:
        """Prepare the sensor for the city (reused while the city and vehicle stay the same).

        Deterministic, so `seed` is unused. Refuses (ResetInfo not ok) maps with non-box obstacles.
        """
        if not boxes_only(world.city):
            return ResetInfo(False, "unsupported_map", 0.0,
                             f"map {world.city.name!r} has non-box obstacles; the potential field's sensor needs boxes")
        radius = world.vehicle.collision_radius_m
        gains = gains_for(world.vehicle, self.base)
        s = self._sensed
        if s is None or s[0] is not world.city or (s[1], s[2]) != (radius, gains):
            s = self._sensed = (world.city, radius, gains, BoxSensor([world.city], gains.k_buildings, gains.range_m,
                                                                    radius))
        self._sensor = s[3]
        self._gains, self._vehicle, self._task = gains, world.vehicle, task
        self._goal = np.asarray(task.goal_m, dtype=float)[None]
        d = self._goal[0, 0:2] - np.asarray(task.start_m, dtype=float)[0:2]
        self._heading = np.array([np.arctan2(d[1], d[0])])  # the goal frame, as `PilotMemory.start` sets it
        self._decided = False
        return ResetInfo(True)

    def act(self, obs: Observation) -> VelocityCommand:
        p = np.asarray(obs.x, dtype=float)[None, 0:3]
        if self._decided:  # the goal frame follows the bearing to the goal, as the environment's after a step
            self._heading = goal_heading(p, self._goal, self._heading)
        self._decided = True
        r = self._sensor.query(p, _CITY)
        v = self._gains.velocity(p, self._goal, r.nearest_m, r.distance_m)
        action = world_velocity_to_action(v, self._heading)
        return velocity_command(action, self._heading, self._vehicle, self._task.start_yaw_rad, hold_periods=1)

    def episode_report(self) -> None:
        """Nothing beyond the trajectory."""


if not TYPE_CHECKING:  # hidden from the type checker: our own code must use the new names
    def __getattr__(name: str) -> Any:
        """The old name `PotentialFieldAgent` (kept for one release, for code written against it):
        `PotentialFieldPilot`, with a warning (`uam_fdm.renamed`). The batched field's old name, `PotentialFieldPilot`,
        now names the pilot; the batched field is `BatchedPotentialField`."""
        return renamed(__name__, name, {"PotentialFieldAgent": "PotentialFieldPilot"})
