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
The MPC is flown closed loop on the simulator (`MPC_EPISODES`: circle, line, wall) for both
vehicles with Ipopt (the reference) and the fast solver (`--mpc-solver`, default the real-time
iteration), on the same episodes: solve ms median/p95 per decision, iterations, failures, RMS
tracking error, and the ratios to Ipopt.

    OMP_NUM_THREADS=1 flock /tmp/uam_cpu.lock python perf/classical.py [--long-s 15] [--variants]
    OMP_NUM_THREADS=1 python perf/classical.py --mpc-only [--mpc-extra fatrop,sqpmethod]
    OMP_NUM_THREADS=1 python perf/classical.py --pilot-plans-only   # plan time per plan, both vehicles

The pilot's plans (`measure_pilot_plans`): `ClassicalPilot.reset` on the same kind of queries for
both vehicles, at sea level in calm air and hot and high (2500 m, ISA+25 K) in moderate
turbulence, i.e. with the margins by speed and the escalation ladder: `plan_time_s_median`,
`plan_time_s_p95` (the worse vehicle's), per vehicle under `pilot_plans`.

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
from uam_fdm.city.buildings import BuildingMap  # noqa: E402
from uam_fdm.city.mapfile import load_named_map  # noqa: E402
from uam_fdm.vehicle.params import load_vehicle  # noqa: E402

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
        "mean_speed_m_s_median": (float(np.median([r["length_m"] / r["duration_s"] for r in good])) if good
                                  else math.nan),
        "refinements_max": max((r["refinements"] for r in good), default=0),
        "stops_total": sum(r["stops"] for r in good),
        "min_clearance_m": min((r["min_clearance_m"] for r in good), default=math.nan),
    }


# (name, field elevation [m], ISA offset [K], forecast turbulence) for the pilot's plans
PILOT_AIRS = (("sea_level", 0.0, 0.0, "none"), ("hot_high", 2500.0, 25.0, "moderate"))


def measure_pilot_plans(vehicle: str, per_map: int, seeds: Sequence[int]) -> dict:
    """The classical pilot's planning as it flies: `ClassicalPilot.reset` (margins by speed from the
    table, the escalation ladder of `planners.ladder`) per query, air and seed; its plan time per plan
    (the ladder's attempts together), the step that found each path and the failures."""
    from planners.classical_pilot import ClassicalPilot
    from rl.task.vehicles import task_for
    from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions
    from uam_fdm.pilot import Task, World
    from uam_fdm.vehicle.dynamics import VehicleDynamics

    params = load_vehicle(vehicle)
    nav = task_for(vehicle).tasks
    pilot, dynamics = ClassicalPilot(), VehicleDynamics(params, 500.0, 50.0)
    queries = make_queries(per_map, params.collision_radius_m, 1.0)
    rows = []
    for air, elevation, offset, turbulence in PILOT_AIRS:
        for q in queries:
            city = _map(q.map_name)
            atm = Atmosphere.from_jsbsim(AtmosphereConditions(elevation, offset),
                                         z_max_m=float(city.bounds_max_m[2]) + 100.0, z_min_m=-50.0)
            world = World(params, dynamics, city, atm, turbulence)
            # the time limit the comparison's generated tasks get (`compare.scenarios.benchmark`): the pilot's
            # ladder climbs on past a plan that does not fit it (a default 120 s made these cross-map legs late
            # everywhere)
            limit = nav.timeout_s(math.dist(q.start_m, q.goal_m), q.goal_m[2] - q.start_m[2],
                                  params.controller.max_speed_m_s, params.controller.max_vertical_speed_m_s)
            task = Task(start_m=q.start_m, goal_m=q.goal_m, timeout_s=limit)
            for seed in seeds:
                info = pilot.reset(world, task, seed)
                rep = pilot.episode_report()
                rows.append(dict(air=air, map=q.map_name, seed=seed, ok=info.ok, plan_time_s=info.plan_time_s,
                                 attempts=rep.planner_attempts, step=rep.planner_step,
                                 margin_m=rep.planner_margin_m, floor_m=rep.planner_margin_floor_m))
    times = np.array([r["plan_time_s"] for r in rows])
    return {"vehicle": vehicle, "plans": len(rows), "failures": sum(not r["ok"] for r in rows),
            "plan_time_s_median": float(np.median(times)), "plan_time_s_p95": float(np.percentile(times, 95)),
            "plan_time_s_max": float(times.max()),
            "attempts": {str(k): sum(r["attempts"] == k for r in rows) for k in sorted({r["attempts"] for r in rows})},
            "rows": rows}


def pilot_plan_figures(per_map: int, seeds: int) -> dict:
    """`measure_pilot_plans` for both vehicles, printed; the JSON keys: `plan_time_s_median` and
    `plan_time_s_p95` of the worse vehicle (targets: <= 1 s and <= 3 s for both), `pilot_plans` per vehicle."""
    pilot = {v: measure_pilot_plans(v, per_map, tuple(range(1, seeds + 1))) for v in ("small_quad", "uam_multicopter")}
    for v, res in pilot.items():
        print(f"pilot plans, {v}: {res['plans']} plans, {res['failures']} failures, plan time median "
              f"{res['plan_time_s_median']:.2f} s, p95 {res['plan_time_s_p95']:.2f} s, max "
              f"{res['plan_time_s_max']:.2f} s; attempts {res['attempts']}")
    return {"plan_time_s_median": max(r["plan_time_s_median"] for r in pilot.values()),
            "plan_time_s_p95": max(r["plan_time_s_p95"] for r in pilot.values()),
            "pilot_plans": {v: {k: x for k, x in r.items() if k != "rows"} for v, r in pilot.items()}}


@dataclass(frozen=True)
class MPCEpisode:
    """A closed-loop MPC episode on the simulator: a reference (and optionally a wall) from hover at 30 m."""

    name: str
    seconds: float


MPC_EPISODES = (MPCEpisode("circle", 10.0), MPCEpisode("line", 8.0), MPCEpisode("wall", 6.0))


def _mpc_reference(episode: str, n_rotors: int, ts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference position and velocity (len(ts), 3) [m, m/s], world ENU, at times ts [s]."""
    quad = n_rotors == 4
    if episode == "circle":   # 20 m at 4 m/s (quad) or 60 m at 8 m/s (UAM), entered at full speed from hover
        radius, speed = (20.0, 4.0) if quad else (60.0, 8.0)
        w = speed / radius
        return (np.stack([radius * np.sin(w * ts), radius * (1 - np.cos(w * ts)), 30.0 + 0 * ts], 1),
                np.stack([speed * np.cos(w * ts), speed * np.sin(w * ts), 0 * ts], 1))
    if episode == "line":     # along (1, 0.5, 0.2), accelerating from rest to 5 m/s (quad) or 8 m/s (UAM)
        speed, accel = (5.0, 3.0) if quad else (8.0, 1.0)
        direction = np.array([1.0, 0.5, 0.2]) / np.linalg.norm([1.0, 0.5, 0.2])
        t_acc = speed / accel
        s = np.where(ts < t_acc, 0.5 * accel * ts ** 2, 0.5 * speed * t_acc + speed * (ts - t_acc))
        v = np.where(ts < t_acc, accel * ts, speed)
        return np.outer(s, direction) + [0.0, 0.0, 30.0], np.outer(v, direction)
    # wall: a fixed target 2 d ahead behind a wall at x = d (d = 5 m quad, 15 m UAM): the half-space is active
    d = 5.0 if quad else 15.0
    return np.tile([2 * d, 0.0, 30.0], (len(ts), 1)), np.zeros((len(ts), 3))


def measure_mpc(vehicle: str, solver: str, episode: MPCEpisode) -> dict:
    """One closed-loop MPC episode on the simulator (50 Hz decisions, 500 Hz physics, calm air).

    Returns solve-time statistics per decision (warm-started; the first, cold solve excluded),
    iterations, failures and the RMS tracking error after 3 s (circle, line) or the largest
    penetration of the wall's keep-out plane (wall). The MPC is built (and compiled, once per
    machine) before timing.
    """
    from planners.mpc import MPCConfig, MPCTracker
    from uam_fdm.vehicle.dynamics import VehicleDynamics
    from uam_fdm.vehicle.model import hover_state, make_env

    p = load_vehicle(vehicle)
    name, _, qp_solver = solver.partition(":")   # "rti:hpipm_conic": the RTI with another QP solver
    try:
        mpc = MPCTracker(p, MPCConfig(solver=name, qp_solver=qp_solver or None))
    except RuntimeError as exc:   # a solver plugin that cannot handle the problem: report, don't crash
        return {"vehicle": vehicle, "solver": solver, "episode": episode.name, "error": str(exc).splitlines()[-1][:120]}
    dyn = VehicleDynamics(p, physics_hz=500.0, control_hz=50.0)
    n, k, h = mpc.config.horizon_steps, mpc.config.n_halfspaces, mpc.config.step_s
    normals, offsets, wall_limit = None, None, math.inf
    if episode.name == "wall":
        d = 5.0 if p.n_rotors == 4 else 15.0
        wall_limit = d - p.collision_radius_m - mpc.config.clearance_margin_m
        normals = np.zeros((n, k, 3))
        offsets = np.full((n, k), -1.0)
        normals[:, 0] = (-1.0, 0.0, 0.0)
        offsets[:, 0] = -wall_limit
    x = hover_state(p, (0.0, 0.0, 30.0))
    env = make_env()
    times, iters, qp_iters, errors, overshoot = [], [], [], [], -math.inf
    for step in range(int(episode.seconds * dyn.control_hz)):
        t = step / dyn.control_hz
        pos, vel = _mpc_reference(episode.name, p.n_rotors, t + h * np.arange(n + 1))
        sol = mpc.solve(x, pos, vel, 0.0, 1.0, normals, offsets, elapsed_s=1.0 / dyn.control_hz)
        if step > 0:
            times.append(sol.solve_time_s)
            iters.append(sol.iterations)
            qp_iters.append(sol.qp_iterations)
        x = dyn.period_rotor(x, sol.rotor_speeds_rad_s, env).final_state
        t1 = t + 1.0 / dyn.control_hz
        overshoot = max(overshoot, x[0] - wall_limit)
        if t1 > 3.0:
            errors.append(np.linalg.norm(x[:3] - _mpc_reference(episode.name, p.n_rotors, np.array([t1]))[0][0]))
    times_ms = 1e3 * np.array(times)
    return {"vehicle": vehicle, "solver": solver, "qp_solver": mpc.qp_solver, "episode": episode.name,
            "input_mode": mpc.input_mode,
            "motor_lag": mpc.motor_lag, "backend": mpc.backend, "solve_ms_median": float(np.median(times_ms)),
            "solve_ms_p95": float(np.percentile(times_ms, 95)), "solve_ms_max": float(times_ms.max()),
            "iterations_median": float(np.median(iters)), "qp_iterations_median": float(np.median(qp_iters)),
            "qp_iterations_p95": float(np.percentile(qp_iters, 95)), "failures": mpc.n_failures,
            "solves": mpc.n_solves, "rms_error_m": float(np.sqrt(np.mean(np.square(errors)))),
            "wall_overshoot_m": float(overshoot) if episode.name == "wall" else None,
            "control_period_ms": 1e3 / dyn.control_hz, "times_ms": times_ms}


def summarize_mpc(rows: list[dict], vehicle: str, solver: str) -> dict:
    """Pooled figures of one (vehicle, solver) over the episodes: solve ms median/p95 over all
    decisions, failures, and RMS error per episode."""
    mine = [r for r in rows if r["vehicle"] == vehicle and r["solver"] == solver and "error" not in r]
    if not mine:
        return {}
    times = np.concatenate([r["times_ms"] for r in mine])
    return {"solve_ms_median": float(np.median(times)), "solve_ms_p95": float(np.percentile(times, 95)),
            "solve_ms_max": float(times.max()), "failures": sum(r["failures"] for r in mine),
            "solves": sum(r["solves"] for r in mine), "control_period_ms": mine[0]["control_period_ms"],
            "rms_error_m": {r["episode"]: r["rms_error_m"] for r in mine}}


def run_mpc_benchmark(vehicles: Sequence[str], solvers: Sequence[str]) -> list[dict]:
    """Every (vehicle, solver, episode) of `MPC_EPISODES`, printed as a table as it goes."""
    print("\nMPC, closed loop on the simulator (50 Hz decisions, 500 Hz physics, calm air; quad N = 15 x 50 ms, "
          "UAM N = 20 x 150 ms), warm solves; iterations: solver (QP median/p95 for rti); RMS error after 3 s; "
          "over: the wall episode's largest overshoot of its keep-out plane")
    print(f"{'vehicle':16s} {'solver':16s} {'episode':7s} {'inputs':7s} {'lag':4s} {'median ms':>9s} {'p95 ms':>7s} "
          f"{'max ms':>7s} {'iters':>9s} {'fail':>7s} {'RMS m':>7s} {'over m':>7s}")
    rows = []
    for vehicle in vehicles:
        for solver in solvers:
            for episode in MPC_EPISODES:
                r = measure_mpc(vehicle, solver, episode)
                rows.append(r)
                if "error" in r:
                    print(f"{vehicle:16s} {solver:10s} failed to build: {r['error']}")
                    break
                over = "" if r["wall_overshoot_m"] is None else f"{r['wall_overshoot_m']:7.3f}"
                its = f"{r['iterations_median']:.0f}" + (f" ({r['qp_iterations_median']:.0f}/"
                                                         f"{r['qp_iterations_p95']:.0f})"
                                                         if r["qp_iterations_median"] >= 0 else "")
                print(f"{vehicle:16s} {solver:16s} {episode.name:7s} {r['input_mode']:7s} {str(r['motor_lag'])[0]:4s} "
                      f"{r['solve_ms_median']:9.2f} {r['solve_ms_p95']:7.2f} {r['solve_ms_max']:7.1f} {its:>9s} "
                      f"{r['failures']:3d}/{r['solves']:<3d} {r['rms_error_m']:7.4f} {over}", flush=True)
    return rows


def _print_planning(res: dict) -> None:
    print(f"{'config':30s} {'iters':>6s} {'1st sol ms':>10s} {'plan s med':>10s} {'plan s max':>10s} "
          f"{'success':>8s} {'efficiency':>10s} {'eff min':>8s} {'min clr m':>9s}")
    for name, f in res["per_config"].items():
        print(f"{name:30s} {f['iterations'] or '-':>6} {f['first_solution_ms_median']:10.1f} "
              f"{f['plan_time_s_median']:10.2f} {f['plan_time_s_max']:10.2f} {f['success_rate']:8.2f} "
              f"{f['path_efficiency']:10.3f} {f['path_efficiency_min']:8.3f} {f['min_clearance_m']:9.2f}")


def mpc_figures(rows: list[dict], fast: str, reference: str = "ipopt", others: Sequence[str] = ()) -> dict:
    """The MPC figures of the JSON line: the fast solver's, its ratios to the reference's on the same
    episodes, and its speed-up over each of `others` (e.g. "rti:hpipm_conic")."""
    out: dict = {"mpc_solver": fast, "mpc_reference_solver": reference}
    for vehicle, prefix in (("small_quad", "mpc"), ("uam_multicopter", "uam_mpc")):
        f, r = summarize_mpc(rows, vehicle, fast), summarize_mpc(rows, vehicle, reference)
        if not f:
            continue
        out.update({f"{prefix}_solve_ms_median": f["solve_ms_median"], f"{prefix}_solve_ms_p95": f["solve_ms_p95"],
                    f"{prefix}_solve_ms_max": f["solve_ms_max"], f"{prefix}_control_period_ms": f["control_period_ms"],
                    f"{prefix}_failures": f["failures"], f"{prefix}_solves": f["solves"],
                    f"{prefix}_rms_error_m": f["rms_error_m"]})
        if r:
            out.update({f"{prefix}_reference_solve_ms_median": r["solve_ms_median"],
                        f"{prefix}_reference_solve_ms_p95": r["solve_ms_p95"],
                        f"{prefix}_reference_failures": r["failures"],
                        f"{prefix}_reference_rms_error_m": r["rms_error_m"],
                        f"{prefix}_speedup_vs_{reference}": r["solve_ms_median"] / f["solve_ms_median"],
                        f"{prefix}_rms_ratio_vs_{reference}": {e: f["rms_error_m"][e] / r["rms_error_m"][e]
                                                                for e in f["rms_error_m"] if e in r["rms_error_m"]}})
        for other in others:
            o = summarize_mpc(rows, vehicle, other)
            if o:
                key = other.replace(":", "_")
                out[f"{prefix}_speedup_vs_{key}"] = o["solve_ms_median"] / f["solve_ms_median"]
                out[f"{prefix}_rms_ratio_vs_{key}"] = {e: f["rms_error_m"][e] / o["rms_error_m"][e]
                                                       for e in f["rms_error_m"] if e in o["rms_error_m"]}
    return out


def _print_mpc_ratios(figures: dict, fast: str, reference: str) -> None:
    for prefix, label in (("mpc", "small_quad"), ("uam_mpc", "uam_multicopter")):
        if f"{prefix}_speedup_vs_{reference}" not in figures:
            continue
        ratios = ", ".join(f"{e} {v:.2f}" for e, v in figures[f"{prefix}_rms_ratio_vs_{reference}"].items())
        print(f"{label}: {fast} median {figures[f'{prefix}_solve_ms_median']:.2f} ms, p95 "
              f"{figures[f'{prefix}_solve_ms_p95']:.2f} ms (period {figures[f'{prefix}_control_period_ms']:.0f} ms), "
              f"{figures[f'{prefix}_failures']} failures / {figures[f'{prefix}_solves']}; speed-up vs {reference} "
              f"x{figures[f'{prefix}_speedup_vs_{reference}']:.1f}; RMS ratio to {reference}: {ratios}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-map", type=int, default=3, help="start/goal queries per shipped map")
    ap.add_argument("--seeds", type=int, default=3, help="seeds per (configuration, query)")
    ap.add_argument("--long-s", type=float, default=15.0, help="time budget of each long reference run [s]")
    ap.add_argument("--variants", action="store_true", help="also measure the non-default variants")
    ap.add_argument("--vehicle", default="small_quad")
    ap.add_argument("--mpc-only", action="store_true", help="skip planning and timing; only the MPC closed loop")
    ap.add_argument("--pilot-plans-only", action="store_true",
                    help="only the pilot's plans (plan time per plan for both vehicles)")
    ap.add_argument("--mpc-solver", default="rti", help="the fast MPC solver whose figures the JSON line reports")
    ap.add_argument("--mpc-extra", default="rti:hpipm_conic",
                    help="comma-separated further MPC solvers to measure, SOLVER[:QP_SOLVER] (fatrop, sqpmethod, "
                         "rti:hpipm_conic: the RTI with HPIPM through casadi.conic; '' for none)")
    args = ap.parse_args()

    params = load_vehicle(args.vehicle)
    default = PlannerConfig()
    t0 = time.perf_counter()
    figures: dict = {}
    print(f"classical pilot; {platform.processor() or platform.machine()}, "
          f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}, load average {os.getloadavg()[0]:.2f}")
    if args.pilot_plans_only:
        print(json.dumps(pilot_plan_figures(args.per_map, args.seeds)))
        return
    if not args.mpc_only:
        queries = make_queries(args.per_map, params.collision_radius_m, default.safety_margin_m)
        configs = {a: PlannerConfig(algorithm=a) for a in ALGORITHMS}
        if args.variants:
            configs.update(VARIANTS)
        print(f"planning: {len(queries)} queries on {', '.join(MAPS)}, {args.seeds} seeds, "
              f"{args.vehicle} (r = {params.collision_radius_m} m, margin {default.safety_margin_m} m), "
              f"long runs {args.long_s} s; default {default.algorithm} ({default.iteration_budget} iterations)")
        plan = measure_planning(configs, queries, params.collision_radius_m, seeds=tuple(range(1, args.seeds + 1)),
                                long_s=args.long_s)
        _print_planning(plan)
        timings = {}
        for vehicle in dict.fromkeys([args.vehicle, "uam_multicopter"]):
            r = load_vehicle(vehicle).collision_radius_m
            timings[vehicle] = t = measure_timing(make_queries(args.per_map, r, default.safety_margin_m), vehicle,
                                                  default)
            lim = ", ".join(f"{v:.2f}" for v in t["limits"].values())
            print(f"timing law, {vehicle} (limits v_h, v_z, a_h, a_z = {lim}): ok {t['ok_rate']:.2f}, median "
                  f"{1e3 * t['timing_time_s_median']:.0f} ms per path, mean speed {t['mean_speed_m_s_median']:.1f} "
                  f"m/s, refinements <= {t['refinements_max']}, stops {t['stops_total']}, "
                  f"min clearance {t['min_clearance_m']:.2f} m (margin {default.safety_margin_m} m)")
        timing = timings[args.vehicle]
        d = plan["per_config"][default.algorithm]
        figures.update({
            "default_algorithm": default.algorithm,
            "rrt_first_solution_ms_median": d["first_solution_ms_median"],
            "path_efficiency": d["path_efficiency"],
            "rrt_plan_time_s_median": d["plan_time_s_median"],
            "success_rate": d["success_rate"],
            "per_algorithm": {k: {kk: v[kk] for kk in ("first_solution_ms_median", "path_efficiency", "success_rate",
                                                       "plan_time_s_median")} for k, v in plan["per_config"].items()},
            "timing_ok_rate": timing["ok_rate"],
            "timing_ms_median": 1e3 * timing["timing_time_s_median"],
            "reference_mean_speed_m_s_median": timing["mean_speed_m_s_median"],
            "reference_min_clearance_m": timing["min_clearance_m"],
        })
        # the pilot's plans as it flies them (margins by speed, escalation ladder): per plan, both vehicles
        figures.update(pilot_plan_figures(args.per_map, args.seeds))

    solvers = list(dict.fromkeys(["ipopt", args.mpc_solver, *[s for s in args.mpc_extra.split(",") if s]]))
    rows = run_mpc_benchmark(["small_quad", "uam_multicopter"], solvers)
    others = [s for s in solvers if s not in ("ipopt", args.mpc_solver)]
    figures.update(mpc_figures(rows, args.mpc_solver, others=others))
    figures["mpc_per_solver"] = {f"{v}/{s}": summarize_mpc(rows, v, s) for v in ("small_quad", "uam_multicopter")
                                 for s in solvers}
    _print_mpc_ratios(figures, args.mpc_solver, "ipopt")
    print(f"total {time.perf_counter() - t0:.0f} s, load average {os.getloadavg()[0]:.2f}")
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
