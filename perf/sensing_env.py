"""The learned pilot's training env flying on what the vehicle senses, against flying on the truth, same run.

`UAMNavVecEnv` of N vehicles (as `perf/rl_throughput.py` builds it: the default quad task, `NavConfig()`, with a pool
of 128 training cities; random actions, automatic resets) with every episode at one sensing level
(`NavConfig.sensing`): at `perfect` the policy observes the true state and the exact senses; at `nominal` (or
`degraded`) each slot also runs its IMU, barometer, heading aid, GNSS and navigation filter every control period
(`uam_fdm.sensing.batch_onboard.BatchOnboard`), flies its controller on the estimate, scans with the learned pilot's
8 x 36 lidar at 10 Hz and reads its obstacle senses from the scans (`rl.sensing.lidar_view.LidarView`). Each figure
is simulated flight seconds per wall second summed over the N vehicles (decisions/s / decision rate), the fastest
of `--repeats` timing blocks of `--seconds` each (on a shared machine other work only ever adds time).

    OMP_NUM_THREADS=1 python perf/sensing_env.py [--batches 16,64,256] [--levels perfect,nominal] [--seconds 3]

Prints a table and, as its last line, one JSON object: sim_s_per_s_<level>_<N> per level and batch size,
<level>_vs_perfect_<N> (the ratio to perfect in the same run) and the run's parameters.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import replace
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from rl.env.vec_env import UAMNavVecEnv  # noqa: E402
from rl.env.world import NavWorld  # noqa: E402
from rl.task.config import NavConfig  # noqa: E402

BENCH_CITY_POOL = 128  # as perf/rl_throughput.py: the pool size does not change a step's cost


def sim_s_per_s(world: NavWorld, n: int, seconds: float, repeats: int) -> float:
    """Simulated seconds per wall second of a `UAMNavVecEnv` of n vehicles (random actions, resets included)."""
    venv = UAMNavVecEnv(n, world=world, seed=0)
    venv.reset()
    acts = np.random.default_rng(1).uniform(-0.5, 0.5, (64, n, 3)).astype(np.float32)
    for k in range(5):  # warm-up: the first casters, priors and compiled functions
        venv.step(acts[k])
    best = 0.0
    for _ in range(repeats):
        k, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            venv.step(acts[k % 64])
            k += 1
        best = max(best, k * n / (time.perf_counter() - t0) / world.config.decision_hz)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--batches", default="16,64,256", help="batch sizes N (default 16,64,256)")
    ap.add_argument("--levels", default="perfect,nominal", help="sensing levels (default perfect,nominal)")
    ap.add_argument("--seconds", type=float, default=3.0, help="length of a timing block [s] (default 3)")
    ap.add_argument("--repeats", type=int, default=2, help="timing blocks per figure (default 2)")
    args = ap.parse_args()
    batches = [int(b) for b in args.batches.split(",")]
    levels = [s.strip() for s in args.levels.split(",") if s.strip()]
    if "perfect" not in levels:
        levels.insert(0, "perfect")  # the baseline of the ratios
    base = replace(NavConfig(), city_pool_size=BENCH_CITY_POOL)
    first = NavWorld(replace(base, sensing=(levels[0],)))
    worlds = {lv: first if lv == levels[0] else NavWorld(replace(base, sensing=(lv,)), dynamics=first.dynamics,
                                                         wind_from=first, geometry_from=first) for lv in levels}
    fig: dict[str, Any] = {"vehicle": base.vehicle, "decision_hz": base.decision_hz, "cities": BENCH_CITY_POOL,
                           "seconds": args.seconds, "repeats": args.repeats}
    print(f"training env by sensing level: {base.vehicle}, {base.decision_hz:g} Hz decisions, {base.physics_hz:g} Hz "
          f"physics, {BENCH_CITY_POOL} training cities, random actions; {platform.processor() or platform.machine()}, "
          f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}; simulated s per wall s (all vehicles), best of "
          f"{args.repeats} blocks of {args.seconds:g} s")
    print(f"{'N':>5} " + " ".join(f"{lv:>10}" for lv in levels) + " " +
          " ".join(f"{lv + '/perfect':>18}" for lv in levels if lv != "perfect"))
    for n in batches:
        rates = {lv: sim_s_per_s(worlds[lv], n, args.seconds, args.repeats) for lv in levels}
        for lv, r in rates.items():
            fig[f"sim_s_per_s_{lv}_{n}"] = round(r, 1)
            if lv != "perfect":
                fig[f"{lv}_vs_perfect_{n}"] = round(r / rates["perfect"], 3)
        print(f"{n:>5} " + " ".join(f"{rates[lv]:>10,.0f}" for lv in levels) + " " +
              " ".join(f"{rates[lv] / rates['perfect']:>18.3f}" for lv in levels if lv != "perfect"))
    print(json.dumps(fig))


if __name__ == "__main__":
    main()
