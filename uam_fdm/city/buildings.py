"""The city: buildings as vertical prisms, the ground, the flight volume; clearance through FCL.

One geometry serves collision, clearance, the RL observation, the planner's validity checks and the
plots.  Frames: world ENU (x east, y north, z up), metres; the ground is the plane z = 0.  A
building's yaw turns its footprint (width along x at yaw 0) counter-clockwise about +z.

Three exact evaluation paths share the geometry (see docs/city.md):
  * FCL (python-fcl, a DynamicAABBTreeCollisionManager of Box / Convex primitives): segment checks
    (an exact swept-sphere test) and the per-point reference `clearance(..., backend="fcl")`.
    Points are queried as zero-radius spheres and the radius subtracted afterwards: FCL's signed
    sphere-box distance for r > 0 goes through GJK/EPA and was off by up to 1.7e-3 m here, while the
    point query is exact to 1e-14 (for Box and Convex alike).
  * NumPy (`uam_fdm.city.distance`): batches of points, the default for `clearance`.
  * A per-cell candidate index in plain Python: `clearance_one`, for OMPL validity callbacks.
"""
from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import fcl
import numpy as np
from numpy.typing import ArrayLike

from uam_fdm.city import distance as clearance_np

logger = logging.getLogger(__name__)

_TINY = 1e-300  # a positive pruning distance that still visits every bounding box touching the query


@dataclass(frozen=True)
class Building:
    """A box building standing on the ground (or, in `BuildingMap.planning_map`, a no-fly box above it).

    Attributes:
        id: building id (parts of one decomposed footprint share it).
        center_xy_m: footprint centre (x, y), ENU metres.
        size_xy_m: footprint size (width along the building's x axis, depth along its y axis) [m].
        height_m: roof height above the ground [m].
        yaw_rad: footprint rotation, counter-clockwise about +z [rad].
        base_m: bottom of the box above the ground [m]: 0 for buildings; a no-fly volume that starts
            above the ground has its own.
    """

    id: int
    center_xy_m: tuple[float, float]
    size_xy_m: tuple[float, float]
    height_m: float
    yaw_rad: float = 0.0
    base_m: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "id", int(self.id))
        object.__setattr__(self, "center_xy_m", _pair(self.center_xy_m, "center_xy_m"))
        object.__setattr__(self, "size_xy_m", _pair(self.size_xy_m, "size_xy_m"))
        object.__setattr__(self, "height_m", float(self.height_m))
        object.__setattr__(self, "yaw_rad", float(self.yaw_rad))
        if min(self.size_xy_m) <= 0.0 or not self.height_m > 0.0 or not math.isfinite(self.height_m):
            raise ValueError(f"building {self.id}: sizes and height must be positive and finite: {self}")
        if not math.isfinite(self.yaw_rad):
            raise ValueError(f"building {self.id}: yaw must be finite")
        object.__setattr__(self, "base_m", float(self.base_m))
        if not 0.0 <= self.base_m < self.height_m:
            raise ValueError(f"building {self.id}: base must be in [0, height), got {self.base_m}")

    def footprint_xy_m(self) -> np.ndarray:
        """Footprint corners, counter-clockwise: (4, 2), ENU metres."""
        hx, hy = 0.5 * self.size_xy_m[0], 0.5 * self.size_xy_m[1]
        local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return local @ np.array([[c, s], [-s, c]]) + np.asarray(self.center_xy_m)


@dataclass(frozen=True)
class Prism:
    """A convex vertical prism standing on the ground: one convex part of a non-box footprint.

    Attributes:
        id: the parent footprint's building id (shared by all its parts).
        vertices_xy_m: convex footprint, counter-clockwise, ENU metres (at least 3 vertices).
        height_m: roof height above the ground [m].
    """

    id: int
    vertices_xy_m: tuple[tuple[float, float], ...]
    height_m: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "id", int(self.id))
        verts = tuple(_pair(v, "vertices_xy_m") for v in self.vertices_xy_m)
        object.__setattr__(self, "vertices_xy_m", verts)
        object.__setattr__(self, "height_m", float(self.height_m))
        if not self.height_m > 0.0 or not math.isfinite(self.height_m):
            raise ValueError(f"prism of building {self.id}: height must be positive and finite")
        v = np.asarray(verts)
        if len(v) < 3:
            raise ValueError(f"prism of building {self.id}: needs at least 3 vertices")
        e = np.roll(v, -1, axis=0) - v
        cross = e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0]
        scale = float(np.max(np.abs(v - v.mean(axis=0)))) ** 2
        if np.any(cross < -1e-12 * scale) or np.sum(cross) <= 0.0:
            raise ValueError(f"prism of building {self.id}: footprint must be convex and counter-clockwise")

    def footprint_xy_m(self) -> np.ndarray:
        """Footprint vertices, counter-clockwise: (K, 2), ENU metres."""
        return np.asarray(self.vertices_xy_m, dtype=float)

    @property
    def center_xy_m(self) -> tuple[float, float]:
        """Area centroid of the footprint, ENU metres."""
        v = self.footprint_xy_m()
        w = np.roll(v, -1, axis=0)
        cross = v[:, 0] * w[:, 1] - w[:, 0] * v[:, 1]
        c = ((v + w) * cross[:, None]).sum(axis=0) / (3.0 * cross.sum())
        return float(c[0]), float(c[1])


Obstacle = Building | Prism


@dataclass(frozen=True)
class NoFlyZone:
    """A no-fly volume: a yawed box over a height range.  Airspace, not an obstacle for clearance.

    Attributes:
        center_xy_m: footprint centre, ENU metres.
        size_xy_m: footprint size along the zone's own x and y axes [m].
        z_range_m: (bottom, top) above the ground [m].
        yaw_rad: rotation counter-clockwise about +z [rad].
    """

    center_xy_m: tuple[float, float]
    size_xy_m: tuple[float, float]
    z_range_m: tuple[float, float]
    yaw_rad: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "center_xy_m", _pair(self.center_xy_m, "center_xy_m"))
        object.__setattr__(self, "size_xy_m", _pair(self.size_xy_m, "size_xy_m"))
        object.__setattr__(self, "z_range_m", _pair(self.z_range_m, "z_range_m"))
        object.__setattr__(self, "yaw_rad", float(self.yaw_rad))
        if min(self.size_xy_m) <= 0.0 or not self.z_range_m[1] > self.z_range_m[0]:
            raise ValueError(f"no-fly zone: sizes must be positive and z_range increasing: {self}")

    def footprint_xy_m(self) -> np.ndarray:
        """Footprint corners, counter-clockwise: (4, 2), ENU metres."""
        return Building(0, self.center_xy_m, self.size_xy_m, 1.0, self.yaw_rad).footprint_xy_m()


@dataclass(frozen=True)
class Clearance:
    """Clearance of spheres from the city.

    Attributes:
        distance_m: (N,) signed distance from each sphere to the nearest building or the ground [m];
            negative when penetrating.
        building_id: (N,) id of that nearest building, -1 for the ground.
        nearest_point_m: (N, 3) the obstacle's surface point nearest to the sphere centre, ENU metres.
    """

    distance_m: np.ndarray
    building_id: np.ndarray
    nearest_point_m: np.ndarray


class _Query:
    """Per-query FCL state: a fresh DistanceResult each time (a reused one keeps stale minima)."""

    __slots__ = ("bound", "request", "result", "stop_at")

    def __init__(self, request: fcl.DistanceRequest, bound: float, stop_at: float) -> None:
        self.request = request
        self.result = fcl.DistanceResult()
        self.bound = bound
        self.stop_at = stop_at


def _distance_callback(o1: fcl.CollisionObject, o2: fcl.CollisionObject, q: _Query) -> tuple[bool, float]:
    """Broadphase callback: exact pair distance, keep the minimum, prune by `q.bound`.

    Unlike fcl.defaultDistanceCallback it does not stop at the first penetration (the deepest one is
    wanted), and it prunes with min(best, bound): no obstacle farther than the ground can be nearest.
    """
    fcl.distance(o1, o2, q.request, q.result)
    m = q.result.min_distance
    if m <= q.stop_at:
        return True, m
    bound = m if m < q.bound else q.bound
    return False, bound if bound > 0.0 else _TINY


class BuildingMap:
    """Buildings (boxes and convex prisms), the ground plane z = 0 and the flight-volume bounds.

    Immutable after construction.  Pickles as plain data; FCL objects are rebuilt on unpickling.
    """

    def __init__(
        self,
        buildings: Sequence[Obstacle],
        bounds_min_m: ArrayLike,
        bounds_max_m: ArrayLike,
        no_fly: Sequence[NoFlyZone] = (),
        name: str = "",
    ) -> None:
        """Build the map and its FCL broadphase.

        Args:
            buildings: obstacle parts (Building boxes and/or convex Prism parts), each standing on
                the ground; footprints must lie inside the bounds in x and y.
            bounds_min_m: (3,) lower corner of the flight volume, ENU metres (z >= 0).
            bounds_max_m: (3,) upper corner, ENU metres.  Buildings may be taller than its top.
            no_fly: no-fly volumes (not obstacles: see `in_no_fly`).
            name: a label for logs and plots.

        Raises:
            ValueError: on inconsistent bounds or a footprint outside them.
        """
        self._init(tuple(buildings), bounds_min_m, bounds_max_m, tuple(no_fly), str(name))

    def _init(self, parts: tuple[Obstacle, ...], lo: ArrayLike, hi: ArrayLike,
              no_fly: tuple[NoFlyZone, ...], name: str, footprints_inside: bool = True) -> None:
        lo_a = np.array(lo, dtype=float).reshape(3)
        hi_a = np.array(hi, dtype=float).reshape(3)
        if not (np.all(np.isfinite(lo_a)) and np.all(np.isfinite(hi_a)) and np.all(hi_a > lo_a)):
            raise ValueError(f"bounds must be finite with max > min, got {lo_a} .. {hi_a}")
        if lo_a[2] < 0.0:
            raise ValueError(f"bounds min z must be >= 0 (the ground is z = 0), got {lo_a[2]}")
        for p in parts:
            if not isinstance(p, (Building, Prism)):
                raise TypeError(f"buildings must be Building or Prism, got {type(p).__name__}")
            fp = p.footprint_xy_m()
            tol = 1e-9 * (1.0 + float(np.max(np.abs(hi_a[:2]))))
            if footprints_inside and (np.any(fp < lo_a[:2] - tol) or np.any(fp > hi_a[:2] + tol)):
                raise ValueError(f"building {p.id}: footprint leaves the bounds in x/y")
        lo_a.setflags(write=False)
        hi_a.setflags(write=False)
        self._parts, self._lo, self._hi, self._no_fly, self._name = parts, lo_a, hi_a, no_fly, name
        self._footprints_inside = footprints_inside
        self._planning: BuildingMap | None = None
        self._part_ids = np.array([p.id for p in parts], dtype=np.int64)
        self._ids = np.unique(self._part_ids)
        self._packed = pack_parts(parts)
        self._packed_no_fly = clearance_np.pack(
            [(*z.center_xy_m, z.yaw_rad, *z.size_xy_m, *z.z_range_m) for z in no_fly], [],
            list(range(len(no_fly))), [])
        z_top = max([float(hi_a[2])] + [p.height_m for p in parts]) * 1.05 + 1.0
        extent = float(np.max(hi_a[:2] - lo_a[:2]))
        self._index = clearance_np.CellIndex(
            self._packed, [p.footprint_xy_m() for p in parts], lo_a[:2], hi_a[:2], z_top,
            cell_m=min(max(extent / 48.0, 5.0), 100.0))
        self._build_fcl()
        logger.debug("BuildingMap %r: %d parts, %d buildings", name, len(parts), len(self._ids))

    def _build_fcl(self) -> None:
        self._geom_part: dict[int, int] = {}  # id(FCL geometry) -> part index, to name the nearest part
        objects = []
        for i, p in enumerate(self._parts):
            geom, obj = _fcl_object(p)
            self._geom_part[id(geom)] = i
            objects.append((geom, obj))
        self._fcl_objects = objects  # keeps the geometries alive (FCL holds raw pointers to them)
        self._manager = fcl.DynamicAABBTreeCollisionManager()
        if objects:
            self._manager.registerObjects([obj for _, obj in objects])
        self._manager.setup()
        self._point_geom = fcl.Sphere(0.0)  # a point: exact signed distances (see the module docstring)
        self._point_obj = fcl.CollisionObject(self._point_geom, fcl.Transform())
        self._request = fcl.DistanceRequest(enable_nearest_points=True, enable_signed_distance=True)

    # ---- pickling: plain data out, FCL rebuilt in -------------------------------------------------
    def __getstate__(self) -> dict[str, Any]:
        return {"buildings": self._parts, "bounds_min_m": self._lo.tolist(), "bounds_max_m": self._hi.tolist(),
                "no_fly": self._no_fly, "name": self._name, "footprints_inside": self._footprints_inside}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self._init(tuple(state["buildings"]), state["bounds_min_m"], state["bounds_max_m"],
                   tuple(state["no_fly"]), state["name"], state.get("footprints_inside", True))

    def planning_map(self) -> BuildingMap:
        """This map with its no-fly volumes as obstacles, for planning (itself when it has none).

        A planner or a tracker that keeps its clearance margin from this map's obstacles keeps it from
        the no-fly volumes too (their boxes, at their own height range); the comparison's clearance
        metric stays on the buildings and the ground. Built once, then cached.
        """
        if not self._no_fly:
            return self
        if self._planning is None:
            first = int(self._ids.max()) + 1 if len(self._ids) else 0
            zones = tuple(Building(first + k, z.center_xy_m, z.size_xy_m, z.z_range_m[1], z.yaw_rad,
                                   base_m=z.z_range_m[0]) for k, z in enumerate(self._no_fly))
            planning = BuildingMap.__new__(BuildingMap)
            # a zone may reach beyond the flight volume: that part of it is never flown anyway
            planning._init(self._parts + zones, self._lo, self._hi, (), self._name, footprints_inside=False)
            self._planning = planning
        return self._planning

    def __repr__(self) -> str:
        return (f"BuildingMap(name={self._name!r}, buildings={len(self._ids)}, parts={len(self._parts)}, "
                f"bounds={self._lo.tolist()}..{self._hi.tolist()})")

    # ---- data ---------------------------------------------------------------------------------------
    @property
    def name(self) -> str:
        """Label of the map (e.g. the shipped map's name)."""
        return self._name

    @property
    def buildings(self) -> tuple[Obstacle, ...]:
        """All obstacle parts (a decomposed footprint contributes several parts with one id)."""
        return self._parts

    @property
    def building_ids(self) -> np.ndarray:
        """Sorted distinct building ids: (n_buildings,)."""
        return self._ids

    @property
    def bounds_min_m(self) -> np.ndarray:
        """(3,) lower corner of the flight volume, ENU metres (read-only)."""
        return self._lo

    @property
    def bounds_max_m(self) -> np.ndarray:
        """(3,) upper corner of the flight volume, ENU metres (read-only)."""
        return self._hi

    @property
    def no_fly(self) -> tuple[NoFlyZone, ...]:
        """No-fly volumes."""
        return self._no_fly

    # ---- clearance ----------------------------------------------------------------------------------
    def clearance(self, points_m: np.ndarray, radius_m: float = 0.0,
                  backend: Literal["numpy", "fcl"] = "numpy") -> Clearance:
        """Signed distance from spheres to the nearest building or the ground.

        Args:
            points_m: (N, 3) sphere centres, ENU metres.
            radius_m: sphere radius [m] (>= 0).
            backend: "numpy" (exact, vectorised; the default) or "fcl" (one FCL query per point;
                the reference, slower).  They agree to ~1e-12 m.

        Returns:
            Clearance with distance (point distance minus radius; the ground's is z - radius),
            nearest building id (-1 = ground; ties go to the ground) and nearest obstacle point.
        """
        p = _as_points(points_m)
        r = _radius(radius_m)
        if backend == "numpy":
            d_pt, part = clearance_np.nearest_parts(p, self._packed)
            use_b = d_pt < p[:, 2]
            near = np.column_stack([p[:, 0], p[:, 1], np.zeros(len(p))])
            if np.any(use_b):
                near[use_b] = clearance_np.nearest_points_on_parts(p[use_b], part[use_b], self._packed)
        elif backend == "fcl":
            d_pt = np.full(len(p), np.inf)
            part = np.full(len(p), -1, dtype=np.int64)
            near = np.column_stack([p[:, 0], p[:, 1], np.zeros(len(p))])
            for i, (x, y, z) in enumerate(p.tolist()):
                d, j, pt = self._fcl_point(x, y, z)
                d_pt[i], part[i] = d, j
                if j >= 0 and d < z:
                    near[i] = pt
            use_b = d_pt < p[:, 2]
        else:
            raise ValueError(f"backend must be 'numpy' or 'fcl', got {backend!r}")
        dist = np.where(use_b, d_pt, p[:, 2]) - r
        bid = np.where(use_b, self._part_ids[np.maximum(part, 0)] if len(self._parts) else -1, -1)
        return Clearance(_frozen(dist), _frozen(bid.astype(np.int64)), _frozen(near))

    def obstacle_clearance_m(self, points_m: np.ndarray, radius_m: float = 0.0) -> np.ndarray:
        """Signed distance from spheres to the nearest obstacle, the ground left out [m] (N,): the clearance to one
        kind of obstacle (e.g. those a prior map lacks); +inf for a map without obstacles."""
        p = _as_points(points_m)
        if not self._parts:
            return np.full(len(p), np.inf)
        return clearance_np.nearest_parts(p, self._packed)[0] - _radius(radius_m)

    def surface_height_m(self, points_m: np.ndarray) -> np.ndarray:
        """Height of the surface directly below each point [m]: the highest roof at or below the point
        whose footprint holds its (x, y), else the ground (0). Points (N, 3), ENU metres -> (N,)."""
        return clearance_np.surface_below(_as_points(points_m), self._packed)

    def clearance_one(self, x: float, y: float, z: float, radius_m: float = 0.0) -> float:
        """Signed clearance of one sphere: the fast scalar path (OMPL validity callbacks).

        Args:
            x, y, z: sphere centre, ENU metres.
            radius_m: sphere radius [m].

        Returns:
            Signed distance [m] to the nearest building or the ground, minus the radius; equal to
            `clearance(...).distance_m` to ~1e-12 m.
        """
        d = self._index.query(x, y, z)
        if d is None:  # outside the indexed volume: ask FCL
            d = min(self._fcl_point(x, y, z)[0], z)
        return d - radius_m

    def is_free(self, points_m: np.ndarray, radius_m: float = 0.0) -> np.ndarray:
        """Whether spheres are clear of buildings and the ground (clearance > 0): (N,) bool."""
        p = _as_points(points_m)
        d_pt, _ = clearance_np.nearest_parts(p, self._packed)
        return np.minimum(d_pt, p[:, 2]) > _radius(radius_m)

    def is_free_one(self, x: float, y: float, z: float, radius_m: float = 0.0) -> bool:
        """Whether one sphere (centre ENU metres, radius metres) is clear: clearance_one(...) > 0."""
        return self.clearance_one(x, y, z, radius_m) > 0.0

    def segment_free(self, a_m: Sequence[float] | np.ndarray, b_m: Sequence[float] | np.ndarray,
                     radius_m: float = 0.0) -> bool:
        """Whether a sphere moving straight from a to b stays clear of buildings and the ground.

        Exact, no sampling, so no tunnelling through thin walls: the swept sphere is the capsule of
        the segment, which is free iff the segment's distance to every obstacle exceeds the radius.
        First a proof of freedom from the endpoint clearances (the distance field is 1-Lipschitz, so
        along a segment of length L it stays above (d_a + d_b - L) / 2); otherwise FCL's exact
        distance from a zero-radius capsule (the segment) to the buildings decides.

        Args:
            a_m: (3,) start centre, ENU metres.
            b_m: (3,) end centre, ENU metres.
            radius_m: sphere radius [m].

        Returns:
            True when the distance stays > 0 all along (touching counts as a collision).
        """
        ax, ay, az = (float(v) for v in a_m)
        bx, by, bz = (float(v) for v in b_m)
        r = float(radius_m)
        length = math.sqrt((bx - ax) ** 2 + (by - ay) ** 2 + (bz - az) ** 2)
        da = self.clearance_one(ax, ay, az, r)
        if da <= 0.0:
            return False
        db = self.clearance_one(bx, by, bz, r)
        if db <= 0.0:
            return False
        if da + db > length:
            return True
        # The ground needs no test here: a plane's nearest segment point is an endpoint, both clear.
        if not self._parts:
            return True
        obj = _segment_object(np.array((ax, ay, az)), np.array((bx, by, bz)), length)
        bound = r + 1e-12 * (1.0 + r)
        q = _Query(self._request, bound, stop_at=r)
        self._manager.distance(obj, q, _distance_callback)
        return q.result.min_distance > r

    def in_bounds(self, points_m: np.ndarray, radius_m: float = 0.0) -> np.ndarray:
        """Whether spheres lie inside the flight volume (bounds inclusive): (N,) bool.

        Args:
            points_m: (N, 3) centres, ENU metres.
            radius_m: sphere radius [m]; the whole sphere must be inside.
        """
        p = _as_points(points_m)
        r = _radius(radius_m)
        return np.all((p >= self._lo + r) & (p <= self._hi - r), axis=1)

    def in_no_fly(self, points_m: np.ndarray, radius_m: float = 0.0) -> np.ndarray:
        """Whether spheres overlap (or touch) a no-fly volume: (N,) bool.

        Args:
            points_m: (N, 3) centres, ENU metres.
            radius_m: sphere radius [m].
        """
        p = _as_points(points_m)
        if not self._no_fly:
            return np.zeros(len(p), dtype=bool)
        d, _ = clearance_np.nearest_parts(p, self._packed_no_fly)
        return d <= _radius(radius_m)

    def nearest_obstacles(self, point_m: Sequence[float], k: int, radius_m: float = 0.0,
                          pad_distance_m: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
        """The k nearest distinct buildings to one sphere (the ground excluded): for observations.

        Args:
            point_m: (3,) sphere centre, ENU metres.
            k: how many buildings.
            radius_m: sphere radius [m], subtracted from the distances.
            pad_distance_m: distance reported for padding rows when the map has fewer than k
                buildings; their nearest point is the query point itself.

        Returns:
            nearest points (k, 3) ENU metres and signed distances (k,) [m], sorted by distance
            (ties by building id), padding last.
        """
        pts, dist, _ = self.nearest_obstacles_batch(np.asarray(point_m, dtype=float).reshape(1, 3), k,
                                                    radius_m, pad_distance_m)
        return pts[0], dist[0]

    def nearest_obstacles_batch(self, points_m: np.ndarray, k: int, radius_m: float = 0.0,
                                pad_distance_m: float = math.inf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`nearest_obstacles` for a batch of points.

        Args:
            points_m: (N, 3) sphere centres, ENU metres.
            k: how many buildings per point.
            radius_m: sphere radius [m].
            pad_distance_m: distance for padding rows (see `nearest_obstacles`).

        Returns:
            nearest points (N, k, 3), distances (N, k) [m] and building ids (N, k) (-1 = padding).
        """
        p = _as_points(points_m)
        k = int(k)
        if k < 0:
            raise ValueError(f"k must be >= 0, got {k}")
        n, nb = len(p), len(self._ids)
        pts = np.repeat(p[:, None, :], k, axis=1)
        dist = np.full((n, k), float(pad_distance_m))
        ids = np.full((n, k), -1, dtype=np.int64)
        kk = min(k, nb)
        if kk > 0 and n > 0:
            near, d, order = clearance_np.k_nearest_groups(p, self._packed, self._part_ids, self._ids, kk)
            pts[:, :kk], dist[:, :kk], ids[:, :kk] = near, d - _radius(radius_m), self._ids[order]
        return pts, dist, ids

    # ---- FCL internals --------------------------------------------------------------------------------
    def _fcl_point(self, x: float, y: float, z: float) -> tuple[float, int, np.ndarray | None]:
        """Exact signed point distance to the nearest part by FCL: (distance, part or -1, nearest point)."""
        if not self._parts:
            return math.inf, -1, None
        self._point_obj.setTranslation(np.array((x, y, z)))
        q = _Query(self._request, bound=z, stop_at=-math.inf)
        self._manager.distance(self._point_obj, q, _distance_callback)
        res = q.result
        if res.o1 is None:  # pruned by the ground bound before any building was measured
            return math.inf, -1, None
        first = res.o1 is not self._point_geom
        geom = res.o1 if first else res.o2
        return res.min_distance, self._geom_part[id(geom)], np.asarray(res.nearest_points[0 if first else 1])


def _pair(v: Any, name: str) -> tuple[float, float]:
    a, b = (float(x) for x in v)
    if not (math.isfinite(a) and math.isfinite(b)):
        raise ValueError(f"{name} must be finite, got {v}")
    return a, b


def _as_points(points_m: np.ndarray) -> np.ndarray:
    p = np.asarray(points_m, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must be an (N, 3) array, got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("points must be finite")
    return p


def _radius(radius_m: float) -> float:
    r = float(radius_m)
    if not (r >= 0.0 and math.isfinite(r)):
        raise ValueError(f"radius must be finite and >= 0, got {radius_m}")
    return r


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def pack_parts(parts: Sequence[Obstacle]) -> clearance_np.PackedPrisms:
    """Obstacle parts packed for the NumPy distance kernel (its row i is parts[i])."""
    boxes, box_part, polys, poly_part = [], [], [], []
    for i, p in enumerate(parts):
        if isinstance(p, Building):
            boxes.append((*p.center_xy_m, p.yaw_rad, *p.size_xy_m, p.base_m, p.height_m))
            box_part.append(i)
        else:
            polys.append((p.footprint_xy_m(), 0.0, p.height_m))
            poly_part.append(i)
    return clearance_np.pack(boxes, polys, box_part, poly_part)


def _rot_z(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _fcl_object(p: Obstacle) -> tuple[fcl.CollisionGeometry, fcl.CollisionObject]:
    """An FCL primitive for one part: Box (analytic) or Convex (a prism with K side faces)."""
    if isinstance(p, Building):
        geom = fcl.Box(p.size_xy_m[0], p.size_xy_m[1], p.height_m - p.base_m)
        tf = fcl.Transform(_rot_z(p.yaw_rad), np.array([*p.center_xy_m, 0.5 * (p.base_m + p.height_m)]))
        return geom, fcl.CollisionObject(geom, tf)
    v = p.footprint_xy_m()
    k = len(v)
    verts = np.vstack([np.column_stack([v, np.zeros(k)]), np.column_stack([v, np.full(k, p.height_m)])])
    faces = [k, *range(k - 1, -1, -1), k, *range(k, 2 * k)]  # bottom (seen from below), top
    for i in range(k):
        j = (i + 1) % k
        faces += [4, i, j, k + j, k + i]  # sides, counter-clockwise seen from outside
    geom = fcl.Convex(verts, k + 2, np.array(faces))
    return geom, fcl.CollisionObject(geom, fcl.Transform())


def _segment_object(a: np.ndarray, b: np.ndarray, length: float) -> fcl.CollisionObject:
    """A zero-radius FCL capsule along the segment a-b (its axis is the capsule's local z).

    The rotation taking local z to the unit direction d is the quaternion (1 + d_z, -d_y, d_x, 0), normalised, in
    plain floats: the planner's motion checks build one capsule each, and NumPy's cross products on 3-vectors
    cost half of the whole check (profiled). A capsule is symmetric end to end, so d is taken with d_z >= 0,
    where that quaternion never degenerates."""
    dx, dy, dz = (float(b[0] - a[0]) / length, float(b[1] - a[1]) / length, float(b[2] - a[2]) / length)
    if dz < 0.0:
        dx, dy, dz = -dx, -dy, -dz
    w = 1.0 + dz
    n = math.sqrt(w * w + dx * dx + dy * dy)
    centre = np.array([0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]), 0.5 * (a[2] + b[2])])
    return fcl.CollisionObject(fcl.Capsule(0.0, length), fcl.Transform(np.array([w / n, -dy / n, dx / n, 0.0]),
                                                                       centre))
