"""The classical pilot's mapping and replanning speed on the `wrong` map level (25 % of buildings missing from the
prior, heights and footprints off, cranes and masts).

A vehicle flies a straight line across the city (clear of the true buildings, 25-40 m up) taking a scan every few
metres; each scan is mapped (`planners.sensed_map.SensedMap.integrate`, on the true pose: this measures the mapping,
not the estimate). Every few scans the pilot's planning ladder plans from the position to a goal on the far side on
the fused map (what a replan in flight does). Figures (one core, `OMP_NUM_THREADS=1`):
  * `map_update_ms_median` / `_p95`: one scan mapped (target: median <= 10 ms for a 28,800-ray VLP-16 scan);
  * `octomap_full_scan_ms_median`: the baseline, every beam of the same scan inserted whole into an OctoMap octree
    at the same resolution (what mapping every ray would cost); `speedup_vs_full_scan` the ratio;
  * `replan_time_s_median` / `_p95`: the planning ladder on the fused map (target: p95 <= 0.5 s, the pilot's
    `replan_budget_s`), beside `plan_on_prior_s_median`, the same plans on the prior (the ratio shows what the
    sensed obstacles cost the planner).

    OMP_NUM_THREADS=1 python perf/mapping.py [--city downtown] [--scans 40] [--seed 3]
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np
import octomap

from planners.classical_pilot import ClassicalConfig
from planners.ladder import plan_with_escalation
from planners.sensed_map import SensedMap
from uam_fdm.city.map_error import apply_map_error, map_error_preset
from uam_fdm.city.mapfile import load_named_map
from uam_fdm.sensing.lidar import Lidar
from uam_fdm.sensing.raycast import RayCaster
from uam_fdm.sensing.specs import VLP16
from uam_fdm.vehicle.params import load_vehicle

TARGET_UPDATE_MS = 10.0
TARGET_REPLAN_P95_S = 0.5


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--city", default="downtown")
    ap.add_argument("--scans", type=int, default=40)
    ap.add_argument("--plan-every", type=int, default=5)
    ap.add_argument("--seed", type=int, default=3)
    args = ap.parse_args()
    world = load_named_map(args.city)
    lo, hi = world.bounds_min_m, world.bounds_max_m
    mid = 0.5 * (lo + hi)
    y = mid[1]
    start, goal = np.array([lo[0] + 0.1 * (hi[0] - lo[0]), y, 30.0]), np.array([lo[0] + 0.9 * (hi[0] - lo[0]), y, 30.0])
    maps = apply_map_error(world, (), map_error_preset("wrong"), args.seed, np.array([start, goal]), 3.0)
    truth, prior = maps.truth, maps.prior
    vehicle = load_vehicle("small_quad")
    cfg = ClassicalConfig()
    lidar = Lidar(VLP16, RayCaster(truth), np.random.default_rng(args.seed))
    sensed = SensedMap(prior, cfg.mapping, VLP16.max_range_m)
    update_ms, full_ms, replan_s, prior_s = [], [], [], []
    x = np.zeros(17)
    x[6] = 1.0
    for k in range(args.scans):
        p = start + (goal - start) * k / max(args.scans - 1, 1)
        for dz in (0.0, 5.0, 10.0, -5.0):
            if truth.is_free_one(p[0], p[1], p[2] + dz, 2.0):
                p = p + [0.0, 0.0, dz]
                break
        else:
            continue
        scan, _ = lidar.scan(0.0, p, np.eye(3))
        x[0:3] = p
        t0 = time.perf_counter()
        sensed.integrate(scan, x, 0.1)
        update_ms.append(1e3 * (time.perf_counter() - t0))
        tree = octomap.OcTree(cfg.mapping.resolution_m)
        t0 = time.perf_counter()
        tree.insertPointCloud(p + scan.points_body_m(), p, maxrange=-1.0)
        full_ms.append(1e3 * (time.perf_counter() - t0))
        if k % args.plan_every == 0:
            for bmap, out in ((sensed.fused(), replan_s), (prior, prior_s)):
                if not bmap.is_free_one(*p, vehicle.collision_radius_m):
                    continue
                found = plan_with_escalation(bmap, p, goal, vehicle.collision_radius_m, cfg.planner, seed=k,
                                             floor_margin_m=cfg.planner.safety_margin_m)
                out.append(found.plan_time_s)
    figures = {
        "map_update_ms_median": float(np.median(update_ms)), "map_update_ms_p95": float(np.percentile(update_ms, 95)),
        "octomap_full_scan_ms_median": float(np.median(full_ms)),
        "speedup_vs_full_scan": float(np.median(full_ms) / np.median(update_ms)),
        "replan_time_s_median": float(np.median(replan_s)) if replan_s else float("nan"),
        "replan_time_s_p95": float(np.percentile(replan_s, 95)) if replan_s else float("nan"),
        "plan_on_prior_s_median": float(np.median(prior_s)) if prior_s else float("nan"),
        "scans": len(update_ms), "replans": len(replan_s), "sensed_obstacles": len(sensed.fused().buildings)
        - len(prior.buildings) + len(sensed.cleared_parts), "cleared_prior_parts": len(sensed.cleared_parts),
        "city": args.city, "rays_per_scan": VLP16.channels * VLP16.columns,
    }
    print(f"{'figure':34s} {'value':>10s}  target")
    for key, target in (("map_update_ms_median", f"<= {TARGET_UPDATE_MS:g}"), ("map_update_ms_p95", ""),
                        ("octomap_full_scan_ms_median", "(baseline)"), ("speedup_vs_full_scan", ""),
                        ("replan_time_s_median", ""), ("replan_time_s_p95", f"<= {TARGET_REPLAN_P95_S:g}"),
                        ("plan_on_prior_s_median", "(baseline)")):
        print(f"{key:34s} {figures[key]:10.3f}  {target}")
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
