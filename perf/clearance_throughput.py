"""Clearance throughput on a 200-building city: batched NumPy, the scalar index, FCL, segments.

Run under the shared CPU lock:  flock /tmp/uam_cpu.lock python perf/clearance_throughput.py

Every path is exact; the run also checks that they agree.  The baseline is plain per-point FCL as
one would write it (a sphere of the vehicle radius, `mgr.distance` with fcl.defaultDistanceCallback
and a fresh DistanceData per query), measured in the same run.  Prints a table, then one JSON line.
"""
from __future__ import annotations

import json
import os
import statistics
import time
from collections.abc import Callable

os.environ["OMP_NUM_THREADS"] = "1"  # before NumPy loads: single-threaded, comparable figures

import fcl  # noqa: E402
import numpy as np  # noqa: E402

from uam_fdm.city.buildings import BuildingMap  # noqa: E402
from uam_fdm.city.generator import CityGenConfig, generate_city  # noqa: E402

N_BUILDINGS = 200
RADIUS_M = 1.0
N_BATCH = 10_000
SEED = 1


def _city() -> BuildingMap:
    """A rotated-grid city with a taller core, cut to its first 200 buildings."""
    params = CityGenConfig(extent_m=(1000.0, 1000.0), block_size_m=(90.0, 90.0), street_width_m=24.0,
                           lots_per_block=(2, 2), density=0.9, core_radius_m=250.0, core_height_factor=4.0,
                           grid_yaw_deg=15.0, yaw_jitter_deg=3.0, height_median_m=30.0)
    full = generate_city(params, SEED)
    assert len(full.buildings) >= N_BUILDINGS, len(full.buildings)
    return BuildingMap(full.buildings[:N_BUILDINGS], full.bounds_min_m, full.bounds_max_m, name="bench")


def _median_time(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _plain_fcl(bmap: BuildingMap) -> Callable[[np.ndarray], list[float]]:
    """Per-point FCL written the plain way, over the same boxes (the benchmark's baseline)."""
    objs = []
    for b in bmap.buildings:
        c, s = np.cos(b.yaw_rad), np.sin(b.yaw_rad)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        objs.append(fcl.CollisionObject(fcl.Box(*b.size_xy_m, b.height_m),
                                        fcl.Transform(rot, np.array([*b.center_xy_m, 0.5 * b.height_m]))))
    mgr = fcl.DynamicAABBTreeCollisionManager()
    mgr.registerObjects(objs)
    mgr.setup()
    sphere = fcl.CollisionObject(fcl.Sphere(RADIUS_M), fcl.Transform())
    request = fcl.DistanceRequest(enable_nearest_points=True, enable_signed_distance=True)

    def run(points: np.ndarray) -> list[float]:
        out = []
        for p in points:
            sphere.setTranslation(p)
            data = fcl.DistanceData(request=request)
            mgr.distance(sphere, data, fcl.defaultDistanceCallback)
            out.append(min(data.result.min_distance, p[2] - RADIUS_M))
        return out

    return run


def main() -> None:
    bmap = _city()
    lo, hi = bmap.bounds_min_m, bmap.bounds_max_m
    rng = np.random.default_rng(SEED)
    pts = rng.uniform([lo[0], lo[1], 0.0], [hi[0], hi[1], 150.0], size=(N_BATCH, 3))
    small = pts[:2000]
    rows: list[tuple[str, int, float]] = []  # (path, queries per run, seconds per run)

    # Agreement first: the fast paths must equal FCL.
    ref = bmap.clearance(small, RADIUS_M, backend="fcl").distance_m
    diff_np = float(np.max(np.abs(bmap.clearance(small, RADIUS_M).distance_m - ref)))
    one = np.array([bmap.clearance_one(*p, RADIUS_M) for p in small.tolist()])  # also warms these cells
    diff_one = float(np.max(np.abs(one - ref)))
    plain = _plain_fcl(bmap)
    diff_plain = float(np.max(np.abs(np.array(plain(small)) - ref)))

    rows.append(("batched NumPy clearance(), 10,000 points", N_BATCH,
                 _median_time(lambda: bmap.clearance(pts, RADIUS_M), 7)))
    rows.append(("clearance() on batches of 1 point", 2000,
                 _median_time(lambda: [bmap.clearance(small[i:i + 1], RADIUS_M) for i in range(2000)], 3)))
    cold_map = _city()
    plist = pts.tolist()
    t_cold = _median_time(lambda: [cold_map.clearance_one(x, y, z, RADIUS_M) for x, y, z in plist], 1)
    rows.append(("clearance_one(), cold cell index (first pass)", N_BATCH, t_cold))
    rows.append(("clearance_one(), warm", N_BATCH,
                 _median_time(lambda: [cold_map.clearance_one(x, y, z, RADIUS_M) for x, y, z in plist], 5)))
    rows.append(("plain per-point FCL (sphere r, default callback)", 2000, _median_time(lambda: plain(small), 3)))
    rows.append(("clearance(backend='fcl') (point query, ids, nearest)", 2000,
                 _median_time(lambda: bmap.clearance(small, RADIUS_M, backend="fcl"), 3)))

    def segments(length_lo: float, length_hi: float, n: int) -> tuple[np.ndarray, np.ndarray]:
        a = rng.uniform([lo[0], lo[1], 5.0], [hi[0], hi[1], 150.0], size=(n, 3))
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return a, a + d * rng.uniform(length_lo, length_hi, size=(n, 1))

    seg_a, seg_b = segments(5.0, 50.0, 5000)
    long_a, long_b = segments(150.0, 400.0, 1000)
    free_short = np.mean([bmap.segment_free(a, b, RADIUS_M) for a, b in zip(seg_a, seg_b)])
    free_long = np.mean([bmap.segment_free(a, b, RADIUS_M) for a, b in zip(long_a, long_b)])
    rows.append(("segment_free(), 5-50 m segments", len(seg_a),
                 _median_time(lambda: [bmap.segment_free(a, b, RADIUS_M) for a, b in zip(seg_a, seg_b)], 3)))
    rows.append(("segment_free(), 150-400 m segments", len(long_a),
                 _median_time(lambda: [bmap.segment_free(a, b, RADIUS_M) for a, b in zip(long_a, long_b)], 3)))

    rate = {name: n / t for name, n, t in rows}
    fcl_rate = rate["plain per-point FCL (sphere r, default callback)"]
    print(f"City: {len(bmap.buildings)} buildings (yawed boxes) in {hi[0]:.0f} x {hi[1]:.0f} m; sphere radius "
          f"{RADIUS_M} m; points uniform in the volume, z 0-150 m; OMP_NUM_THREADS=1\n")
    print(f"{'path':<55} {'queries':>8} {'us/query':>10} {'queries/s':>12} {'x plain FCL':>12}")
    for name, n, t in rows:
        print(f"{name:<55} {n:>8} {1e6 * t / n:>10.2f} {n / t:>12,.0f} {(n / t) / fcl_rate:>12.2f}")
    print(f"\nmax |NumPy - FCL| = {diff_np:.2e} m, max |clearance_one - FCL| = {diff_one:.2e} m, "
          f"max |plain FCL (sphere r) - point FCL| = {diff_plain:.2e} m over {len(small)} points")
    print(f"segments free: {100 * free_short:.0f}% (5-50 m), {100 * free_long:.0f}% (150-400 m)")
    figures = {
        "n_buildings": len(bmap.buildings),
        "batched_point_queries_per_s": round(rate["batched NumPy clearance(), 10,000 points"]),
        "batch1_point_queries_per_s": round(rate["clearance() on batches of 1 point"]),
        "single_point_queries_per_s": round(rate["clearance_one(), warm"]),
        "single_point_cold_queries_per_s": round(rate["clearance_one(), cold cell index (first pass)"]),
        "fcl_per_point_queries_per_s": round(fcl_rate),
        "fcl_backend_queries_per_s": round(rate["clearance(backend='fcl') (point query, ids, nearest)"]),
        "batched_vs_fcl_ratio": round(rate["batched NumPy clearance(), 10,000 points"] / fcl_rate, 2),
        "single_vs_fcl_ratio": round(rate["clearance_one(), warm"] / fcl_rate, 2),
        "segment_checks_per_s": round(rate["segment_free(), 5-50 m segments"]),
        "long_segment_checks_per_s": round(rate["segment_free(), 150-400 m segments"]),
        "max_abs_diff_numpy_fcl_m": diff_np,
        "max_abs_diff_single_fcl_m": diff_one,
        "max_abs_diff_plain_sphere_fcl_m": diff_plain,
    }
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
