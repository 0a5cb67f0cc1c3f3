"""Range-limited obstacle sensing for many vehicles in many cities, in one vectorised call.

For each query point (world ENU, metres) in its own city, `BoxSensor.query` returns the K nearest
distinct buildings within the sensing range (nearest point on each building's surface and the
signed distance to it) and the clearance to buildings and the ground. A box raised off the ground
(`Building.base_m` > 0, a crane's jib) spans base_m..height_m, exactly. Distances are the exact
point-to-box kernel of `uam_fdm.city.distance` (`box_signed_sq_distance`, `box_signed_distance_one`), the
one `uam_fdm.city.buildings.BuildingMap.clearance` uses (which agrees with FCL to ~1e-12 m;
tests/rl/env/test_nav_env.py::test_sensor_matches_fcl checks this sensor against FCL directly).

Speed comes from a per-city grid: each cell of `cell_m` lists every building whose footprint
could lie within `range_m` of a point in the cell (a conservative circumscribed-circle test), so a
query evaluates only its cell's short candidate list. Within the range the answer is exact;
buildings beyond it are not reported (padding rows: distance = range, nearest point = the query
point). Clearance beyond the range is reported as `range_m` at most (the ground is always exact).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.city.distance import box_frame_xy, box_signed_distance_one, box_signed_sq_distance, signed_sqrt


@dataclass(frozen=True)
class SensorReading:
    """Per query point: nearest points (N, K, 3) [m], distances (N, K) [m] (signed, minus the radius),
    building ids (N, K) (-1 = nothing within range), clearance (N,) [m] to buildings or the ground."""

    nearest_m: np.ndarray
    distance_m: np.ndarray
    building_id: np.ndarray
    clearance_m: np.ndarray


class BoxSensor:
    """K-nearest buildings within a range, for points spread over several box-building cities.

    Args:
        cities: the cities (all obstacles must be `Building` boxes).
        k: buildings reported per point.
        range_m: sensing range [m] (distances from the sphere surface).
        radius_m: the vehicle's collision radius [m], subtracted from every distance.
        cell_m: grid cell size [m].
    """

    def __init__(self, cities: Sequence[BuildingMap], k: int, range_m: float, radius_m: float,
                 cell_m: float = 10.0) -> None:
        if k < 1 or range_m <= 0 or radius_m < 0 or cell_m <= 0:
            raise ValueError(f"need k >= 1, range > 0, radius >= 0, cell > 0; got {k}, {range_m}, {radius_m}, {cell_m}")
        self.k, self.range_m, self.radius_m, self.cell_m = int(k), float(range_m), float(radius_m), float(cell_m)
        self.cities = list(cities)
        n_city = len(self.cities)
        nb = max([len(c.buildings) for c in self.cities] + [1])
        # Box table with one extra far-away dummy row per city (index nb) used for padding candidates.
        self._cx = np.full((n_city, nb + 1), 1e9)
        self._cy = np.full((n_city, nb + 1), 1e9)
        self._cos = np.ones((n_city, nb + 1))
        self._sin = np.zeros((n_city, nb + 1))
        self._hx = np.ones((n_city, nb + 1))
        self._hy = np.ones((n_city, nb + 1))
        self._h = np.ones((n_city, nb + 1))
        self._base = np.zeros((n_city, nb + 1))
        self._id = np.full((n_city, nb + 1), -1, dtype=np.int64)
        self._origin = np.zeros((n_city, 2))
        self._dims = np.zeros((n_city, 2), dtype=np.int64)
        cand_lists = []
        for ci, city in enumerate(self.cities):
            blds = [b for b in city.buildings if isinstance(b, Building)]
            if len(blds) != len(city.buildings):
                raise ValueError(f"city {city.name!r}: the sensor needs box buildings only")
            for j, b in enumerate(blds):
                self._cx[ci, j], self._cy[ci, j] = b.center_xy_m
                self._cos[ci, j], self._sin[ci, j] = math.cos(b.yaw_rad), math.sin(b.yaw_rad)
                self._hx[ci, j], self._hy[ci, j] = 0.5 * b.size_xy_m[0], 0.5 * b.size_xy_m[1]
                self._h[ci, j], self._id[ci, j] = b.height_m, b.id
                self._base[ci, j] = b.base_m
            lo, hi = np.asarray(city.bounds_min_m[:2]), np.asarray(city.bounds_max_m[:2])
            dims = np.maximum(np.ceil((hi - lo) / self.cell_m).astype(np.int64), 1)
            self._origin[ci], self._dims[ci] = lo, dims
            cand_lists.append(self._candidates(blds, lo, dims, nb))
        self._cmax = max([c.shape[-1] for c in cand_lists] + [1])
        gmax = int(max([int(d[0] * d[1]) for d in self._dims] + [1]))
        self._cand = np.full((n_city, gmax, self._cmax), nb, dtype=np.int64)
        for ci, c in enumerate(cand_lists):
            self._cand[ci, : c.shape[0], : c.shape[1]] = c
        self._nb1 = nb + 1
        # One row per box (cities stacked): cx, cy, cos, sin, hx, hy, half height (and, only when some box is
        # raised, the height range's centre: otherwise it equals the half height, the same doubles); one gather.
        columns = [self._cx, self._cy, self._cos, self._sin, self._hx, self._hy, 0.5 * (self._h - self._base)]
        raised = bool(np.any(self._base > 0.0))
        if raised:
            columns.append(0.5 * (self._base + self._h))
        self._zc = 7 if raised else 6  # the column of the height range's centre
        self._tab = np.stack([a.ravel() for a in columns], axis=-1)
        self._ids_flat = self._id.ravel()
        # For single queries (one vehicle): plain-Python rows (cx, cy, cos, sin, hx, hy, zc, hz, as
        # `box_signed_distance_one` takes them) and per-cell lists without padding.
        self._tab_rows = [(*r[:6], r[self._zc], r[6]) for r in self._tab.tolist()]
        self._cells_py = [[[int(j) for j in row if j != nb] for row in c] for c in cand_lists]

    def _candidates(self, blds: Sequence[Building], lo: np.ndarray, dims: np.ndarray, pad: int) -> np.ndarray:
        """(cells, C) candidate building rows per cell (row-major x fastest), padded with `pad`."""
        n_cells = int(dims[0] * dims[1])
        reach = self.range_m + self.radius_m
        cells, rows = [], []
        for j, b in enumerate(blds):
            r = reach + 0.5 * math.hypot(*b.size_xy_m)
            c = np.asarray(b.center_xy_m)
            i0 = np.clip(np.floor((c - r - lo) / self.cell_m).astype(int), 0, dims - 1)
            i1 = np.clip(np.floor((c + r - lo) / self.cell_m).astype(int), 0, dims - 1)
            grid_x, grid_y = np.meshgrid(np.arange(i0[0], i1[0] + 1), np.arange(i0[1], i1[1] + 1))
            ix, iy = grid_x.ravel(), grid_y.ravel()
            # the cell's point nearest the centre, as in a per-cell loop (same operations, same doubles)
            cell_x, cell_y = lo[0] + self.cell_m * ix, lo[1] + self.cell_m * iy
            nx = np.minimum(np.maximum(c[0], cell_x), cell_x + self.cell_m) - c[0]
            ny = np.minimum(np.maximum(c[1], cell_y), cell_y + self.cell_m) - c[1]
            keep = np.hypot(nx, ny) <= r
            cells.append(iy[keep] * int(dims[0]) + ix[keep])
            rows.append(np.full(int(keep.sum()), j, dtype=np.int64))
        cell = np.concatenate(cells) if cells else np.zeros(0, dtype=np.int64)
        row = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
        order = np.argsort(cell, kind="stable")  # per cell, buildings in index order
        cell, row = cell[order], row[order]
        counts = np.bincount(cell, minlength=n_cells)
        width = max(int(counts.max()) if len(counts) else 0, self.k)  # at least k columns: no padding branch in query
        out = np.full((n_cells, width), pad, dtype=np.int64)
        starts = np.cumsum(counts) - counts
        out[cell, np.arange(len(cell)) - starts[cell]] = row
        return out

    def _box_rows(self, points: np.ndarray, city: np.ndarray) -> np.ndarray:
        """Flat indices into the box table of each point's candidates: (N, C)."""
        rel = (points[:, :2] - self._origin[city]) / self.cell_m
        ix = np.clip(rel[:, 0].astype(np.int64), 0, self._dims[city, 0] - 1)
        iy = np.clip(rel[:, 1].astype(np.int64), 0, self._dims[city, 1] - 1)
        rows = self._cand[city, iy * self._dims[city, 0] + ix]
        return city[:, None] * self._nb1 + rows

    def _box_frame(self, points: np.ndarray, flat: np.ndarray):
        """Points in the frames of boxes `flat` (N, C): local x, y, z (z from mid-height) and the box rows."""
        b = self._tab[flat]  # (N, C, 7 or 8)
        lx, ly = box_frame_xy(points[:, 0:1], points[:, 1:2], b[..., 0], b[..., 1], b[..., 2], b[..., 3])
        return lx, ly, points[:, 2:3] - b[..., self._zc], b

    def _keys(self, points: np.ndarray, flat: np.ndarray) -> np.ndarray:
        """Signed squared point distances (N, C) to the boxes `flat` (`box_signed_sq_distance`)."""
        b = self._tab[flat]  # (N, C, 7 or 8)
        half_h = b[..., 6]
        return box_signed_sq_distance(points[:, 0:1], points[:, 1:2], points[:, 2:3], b[..., 0], b[..., 1],
                                      b[..., 2], b[..., 3], b[..., 4], b[..., 5], b[..., self._zc], half_h)

    def _nearest_points(self, points: np.ndarray, flat: np.ndarray) -> np.ndarray:
        """Nearest points (N, C, 3) on the boxes `flat`: the clamp (inside a box: the point itself)."""
        lx, ly, lz, b = self._box_frame(points, flat)
        hx, hy, hz = b[..., 4], b[..., 5], b[..., 6]
        nx, ny = np.minimum(np.maximum(lx, -hx), hx), np.minimum(np.maximum(ly, -hy), hy)
        nz = np.minimum(np.maximum(lz, -hz), hz) + b[..., self._zc]
        co, si = b[..., 2], b[..., 3]
        return np.stack([b[..., 0] + nx * co - ny * si, b[..., 1] + nx * si + ny * co, nz], axis=-1)

    def query(self, points_m: np.ndarray, city: np.ndarray) -> SensorReading:
        """Sense from points (N, 3) ENU metres, each in city index city (N,)."""
        p = np.asarray(points_m, dtype=float).reshape(-1, 3)
        city = np.asarray(city, dtype=np.int64).reshape(-1)
        if len(p) == 1:
            return self._query_one(p, int(city[0]))
        flat = self._box_rows(p, city)
        dist = signed_sqrt(self._keys(p, flat)) - self.radius_m
        k = self.k
        rows = np.arange(len(p))[:, None]
        part = np.argpartition(dist, k - 1, axis=1)[:, :k] if dist.shape[1] > k else \
            np.broadcast_to(np.arange(k), (len(p), k))
        d_k = dist[rows, part]
        order = np.argsort(d_k, axis=1, kind="stable")
        idx = part[rows, order]
        d_k = d_k[rows, order]
        flat_k = flat[rows, idx]
        ids = self._ids_flat[flat_k]
        far = (d_k > self.range_m) | (ids < 0)
        near_k = np.where(far[..., None], p[:, None, :], self._nearest_points(p, flat_k))
        d_k = np.where(far, self.range_m, d_k)
        ids = np.where(far, -1, ids)
        clearance = np.minimum(d_k[:, 0], p[:, 2] - self.radius_m)
        return SensorReading(near_k, d_k, ids, clearance)

    def _query_one(self, p: np.ndarray, ci: int) -> SensorReading:
        """`query` for one point in plain Python: the same arithmetic, without NumPy's per-call overhead."""
        x, y, z = p[0].tolist()
        ox, oy = self._origin[ci].tolist()
        gx, gy = self._dims[ci].tolist()
        ix = min(max(int((x - ox) / self.cell_m), 0), gx - 1)
        iy = min(max(int((y - oy) / self.cell_m), 0), gy - 1)
        base = ci * self._nb1
        rows, r = self._tab_rows, self.radius_m
        found = [(box_signed_distance_one(x, y, z, rows[base + j]) - r, j)
                 for j in self._cells_py[ci][iy * gx + ix]]
        found.sort(key=lambda f: f[0])
        k, rng_m = self.k, self.range_m
        near = np.empty((1, k, 3))
        dist = np.full((1, k), rng_m)
        ids = np.full((1, k), -1, dtype=np.int64)
        near[0, :] = (x, y, z)
        for m, (d, j) in enumerate(found[:k]):
            if d > rng_m:
                break
            cx, cy, co, si, hx, hy, zc, hz = rows[base + j]
            lx, ly = box_frame_xy(x, y, cx, cy, co, si)
            lz = z - zc
            nx, ny = min(max(lx, -hx), hx), min(max(ly, -hy), hy)
            near[0, m] = (cx + nx * co - ny * si, cy + nx * si + ny * co, min(max(lz, -hz), hz) + zc)
            dist[0, m] = d
            ids[0, m] = self._ids_flat[base + j]
        clearance = np.array([min(dist[0, 0], z - r)])
        return SensorReading(near, dist, ids, clearance)

    def clearance(self, points_m: np.ndarray, city: np.ndarray) -> np.ndarray:
        """Clearance (N,) [m] of spheres at points (N, 3) to buildings and the ground, capped at the range."""
        p = np.asarray(points_m, dtype=float).reshape(-1, 3)
        city = np.asarray(city, dtype=np.int64).reshape(-1)
        flat = self._box_rows(p, city)
        # the nearest box's distance: the square root of the least key (exact: sqrt is monotone)
        d = np.minimum(signed_sqrt(self._keys(p, flat).min(axis=1)) - self.radius_m, self.range_m)
        return np.minimum(d, p[:, 2] - self.radius_m)
