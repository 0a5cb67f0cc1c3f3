"""The classical pilot's planning candidates, measured on the benchmark's validation twin.

For every leg of `benchmark-perfect-validation` (the test set's design on other cities:
`compare.scenarios.benchmark`), the pilot's plan at reset (`ClassicalPilot.reset`: margins for the scenario's air
and turbulence, the planning ladder, the reference timed as it will be flown) under each variant of the ladder,
paired by leg:

* `single`: every step one seed with its whole budget, no time fit (the pilot before candidates);
* `shipped`: `planners.ladder.LADDER` and `ClassicalConfig.time_fraction` as shipped (two seeds sharing RRT*'s
  budget, RRTConnect's first path four times, the fastest flown, a plan that does not fit 80 % of the time climbs on);
* `whole`: as shipped, but each of RRT*'s two seeds gets the whole budget (twice the plan time).

The figure of merit is the reference's flight time (what the tracker is asked to take), the plan time and the legs
whose plan takes more than 80 % of their time limit. The test set (`benchmark-perfect`) is never planned here.

    OMP_NUM_THREADS=1 python perf/plan_candidates.py --vehicle small_quad              # 432 legs, ~15 min
    OMP_NUM_THREADS=1 python perf/plan_candidates.py --vehicle uam_multicopter --scenarios 9

Prints a table and, as its last line, one JSON object of the figures (per variant: `duration_s_mean`,
`vs_single_s` with `vs_single_ci95`, `faster`, `slower`, `plan_time_s_median`, `plan_time_s_p95`, `over_80pct`,
`by_step`).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from compare.flying.seeding import cell_seed  # noqa: E402
from compare.run.cells import CellRunner  # noqa: E402
from compare.scenarios.benchmark import PERFECT_SETS, build_task_set  # noqa: E402

VALIDATION = PERFECT_SETS[2]  # benchmark-perfect-validation: the set its figures were measured on
from planners.classical_pilot import ClassicalConfig, ClassicalPilot  # noqa: E402
from planners.ladder import LADDER  # noqa: E402
from planners.rrt_star import DEFAULT_ITERATIONS, FIRST_PATH, PlannerConfig  # noqa: E402

VARIANTS = ("single", "shipped", "whole")


def variant_config(name: str) -> ClassicalConfig:
    """The pilot's settings for a variant (module docstring)."""
    if name == "single":
        return ClassicalConfig(ladder=tuple(dataclasses.replace(s, candidates=1) for s in LADDER),
                               time_fraction=math.inf)
    if name == "shipped":
        return ClassicalConfig()
    if name == "whole":
        whole = DEFAULT_ITERATIONS[PlannerConfig().algorithm]
        return ClassicalConfig(ladder=tuple(
            dataclasses.replace(s, max_iterations=s.candidates * whole)
            if (s.algorithm or PlannerConfig().algorithm) not in FIRST_PATH and s.iteration_factor == 1 else s
            for s in LADDER))
    raise ValueError(f"unknown variant {name!r} (known: {', '.join(VARIANTS)})")


def plan_legs(vehicle: str, variant: str, n_scenarios: int) -> list[dict]:
    """Every leg's plan at reset under `variant`: ok, ladder step, reference time, limit and plan time [s]."""
    scenarios = [sc for sc in build_task_set(VALIDATION).scenarios if sc.vehicle_name == vehicle][:n_scenarios]
    runner = CellRunner(scenarios, out_dir=os.devnull, policies={})
    pilot = ClassicalPilot(variant_config(variant))
    rows = []
    for si, sc in enumerate(scenarios):
        world = runner.world(si)
        for ep in sc.episodes:
            info = pilot.reset(world, ep.task, cell_seed(sc.name, ep.index, sc.seeds[0], "agent"))
            found = pilot.ladder_result
            rows.append({"leg": f"{sc.name}:{ep.index}", "ok": info.ok, "step": 0 if found is None else found.step,
                         "duration_s": pilot.reference.duration_s if info.ok and pilot.reference else math.nan,
                         "limit_s": ep.task.timeout_s, "plan_time_s": info.plan_time_s})
    return rows


def summarise(rows: list[dict], base: list[dict] | None) -> dict:
    """A variant's figures; against `base` (the `single` variant's rows, same legs) paired by leg."""
    dur = np.array([r["duration_s"] for r in rows])
    plan = np.array([r["plan_time_s"] for r in rows])
    out = {"legs": len(rows), "ok": int(sum(r["ok"] for r in rows)), "duration_s_mean": float(np.nanmean(dur)),
           "plan_time_s_median": float(np.median(plan)), "plan_time_s_p95": float(np.percentile(plan, 95)),
           "plan_time_s_max": float(plan.max()),
           "over_80pct": int(np.sum(dur > 0.8 * np.array([r["limit_s"] for r in rows]))),
           "by_step": {str(k): int(sum(r["step"] == k for r in rows)) for k in sorted({r["step"] for r in rows})}}
    if base is not None:
        d = dur - np.array([r["duration_s"] for r in base])
        d = d[np.isfinite(d)]
        half = 1.96 * float(d.std(ddof=1)) / math.sqrt(len(d)) if len(d) > 1 else math.nan
        out.update(vs_single_s=float(d.mean()), vs_single_ci95=[float(d.mean()) - half, float(d.mean()) + half],
                   faster=int(np.sum(d < -1e-6)), slower=int(np.sum(d > 1e-6)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--vehicle", default="small_quad", choices=("small_quad", "uam_multicopter"))
    ap.add_argument("--scenarios", type=int, default=36, help="the first N validation scenarios (12 legs each)")
    ap.add_argument("--variants", default="single,shipped,whole", help=f"comma-separated, of {', '.join(VARIANTS)}")
    args = ap.parse_args()
    names = [v for v in args.variants.split(",") if v]
    for v in names:
        variant_config(v)  # an unknown name fails before any planning
    t0 = time.perf_counter()
    rows = {v: plan_legs(args.vehicle, v, args.scenarios) for v in names}
    figures = {v: summarise(rows[v], rows.get("single") if v != "single" else None) for v in names}
    print(f"{args.vehicle}, {VALIDATION} (first {args.scenarios} scenarios), plans at reset, paired by leg")
    print(f"{'variant':8s} {'legs':>4s} {'ok':>4s} {'time [s]':>9s} {'vs single [s] (95 %)':>28s} "
          f"{'faster/slower':>13s} {'plan s median/p95/max':>22s} {'>80 %':>5s} by step")
    for v in names:
        f = figures[v]
        vs = (f"{f['vs_single_s']:+.2f} [{f['vs_single_ci95'][0]:+.2f}, {f['vs_single_ci95'][1]:+.2f}]"
              if "vs_single_s" in f else "")
        fs = f"{f['faster']}/{f['slower']}" if "faster" in f else ""
        print(f"{v:8s} {f['legs']:4d} {f['ok']:4d} {f['duration_s_mean']:9.2f} {vs:>28s} {fs:>13s} "
              f"{f['plan_time_s_median']:6.2f}/{f['plan_time_s_p95']:5.2f}/{f['plan_time_s_max']:5.2f}      "
              f"{f['over_80pct']:5d} {f['by_step']}")
    print(json.dumps({"vehicle": args.vehicle, "set": VALIDATION, "scenarios": args.scenarios,
                      "wall_s": time.perf_counter() - t0, "variants": figures}))


if __name__ == "__main__":
    main()
