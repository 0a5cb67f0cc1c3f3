"""The classical pilot's map of what its lidar has sensed, fused with the prior map it was given.

Each scan is placed on the navigation estimate (the pilot knows no truer pose) and compared, beam by beam, with
what the prior map predicts along the same beam (Embree, `uam_fdm.sensing.raycast.RayCaster` over the prior):

* a return well short of the prior's surface (by more than `front_tolerance_m`) is something the prior lacks: its
  voxel is marked occupied in an OctoMap octree (log-odds, `octomap-python`);
* a return well beyond a prior part's surface (by more than `through_tolerance_m` plus 3 σ of the estimate's
  position) means the beam flew through that part: after `clear_beams` such beams the part is taken out of the
  map (the survey has it where the world does not);
* every `carve_stride`-th beam is also inserted whole (free space along it up to `carve_range_m`, its end
  occupied), so that voxels marked by noise or by an estimate since corrected are cleared as beams pass through.

Returns on the ground (below `ground_band_m`) are left out: the prior knows the ground. `fused()` gives the map the
pilot plans and tracks on: the prior parts not cleared, plus the octree's occupied unexplained voxels as obstacles
standing on the ground (2.5-D: each occupied column as tall as its highest voxel, equal neighbouring columns merged
into boxes). It is conservative where it must be: the space under a crane's jib is closed. Frames: world ENU
metres.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import octomap

from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.sensing.lidar import LidarScan
from uam_fdm.sensing.raycast import RayCaster
from uam_fdm.vehicle.attitude import rotation_matrix


@dataclass(frozen=True)
class MappingConfig:
    """How the classical pilot maps what it senses.

    Attributes:
        resolution_m: octree voxel edge [m].
        front_tolerance_m: a return this much short of the prior's surface is an obstacle the prior lacks [m].
        through_tolerance_m: a return this much beyond a prior part's surface (plus 3 σ of the estimate's
            position) has passed through it [m].
        clear_beams: beams passing through a prior part before it is taken out of the map.
        carve_stride: every this-many-th returned beam is inserted whole, clearing the free space along it.
        carve_range_m: free space is cleared along a beam up to this range [m].
        ground_band_m: returns below this height are the ground [m].
    """

    resolution_m: float = 1.0
    front_tolerance_m: float = 1.0
    through_tolerance_m: float = 2.0
    clear_beams: int = 20
    carve_stride: int = 16
    carve_range_m: float = 40.0
    ground_band_m: float = 0.5

    def __post_init__(self) -> None:
        for name in ("resolution_m", "front_tolerance_m", "through_tolerance_m", "carve_range_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"MappingConfig.{name} must be positive and finite, got {value!r}")
        if self.clear_beams < 1 or self.carve_stride < 1:
            raise ValueError(f"MappingConfig.clear_beams and carve_stride must be >= 1, got {self.clear_beams}, "
                             f"{self.carve_stride}")


@dataclass(frozen=True)
class ScanUpdate:
    """What one scan changed.

    Attributes:
        new_voxels_m: (K, 3) centres of voxels first marked as unexplained obstacles by this scan [m].
        cleared_parts: indices (in the prior's `buildings`) of prior parts taken out by this scan.
    """

    new_voxels_m: np.ndarray
    cleared_parts: tuple[int, ...]

    @property
    def changed(self) -> bool:
        """True when the fused map differs from before the scan."""
        return len(self.new_voxels_m) > 0 or bool(self.cleared_parts)


class SensedMap:
    """The prior map and an OctoMap octree of what the lidar found that the prior lacks.

    Args:
        prior: the map the pilot was given.
        config: mapping settings.
        max_range_m: the lidar's longest range [m].
        top_elevation_deg: the lidar's highest beam's elevation [deg] (a return from it leaves its column open above).
    """

    def __init__(self, prior: BuildingMap, config: MappingConfig, max_range_m: float,
                 top_elevation_deg: float = 90.0) -> None:
        self.prior, self.config, self.max_range_m = prior, config, float(max_range_m)
        # a column whose highest return came from the lidar's highest beam may reach higher than anything it saw
        self._top_sin = math.sin(math.radians(top_elevation_deg)) - 1e-6
        self._open_top = np.zeros(0, dtype=np.int64)  # packed keys of voxels hit by the highest beam
        self._caster = RayCaster(prior)
        self._tree = octomap.OcTree(config.resolution_m)
        self._through = np.zeros(len(prior.buildings), dtype=np.int64)
        self._cleared = np.zeros(len(prior.buildings), dtype=bool)
        self._keys = np.zeros(0, dtype=np.int64)  # packed keys of the voxels ever marked unexplained, sorted
        self._fused: BuildingMap | None = prior

    @property
    def cleared_parts(self) -> tuple[int, ...]:
        """Indices of the prior parts taken out of the map."""
        return tuple(int(i) for i in np.flatnonzero(self._cleared))

    def integrate(self, scan: LidarScan, x_est: np.ndarray, position_sigma_m: float = 0.0) -> ScanUpdate:
        """Add one scan taken at the estimated state `x_est` (13 + n,) whose position is uncertain by
        `position_sigma_m` (1 σ) [m]."""
        cfg, res = self.config, self.config.resolution_m
        origin = np.asarray(x_est[0:3], float)
        x6 = np.asarray(x_est[6:10], float)
        rot = rotation_matrix(x6 / np.linalg.norm(x6))
        dirs = np.asarray(scan.directions_body, float) @ rot.T
        ranges = np.asarray(scan.ranges_m, float)
        points = origin + dirs * ranges[:, None]
        if not len(ranges):
            return ScanUpdate(np.zeros((0, 3)), ())
        expected, part = self._caster.first_hits(origin, dirs, self.max_range_m)
        above = points[:, 2] > cfg.ground_band_m
        short = above & (ranges < expected - cfg.front_tolerance_m)
        through = (part >= 0) & (ranges > expected + cfg.through_tolerance_m + 3.0 * position_sigma_m)
        cleared: list[int] = []
        if np.any(through):
            counts = np.bincount(part[through], minlength=len(self._through))
            self._through += counts
            newly = (self._through >= cfg.clear_beams) & ~self._cleared
            self._cleared |= newly
            cleared = [int(i) for i in np.flatnonzero(newly)]
        # beams through a cleared part, or beyond every prior surface, end on something the map now lacks
        unexplained = short | (above & through)
        packed = np.unique(pack_keys(np.floor(points[unexplained] / res).astype(np.int64)))
        topmost = unexplained & (np.asarray(scan.directions_body, float)[:, 2] >= self._top_sin)
        if np.any(topmost):
            self._open_top = np.union1d(self._open_top, pack_keys(np.floor(points[topmost] / res).astype(np.int64)))
        fresh = np.setdiff1d(packed, self._keys, assume_unique=True)
        if len(packed):
            self._tree.updateNodes((unpack_keys(packed) + 0.5) * res, True)
        carve = np.flatnonzero(above)[::cfg.carve_stride]
        if len(carve):
            self._tree.insertPointCloud(points[carve], origin, maxrange=cfg.carve_range_m)
        if len(fresh):
            self._keys = np.union1d(self._keys, fresh)
        if len(fresh) or cleared:
            self._fused = None
        return ScanUpdate((unpack_keys(fresh) + 0.5) * res, tuple(cleared))

    def occupied_voxels_m(self) -> np.ndarray:
        """Centres (K, 3) [m] of the unexplained voxels the octree holds occupied now."""
        res = self.config.resolution_m
        if not len(self._keys):
            return np.zeros((0, 3))
        centres = (unpack_keys(self._keys) + 0.5) * res
        held = np.zeros(len(centres), dtype=bool)
        # one search per voxel (under a microsecond each); the binding's extractPointCloud builds a Python array per
        # leaf of the whole tree, a thousand times slower
        for i, c in enumerate(centres):
            try:
                held[i] = self._tree.isNodeOccupied(self._tree.search(c))
            except octomap.NullPointerException:  # never reached by a beam since, or pruned: unknown
                continue
        return centres[held]

    def fused(self) -> BuildingMap:
        """The map to plan and track on: the prior's kept parts and the sensed obstacles as boxes (cached until a
        scan changes it)."""
        if self._fused is None:
            self._fused = self._fuse()
        return self._fused

    def _fuse(self) -> BuildingMap:
        prior, res = self.prior, self.config.resolution_m
        kept = tuple(p for p, gone in zip(prior.buildings, self._cleared, strict=True) if not gone)
        voxels = self.occupied_voxels_m()
        if len(voxels) and len(self._open_top):
            voxels = _open_columns(voxels, self._open_top, res, float(prior.bounds_max_m[2]))
        first = int(max((p.id for p in prior.buildings), default=-1)) + 1
        sensed = column_boxes(voxels, res, first, prior.bounds_min_m, prior.bounds_max_m)
        return BuildingMap(kept + sensed, prior.bounds_min_m, prior.bounds_max_m, prior.no_fly, prior.name)


def column_boxes(voxels_m: np.ndarray, resolution_m: float, first_id: int, lo_m: np.ndarray, hi_m: np.ndarray
                 ) -> tuple[Building, ...]:
    """Occupied voxel centres (K, 3) [m] as boxes standing on the ground: each occupied column (a cell of
    `resolution_m` in x, y, inside the bounds) as tall as its highest voxel's top, rounded up to whole voxels;
    runs of equal columns along x, then equal runs along y, merged into one box; ids from `first_id`. Only the
    cells seen are closed (a building seen from one side is a wall), never the space between them."""
    r = float(resolution_m)
    lo = np.asarray(lo_m, float)[0:2]
    n = np.maximum(np.ceil((np.asarray(hi_m, float)[0:2] - lo) / r).astype(int), 1)
    v = np.asarray(voxels_m, float).reshape(-1, 3)
    cells = np.floor((v[:, 0:2] - lo) / r).astype(int)
    inside = np.all((cells >= 0) & (cells < n), axis=1)
    if not np.any(inside):
        return ()
    levels = np.floor(v[inside, 2] / r).astype(int) + 1  # the column's top, in voxels
    top: dict[tuple[int, int], int] = {}
    for (cx, cy), level in zip(map(tuple, cells[inside]), levels):
        top[(cx, cy)] = max(top.get((cx, cy), 0), int(level))
    rows: dict[int, list[tuple[int, int]]] = {}  # y -> sorted (x, level)
    for (cx, cy), level in sorted(top.items(), key=lambda kv: (kv[0][1], kv[0][0])):
        rows.setdefault(cy, []).append((cx, level))
    rects: list[tuple[int, int, int, int, int]] = []  # x0, x1, y0, y1, level
    open_rects: dict[tuple[int, int, int], int] = {}  # (x0, x1, level) -> y0, for runs continued up to this row
    last_row = -(1 << 40)  # no row yet
    for cy in sorted(rows):
        runs: list[tuple[int, int, int]] = []
        for cx, level in rows[cy]:
            if runs and runs[-1][1] == cx - 1 and runs[-1][2] == level:
                runs[-1] = (runs[-1][0], cx, level)
            else:
                runs.append((cx, cx, level))
        continued = {} if last_row != cy - 1 else {run: open_rects[run] for run in runs if run in open_rects}
        for run, y0 in open_rects.items():
            if run not in continued:
                rects.append((run[0], run[1], y0, last_row, run[2]))
        open_rects = {run: continued.get(run, cy) for run in runs}
        last_row = cy
    rects.extend((run[0], run[1], y0, last_row, run[2]) for run, y0 in open_rects.items())
    out: list[Building] = []
    for x0, x1, y0, y1, level in sorted(rects):
        xa, xb = max(lo[0] + x0 * r, float(lo_m[0])), min(lo[0] + (x1 + 1) * r, float(hi_m[0]))
        ya, yb = max(lo[1] + y0 * r, float(lo_m[1])), min(lo[1] + (y1 + 1) * r, float(hi_m[1]))
        out.append(Building(first_id + len(out), (0.5 * (xa + xb), 0.5 * (ya + yb)), (xb - xa, yb - ya), level * r))
    return tuple(out)


def _open_columns(voxels_m: np.ndarray, open_top: np.ndarray, resolution_m: float, top_m: float) -> np.ndarray:
    """`voxels_m` (K, 3) with each column whose highest voxel was hit by the lidar's highest beam (`open_top`,
    packed keys) raised to the flight volume's top `top_m` [m]: what lies above it was never seen."""
    r = float(resolution_m)
    keys = np.floor(voxels_m / r).astype(np.int64)
    column = keys[:, 0] * (1 << 21) + keys[:, 1]
    order = np.lexsort((-keys[:, 2], column))
    first = order[np.r_[True, column[order][1:] != column[order][:-1]]]  # each column's highest voxel
    raise_ = first[np.isin(pack_keys(keys[first]), open_top)]
    if not len(raise_):
        return voxels_m
    extra = voxels_m[raise_].copy()
    extra[:, 2] = max(top_m - 0.5 * r, float(np.max(voxels_m[raise_, 2])))
    return np.vstack([voxels_m, extra])


_KEY_OFFSET = 1 << 20  # voxel keys within ±2^20 of the origin (±1,000 km at 1 m) pack into one int64
_KEY_BITS = 21


def pack_keys(keys: np.ndarray) -> np.ndarray:
    """Integer voxel keys (K, 3) packed into one int64 each (ordered by z, then y, then x)."""
    k = np.asarray(keys, np.int64).reshape(-1, 3) + _KEY_OFFSET
    return (k[:, 2] << (2 * _KEY_BITS)) | (k[:, 1] << _KEY_BITS) | k[:, 0]


def unpack_keys(packed: np.ndarray) -> np.ndarray:
    """The integer voxel keys (K, 3) of `pack_keys`' output."""
    p = np.asarray(packed, np.int64)
    mask = (1 << _KEY_BITS) - 1
    return np.column_stack([p & mask, (p >> _KEY_BITS) & mask, p >> (2 * _KEY_BITS)]) - _KEY_OFFSET
