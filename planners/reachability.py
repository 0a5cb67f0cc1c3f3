"""Is a goal reachable at a margin? A two-sided grid test that tells a planner failure on a reachable goal
from one on a goal no path reaches.

A sampling planner's failure proves nothing: RRT* may simply not have entered a narrow passage within its
budget. This test decides, where it can, with a proof either way. The space the planner searches is the
box of the map's flight volume shrunk by R = radius + margin (its state bounds) with the positions whose
point clearance d(p) (distance to the nearest building, no-fly volume or the ground) exceeds the
required clearance R(p) (`planners.clearance.RequiredClearance`: R, relaxed only inside the zone of a start
or goal that is itself inside the margin). The box is cut into n_x x n_y x n_z cells (sides c_i <= c); every
point of a cell lies within h = |c| / 2 of its centre, and d is 1-Lipschitz, so from the exact clearance at
the centres alone:

* a cell with d(centre) - h > R is **certainly free** (every point of it is valid), and a segment between the
  centres of two face-adjacent certainly free cells lies inside their union;
* a cell with d(centre) + h <= R_low (the smallest requirement anywhere in it) is **certainly blocked**.

*Reachable* (proved): the start and the goal are joined to certainly free cells by straight motions the
planner itself accepts (`FreeSpace.edge_ok`, exact swept spheres), and those cells are connected through
face-adjacent certainly free cells (or the straight motion from start to goal is valid). *Unreachable*
(proved): in the grid of cells not certainly blocked, connected through faces, edges and corners (any
continuous path crosses such a chain), the start's cell and the goal's cell lie apart. Otherwise the
test halves c and tries again, up to `max_cells`; what is still open is *undetermined*, and says at
which cell size.

Frames and units: world ENU, metres.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy import ndimage

from planners.rrt_star import FreeSpace
from uam_fdm.city.buildings import BuildingMap

Verdict = Literal["reachable", "unreachable", "undetermined"]

_FACES = ndimage.generate_binary_structure(3, 1)  # 6-connected: shared faces
_TOUCHING = ndimage.generate_binary_structure(3, 3)  # 26-connected: faces, edges, corners
_HOOKUP_CELLS = 2  # a start or goal is joined to certainly free cells at most this many cells away per axis
_CHUNK = 200_000  # points per clearance call (memory: the vectorised distance is points x obstacle parts)


@dataclass(frozen=True)
class Reachability:
    """The test's answer.

    Attributes:
        verdict: "reachable" or "unreachable" (proved, see the module docstring), or "undetermined" at the
            finest grid tried.
        margin_m: the margin tested, beyond the collision radius [m].
        cell_m: the largest cell side of the finest grid tried [m].
        cells: cells of that grid.
        reason: one sentence for reports and failure messages.
    """

    verdict: Verdict
    margin_m: float
    cell_m: float
    cells: int
    reason: str


def check_reachable(city: BuildingMap, start_m: Sequence[float] | np.ndarray, goal_m: Sequence[float] | np.ndarray,
                    radius_m: float, margin_m: float, cell_m: float | None = None,
                    max_cells: int = 4_000_000) -> Reachability:
    """Whether a path from start to goal exists that keeps `margin_m` beyond `radius_m` (module docstring).

    Args:
        city: the map (its planning map is used: buildings and no-fly volumes, as the planner's).
        start_m, goal_m: (3,) ENU metres.
        radius_m: vehicle collision radius [m].
        margin_m: the margin beyond it [m] (the planner's floor margin for a "no path at the floor margin"
            failure).
        cell_m: the first grid's largest cell side [m] (None: about 100 cells along the longest side, at
            least R).
        max_cells: the finest grid allowed (cells).

    Returns:
        A Reachability; a start or goal that is itself invalid is "unreachable" with that reason.

    Raises:
        ValueError: a negative radius or margin, a non-positive cell, or no room inside the bounds.
    """
    r, m = float(radius_m), float(margin_m)
    if not (math.isfinite(r) and r >= 0 and math.isfinite(m) and m >= 0):
        raise ValueError(f"radius_m and margin_m must be finite and >= 0, got {radius_m!r}, {margin_m!r}")
    if cell_m is not None and not (math.isfinite(cell_m) and cell_m > 0):
        raise ValueError(f"cell_m must be positive, got {cell_m!r}")
    plan_map = city.planning_map()
    s = _xyz(start_m)
    g = _xyz(goal_m)
    free = FreeSpace(plan_map, r, m, (s, g))
    big_r = free.R
    lo = np.asarray(plan_map.bounds_min_m, float) + big_r
    hi = np.asarray(plan_map.bounds_max_m, float) - big_r
    if np.any(hi <= lo):
        raise ValueError(f"radius + margin {big_r:g} m leaves no room inside the map bounds")
    for name, p in (("start", s), ("goal", g)):
        if not free.state_ok(*p):
            return Reachability("unreachable", m, 0.0, 0, f"the {name} itself is not valid at margin {m:.2f} m")
    if free.edge_ok(s, g):
        return Reachability("reachable", m, 0.0, 0, "the straight motion from start to goal is valid")
    extent = hi - lo
    c = float(cell_m) if cell_m is not None else max(big_r, float(extent.max()) / 100.0)
    # the relaxed zones of close endpoints: the only places where the requirement is below R
    zones = [(np.asarray(p), r_e, zone) for p, r_e, zone in free.required.relaxed]
    answer = Reachability("undetermined", m, c, 0, f"the first grid ({c:.2f} m cells) has more than {max_cells} cells")
    while True:
        shape = tuple(int(v) for v in np.maximum(1, np.ceil(extent / c)))
        cells = int(np.prod(shape))
        if cells > max_cells:
            break
        answer = _at_resolution(plan_map, free, zones, lo, extent, shape, s, g, m)
        if answer.verdict != "undetermined":
            return answer
        c /= 2.0
    return answer


def _at_resolution(city: BuildingMap, free: FreeSpace, zones: list[tuple[np.ndarray, float, float]],
                   lo: np.ndarray, extent: np.ndarray, shape: tuple[int, ...], s: tuple[float, float, float],
                   g: tuple[float, float, float], margin_m: float) -> Reachability:
    """One grid of `shape` cells over the box [lo, lo + extent] (module docstring)."""
    sides = extent / np.asarray(shape, float)
    half_diag = 0.5 * float(np.linalg.norm(sides))
    axes = [lo[i] + (np.arange(shape[i]) + 0.5) * sides[i] for i in range(3)]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    d = np.concatenate([city.clearance(centres[k:k + _CHUNK]).distance_m for k in range(0, len(centres), _CHUNK)])
    certain = (d - half_diag > free.R).reshape(shape)
    need_low = np.full(len(centres), free.R)
    for p, r_e, zone in zones:
        near = np.linalg.norm(centres - p, axis=1) <= zone + half_diag
        need_low[near] = np.minimum(need_low[near], r_e)
    possible = (d + half_diag > need_low).reshape(shape)
    s_cell, g_cell = (_cell_of(p, lo, sides, shape) for p in (s, g))
    cell_m = float(sides.max())
    cells = int(np.prod(shape))
    loose, _ = ndimage.label(possible, structure=_TOUCHING)
    if loose[s_cell] == 0 or loose[s_cell] != loose[g_cell]:
        return Reachability("unreachable", margin_m, cell_m, cells,
                            f"no connected free space joins start and goal at margin {margin_m:.2f} m "
                            f"(proved on a {cell_m:.2f} m grid)")
    strict, _ = ndimage.label(certain, structure=_FACES)
    ends = [_hookups(free, p, cell, strict, lo, sides) for p, cell in ((s, s_cell), (g, g_cell))]
    if ends[0] & ends[1]:
        return Reachability("reachable", margin_m, cell_m, cells,
                            f"a path keeping margin {margin_m:.2f} m exists (shown on a {cell_m:.2f} m grid)")
    return Reachability("undetermined", margin_m, cell_m, cells,
                        f"neither a path nor its absence shown at margin {margin_m:.2f} m down to a "
                        f"{cell_m:.2f} m grid")


def _xyz(p: Sequence[float] | np.ndarray) -> tuple[float, float, float]:
    return float(p[0]), float(p[1]), float(p[2])


def _cell_of(p: Sequence[float], lo: np.ndarray, sides: np.ndarray, shape: tuple[int, ...]) -> tuple[int, int, int]:
    """The index of the cell holding p (clipped to the grid: an endpoint may sit on the box's face)."""
    k = np.floor((np.asarray(p, float) - lo) / sides).astype(int)
    i, j, n = np.clip(k, 0, np.asarray(shape) - 1)
    return int(i), int(j), int(n)


def _hookups(free: FreeSpace, p: tuple[float, float, float], cell: tuple[int, int, int], labels: np.ndarray,
             lo: np.ndarray, sides: np.ndarray) -> set[int]:
    """Components of certainly free cells that a valid straight motion joins to p: the cells at most
    `_HOOKUP_CELLS` away per axis, nearest first, until one cell of each component is joined."""
    window = tuple(slice(max(0, c - _HOOKUP_CELLS), c + _HOOKUP_CELLS + 1) for c in cell)
    idx = np.argwhere(labels[window] > 0) + np.array([w.start for w in window])
    if len(idx) == 0:
        return set()
    centres = lo + (idx + 0.5) * sides
    order = np.argsort(np.linalg.norm(centres - np.asarray(p), axis=1), kind="stable")
    found: set[int] = set()
    for k in order:
        label = int(labels[tuple(idx[k])])
        if label not in found and free.edge_ok(p, _xyz(centres[k])):
            found.add(label)
    return found
