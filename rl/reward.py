"""The learned pilot's reward, term by term (as in the original demo, with its terms made explicit).

Per decision (one control period, 20 ms at 50 Hz), summed into `total`; each term is also
reported separately in the environment's `info["reward_terms"]`:

===========  ==================================================================================
term         value
===========  ==================================================================================
progress     progress_per_m × (d_before - d_after): positive when approaching the goal, negative
             when moving away (d = distance to the goal [m])
proximity    -proximity_weight × max(0, 1 - clearance / safe_distance_m)²: grows as the vehicle's
             collision sphere gets closer than safe_distance_m to a building or the ground
time         -time_penalty per decision (flying slowly costs)
arrival      +arrival_bonus on reaching the goal radius
collision    -collision_penalty on a collision, leaving the flight volume or a non-finite state
===========  ==================================================================================
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TERMS = ("progress", "proximity", "time", "arrival", "collision")


@dataclass(frozen=True)
class RewardConfig:
    """Reward weights (see the module table).

    The proximity and time terms are per decision (50 per second), so they are kept small: with a
    per-step proximity cost comparable to the collision penalty over a few seconds, crashing fast
    pays better than flying carefully past a building (measured: the policy then never brakes).
    """

    progress_per_m: float = 1.0
    proximity_weight: float = 0.03
    safe_distance_m: float = 5.0
    time_penalty: float = 0.005
    arrival_bonus: float = 100.0
    collision_penalty: float = 200.0


def reward_terms(cfg: RewardConfig, d_before: np.ndarray, d_after: np.ndarray, clearance_m: np.ndarray,
                 arrived: np.ndarray, crashed: np.ndarray) -> dict[str, np.ndarray]:
    """Each reward term (N,) for N vehicles; `crashed` = collision, out of bounds or non-finite."""
    closeness = np.minimum(np.maximum(1.0 - clearance_m / cfg.safe_distance_m, 0.0), 1.0)  # NaN -> 0 or 1
    closeness = np.where(np.isnan(closeness), 1.0, closeness)
    progress = cfg.progress_per_m * (d_before - d_after)
    return {
        "progress": np.where(np.isfinite(progress), progress, 0.0),
        "proximity": -cfg.proximity_weight * closeness ** 2,
        "time": np.full(d_before.shape, -cfg.time_penalty),
        "arrival": np.where(arrived, cfg.arrival_bonus, 0.0),
        "collision": np.where(crashed, -cfg.collision_penalty, 0.0),
    }
