"""Exact ray casting against the true city with Embree (through `embreex`): lidar beams, satellite lines of sight.

The city's parts become one static triangle mesh, built once per city: a `Building` box is 8 vertices and 12
triangles (10 when it stands on the ground: its bottom lies on the ground plane), a convex `Prism` with K
footprint vertices 2K side triangles and K - 2 roof triangles; the ground (z = 0) is one quad reaching
`ground_margin_m` beyond the flight volume. Faces are shared-vertex and the scene is built with Embree's
robust flag, so a ray through an edge between two triangles is not lost.

Embree works in float32. The mesh and the rays are shifted to a local origin at the centre of the flight volume
before the cast (in float64), so coordinates stay below ~1 km (float32's step there: 6e-5 m). A hit then lies
within ~1e-5 m of the surface and a range within ~1e-4 m of the exact one; along a ray grazing a face at an
angle α the range error is the former over sin α (1e-3 m at 1°, 4e-3 m at 0.1°). Tested against an analytic slab
test. `ranges_m(..., exact=True)` recomputes each hit's range in float64 on the hit triangle's plane (~1e-12 m
except where a ray grazes a face or runs through an edge), for ~1 ms more per 28,800 rays; a lidar's
centimetres of range noise do not need it.
"""
from __future__ import annotations

import functools
import logging
import math
from typing import Any

import numpy as np
from embreex import rtcore_scene as rtcs
from embreex.mesh_construction import TriangleMesh

from uam_fdm.city.buildings import Building, BuildingMap, Prism

logger = logging.getLogger(__name__)


def part_mesh(part: Building | Prism) -> tuple[np.ndarray, np.ndarray]:
    """One part as a closed triangle mesh.

    Args:
        part: a box (yawed, from `base_m` to `height_m`) or a convex prism (from the ground to `height_m`).

    Returns:
        vertices (2K, 3) ENU metres (bottom ring, then top ring) and triangles (T, 3) vertex indices, faces
        counter-clockwise seen from outside. The bottom face is left out when the part stands on the ground.
    """
    foot = part.footprint_xy_m()
    base = part.base_m if isinstance(part, Building) else 0.0
    k = len(foot)
    verts = np.vstack([np.column_stack([foot, np.full(k, base)]), np.column_stack([foot, np.full(k, part.height_m)])])
    i = np.arange(k)
    j = (i + 1) % k
    tris = [np.column_stack([i, j, k + j]), np.column_stack([i, k + j, k + i])]  # sides
    fan = np.arange(1, k - 1)
    tris.append(np.column_stack([np.full(k - 2, k), k + fan, k + fan + 1]))  # roof, seen from above
    if base > 0.0:  # an elevated box (a crane jib, a bridge): rays from below must hit its underside
        tris.append(np.column_stack([np.zeros(k - 2, dtype=int), fan + 1, fan]))
    return verts, np.vstack(tris)


@functools.lru_cache(maxsize=16384)
def _shared_part_mesh(part: Building | Prism) -> tuple[np.ndarray, np.ndarray]:
    """`part_mesh`, read-only and kept for equal parts: a pilot's fused map changes by a few sensed columns between
    scans, and its line-of-sight caster is rebuilt from every part each time."""
    verts, tris = part_mesh(part)
    verts.setflags(write=False)
    tris.setflags(write=False)
    return verts, tris


def city_mesh(city: BuildingMap, *, ground: bool = True, ground_margin_m: float = 2000.0
              ) -> tuple[np.ndarray, np.ndarray]:
    """All of a city's parts (and the ground) as one triangle mesh: vertices (V, 3) ENU metres, triangles (T, 3)."""
    verts, tris, _ = _city_mesh_parts(city, ground, ground_margin_m)
    return verts, tris


def _city_mesh_parts(city: BuildingMap, ground: bool, ground_margin_m: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`city_mesh` and, per triangle, the index of its part in `city.buildings` (-1: the ground)."""
    verts: list[np.ndarray] = []
    tris: list[np.ndarray] = []
    owner: list[np.ndarray] = []
    n = 0
    for i, part in enumerate(city.buildings):
        v, t = _shared_part_mesh(part)
        verts.append(v)
        tris.append(t + n)
        owner.append(np.full(len(t), i, dtype=np.int64))
        n += len(v)
    if ground:
        lo = city.bounds_min_m[:2] - ground_margin_m
        hi = city.bounds_max_m[:2] + ground_margin_m
        verts.append(np.array([[lo[0], lo[1], 0.0], [hi[0], lo[1], 0.0], [hi[0], hi[1], 0.0], [lo[0], hi[1], 0.0]]))
        tris.append(np.array([[0, 1, 2], [0, 2, 3]]) + n)
        owner.append(np.full(2, -1, dtype=np.int64))
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64)
    return np.vstack(verts), np.vstack(tris), np.concatenate(owner)


class RayCaster:
    """First hits of rays on a city's true buildings and the ground (Embree, one core).

    Args:
        city: the true city (all its parts: yawed boxes with `base_m`, convex prisms).
        ground: include the ground plane z = 0.
        ground_margin_m: how far the ground reaches beyond the flight volume in x and y [m] (longer than any
            lidar range, so a beam from inside the volume never runs off its edge).
    """

    def __init__(self, city: BuildingMap, *, ground: bool = True, ground_margin_m: float = 2000.0) -> None:
        self._args = (city, ground, ground_margin_m)
        verts, tris, self._tri_part = _city_mesh_parts(city, ground, ground_margin_m)
        # float32 loses ~1e-4 m at 1 km: cast around the centre of the volume, not around the map's corner
        self._offset = 0.5 * (np.asarray(city.bounds_min_m, float) + np.asarray(city.bounds_max_m, float))
        self._offset[2] = 0.0  # keep the ground exactly at z = 0 in the local frame too
        self.n_triangles = len(tris)
        # each triangle's plane in float64 (unit normal n, n . v0 in the local frame), for `ranges_m(exact=True)`
        local = verts - self._offset
        self._normal, self._plane = np.zeros((0, 3)), np.zeros(0)
        if len(tris):
            nrm = np.cross(local[tris[:, 1]] - local[tris[:, 0]], local[tris[:, 2]] - local[tris[:, 0]])
            nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
            self._normal, self._plane = nrm, np.einsum("ij,ij->i", nrm, local[tris[:, 0]])
        self._normal_xyz = tuple(np.ascontiguousarray(self._normal[:, i]) for i in range(3))
        # Embree's fast (not "robust") traversal: on the shipped cities it agrees with an exact slab test on every
        # hit and miss of 300,000 lidar rays (perf/lidar.py) and casts 20 % faster
        self._scene = rtcs.EmbreeScene(robust=False)
        self._mesh = None
        if len(tris):
            self._mesh = TriangleMesh(self._scene, np.ascontiguousarray(local, dtype=np.float32),
                                      np.ascontiguousarray(tris, dtype=np.int32))
        # the scene's BVH is built on its first query: build it here, once per city, not in the first scan
        self._scene.run(np.zeros((1, 3), np.float32), np.array([[0.0, 0.0, 1.0]], np.float32), query="OCCLUDED")
        logger.debug("RayCaster for %r: %d triangles", city.name, self.n_triangles)

    def __reduce__(self) -> tuple[Any, tuple[BuildingMap, bool, float]]:
        # an Embree scene does not pickle: a worker process rebuilds it from the city (milliseconds)
        return _rebuild, self._args

    def _local(self, origins_m: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Origins in the local frame ((3,) or (N, 3), float64) and directions (N, 3) float64, checked."""
        o = np.asarray(origins_m, dtype=float)
        d = np.asarray(directions, dtype=float)
        if d.ndim != 2 or d.shape[1] != 3:
            raise ValueError(f"directions must be an (N, 3) array, got shape {d.shape}")
        if o.shape != d.shape and o.shape != (3,):
            raise ValueError(f"origins must be (3,) or shaped like the directions {d.shape}, got {o.shape}")
        return o - self._offset, d

    @staticmethod
    def _f32(o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        o32 = np.empty(d.shape, dtype=np.float32)
        o32[:] = o  # broadcasts one origin to every ray
        return o32, np.ascontiguousarray(d, dtype=np.float32)

    def ranges_m(self, origins_m: np.ndarray, directions: np.ndarray, max_range_m: float, *,
                 exact: bool = False) -> np.ndarray:
        """Distance along each ray to its first hit.

        Args:
            origins_m: (N, 3) ray origins, or one (3,) origin for all, world ENU metres.
            directions: (N, 3) unit directions, world ENU (a range is in units of the direction's length).
            max_range_m: longest range [m] (np.inf: unlimited).
            exact: recompute each hit's range in float64 on the hit triangle's plane (~1e-12 m instead of float32's
                ~1e-4 m; a ray grazing a face keeps float32's; ~1 ms more for a 28,800-ray scan).

        Returns:
            (N,) range [m] to the first hit, np.inf where there is none within max_range_m.
        """
        o, d = self._local(origins_m, directions)
        if len(d) == 0 or self.n_triangles == 0:
            return np.full(len(d), np.inf)
        # One float32 step beyond the range, so that a hit at exactly max_range_m is still found.
        tfar = np.nextafter(np.float32(max_range_m), np.float32(np.inf)) if math.isfinite(max_range_m) \
            else np.float32(np.inf)
        if not exact:
            # a miss leaves tfar as it was given, above max_range_m
            t = self._scene.run(*self._f32(o, d), dists=float(tfar), query="DISTANCE").astype(float)
        else:
            t = self._exact(o, d, self._scene.run(*self._f32(o, d), dists=float(tfar), query="DISTANCE",
                                                  output=True))
        t[t > max_range_m] = np.inf
        return t

    def first_hits(self, origins_m: np.ndarray, directions: np.ndarray, max_range_m: float, *,
                   exact: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Each ray's first hit and what it hit.

        Args:
            origins_m: (N, 3) ray origins, or one (3,) origin for all, world ENU metres.
            directions: (N, 3) unit directions, world ENU.
            max_range_m: longest range [m].
            exact: as in `ranges_m`.

        Returns:
            (N,) range [m] as `ranges_m` gives it (np.inf where there is no hit within max_range_m) and (N,) index
            of the hit part in the city's `buildings` (-1: the ground, -2: no hit).
        """
        o, d = self._local(origins_m, directions)
        if len(d) == 0 or self.n_triangles == 0:
            return np.full(len(d), np.inf), np.full(len(d), -2, dtype=np.int64)
        tfar = np.nextafter(np.float32(max_range_m), np.float32(np.inf)) if math.isfinite(max_range_m) \
            else np.float32(np.inf)
        hit = self._scene.run(*self._f32(o, d), dists=float(tfar), query="DISTANCE", output=True)
        t = self._exact(o, d, hit) if exact else hit["tfar"].astype(float)
        t[t > max_range_m] = np.inf
        part = np.where(hit["primID"] >= 0, self._tri_part[np.maximum(hit["primID"], 0)], -2)
        part[~np.isfinite(t)] = -2
        return t, part

    def _exact(self, o: np.ndarray, d: np.ndarray, hit: dict[str, np.ndarray]) -> np.ndarray:
        """Embree's hits with their ranges recomputed in float64 on the hit triangles' planes; misses inf."""
        prim = hit["primID"]
        miss = prim < 0
        tri = np.where(miss, 0, prim)  # over all rays: cheaper than gathering the hits first
        nx, ny, nz = self._normal_xyz
        if o.ndim == 1:  # one origin (a lidar scan): its distance to every plane once, then gathered
            num = (self._plane - self._normal @ o)[tri]
        else:
            num = self._plane[tri] - (nx[tri] * o[:, 0] + ny[tri] * o[:, 1] + nz[tri] * o[:, 2])
        den = nx[tri] * d[:, 0]
        den += ny[tri] * d[:, 1]
        den += nz[tri] * d[:, 2]
        t32 = hit["tfar"].astype(float)
        with np.errstate(divide="ignore", invalid="ignore"):
            t64 = num / den
        # where a ray grazes the hit triangle (a hit at an edge) its plane's answer can be far off while float32's
        # is not: keep float32's there
        t = np.where(np.abs(t64 - t32) <= 1e-3 + 1e-6 * t32, t64, t32)
        t[miss] = np.inf
        return t

    def hits_any(self, origins_m: np.ndarray, directions: np.ndarray, max_range_m: float = np.inf) -> np.ndarray:
        """Whether each ray hits anything within max_range_m (an occlusion test: cheaper than `ranges_m`).

        Args:
            origins_m: (N, 3) ray origins, or one (3,) origin for all, world ENU metres.
            directions: (N, 3) directions, world ENU.
            max_range_m: longest range [m], in units of the direction's length.

        Returns:
            (N,) bool: True where the ray is blocked.
        """
        o, d = self._local(origins_m, directions)
        if len(d) == 0 or self.n_triangles == 0:
            return np.zeros(len(d), dtype=bool)
        # embreex's OCCLUDED query returns 0 for a blocked ray and -1 for a free one
        return self._scene.run(*self._f32(o, d), dists=float(max_range_m), query="OCCLUDED") == 0


def _rebuild(city: BuildingMap, ground: bool, ground_margin_m: float) -> RayCaster:
    return RayCaster(city, ground=ground, ground_margin_m=ground_margin_m)
