"""An example plug-in pilot: climb over everything on the straight line, cross, descend.

Fly it beside ours without installing anything (the folder on PYTHONPATH, the class by its import
path)::

    PYTHONPATH=examples uam-compare run benchmark-quick --pilot straight_climb:StraightClimbPilot

A plug-in is any class with the `uam_fdm.pilot.Pilot` interface: `name`, `reset(world, task, seed)`
(called once per episode, timed as planning), `act(obs)` (called once per decision, timed) and
`episode_report()`. Optional class attributes tell the report how to show it: `label`, `color`,
`given` (a sentence for the run's fairness statement: what it uses of what it is given) and
`wall_s_per_flight_s` (for run-time estimates). This one is a deliberately simple, honest baseline:
it needs no training and no planner, and it shows what "just fly over the city" costs in time and
energy (and where it fails: under a low ceiling, or over towers taller than the flight volume).
"""
from __future__ import annotations

import numpy as np

from uam_fdm.pilot import Observation, ResetInfo, Task, VelocityCommand, World


class StraightClimbPilot:
    """Straight-line-then-climb pilot: climb vertically to a cruise height above every roof near the straight
    line from start to goal, fly straight across at that height, descend onto the goal.

    Its cruise height is the highest roof within a corridor (the collision radius plus `corridor_margin_m` on
    each side of the line) plus the collision radius and `roof_margin_m`; it never goes below the higher of the
    start and goal heights, and gives up (reset not ok) when that height leaves the flight volume.
    """

    name = "straight_climb"
    label = "Straight climb"
    color = "tab:green"
    given = ("It uses the building map (roof heights near the straight line) and its position; it ignores the "
             "forecast turbulence level and the air density, and commands a velocity that the vehicle's "
             "low-level controller turns into rotor speeds.")
    wall_s_per_flight_s = 0.2

    def __init__(self, roof_margin_m: float = 5.0, corridor_margin_m: float = 5.0, gain_per_s: float = 0.8,
                 sample_step_m: float = 2.0) -> None:
        self.roof_margin_m, self.corridor_margin_m = roof_margin_m, corridor_margin_m
        self.gain_per_s, self.sample_step_m = gain_per_s, sample_step_m
        self._waypoints: list[np.ndarray] = []
        self._speed_m_s = 0.0
        self._accept_m = 0.0

    def reset(self, world: World, task: Task, seed: int) -> ResetInfo:
        """Find the cruise height and the three waypoints (deterministic: `seed` is unused)."""
        start, goal = np.asarray(task.start_m, float), np.asarray(task.goal_m, float)
        radius = world.vehicle.collision_radius_m
        cruise = max(start[2], goal[2], self._highest_roof_m(world, start, goal, radius) + radius + self.roof_margin_m)
        ceiling = float(world.city.bounds_max_m[2]) - radius
        if cruise > ceiling:
            return ResetInfo(False, "ceiling", 0.0,
                             f"cruise height {cruise:.1f} m is above the ceiling {ceiling:.1f} m")
        self._waypoints = [np.array([start[0], start[1], cruise]), np.array([goal[0], goal[1], cruise]), goal]
        self._speed_m_s = world.vehicle.controller.max_speed_m_s
        self._accept_m = max(0.5 * task.goal_radius_m, 0.5)
        return ResetInfo(True)

    def act(self, obs: Observation) -> VelocityCommand:
        """Head for the current waypoint (proportional, capped at the vehicle's top speed)."""
        p = np.asarray(obs.x[0:3], float)
        while len(self._waypoints) > 1 and np.linalg.norm(self._waypoints[0] - p) < self._accept_m:
            self._waypoints.pop(0)
        v = self.gain_per_s * (self._waypoints[0] - p)
        speed = float(np.linalg.norm(v))
        if speed > self._speed_m_s:
            v *= self._speed_m_s / speed
        return VelocityCommand(v)

    def episode_report(self) -> None:
        """Nothing beyond the trajectory."""
        return None

    def _highest_roof_m(self, world: World, start: np.ndarray, goal: np.ndarray, radius_m: float) -> float:
        """The highest surface under a corridor along the horizontal straight line [m]."""
        d = goal[:2] - start[:2]
        length = float(np.linalg.norm(d))
        along = d / length if length > 0 else np.array([1.0, 0.0])
        across = np.array([-along[1], along[0]])
        half = radius_m + self.corridor_margin_m
        s = np.linspace(0.0, length, max(2, int(np.ceil(length / self.sample_step_m)) + 1))
        w = np.linspace(-half, half, max(3, int(np.ceil(2 * half / self.sample_step_m)) + 1))
        xy = start[:2] + s[:, None, None] * along + w[None, :, None] * across
        points = np.concatenate([xy.reshape(-1, 2), np.full((xy.size // 2, 1), 1e4)], axis=1)
        return float(np.max(world.city.surface_height_m(points)))
