"""A reactive potential-field pilot: the baseline the learned pilot must beat on the same tasks.

It senses the k nearest buildings within a range (`rl.sensor.BoxSensor`) and the straight-line
goal direction, nothing else: attraction along the goal direction, repulsion from each sensed
building closer than `influence_m` (quadratic in the intrusion), a climb bias near buildings, and a
speed that falls from `speed_max` to `speed_min` (fractions of the vehicle's limits) as the nearest
building comes within `slow_m`. Its gains were tuned on validation cities at 50 Hz decisions
(the earlier learned pilot's teacher): 92 % success, 0 % collisions, the rest time-outs in local
minima behind buildings (a reactive pilot with a 30 m view cannot see around a block). It flies
the environment's batch directly, at whatever decision rate the batch runs.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from rl.nav import NavBatch
from rl.observation import world_velocity_to_action
from rl.sensor import BoxSensor


@dataclass(frozen=True)
class PotentialField:
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

    def scaled(self, factor: float) -> PotentialField:
        """The same pilot with every distance (range, influence, slow-down) times `factor`: for a
        vehicle whose task is `factor` times larger (`rl.evaluation.evaluate_potential_field` uses
        the task's clearance scale over the small quad's 30 m). Scaled, not re-tuned."""
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


class PotentialFieldPilot:
    """The potential field flying a `NavBatch`: call it as `pilot(obs, batch) -> actions (N, 3)`.

    Args:
        batch: the batch it will fly (its cities give the sensor).
        gains: the pilot's gains.
    """

    def __init__(self, batch: NavBatch, gains: PotentialField = PotentialField()) -> None:
        w = batch.world
        self.gains = gains
        self.sensor = BoxSensor(w.cities, gains.k_buildings, gains.range_m, w.vehicle.collision_radius_m)

    def __call__(self, obs: np.ndarray, batch: NavBatch) -> np.ndarray:
        p = batch.x[:, 0:3]
        r = self.sensor.query(p, batch.city)
        v = self.gains.velocity(p, batch.goal, r.nearest_m, r.distance_m)
        return world_velocity_to_action(v, batch.memory.heading_rad)
