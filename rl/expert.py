"""A reactive potential-field pilot on the learned pilot's own observation (the `tuned` preset's teacher).

It sees exactly what the policy sees (`rl.observation`) and nothing else: attraction along the
goal direction, repulsion from each sensed building closer than `influence_m` (quadratic in the
intrusion), a climb bias near buildings, and a speed that falls from `speed_max` to `speed_min`
(fractions of the vehicle's limits) as the nearest building comes within `slow_m`. Measured on
200 held-out validation cities with light turbulence: 92 % success, 0 % collisions, the rest time-outs in
local minima. The `tuned` training preset clones it (behaviour cloning with noise injection) before
PPO takes over, so PPO starts from a pilot that already avoids buildings.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rl.observation import N_BASE


@dataclass(frozen=True)
class PotentialField:
    """Gains of the reactive pilot (distances in metres; speeds as fractions of the vehicle's limits)."""

    k_buildings: int
    range_m: float
    repulsion: float = 2.0
    influence_m: float = 15.0
    climb: float = 2.0
    speed_max: float = 0.8
    speed_min: float = 0.2
    slow_m: float = 15.0
    vertical_gain: float = 4.0

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Actions (N, 3) in [-1, 1] from raw (unnormalised) observations (N, 16 + 4k)."""
        o = np.asarray(obs, dtype=np.float64)
        goal_dir = o[:, 6:9]
        b = o[:, N_BASE:].reshape(len(o), self.k_buildings, 4)
        vec, clear = b[:, :, 0:3], b[:, :, 3] * self.range_m
        away = -vec / (np.linalg.norm(vec, axis=2, keepdims=True) + 1e-9)
        w = np.clip((self.influence_m - clear) / self.influence_m, 0.0, 1.0)[..., None] ** 2
        cmd = goal_dir + self.repulsion * (w * away).sum(axis=1)
        cmd[:, 2] += self.climb * w[..., 0].max(axis=1)
        speed = self.speed_min + (self.speed_max - self.speed_min) * np.clip(clear.min(axis=1) / self.slow_m, 0, 1)
        cmd *= (speed / np.maximum(np.linalg.norm(cmd, axis=1), 1e-9))[:, None]
        cmd[:, 2] *= self.vertical_gain
        return np.clip(cmd, -1.0, 1.0)
