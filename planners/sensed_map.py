"""The classical pilot's map of what its lidar has sensed, fused with the prior map it was given.

Each scan is placed on the navigation estimate (the pilot knows no truer pose) and compared, beam by beam, with
what the prior map predicts along the same beam (Embree, `uam_fdm.sensing.raycast.RayCaster` over the prior):

* a return well short of the prior's surface (by more than `front_tolerance_m` plus 3 σ of the estimate's position)
  is something the prior lacks: its voxel is marked occupied in an OctoMap octree (log-odds, `octomap-python`);
* a return well beyond a prior part's surface (by more than `through_tolerance_m` plus 3 σ of the estimate's
  position) and outside that part (by as much) means the beam flew through it. A part is taken out of the map (the
  survey has it where the world does not) after `clear_beams` beams crossed its core, the part shrunk by the
  survey's stated accuracy (`core_inset_m` off its walls, `core_drop_m` off its roof), unless beams also end on it
  (at least `confirm_ratio` of those through it). A building surveyed a few metres off or too tall stands in its
  surveyed core; beams through the rest (an overhanging end, a roof surveyed too high) say where the survey is off,
  not that the building is gone, and it stays as surveyed; a return beyond the surveyed face but inside the part
  is its real face: it confirms it. A return on a part taken out is an obstacle like any unexplained one;
* every `carve_stride`-th beam is also inserted whole (free space along it up to `carve_range_m`, its end
  occupied), so that voxels marked by noise or by an estimate since corrected are cleared as beams pass through.

Returns on the ground (below `ground_band_m` plus 3 σ) are left out: the prior knows the ground. `fused()` gives the
map the pilot plans and tracks on: the prior parts not cleared, grown to cover the occupied voxels next to them (a
survey's footprint and height errors, `grown_parts`), their faces surveyed proud of what the beams found behind them
moved in (`shrunk_parts`, `MappingConfig.face_returns`), and the other occupied voxels as obstacles standing on the
ground (2.5-D columns of `column_m`, each as tall as its highest voxel, equal neighbouring columns merged into boxes;
what lies above a column is taken as free, as all unseen space is, unless `open_above_m` holds an unmapped obstacle's
column taller where the lidar's highest beam ended on it; a prior part's height stands above what was seen of it). It
is conservative where it must be: the space under a crane's jib is closed. Frames: world ENU metres.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TypeGuard

import numpy as np
import octomap

from uam_fdm.city.buildings import Building, BuildingMap, Obstacle
from uam_fdm.sensing.lidar import LidarScan
from uam_fdm.sensing.raycast import RayCaster
from uam_fdm.vehicle.attitude import rotation_matrix


@dataclass(frozen=True)
class MappingConfig:
    """How the classical pilot maps what it senses.

    Attributes:
        resolution_m: octree voxel edge [m].
        front_tolerance_m: a return this much short of the prior's surface (plus 3 σ of the estimate's position) is
            an obstacle the prior lacks [m].
        through_tolerance_m: a return this much beyond a prior part's surface (plus 3 σ of the estimate's
            position) has passed through it [m].
        clear_beams: beams crossing a prior part's core before it is taken out of the map.
        core_inset_m, core_drop_m: a part's core is its footprint shrunk by `core_inset_m` and its roof lowered by
            `core_drop_m` [m]: beyond the prior map's stated accuracy (the `wrong` preset shifts footprints by up
            to 3 m and heights by up to 8 m, `uam_fdm.city.map_error`), so a real building surveyed off still
            stands in its core. A part too small to have a core is never taken out.
        confirm_ratio: a prior part is kept, whatever passed through it, while the beams ending on or in it (within
            the tolerances) number at least this fraction of those through it: it stands, surveyed a little off.
            Found on a tuning leg (docs/planner.md): two buildings of a `wrong` map, surveyed 1.7 m and 2.7 m off
            (and one 7 m too tall), were taken out whole, and the quad flew into one.
        carve_stride: every this-many-th returned beam is inserted whole, clearing the free space along it.
        carve_range_m: free space is cleared along a beam up to this range [m].
        ground_band_m: returns below this height (plus 3 σ of the estimate's position) are the ground [m].
        column_m: the fused map's sensed obstacles are columns of this square footprint, their heights rounded up
            to it [m] (a whole number of voxels: coarser columns merge into fewer boxes, which the planner checks
            faster, at up to one column of added conservatism).
        attach_m, attach_height_m: a sensed voxel within `attach_m` of a prior part's footprint (horizontally) and
            at most `attach_height_m` above its roof is that part's, seen where the survey did not put it: the part
            grows to cover it (`grown_parts`) instead of a column standing beside it [m].
        attach_cover: a part grows out past one of its sides only when such voxels beyond it cover at least this
            fraction of the side's length (a surveyed-off face runs along it; an unmapped neighbour standing within
            `attach_m` covers a stretch, and the box grown over it swelled along the whole side: 10.6 m to 17.9 m
            wide on a tuning leg, docs/planner.md); the others stand as columns.
        open_above_m: a column of an obstacle the prior lacks whose highest return came from the lidar's highest
            beam is held this much taller (what lies above was not seen then), never above where the vehicle has
            flown over it [m]. 0 (the default): the space above is taken as free, as all unseen space is; climbing
            past such a column brings its face into the lidar's view, where a taller obstacle blocks the path and
            the pilot replans. Measured on tuning legs (docs/planner.md): 10 m held the vehicle out of streets it
            could fly and, once its reference ran above such a column, inside an obstacle it could not plan out of;
            the flight volume's top (the earliest rule) closed whole districts seen from low down.
        face_returns: a box part's wall (or roof) surveyed proud of the building is moved in to the real face once
            this many returns landed on that face inside the surveyed part, to the least deep of them less 3 σ of the
            estimate's position (`shrunk_parts`; the `wrong` preset shifts footprints by up to 3 m, which left a
            surveyed face standing in the street); 0: parts keep their surveyed faces.
        column_fit_m: a sensed column's footprint is the extent of the returns that marked its voxels, snapped
            outward to this grid [m] (it divides `column_m`), not its whole square: the squares of a wall at an
            angle to the grid stood 2-3 m proud of it and closed streets the truth leaves open (validation legs
            quad-020/6, quad-031/10; docs/planner.md). 0: whole squares.
    """

    resolution_m: float = 1.0
    front_tolerance_m: float = 1.0
    through_tolerance_m: float = 1.0
    clear_beams: int = 20
    confirm_ratio: float = 0.5
    core_inset_m: float = 4.0
    core_drop_m: float = 10.0
    carve_stride: int = 32
    carve_range_m: float = 20.0
    ground_band_m: float = 0.5
    column_m: float = 2.0
    attach_m: float = 3.0
    attach_height_m: float = 10.0
    attach_cover: float = 0.5
    open_above_m: float = 0.0
    face_returns: int = 5
    column_fit_m: float = 0.25

    def __post_init__(self) -> None:
        for name in ("resolution_m", "front_tolerance_m", "through_tolerance_m", "carve_range_m", "column_m",
                     "attach_m", "attach_height_m", "core_inset_m", "core_drop_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"MappingConfig.{name} must be positive and finite, got {value!r}")
        if not (math.isfinite(self.attach_cover) and 0.0 <= self.attach_cover <= 1.0):
            raise ValueError(f"MappingConfig.attach_cover must be in [0, 1], got {self.attach_cover!r}")
        if not (math.isfinite(self.confirm_ratio) and self.confirm_ratio > 0.0):
            raise ValueError(f"MappingConfig.confirm_ratio must be positive and finite, got {self.confirm_ratio!r}")
        if not (math.isfinite(self.open_above_m) and self.open_above_m >= 0.0):
            raise ValueError(f"MappingConfig.open_above_m must be >= 0 and finite, got {self.open_above_m!r}")
        voxels = self.column_m / self.resolution_m
        if abs(voxels - round(voxels)) > 1e-9 or round(voxels) < 1:
            raise ValueError(f"MappingConfig.column_m must be a whole number of voxels ({self.resolution_m} m), got "
                             f"{self.column_m!r}")
        fit = self.column_fit_m
        steps = self.column_m / fit if math.isfinite(fit) and fit > 0.0 else 1.0
        if not (math.isfinite(fit) and fit >= 0.0) or abs(steps - round(steps)) > 1e-9:
            raise ValueError(f"MappingConfig.column_fit_m must be 0 or divide column_m ({self.column_m}), got {fit!r}")
        if self.face_returns < 0:
            raise ValueError(f"MappingConfig.face_returns must be >= 0, got {self.face_returns!r}")
        if self.clear_beams < 1 or self.carve_stride < 1:
            raise ValueError(f"MappingConfig.clear_beams and carve_stride must be >= 1, got {self.clear_beams}, "
                             f"{self.carve_stride}")


def part_halfspaces(parts: Sequence[Obstacle]) -> tuple[np.ndarray, np.ndarray]:
    """The convex parts' walls as half-planes and their vertical extents, padded to the most walls.

    Returns:
        planes (P, E, 3): per wall its outward unit normal (x, y) and offset c, inside where n·p <= c (padding walls
            never bind); heights (P, 2): base and roof [m].
    """
    # every part's footprint is counter-clockwise (`Building.footprint_xy_m`; a `Prism` is checked so)
    rings: list[np.ndarray] = [np.asarray(p.footprint_xy_m(), dtype=np.float64) for p in parts]
    n_walls = max((len(r) for r in rings), default=3)
    planes = np.zeros((len(rings), n_walls, 3))
    planes[:, :, 2] = np.inf  # padding: n·p - c = -inf
    for k, ring in enumerate(rings):
        edge: np.ndarray = np.roll(ring, -1, axis=0) - ring
        normal = np.column_stack([edge[:, 1], -edge[:, 0]]) / np.linalg.norm(edge, axis=1)[:, None]  # outward (CCW)
        planes[k, :len(ring), 0:2] = normal
        planes[k, :len(ring), 2] = np.sum(normal * ring, axis=1)
    heights = np.array([[float(getattr(p, "base_m", 0.0)), float(p.height_m)] for p in parts],
                       dtype=np.float64).reshape(-1, 2)
    return planes, heights


def scaled_to_vehicle(config: MappingConfig, radius_m: float) -> MappingConfig:
    """`config` with columns as wide as the vehicle's collision radius `radius_m` [m] (whole voxels), when that is
    wider than `config.column_m`: a passenger vehicle of 6 m radius gains nothing from 2 m columns, and the planner's
    work grows with the fused map's boxes (docs/planner.md)."""
    voxels = math.floor(float(radius_m) / config.resolution_m + 1e-9)
    wide = voxels * config.resolution_m
    return dataclasses.replace(config, column_m=wide) if wide > config.column_m else config


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
        # per column (x, y voxel keys) the lowest the vehicle has flown over it [m]: the space above is free
        self._flown_over: dict[tuple[int, int], float] = {}
        self._caster = RayCaster(prior)
        self._planes, self._heights = part_halfspaces(prior.buildings)
        self._tree = octomap.OcTree(config.resolution_m)
        self._through = np.zeros(len(prior.buildings), dtype=np.int64)
        self._confirmed = np.zeros(len(prior.buildings), dtype=np.int64)  # beams ending on or in each part
        self._through_core = np.zeros(len(prior.buildings), dtype=np.int64)  # beams through its core
        self._cleared = np.zeros(len(prior.buildings), dtype=bool)
        # per part, walls 0-3 (its footprint's edges) and roof (4): returns on the real face inside the surveyed
        # part, and the least depth [m] of them behind the surveyed face (less 3 σ), for `shrunk_parts`
        self._box_part = np.array([_ground_box(p) for p in prior.buildings], dtype=bool)
        self._face_hits = np.zeros((len(prior.buildings), 5), dtype=np.int64)
        self._face_depth = np.full((len(prior.buildings), 5), np.inf)
        self._face_deepest = np.full((len(prior.buildings), 5), -np.inf)  # the deepest of them (plus 3 σ)
        self._face_confirmed = np.zeros((len(prior.buildings), 5), dtype=np.int64)  # returns on the surveyed face
        self._keys = np.zeros(0, dtype=np.int64)  # packed keys of the voxels ever marked unexplained, sorted
        # per key a row (`_Rows`, in the order first marked; `_slot`, aligned with `_keys`, gives each key's): its
        # centre, whether the octree held it occupied when last searched, its prior part. A key is searched again
        # only when a scan since may have changed it (`_stale`): searching all 55,000 keys of a UAM leg at every
        # refresh cost a third of the pilot's mapping time. Rows are appended, not inserted: copying 55,000 centres
        # per scan cost as much as the searches saved.
        self._slot = np.zeros(0, dtype=np.int64)
        self._rows = _Rows()
        self._touched: list[np.ndarray] = []  # packed keys updated occupied since the last search
        self._carved_at: list[np.ndarray] = []  # origins [m] of the carves since the last search
        self._fused: BuildingMap | None = prior

    @property
    def cleared_parts(self) -> tuple[int, ...]:
        """Indices of the prior parts taken out of the map."""
        return tuple(int(i) for i in np.flatnonzero(self._cleared))

    def integrate(self, scan: LidarScan, x_est: np.ndarray, position_sigma_m: float = 0.0) -> ScanUpdate:
        """Add one scan, placed on the pose the vehicle estimated when it was taken (`LidarScan.pose_estimate`), or
        on the estimated state `x_est` (13 + n,) for a scan without one, whose position is uncertain by
        `position_sigma_m` (1 σ) [m]."""
        cfg, res = self.config, self.config.resolution_m
        pose = scan.pose_estimate
        # a scan handed over a latency later is placed where the vehicle thought it was then: on the newer estimate
        # its turn in between would put phantom returns metres off at the lidar's range
        origin = np.asarray(x_est[0:3] if pose is None else pose[0:3], float)
        q = np.asarray(x_est[6:10] if pose is None else pose[3:7], float)
        rot = rotation_matrix(q / np.linalg.norm(q))
        dirs = np.asarray(scan.directions_body, float) @ rot.T
        ranges = np.asarray(scan.ranges_m, float)
        points = origin + dirs * ranges[:, None]
        if not len(ranges):
            return ScanUpdate(np.zeros((0, 3)), ())
        expected, part = self._caster.first_hits(origin, dirs, self.max_range_m)
        # the estimate's error moves every return with it: 3 σ more tolerance each way, and a higher ground band (a
        # grazing ground beam's range changes by the height error over the beam's depression's sine: many metres)
        spread = 3.0 * position_sigma_m
        if cfg.open_above_m > 0.0:  # only an open column is capped by where the vehicle flew
            self._fly_over(origin, spread)
        above = points[:, 2] > cfg.ground_band_m + spread
        short = above & (ranges < expected - cfg.front_tolerance_m - spread)
        through = (part >= 0) & (ranges > expected + cfg.through_tolerance_m + spread)
        rows = np.flatnonzero(through)
        moves_before = self.face_moves_m() if cfg.face_returns else None
        behind = np.zeros_like(through)  # returns on a part's real face, behind its surveyed one
        if len(rows):  # a return inside the part it passed is that part's real face, surveyed a little off
            inside = self._outside_m(points[rows], part[rows]) <= cfg.through_tolerance_m + spread
            if cfg.face_returns and np.any(inside):
                at = rows[inside]
                self._note_faces(origin + dirs[at] * expected[at, None], points[at], part[at], spread)
            behind[rows[inside]] = True
            through[rows[inside]] = False
            rows = rows[~inside]
        on_part = above & (part >= 0) & ~short & ~through  # ends on a prior part's surface, within the tolerances
        n_parts = len(self._through)
        if np.any(on_part):
            self._confirmed += np.bincount(part[on_part], minlength=n_parts)
            on_face = on_part & ~behind
            if cfg.face_returns and np.any(on_face):
                self._note_confirmed(points[on_face], part[on_face])
        cleared: list[int] = []
        if len(rows):
            self._through += np.bincount(part[rows], minlength=n_parts)
            core = self._crosses_core(origin, dirs[rows], ranges[rows], part[rows])
            self._through_core += np.bincount(part[rows[core]], minlength=n_parts)
            newly = ((self._through_core >= cfg.clear_beams) & (self._confirmed < cfg.confirm_ratio * self._through)
                     & ~self._cleared)
            self._cleared |= newly
            cleared = [int(i) for i in np.flatnonzero(newly)]
        # beams through a part, or on a part taken out, end on something the map now lacks
        on_cleared = np.zeros_like(on_part)
        if self._cleared.any():
            on_cleared[on_part] = self._cleared[part[on_part]]
        unexplained = short | (above & through) | on_cleared
        packed = np.unique(pack_keys(np.floor(points[unexplained] / res).astype(np.int64)))
        topmost = unexplained & (np.asarray(scan.directions_body, float)[:, 2] >= self._top_sin)
        if np.any(topmost):
            self._open_top = np.union1d(self._open_top, pack_keys(np.floor(points[topmost] / res).astype(np.int64)))
        fresh = packed[~_members(self._keys, packed)]
        if len(packed):
            self._tree.updateNodes((unpack_keys(packed) + 0.5) * res, True)
            self._touched.append(packed)
        carve = np.flatnonzero(above)[::cfg.carve_stride]
        if len(carve):
            self._tree.insertPointCloud(points[carve], origin, maxrange=cfg.carve_range_m)
            self._carved_at.append(origin)
        if len(fresh):  # sorted and new: an insertion, not a re-sort of the whole set
            at = np.searchsorted(self._keys, fresh)
            self._keys = np.insert(self._keys, at, fresh)
            centres = (unpack_keys(fresh) + 0.5) * res
            self._slot = np.insert(self._slot, at, self._rows.append(centres, self._owners(centres)))
        if len(packed) and cfg.column_fit_m > 0.0:  # where in its voxel each return fell
            marked = points[unexplained]
            slot = self._slot[np.searchsorted(self._keys, pack_keys(np.floor(marked / res).astype(np.int64)))]
            footprint = self._rows.footprint  # a view: written through
            for axis in (0, 1):
                np.minimum.at(footprint[:, axis], slot, marked[:, axis])
                np.maximum.at(footprint[:, 2 + axis], slot, marked[:, axis])
        if cleared:  # a part taken out owns nothing: the keys it owned may belong to a neighbour
            self._rows.owner[:] = self._owners(self._rows.centres)
        faces_moved = moves_before is not None and not np.array_equal(moves_before, self.face_moves_m())
        if len(fresh) or cleared or faces_moved:
            self._fused = None
        return ScanUpdate((unpack_keys(fresh) + 0.5) * res, tuple(cleared))

    def _note_faces(self, entries_m: np.ndarray, points_m: np.ndarray, parts: np.ndarray, spread_m: float) -> None:
        """Count returns (M, 3) [m] that ended inside their prior part (M,) against the surveyed face their beam
        entered it by (the one its entry point (M, 3) [m] lies on: a box part's walls and roof), keeping each face's
        least depth of them behind it less `spread_m` [m] (and the deepest plus it)."""
        keep = self._box_part[parts]
        j = parts[keep]
        face = np.argmin(np.abs(self._face_depths(entries_m[keep], j)), axis=1)
        depth = self._face_depths(points_m[keep], j)[np.arange(len(j)), face]
        np.add.at(self._face_hits, (j, face), 1)
        np.minimum.at(self._face_depth, (j, face), depth - spread_m)
        np.maximum.at(self._face_deepest, (j, face), depth + spread_m)

    def _note_confirmed(self, points_m: np.ndarray, parts: np.ndarray) -> None:
        """Count returns (M, 3) [m] on their box part's (M,) surveyed surface against the face they lie on (a
        confirmed face stays where it was surveyed)."""
        keep = self._box_part[parts]
        j = parts[keep]
        face = np.argmin(np.abs(self._face_depths(points_m[keep], j)), axis=1)
        np.add.at(self._face_confirmed, (j, face), 1)

    def _face_depths(self, points_m: np.ndarray, parts: np.ndarray) -> np.ndarray:
        """How far each point (M, 3) [m] lies behind each of its box part's (M,) walls 0-3 and roof (M, 5) [m]."""
        planes = self._planes[parts][:, :4]
        depth = np.empty((len(parts), 5))
        depth[:, :4] = planes[:, :, 2] - (planes[:, :, 0] * points_m[:, 0:1] + planes[:, :, 1] * points_m[:, 1:2])
        depth[:, 4] = self._heights[parts, 1] - points_m[:, 2]
        return depth

    def face_moves_m(self) -> np.ndarray:
        """How far each prior part's walls 0-3 and roof (P, 5) are moved in [m] (`MappingConfig.face_returns`): to
        the least deep return behind the face, once at least `face_returns` came, fewer returns confirmed the face
        where it was surveyed than `confirm_ratio` of them, and they lie on one plane parallel to it (their depths
        within `through_tolerance_m`): returns spread in depth entered by one face and ended on another (a roof
        surveyed too high, seen through the top of a wall)."""
        cfg = self.config
        if cfg.face_returns == 0:
            return np.zeros_like(self._face_depth)
        move = ((self._face_hits >= cfg.face_returns) & (self._face_confirmed < cfg.confirm_ratio * self._face_hits)
                & (self._face_deepest - self._face_depth <= cfg.through_tolerance_m))
        return np.where(move, np.maximum(self._face_depth, 0.0), 0.0)

    def _owners(self, centres_m: np.ndarray) -> np.ndarray:
        cfg = self.config
        return part_owners(self.prior.buildings, centres_m, cfg.resolution_m, cfg.attach_m, cfg.attach_height_m,
                           self._cleared)

    def _outside_m(self, points_m: np.ndarray, parts: np.ndarray) -> np.ndarray:
        """How far each point (M, 3) [m] lies outside its prior part (M,): the largest of its distances beyond the
        part's walls, roof and base planes (<= 0 inside; a lower bound of the distance outside, near a corner)."""
        planes = self._planes[parts]  # (M, E, 3): outward normal (x, y) and offset per wall
        walls = np.max(planes[:, :, 0] * points_m[:, 0:1] + planes[:, :, 1] * points_m[:, 1:2] - planes[:, :, 2],
                       axis=1)
        base, top = self._heights[parts, 0], self._heights[parts, 1]
        return np.maximum(walls, np.maximum(points_m[:, 2] - top, base - points_m[:, 2]))

    def _crosses_core(self, origin_m: np.ndarray, dirs: np.ndarray, ranges_m: np.ndarray,
                      parts: np.ndarray) -> np.ndarray:
        """Whether each beam (M,) from origin_m along dirs (M, 3), up to its return at ranges_m (M,) [m], crosses the
        core of its prior part (M,) (`MappingConfig.core_inset_m`, `core_drop_m`): a slab test on the shrunk walls."""
        cfg = self.config
        planes = self._planes[parts]
        n_d = planes[:, :, 0] * dirs[:, 0:1] + planes[:, :, 1] * dirs[:, 1:2]  # (M, E)
        gap = planes[:, :, 2] - cfg.core_inset_m - (planes[:, :, 0] * origin_m[0] + planes[:, :, 1] * origin_m[1])
        with np.errstate(divide="ignore", invalid="ignore"):
            t = gap / n_d
        # a wall the beam runs parallel to: inside it for every t, or for none
        parallel = n_d == 0.0
        t_in = np.where(n_d < 0.0, t, np.where(parallel & (gap < 0.0), np.inf, -np.inf))
        t_out = np.where(n_d > 0.0, t, np.where(parallel & (gap < 0.0), -np.inf, np.inf))
        lo = np.maximum(np.max(t_in, axis=1), 0.0)
        hi = np.minimum(np.min(t_out, axis=1), ranges_m)
        base, top = self._heights[parts, 0], self._heights[parts, 1] - cfg.core_drop_m
        dz = dirs[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            ta, tb = (base - origin_m[2]) / dz, (top - origin_m[2]) / dz
        flat = dz == 0.0
        inside_z = (origin_m[2] >= base) & (origin_m[2] <= top)
        z_lo = np.where(flat, np.where(inside_z, -np.inf, np.inf), np.minimum(ta, tb))
        z_hi = np.where(flat, np.where(inside_z, np.inf, -np.inf), np.maximum(ta, tb))
        return (np.maximum(lo, z_lo) < np.minimum(hi, z_hi)) & (top > base)

    def _fly_over(self, origin_m: np.ndarray, spread_m: float) -> None:
        """Record that the columns around the vehicle at `origin_m` (within `spread_m` plus a voxel) are free from a
        voxel below it up: an open column there is no taller (the vehicle flies where nothing stands)."""
        res = self.config.resolution_m
        reach = int(math.ceil(spread_m / res)) + 1
        cx, cy = (int(math.floor(float(v) / res)) for v in origin_m[0:2])
        free_from = float(origin_m[2]) - spread_m - res
        for ix in range(cx - reach, cx + reach + 1):
            for iy in range(cy - reach, cy + reach + 1):
                key = (ix, iy)
                if free_from < self._flown_over.get(key, math.inf):
                    self._flown_over[key] = free_from

    def occupied_voxels_m(self) -> np.ndarray:
        """Centres (K, 3) [m] of the unexplained voxels the octree holds occupied now (in key order)."""
        return self._rows.centres[self._held_slots()]

    def _held_slots(self) -> np.ndarray:
        """Rows of the keys the octree holds occupied now, in key order (the stale ones searched again)."""
        if not len(self._keys):
            return np.zeros(0, dtype=np.int64)
        held, centres, tree = self._rows.held, self._rows.centres, self._tree  # views: written through
        # one search per voxel (under a microsecond each); the binding's extractPointCloud builds a Python array per
        # leaf of the whole tree, a thousand times slower
        for i in np.flatnonzero(self._stale()).tolist():
            try:
                held[i] = tree.isNodeOccupied(tree.search(centres[i]))
            except octomap.NullPointerException:  # never reached by a beam since, or pruned: unknown
                held[i] = False
        return self._slot[held[self._slot]]

    def _stale(self) -> np.ndarray:
        """Which rows a scan since the last search may have changed: those updated occupied, and those within a
        carve's reach (`carve_range_m` and a voxel's diagonal) of where it was inserted from; then forgets both."""
        centres = self._rows.centres
        stale = np.zeros(len(centres), dtype=bool)
        if self._touched:
            stale[self._slot[_members(np.unique(np.concatenate(self._touched)), self._keys)]] = True
        if self._carved_at:
            origins = np.asarray(self._carved_at, float)
            centre = 0.5 * (origins.min(axis=0) + origins.max(axis=0))
            spread = 0.5 * float(np.linalg.norm(origins.max(axis=0) - origins.min(axis=0)))
            reach = self.config.carve_range_m + math.sqrt(3.0) * self.config.resolution_m + spread
            stale |= np.einsum("ij,ij->i", centres - centre, centres - centre) <= reach * reach
        self._touched.clear()
        self._carved_at.clear()
        return stale

    def fused(self) -> BuildingMap:
        """The map to plan and track on: the prior's kept parts and the sensed obstacles as boxes (cached until a
        scan changes it)."""
        if self._fused is None:
            self._fused = self._fuse()
        return self._fused

    def _fuse(self) -> BuildingMap:
        prior, res = self.prior, self.config.resolution_m
        held = self._held_slots()
        voxels, footprints = self._rows.centres[held], self._rows.footprint[held]
        cfg = self.config
        grown, attached = grown_parts(shrunk_parts(prior.buildings, self.face_moves_m()), voxels, res, cfg.attach_m,
                                      cfg.attach_height_m, cfg.attach_cover, self._rows.owner[held])
        kept = tuple(p for p, gone in zip(grown, self._cleared, strict=True) if not gone)
        voxels, footprints = voxels[~attached], footprints[~attached]
        # a part the prior has keeps the prior's height above what was seen of it; only an obstacle the prior lacks
        # is open above its highest return
        if len(voxels) and len(self._open_top) and cfg.open_above_m > 0.0:
            voxels = _open_columns(voxels, self._open_top, res, float(prior.bounds_max_m[2]), cfg.open_above_m,
                                   self._flown_over)
            # a raised voxel adds height to its column, not footprint
            footprints = np.vstack([footprints, np.full((len(voxels) - len(footprints), 4), np.nan)])
        first = int(max((p.id for p in prior.buildings), default=-1)) + 1
        sensed = column_boxes(voxels, cfg.column_m, first, prior.bounds_min_m, prior.bounds_max_m, footprints,
                              cfg.column_fit_m)
        return BuildingMap(kept + sensed, prior.bounds_min_m, prior.bounds_max_m, prior.no_fly, prior.name)


class _Rows:
    """Per marked voxel, in the order first marked: its centre [m], whether the octree held it occupied when last
    searched, the prior part it may belong to (`part_owners`) and the horizontal extent of the returns that marked
    it; grown by doubling."""

    def __init__(self) -> None:
        self.n = 0
        self._centres, self._held, self._owner = np.zeros((64, 3)), np.zeros(64, dtype=bool), np.zeros(64, np.int64)
        self._footprint = np.zeros((64, 4))

    @property
    def centres(self) -> np.ndarray:
        return self._centres[:self.n]

    @property
    def held(self) -> np.ndarray:
        return self._held[:self.n]

    @property
    def owner(self) -> np.ndarray:
        return self._owner[:self.n]

    @property
    def footprint(self) -> np.ndarray:
        """(x_lo, y_lo, x_hi, y_hi) [m] of the returns that marked each voxel (+inf, +inf, -inf, -inf: none yet)."""
        return self._footprint[:self.n]

    def append(self, centres_m: np.ndarray, owner: np.ndarray) -> np.ndarray:
        """Add rows (not yet searched: not held; no returns on record); returns their indices."""
        k = len(centres_m)
        if self.n + k > len(self._held):
            size = max(2 * len(self._held), self.n + k)
            self._centres, self._footprint = np.resize(self._centres, (size, 3)), np.resize(self._footprint, (size, 4))
            self._held, self._owner = np.resize(self._held, size), np.resize(self._owner, size)
        new = np.arange(self.n, self.n + k)
        self._centres[new], self._held[new], self._owner[new] = centres_m, False, owner
        self._footprint[new] = (np.inf, np.inf, -np.inf, -np.inf)
        self.n += k
        return new


def part_owners(parts: Sequence[Obstacle], voxels_m: np.ndarray, resolution_m: float, attach_m: float,
                attach_height_m: float, skip: np.ndarray | None = None) -> np.ndarray:
    """For each occupied voxel (K, 3) [m], the index of the prior part it may belong to (-1: none).

    That is the nearest ground-standing box part (ties: the first) whose footprint its centre lies within `attach_m`
    of (horizontally) and whose roof its bottom is at most `attach_height_m` above: what the survey's footprint and
    height errors look like. Prisms, raised boxes and the parts `skip` (P,) marks are never owners."""
    v = np.asarray(voxels_m, float).reshape(-1, 3)
    owner = np.full(len(v), -1, dtype=np.int64)
    sel = [(j, p) for j, p in enumerate(parts) if _ground_box(p)
           and (skip is None or not skip[j])]
    if not len(v) or not sel:
        return owner
    c = np.array([p.center_xy_m for _, p in sel], dtype=float)
    half = 0.5 * np.array([p.size_xy_m for _, p in sel], dtype=float)
    yaw = np.array([p.yaw_rad for _, p in sel], dtype=float)
    co, si = np.cos(yaw), np.sin(yaw)
    roof = np.array([p.height_m for _, p in sel], dtype=float) + attach_height_m
    index = np.array([j for j, _ in sel], dtype=np.int64)
    chunk = max(1, (1 << 20) // len(sel))  # (points x parts) pairs per step, about a million
    for a in range(0, len(v), chunk):
        d = v[a:a + chunk, None, 0:2] - c  # (M, P, 2)
        lx, ly = d[..., 0] * co + d[..., 1] * si, -d[..., 0] * si + d[..., 1] * co
        gap = np.hypot(np.maximum(np.abs(lx) - half[:, 0], 0.0), np.maximum(np.abs(ly) - half[:, 1], 0.0))
        gap[(gap > attach_m) | (v[a:a + chunk, 2:3] - 0.5 * resolution_m > roof)] = np.inf
        best = np.argmin(gap, axis=1)
        found = np.isfinite(gap[np.arange(len(best)), best])
        owner[a:a + chunk][found] = index[best[found]]
    return owner


def _ground_box(part: Obstacle) -> TypeGuard[Building]:
    """A box standing on the ground (a `Building` with a base of 0): the parts whose faces `shrunk_parts` moves."""
    return isinstance(part, Building) and part.base_m <= 0.0


_MIN_PART_M = 1.0  # a part moved in keeps at least this width, depth and height [m]


def shrunk_parts(parts: Sequence[Obstacle], moves_m: np.ndarray) -> tuple:
    """The parts with each ground-standing box's walls (its footprint's edges 0-3, counter-clockwise) and roof (4)
    moved in by `moves_m` (P, 5) [m], each dimension kept at least 1 m; other parts as they are."""
    out = list(parts)
    for j in np.flatnonzero(np.any(moves_m > 0.0, axis=1)).tolist():
        part = out[j]
        if not _ground_box(part):
            continue
        ring = np.asarray(part.footprint_xy_m(), float)
        edge = np.roll(ring, -1, axis=0) - ring
        co, si = math.cos(part.yaw_rad), math.sin(part.yaw_rad)
        # each edge's outward normal in the part's frame: +x, +y, -x or -y
        nx, ny = edge[:, 1] * co - edge[:, 0] * si, -edge[:, 1] * si - edge[:, 0] * co
        half = 0.5 * np.asarray(part.size_xy_m, float)
        lo, hi = -half.copy(), half.copy()
        for k in range(4):
            axis = 0 if abs(nx[k]) >= abs(ny[k]) else 1
            outward = nx[k] if axis == 0 else ny[k]
            if outward > 0:
                hi[axis] -= moves_m[j, k]
            else:
                lo[axis] += moves_m[j, k]
        for axis in (0, 1):  # never thinner than the minimum, shrunk about what is left
            if hi[axis] - lo[axis] < _MIN_PART_M:
                mid = 0.5 * (lo[axis] + hi[axis])
                lo[axis], hi[axis] = mid - 0.5 * _MIN_PART_M, mid + 0.5 * _MIN_PART_M
        mx, my = 0.5 * (lo + hi)
        centre = (float(part.center_xy_m[0] + mx * co - my * si), float(part.center_xy_m[1] + mx * si + my * co))
        height = max(float(part.height_m) - float(moves_m[j, 4]), _MIN_PART_M)
        out[j] = dataclasses.replace(part, center_xy_m=centre, size_xy_m=(float(hi[0] - lo[0]), float(hi[1] - lo[1])),
                                     height_m=height)
    return tuple(out)


def grown_parts(parts: tuple, voxels_m: np.ndarray, resolution_m: float, attach_m: float, attach_height_m: float,
                min_cover: float = 0.5, owner: np.ndarray | None = None) -> tuple[tuple, np.ndarray]:
    """The prior's parts grown to cover the occupied voxels (K, 3) [m] that belong to them, and which voxels did.

    A voxel is a candidate of the part `part_owners` gives it (`owner` (K,), when the caller has them). A part grows
    out past one of its sides only when its candidates beyond that side cover at least `min_cover` of the side's
    length (a building surveyed off shows its face along the whole side; an unmapped neighbour standing close shows
    a stretch of it, and an oriented box grown to cover that stretch would swell along the whole side, into the
    street). The part grows, in its own frame, to the box covering its footprint and the accepted sides'
    candidates, and up to the highest top of the candidates it then covers; those are the attached voxels, the
    others stay for the caller."""
    v = np.asarray(voxels_m, float).reshape(-1, 3)
    if owner is None:
        owner = part_owners(parts, v, resolution_m, attach_m, attach_height_m)
    attached = np.zeros(len(v), dtype=bool)
    out = list(parts)
    corner = 0.5 * resolution_m * np.array([[-1, -1], [-1, 1], [1, -1], [1, 1]])
    for j in np.unique(owner[owner >= 0]).tolist():
        part = out[j]
        c, half = np.asarray(part.center_xy_m, float), 0.5 * np.asarray(part.size_xy_m, float)
        co, si = math.cos(part.yaw_rad), math.sin(part.yaw_rad)
        idx = np.flatnonzero(owner == j)
        d = v[idx, 0:2] - c
        local = np.column_stack([d[:, 0] * co + d[:, 1] * si, -d[:, 0] * si + d[:, 1] * co])
        lo, hi = -half.copy(), half.copy()
        for axis in (0, 1):
            other = 1 - axis
            bins = max(int(math.ceil(2.0 * half[other] / resolution_m - 1e-9)), 1)
            for sign in (-1.0, 1.0):
                beyond = sign * local[:, axis] > half[axis]
                if not beyond.any():
                    continue
                along = np.floor((local[beyond, other] + half[other]) / resolution_m).astype(np.int64)
                if np.unique(np.clip(along, 0, bins - 1)).size < min_cover * bins:
                    continue
                reach = float(np.max(sign * local[beyond, axis])) + 0.5 * resolution_m
                if sign > 0:
                    hi[axis] = max(hi[axis], reach)
                else:
                    lo[axis] = min(lo[axis], -reach)
        inside = np.all((local >= lo - 1e-9) & (local <= hi + 1e-9), axis=1)
        if not inside.any():
            continue
        attached[idx[inside]] = True
        cells = (local[inside, None, :] + corner).reshape(-1, 2)
        x0, x1 = min(lo[0], float(cells[:, 0].min())), max(hi[0], float(cells[:, 0].max()))
        y0, y1 = min(lo[1], float(cells[:, 1].min())), max(hi[1], float(cells[:, 1].max()))
        mx, my = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        centre = (float(c[0] + mx * co - my * si), float(c[1] + mx * si + my * co))
        out[j] = dataclasses.replace(part, center_xy_m=centre, size_xy_m=(x1 - x0, y1 - y0),
                                     height_m=max(part.height_m, float(v[idx[inside], 2].max()) + 0.5 * resolution_m))
    return tuple(out), attached


def column_boxes(voxels_m: np.ndarray, column_m: float, first_id: int, lo_m: np.ndarray, hi_m: np.ndarray,
                 footprints_m: np.ndarray | None = None, fit_m: float = 0.0) -> tuple[Building, ...]:
    """Occupied voxel centres (K, 3) [m] as boxes standing on the ground: each occupied column (a square of
    `column_m` in x, y, inside the bounds) as tall as its highest voxel's top, rounded up to whole `column_m` (a
    multiple of the voxel edge, so that the rounding never cuts a voxel);
    runs of equal columns along x, then equal runs along y, merged into one box (touching: a column's footprint
    reaching its cell's side); ids from `first_id`, boxes ordered by their cells. Only the cells seen are closed (a
    building seen from one side is a wall), never the space between them.

    `footprints_m` (K, 4): per voxel the (x_lo, y_lo, x_hi, y_hi) [m] of the returns that marked it (NaN: not
    known); with `fit_m` > 0 a column's footprint is the union of its voxels' snapped outward to a grid of `fit_m`
    (which divides `column_m`) inside its cell, not the whole cell: a wall at an angle to the grid stands as a
    staircase of cells whose outer corners stood up to a column's diagonal off it."""
    c = float(column_m)
    lo = np.asarray(lo_m, float)[0:2]
    n = np.maximum(np.ceil((np.asarray(hi_m, float)[0:2] - lo) / c).astype(np.int64), 1)
    v = np.asarray(voxels_m, float).reshape(-1, 3)
    cells = np.floor((v[:, 0:2] - lo) / c).astype(np.int64)
    inside = np.all((cells >= 0) & (cells < n), axis=1)
    if not np.any(inside):
        return ()
    fitted = footprints_m is not None and fit_m > 0.0
    q = float(fit_m) if fitted else c  # the footprint's grid [m]
    per = int(round(c / q))  # grid steps per column
    column = cells[inside, 1] * n[0] + cells[inside, 0]  # row-major: by y, then x
    level = np.floor(v[inside, 2] / c).astype(np.int64) + 1  # the voxel's top, in columns
    order = np.argsort(column, kind="stable")
    column, level = column[order], level[order]
    first = np.flatnonzero(np.r_[True, column[1:] != column[:-1]])
    cy, cx = np.divmod(column[first], n[0])
    top = np.maximum.reduceat(level, first)  # each column's top
    # each column's footprint in grid steps from `lo`: its cell, or the snapped union of its voxels' returns
    fx0, fy0, fx1, fy1 = cx * per, cy * per, (cx + 1) * per, (cy + 1) * per
    if fitted:
        assert footprints_m is not None
        f = np.asarray(footprints_m, float).reshape(-1, 4)[inside][order]
        known = np.all(np.isfinite(f), axis=1)
        big = np.where(known[:, None], f, [np.inf, np.inf, -np.inf, -np.inf])
        ux0, uy0 = np.minimum.reduceat(big[:, 0], first), np.minimum.reduceat(big[:, 1], first)
        ux1, uy1 = np.maximum.reduceat(big[:, 2], first), np.maximum.reduceat(big[:, 3], first)
        seen = np.isfinite(ux0)  # a column none of whose voxels has returns on record keeps its whole cell
        with np.errstate(invalid="ignore"):
            fx0 = np.where(seen, np.clip(np.floor((ux0 - lo[0]) / q), fx0, fx1 - 1), fx0).astype(np.int64)
            fy0 = np.where(seen, np.clip(np.floor((uy0 - lo[1]) / q), fy0, fy1 - 1), fy0).astype(np.int64)
            fx1 = np.where(seen, np.clip(np.ceil((ux1 - lo[0]) / q), fx0 + 1, fx1), fx1).astype(np.int64)
            fy1 = np.where(seen, np.clip(np.ceil((uy1 - lo[1]) / q), fy0 + 1, fy1), fy1).astype(np.int64)
    # runs of equal neighbouring columns along x that touch across their shared side
    joins = ((cy[1:] == cy[:-1]) & (cx[1:] == cx[:-1] + 1) & (top[1:] == top[:-1]) & (fy0[1:] == fy0[:-1])
             & (fy1[1:] == fy1[:-1]) & (fx1[:-1] == (cx[:-1] + 1) * per) & (fx0[1:] == cx[1:] * per))
    starts = np.flatnonzero(np.r_[True, ~joins])
    ends = np.r_[starts[1:], len(cx)] - 1
    x0, x1, y0, y1, ry, rl = fx0[starts], fx1[ends], fy0[starts], fy1[starts], cy[starts], top[starts]
    # equal runs in consecutive rows that touch across their shared side merged into one rectangle
    order = np.lexsort((ry, rl, x1, x0))
    x0, x1, y0, y1, ry, rl = x0[order], x1[order], y0[order], y1[order], ry[order], rl[order]
    joins = ((x0[1:] == x0[:-1]) & (x1[1:] == x1[:-1]) & (rl[1:] == rl[:-1]) & (ry[1:] == ry[:-1] + 1)
             & (y1[:-1] == (ry[:-1] + 1) * per) & (y0[1:] == ry[1:] * per))
    starts = np.flatnonzero(np.r_[True, ~joins])
    ends = np.r_[starts[1:], len(x0)] - 1
    rect = np.column_stack([x0[starts], x1[starts], y0[starts], y1[ends], rl[starts]])
    rect = rect[np.lexsort(rect.T[::-1])]
    out: list[Building] = []
    for rx0, rx1, ry0, ry1, h in rect.tolist():
        xa, xb = max(lo[0] + rx0 * q, float(lo_m[0])), min(lo[0] + rx1 * q, float(hi_m[0]))
        ya, yb = max(lo[1] + ry0 * q, float(lo_m[1])), min(lo[1] + ry1 * q, float(hi_m[1]))
        if xb - xa <= 1e-9 or yb - ya <= 1e-9:  # returns beyond the flight volume, in its last cells' overhang
            continue
        out.append(Building(first_id + len(out), (0.5 * (xa + xb), 0.5 * (ya + yb)), (xb - xa, yb - ya), h * c))
    return tuple(out)


def _open_columns(voxels_m: np.ndarray, open_top: np.ndarray, resolution_m: float, top_m: float, above_m: float,
                  flown_over: dict[tuple[int, int], float]) -> np.ndarray:
    """`voxels_m` (K, 3) with each column whose highest voxel was hit by the lidar's highest beam (`open_top`,
    packed keys) raised by `above_m` [m], at most to the flight volume's top `top_m` [m] and to below where the vehicle
    flew over the column (`flown_over`, by the columns' x, y voxel keys) [m]: what lies above it was not seen then."""
    r = float(resolution_m)
    keys = np.floor(voxels_m / r).astype(np.int64)
    column = keys[:, 0] * (1 << 21) + keys[:, 1]
    order = np.lexsort((-keys[:, 2], column))
    first = order[np.r_[True, column[order][1:] != column[order][:-1]]]  # each column's highest voxel
    raise_ = first[np.isin(pack_keys(keys[first]), open_top)]
    if not len(raise_):
        return voxels_m
    extra = voxels_m[raise_].copy()
    flown = np.array([flown_over.get((int(k[0]), int(k[1])), math.inf) for k in keys[raise_]])
    # the raised voxel's top: the hit voxel's top plus `above_m`, under the volume's top and where the vehicle flew
    extra[:, 2] = np.maximum(np.minimum(extra[:, 2] + above_m, np.minimum(top_m, flown) - 0.5 * r), extra[:, 2])
    return np.vstack([voxels_m, extra])


def _members(sorted_keys: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Which of `values` are in the sorted array `sorted_keys` (a binary search each: the set is large, the scan's
    keys few)."""
    if not len(sorted_keys):
        return np.zeros(len(values), dtype=bool)
    at = np.minimum(np.searchsorted(sorted_keys, values), len(sorted_keys) - 1)
    return sorted_keys[at] == values


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
