"""The learned pilot's obstacle senses measured by its lidar: rays, clearance, nearest surface and height map of M
slots (the env's batch, or the runner's single pilot), from the scans a decision receives and the navigation
ESTIMATE, with the same meaning and layout as the exact senses (`rl.sensing.perception`, `rl.sensing.senses`).

Every scan is placed in the world on the pose the vehicle estimated when the scan was taken (its stamp,
`LidarScan.pose_estimate`; an unstamped scan on the estimate it is integrated with): position p, attitude q, a
returned point is p + R(q) d rho, d its body FLU direction, rho its measured range; the pilot knows no truer pose. (A
scan placed on the newer estimate of the decision that receives it lands metres off at range: the small quad turns
by several degrees in the 0.1 s between, and phantom columns rose 10-20 m above open ground.) A return is
**ground** when its height is at most `ground_band_m` plus `ground_sigmas` sigma of the estimate's position (the
estimate's height error lifts every ground return with it); ground returns are never obstacles (the ground is
z = 0 in this project, and it is sensed at the estimated altitude instead). Of each slot's newest scan the
non-ground points are kept; a decision without a new scan keeps them and reads them from its current estimate.

With r the collision radius, z the estimated altitude and heading the goal frame's x' axis:

* **rays** (M, n_rays) [m]: ray j reads the nearest BAND return in its SECTOR, its horizontal distance minus r
  (at least 0), capped at `ray_range_m` (no return: the range). The band holds the returns whose height h
  satisfies z - r < h <= z + r + `band_above_m`: above z - r is where a ground-standing column blocks the sphere
  at z (the exact rays' roof + r > z); a return up to `band_above_m` above the sphere's top is taken as such a
  column's wall too (the lidar's channels are apart: level, the channel at elevation e reaches the band at
  horizontal distance d when -r < d tan e <= r + band_above_m, so at range only the channels nearest the horizontal
  do: `LidarView.band_reach_m`). Sector j is the wedge of bearings [heading + (j - 1/2) w, heading + (j + 1/2) w),
  w = 2 pi / n_rays, counter-clockwise, as `PerceptionReading.ray_m`'s rays.
* **clearance** (M,) [m] and **nearest** (M, 3) [m, world], as `rl.sensing.senses.nearest_surface` gives them:
  the nearest kept return's 3D distance minus r (beyond `clearance_range_m`: that range, no point), against the
  ground's z - r; the vector to the nearest point (the return, or (0, 0, -z) when the ground is nearer and within
  the range; zero when neither is).
* **height map** (M, grid_cells**2) [m], `PerceptionReading.roof_m`'s cells (goal frame, index a * grid_cells + b,
  a ahead): the prior map's conservative raster (`Perception.roofs` over the PRIOR cities) max'ed with the slot's
  sensed memory, which holds per world cell of side cell_m / `sensed_cells_per_cell` (world-axis aligned,
  from the origin) the highest non-ground return integrated this episode within `memory_range_m` horizontally of
  the estimate, rounded up to 0.1 m. A map cell reads the highest memory cell touched by its rotated square's
  world-axis-aligned bounding box, as the prior's raster is read. The memory is a window of G x G cells per slot
  (G = 2 ceil(memory range / cell) + 1: every cell a scan writes), centred on the cell of the estimate the slot
  last integrated a scan at, held as a ring (a world cell keeps its entry while it stays in the window); cells
  that leave the window as it follows the vehicle are forgotten, and a map cell reaching beyond it reads only the
  prior there. Bounded: 2 (G + 1)**2 bytes per slot (about 10 kB for the small quad's defaults).

What it does not do (the next person decides whether it matters):

* It never lowers a roof: a building the prior has and the world lacks stays in the height map all episode, and a
  noisy or spurious return raises its cell for the episode (no clearing by beams passing through, no log-odds).
* A sensed height is the highest return seen, not the roof: a wall seen only up to the top channel reads lower
  than its roof (still above the vehicle); the classical pilot's map holds such columns open above, this does not.
  Memory cells are coarser than the prior's raster (3 m against 1 m by default): a sensed wall also raises the map
  cells whose box touches its memory cell, up to one memory cell beyond the wall.
* Points stay where the estimate put them when integrated: a later correction of the estimate moves the vehicle,
  not the memory (nor the kept scan, read from the corrected position).
* Rays and clearance come from the newest scan alone: what left the field of view (below a pitched-down vehicle,
  beside it between scans) is forgotten there. A wedge is not a line: an obstacle in the sector off the ray (a
  street wall along it) shortens the ray; beams miss what lies between columns (a thin mast); the band takes a
  raised part's underside (a crane's jib) within `band_above_m` of the sphere as a column, and sees no wall whose
  returns all fall below z - r (a steeply pitched vehicle's beams ahead).

The arithmetic is element-wise and the reductions are min and max (exact in any order), so a slot's reading does
not depend on the other slots or on M: the env and the runner produce it bit for bit from the same scans and
estimates. Frames: world ENU metres; body FLU; the goal frame of `rl.sensing.observation`.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from rl.sensing.perception import PerceptionConfig, PerceptionReading
from uam_fdm.sensing.lidar import LidarScan
from uam_fdm.sensing.specs import LidarSpec
from uam_fdm.vehicle.attitude import rotation_matrices

_FAR_M = 1e9  # an empty point slot: beyond every range and band (finite: no inf - inf in the arithmetic)
_STEP_M = 0.1  # the height memory's resolution [m]
_TOP_STEPS = 65535  # heights are held as uint16 steps of _STEP_M (0: nothing sensed; 6,553 m at most)
_NOWHERE = -(1 << 40)  # a reset slot's window origin [cells]: the first scan's window shares no cell with it
_TOL_M = 1e-7  # a map cell's bounding box is shrunk by this: an edge on a cell line does not reach the next cell
_POSE = np.r_[0:3, 6:10]  # a pose's elements in the vehicle-state layout: position, attitude quaternion


@dataclass(frozen=True)
class LidarViewConfig:
    """How the learned pilot reads its lidar (the module docstring defines each use).

    Attributes:
        band_above_m: returns up to this far above the collision sphere's top block the rays [m].
        ground_band_m: returns at most this high (plus `ground_sigmas` sigma of the estimate) are the ground [m].
        ground_sigmas: sigmas of the estimate's position added to the ground band.
        sensed_cells_per_cell: the height memory's cells per height-map cell side (its cell is cell_m / this).
        memory_range_m: returns within this horizontal distance of the estimate enter the height memory [m].
    """

    band_above_m: float = 2.0
    ground_band_m: float = 0.5
    ground_sigmas: float = 3.0
    sensed_cells_per_cell: int = 2
    memory_range_m: float = 100.0

    def __post_init__(self) -> None:
        for name in ("band_above_m", "ground_band_m", "ground_sigmas"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0.0):
                raise ValueError(f"LidarViewConfig.{name} must be >= 0 and finite, got {value!r}")
        if not (isinstance(self.memory_range_m, (int, float)) and math.isfinite(self.memory_range_m)
                and self.memory_range_m > 0.0):
            raise ValueError(f"LidarViewConfig.memory_range_m must be positive and finite, got {self.memory_range_m!r}")
        k = self.sensed_cells_per_cell
        # a map cell reads (ceil(sqrt(2) k) + 1)**2 memory entries: beyond 8 the read costs more than the rest
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= 8:
            raise ValueError(f"LidarViewConfig.sensed_cells_per_cell must be an integer from 1 to 8, got {k!r}")


class PriorRoofs(Protocol):
    """The prior map's height maps (a `Perception` over the prior cities is one)."""

    radius_m: float
    config: PerceptionConfig

    def roofs(self, points_m: np.ndarray, heading_rad: np.ndarray, city: np.ndarray) -> np.ndarray:
        """Height maps (N, grid_cells**2) [m] around points (N, 3) [m, world] in goal frames at headings (N,) [rad],
        each in its prior city index (N,)."""
        ...


@dataclass(frozen=True)
class ObstacleSenses:
    """The obstacle part of M slots' observations, measured by the lidar.

    Attributes:
        reading: rays (M, n_rays) [m] and height map (M, grid_cells**2) [m] in the goal frame, as `Perception` gives.
        clearance_m: (M,) clearance of the collision sphere to the returns or the ground [m].
        nearest_m: (M, 3) vector to the nearest return or the ground [m, world]; zero when neither is in range.
    """

    reading: PerceptionReading
    clearance_m: np.ndarray
    nearest_m: np.ndarray


class LidarView:
    """The lidar-measured obstacle senses of N slots, each with its newest scan's points and its height memory.

    Args:
        prior: the prior maps' height maps, and the perception (rays, grid) and collision radius r [m] to read with.
        n: slots.
        lidar: the lidar every slot carries (its scans' size bounds the points kept per slot).
        clearance_range_m: the clearance is measured up to this [m] (`ObservationScales.clearance_m`).
        config: how the returns are read.

    Raises:
        ValueError: no slots, or a clearance range that is not positive and finite.
    """

    def __init__(self, prior: PriorRoofs, n: int, lidar: LidarSpec, clearance_range_m: float,
                 config: LidarViewConfig = LidarViewConfig()) -> None:
        if int(n) != n or n < 1:
            raise ValueError(f"LidarView needs at least one slot, got n={n!r}")
        if not (math.isfinite(clearance_range_m) and clearance_range_m > 0.0):
            raise ValueError(f"clearance_range_m must be positive and finite, got {clearance_range_m!r}")
        self.prior, self.lidar, self.config = prior, lidar, config
        self.perception: PerceptionConfig = prior.config
        self.radius_m = float(prior.radius_m)
        self.clearance_range_m = float(clearance_range_m)
        self.n = int(n)
        pc = self.perception
        self.sensed_cell_m = pc.cell_m / config.sensed_cells_per_cell
        # the window's side [cells]: every cell within the memory range of the centre cell's points
        self.window = 2 * math.ceil(config.memory_range_m / self.sensed_cell_m) + 1
        # memory cells a map cell's bounding box (side cell_m to sqrt(2) cell_m) touches along an axis, at most
        self._n_look = math.ceil(math.sqrt(2.0) * config.sensed_cells_per_cell) + 1
        self._offsets_m = (np.arange(pc.grid_cells) - pc.grid_cells // 2) * pc.cell_m
        self._points = np.full((self.n, lidar.rays_per_scan, 3), _FAR_M)
        self._count = np.zeros(self.n, dtype=np.int64)  # points kept per slot (the rest of its row is _FAR_M)
        # (y, x) ring entries, plus a row and a column that stay 0: where reads outside the window land
        self._memory = np.zeros((self.n, self.window + 1, self.window + 1), dtype=np.uint16)
        self._origin = np.full((self.n, 2), _NOWHERE, dtype=np.int64)  # the window's first world cell (x, y)
        self._prior_index = np.zeros(self.n, dtype=np.int64)

    @property
    def nbytes(self) -> int:
        """Bytes of the slots' state (kept points and height memories)."""
        return sum(a.nbytes for a in (self._points, self._count, self._memory, self._origin, self._prior_index))

    def band_reach_m(self, tilt_rad: float = 0.0) -> float:
        """The horizontal distance [m] out to which some channel of a vehicle pitched down by `tilt_rad` [rad]
        returns an upright wall inside the rays' band (ahead; inf: a channel at the horizontal)."""
        lo, hi = self.lidar.vertical_fov_deg
        n = self.lidar.channels
        el = np.radians(np.linspace(lo, hi, n) if n > 1 else np.array([0.5 * (lo + hi)])) - tilt_rad
        r, above = self.radius_m, self.config.band_above_m
        reach = [math.inf if e == 0.0 else (r + above) / math.tan(e) if e > 0.0 else r / math.tan(-e)
                 for e in el.tolist()]
        return max(reach)

    def reset(self, slots: Sequence[int] | np.ndarray, prior_index: Sequence[int] | np.ndarray) -> None:
        """New episodes in `slots` (M,): no points, an empty memory, the prior city index (M,) of `prior` to read."""
        idx = self._slots(slots)
        pi = np.asarray(prior_index, dtype=np.int64).reshape(-1)
        if len(pi) != len(idx):
            raise ValueError(f"reset: {len(idx)} slots but {len(pi)} prior indices")
        self._points[idx] = _FAR_M
        self._count[idx] = 0
        self._memory[idx] = 0
        self._origin[idx] = _NOWHERE
        self._prior_index[idx] = pi

    def integrate(self, slots: Sequence[int] | np.ndarray, scans_per_slot: Sequence[Sequence[LidarScan]],
                  x_est: np.ndarray, position_sigma_m: np.ndarray | None = None) -> None:
        """Place each slot's scans (in time order, as `BatchOnboard.lidar_scans` hands them) on its estimate: all go
        into the height memory, the newest's non-ground points replace the kept ones (a slot without a scan keeps
        its points).

        Args:
            slots: (M,) distinct slots, each reset before.
            scans_per_slot: per slot its scans (body FLU directions, measured ranges [m]).
            x_est: (M, 10+) the estimates the scans are placed on: position [m] world ENU, velocity, attitude
                quaternion [w, x, y, z] body FLU -> world ENU (the vehicle-state layout).
            position_sigma_m: (M,) 1 sigma of the estimate's position [m] (e.g. along its covariance's longest axis,
                `SlotEstimates.sigma_max_m`); None: 0.
        """
        idx = self._slots(slots)
        m = len(idx)
        x = self._estimates(x_est, m)
        sigma = np.zeros(m) if position_sigma_m is None else np.asarray(position_sigma_m, dtype=float).reshape(-1)
        if len(scans_per_slot) != m or len(sigma) != m or not np.all(np.isfinite(sigma)):
            raise ValueError(f"integrate: {m} slots need as many scan tuples ({len(scans_per_slot)}) and finite "
                             f"position sigmas ({len(sigma)})")
        dirs, ranges, owner, newest, sizes, poses = [], [], [], [], [], []
        cap = self._points.shape[1]
        for k, taken in enumerate(scans_per_slot):
            for j, scan in enumerate(taken):
                if len(scan.ranges_m) > cap:
                    raise ValueError(f"a scan of {len(scan.ranges_m)} returns exceeds the lidar's {cap} beams")
                dirs.append(scan.directions_body)
                ranges.append(scan.ranges_m)
                owner.append(k)
                newest.append(j == len(taken) - 1)
                sizes.append(len(scan.ranges_m))
                poses.append(x[k, _POSE] if scan.pose_estimate is None else scan.pose_estimate)
        has_scan = np.zeros(m, dtype=bool)
        has_scan[owner] = True
        self._points[idx[has_scan]] = _FAR_M
        self._count[idx[has_scan]] = 0
        if not dirs:
            return
        rows = np.repeat(np.array(owner, dtype=np.intp), sizes)
        # each scan on the pose it was taken at, as the vehicle estimated it then (its stamp; else the estimate here)
        stamped = np.zeros((len(poses), 10))
        stamped[:, _POSE] = poses
        world = _place(np.concatenate(dirs), np.concatenate(ranges), np.repeat(np.arange(len(poses)), sizes), stamped)
        p = x[:, 0:3]
        ground = self.config.ground_band_m + self.config.ground_sigmas * sigma
        solid = np.flatnonzero(world[:, 2] > ground[rows])
        world, rows, fresh = world[solid], rows[solid], np.repeat(np.array(newest), sizes)[solid]
        # the newest scan's points, packed from each slot's first entry (a slot's points are contiguous, in order)
        kept_rows = rows[fresh]
        count = np.bincount(kept_rows, minlength=m)
        rank = np.arange(len(kept_rows)) - (np.cumsum(count) - count)[kept_rows]
        self._points[idx[kept_rows], rank] = world[fresh]
        self._count[idx[has_scan]] = count[has_scan]
        self._follow(idx[has_scan], p[has_scan])
        dx, dy = world[:, 0] - p[rows, 0], world[:, 1] - p[rows, 1]
        near = np.flatnonzero(dx * dx + dy * dy <= self.config.memory_range_m ** 2)
        self._remember(idx[rows[near]], world[near])

    def _follow(self, slots: np.ndarray, p: np.ndarray) -> None:
        """Centre the windows of `slots` (K,) on the cells of positions p (K, 3) [m], forgetting the cells that
        leave them."""
        g = self.window
        origin = np.floor(p[:, 0:2] / self.sensed_cell_m).astype(np.int64) - g // 2
        moved = np.flatnonzero(np.any(origin != self._origin[slots], axis=1))
        if not len(moved):
            return
        at = slots[moved]
        old, new = self._origin[at][:, :, None], origin[moved][:, :, None]
        r = np.arange(g)
        # ring entry r holds world cell o + (r - o) mod g under origin o: where that changes, the cell left
        gone = (r - old) % g + old != (r - new) % g + new  # (K, 2 (x, y), g)
        k, ry = np.nonzero(gone[:, 1])  # (a vehicle crossing a cell line clears one row or column)
        self._memory[at[k], ry, :] = 0
        k, rx = np.nonzero(gone[:, 0])
        self._memory[at[k], :, rx] = 0
        self._origin[at] = origin[moved]

    def _remember(self, slot: np.ndarray, world: np.ndarray) -> None:
        """Raise the memory cells of points (P, 3) [m, world] of slots (P,) to their heights."""
        g = self.window
        cell = np.floor(world[:, 0:2] / self.sensed_cell_m).astype(np.int64)
        org = self._origin[slot]
        at_x, at_y = (_ring(cell[:, i] - org[:, i], org[:, i] % g, g) for i in (0, 1))
        inside = np.flatnonzero((at_x < g) & (at_y < g))  # all of them, but for rounding
        flat = slot[inside] * (g + 1) ** 2 + at_y[inside] * (g + 1) + at_x[inside]
        steps = np.clip(np.ceil(world[inside, 2] / _STEP_M), 1, _TOP_STEPS).astype(np.uint16)
        np.maximum.at(self._memory.reshape(-1), flat, steps)

    def read(self, slots: Sequence[int] | np.ndarray, x_est: np.ndarray, heading_rad: np.ndarray) -> ObstacleSenses:
        """The obstacle senses of `slots` (M,) from their kept points and memories, at the estimates `x_est`
        (M, 3+) (position [m], world ENU) in goal frames at headings `heading_rad` (M,) [rad, CCW from east]."""
        idx = self._slots(slots)
        m = len(idx)
        p = self._estimates(x_est, m, columns=3)[:, 0:3]
        heading = np.asarray(heading_rad, dtype=float).reshape(-1)
        if len(heading) != m or not np.all(np.isfinite(heading)):
            raise ValueError(f"read: {m} slots need as many finite headings, got {len(heading)}")
        c, s = np.cos(heading), np.sin(heading)
        # the points past every read slot's own count are _FAR_M: left out, the same numbers at less cost
        pts = self._points[idx, :max(1, int(self._count[idx].max(initial=0)))]
        d = pts - p[:, None, :]
        dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
        h2 = dx * dx + dy * dy
        rays = self._rays(np.sqrt(h2), dx, dy, dz, c, s)
        clearance, nearest = self._nearest(h2 + dz * dz, d, p)
        roofs = np.maximum(self.prior.roofs(p, heading, self._prior_index[idx]), self._sensed_roofs(idx, p, c, s))
        return ObstacleSenses(PerceptionReading(rays, roofs), clearance, nearest)

    def _rays(self, horiz: np.ndarray, dx: np.ndarray, dy: np.ndarray, dz: np.ndarray, c: np.ndarray,
              s: np.ndarray) -> np.ndarray:
        """Rays (M, n_rays) [m] from the points' offsets (M, P) [m] and the goal frames' cos, sin (M,)."""
        n, rng, r = self.perception.n_rays, self.perception.ray_range_m, self.radius_m
        m = len(horiz)
        out = np.full(m * n, rng)
        row, col = np.nonzero((dz > -r) & (dz <= r + self.config.band_above_m) & (horiz < rng + r))
        if len(row):
            ux, uy, ch, sh = dx[row, col], dy[row, col], c[row], s[row]
            bearing = np.arctan2(ch * uy - sh * ux, ch * ux + sh * uy)  # in the goal frame, (-pi, pi]
            sector = np.floor(bearing * (n / (2.0 * math.pi)) + 0.5).astype(np.int64) % n
            np.minimum.at(out, row * n + sector, np.maximum(horiz[row, col] - r, 0.0))
        return out.reshape(m, n)

    def _nearest(self, d2: np.ndarray, d: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Clearance (M,) and nearest vector (M, 3) [m] from squared distances (M, P) and offsets (M, P, 3) of the
        points, at positions p (M, 3) [m] (`nearest_surface`'s rules, the ground at the estimated altitude)."""
        r, rng = self.radius_m, self.clearance_range_m
        rows = np.arange(len(d2))
        j = np.argmin(d2, axis=1)  # an empty point slot is _FAR_M away: never seen
        dist = np.sqrt(d2[rows, j]) - r
        seen = dist <= rng
        dist = np.where(seen, dist, rng)
        z = p[:, 2]
        clearance = np.minimum(dist, z - r)
        vec = np.where(seen[:, None], d[rows, j], 0.0)
        ground = z - r < dist  # (dist is at most the range: a nearer ground is within it)
        vec[ground] = 0.0
        vec[ground, 2] = -z[ground]
        return clearance, vec

    def _sensed_roofs(self, idx: np.ndarray, p: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
        """The memory's height maps (M, grid_cells**2) [m] at positions p (M, 3) [m] in goal frames cos, sin (M,)."""
        pc, cell, g, nl = self.perception, self.sensed_cell_m, self.window, self._n_look
        o = self._offsets_m
        m = len(p)
        # map cell centres (M, a, b): p + o_a (c, s) + o_b (-s, c), as `Perception` places them
        xc = (p[:, 0:1] + o * c[:, None])[:, :, None] - (o * s[:, None])[:, None, :]
        yc = (p[:, 1:2] + o * s[:, None])[:, :, None] + (o * c[:, None])[:, None, :]
        half = (0.5 * pc.cell_m * (np.abs(c) + np.abs(s)) - _TOL_M)[:, None, None]
        org = self._origin[idx][:, :, None, None]
        at_x = _ring(_touched(xc, half, cell, nl, org[:, 0]), org[:, 0] % g, g)  # (nl, M, a, b)
        at_y = _ring(_touched(yc, half, cell, nl, org[:, 1]), org[:, 1] % g, g)
        at_y *= g + 1
        at_y += (idx * (g + 1) ** 2)[:, None, None]
        steps = self._memory.reshape(-1).take(at_y[:, None] + at_x[None, :])  # (nl_y, nl_x, M, a, b)
        return steps.reshape(nl * nl, m * pc.grid_cells ** 2).max(axis=0).reshape(m, pc.grid_cells ** 2) * _STEP_M

    def columns(self, slot: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The height memory of `slot` as columns: world cell indices ix, iy (K,) (cell (ix, iy) spans
        [ix, ix + 1) x [iy, iy + 1) times `sensed_cell_m` [m], world ENU) and the highest return in each (K,) [m],
        for the cells its window holds that something was sensed in (row-major in the ring)."""
        g = self.window
        memory = self._memory[slot, :g, :g]
        ry, rx = np.nonzero(memory)
        ox, oy = (int(v) for v in self._origin[slot])
        # ring entry r holds world cell o + (r - o) mod g under origin o (`_follow`)
        return ox + (rx - ox) % g, oy + (ry - oy) % g, memory[ry, rx] * _STEP_M

    def _slots(self, slots: Sequence[int] | np.ndarray) -> np.ndarray:
        """Slot indices (M,) checked: distinct and in range."""
        idx = np.asarray(slots, dtype=np.intp).reshape(-1)
        if len(idx) and (idx.min() < 0 or idx.max() >= self.n or len(np.unique(idx)) != len(idx)):
            raise ValueError(f"slots must be distinct indices below {self.n}, got {idx.tolist()}")
        return idx

    @staticmethod
    def _estimates(x_est: np.ndarray, m: int, columns: int = 10) -> np.ndarray:
        """Estimates (M, columns+) checked: as many as slots, finite."""
        x = np.asarray(x_est, dtype=float)
        if x.ndim != 2 or len(x) != m or x.shape[1] < columns or not np.all(np.isfinite(x[:, 0:columns])):
            raise ValueError(f"need {m} finite estimates of at least {columns} elements, got shape {x.shape}")
        return x


def _place(directions_body: np.ndarray, ranges_m: np.ndarray, rows: np.ndarray, x: np.ndarray) -> np.ndarray:
    """World points (P, 3) [m] of returns (body FLU unit directions (P, 3), ranges (P,) [m]) of estimates x (M, 10+)
    (row (P,) of each): p + R(q) d rho, element by element (a stacked matrix product might sum in another order)."""
    q = x[:, 6:10]
    q = q / np.sqrt(q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1] + q[:, 2] * q[:, 2] + q[:, 3] * q[:, 3])[:, None]
    pose = np.concatenate([rotation_matrices(q).reshape(-1, 9), x[:, 0:3]], axis=1).T.take(rows, axis=1)  # (12, P)
    b = (directions_body * ranges_m[:, None]).T
    bx, by, bz = b[0], b[1], b[2]
    return np.stack([pose[9 + i] + (pose[3 * i] * bx + pose[3 * i + 1] * by + pose[3 * i + 2] * bz)
                     for i in range(3)], axis=1)


def _ring(rel: np.ndarray, shift: np.ndarray, g: int) -> np.ndarray:
    """Ring positions of cells at offsets `rel` (int64) from their window's origin, whose own ring position is
    `shift` (broadcast; the origin's index mod g): the cell's index mod g; g (the zero row or column) outside."""
    pos = rel + shift  # (an integer modulo per element costs more than this)
    np.subtract(pos, g, out=pos, where=pos >= g)
    pos[rel.view(np.uint64) >= g] = g  # negative offsets wrap to huge unsigned ones
    return pos


def _touched(centre_m: np.ndarray, half_m: np.ndarray, cell_m: float, n: int, origin: np.ndarray) -> np.ndarray:
    """Offsets (n, ...) from `origin` (broadcast) of the world cells along one axis that [centre - half,
    centre + half] [m] touches, from the first; past the last touched the last repeats (a max is unchanged)."""
    first = np.floor((centre_m - half_m) / cell_m).astype(np.int64) - origin
    last = np.floor((centre_m + half_m) / cell_m).astype(np.int64) - origin
    out = np.empty((n,) + first.shape, dtype=np.int64)
    for t in range(n):
        np.minimum(first + t, last, out=out[t])
    return out
