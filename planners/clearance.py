"""The clearance contract shared by the planner and the time-parameterisation: what the reference must keep, where.

Frames: world ENU, metres.

Everywhere the vehicle's point clearance (distance from its centre to the nearest obstacle) must
exceed R(p) = radius + margin(p). The margin is the cruise margin, except

* near a start or goal, where the reference is slow and the margin follows the speed
  (`MarginTaper`: within d_i of the point, margin m_i; built by `planners.margins.SpeedMargins.taper`);
* inside the zone of a start or goal that is itself closer than radius + (its margin) to a building
  (`endpoint_allowance`): the requirement there is that point's own clearance less 5 cm.

`RequiredClearance` evaluates R at points, at one point (the planner's validity checker, pure
Python) and as conservative runs along a segment (its motion checker).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from uam_fdm.city.buildings import BuildingMap

_ENDPOINT_SLACK_M = 0.05  # a close start or goal is required to keep its own clearance less this
_MIN_PIECE_M = 0.01  # the finest split of a segment near a start or goal
_MAX_PIECE_M = 0.5  # the coarsest (the taper's steps are metres apart)


def endpoint_allowance(city: BuildingMap, point_m: np.ndarray, radius_m: float, margin_m: float
                       ) -> tuple[float, float]:
    """The clearance radius required near a start or goal, and how far from it that applies.

    Everywhere the vehicle's point clearance must exceed R = radius + margin.  A start or goal that
    is collision-free (clearance c > radius) but inside the margin would make every plan from it
    fail, so near it the requirement is relaxed to r_e = max(radius, c - 0.05 m) within
    2 (R - r_e) of it: enough to regain R when leaving at 30 degrees or more.  The vehicle is thus
    never asked to come closer to a building than it already is, and the full margin holds beyond.
    The planner and the time-parameterisation apply this same rule.

    Args:
        city: the map.
        point_m: (3,) the start or goal, ENU metres.
        radius_m: vehicle collision radius [m].
        margin_m: safety margin in force at the point [m].

    Returns:
        (required point clearance [m], radius of the relaxed zone [m]); (R, 0) when not relaxed.
    """
    big_r = float(radius_m) + float(margin_m)
    c = city.clearance_one(float(point_m[0]), float(point_m[1]), float(point_m[2]), 0.0)
    if float(radius_m) < c <= big_r:
        r_e = max(float(radius_m), c - _ENDPOINT_SLACK_M)
        return r_e, 2.0 * (big_r - r_e)
    return big_r, 0.0


@dataclass(frozen=True)
class MarginTaper:
    """A margin that narrows towards a start or goal, where the reference is slow.

    Within a straight-line distance `distances_m[i]` of `point_m` the margin is `margins_m[i]`
    (the first i that applies); beyond the last distance, the cruise margin. Distances increase,
    margins do not decrease.

    Attributes:
        point_m: the start or goal (ENU metres).
        distances_m: (n,) distances from the point [m].
        margins_m: (n,) margins beyond the collision radius [m].
    """

    point_m: tuple[float, float, float]
    distances_m: tuple[float, ...] = ()
    margins_m: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        d, m = np.asarray(self.distances_m, float), np.asarray(self.margins_m, float)
        if d.shape != m.shape or np.any(np.diff(d) < 0) or np.any(np.diff(m) < 0) or np.any(d < 0) \
                or np.any(m < 0) or not (np.all(np.isfinite(d)) and np.all(np.isfinite(m))):
            raise ValueError(f"a taper needs equal numbers of non-decreasing finite distances and margins >= 0, "
                             f"got {self.distances_m!r}, {self.margins_m!r}")

    @property
    def reach_m(self) -> float:
        """Beyond this distance the taper does not narrow the margin [m]."""
        return float(self.distances_m[-1]) if self.distances_m else 0.0

    def margin_at(self, distance_m: float, cruise_m: float) -> float:
        """The margin [m] at `distance_m` from the point (the cruise margin beyond the taper)."""
        for d, m in zip(self.distances_m, self.margins_m, strict=True):
            if distance_m <= d:
                return min(m, cruise_m)
        return cruise_m


class RequiredClearance:
    """R(p): the point clearance [m] the reference must keep at p (module docstring).

    Args:
        city: the map (its planning map: buildings and no-fly volumes).
        radius_m: vehicle collision radius [m].
        margin_m: the cruise margin [m].
        endpoints: the start and goal (ENU metres), for the relaxed zones of close ones.
        tapers: margins that narrow towards a start or goal.
    """

    def __init__(self, city: BuildingMap, radius_m: float, margin_m: float,
                 endpoints: Sequence[Sequence[float]] = (), tapers: Sequence[MarginTaper] = ()) -> None:
        self.r = float(radius_m)
        self.margin = float(margin_m)
        self.R = self.r + self.margin
        self.tapers = tuple(t for t in tapers if t.distances_m)
        # (point, relaxed radius r_e, zone radius) of each close start or goal
        self.relaxed: list[tuple[tuple[float, float, float], float, float]] = []
        for e in endpoints:
            key = (float(e[0]), float(e[1]), float(e[2]))
            r_e, zone = endpoint_allowance(city, np.array(key), radius_m, self._margin_one(*key))
            if zone > 0.0:
                self.relaxed.append((key, r_e, zone))
        self.uniform = not self.tapers and not self.relaxed
        # every special point with the distance beyond which it no longer matters
        self._reach = [(t.point_m, t.reach_m) for t in self.tapers] + [(p, z) for p, _, z in self.relaxed]
        shortest = min([z for _, _, z in self.relaxed] + [d for t in self.tapers for d in t.distances_m if d > 0]
                       + [4 * _MAX_PIECE_M])
        self._piece_m = min(_MAX_PIECE_M, max(_MIN_PIECE_M, shortest / 4.0))

    def _margin_one(self, x: float, y: float, z: float) -> float:
        m = self.margin
        for t in self.tapers:
            px, py, pz = t.point_m
            m = min(m, t.margin_at(math.sqrt((x - px) ** 2 + (y - py) ** 2 + (z - pz) ** 2), self.margin))
        return m

    def at_one(self, x: float, y: float, z: float) -> float:
        """R [m] at one point (pure Python: the planner's validity checker calls it per state)."""
        if self.uniform:
            return self.R
        req = self.r + self._margin_one(x, y, z)
        for (px, py, pz), r_e, zone in self.relaxed:
            if (x - px) ** 2 + (y - py) ** 2 + (z - pz) ** 2 <= zone * zone:
                req = min(req, r_e)
        return req

    def at(self, points_m: np.ndarray) -> np.ndarray:
        """R [m] at points (N, 3)."""
        pts = np.asarray(points_m, float).reshape(-1, 3)
        req = np.full(len(pts), self.R)
        for t in self.tapers:
            d = np.linalg.norm(pts - np.asarray(t.point_m), axis=1)
            i = np.searchsorted(np.asarray(t.distances_m), d, side="left")
            req = np.minimum(req, self.r + np.append(np.minimum(t.margins_m, self.margin), self.margin)[i])
        for p, r_e, zone in self.relaxed:
            near = np.linalg.norm(pts - np.asarray(p), axis=1) <= zone
            req[near] = np.minimum(req[near], r_e)
        return req

    def runs(self, a: tuple[float, float, float], b: tuple[float, float, float]
             ) -> list[tuple[np.ndarray, np.ndarray, float]]:
        """The segment a -> b cut into runs (start, end, R) whose R bounds R(p) from above on the run.

        Far from every start and goal: one run at the cruise R. Near one, pieces of at most 0.5 m
        (finer for a small zone), each taking R at its farther end from each special point (the
        distance to a point is convex along a segment, so its largest value on a piece is at an
        end), merged where consecutive pieces share R.
        """
        pa, pb = np.asarray(a, float), np.asarray(b, float)
        if self.uniform or not self.near(pa, pb):
            return [(pa, pb, self.R)]
        length = float(np.linalg.norm(pb - pa))
        n = max(1, math.ceil(length / self._piece_m))
        knots = pa + (pb - pa) * (np.arange(n + 1) / n)[:, None]
        req = np.full(n, self.R)
        for t in self.tapers:
            d = np.linalg.norm(knots - np.asarray(t.point_m), axis=1)
            far = np.maximum(d[:-1], d[1:])
            i = np.searchsorted(np.asarray(t.distances_m), far, side="left")
            req = np.minimum(req, self.r + np.append(np.minimum(t.margins_m, self.margin), self.margin)[i])
        for p, r_e, zone in self.relaxed:
            d = np.linalg.norm(knots - np.asarray(p), axis=1)
            inside = np.maximum(d[:-1], d[1:]) <= zone
            req[inside] = np.minimum(req[inside], r_e)
        cuts = np.concatenate(([0], np.flatnonzero(req[1:] != req[:-1]) + 1, [n]))  # where R changes
        return [(knots[i], knots[j], float(req[i])) for i, j in zip(cuts[:-1], cuts[1:])]

    def near(self, pa: Sequence[float] | np.ndarray, pb: Sequence[float] | np.ndarray) -> bool:
        """Whether the segment comes within reach of any start or goal that changes R (pure Python floats:
        the motion checker asks this for every edge the planner tries)."""
        ax, ay, az = float(pa[0]), float(pa[1]), float(pa[2])
        dx, dy, dz = float(pb[0]) - ax, float(pb[1]) - ay, float(pb[2]) - az
        den = dx * dx + dy * dy + dz * dz
        for (qx, qy, qz), reach in self._reach:
            s = 0.0 if den == 0.0 else min(1.0, max(0.0, ((qx - ax) * dx + (qy - ay) * dy + (qz - az) * dz) / den))
            ex, ey, ez = ax + s * dx - qx, ay + s * dy - qy, az + s * dz - qz
            if ex * ex + ey * ey + ez * ez <= reach * reach:
                return True
        return False
