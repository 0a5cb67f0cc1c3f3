"""How far along its path a vehicle can see, and the speed from which it can still stop within that.

A pilot on a map it knows to be incomplete takes unseen space as free (the planner must, or it could plan nothing);
it flies safely there only at a speed from which it can stop inside what it has in sight: a face hidden behind a
building it has sensed comes into view only as the path rounds the corner, and a lidar fixed to a body tilted
forward at cruise looks below the horizon ahead (the small quad at 9.5 m/s: 24-36 degrees). Frames: world ENU
metres.
"""
from __future__ import annotations

import math

import numpy as np

from uam_fdm.sensing.raycast import RayCaster

_NEAR_M = 1.0  # points this close to the eye are taken as seen (a ray from inside the sphere's own margin)
_SURFACE_M = 0.02  # a tube point cut at a known face stands this far in front of it [m]


def in_sight(eye_m: np.ndarray, path_m: np.ndarray, caster: RayCaster, max_range_m: float, tube_m: float = 0.0,
             body_to_world: np.ndarray | None = None, fov_deg: tuple[float, float] | None = None) -> np.ndarray:
    """Which points of a path (K, 3) are in sight from `eye_m` (3,): (K,) bool. A point is in sight when the straight
    line of sight to it, and to each of the 8 points round it at `tube_m` [m] across the path (a face beside the
    path hides the side of the tube the vehicle flies in, not the path's centre line), misses the caster's map and
    is at most `max_range_m` [m] long, and, given the sensor's orientation `body_to_world` (3, 3) and its fan's
    elevations `fov_deg` (lowest, highest) in that frame [deg], the point itself lies inside the fan wherever a
    level sensor's fan would hold it (its elevation above the horizon within `fov_deg`): the fan is asked where the
    attitude flown turns it away from what level flight would see (a quad tilted forward at cruise looks below the
    path ahead), not of a climb or descent steeper than the fan, which no attitude a multirotor flies would bring
    into it (a vehicle at rest on a climbing path would wait for ever).
    """
    path = np.asarray(path_m, float).reshape(-1, 3)
    eye = np.asarray(eye_m, float).reshape(3)
    points = path[:, None, :]
    if tube_m > 0.0 and len(path) > 1:
        points = path[:, None, :] + _tube_reach_m(path, caster, tube_m)  # (K, 9, 3): the centre and 8 around it
    ray = points - eye
    dist = np.linalg.norm(ray, axis=2)
    hidden = dist > max_range_m
    if body_to_world is not None and fov_deg is not None:  # the fan is asked of the centre line (the tube's width
        # subtends more than the fan near the eye)
        centre, reach = ray[:, 0, :], dist[:, 0]
        sine = centre @ np.asarray(body_to_world, float)[:, 2] / np.maximum(reach, 1e-12)
        elevation = np.degrees(np.arcsin(np.clip(sine, -1.0, 1.0)))
        level = np.degrees(np.arcsin(np.clip(centre[:, 2] / np.maximum(reach, 1e-12), -1.0, 1.0)))
        in_level_fan = (level >= fov_deg[0]) & (level <= fov_deg[1])
        outside = ((elevation < fov_deg[0]) | (elevation > fov_deg[1])) & in_level_fan & (reach > _NEAR_M)
        hidden |= outside[:, None]
    look = (dist > _NEAR_M) & ~hidden
    if np.any(look):
        # unnormalised directions: a range of 1 is the point itself (stopped just short, not at the point's surface)
        hidden[look] = caster.hits_any(eye, ray[look], 1.0 - 1e-4)
    hidden &= dist > _NEAR_M
    return ~np.any(hidden, axis=1)


def arc_in_sight_m(path_m: np.ndarray, seen: np.ndarray) -> float:
    """Arc length [m] along a path (K, 3) from its first point to its last point before the first not `seen` (K,);
    inf when every point is."""
    path = np.asarray(path_m, float).reshape(-1, 3)
    first = np.flatnonzero(~np.asarray(seen, bool))
    if first.size == 0:
        return math.inf
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    return float(arc[first[0] - 1]) if first[0] > 0 else 0.0


def _tube_reach_m(path: np.ndarray, caster: RayCaster, tube_m: float) -> np.ndarray:
    """Offsets (K, 9, 3) [m] from each point of a path (K, 3) to the tube's edge round it (`_ring` at `tube_m`),
    each cut short of the first known surface across the path: where the path passes nearer than `tube_m` to a face
    the map has, what lies beyond that face is known, not unseen (a tube point inside a wall is never in sight,
    and a reference that starts beside one would never run)."""
    ring = _ring(path)
    across = ring[:, 1:, :].reshape(-1, 3)
    moving = np.linalg.norm(across, axis=1) > 0.0
    reach = np.full(len(across), tube_m)
    if np.any(moving):
        origins = np.repeat(path, 8, axis=0)[moving]
        hit, _ = caster.first_hits(origins, across[moving], tube_m)
        # just short of the surface (Embree's float32 places it to ~1e-4 m): the line of sight must reach it
        reach[moving] = np.where(np.isfinite(hit), np.maximum(hit - _SURFACE_M, 0.0), tube_m)
    ring[:, 1:, :] *= reach.reshape(-1, 8, 1)
    return ring


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
