"""Geodesic route fields (rl/sensing/route.py): time to build one field, to store it, and to query a bank.

`route_field` is timed on 420 m x 420 m training-style cities (the largest extent the training
distribution draws) at the default 4 m cells, one random free goal per repetition, with its two
parts (rasterising the footprints, the fast march) timed alone; `RouteBank` queries are timed
for N = 256 vehicles, each slot holding its own field. Medians over repetitions.

Prints a table, then (last line) one JSON object of the figures.

    python perf/route.py [--reps 200]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np
import skfmm

from rl.sensing.route import RouteBank, RouteConfig, _blocking_boxes, _rasterise, grid_shape, route_field
from rl.task.cities import CityDistribution

RADIUS_M = 0.5
ALT_M = 20.0


CPU_MS: dict[str, float] = {}  # process CPU time per figure: what the wall time would be on an idle machine


def median_ms(fn, reps: int, name: str = "") -> float:
    """Median wall time of fn() [ms] over `reps` calls, after two warm-up calls (CPU time kept in CPU_MS)."""
    fn()
    fn()
    ts, cs = [], []
    for _ in range(reps):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
        cs.append(time.process_time() - c0)
    CPU_MS[name] = 1e3 * float(np.median(cs))
    return 1e3 * float(np.median(ts))


def free_goals(city, rng: np.random.Generator, n: int) -> np.ndarray:
    """n points at the flight level with clearance > radius + margin, 5 m inside the bounds."""
    lo, hi = np.asarray(city.bounds_min_m[:2]) + 5.0, np.asarray(city.bounds_max_m[:2]) - 5.0
    out = np.empty((0, 3))
    while len(out) < n:
        p = np.column_stack([rng.uniform(lo[0], hi[0], 4 * n), rng.uniform(lo[1], hi[1], 4 * n),
                             np.full(4 * n, ALT_M)])
        out = np.vstack([out, p[city.clearance(p, RADIUS_M).distance_m > RouteConfig().margin_m]])
    return out[:n]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=200, help="repetitions per figure")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    dist = CityDistribution(extent_m=(420.0, 420.0))
    cities = [dist.city(s) for s in range(8)]
    goals = [free_goals(c, rng, 16) for c in cities]
    cfg = RouteConfig()
    fig: dict[str, float | int | str] = {}
    rows = []

    k = [0]

    def one_field(cell_m: float = cfg.cell_m):
        i = k[0] = k[0] + 1
        c = cities[i % len(cities)]
        goal = goals[i % len(cities)][(i // len(cities)) % 16]
        return route_field(c, goal, ALT_M, RADIUS_M, RouteConfig(cell_m=cell_m))

    shape = grid_shape(cities[0], cfg.cell_m)
    fig["grid_cells"] = int(shape[0] * shape[1])
    fig["buildings_mean"] = float(np.mean([len(c.buildings) for c in cities]))
    fig["route_field_ms"] = median_ms(one_field, args.reps, "route_field_ms")
    rows.append(("route_field", f"{shape[1]} x {shape[0]} cells", fig["route_field_ms"]))

    reach = RADIUS_M + cfg.margin_m
    c0 = cities[0]
    boxes = _blocking_boxes(c0, ALT_M - reach)
    origin = np.asarray(c0.bounds_min_m[:2]) + 0.5 * cfg.cell_m
    fig["rasterise_ms"] = median_ms(lambda: _rasterise(boxes, reach, origin, cfg.cell_m, shape), args.reps,
                                    "rasterise_ms")
    rows.append(("  rasterise footprints", f"{len(boxes)} blocking boxes", fig["rasterise_ms"]))
    f0 = route_field(c0, goals[0][0], ALT_M, RADIUS_M)
    xs = origin[0] + cfg.cell_m * np.arange(shape[1])
    ys = origin[1] + cfg.cell_m * np.arange(shape[0])
    phi = np.hypot(xs[None, :] - goals[0][0][0], ys[:, None] - goals[0][0][1]) - 1.5 * cfg.cell_m
    speed = np.where(f0.blocked, cfg.blocked_speed, 1.0)
    fig["fmm_ms"] = median_ms(lambda: skfmm.travel_time(phi, speed, dx=cfg.cell_m, order=2), args.reps,
                              "fmm_ms")
    rows.append(("  skfmm.travel_time", "order 2", fig["fmm_ms"]))

    fig["route_field_2m_ms"] = median_ms(lambda: one_field(2.0), max(args.reps // 4, 10), "route_field_2m_ms")
    rows.append(("route_field, 2 m cells", "for comparison", fig["route_field_2m_ms"]))

    n = 256
    fields = [one_field() for _ in range(n)]
    bank = RouteBank(n, shape)
    j = [0]

    def store():
        j[0] = (j[0] + 1) % n
        bank.set(j[0], fields[j[0]])

    fig["bank_set_ms"] = median_ms(store, args.reps, "bank_set_ms")
    rows.append(("RouteBank.set", "one slot", fig["bank_set_ms"]))
    for i, f in enumerate(fields):
        bank.set(i, f)
    pts = np.column_stack([rng.uniform(0, 420, n), rng.uniform(0, 420, n), rng.uniform(5, 30, n)])
    for name in ("distance", "potential", "direction"):
        fn = getattr(bank, name)
        fig[f"bank_{name}_ms_n256"] = median_ms(lambda: fn(pts), 5 * args.reps, f"bank_{name}_ms_n256")
        rows.append((f"RouteBank.{name}", "N = 256", fig[f"bank_{name}_ms_n256"]))
    fig["bank_query_ms_n256"] = max(fig[f"bank_{q}_ms_n256"] for q in ("distance", "potential", "direction"))

    print(f"route fields: 420 m x 420 m cities, {cfg.cell_m:g} m cells, flight level {ALT_M:g} m, "
          f"radius {RADIUS_M:g} m; {platform.processor() or platform.machine()}, {os.cpu_count()} cores")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"load average (1 min) {load:.2f}: with other jobs running, wall times exceed the CPU times")
    print(f"{'what':28s} {'size':22s} {'wall ms':>9s} {'CPU ms':>9s}")
    keys = ["route_field_ms", "rasterise_ms", "fmm_ms", "route_field_2m_ms", "bank_set_ms",
            "bank_distance_ms_n256", "bank_potential_ms_n256", "bank_direction_ms_n256"]
    for (what, size, ms), key in zip(rows, keys):
        print(f"{what:28s} {size:22s} {ms:9.3f} {CPU_MS[key]:9.3f}")
    fig["route_field_cpu_ms"] = CPU_MS["route_field_ms"]
    fig["bank_query_cpu_ms_n256"] = max(CPU_MS[f"bank_{q}_ms_n256"]
                                        for q in ("distance", "potential", "direction"))
    fig["load_average"] = load
    for text, ok in [("route_field_ms <= 6", fig["route_field_ms"] <= 6.0),
                     ("route_field_cpu_ms <= 6", fig["route_field_cpu_ms"] <= 6.0),
                     ("bank_query_ms_n256 <= 0.5 (each of distance, potential, direction)",
                      fig["bank_query_ms_n256"] <= 0.5)]:
        print(f"target {text}: {'met' if ok else 'NOT met'}")
    print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in fig.items()}))


if __name__ == "__main__":
    main()
