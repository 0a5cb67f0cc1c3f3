"""The reactive potential-field pilot (`rl.expert`) as an `Agent`, flown by the comparison runner.

Each decision it senses the k nearest buildings within its range (`rl.sensor.BoxSensor`, exact
distances from the map) from the vehicle's position, computes the potential field's world velocity
(`rl.expert.PotentialField.velocity`) and hands it to the vehicle's low-level controller through the
learned pilot's own path (`rl.observation.velocity_command`: the goal-frame action, then the environment's
`action_to_command`), so a command is the one the evaluation environment would fly for the same
field (`rl.evaluation.evaluate_potential_field`).

It decides every control period (its gains were tuned at 50 Hz decisions, the scenarios' default
control rate), does not plan (no planning time) and has nothing to report at the end of an episode.
Its distances are scaled as in the evaluation: by the learned pilot's task clearance scale for the
vehicle (`rl.tasks`) over the small quad's; a vehicle without a task keeps the small quad's gains.
"""
from __future__ import annotations

import numpy as np

from rl.cities import boxes_only
from rl.expert import PotentialField
from rl.observation import ObservationScales, goal_heading, velocity_command, world_velocity_to_action
from rl.sensor import BoxSensor
from rl.tasks import TASKS
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.pilot import Observation, ResetInfo, Task, VelocityCommand, World
from uam_fdm.vehicle.params import VehicleParams

_CITY = np.zeros(1, dtype=np.int64)
TUNED = PotentialField()
"""The gains tuned for the small quad (`rl.expert`)."""


def gains_for(vehicle: VehicleParams, base: PotentialField = TUNED) -> PotentialField:
    """The potential field's gains for `vehicle`: `base` with its distances scaled by the vehicle's task
    clearance scale over the small quad's (1 for a vehicle without a learned-pilot task)."""
    task = TASKS.get(vehicle.name)
    scale = 1.0 if task is None else task.scales.clearance_m / ObservationScales().clearance_m
    return base.scaled(scale)


class PotentialFieldAgent:
    """The potential-field pilot (implements `uam_fdm.pilot.Agent`).

    Args:
        base: the gains tuned for the small quad (scaled per vehicle at reset, `gains_for`).
    """

    name = "apf"

    def __init__(self, base: PotentialField = TUNED) -> None:
        self.base = base
        self._sensed: tuple[BuildingMap, float, PotentialField, BoxSensor] | None = None

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
