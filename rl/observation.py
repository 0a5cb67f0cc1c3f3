"""The learned pilot's observation and action, shared by the environment and the policy agent.

Observation (float32, `obs_size(k)` = 16 + 4k elements), element by element, for one vehicle at a
decision (world ENU, body-independent; every element roughly within [-1, 1] in normal flight and
clipped to ±OBS_CLIP):

====================  =====  =======================================================================
elements              count  meaning
====================  =====  =======================================================================
0:3   position          3    position in the flight volume, 2(p - lo)/(hi - lo) - 1 (±1 at the sides)
3:6   goal vector       3    (goal - p) / GOAL_SCALE_M (100 m)
6:9   goal direction    3    (goal - p) / |goal - p| (zero at the goal)
9:12  velocity          3    world velocity / the vehicle's max horizontal speed
12:15 angular velocity  3    body rates / RATE_SCALE_RAD_S (3 rad/s)
15    altitude          1    z / ALTITUDE_SCALE_M (100 m)
16:   buildings        4k    for each of the k nearest buildings within the sensing range, nearest
                             first: (nearest surface point - p) / range (3) and the sphere's signed
                             clearance / range (1); rows beyond the range are (0, 0, 0, 1)
====================  =====  =======================================================================

Action: a = (a_e, a_n, a_u) in [-1, 1]^3, scaled to the vehicle's limits: horizontal velocity
command (a_e, a_n) × max horizontal speed (its norm clipped to the max speed), vertical a_u × max
vertical speed. The heading is held at the episode's start yaw. The low-level controller
(`uam_fdm.control`) turns the velocity command into rotor speeds at the physics rate.
"""
from __future__ import annotations

import numpy as np

from uam_fdm.params import VehicleParams

GOAL_SCALE_M = 100.0
RATE_SCALE_RAD_S = 3.0
ALTITUDE_SCALE_M = 100.0
OBS_CLIP = 10.0
N_BASE = 16


def obs_size(k: int) -> int:
    """Observation length for k buildings."""
    return N_BASE + 4 * k


def build_observations(x: np.ndarray, goal: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                       nearest_m: np.ndarray, clearance_k_m: np.ndarray, range_m: float,
                       max_speed_m_s: float) -> np.ndarray:
    """Observations (N, 16 + 4k) float32.

    Args:
        x: states (N, 13 + n) (see `uam_fdm.model`).
        goal: goals (N, 3) ENU [m].
        lo, hi: flight-volume corners (N, 3) [m].
        nearest_m: nearest building points (N, k, 3) [m] (the query point itself for empty rows).
        clearance_k_m: signed clearances (N, k) [m], `range_m` for empty rows.
        range_m: sensing range [m].
        max_speed_m_s: the vehicle's max horizontal speed [m/s].
    """
    n = x.shape[0]
    k = nearest_m.shape[1]
    p = x[:, 0:3]
    g = goal - p
    dist = np.sqrt(np.add.reduce(g * g, axis=1))[:, None]
    rel = nearest_m - p[:, None, :]
    out = np.concatenate([
        2.0 * (p - lo) / (hi - lo) - 1.0,
        g / GOAL_SCALE_M,
        g / np.maximum(dist, 1e-9),
        x[:, 3:6] / max_speed_m_s,
        x[:, 10:13] / RATE_SCALE_RAD_S,
        p[:, 2:3] / ALTITUDE_SCALE_M,
        np.concatenate([rel, clearance_k_m[:, :, None]], axis=2).reshape(n, 4 * k) / range_m,
    ], axis=1)
    np.minimum(np.maximum(out, -OBS_CLIP, out=out), OBS_CLIP, out=out)
    return out.astype(np.float32)


def action_to_command(action: np.ndarray, p: VehicleParams, yaw_rad: np.ndarray | float) -> np.ndarray:
    """Velocity commands (N, 4) = [v_e, v_n, v_u (m/s), yaw (rad)] from actions (N, 3) in [-1, 1]."""
    a = np.minimum(np.maximum(np.asarray(action, dtype=np.float64).reshape(-1, 3), -1.0), 1.0)
    c = p.controller
    horiz = a[:, 0:2] * c.max_speed_m_s
    norm = np.sqrt(np.add.reduce(horiz * horiz, axis=1))
    cmd = np.empty((a.shape[0], 4))
    cmd[:, 0:2] = horiz * np.minimum(1.0, c.max_speed_m_s / np.maximum(norm, 1e-12))[:, None]
    cmd[:, 2] = a[:, 2] * c.max_vertical_speed_m_s
    cmd[:, 3] = yaw_rad
    return cmd
