"""Heading-relative perception for many vehicles in many box-building cities, in one vectorised call.

`Perception.observe` gives, for each query point (world ENU, metres) in its own city, two readings
in the point's horizontal frame (x' along the heading, y' 90 deg to its left, counter-clockwise):

**Rays (exact).** `n_rays` horizontal rays at angles heading + 2*pi*j/n_rays (j = 0 straight ahead,
j increasing counter-clockwise) from the point at its altitude z. Each is a conservative stand-in for
sweeping the vehicle's collision sphere (radius r): a 2D ray against every box footprint inflated by
r on each side (half-extents hx + r, hy + r) of the buildings whose roof plus r is above z
(height + r > z). The distance is the ray's entry parameter into the first such rectangle (0 when the
point is already inside one), capped at `ray_range_m`. It is an analytic slab test in each box's own
frame, exact to rounding (~1e-12 m). Speed comes from a per-city candidate grid (as in
`rl.sensing.sensor.BoxSensor`): each grid cell lists the buildings whose inflated rectangle lies within
`ray_range_m` of some point of the cell (an exact convex-polygon distance), and the grid covers every
inflated rectangle, so a point anywhere (also outside the city's bounds: it is clamped to the grid's
edge cells, which cannot lose a hit because projection onto a convex region containing all the
rectangles shortens every distance to them) evaluates only its cell's short list.

**Height map (rasterised, conservative).** A `grid_cells` x `grid_cells` grid of `cell_m` squares in
the point's frame, cell (a, b) centred at x' = (a - c) cell_m, y' = (b - c) cell_m (c = grid_cells // 2),
flattened as a * grid_cells + b (a, the ahead index, is the slow one). Each value is an upper bound of
the highest roof over the cell's square (0 = open ground), never below it:

* Once per city, a world-frame raster of `raster_m` cells holds for each raster cell the height of the
  tallest building whose footprint touches the closed raster cell (an exact rectangle-square
  separating-axis test, widened by 1e-6 m), **rounded up to whole metres** and stored as uint8
  (uint16 if some roof is above 255 m). From it only a derived table is kept: the max over each k x k
  block of raster cells (k = ceil(cell_m / raster_m)), with zero padding around the city, about
  (W + k + 1)(H + k + 1) bytes per city (~120 kB for a 340 m city at 1 m).
* A local cell's value is the max over the raster cells touched by the world-axis-aligned bounding
  box (AABB) of its rotated square, read as n x n lookups of k x k blocks (n = 2 for the defaults:
  the AABB spans k to 2k raster cells per axis) that together cover exactly those raster cells.

So the value is exactly the (ceil'd) highest roof touching the raster cells under the square's AABB:
never below the true highest roof over the square (no sampling miss), and never above the highest
roof of a building whose footprint reaches the AABB widened by `raster_m` on each side. The AABB
equals the square at headings aligned with the world axes and is up to twice its area at 45 deg
(its corners are then cell_m/2 beyond the square's sides). Cells whose AABB is more than one raster
cell outside the city's bounds read 0.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.city.distance import box_frame_xy

_EPS_M = 1e-6  # widening of build-time overlap and distance tests [m] (keeps them conservative)
_TOL_M = 1e-7  # shrinking of the height map's query boxes [m] (well within _EPS_M)
_ONE_RAY = (np.ones(1), np.zeros(1))  # a single ray along the heading


@dataclass(frozen=True)
class PerceptionConfig:
    """What the vehicle perceives.

    Attributes:
        n_rays: horizontal rays, evenly spaced over 360 deg, ray 0 along the heading.
        ray_range_m: ray length [m]; farther (or no) hits read this.
        grid_cells: the height map is grid_cells x grid_cells cells (odd), centred on the vehicle.
        cell_m: height-map cell size [m].
        raster_m: resolution [m] of the per-city height raster the map is read from.
    """

    n_rays: int = 16
    ray_range_m: float = 40.0
    grid_cells: int = 9
    cell_m: float = 6.0
    raster_m: float = 1.0

    def __post_init__(self) -> None:
        if int(self.n_rays) != self.n_rays or self.n_rays < 1:
            raise ValueError(f"n_rays must be a positive integer, got {self.n_rays}")
        if int(self.grid_cells) != self.grid_cells or self.grid_cells < 1 or self.grid_cells % 2 == 0:
            raise ValueError(f"grid_cells must be a positive odd integer, got {self.grid_cells}")
        for name in ("ray_range_m", "cell_m", "raster_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be positive and finite, got {v}")


@dataclass(frozen=True)
class PerceptionReading:
    """Per query point: ray distances (N, n_rays) [m], capped at the range (ray j at heading +
    2 pi j / n_rays, counter-clockwise), and the height map (N, grid_cells**2) [m]: per cell of the
    point's frame (index a * grid_cells + b, a ahead) an upper bound of the highest roof, 0 = ground."""

    ray_m: np.ndarray
    roof_m: np.ndarray


class Perception:
    """Rays and a height map around points spread over several box-building cities.

    Args:
        cities: the cities (all obstacles must be `Building` boxes).
        radius_m: the vehicle's collision radius r [m]: footprints are inflated by r for the rays and
            roofs count for a ray when height + r > z.
        config: what is perceived (see `PerceptionConfig`).
        ray_cell_m: cell size [m] of the rays' candidate grid (speed only; results do not depend on it).
    """

    def __init__(self, cities: Sequence[BuildingMap], radius_m: float,
                 config: PerceptionConfig = PerceptionConfig(), *, ray_cell_m: float = 10.0) -> None:
        if not (math.isfinite(radius_m) and radius_m >= 0):
            raise ValueError(f"radius_m must be >= 0 and finite, got {radius_m}")
        if not (math.isfinite(ray_cell_m) and ray_cell_m > 0):
            raise ValueError(f"ray_cell_m must be positive and finite, got {ray_cell_m}")
        self.cities = list(cities)
        self.radius_m, self.config, self.ray_cell_m = float(radius_m), config, float(ray_cell_m)
        cfg, r = config, self.radius_m
        n_city = len(self.cities)

        # Box table, cities stacked: cx, cy, cos, sin, hx + r, hy + r, height + r.
        rows = [(*b.center_xy_m, math.cos(b.yaw_rad), math.sin(b.yaw_rad), 0.5 * b.size_xy_m[0] + r,
                 0.5 * b.size_xy_m[1] + r, b.height_m + r) for c in self.cities for b in _boxes(c)]
        self._tab = np.array(rows, dtype=float).reshape(-1, 7)
        self._row0 = np.zeros(n_city + 1, dtype=np.int64)
        np.cumsum([len(c.buildings) for c in self.cities], out=self._row0[1:])
        ang = 2.0 * math.pi * np.arange(cfg.n_rays) / cfg.n_rays
        self._ray_cos, self._ray_sin = np.cos(ang), np.sin(ang)

        # Rays' candidate grid (CSR over all cities' cells): origin, dims, first global cell per city.
        self._g_origin = np.zeros((n_city, 2))
        self._g_dims = np.ones((n_city, 2), dtype=np.int64)
        self._g_cell0 = np.zeros(n_city, dtype=np.int64)
        lists: list[np.ndarray] = []
        counts: list[np.ndarray] = []
        n_cells = 0
        for ci, city in enumerate(self.cities):
            o, dims, cand, cnt = self._ray_grid(city, self._tab[self._row0[ci]:self._row0[ci + 1]])
            self._g_origin[ci], self._g_dims[ci], self._g_cell0[ci] = o, dims, n_cells
            n_cells += int(dims[0] * dims[1])
            lists.append(cand + self._row0[ci])
            counts.append(cnt)
        self._cand = np.concatenate(lists + [np.zeros(0, dtype=np.int64)]).astype(np.int32)
        self._cell_start = np.zeros(n_cells + 1, dtype=np.int64)
        np.cumsum(np.concatenate(counts + [np.zeros(0, dtype=np.int64)]), out=self._cell_start[1:])

        # Height map: per city a k x k block-max table of the conservative roof raster, stacked flat.
        # local cell-centre offsets [raster cells]
        self._offsets = (np.arange(cfg.grid_cells) - cfg.grid_cells // 2) * (cfg.cell_m / cfg.raster_m)
        self._k = max(1, math.ceil(cfg.cell_m / cfg.raster_m - 1e-9))
        # most raster cells an AABB touches along an axis, in n_look blocks of k (k <= the fewest)
        span = math.ceil(cfg.cell_m * math.sqrt(2.0) / cfg.raster_m + 1e-9) + 1
        self._n_look = max(1, math.ceil(span / self._k))
        top = max([math.ceil(b.height_m) for c in self.cities for b in c.buildings] + [0])
        dtype = np.uint8 if top <= 255 else np.uint16
        self._r_origin = np.array([c.bounds_min_m[:2] for c in self.cities], dtype=float).reshape(-1, 2)
        hi = np.array([c.bounds_max_m[:2] for c in self.cities], dtype=float).reshape(-1, 2)
        extent = hi - self._r_origin
        self._r_dims = np.maximum(np.ceil(extent / cfg.raster_m - 1e-9).astype(np.int64), 1)  # raster (W, H)
        sizes = np.prod(self._r_dims + self._k + 1, axis=1)
        self._r_off = (np.cumsum(sizes) - sizes).astype(np.int64)
        self._table = np.empty(int(sizes.sum()), dtype=dtype)
        for ci, city in enumerate(self.cities):
            raster = self._raster(city, self._r_origin[ci], self._r_dims[ci], dtype)
            start = self._r_off[ci]
            self._table[start:start + sizes[ci]] = self._block_max(raster, self._k).ravel()

    @property
    def nbytes(self) -> int:
        """Bytes held by the query structures (box table, candidate grid, height tables)."""
        return sum(a.nbytes for a in (self._tab, self._row0, self._ray_cos, self._ray_sin, self._g_origin,
                                      self._g_dims, self._g_cell0, self._cand, self._cell_start,
                                      self._r_origin, self._r_dims, self._r_off, self._table))

    # ----------------------------------------------------------------------------------- build

    def _ray_grid(self, city: BuildingMap, tab: np.ndarray):
        """Candidate grid of one city: origin (2,), dims (gx, gy), candidate rows (sum,), counts (cells,).

        The grid covers the bounds widened by r*sqrt(2) (so every inflated rectangle); a cell lists a
        building when the exact distance between the cell's square and its inflated rectangle is at
        most the ray range (plus 1e-6 m). Lists are sorted by building row; cells row-major, x fastest.
        """
        g, r = self.ray_cell_m, self.radius_m
        margin = r * math.sqrt(2.0) + _EPS_M
        lo = np.asarray(city.bounds_min_m[:2], dtype=float) - margin
        hi = np.asarray(city.bounds_max_m[:2], dtype=float) + margin
        dims = np.maximum(np.ceil((hi - lo) / g).astype(np.int64), 1)
        gx, gy = int(dims[0]), int(dims[1])
        if len(tab) == 0:
            return lo, dims, np.zeros(0, dtype=np.int64), np.zeros(gx * gy, dtype=np.int64)
        ix, iy = np.meshgrid(np.arange(gx), np.arange(gy))  # (gy, gx): row-major, x fastest
        x0 = (lo[0] + g * ix.ravel())[None, :]
        y0 = (lo[1] + g * iy.ravel())[None, :]
        cx, cy, co, si, hx, hy = (tab[:, i:i + 1] for i in range(6))
        d = _square_rect_distance(x0, y0, g, cx, cy, co, si, hx, hy)  # (B, cells)
        near = d <= self.config.ray_range_m + _EPS_M
        _, b_idx = np.nonzero(near.T)  # ordered by cell, then building
        return lo, dims, b_idx.astype(np.int64), near.sum(axis=0)

    def _raster(self, city: BuildingMap, lo: np.ndarray, dims: np.ndarray, dtype) -> np.ndarray:
        """(H, W) raster of `raster_m` cells from `lo`: ceil of the tallest roof touching each closed cell."""
        rho = self.config.raster_m
        w, h = int(dims[0]), int(dims[1])
        out = np.zeros((h, w), dtype=dtype)
        for b in _boxes(city):
            cx, cy = b.center_xy_m
            co, si = math.cos(b.yaw_rad), math.sin(b.yaw_rad)
            hx, hy = 0.5 * b.size_xy_m[0], 0.5 * b.size_xy_m[1]
            ex, ey = hx * abs(co) + hy * abs(si), hx * abs(si) + hy * abs(co)  # footprint AABB half-widths
            i0 = max(math.floor((cx - ex - _EPS_M - lo[0]) / rho), 0)
            i1 = min(math.floor((cx + ex + _EPS_M - lo[0]) / rho), w - 1)
            j0 = max(math.floor((cy - ey - _EPS_M - lo[1]) / rho), 0)
            j1 = min(math.floor((cy + ey + _EPS_M - lo[1]) / rho), h - 1)
            if i1 < i0 or j1 < j0:
                continue
            # Raster-cell centres relative to the box centre, projected on the box axes (SAT: the
            # world axes already overlap by construction of the index range).
            lx, ly = box_frame_xy((lo[0] + rho * (np.arange(i0, i1 + 1) + 0.5))[None, :],
                                  (lo[1] + rho * (np.arange(j0, j1 + 1) + 0.5))[:, None], cx, cy, co, si)
            half = 0.5 * rho * (abs(co) + abs(si)) + _EPS_M
            touch = (np.abs(lx) <= hx + half) & (np.abs(ly) <= hy + half)
            block = out[j0:j1 + 1, i0:i1 + 1]
            np.maximum(block, np.where(touch, math.ceil(b.height_m), 0).astype(dtype), out=block)
        return out

    @staticmethod
    def _block_max(raster: np.ndarray, k: int) -> np.ndarray:
        """(H + k + 1, W + k + 1) table: entry [j + k, i + k] = max of raster[j:j+k, i:i+k] (zero
        outside the raster), for block corners i in [-k, W], j in [-k, H]."""
        h, w = raster.shape
        pad = np.zeros((h + 2 * k, w + 2 * k), dtype=raster.dtype)
        pad[k:k + h, k:k + w] = raster
        for axis in (0, 1):
            pad = _sliding_max(pad, k, axis)  # length n - k + 1 along axis
        return np.ascontiguousarray(pad)

    # ----------------------------------------------------------------------------------- query

    def observe(self, points_m: np.ndarray, heading_rad: np.ndarray, city: np.ndarray) -> PerceptionReading:
        """Rays and height maps.

        Args:
            points_m: query points (N, 3), world ENU [m] (finite; anywhere, also outside the bounds).
            heading_rad: headings (N,) [rad]: each frame's x' axis, counter-clockwise from east.
            city: city indices (N,) into `cities`.
        """
        p, ch, sh, ci = self._inputs(points_m, heading_rad, city)
        return PerceptionReading(self._rays(p, ch, sh, ci), self._roofs(p, ch, sh, ci))

    def rays(self, points_m: np.ndarray, heading_rad: np.ndarray, city: np.ndarray) -> np.ndarray:
        """Only the ray distances (N, n_rays) [m] of `observe` (same arguments)."""
        return self._rays(*self._inputs(points_m, heading_rad, city))

    def free_distance(self, points_m: np.ndarray, bearing_rad: np.ndarray, city: np.ndarray) -> np.ndarray:
        """Distances (N,) [m] of one ray per point at its own bearing (CCW from east): the same sphere
        stand-in and range cap as the rays (e.g. along the vehicle's horizontal velocity)."""
        p, ch, sh, ci = self._inputs(points_m, bearing_rad, city)
        return self._rays(p, ch, sh, ci, _ONE_RAY)[:, 0]

    def roofs(self, points_m: np.ndarray, heading_rad: np.ndarray, city: np.ndarray) -> np.ndarray:
        """Only the height maps (N, grid_cells**2) [m] of `observe` (same arguments)."""
        return self._roofs(*self._inputs(points_m, heading_rad, city))

    @staticmethod
    def _inputs(points_m, heading_rad, city):
        """Points (N, 3), cos and sin of the headings (N,), city indices (N,)."""
        p = np.asarray(points_m, dtype=float).reshape(-1, 3)
        hd = np.asarray(heading_rad, dtype=float).reshape(-1)
        ci = np.asarray(city, dtype=np.int64).reshape(-1)
        if not (len(hd) == len(ci) == len(p)):
            raise ValueError(f"need as many headings and cities as points: {len(p)}, {len(hd)}, {len(ci)}")
        return p, np.cos(hd), np.sin(hd), ci

    def _rays(self, p: np.ndarray, ch: np.ndarray, sh: np.ndarray, ci: np.ndarray,
              fan: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """Ray distances (N, R) [m]; headings given by their cos, sin (N,); `fan` the rays' (cos, sin)
        relative to the heading (R,) (None: the configured n_rays)."""
        n, rng_m = len(p), self.config.ray_range_m
        fan = (self._ray_cos, self._ray_sin) if fan is None else fan
        if n == 1:
            return self._rays_one(p, ch, sh, ci, fan)
        out = np.full((n, len(fan[0])), rng_m)
        if n == 0:
            return out
        # Candidate lists of each point's (clamped) grid cell.
        # (clamping to the grid is projecting onto a convex region that holds every inflated footprint:
        # it brings the point no farther from any of them, so the clamped cell's list holds all hits)
        dims = self._g_dims[ci]
        rel = np.floor(np.clip((p[:, :2] - self._g_origin[ci]) / self.ray_cell_m, 0.0, 1e9)).astype(np.int64)
        np.minimum(rel, dims - 1, out=rel)
        cell = self._g_cell0[ci] + rel[:, 1] * dims[:, 0] + rel[:, 0]
        start, stop = self._cell_start[cell], self._cell_start[cell + 1]
        lens = stop - start
        m = int(lens.sum())
        if m == 0:
            return out
        pt = np.repeat(np.arange(n), lens)
        seg = np.cumsum(lens) - lens
        cand = self._cand[np.arange(m) + np.repeat(start - seg, lens)]
        b = self._tab[cand]  # (M, 7)
        co, si = b[:, 2], b[:, 3]
        lx, ly = box_frame_xy(p[pt, 0], p[pt, 1], b[:, 0], b[:, 1], co, si)
        hc, hs = ch[pt], sh[pt]
        near = self._entries(b, lx, ly, hc * co + hs * si, hs * co - hc * si, p[pt, 2] >= b[:, 6], fan)
        has = lens > 0
        out[has] = np.minimum(np.minimum.reduceat(near, seg[has], axis=0), rng_m)
        return out

    def _rays_one(self, p: np.ndarray, ch: np.ndarray, sh: np.ndarray, ci: np.ndarray,
                  fan: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """`_rays` of one point (1, n_rays): the candidate lookup in plain Python (NumPy's per-call
        overhead on one row dominated a single vehicle's step), then the same array operations on
        the same candidates as `_rays`, so the same numbers (tested)."""
        out = np.full((1, len(fan[0])), self.config.ray_range_m)
        x, y, z = p[0].tolist()
        c = int(ci[0])
        ox, oy = self._g_origin[c].tolist()
        gx, gy = self._g_dims[c].tolist()
        # `_rays`' floor(clip(., 0, 1e9)), capped at the last cell (int() is floor on [0, 1e9])
        ix = min(int(min(max((x - ox) / self.ray_cell_m, 0.0), 1e9)), gx - 1)
        iy = min(int(min(max((y - oy) / self.ray_cell_m, 0.0), 1e9)), gy - 1)
        cell = int(self._g_cell0[c]) + iy * gx + ix
        start, stop = self._cell_start[cell:cell + 2].tolist()
        if start == stop:
            return out
        b = self._tab[self._cand[start:stop]]  # (M, 7)
        co, si = b[:, 2], b[:, 3]
        lx, ly = box_frame_xy(x, y, b[:, 0], b[:, 1], co, si)
        hc, hs = float(ch[0]), float(sh[0])
        near = self._entries(b, lx, ly, hc * co + hs * si, hs * co - hc * si, z >= b[:, 6], fan)
        np.minimum(out, near.min(axis=0, keepdims=True), out=out)
        return out

    @staticmethod
    def _entries(b: np.ndarray, lx: np.ndarray, ly: np.ndarray, c_rel: np.ndarray, s_rel: np.ndarray,
                 low: np.ndarray, fan: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """Entry distances (M, R) [m] of the rays into candidate boxes b (M, 7) (inf: no hit).

        Args:
            lx, ly: (M,) the ray origin in each box's frame; c_rel, s_rel: (M,) cos, sin of the heading
                in the box's frame; low: (M,) the box's roof + r is at or below the ray (no obstacle);
                fan: the rays' cos, sin (R,) relative to the heading.
        """
        hx = np.where(low, -1.0, b[:, 4])[:, None]  # a negative half-extent never hits
        hy = np.where(low, -1.0, b[:, 5])[:, None]
        rc, rs = fan
        # Ray directions in the box frame (M, R); +1e-300 turns exact zeros into a tiny positive
        # component (no 0 * inf) and leaves every other value unchanged.
        ux = c_rel[:, None] * rc - s_rel[:, None] * rs
        ux += 1e-300
        uy = s_rel[:, None] * rc + c_rel[:, None] * rs
        uy += 1e-300
        np.divide(1.0, ux, out=ux)
        np.divide(1.0, uy, out=uy)
        ax, ay = lx[:, None] * ux, ly[:, None] * uy  # l / u
        np.abs(ux, out=ux)
        np.abs(uy, out=uy)
        ux *= hx  # h / |u|
        uy *= hy
        # slab x: entry -(h/|u| + l/u), exit h/|u| - l/u; likewise y.
        near = np.minimum(ux + ax, uy + ay)  # = -entry
        far = np.minimum(np.subtract(ux, ax, out=ux), np.subtract(uy, ay, out=uy))  # = exit
        hit = (near + far >= 0.0) & (far >= 0.0)
        np.negative(near, out=near)
        np.maximum(near, 0.0, out=near)
        near[~hit] = np.inf
        return near

    def _roofs(self, p: np.ndarray, ch: np.ndarray, sh: np.ndarray, ci: np.ndarray) -> np.ndarray:
        """Height maps (N, grid_cells**2) [m]; headings given by their cos, sin (N,)."""
        cfg, k, nl = self.config, self._k, self._n_look
        g = cfg.grid_cells
        n = len(p)
        if n == 1:
            return self._roofs_one(p, ch, sh, ci)
        rho = cfg.raster_m
        o = self._offsets
        org = self._r_origin[ci]
        w, h = self._r_dims[ci, 0], self._r_dims[ci, 1]
        xr = (p[:, 0] - org[:, 0]) / rho
        yr = (p[:, 1] - org[:, 1]) / rho
        # AABB half-width, less 1e-7 m: the raster's 1e-6 m widening covers it and rounding, and a
        # square edge on a raster line then does not reach into the next raster cell.
        half = (0.5 * cfg.cell_m / rho) * (np.abs(ch) + np.abs(sh)) - _TOL_M / rho
        # Cell centres (N, g_a, g_b) in raster units: p + o_a (c, s) + o_b (-s, c).
        xc = (xr[:, None] + o * ch[:, None])[:, :, None] - (o * sh[:, None])[:, None, :]
        yc = (yr[:, None] + o * sh[:, None])[:, :, None] + (o * ch[:, None])[:, None, :]
        cols = self._positions(xc, half, w, k, nl)  # (nl, N, g, g) block columns, shifted by +k
        rows = self._positions(yc, half, h, k, nl)
        wt = (w + k + 1)[:, None, None]
        rows *= wt
        rows += self._r_off[ci][:, None, None]
        idx = rows[:, None] + cols[None, :]  # (nl, nl, N, g, g)
        v = self._table.take(idx.reshape(nl * nl, -1))
        best = v[0]
        for i in range(1, nl * nl):
            np.maximum(best, v[i], out=best)
        return best.reshape(n, g * g).astype(float)

    def _roofs_one(self, p: np.ndarray, ch: np.ndarray, sh: np.ndarray, ci: np.ndarray) -> np.ndarray:
        """`_roofs` of one point (1, grid_cells**2) with fewer NumPy calls (their per-call overhead
        dominated a single vehicle's step): the x and y cell centres stacked as two rows of one
        `_positions` call. The same operations on the same doubles and integers, so the same numbers."""
        cfg, k, nl = self.config, self._k, self._n_look
        g, rho, o = cfg.grid_cells, cfg.raster_m, self._offsets
        c = int(ci[0])
        ox, oy = self._r_origin[c].tolist()
        x, y, _ = p[0].tolist()
        hc, hs = float(ch[0]), float(sh[0])
        xr, yr = (x - ox) / rho, (y - oy) / rho
        half = (0.5 * cfg.cell_m / rho) * (abs(hc) + abs(hs)) - _TOL_M / rho
        centres = np.empty((2, g, g))  # x, y in raster units, as in `_roofs`
        np.subtract((xr + o * hc)[:, None], (o * hs)[None, :], out=centres[0])
        np.add((yr + o * hs)[:, None], (o * hc)[None, :], out=centres[1])
        dims = self._r_dims[c]
        pos = self._positions(centres, np.array([half, half]), dims, k, nl)  # (nl, 2, g, g): columns, rows
        rows = pos[:, 1] * (int(dims[0]) + k + 1) + int(self._r_off[c])
        idx = rows[:, None] + pos[None, :, 0]  # (nl, nl, g, g)
        return self._table.take(idx.reshape(nl * nl, -1)).max(axis=0).reshape(1, g * g).astype(float)

    @staticmethod
    def _positions(c: np.ndarray, half: np.ndarray, size: np.ndarray, k: int, nl: int) -> np.ndarray:
        """Block starts (nl, N, g, g) (+k, clipped to the table) covering the raster cells touched by
        [c - half, c + half] along one axis (raster units; `size` (N,) cells along it)."""
        top = (size + k + 2).astype(float)[:, None, None]
        hw = half[:, None, None]
        lo = np.floor(np.minimum(np.maximum(c - hw, -(k + 2.0)), top)).astype(np.int64)
        last = np.ceil(np.minimum(np.maximum(c + hw, -(k + 2.0)), top)).astype(np.int64) - k  # hi - (k - 1)
        if nl == 1:
            pos = lo[None]
        elif nl == 2:
            pos = np.empty((2,) + lo.shape, dtype=np.int64)  # (np.stack, without its Python overhead)
            pos[0], pos[1] = lo, last
        else:
            t = np.arange(nl)[:, None, None, None]
            pos = lo[None] + ((last - lo)[None] * t) // (nl - 1)
        lim = size[None, :, None, None]
        np.minimum(np.maximum(pos, -k), lim, out=pos)
        pos += k
        return pos


def _boxes(city: BuildingMap) -> list[Building]:
    """The city's obstacles, every one a box (`Building`); ValueError otherwise."""
    boxes = [b for b in city.buildings if isinstance(b, Building)]
    if len(boxes) != len(city.buildings):
        raise ValueError(f"city {city.name!r}: perception needs box buildings only")
    return boxes


def _sliding_max(a: np.ndarray, k: int, axis: int) -> np.ndarray:
    """Max over windows of k consecutive entries along `axis` (length shrinks by k - 1)."""
    a = np.moveaxis(a, axis, 0)
    span = 1
    while 2 * span <= k:  # a[i] = max over a[i : i + span] (doubling)
        a = np.maximum(a[:-span], a[span:])
        span *= 2
    if span < k:
        a = np.maximum(a[: len(a) - (k - span)], a[k - span:])
    return np.moveaxis(a, 0, axis)


def _square_rect_distance(x0, y0, g: float, cx, cy, co, si, hx, hy) -> np.ndarray:
    """Euclidean distance [m] between axis-aligned squares [x0, x0+g] x [y0, y0+g] and rectangles
    centred (cx, cy) with axes (co, si), (-si, co) and half-extents hx, hy (broadcast; 0 on overlap).

    Disjoint convex polygons are closest at a vertex of one of them; overlap is the separating-axis
    test on the four edge directions.
    """
    half = 0.5 * g
    sx, sy = x0 + half, y0 + half  # square centres
    ddx, ddy = cx - sx, cy - sy
    aco, asi = np.abs(co), np.abs(si)
    overlap = ((np.abs(ddx) <= half + hx * aco + hy * asi) & (np.abs(ddy) <= half + hx * asi + hy * aco)
               & (np.abs(ddx * co + ddy * si) <= hx + half * (aco + asi))
               & (np.abs(ddy * co - ddx * si) <= hy + half * (aco + asi)))
    best = np.full(np.broadcast_shapes(np.shape(sx), np.shape(cx)), np.inf)
    for ex, ey in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        # rectangle corner to the square
        px = cx + ex * hx * co - ey * hy * si
        py = cy + ex * hx * si + ey * hy * co
        qx = np.maximum(np.abs(px - sx) - half, 0.0)
        qy = np.maximum(np.abs(py - sy) - half, 0.0)
        np.minimum(best, np.hypot(qx, qy), out=best)
        # square corner to the rectangle (in the rectangle's frame)
        lx, ly = box_frame_xy(sx + ex * half, sy + ey * half, cx, cy, co, si)
        qx = np.maximum(np.abs(lx) - hx, 0.0)
        qy = np.maximum(np.abs(ly) - hy, 0.0)
        np.minimum(best, np.hypot(qx, qy), out=best)
    return np.where(overlap, 0.0, best)
