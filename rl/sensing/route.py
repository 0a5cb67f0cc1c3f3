"""Geodesic (flow-field) distance to the goal around buildings, for a potential-based progress reward.

Why: the learned pilot's progress reward is potential-based, r = Φ(s) - Φ(s') with Φ = distance
to the goal. With the straight-line (Euclidean) distance, Φ has local minima behind buildings: a
vehicle whose goal lies beyond a wall is paid to press against the wall and is charged for every
metre of the detour around it. A geodesic distance, the length of the shortest horizontal path
to the goal that goes around the buildings standing above the flight level, has no local minima:
from every point some direction descends, and descending leads to the goal. Shaping a reward with
the difference of any potential leaves the optimal policy unchanged (Ng, Harada & Russell 1999,
"Policy invariance under reward transformations"), so the change only removes the misleading
gradient, not the task.

How: per (city, goal, flight level) `route_field` rasterises the building footprints on a grid of
`cell_m` cells covering the city's horizontal bounds, marks a cell blocked when its centre lies
within `radius_m + margin_m` of the footprint of a building taller than the flight level minus
that clearance (lower buildings are flown over), and solves the eikonal equation |∇G| = 1/speed
with the fast marching method (scikit-fmm), speed 1 in free cells and `blocked_speed` in blocked
ones. A finite blocked speed keeps G defined everywhere (inside a building, in a walled-in
courtyard), still without local minima. The march starts from a small circle around the goal;
inside it G is the exact Euclidean distance.

`RouteBank` holds one field per vehicle in one padded array and answers G, the 3-D potential
sqrt(G² + Δz²) and the descent direction for all vehicles in one vectorised call. G is bilinear
between cell centres; the direction is the bilinear interpolant of central-difference gradients
(one-sided beside blocked cells, so the descent is not pushed off the walls and does not stall at
the mouth of a narrow passage); both blend into the exact straight-line answer within the
obstacle-free disk around the goal.

Accuracy: with no buildings G is the Euclidean distance to within about 1.5 m (the march's
start-up error; 4 m cells). Around buildings G over-estimates: the grid sees an obstacle's corner
only to within a cell, so each corner turned adds up to about a cell (at 4 m cells a detour round
a wall's two corners measures 2-5 % long for paths of about 200 m, and more for shorter ones;
2 m cells halve it). A blocked band is crossed rather than skirted when crossing it costs less,
i.e. when it is thinner than blocked_speed × the detour: in generated cities that happens only
across gaps between buildings narrower than the margin allows, which the vehicle can still pass.

Frames and units: world ENU metres; grids are indexed [iy, ix] (row = north, column = east) with
cell (0, 0)'s centre at `origin_m` = city bounds min + cell / 2.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import skfmm

from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.city.distance import box_frame_xy

_SEED_CELLS = 1.5    # radius of the goal circle (the march's zero level set) [cells]
_SEGMENT_SAMPLES = 8  # samples on each goal-to-cell segment when testing line of sight near the goal


@dataclass(frozen=True)
class RouteConfig:
    """Grid and cost settings of a route field.

    Attributes:
        cell_m: grid cell size [m].
        margin_m: clearance on top of the vehicle radius [m]: footprints are inflated by radius + margin.
        blocked_speed: relative travel speed in blocked cells (free = 1), in (0, 1]: a blocked cell
            costs 1 / blocked_speed per metre. Finite, so G is defined everywhere without local
            minima; a blocked band thinner than (detour around it) × blocked_speed is cheaper to
            cross than to go around, so it must stay small.
        climb_weight: k in the 3-D potential sqrt(G² + (k Δz)²): a metre of height difference
            counts as k metres of route (1 for the small quad; more for a vehicle whose climb is
            much slower than its cruise, so that closing the height gap earns a fair progress rate).
        level_step_m: None: one field at the higher of start and goal (buildings below it are flown
            over: right when the climb between them is short). A number: fields at flight levels
            from the lower to the higher of start and goal, at most this far apart (`flight_levels`);
            G at a point interpolates linearly in altitude between the two levels around it
            (clamped at the ends), so a building taller than the lower end blocks the route at the
            altitudes it stands in instead of being flown through.
        refresh_s: below perfect sensing, the pilot's route is redrawn around the columns its lidar sensed
            (`rl.sensing.route_refresh`) at decisions this far apart [s], when a sensed column stands where the
            route is open (0: the prior map's route all episode).
    """

    cell_m: float = 4.0
    margin_m: float = 3.0
    blocked_speed: float = 0.1
    climb_weight: float = 1.0
    level_step_m: float | None = None
    refresh_s: float = 0.0

    def __post_init__(self) -> None:
        if not (self.cell_m > 0 and math.isfinite(self.cell_m)):
            raise ValueError(f"cell_m must be positive and finite, got {self.cell_m}")
        if not (self.margin_m >= 0 and math.isfinite(self.margin_m)):
            raise ValueError(f"margin_m must be >= 0 and finite, got {self.margin_m}")
        if not 0 < self.blocked_speed <= 1:
            raise ValueError(f"blocked_speed must be in (0, 1], got {self.blocked_speed}")
        if not (self.climb_weight > 0 and math.isfinite(self.climb_weight)):
            raise ValueError(f"climb_weight must be positive and finite, got {self.climb_weight}")
        if self.level_step_m is not None and not (self.level_step_m > 0 and math.isfinite(self.level_step_m)):
            raise ValueError(f"level_step_m must be None or positive and finite, got {self.level_step_m}")
        if not (self.refresh_s >= 0 and math.isfinite(self.refresh_s)):
            raise ValueError(f"refresh_s must be >= 0 and finite, got {self.refresh_s}")


def flight_levels(z_a_m: float, z_b_m: float, step_m: float | None) -> tuple[float, ...]:
    """The route fields' flight levels [m] for a leg between altitudes z_a and z_b: the higher alone
    (step None, or the two within 1 mm), else evenly spaced from the lower to the higher, at most
    `step_m` apart."""
    lo, hi = min(z_a_m, z_b_m), max(z_a_m, z_b_m)
    if step_m is None or hi - lo < 1e-3:
        return (float(hi),)
    n = int(math.ceil((hi - lo) / step_m - 1e-9)) + 1
    return tuple(float(z) for z in np.linspace(lo, hi, n))


def max_levels(altitude_range_m: tuple[float, float], step_m: float | None) -> int:
    """The most flight levels a leg between altitudes in `altitude_range_m` [m] can need (sizes a `RouteBank`)."""
    return len(flight_levels(altitude_range_m[0], altitude_range_m[1], step_m))


@dataclass(frozen=True)
class RouteField:
    """Geodesic horizontal distance to one goal over one city's grid.

    Attributes:
        distance_m: (ny, nx) float32 travel distance G [m] from each cell centre to the goal
            (rows = y / north, columns = x / east); read-only.
        origin_m: world (x, y) of cell (0, 0)'s centre, ENU metres.
        cell_m: cell size [m].
        goal_m: the goal (x, y, z), ENU metres (z is used by the 3-D potential only).
        blocked: (ny, nx) bool, the cells marked blocked (inflated footprints of buildings above the
            flight level); read-only.
        clear_radius_m: radius [m] of the disk around the goal, at most the goal circle's radius, that
            holds no blocking footprint inflated by the vehicle radius (0 when the goal is inside
            one); within it the straight line to the goal is free and G is Euclidean.
    """

    distance_m: np.ndarray
    origin_m: tuple[float, float]
    cell_m: float
    goal_m: tuple[float, float, float]
    blocked: np.ndarray
    clear_radius_m: float

    @property
    def shape(self) -> tuple[int, int]:
        """Grid shape (ny, nx)."""
        return self.distance_m.shape


@dataclass(frozen=True)
class LeveledRoute:
    """Route fields of one goal over one city's grid at increasing, evenly spaced flight levels.

    Attributes:
        levels_m: the flight levels [m] (one or more, increasing, evenly spaced).
        fields: the field at each level (same grid and goal).
    """

    levels_m: tuple[float, ...]
    fields: tuple[RouteField, ...]

    def __post_init__(self) -> None:
        if len(self.levels_m) != len(self.fields) or not self.fields:
            raise ValueError(f"need one field per level, got {len(self.fields)} fields for {len(self.levels_m)} levels")
        gaps = np.diff(self.levels_m)
        if len(gaps) and (np.any(gaps <= 0) or np.ptp(gaps) > 1e-6 * max(1.0, float(gaps[0]))):
            raise ValueError(f"flight levels must increase evenly, got {self.levels_m}")
        if len({(f.shape, f.origin_m, f.cell_m, f.goal_m) for f in self.fields}) != 1:
            raise ValueError("the fields of a leveled route must share their grid and goal")


def leveled_route(city: BuildingMap, goal_m: Sequence[float], levels_m: Sequence[float], radius_m: float,
                  config: RouteConfig = RouteConfig(), columns: np.ndarray | None = None) -> LeveledRoute:
    """`route_field` at each flight level of `levels_m` [m] (increasing, evenly spaced), with `columns` standing
    beside the city's buildings (see `route_field`)."""
    levels = tuple(float(z) for z in levels_m)
    return LeveledRoute(levels, tuple(route_field(city, goal_m, z, radius_m, config, columns) for z in levels))


def grid_shape(city: BuildingMap, cell_m: float = RouteConfig.cell_m) -> tuple[int, int]:
    """Grid shape (ny, nx) of `city`'s route fields at `cell_m` [m], at least 2 x 2 (sizes a `RouteBank`)."""
    ext = np.asarray(city.bounds_max_m[:2], dtype=float) - np.asarray(city.bounds_min_m[:2], dtype=float)
    n = np.maximum(np.ceil(ext / cell_m - 1e-9).astype(np.int64), 2)
    return int(n[1]), int(n[0])


def _blocking_boxes(city: BuildingMap, min_height_m: float) -> np.ndarray:
    """(B, 6) rows cx, cy, cos(yaw), sin(yaw), half x, half y of the buildings taller than `min_height_m`."""
    rows = []
    for b in city.buildings:
        if not isinstance(b, Building):
            raise ValueError(f"city {city.name!r}: route fields need box buildings only, "
                             f"got a {type(b).__name__}")
        if b.height_m > min_height_m:
            rows.append((b.center_xy_m[0], b.center_xy_m[1], math.cos(b.yaw_rad), math.sin(b.yaw_rad),
                         0.5 * b.size_xy_m[0], 0.5 * b.size_xy_m[1]))
    return np.asarray(rows, dtype=float).reshape(-1, 6)


def _box_sq_distance(boxes: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Squared horizontal distance [m²] from points (x, y) to box footprints (0 inside).

    `boxes` is (B, 6); x, y have a leading axis of 1 or B and broadcast to (B, ...). Each point is
    taken into each box's own frame (x along the box's x axis) and compared with its half sizes.
    """
    sh = (-1,) + (1,) * (np.ndim(x) - 1)
    cx, cy, co, si, hx, hy = (boxes[:, k].reshape(sh) for k in range(6))
    lx, ly = box_frame_xy(x, y, cx, cy, co, si)
    qx = np.maximum(np.abs(lx) - hx, 0.0)
    qy = np.maximum(np.abs(ly) - hy, 0.0)
    return qx * qx + qy * qy


def _rasterise(boxes: np.ndarray, reach_m: float, origin: np.ndarray, cell_m: float,
               shape: tuple[int, int]) -> np.ndarray:
    """(ny, nx) bool: cells whose centre lies within `reach_m` of a box footprint.

    Vectorised over buildings: each box's cell window (its footprint's bounding box grown by the
    reach) is padded to the largest window; the window's cell centres are tested in the box's frame.
    """
    ny, nx = shape
    mask = np.zeros(ny * nx, dtype=bool)
    if len(boxes) == 0:
        return mask.reshape(shape)
    cx, cy, co, si, hx, hy = boxes.T
    ex = np.abs(co) * hx + np.abs(si) * hy + reach_m  # half extents of the grown axis-aligned bounding box
    ey = np.abs(si) * hx + np.abs(co) * hy + reach_m
    ix0 = np.clip(np.ceil((cx - ex - origin[0]) / cell_m), 0, nx).astype(np.int64)
    ix1 = np.clip(np.floor((cx + ex - origin[0]) / cell_m), -1, nx - 1).astype(np.int64)
    iy0 = np.clip(np.ceil((cy - ey - origin[1]) / cell_m), 0, ny).astype(np.int64)
    iy1 = np.clip(np.floor((cy + ey - origin[1]) / cell_m), -1, ny - 1).astype(np.int64)
    wx = int(max(np.max(ix1 - ix0 + 1), 0))
    wy = int(max(np.max(iy1 - iy0 + 1), 0))
    if wx == 0 or wy == 0:
        return mask.reshape(shape)
    ix = ix0[:, None] + np.arange(wx)  # (B, wx)
    iy = iy0[:, None] + np.arange(wy)  # (B, wy)
    x = (origin[0] + cell_m * ix)[:, None, :]  # (B, 1, wx)
    y = (origin[1] + cell_m * iy)[:, :, None]  # (B, wy, 1)
    hit = _box_sq_distance(boxes, x, y) <= reach_m * reach_m  # (B, wy, wx)
    hit &= (ix <= ix1[:, None])[:, None, :] & (iy <= iy1[:, None])[:, :, None]
    flat = iy[:, :, None] * nx + ix[:, None, :]
    mask[flat[hit]] = True
    return mask.reshape(shape)


def route_field(city: BuildingMap, goal_m: Sequence[float], ref_altitude_m: float, radius_m: float,
                config: RouteConfig = RouteConfig(), columns: np.ndarray | None = None) -> RouteField:
    """The geodesic horizontal distance to `goal_m` over `city`, flying at `ref_altitude_m`.

    Blocked cells: centre within radius_m + margin_m of the footprint of a building with
    height_m > ref_altitude_m - radius_m - margin_m (a lower building is flown over at cost 1).
    G is the fast-marching travel time (scikit-fmm, second order) with speed 1 in free cells and
    `blocked_speed` in blocked ones, from a circle of 1.5 cells around the goal; inside that circle
    G is the exact Euclidean distance for the cells in line of sight of the goal (the cells hidden
    by a footprint inflated by `radius_m` are marched to like the rest).

    Args:
        city: box-building city (ENU metres).
        goal_m: goal (x, y, z) [m]; x, y within the city's horizontal bounds, anywhere in free space
            (a goal inside an inflated footprint is served too: its neighbourhood is the source).
        ref_altitude_m: flight level [m] above the ground deciding which buildings block.
        radius_m: the vehicle's collision radius [m].
        config: grid and cost settings.
        columns: (K, 5) more obstacles standing on the ground, axis-aligned: x0, y0, x1, y1 [m] (their footprint's
            corners) and height [m] (e.g. what a lidar sensed, `rl.sensing.route_refresh`); None: the city alone.

    Raises:
        ValueError: non-box buildings, a goal outside the horizontal bounds, non-finite inputs.
    """
    goal = np.asarray(goal_m, dtype=float).reshape(-1)
    if goal.shape != (3,) or not np.all(np.isfinite(goal)):
        raise ValueError(f"goal_m must be 3 finite numbers, got {goal_m!r}")
    if not (radius_m >= 0 and math.isfinite(radius_m) and math.isfinite(ref_altitude_m)):
        raise ValueError(f"need a finite radius >= 0 and a finite reference altitude, "
                         f"got {radius_m}, {ref_altitude_m}")
    lo = np.asarray(city.bounds_min_m[:2], dtype=float)
    hi = np.asarray(city.bounds_max_m[:2], dtype=float)
    tol = 1e-9 * (1.0 + float(np.max(np.abs(hi))))
    if np.any(goal[:2] < lo - tol) or np.any(goal[:2] > hi + tol):
        raise ValueError(f"goal {goal[:2].tolist()} outside the city's horizontal bounds "
                         f"{lo.tolist()} .. {hi.tolist()}")
    h = float(config.cell_m)
    shape = grid_shape(city, h)
    ny, nx = shape
    origin = lo + 0.5 * h
    reach = float(radius_m) + float(config.margin_m)
    boxes = _blocking_boxes(city, float(ref_altitude_m) - reach)
    if columns is not None and len(columns):
        tall = columns[columns[:, 4] > float(ref_altitude_m) - reach]
        half_x, half_y = 0.5 * (tall[:, 2] - tall[:, 0]), 0.5 * (tall[:, 3] - tall[:, 1])
        boxes = np.concatenate([boxes, np.stack([tall[:, 0] + half_x, tall[:, 1] + half_y, np.ones(len(tall)),
                                                 np.zeros(len(tall)), half_x, half_y], axis=1)])
    blocked = _rasterise(boxes, reach, origin, h, shape)

    # Distance of every cell centre to the goal; the source circle (zero level set) around it.
    xs = origin[0] + h * np.arange(nx)
    ys = origin[1] + h * np.arange(ny)
    euclid = np.hypot(xs[None, :] - goal[0], ys[:, None] - goal[1])
    r0 = _SEED_CELLS * h
    disk_iy, disk_ix = np.nonzero(euclid <= r0)  # never empty: the goal's nearest centre is within 0.71 h
    # Line of sight from the goal to each disk cell against footprints inflated by the radius.
    t = np.linspace(0.0, 1.0, _SEGMENT_SAMPLES)
    px = goal[0] + t[None, :] * (xs[disk_ix][:, None] - goal[0])  # (D, S)
    py = goal[1] + t[None, :] * (ys[disk_iy][:, None] - goal[1])
    r2 = float(radius_m) ** 2
    if len(boxes):
        d2 = _box_sq_distance(boxes, px[None], py[None])  # (B, D, S)
        seen = np.all(d2 > r2, axis=(0, 2))
        goal_d2 = _box_sq_distance(boxes, goal[None, 0:1], goal[None, 1:2])[:, 0]
        clear = float(min(max(math.sqrt(float(goal_d2.min())) - float(radius_m), 0.0), r0))
    else:
        seen = np.ones(len(disk_ix), dtype=bool)
        clear = r0
    if not seen.any():  # the goal itself is inside a footprint: its whole disk is the source
        seen[:] = True
    source = np.zeros(shape, dtype=bool)
    source[disk_iy[seen], disk_ix[seen]] = True
    phi = euclid - r0
    phi[(euclid <= r0) & ~source] = 0.5 * h  # hidden disk cells lie outside the source circle
    if source.all():
        dist = euclid
    else:
        speed = np.where(blocked, float(config.blocked_speed), 1.0)
        travel = np.asarray(skfmm.travel_time(phi, speed, dx=h, order=2), dtype=float)
        dist = np.where(source, euclid, travel + r0)
    dist = dist.astype(np.float32)
    dist.setflags(write=False)
    blocked.setflags(write=False)
    return RouteField(distance_m=dist, origin_m=(float(origin[0]), float(origin[1])),
                      cell_m=h, goal_m=(float(goal[0]), float(goal[1]), float(goal[2])), blocked=blocked,
                      clear_radius_m=clear)


def _gradient(g: np.ndarray, free: np.ndarray, cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(dG/dx, dG/dy) at cell centres [m/m]: central differences, one-sided beside blocked cells.

    At a free cell a blocked neighbour's value is not used (its much larger G would push the
    descent away from the walls and stall it at the mouth of a one-cell passage); with both
    neighbours of an axis blocked that component is 0. Blocked cells use plain central differences
    (pointing out of the obstacle). Grid edges use the one-sided difference.
    """
    gx = _gradient_along_rows(g, free, cell_m)
    gy = _gradient_along_rows(g.T, free.T, cell_m).T
    return gx, gy


def _gradient_along_rows(g: np.ndarray, free: np.ndarray, cell_m: float) -> np.ndarray:
    """`_gradient`'s component along the last axis."""
    d = (g[:, 1:] - g[:, :-1]) / cell_m  # d[:, k] = (G[k + 1] - G[k]) / h
    blocked = ~free
    prev_ok = np.zeros(g.shape, dtype=bool)  # the previous cell exists and may be used
    prev_ok[:, 1:] = free[:, :-1] | blocked[:, 1:]
    next_ok = np.zeros(g.shape, dtype=bool)
    next_ok[:, :-1] = free[:, 1:] | blocked[:, :-1]
    back = np.zeros(g.shape)
    back[:, 1:] = d
    fwd = np.zeros(g.shape)
    fwd[:, :-1] = d
    both = prev_ok & next_ok
    return np.where(both, 0.5 * (back + fwd), np.where(prev_ok, back, np.where(next_ok, fwd, 0.0)))


class RouteBank:
    """Route fields for N slots (one per vehicle), stored padded in one array, queried in one call.

    Each slot holds one `RouteField` (its own city grid, origin, cell size and goal), or a
    `LeveledRoute` of up to `levels` of them, in (levels, ny_max, nx_max) blocks of G and its
    central-difference gradient. Queries take one point per slot (or points for chosen slots), clamp
    it to the slot's grid (outside the grid the value at the nearest edge point: continuous, finite)
    and interpolate bilinearly, and between the two flight levels around the point's altitude
    linearly (clamped to the lowest and highest). A slot never set, or a point with a NaN
    coordinate, answers NaN.

    Args:
        n: number of slots.
        max_cells: (ny_max, nx_max), the largest grid shape a slot will hold (see `grid_shape`).
        climb_weight: k of the potential (`RouteConfig.climb_weight`).
        levels: the most flight levels a slot will hold (see `max_levels`).
    """

    def __init__(self, n: int, max_cells: tuple[int, int], climb_weight: float = 1.0, levels: int = 1) -> None:
        ny, nx = (int(v) for v in max_cells)
        if n < 1 or ny < 2 or nx < 2 or int(levels) != levels or levels < 1:
            raise ValueError(f"need n >= 1, max_cells >= (2, 2) and levels >= 1, got {n}, {max_cells}, {levels}")
        self.n, self.max_cells, self.levels = int(n), (ny, nx), int(levels)
        self.climb_weight = float(climb_weight)
        self._stride = nx
        self._block = ny * nx
        # Per cell: G, dG/dx, dG/dy (float32); block (slot, level) at slot * levels + level, cells row-major.
        self._data = np.full((self.n * self.levels * self._block, 3), np.nan, dtype=np.float32)
        self._origin = np.zeros((self.n, 2))
        self._inv_cell = np.ones(self.n)
        self._last = np.ones((self.n, 2))  # (nx - 1, ny - 1): the clamp limits in cell units
        self._goal = np.zeros((self.n, 3))
        self._clear = np.zeros(self.n)
        self._z0 = np.zeros(self.n)  # lowest flight level [m]
        self._inv_dz = np.zeros(self.n)  # 1 / level spacing [1/m] (0 with one level)
        self._top = np.zeros(self.n)  # index of the highest level

    def set(self, i: int, route: RouteField | LeveledRoute) -> None:
        """Store `route` in slot i (its grid must fit in `max_cells`, its levels in `levels`)."""
        if not 0 <= i < self.n:
            raise IndexError(f"slot {i} out of range 0..{self.n - 1}")
        if isinstance(route, RouteField):
            route = LeveledRoute((0.0,), (route,))
        if len(route.fields) > self.levels:
            raise ValueError(f"{len(route.fields)} flight levels do not fit the bank's {self.levels}")
        first = route.fields[0]
        ny, nx = first.distance_m.shape
        if ny > self.max_cells[0] or nx > self.max_cells[1] or ny < 2 or nx < 2:
            raise ValueError(f"field grid {(ny, nx)} does not fit the bank's max_cells {self.max_cells}")
        for lvl, field in enumerate(route.fields):
            g = field.distance_m.astype(np.float64)
            gx, gy = _gradient(g, ~field.blocked, field.cell_m)
            k = i * self.levels + lvl
            block = self._data[k * self._block:(k + 1) * self._block].reshape(self.max_cells + (3,))
            block[:] = np.nan
            block[:ny, :nx, 0] = g
            block[:ny, :nx, 1] = gx
            block[:ny, :nx, 2] = gy
        levels = route.levels_m
        self._origin[i] = first.origin_m
        self._inv_cell[i] = 1.0 / first.cell_m
        self._last[i] = (nx - 1, ny - 1)
        self._goal[i] = first.goal_m
        # the straight-line blend near the goal uses the obstacle-free disk at the goal's own level
        at_goal = int(np.argmin(np.abs(np.asarray(levels) - first.goal_m[2]))) if len(levels) > 1 else 0
        self._clear[i] = route.fields[at_goal].clear_radius_m
        self._z0[i] = levels[0]
        self._inv_dz[i] = 1.0 / (levels[1] - levels[0]) if len(levels) > 1 else 0.0
        self._top[i] = len(levels) - 1

    def _slots(self, points_m: np.ndarray, slots: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        p = np.asarray(points_m, dtype=float).reshape(-1, 3)
        if slots is None:
            if len(p) != self.n:
                raise ValueError(f"expected {self.n} points (one per slot), got {len(p)}; "
                                 "pass slots= for a subset")
            s = np.arange(self.n)
        else:
            s = np.asarray(slots, dtype=np.int64).reshape(-1)
            if len(s) != len(p):
                raise ValueError(f"{len(p)} points for {len(s)} slots")
        return p, s

    def _sample(self, p: np.ndarray, s: np.ndarray, grad: bool) -> np.ndarray:
        """G (M,) or (G, dG/dx, dG/dy) (M, 3) at points p (M, 3) of slots s (M,): bilinear on each
        level's grid, linear between the two levels around the altitude."""
        if self.levels == 1:
            return self._sample_level(p, s, s, grad)
        lvl, t = self._level(p[:, 2], s)
        k = s * self.levels + lvl
        below = self._sample_level(p, s, k, grad)
        above = self._sample_level(p, s, k + (lvl < self._top[s]), grad)
        t = t[:, None] if grad else t
        return (1.0 - t) * below + t * above

    def _level(self, z: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Index (M,) of the level at or below altitudes z (M,) [m] of slots s (clamped) and the
        interpolation weight (M,) of the one above it."""
        f = np.clip(np.nan_to_num((z - self._z0[s]) * self._inv_dz[s]), 0.0, self._top[s])
        lvl = np.minimum(f.astype(np.int64), np.maximum(self._top[s].astype(np.int64) - 1, 0))
        return lvl, f - lvl

    def _sample_level(self, p: np.ndarray, s: np.ndarray, k: np.ndarray, grad: bool) -> np.ndarray:
        """Bilinear G (M,) or (G, dG/dx, dG/dy) (M, 3) at points p (M, 3) of slots s (M,) on blocks k (M,)."""
        f = (p[:, :2] - self._origin[s]) * self._inv_cell[s, None]
        nan = np.isnan(f).any(axis=1)  # a non-finite state (a crashed vehicle): NaN out, not an index error
        if nan.any():
            f[nan] = 0.0
        np.clip(f, 0.0, self._last[s], out=f)
        i0 = np.minimum(f.astype(np.int64), self._last[s].astype(np.int64) - 1)
        t = f - i0
        base = k * self._block + i0[:, 1] * self._stride + i0[:, 0]
        idx = base[:, None] + np.array([0, 1, self._stride, self._stride + 1])
        tx, ty = t[:, 0:1], t[:, 1:2]
        w = np.concatenate([(1 - tx) * (1 - ty), tx * (1 - ty), (1 - tx) * ty, tx * ty], axis=1)  # (M, 4)
        if grad:
            out = np.einsum("mk,mkc->mc", w, self._data[idx])
        else:
            out = np.einsum("mk,mk->m", w, self._data[idx, 0])
        if nan.any():
            out[nan] = np.nan
        return out

    def _sample_one(self, x: float, y: float, z: float, s: int, grad: bool) -> np.ndarray | None:
        """`_sample` of one point (see `_sample_one_level`)."""
        if self.levels == 1:
            return self._sample_one_level(x, y, s, s, grad)
        lvl, t = self._level(np.array([z]), np.array([s]))
        k = s * self.levels + int(lvl[0])
        below = self._sample_one_level(x, y, s, k, grad)
        if below is None:
            return None
        above = self._sample_one_level(x, y, s, k + int(lvl[0] < self._top[s]), grad)
        t = t[:, None] if grad else t
        return (1.0 - t) * below + t * above

    def _sample_one_level(self, x: float, y: float, s: int, k: int, grad: bool) -> np.ndarray | None:
        """`_sample_level` of one point, (1,) or (1, 3), or None for a NaN coordinate: the cell lookup and the
        weights in plain Python (NumPy's per-call overhead on one row dominated a single vehicle's
        step), the same operations on the same doubles; the weighted sum is `_sample_level`'s own einsum on
        operands of the same shapes and types, so the summation order is the same too."""
        ox, oy = self._origin[s].tolist()
        inv = float(self._inv_cell[s])
        fx, fy = (x - ox) * inv, (y - oy) * inv
        if fx != fx or fy != fy:
            return None
        lx, ly = self._last[s].tolist()
        # np.clip(f, 0, last) with array bounds: the bound where f is not beyond it (-0.0 -> 0.0)
        fx = lx if fx >= lx else (fx if fx > 0.0 else 0.0)
        fy = ly if fy >= ly else (fy if fy > 0.0 else 0.0)
        ix, iy = min(int(fx), int(lx) - 1), min(int(fy), int(ly) - 1)
        tx, ty = fx - ix, fy - iy
        base = k * self._block + iy * self._stride + ix
        idx = np.array([[base, base + 1, base + self._stride, base + self._stride + 1]])
        w = np.array([[(1 - tx) * (1 - ty), tx * (1 - ty), (1 - tx) * ty, tx * ty]])
        if grad:
            return np.einsum("mk,mkc->mc", w, self._data[idx])
        return np.einsum("mk,mk->m", w, self._data[idx, 0])

    def _near_goal_one(self, x: float, y: float, s: int) -> tuple[float, float, float, float]:
        """`_near_goal` of one point in plain Python: (to-goal x, y, length, weight); np.hypot as there."""
        gx, gy = self._goal[s, :2].tolist()
        tx, ty = gx - x, gy - y
        dn = float(np.hypot(tx, ty))
        clear = float(self._clear[s])
        v = 2.0 - 2.0 * dn / (clear if clear > 0 else 1.0)
        v = 0.0 if v < 0.0 else (1.0 if v > 1.0 else v)  # np.clip with scalar bounds (NaN stays NaN)
        return tx, ty, dn, v * (clear > 0)

    def _potential_one(self, p: np.ndarray, s: int) -> np.ndarray:
        """`potential` (1,) of one point (see `_sample_one`)."""
        x, y, z = p.tolist()
        sample = self._sample_one(x, y, z, s, grad=False)
        if sample is None:
            return np.array([math.nan])
        _, _, dn, w = self._near_goal_one(x, y, s)
        g = w * dn + (1.0 - w) * float(sample[0])
        dz = (z - float(self._goal[s, 2])) * self.climb_weight
        return np.array([math.sqrt(g * g + dz * dz)])

    def _direction_one(self, p: np.ndarray, s: int) -> np.ndarray:
        """`direction` (1, 2) of one point (see `_sample_one`)."""
        x, y, z = p.tolist()
        sample = self._sample_one(x, y, z, s, grad=True)
        if sample is None:
            return np.full((1, 2), math.nan)
        gx, gy = (-sample[0, 1:3]).tolist()
        gn = float(np.hypot(gx, gy))
        gn = gn if gn > 1e-12 else math.inf
        gx, gy = gx / gn, gy / gn
        tx, ty, dn, w = self._near_goal_one(x, y, s)
        dn = dn if dn > 1e-9 else math.inf
        tx, ty = tx / dn, ty / dn
        dx, dy = w * tx + (1.0 - w) * gx, w * ty + (1.0 - w) * gy
        n = float(np.hypot(dx, dy))
        n = n if n > 1e-12 else math.inf
        return np.array([[dx / n, dy / n]])

    def _near_goal(self, p: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Horizontal offsets to the goal (M, 2) [m], their lengths (M,) [m] and the weight (M,) of the exact
        straight-line answer: 1 within half the clear radius, falling linearly to 0 at the clear radius."""
        to_goal = self._goal[s, :2] - p[:, :2]
        dn = np.hypot(to_goal[:, 0], to_goal[:, 1])
        clear = self._clear[s]
        w = np.clip(2.0 - 2.0 * dn / np.where(clear > 0, clear, 1.0), 0.0, 1.0) * (clear > 0)
        return to_goal, dn, w

    def _distance(self, p: np.ndarray, s: np.ndarray) -> np.ndarray:
        _, dn, w = self._near_goal(p, s)
        return w * dn + (1.0 - w) * self._sample(p, s, grad=False)

    def distance(self, points_m: np.ndarray, slots: np.ndarray | None = None) -> np.ndarray:
        """Geodesic horizontal distance G [m] (M,) of points (M, 3) ENU metres to their slots' goals.

        Without `slots`, M = n and point i belongs to slot i. Bilinear between cell centres; within
        the obstacle-free disk around the goal (`RouteField.clear_radius_m`) it blends into the exact
        Euclidean distance (fully so in the inner half), so G is 0 at the goal.
        """
        p, s = self._slots(points_m, slots)
        return self._distance(p, s)

    def potential(self, points_m: np.ndarray, slots: np.ndarray | None = None) -> np.ndarray:
        """3-D potential sqrt(G² + (k (z - z_goal))²) [m] (M,) of points (M, 3) ENU metres (k: `climb_weight`)."""
        p, s = self._slots(points_m, slots)
        if len(s) == 1:
            return self._potential_one(p[0], int(s[0]))
        g = self._distance(p, s)
        dz = (p[:, 2] - self._goal[s, 2]) * self.climb_weight
        return np.sqrt(g * g + dz * dz)

    def direction(self, points_m: np.ndarray, slots: np.ndarray | None = None) -> np.ndarray:
        """(M, 2) unit horizontal direction (east, north) of steepest descent of G: the route's way.

        The bilinear interpolant of G's central-difference gradient (one-sided beside blocked cells),
        negated and normalised; within the obstacle-free disk around the goal it blends into the
        straight line to the goal as `distance` does. Zero at the goal and wherever the gradient
        vanishes.
        """
        p, s = self._slots(points_m, slots)
        if len(s) == 1:
            return self._direction_one(p[0], int(s[0]))
        g = -self._sample(p, s, grad=True)[:, 1:3]
        gn = np.hypot(g[:, 0], g[:, 1])
        g /= np.where(gn > 1e-12, gn, np.inf)[:, None]
        to_goal, dn, w = self._near_goal(p, s)
        to_goal /= np.where(dn > 1e-9, dn, np.inf)[:, None]
        d = w[:, None] * to_goal + (1.0 - w[:, None]) * g
        n = np.hypot(d[:, 0], d[:, 1])
        d /= np.where(n > 1e-12, n, np.inf)[:, None]
        return d
