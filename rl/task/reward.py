"""The learned pilot's reward, term by term; every weight is per metre or per second, not per step.

Per decision (whatever the decision rate), summed into the reward; each term is also reported in
the environment's `info["reward_terms"]`. Δt is the flight time the decision covered (shorter when
the episode ended inside it), Φ the geodesic distance-to-go around the buildings (`rl.sensing.route`):

===========  ==================================================================================
term         value
===========  ==================================================================================
progress     progress_per_m x (Φ_before - Φ_after). A potential-based shaping term (Ng et al.
             1999): it sums to Φ(start) - Φ(end) along any path, so it cannot be farmed, and
             since Φ goes around buildings it has no local minima behind them (Euclidean
             progress does: the old pilot's every time-out was stuck behind a building)
time         -time_per_s x Δt (flying slowly costs)
danger       -danger_per_s x Δt x max(0, 1 - TTC / ttc_horizon_s)², TTC = clearance / closing
             speed (the clearance's rate of decrease over the decision): grows with closing speed,
             not only with closeness, so braking before a wall pays and crashing fast does not
proximity    -proximity_per_s x Δt x max(0, 1 - clearance / proximity_m)² x (1 + (v / proximity_speed_m_s)²),
             v the ground speed at the decision's end: near a surface, cost per *metre* grows with
             speed (per second alone, a fast graze would cost less than a slow one, being shorter),
             so the cheapest way past a wall is wide or slow
braking      -braking_per_s x Δt x max(0, 1 - s / (braking_margin x d))², s the free distance along the
             horizontal velocity (a ray of the collision sphere's stand-in, `rl.sensing.perception`) and
             d = v² / (2 a) + v τ the vehicle's stopping distance from its horizontal speed v at its
             braking deceleration a = g tan(max tilt) after its velocity loop's lag τ = 1 / gain:
             it costs to be heading at a wall closer than a margin times the distance needed to
             stop. The TTC of `danger` cannot say this for a vehicle that needs more time to stop
             than its horizon, nor see a wall while a nearer roof below sets the clearance. Off
             (0) for the small quad; on for the UAM (`rl.task.vehicles`)
arrival      +arrival_bonus on reaching the goal radius
collision    -collision_penalty on a collision, leaving the flight volume or a non-finite state
===========  ==================================================================================
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TERMS = ("progress", "time", "danger", "proximity", "braking", "arrival", "collision")
MAX_WEIGHT = 1e6  # per metre, second or event: the shipped tasks' are 100 at most
SCALE_RANGE = (1e-3, 1e6)  # the horizon [s], distance [m], speed [m/s] and margin the terms divide by
_SCALES = ("ttc_horizon_s", "proximity_m", "proximity_speed_m_s", "braking_margin")


@dataclass(frozen=True)
class RewardConfig:
    """Reward weights (see the module table; per metre, per second or per event)."""

    progress_per_m: float = 1.0
    time_per_s: float = 0.5
    danger_per_s: float = 4.0
    ttc_horizon_s: float = 1.5
    proximity_per_s: float = 5.0
    proximity_m: float = 4.0
    proximity_speed_m_s: float = 5.0
    braking_per_s: float = 0.0
    braking_margin: float = 1.5
    arrival_bonus: float = 50.0
    collision_penalty: float = 100.0

    def __post_init__(self) -> None:
        # bounded, so that no episode's return overflows (float32 in the environment, summed over thousands of
        # decisions): a weight of 1e308 in a policy's config.json would make every return infinite
        for k, v in self.__dict__.items():
            lo, hi = SCALE_RANGE if k in _SCALES else (0.0, MAX_WEIGHT)
            if not (np.isfinite(v) and lo <= v <= hi):
                raise ValueError(f"reward.{k} must be a finite number in [{lo:g}, {hi:g}], got {v!r}")


def reward_terms(cfg: RewardConfig, route_before_m: np.ndarray, route_after_m: np.ndarray,
                 clear_before_m: np.ndarray, clear_after_m: np.ndarray, speed_m_s: np.ndarray,
                 elapsed_s: np.ndarray, arrived: np.ndarray, crashed: np.ndarray,
                 free_ahead_m: np.ndarray | None = None, stopping_m: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Each reward term (N,) for N vehicles over one decision (see the module table).

    Args:
        route_before_m, route_after_m: Φ at the decision's start and end [m].
        clear_before_m, clear_after_m: clearance at the decision's start and end [m].
        speed_m_s: ground speed at the decision's end [m/s].
        elapsed_s: flight time the decision covered [s] (> 0).
        arrived: reached the goal; crashed: collision, out of bounds or non-finite.
        free_ahead_m, stopping_m: free distance along the horizontal velocity and the stopping
            distance [m] at the decision's end (needed when `braking_per_s` > 0; see `stopping_distance`).
    """
    if cfg.braking_per_s > 0.0 and (free_ahead_m is None or stopping_m is None):
        raise ValueError("reward.braking_per_s > 0 needs the free distance ahead and the stopping distance")
    with np.errstate(invalid="ignore", divide="ignore"):
        progress = cfg.progress_per_m * (route_before_m - route_after_m)
        closing = (clear_before_m - clear_after_m) / elapsed_s
        ttc = np.where(closing > 0.0, np.maximum(clear_after_m, 0.0) / closing, np.inf)
        danger = np.maximum(0.0, 1.0 - ttc / cfg.ttc_horizon_s) ** 2
        near = np.minimum(np.maximum(0.0, 1.0 - clear_after_m / cfg.proximity_m) ** 2, 1.0)
        near = near * (1.0 + (speed_m_s / cfg.proximity_speed_m_s) ** 2)
        if cfg.braking_per_s > 0.0:
            reach = cfg.braking_margin * np.asarray(stopping_m, dtype=float)
            brake = np.where(reach > 0.0, np.maximum(0.0, 1.0 - np.asarray(free_ahead_m) / reach), 0.0) ** 2
        else:
            brake = np.zeros_like(elapsed_s, dtype=float)
    ok = ~crashed
    return {
        "progress": np.where(ok & np.isfinite(progress), progress, 0.0),
        "time": -cfg.time_per_s * elapsed_s,
        "danger": np.where(ok & np.isfinite(danger), -cfg.danger_per_s * elapsed_s * danger, 0.0),
        "proximity": np.where(ok & np.isfinite(near), -cfg.proximity_per_s * elapsed_s * near, 0.0),
        "braking": np.where(ok & np.isfinite(brake), -cfg.braking_per_s * elapsed_s * brake, 0.0),
        "arrival": np.where(arrived, cfg.arrival_bonus, 0.0),
        "collision": np.where(crashed, -cfg.collision_penalty, 0.0),
    }


def stopping_distance(speed_m_s: np.ndarray, decel_m_s2: float, lag_s: float) -> np.ndarray:
    """Stopping distance [m] from `speed_m_s` [m/s]: v² / (2 a) at deceleration a [m/s²] after v τ
    of lag τ [s] (the velocity loop's time constant) before the full deceleration is reached."""
    v = np.asarray(speed_m_s, dtype=float)
    return v * v / (2.0 * decel_m_s2) + v * lag_s
