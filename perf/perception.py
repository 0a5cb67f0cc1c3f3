"""Perception speed and size: `rl.sensing.perception.Perception.observe` (rays + height map) and its build.

Query points are spread uniformly over the cities' bounds (altitude 2-60 m, random headings), one
point per city for the batched call (N = 256 points in 256 different training cities); the single
call is one point. Build figures are for `--build-cities` training cities (generation not timed);
the build's peak memory is measured with tracemalloc in a second build.

Prints a table, then (last line) one JSON object of the figures.

    python perf/perception.py [--build-cities 1000] [--calls 200]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
import tracemalloc

import numpy as np

from rl.sensing.perception import Perception, PerceptionConfig
from rl.task.cities import CityDistribution

RADIUS_M = 0.42  # small_quad's collision radius


def queries(cities, n: int, batches: int, seed: int):
    """`batches` query sets of n points: (points (n, 3), headings (n,), city indices (n,))."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(batches):
        ci = rng.permutation(len(cities))[:n] if n <= len(cities) else rng.integers(0, len(cities), n)
        lo = np.array([cities[c].bounds_min_m for c in ci])
        hi = np.array([cities[c].bounds_max_m for c in ci])
        p = rng.uniform(lo, hi)
        p[:, 2] = rng.uniform(2.0, 60.0, n)
        out.append((p, rng.uniform(-np.pi, np.pi, n), ci))
    return out


def median_ms(fn, sets, calls: int) -> float:
    """Median wall time [ms] of fn(*set) over `calls` calls cycling through the sets (after a warm-up)."""
    for s in sets[:5]:
        fn(*s)
    ts = []
    for i in range(calls):
        s = sets[i % len(sets)]
        t0 = time.perf_counter()
        fn(*s)
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build-cities", type=int, default=1000, help="cities for the build figures")
    ap.add_argument("--calls", type=int, default=200, help="timed calls per figure")
    args = ap.parse_args()
    cfg = PerceptionConfig()
    dist = CityDistribution()
    cities = [dist.city(s) for s in range(max(256, args.build_cities))]

    t0 = time.perf_counter()
    big = Perception(cities[: args.build_cities], RADIUS_M, cfg)
    build_s = time.perf_counter() - t0
    bytes_per_city = big.nbytes / args.build_cities
    table_per_city = big._table.nbytes / args.build_cities
    del big
    tracemalloc.start()
    big = Perception(cities[: args.build_cities], RADIUS_M, cfg)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    del big

    per = Perception(cities[:256], RADIUS_M, cfg)
    sets256 = queries(cities[:256], 256, 20, 0)
    sets1 = queries(cities[:256], 1, 200, 1)
    fig = {
        "observe_ms_n256": median_ms(per.observe, sets256, args.calls),
        "observe_ms_n1": median_ms(per.observe, sets1, 5 * args.calls),
        "rays_ms_n256": median_ms(per.rays, sets256, args.calls),
        "roofs_ms_n256": median_ms(per.roofs, sets256, args.calls),
        "rays_ms_n1": median_ms(per.rays, sets1, 5 * args.calls),
        "roofs_ms_n1": median_ms(per.roofs, sets1, 5 * args.calls),
        "build_s_per_city": build_s / args.build_cities,
        "build_s": build_s,
        "build_peak_mb": peak / 1e6,
        "bytes_per_city": bytes_per_city,
        "height_table_bytes_per_city": table_per_city,
        "build_cities": args.build_cities,
    }
    # Candidate-list lengths met by the batched queries (mean buildings tested per point).
    lens = []
    for p, _, ci in sets256:
        rel = (p[:, :2] - per._g_origin[ci]) / per.ray_cell_m
        ix = np.clip(np.floor(rel[:, 0]), 0, per._g_dims[ci, 0] - 1).astype(np.int64)
        iy = np.clip(np.floor(rel[:, 1]), 0, per._g_dims[ci, 1] - 1).astype(np.int64)
        cell = per._g_cell0[ci] + iy * per._g_dims[ci, 0] + ix
        lens.append(per._cell_start[cell + 1] - per._cell_start[cell])
    fig["candidates_per_point"] = float(np.mean(np.concatenate(lens)))

    print(f"perception: {cfg.n_rays} rays to {cfg.ray_range_m:g} m, "
          f"{cfg.grid_cells}x{cfg.grid_cells} height map of {cfg.cell_m:g} m cells "
          f"from a {cfg.raster_m:g} m raster; radius {RADIUS_M} m; "
          f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores")
    print(f"{'what':40s} {'value':>12s}  target")
    rows = [("observe, N=256 in 256 cities [ms]", fig["observe_ms_n256"], "<= 4"),
            ("  rays only [ms]", fig["rays_ms_n256"], ""),
            ("  height map only [ms]", fig["roofs_ms_n256"], ""),
            ("observe, N=1 [ms]", fig["observe_ms_n1"], "<= 0.3"),
            ("  rays only [ms]", fig["rays_ms_n1"], ""),
            ("  height map only [ms]", fig["roofs_ms_n1"], ""),
            (f"build, {args.build_cities} cities [s]", build_s, "<= 60"),
            ("build peak memory [MB]", fig["build_peak_mb"], "<= 400"),
            ("stored bytes per city", bytes_per_city, ""),
            ("  of which height table", table_per_city, ""),
            ("candidate buildings per ray query", fig["candidates_per_point"], "")]
    for what, value, target in rows:
        print(f"{what:40s} {value:12,.3f}  {target}")
    targets = [("observe_ms_n256 <= 4", fig["observe_ms_n256"] <= 4.0),
               ("observe_ms_n1 <= 0.3", fig["observe_ms_n1"] <= 0.3),
               ("build <= 60 s per 1000 cities", fig["build_s_per_city"] * 1000 <= 60.0),
               ("build peak <= 400 MB per 1000 cities",
                fig["build_peak_mb"] * 1000 / args.build_cities <= 400.0)]
    for text, ok in targets:
        print(f"target {text}: {'met' if ok else 'NOT met'}")
    print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in fig.items()}))


if __name__ == "__main__":
    main()
