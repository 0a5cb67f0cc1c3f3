"""The classical pilot's figures: planning (OMPL) and, later, tracking (MPC).

Planning, per algorithm at its default deterministic budget, over start/goal queries on the
shipped maps (suburb, downtown, canyon) and several seeds:
  * time to the first solution (median) and whole-query plan time (median);
  * success rate;
  * path efficiency = best known length / length after the budget (<= 1, higher is better), where
    the best known length of a query is the shortest of long time-budget runs of BIT* and
    InformedRRT* (run in parallel first) and of every budget run.
The timing law (planners.timing) is measured on the default planner's paths: duration, mean
speed, refinements, stops, clearance.

    OMP_NUM_THREADS=1 flock /tmp/uam_cpu.lock python benchmarks/classical.py [--long-s 15] [--variants]

Prints a table and, as its last line, one JSON object of the figures.
"""
from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import os
import platform
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from planners.rrt_star import ALGORITHMS, PlannerConfig, plan_path  # noqa: E402
from planners.timing import TimingLimits, time_parameterize  # noqa: E402
from uam_fdm.city import BuildingMap, load_named_map  # noqa: E402
from uam_fdm.params import load_vehicle  # noqa: E402

MAPS = ("suburb", "downtown", "canyon")
# Start/goal heights per map [m]: low enough that the buildings are in the way.
HEIGHTS_M = {"suburb": (5.0, 20.0), "downtown": (10.0, 60.0), "canyon": (10.0, 80.0)}

# Extra configurations measured with --variants (they informed the defaults; see docs/planner.md).
VARIANTS = {
    "rrtstar_radius_10k": PlannerConfig(algorithm="rrtstar", k_nearest=False, max_iterations=10000),
    "rrtstar_range_none": PlannerConfig(algorithm="rrtstar", range_m=None),
    "informed_rrtstar_radius_10k": PlannerConfig(algorithm="informed_rrtstar", k_nearest=False,
                                                 max_iterations=10000),
    "bitstar_5k": PlannerConfig(algorithm="bitstar", max_iterations=5000),
    "bitstar_10k": PlannerConfig(algorithm="bitstar", max_iterations=10000),
    "bitstar_40k": PlannerConfig(algorithm="bitstar", max_iterations=40000),
}


@dataclass(frozen=True)
class Query:
    """One planning problem on a shipped map (ENU metres)."""

    map_name: str
    start_m: tuple[float, float, float]
    goal_m: tuple[float, float, float]


@functools.cache
def _map(name: str) -> BuildingMap:
    return load_named_map(name)


def make_queries(per_map: int, radius_m: float, margin_m: float, seed: int = 0,
                 maps: Sequence[str] = MAPS) -> list[Query]:
    """Random start/goal pairs, far apart (>= half the map) and clear by R + 1 m, per map."""
    out = []
    for k, name in enumerate(maps):
        city = _map(name)
        rng = np.random.default_rng([seed, k])
        lo, hi = np.asarray(city.bounds_min_m), np.asarray(city.bounds_max_m)
        ext = hi[:2] - lo[:2]
        z0, z1 = HEIGHTS_M.get(name, (10.0, 60.0))
        found = 0
        while found < per_map:
            p, q = (np.r_[lo[:2] + 0.05 * ext + rng.random(2) * 0.9 * ext, rng.uniform(z0, z1)] for _ in range(2))
            if np.linalg.norm(p[:2] - q[:2]) < 0.5 * ext.min():
                continue
            if min(city.clearance_one(*p, radius_m + margin_m), city.clearance_one(*q, radius_m + margin_m)) > 1.0:
                out.append(Query(name, tuple(map(float, p)), tuple(map(float, q))))
                found += 1
    return out


def _long_run(args: tuple[Query, str, float, float, float]) -> float:
    query, algorithm, seconds, radius_m, margin_m = args
    cfg = PlannerConfig(algorithm=algorithm, max_iterations=None, time_budget_s=seconds, safety_margin_m=margin_m,
                        k_nearest=algorithm == "bitstar")
    r = plan_path(_map(query.map_name), query.start_m, query.goal_m, radius_m, cfg, seed=7)
    return r.length_m if r.ok else math.inf


def measure_planning(configs: dict[str, PlannerConfig], queries: Sequence[Query], radius_m: float,
                     seeds: Sequence[int] = (1, 2, 3), long_s: float = 15.0, workers: int = 2,
                     reference_m: Sequence[float] | None = None) -> dict:
    """Planning figures per configuration.

    Args:
        configs: name -> planner configuration to measure (their safety margins should agree).
        queries: the planning problems.
        radius_m: vehicle collision radius [m].
        seeds: OMPL seeds per (configuration, query).
        long_s: time budget of each long reference run [s] (BIT* and InformedRRT*, one each).
        workers: processes for the long runs (the timed runs are sequential, after them).
        reference_m: best lengths per query from an earlier call (`best_m`): skips the long runs.

    Returns:
        {"best_m": [...], "per_config": {name: {...figures...}}, "runs": [...]} where each
        config's figures are first_solution_ms_median, plan_time_s_median, success_rate,
        path_efficiency (mean over successful runs), path_efficiency_min and n_runs.
    """
    margin = next(iter(configs.values())).safety_margin_m
    if reference_m is None:
        jobs = [(q, alg, long_s, radius_m, margin) for q in queries for alg in ("bitstar", "informed_rrtstar")]
        with ProcessPoolExecutor(max_workers=workers) as pool:
            long_lengths = list(pool.map(_long_run, jobs))
        best = [min(long_lengths[2 * i:2 * i + 2]) for i in range(len(queries))]
    else:
        long_lengths, best = [], [float(x) for x in reference_m]
    # Warm-up: the maps' clearance index is built lazily on first use; keep that out of the timings.
    for q in queries:
        plan_path(_map(q.map_name), q.start_m, q.goal_m, radius_m, PlannerConfig(max_iterations=200,
                                                                             safety_margin_m=margin), seed=0)
    runs = []
    for name, cfg in configs.items():
        for qi, q in enumerate(queries):
            for seed in seeds:
                r = plan_path(_map(q.map_name), q.start_m, q.goal_m, radius_m, cfg, seed=seed)
                runs.append(dict(config=name, query=qi, seed=seed, status=r.status, length_m=r.length_m,
                                 first_solution_s=r.first_solution_time_s, plan_time_s=r.plan_time_s,
                                 iterations=r.iterations, min_clearance_m=r.min_clearance_m,
                                 wall_cap_hit=r.wall_cap_hit))
                if r.ok:
                    best[qi] = min(best[qi], r.length_m)
    per_config = {}
    for name, cfg in configs.items():
        mine = [x for x in runs if x["config"] == name]
        ok = [x for x in mine if x["status"] == "exact"]
        eff = [best[x["query"]] / x["length_m"] for x in ok]
        first = [x["first_solution_s"] for x in mine if math.isfinite(x["first_solution_s"])]
        per_config[name] = dict(
            algorithm=cfg.algorithm, iterations=cfg.iteration_budget,
            first_solution_ms_median=1e3 * float(np.median(first)) if first else math.nan,
            plan_time_s_median=float(np.median([x["plan_time_s"] for x in mine])),
            plan_time_s_max=float(np.max([x["plan_time_s"] for x in mine])),
            success_rate=len(ok) / len(mine), path_efficiency=float(np.mean(eff)) if eff else math.nan,
            path_efficiency_min=float(np.min(eff)) if eff else math.nan,
            min_clearance_m=float(np.min([x["min_clearance_m"] for x in ok])) if ok else math.nan,
            wall_cap_hits=sum(x["wall_cap_hit"] for x in mine), n_runs=len(mine))
    return {"best_m": best, "long_m": long_lengths, "per_config": per_config, "runs": runs}


def measure_timing(queries: Sequence[Query], vehicle: str = "small_quad", config: PlannerConfig | None = None,
                   seed: int = 1) -> dict:
    """Timing-law figures on the (default) planner's paths for one vehicle."""
    config = config or PlannerConfig()
    params = load_vehicle(vehicle)
    limits = TimingLimits.from_vehicle(params)
    rows = []
    for q in queries:
        city = _map(q.map_name)
        plan = plan_path(city, q.start_m, q.goal_m, params.collision_radius_m, config, seed=seed)
        if not plan.ok:
            rows.append({"status": f"plan {plan.status}"})
            continue
        t0 = time.perf_counter()
        ref = time_parameterize(plan.path_m, limits, city, params.collision_radius_m, config.safety_margin_m)
        rows.append(dict(status=ref.status, time_s=time.perf_counter() - t0, duration_s=ref.duration_s,
                         length_m=ref.length_m, path_length_m=plan.length_m, refinements=ref.refinements,
                         stops=ref.stops, min_clearance_m=ref.min_clearance_m,
                         max_speed_m_s=float(np.max(np.linalg.norm(ref.vel_m_s[:, :2], axis=1))),
                         max_accel_m_s2=float(np.max(np.linalg.norm(ref.acc_m_s2[:, :2], axis=1)))))
    good = [r for r in rows if r["status"] == "ok"]
    return {
        "vehicle": vehicle, "limits": dataclasses.asdict(limits), "rows": rows,
        "ok_rate": len(good) / len(rows),
        "timing_time_s_median": float(np.median([r["time_s"] for r in good])) if good else math.nan,
        "mean_speed_m_s_median": float(np.median([r["length_m"] / r["duration_s"] for r in good])) if good else math.nan,
        "refinements_max": max((r["refinements"] for r in good), default=0),
        "stops_total": sum(r["stops"] for r in good),
        "min_clearance_m": min((r["min_clearance_m"] for r in good), default=math.nan),
    }


def measure_mpc(vehicle: str, solver: str, seconds: float = 10.0) -> dict:
    """Closed-loop MPC on the simulator: a 20 m circle at 4 m/s (quad) or 60 m at 8 m/s (UAM).

    Returns solve-time statistics per decision (warm-started; the first, cold solve excluded) and
    the RMS tracking error after 3 s. The MPC is built (and its NLP compiled, once per machine)
    before timing.
    """
    from planners.mpc import MPCConfig, MPCTracker
    from uam_fdm.dynamics import VehicleDynamics
    from uam_fdm.model import hover_state, make_env

    p = load_vehicle(vehicle)
    try:
        mpc = MPCTracker(p, MPCConfig(solver=solver))
    except RuntimeError as exc:   # a solver plugin that cannot handle the problem: report, don't crash
        return {"solver": solver, "error": str(exc).splitlines()[-1][:120]}
    dyn = VehicleDynamics(p, physics_hz=500.0, control_hz=50.0)
    radius, speed = (20.0, 4.0) if p.n_rotors == 4 else (60.0, 8.0)
    w = speed / radius
    n, h = mpc.config.horizon_steps, mpc.config.step_s
    x = hover_state(p, (0.0, 0.0, 30.0))
    env = make_env()
    times, iters, errors = [], [], []
    for k in range(int(seconds * dyn.control_hz)):
        t = k / dyn.control_hz
        ts = t + h * np.arange(n + 1)
        pos = np.stack([radius * np.sin(w * ts), radius * (1 - np.cos(w * ts)), 30.0 + 0 * ts], 1)
        vel = np.stack([speed * np.cos(w * ts), speed * np.sin(w * ts), 0 * ts], 1)
        sol = mpc.solve(x, pos, vel, 0.0, 1.0, elapsed_s=1.0 / dyn.control_hz)
        if k > 0:
            times.append(sol.solve_time_s)
            iters.append(sol.iterations)
        x = dyn.period_rotor(x, sol.rotor_speeds_rad_s, env).final_state
        t1 = t + 1.0 / dyn.control_hz
        if t1 > 3.0:
            errors.append(np.linalg.norm(x[:3] - [radius * np.sin(w * t1), radius * (1 - np.cos(w * t1)), 30.0]))
    times_ms = 1e3 * np.array(times)
    return {"vehicle": vehicle, "solver": mpc.solver_name, "input_mode": mpc.input_mode, "motor_lag": mpc.motor_lag,
            "backend": mpc.backend, "solve_ms_median": float(np.median(times_ms)),
            "solve_ms_p95": float(np.percentile(times_ms, 95)), "solve_ms_max": float(times_ms.max()),
            "iterations_median": float(np.median(iters)), "failures": mpc.n_failures, "solves": mpc.n_solves,
            "rms_error_m": float(np.sqrt(np.mean(np.square(errors)))),
            "control_period_ms": 1e3 / dyn.control_hz}


def _print_planning(res: dict) -> None:
    print(f"{'config':30s} {'iters':>6s} {'1st sol ms':>10s} {'plan s med':>10s} {'plan s max':>10s} "
          f"{'success':>8s} {'efficiency':>10s} {'eff min':>8s} {'min clr m':>9s}")
    for name, f in res["per_config"].items():
        print(f"{name:30s} {f['iterations'] or '-':>6} {f['first_solution_ms_median']:10.1f} "
              f"{f['plan_time_s_median']:10.2f} {f['plan_time_s_max']:10.2f} {f['success_rate']:8.2f} "
              f"{f['path_efficiency']:10.3f} {f['path_efficiency_min']:8.3f} {f['min_clearance_m']:9.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-map", type=int, default=3, help="start/goal queries per shipped map")
    ap.add_argument("--seeds", type=int, default=3, help="seeds per (configuration, query)")
    ap.add_argument("--long-s", type=float, default=15.0, help="time budget of each long reference run [s]")
    ap.add_argument("--variants", action="store_true", help="also measure the non-default variants")
    ap.add_argument("--vehicle", default="small_quad")
    args = ap.parse_args()

    params = load_vehicle(args.vehicle)
    default = PlannerConfig()
    queries = make_queries(args.per_map, params.collision_radius_m, default.safety_margin_m)
    configs = {a: PlannerConfig(algorithm=a) for a in ALGORITHMS}
    if args.variants:
        configs.update(VARIANTS)
    print(f"classical pilot, planning: {len(queries)} queries on {', '.join(MAPS)}, {args.seeds} seeds, "
          f"{args.vehicle} (r = {params.collision_radius_m} m, margin {default.safety_margin_m} m), "
          f"long runs {args.long_s} s; default {default.algorithm} ({default.iteration_budget} iterations); "
          f"{platform.processor() or platform.machine()}, OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}")
    t0 = time.perf_counter()
    plan = measure_planning(configs, queries, params.collision_radius_m, seeds=tuple(range(1, args.seeds + 1)),
                            long_s=args.long_s)
    _print_planning(plan)
    timings = {}
    for vehicle in dict.fromkeys([args.vehicle, "uam_multicopter"]):
        r = load_vehicle(vehicle).collision_radius_m
        timings[vehicle] = t = measure_timing(make_queries(args.per_map, r, default.safety_margin_m), vehicle, default)
        lim = ", ".join(f"{v:.2f}" for v in t["limits"].values())
        print(f"timing law, {vehicle} (limits v_h, v_z, a_h, a_z = {lim}): ok {t['ok_rate']:.2f}, median "
              f"{1e3 * t['timing_time_s_median']:.0f} ms per path, mean speed {t['mean_speed_m_s_median']:.1f} m/s, "
              f"refinements <= {t['refinements_max']}, stops {t['stops_total']}, "
              f"min clearance {t['min_clearance_m']:.2f} m (margin {default.safety_margin_m} m)")
    timing = timings[args.vehicle]

    print("\nMPC, closed loop on the simulator (50 Hz decisions; quad N = 15 x 50 ms, UAM N = 20 x 150 ms), warm solves:")
    print(f"{'vehicle':16s} {'solver':10s} {'inputs':7s} {'lag':4s} {'median ms':>9s} {'p95 ms':>7s} {'max ms':>7s} "
          f"{'iters':>5s} {'fail':>6s} {'RMS m':>6s}")
    mpc_rows = [measure_mpc("small_quad", s) for s in ("ipopt", "sqpmethod", "fatrop")]
    mpc_rows.append(measure_mpc("uam_multicopter", "ipopt"))
    for r in mpc_rows:
        if "error" in r:
            print(f"{'small_quad':16s} {r['solver']:10s} failed to build: {r['error']}")
            continue
        print(f"{r['vehicle']:16s} {r['solver']:10s} {r['input_mode']:7s} {str(r['motor_lag'])[0]:4s} "
              f"{r['solve_ms_median']:9.2f} {r['solve_ms_p95']:7.2f} {r['solve_ms_max']:7.1f} "
              f"{r['iterations_median']:5.0f} {r['failures']:3d}/{r['solves']:<3d} {r['rms_error_m']:6.3f}")
    quad_default = next(r for r in mpc_rows if r.get("vehicle") == "small_quad" and r["solver"] == "ipopt")
    uam = mpc_rows[-1]
    print(f"total {time.perf_counter() - t0:.0f} s")

    d = plan["per_config"][default.algorithm]
    figures = {
        "default_algorithm": default.algorithm,
        "rrt_first_solution_ms_median": d["first_solution_ms_median"],
        "path_efficiency": d["path_efficiency"],
        "plan_time_s_median": d["plan_time_s_median"],
        "success_rate": d["success_rate"],
        "per_algorithm": {k: {kk: v[kk] for kk in ("first_solution_ms_median", "path_efficiency", "success_rate",
                                                   "plan_time_s_median")} for k, v in plan["per_config"].items()},
        "timing_ok_rate": timing["ok_rate"],
        "timing_ms_median": 1e3 * timing["timing_time_s_median"],
        "reference_mean_speed_m_s_median": timing["mean_speed_m_s_median"],
        "reference_min_clearance_m": timing["min_clearance_m"],
        "mpc_solver": quad_default["solver"],
        "mpc_solve_ms_median": quad_default["solve_ms_median"],
        "mpc_solve_ms_p95": quad_default["solve_ms_p95"],
        "mpc_control_period_ms": quad_default["control_period_ms"],
        "mpc_rms_error_m": quad_default["rms_error_m"],
        "mpc_per_solver": {r["solver"]: (r.get("solve_ms_median"), r.get("failures")) for r in mpc_rows[:-1]},
        "mpc_uam_solver": uam.get("solver"),
        "mpc_uam_solve_ms_median": uam.get("solve_ms_median"),
        "mpc_uam_solve_ms_p95": uam.get("solve_ms_p95"),
    }
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
