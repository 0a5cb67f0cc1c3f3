"""How far along its path a vehicle can see, and the speed from which it can still stop within that.

A pilot on a map it knows to be incomplete takes unseen space as free (the planner must, or it could plan nothing);
it flies safely there only at a speed from which it can stop inside what it has in sight: a face hidden behind a
building it has sensed comes into view only as the path rounds the corner. Frames: world ENU metres.
"""
from __future__ import annotations

import math

import numpy as np

from uam_fdm.sensing.raycast import RayCaster

_NEAR_M = 1.0  # points this close to the eye are taken as seen (a ray from inside the sphere's own margin)


def visible_arc_m(eye_m: np.ndarray, path_m: np.ndarray, caster: RayCaster, max_range_m: float,
                  tube_m: float = 0.0) -> float:
    """Arc length [m] along `path_m` (K, 3) from its first point to its last point before the first one hidden from
    `eye_m` (3,); inf when no point is hidden. A point is hidden when the straight line of sight to it, or to any of
    the 8 points around it at `tube_m` [m] across the path (its sides, above, below and between), meets the caster's
    map or is longer than `max_range_m` [m]: a face beside the path, hidden behind a corner that was seen, hides
    the side of the tube the vehicle flies in, not the path's centre line."""
    path = np.asarray(path_m, float).reshape(-1, 3)
    eye = np.asarray(eye_m, float).reshape(3)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    points = path[:, None, :]
    if tube_m > 0.0 and len(path) > 1:
        points = path[:, None, :] + tube_m * _ring(path)  # (K, 9, 3): the centre and 8 around it
    ray = points - eye
    dist = np.linalg.norm(ray, axis=2)
    far = dist > max_range_m
    look = (dist > _NEAR_M) & ~far
    hidden = far.copy()
    if np.any(look):
        # unnormalised directions: a range of 1 is the point itself (stopped just short, not at the point's surface)
        hidden[look] = caster.hits_any(eye, ray[look], 1.0 - 1e-4)
    first = np.flatnonzero(np.any(hidden, axis=1))
    if first.size == 0:
        return math.inf
    return float(arc[first[0] - 1]) if first[0] > 0 else 0.0


def _ring(path: np.ndarray) -> np.ndarray:
    """Offsets (K, 9, 3) of unit length across a path (K, 3) at each point, and a zero one: its horizontal normal,
    the normal to that and the tangent, and the diagonals between (a point where the path does not move has
    only the zero one: its other eight are zero too)."""
    tangent = np.gradient(path, axis=0)
    length = np.linalg.norm(tangent, axis=1, keepdims=True)
    tangent = np.divide(tangent, length, out=np.zeros_like(tangent), where=length > 0.0)
    side = np.column_stack([-tangent[:, 1], tangent[:, 0], np.zeros(len(path))])
    flat = np.linalg.norm(side, axis=1, keepdims=True)
    # a vertical stretch has no horizontal normal: east is across it
    side = np.where(flat > 1e-9, side / np.maximum(flat, 1e-12), np.array([1.0, 0.0, 0.0]))
    up = np.cross(tangent, side)
    angles = np.arange(8) * math.pi / 4.0
    ring = np.cos(angles)[None, :, None] * side[:, None, :] + np.sin(angles)[None, :, None] * up[:, None, :]
    ring[length[:, 0] <= 0.0] = 0.0
    return np.concatenate([np.zeros((len(path), 1, 3)), ring], axis=1)


def stopping_speed_m_s(distance_m: float, decel_m_s2: float, reaction_s: float) -> float:
    """The largest speed [m/s] from which a vehicle that flies on for `reaction_s` [s] and then brakes at
    `decel_m_s2` [m/s²] comes to rest within `distance_m` [m]: v t + v² / 2a = d. inf for an infinite distance, 0 for
    none."""
    if not (decel_m_s2 > 0.0 and reaction_s >= 0.0):
        raise ValueError(f"decel_m_s2 must be positive and reaction_s non-negative, got {decel_m_s2!r}, "
                         f"{reaction_s!r}")
    if math.isinf(distance_m):
        return math.inf
    d = max(float(distance_m), 0.0)
    at = decel_m_s2 * reaction_s
    return -at + math.sqrt(at * at + 2.0 * decel_m_s2 * d)
