"""The classical pilot's tracking error per vehicle and air, measured closed loop: the margin table.

Flies `planners.classical_pilot.ClassicalPilot` (fixed margins, no replanning: the tracker as it is) through
the comparison's own runner (`compare.flying.episode_loop.run_episode`, 500 Hz physics, 50 Hz decisions) on
generated cities and legs from the learned pilot's **validation** pool of each vehicle
(`rl.task.vehicles.task_for(vehicle)`, `rl.training.evaluation.eval_config(..., pool="validation")`: city i of the
pool, a leg drawn from the vehicle's task distribution with its own seed, a steady wind up to the
task's maximum). The comparison's scenario sets (`default`, `full`) are the evaluation and are
never flown here. The same cities, legs and winds serve every condition (paired).

At every decision the pilot records its distance to the reference curve (`Reference.deviation_m`)
and the reference's speed; the table holds the percentiles of these distances pooled per (vehicle,
turbulence, air) and per bin of reference speed (`planners.margins.bin_by_speed`), and is
written with its provenance to `planners/data/tracking_error.json` (`--out`), which the classical
pilot reads to size its margins (`planners.margins`). The UAM legs are capped at 600 m (the task
draws up to 1.5 km; the comparison's UAM legs are 250-400 m) to keep the run short.

    # the shipped table:
    OMP_NUM_THREADS=1 python perf/tracking_error.py --jobs 1 --episodes-quad 24 --episodes-uam 12
    # the shipped margins flown on other validation legs: least clearance over the local margin, attempts:
    OMP_NUM_THREADS=1 python perf/tracking_error.py --check --jobs 1 --episodes-quad 12 --episodes-uam 6
    # only the plans at reset on those legs: which step of the planning ladder found each path
    OMP_NUM_THREADS=1 python perf/tracking_error.py --plans-only --episodes-quad 40 --episodes-uam 20

Prints a table and, as its last line, one JSON object of the figures.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from planners.margins import (  # noqa: E402
    DEFAULT_TABLE_PATH,
    MIN_BIN_SAMPLES,
    SPEED_BIN_EDGES,
    TrackingErrorRow,
    bin_by_speed,
    write_tracking_table,
)
from uam_fdm.air.wind import TurbulenceLevel  # noqa: E402
from uam_fdm.episode import Outcome  # noqa: E402

# (name, field elevation [m], ISA offset [K]): sea level, and the full set's hot-and-high field
AIRS = {"sea_level": (0.0, 0.0), "hot_high": (2500.0, 25.0)}
# (vehicle, turbulence, air) measured; the UAM's hot-and-high only where the comparison could need it
CONDITIONS = (("small_quad", "none", "sea_level"), ("small_quad", "light", "sea_level"),
              ("small_quad", "moderate", "sea_level"), ("small_quad", "light", "hot_high"),
              ("small_quad", "moderate", "hot_high"),
              ("uam_multicopter", "none", "sea_level"), ("uam_multicopter", "light", "sea_level"),
              ("uam_multicopter", "moderate", "sea_level"), ("uam_multicopter", "moderate", "hot_high"))
UAM_MAX_LEG_M = 600.0
CHECK_OFFSET = 1000  # --check flies validation cities from this index on (not those the table was built on)


@dataclass(frozen=True)
class Job:
    """One episode: vehicle, condition, index in the validation pool, seed, and the margins to fly."""

    vehicle: str
    turbulence: str
    air: str
    index: int
    seed: int
    adaptive: bool = False


def _validation_task(vehicle: str, index: int, seed: int):
    """City `index` of the vehicle's validation pool, a leg and a steady wind drawn from (seed, index)."""
    from rl.task.vehicles import task_for
    from rl.training.evaluation import eval_config
    from uam_fdm.vehicle.params import load_vehicle

    nav = eval_config(task_for(vehicle), index + 1, pool="validation")
    tasks = nav.tasks
    if vehicle == "uam_multicopter":
        tasks = dataclasses.replace(tasks, distance_m=(tasks.distance_m[0], min(tasks.distance_m[1], UAM_MAX_LEG_M)))
    city_seed = nav.city_seeds()[index]
    city = nav.cities.city(city_seed)
    p = load_vehicle(vehicle)
    rng = np.random.default_rng([seed, index, 0x7E])
    task = tasks.sample(city, rng, p.collision_radius_m, p.controller.max_speed_m_s,
                        max_vertical_speed_m_s=p.controller.max_vertical_speed_m_s)
    speed, heading = rng.uniform(0.0, nav.air.steady_wind_max_m_s), rng.uniform(-math.pi, math.pi)
    return p, city, city_seed, task, (speed * math.cos(heading), speed * math.sin(heading), 0.0)


_PILOTS: dict = {}


def fly(job: Job) -> dict:
    """Fly one episode; its deviations from the reference and its outcome."""
    from compare.flying.episode_loop import run_episode
    from compare.flying.promise import scored_report
    from planners.classical_pilot import ClassicalConfig, ClassicalPilot
    from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions
    from uam_fdm.air.wind import WindConditions, WindField, probe_heights_up_to
    from uam_fdm.pilot import World
    from uam_fdm.vehicle.dynamics import VehicleDynamics

    p, city, city_seed, task, steady = _validation_task(job.vehicle, job.index, job.seed)
    key = (job.vehicle, job.adaptive)
    if key not in _PILOTS:
        cfg = (ClassicalConfig() if job.adaptive else
               ClassicalConfig(margin_rule=None, replan_error_m=None, replan_on_clearance=False))
        _PILOTS[key] = (ClassicalPilot(cfg), VehicleDynamics(p, 500.0, 50.0))
    pilot, dyn = _PILOTS[key]
    elevation, offset = AIRS[job.air]
    top = float(city.bounds_max_m[2]) + 100.0
    atm = Atmosphere.from_jsbsim(AtmosphereConditions(elevation, offset), z_max_m=top, z_min_m=-50.0)
    world = World(p, dyn, city, atm, TurbulenceLevel.parse(job.turbulence))
    conditions = WindConditions(steady, job.turbulence)
    airspeed = float(np.clip(max(p.controller.max_speed_m_s, np.linalg.norm(steady)), 1.0, 100.0))
    wind = WindField.from_conditions(conditions, job.seed * 100_003 + job.index, task.timeout_s + 1.0, airspeed,
                                     probe_heights_up_to(float(city.bounds_max_m[2])))
    t0 = time.perf_counter()
    traj = run_episode(world, pilot, task, wind, seed=job.seed + job.index)
    rep = scored_report(pilot, traj)  # its promise measured on the truth
    return {"job": dataclasses.asdict(job), "city_seed": city_seed, "outcome": traj.outcome,
            "deviations_m": np.asarray(pilot.stats.deviations_m, float),
            "reference_speeds_m_s": np.asarray(pilot.stats.reference_speeds_m_s, float),
            "max_speed_m_s": float(p.controller.max_speed_m_s),
            "local_margin_ratio": rep.clearance_over_margin_min, "planner_attempts": rep.planner_attempts,
            "planner_margin_floor_m": rep.planner_margin_floor_m,
            "min_clearance_m": float(np.nanmin(traj.clearance_m)), "flight_s": float(traj.t_s[-1]),
            "wall_s": time.perf_counter() - t0, "planner_margin_m": rep.planner_margin_m,
            "mpc_margin_m": rep.mpc_margin_m, "replans": rep.replans, "mpc_failures": rep.mpc_failures}


def table_rows(results: list[dict]) -> list[TrackingErrorRow]:
    """Pooled percentiles per (vehicle, turbulence, air)."""
    from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions
    from uam_fdm.vehicle.params import load_vehicle

    rows = []
    for vehicle, turbulence, air in CONDITIONS:
        mine = [r for r in results if (r["job"]["vehicle"], r["job"]["turbulence"], r["job"]["air"])
                == (vehicle, turbulence, air) and r["outcome"] != Outcome.PLANNER_FAILURE]
        if not mine:
            continue
        dev = np.concatenate([r["deviations_m"] for r in mine])
        speeds = np.concatenate([r["reference_speeds_m_s"] for r in mine])
        elevation, offset = AIRS[air]
        sigma = Atmosphere.from_jsbsim(AtmosphereConditions(elevation, offset), z_max_m=50.0,
                                       z_min_m=0.0).density_ratio(0.0)
        p50, p95, p99 = np.percentile(dev, [50, 95, 99])
        rows.append(TrackingErrorRow(vehicle, load_vehicle(vehicle).fingerprint(), TurbulenceLevel.parse(turbulence),
                                     float(sigma), len(mine), int(dev.size), float(p50), float(p95), float(p99),
                                     float(dev.max()), bin_by_speed(dev, speeds, mine[0]["max_speed_m_s"])))
    return rows


def plan_only(job: Job) -> dict:
    """Only the shipped pilot's plan at reset (margins by speed, the planning ladder) for one validation leg:
    which step found the path (deterministic; the plan time is wall time)."""
    from planners.classical_pilot import ClassicalPilot
    from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions
    from uam_fdm.air.wind import TurbulenceLevel
    from uam_fdm.pilot import World
    from uam_fdm.vehicle.dynamics import VehicleDynamics

    p, city, city_seed, task, _ = _validation_task(job.vehicle, job.index, job.seed)
    key = (job.vehicle, "plan")
    if key not in _PILOTS:
        _PILOTS[key] = (ClassicalPilot(), VehicleDynamics(p, 500.0, 50.0))
    pilot, dyn = _PILOTS[key]
    elevation, offset = AIRS[job.air]
    atm = Atmosphere.from_jsbsim(AtmosphereConditions(elevation, offset), z_max_m=float(city.bounds_max_m[2]) + 100.0,
                                 z_min_m=-50.0)
    info = pilot.reset(World(p, dyn, city, atm, TurbulenceLevel.parse(job.turbulence)), task, job.seed + job.index)
    rep = pilot.episode_report()
    return {"job": dataclasses.asdict(job), "city_seed": city_seed, "ok": info.ok, "status": info.status,
            "detail": info.detail, "plan_time_s": info.plan_time_s, "attempts": rep.planner_attempts,
            "step": rep.planner_step}


def plans_main(jobs: list[Job]) -> None:
    """`--plans-only`: the ladder's steps per condition, printed, and the last JSON line."""
    results = [plan_only(j) for j in jobs]
    figures: dict = {}
    print(f"{'vehicle':16s} {'turb':8s} {'air':9s} {'legs':>4s} {'ok':>3s} attempts (1/2/3/4)  plan s median / max")
    for vehicle, turbulence, air in CONDITIONS:
        mine = [r for r in results if (r["job"]["vehicle"], r["job"]["turbulence"], r["job"]["air"])
                == (vehicle, turbulence, air)]
        if not mine:
            continue
        counts = [sum(r["attempts"] == k and r["ok"] for r in mine) for k in (1, 2, 3, 4)]
        times = np.array([r["plan_time_s"] for r in mine])
        figures[f"{vehicle}/{turbulence}/{air}"] = {
            "legs": len(mine), "ok": sum(r["ok"] for r in mine), "found_by_step": counts,
            "failures": [r["detail"] for r in mine if not r["ok"]],
            "plan_time_s_median": float(np.median(times)), "plan_time_s_max": float(times.max())}
        print(f"{vehicle:16s} {turbulence:8s} {air:9s} {len(mine):4d} {sum(r['ok'] for r in mine):3d} "
              f"{'/'.join(map(str, counts)):18s} {np.median(times):6.2f} / {times.max():6.2f}", flush=True)
    print(json.dumps(figures, default=float))


def run(jobs: list[Job], workers: int) -> list[dict]:
    if workers <= 1:
        return [fly(j) for j in jobs]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(fly, jobs, chunksize=1))


def _mode(args: argparse.Namespace) -> str:
    if args.plans_only:
        return "plans of the shipped pilot"
    return "check of the shipped margins" if args.check else "fixed margins, no replanning"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes-quad", type=int, default=16, help="validation episodes per small_quad condition")
    ap.add_argument("--episodes-uam", type=int, default=8, help="validation episodes per uam_multicopter condition")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", default=str(DEFAULT_TABLE_PATH), help="the table file to write")
    ap.add_argument("--plans-only", action="store_true",
                    help="only the shipped pilot's plans at reset on other validation legs (which ladder step)")
    ap.add_argument("--check", action="store_true",
                    help="fly the shipped margins (adaptive, replanning on) on other validation legs instead")
    args = ap.parse_args()
    t0 = time.perf_counter()
    print(f"tracking error, classical pilot; {platform.processor() or platform.machine()}, "
          f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}, load average {os.getloadavg()[0]:.2f}, "
          f"{_mode(args)}", flush=True)
    n = {"small_quad": args.episodes_quad, "uam_multicopter": args.episodes_uam}
    first = CHECK_OFFSET if args.check or args.plans_only else 0
    jobs = [Job(v, t, a, first + i, args.seed, args.check) for v, t, a in CONDITIONS for i in range(n[v])]
    if args.plans_only:
        plans_main(jobs)
        return
    results = run(jobs, args.jobs)
    print(f"{'vehicle':16s} {'turb':8s} {'air':9s} {'eps':>4s} {'ok':>3s} {'p50 m':>7s} {'p95 m':>7s} {'p99 m':>7s} "
          f"{'max m':>7s} {'margin m':>10s} {'min clr m':>9s} {'/local M':>8s} {'replans':>7s} {'wall s':>7s}")
    figures: dict = {"conditions": {}}
    for vehicle, turbulence, air in CONDITIONS:
        mine = [r for r in results if (r["job"]["vehicle"], r["job"]["turbulence"], r["job"]["air"])
                == (vehicle, turbulence, air)]
        if not mine:
            continue
        dev = np.concatenate([r["deviations_m"] for r in mine])
        q = np.percentile(dev, [50, 95, 99])
        ok = sum(r["outcome"] == Outcome.SUCCESS for r in mine)
        # the clearance figure that matters: least clearance over half the margin flown, per episode
        ratio = min(r["min_clearance_m"] / r["planner_margin_m"] for r in mine)
        key = f"{vehicle}/{turbulence}/{air}"
        figures["conditions"][key] = {
            "episodes": len(mine), "successes": ok, "p50_m": q[0], "p95_m": q[1], "p99_m": q[2],
            "max_m": float(dev.max()),
            "planner_margin_m": mine[0]["planner_margin_m"], "min_clearance_m": min(r["min_clearance_m"] for r in mine),
            "min_clearance_over_margin": ratio, "replans": sum(r["replans"] for r in mine),
            # the promise with margins that follow the speed: clearance over the margin in force, per decision
            "min_clearance_over_local_margin": min(r["local_margin_ratio"] for r in mine),
            "planner_margin_floor_m": mine[0]["planner_margin_floor_m"],
            "planner_attempts_max": max(r["planner_attempts"] for r in mine),
            "mpc_failures": sum(r["mpc_failures"] for r in mine), "outcomes": sorted({r["outcome"] for r in mine})}
        print(f"{vehicle:16s} {turbulence:8s} {air:9s} {len(mine):4d} {ok:3d} {q[0]:7.3f} {q[1]:7.3f} {q[2]:7.3f} "
              f"{dev.max():7.3f} {mine[0]['planner_margin_floor_m']:4.2f}-{mine[0]['planner_margin_m']:5.2f} "
              f"{figures['conditions'][key]['min_clearance_m']:9.3f} "
              f"{figures['conditions'][key]['min_clearance_over_local_margin']:8.2f} "
              f"{figures['conditions'][key]['replans']:7d} {sum(r['wall_s'] for r in mine):7.0f}", flush=True)
    if not args.check:
        provenance = {
            "command": "OMP_NUM_THREADS=1 python " + " ".join(["perf/tracking_error.py", *sys.argv[1:]]),
            "pool": "validation (rl.training.evaluation.eval_config(task_for(vehicle), n, pool='validation'): cities "
                    "1,050,000 on of rl.task.cities.EVAL_SEEDS), never the comparison's scenario sets",
            "seed": args.seed, "episodes": n, "uam_max_leg_m": UAM_MAX_LEG_M,
            "pilot": "planners.classical_pilot.ClassicalPilot(margin_rule=None, replan_error_m=None, "
                     "replan_on_clearance=False): fixed 1 m planner / 0.5 m MPC margins, no replanning",
            "statistic": "distance from the vehicle to its reference curve at each 50 Hz decision "
                         "(planners.timing.Reference.deviation_m), pooled over the episodes' decisions; "
                         "speed_bins: the same per bin of the reference's speed at the decision "
                         "(planners.margins.bin_by_speed: edges at shares "
                         f"{list(SPEED_BIN_EDGES)} of the vehicle's speed cap, bins under "
                         f"{MIN_BIN_SAMPLES} decisions merged into the next faster)",
            "airs": {k: {"elevation_m": v[0], "isa_offset_k": v[1]} for k, v in AIRS.items()},
            "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        }
        rows = table_rows(results)
        path = write_tracking_table(rows, provenance, args.out)
        print(f"wrote {path}")
        print("by reference speed: vehicle turbulence sigma | speed range [m/s]: samples, p99 [m]")
        for row in rows:
            bins = "; ".join(f"{b.speed_lo_m_s:.1f}-{b.speed_hi_m_s:.1f}: {b.samples}, {b.p99_m:.3f}"
                             for b in row.speed_bins)
            print(f"{row.vehicle:16s} {row.turbulence.value:8s} {row.density_ratio:.3f} | {bins}")
            key = f"{row.vehicle}/{row.turbulence.value}/{row.density_ratio:.4f}"
            figures.setdefault("speed_bins", {})[key] = [dataclasses.asdict(b) for b in row.speed_bins]
    figures["total_s"] = time.perf_counter() - t0
    print(f"total {figures['total_s']:.0f} s, load average {os.getloadavg()[0]:.2f}")
    print(json.dumps(figures, default=float))


if __name__ == "__main__":
    main()
