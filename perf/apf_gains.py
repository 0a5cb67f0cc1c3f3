"""Tune the potential-field pilot's gains per vehicle on **validation** cities: the reactive baseline at its best.

The potential field (`rl.pilots.potential_field`) was tuned for the small quad; other vehicles flew its gains
with every distance scaled by the vehicle's task clearance scale (x4 for the UAM multicopter), never tuned. This
searches a grid around that scaled starting point, per vehicle:

* distance factor (range, influence and slow-down distances, times the scaled base): 0.5, 0.75, 1.0;
* repulsion: 1, 2, 4;
* top speed (fraction of the vehicle's limit): 0.6, 0.8;

18 candidates (the untuned scaled gains among them), each flown on the same `--episodes` validation legs
(`rl.training.evaluation.evaluate_potential_field`: the learned pilot's validation pool, the vehicle's envelope
task by default, i.e. the air, wind and space the benchmark and the `full` set fly, as the learned pilot is trained;
`--task own` for the sea-level policy's task; paired across candidates). The score is success - 2 x collisions (the rule
that keeps the learned pilot's checkpoint). The best `--finalists` are flown again on `--confirm` further
validation legs (other cities of the same pool) and the best of them on the sum is kept. Test cities and
the comparison's scenario sets are never flown.

    OMP_NUM_THREADS=1 python perf/apf_gains.py --vehicle uam_multicopter [--write]
    OMP_NUM_THREADS=1 python perf/apf_gains.py --vehicle small_quad [--write]

`--write` stores the kept gains with their provenance in rl/pilots/data/potential_field_gains.json, which the
comparison's `apf` pilot and `evaluate-policy`'s baseline then fly. Prints a table and, as its last line, one
JSON object of the figures.
"""
from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import time
from dataclasses import asdict, replace
from datetime import datetime, timezone

os.environ.setdefault("OMP_NUM_THREADS", "1")

from rl.env.world import NavWorld  # noqa: E402
from rl.pilots.potential_field import GAINS_FILE, TUNED, PotentialFieldConfig, gains_for_task  # noqa: E402
from rl.task.vehicles import task_for  # noqa: E402
from rl.training.evaluation import EvalResult, eval_config, evaluate_potential_field  # noqa: E402
from uam_fdm.files.atomic import write_text_atomic  # noqa: E402
from uam_fdm.files.version import code_version  # noqa: E402
from uam_fdm.stats import wilson_interval  # noqa: E402

FACTORS = (0.5, 0.75, 1.0)
REPULSIONS = (1.0, 2.0, 4.0)
SPEEDS = (0.6, 0.8)
COLLISION_WEIGHT = 2.0


def candidates(vehicle: str) -> list[PotentialFieldConfig]:
    """The grid around the vehicle's scaled starting point (the untuned gains are factor 1, repulsion 2, 0.8)."""
    base = gains_for_task(task_for(vehicle).scales, TUNED)
    return [replace(base.scaled(f), repulsion=r, speed_max=s) for f, r, s in itertools.product(FACTORS, REPULSIONS,
                                                                                                  SPEEDS)]


def score(r: EvalResult) -> float:
    """Success - 2 x collisions."""
    return r.success_rate - COLLISION_WEIGHT * r.collision_rate


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--vehicle", default="uam_multicopter")
    ap.add_argument("--episodes", type=int, default=100, help="validation legs per candidate (default 100)")
    ap.add_argument("--finalists", type=int, default=3)
    ap.add_argument("--confirm", type=int, default=300, help="further validation legs for the finalists")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--task", choices=("envelope", "own"), default="envelope",
                    help="the vehicle's envelope task (the air and space every pilot meets: default) or the shipped "
                         "sea-level policy's own")
    ap.add_argument("--write", action="store_true", help=f"store the kept gains in {GAINS_FILE}")
    args = ap.parse_args(argv)
    nav = task_for(args.vehicle, envelope=args.task == "envelope")
    t0 = time.perf_counter()
    grid = candidates(args.vehicle)
    untuned = gains_for_task(nav.scales, TUNED)
    rows = []
    print(f"{args.vehicle}: {len(grid)} candidates x {args.episodes} validation legs of the {args.task} task "
          f"(seed {args.seed})")
    print(f"{'#':>3} {'range m':>8} {'repulsion':>9} {'speed':>5} {'success':>8} {'collision':>9} {'score':>6}")
    # one world per leg set (cities, fields, turbulence tabulated once), every candidate flies the same legs
    search = NavWorld(eval_config(nav, args.episodes, pool="validation"))
    for i, g in enumerate(grid):
        r = evaluate_potential_field(nav, args.episodes, seed=args.seed, pool="validation", world=search, gains=g)
        rows.append((score(r), i, g, r))
        print(f"{i:>3} {g.range_m:>8.0f} {g.repulsion:>9g} {g.speed_max:>5g} {r.success_rate:>8.1%} "
              f"{r.collision_rate:>9.1%} {score(r):>6.3f}{'  (untuned)' if g == untuned else ''}", flush=True)
    finalists = sorted(rows, key=lambda x: (-x[0], x[1]))[:args.finalists]
    # other validation cities: the confirmation's start where the search's end (same pool, later seeds)
    confirm_nav = eval_config(nav, args.confirm, pool="validation")
    confirm = NavWorld(replace(confirm_nav, city_pool_offset=confirm_nav.city_pool_offset + args.episodes),
                       dynamics=search.dynamics, wind_from=search)
    best = None
    for _, i, g, r in finalists:
        c = evaluate_potential_field(nav, args.confirm, seed=args.seed + 1, pool="validation", world=confirm, gains=g)
        n = r.episodes + c.episodes
        succ = round(r.success_rate * r.episodes) + round(c.success_rate * c.episodes)
        coll = round(r.collision_rate * r.episodes) + round(c.collision_rate * c.episodes)
        total = (succ - COLLISION_WEIGHT * coll) / n
        print(f"finalist {i}: confirm success {c.success_rate:.1%}, collisions {c.collision_rate:.1%}; "
              f"both {succ}/{n} success, {coll}/{n} collisions, score {total:.3f}", flush=True)
        if best is None or total > best[0]:
            best = (total, i, g, succ, coll, n)
    assert best is not None
    _, i, g, succ, coll, n = best
    base_row = next(x for x in rows if x[2] == untuned)
    out = {"vehicle": args.vehicle, "task": args.task, "kept_candidate": i, "gains": asdict(g),
           "validation_legs": n, "success_rate": succ / n, "success_ci95": wilson_interval(succ, n),
           "collision_rate": coll / n, "collision_ci95": wilson_interval(coll, n),
           "untuned_success_rate_search": base_row[3].success_rate,
           "untuned_collision_rate_search": base_row[3].collision_rate,
           "kept_success_rate_search": rows[i][3].success_rate, "search_legs": args.episodes,
           "wall_time_s": round(time.perf_counter() - t0, 1)}
    print(f"kept candidate {i}: {asdict(g)}; validation {succ}/{n} success, {coll}/{n} collisions")
    if args.write:
        table = json.loads(GAINS_FILE.read_text()) if GAINS_FILE.is_file() else {"vehicles": {}}
        table["vehicles"][args.vehicle] = {
            "gains": asdict(g),
            "provenance": {
                "command": "python perf/apf_gains.py " + " ".join(sys.argv[1:] if argv is None else argv),
                "pool": f"validation cities of the {args.vehicle} {args.task} task (search: the first {args.episodes}, "
                        f"confirmation: the next {args.confirm}); no test city, no comparison scenario",
                "rule": f"max success - {COLLISION_WEIGHT:g} x collisions over search + confirmation legs",
                "grid": {"distance_factor": FACTORS, "repulsion": REPULSIONS, "speed_max": SPEEDS},
                "result": {k: out[k] for k in ("validation_legs", "success_rate", "success_ci95", "collision_rate",
                                               "collision_ci95", "untuned_success_rate_search",
                                               "untuned_collision_rate_search")},
                "date": datetime.now(timezone.utc).strftime("%Y-%m-%d"), "code": code_version(),
            }}
        GAINS_FILE.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(GAINS_FILE, json.dumps(table, indent=2, sort_keys=True) + "\n")
        print(f"written to {GAINS_FILE}")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
