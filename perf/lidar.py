"""Lidar scan speed: a Velodyne VLP-16 scan (16 channels x 0.2 deg = 28,800 rays, 100 m) cast with Embree
(`uam_fdm.sensing.raycast.RayCaster`) against a vectorised NumPy slab test over the city's boxes (the project has
no 3D ray kernel of its own; this one lives here only, as the baseline), in the shipped cities.

Positions: `--positions` street points (clearance >= 3 m, 5-60 m up, random attitude within 20 deg of level).
Figures (one core, `OMP_NUM_THREADS=1`): median over positions and repeats of
  * `lidar_scan_ms`: `Lidar.scan` as the episode calls it (cast, dropout, noise, true points),
  * `lidar_cast_ms` / `lidar_cast_exact_ms`: `RayCaster.ranges_m` alone, float32 / float64-refined,
  * `box_kernel_scan_ms`: the same rays through the slab test (boxes out of range culled first),
and the largest difference between the slab test and Embree on the same rays. `speedup_vs_box_kernel` compares like
for like: the slab test's cast against Embree's (`lidar_cast_ms`); the table also gives it against the whole scan.
The JSON figures are the densest city's (canyon: 37 % of its ground built, 110 m median height).

    OMP_NUM_THREADS=1 python perf/lidar.py [--positions 8] [--repeats 20]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time

import numpy as np

from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.city.mapfile import load_named_map
from uam_fdm.sensing.lidar import Lidar
from uam_fdm.sensing.raycast import RayCaster
from uam_fdm.sensing.specs import VLP16

CITIES = ("canyon", "downtown", "suburb")  # canyon first: the densest (coverage and height)
TARGET_SCAN_MS = 5.0


def rotation(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Body FLU -> world ENU for Z-Y-X Euler angles [rad]."""
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), \
        math.sin(yaw)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def poses(city: BuildingMap, n: int, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """n street positions (clearance >= 3 m, 5-60 m up) with random near-level attitudes."""
    rng = np.random.default_rng(seed)
    out: list[tuple[np.ndarray, np.ndarray]] = []
    while len(out) < n:
        p = rng.uniform(city.bounds_min_m, city.bounds_max_m, (256, 3))
        p[:, 2] = rng.uniform(5.0, 60.0, 256)
        for q in p[city.clearance(p).distance_m >= 3.0][: n - len(out)]:
            tilt = np.radians(20.0)
            out.append((q, rotation(rng.uniform(-tilt, tilt), rng.uniform(-tilt, tilt), rng.uniform(-np.pi, np.pi))))
    return out


class BoxKernel:
    """First hits of rays from one origin on a city's boxes and the ground: a slab test in each box's own frame,
    vectorised over (rays x boxes) in chunks; boxes whose bounding circle lies beyond the range are culled."""

    def __init__(self, city: BuildingMap, chunk: int = 2048) -> None:
        parts = city.buildings
        if not all(isinstance(b, Building) for b in parts):
            raise ValueError("the slab kernel handles box buildings only")
        boxes = [b for b in parts if isinstance(b, Building)]
        self.c = np.array([b.center_xy_m for b in boxes]).reshape(-1, 2)
        self.cos = np.cos([b.yaw_rad for b in boxes])
        self.sin = np.sin([b.yaw_rad for b in boxes])
        self.half = 0.5 * np.array([b.size_xy_m for b in boxes]).reshape(-1, 2)
        self.z = np.array([(b.base_m, b.height_m) for b in boxes]).reshape(-1, 2)
        self.chunk = chunk

    def ranges_m(self, o: np.ndarray, d: np.ndarray, max_range_m: float) -> np.ndarray:
        near = np.hypot(*(self.c - o[:2]).T) - np.hypot(*self.half.T) <= max_range_m
        c, cos, sin, half, z = self.c[near], self.cos[near], self.sin[near], self.half[near], self.z[near]
        rel = o[:2] - c  # (B, 2) origin in each box's frame
        ox, oy = cos * rel[:, 0] + sin * rel[:, 1], -sin * rel[:, 0] + cos * rel[:, 1]
        lo = np.stack([-half[:, 0] - ox, -half[:, 1] - oy, z[:, 0] - o[2]])  # (3, B) slab bounds minus origin
        hi = np.stack([half[:, 0] - ox, half[:, 1] - oy, z[:, 1] - o[2]])
        out = np.full(len(d), np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            for s in range(0, len(d), self.chunk):
                dd = d[s:s + self.chunk]
                dl = [dd[:, 0:1] * cos + dd[:, 1:2] * sin, -dd[:, 0:1] * sin + dd[:, 1:2] * cos,
                      np.broadcast_to(dd[:, 2:3], (len(dd), len(cos)))]  # (R, B) directions in box frames
                t_in = np.zeros((len(dd), len(cos)))
                t_out = np.full((len(dd), len(cos)), np.inf)
                for k in range(3):
                    inv = 1.0 / dl[k]
                    a, b = lo[k] * inv, hi[k] * inv
                    t_in = np.fmax(t_in, np.fmin(a, b))
                    t_out = np.fmin(t_out, np.fmax(a, b))
                t_box = np.where(t_in <= t_out, t_in, np.inf).min(axis=1)
                t_ground = np.where(dd[:, 2] < 0.0, -o[2] / dd[:, 2], np.inf)
                out[s:s + self.chunk] = np.minimum(t_box, t_ground)
        out[out > max_range_m] = np.inf
        return out


def median_ms(fn, args_list, repeats: int) -> float:
    """Median wall time [ms] of fn(*args) over repeats x the argument sets, after one warm-up each."""
    for a in args_list:
        fn(*a)
    ts = []
    for _ in range(repeats):
        for a in args_list:
            t0 = time.perf_counter()
            fn(*a)
            ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts))


def measure(name: str, n_pos: int, repeats: int) -> dict[str, float]:
    city = load_named_map(name)
    t0 = time.perf_counter()
    caster = RayCaster(city)
    build_ms = 1e3 * (time.perf_counter() - t0)
    lidar = Lidar(VLP16, caster, np.random.default_rng(0))
    kernel = BoxKernel(city)
    ps = poses(city, n_pos, seed=1)
    rays = [(p, lidar.directions_body @ r.T) for p, r in ps]
    fig = {"buildings": float(len(city.building_ids)), "triangles": float(caster.n_triangles),
           "build_ms": build_ms,
           "scan_ms": median_ms(lambda p, r: lidar.scan(0.0, p, r), ps, repeats),
           "cast_ms": median_ms(lambda p, d: caster.ranges_m(p, d, VLP16.max_range_m), rays, repeats),
           "cast_exact_ms": median_ms(lambda p, d: caster.ranges_m(p, d, VLP16.max_range_m, exact=True), rays,
                                      repeats),
           "box_ms": median_ms(lambda p, d: kernel.ranges_m(p, d, VLP16.max_range_m), rays, max(1, repeats // 10))}
    diff, diff_exact, disagree, hits = 0.0, 0.0, 0, 0
    for p, d in rays:
        ref = kernel.ranges_m(p, d, VLP16.max_range_m)
        for exact in (False, True):
            got = caster.ranges_m(p, d, VLP16.max_range_m, exact=exact)
            both = np.isfinite(ref) & np.isfinite(got)
            dmax = float(np.max(np.abs(got[both] - ref[both]))) if both.any() else 0.0
            if exact:
                diff_exact = max(diff_exact, dmax)
            else:
                diff = max(diff, dmax)
                disagree += int(np.count_nonzero(np.isfinite(ref) != np.isfinite(got)))
                hits += int(np.count_nonzero(np.isfinite(ref)))
    fig.update(max_diff_m=diff, max_diff_exact_m=diff_exact, hit_miss_disagree=float(disagree),
               hits=float(hits), rays=float(len(rays) * VLP16.rays_per_scan))
    return fig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--positions", type=int, default=8, help="scan positions per city")
    ap.add_argument("--repeats", type=int, default=20, help="timed scans per position")
    args = ap.parse_args()
    print(f"VLP-16 scan: {VLP16.rays_per_scan:,} rays to {VLP16.max_range_m:g} m, {args.positions} positions x "
          f"{args.repeats} repeats; {platform.processor() or platform.machine()}, "
          f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}")
    head = (f"{'city':9s} {'bldgs':>5s} {'tris':>6s} {'build ms':>8s} {'scan ms':>8s} {'cast ms':>8s} "
            f"{'exact ms':>8s} {'slab ms':>8s} {'vs cast':>8s} {'vs scan':>8s} {'max |diff| m':>12s} {'exact':>8s} "
            f"{'hit/miss':>9s}")
    print(head)
    figs = {}
    for name in CITIES:
        f = measure(name, args.positions, args.repeats)
        figs[name] = f
        print(f"{name:9s} {f['buildings']:5.0f} {f['triangles']:6.0f} {f['build_ms']:8.1f} {f['scan_ms']:8.2f} "
              f"{f['cast_ms']:8.2f} {f['cast_exact_ms']:8.2f} {f['box_ms']:8.1f} {f['box_ms'] / f['cast_ms']:7.1f}x "
              f"{f['box_ms'] / f['scan_ms']:7.1f}x "
              f"{f['max_diff_m']:12.1e} {f['max_diff_exact_m']:8.1e} {f['hit_miss_disagree']:4.0f}/{f['hits']:.0f}")
    c = figs[CITIES[0]]
    print("vs cast / vs scan: the slab kernel's cast time over Embree's cast / over the whole scan (cast, dropout, "
          "noise, true points); max |diff|: slab kernel against Embree (float32 / exact=True) where both hit; "
          "hit/miss: rays one finds and the other does not, of the slab kernel's hits")
    met = "met" if c["scan_ms"] <= TARGET_SCAN_MS else "NOT met"
    print(f"target lidar_scan_ms <= {TARGET_SCAN_MS:g} ({CITIES[0]}): {met}")
    out = {"lidar_scan_ms": c["scan_ms"], "lidar_rays_per_s": VLP16.rays_per_scan / (1e-3 * c["scan_ms"]),
           "lidar_cast_ms": c["cast_ms"], "lidar_cast_exact_ms": c["cast_exact_ms"],
           "box_kernel_scan_ms": c["box_ms"], "speedup_vs_box_kernel": c["box_ms"] / c["cast_ms"],
           "box_kernel_max_diff_m": c["max_diff_m"], "box_kernel_max_diff_exact_m": c["max_diff_exact_m"]}
    print(json.dumps({k: float(f"{v:.4g}") for k, v in out.items()}))


if __name__ == "__main__":
    main()
