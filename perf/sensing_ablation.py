"""The learned pilot's ablation on its sensors (docs/learned_pilot.md, "Flying on its sensors"): trained arms flown on
the same validation legs, paired.

Each POLICY_DIR is an arm trained by `uam-compare train` (its command is in its provenance.json). Every arm is flown
on the same `--episodes` validation legs of the first arm's task (its cities, legs, air, sensing and map-error levels,
drawn per leg from the same seeds; each arm reads them in its own observation), deterministically, as
`uam-compare evaluate-policy POLICY_DIR --pool validation` flies one. Never the test pool.

Prints per arm its success, collision and time-out rates with Wilson 95 % intervals and its score, success - 2 x
collisions; per arm after the first its paired differences to the first (Newcombe 95 %); and the arm the rule fixed
before any arm was evaluated picks: the highest score, but an arm replaces the first (the plain recipe) only when its
paired difference in success or in collisions excludes zero in its favour. Then (last line) one JSON object.

    python perf/sensing_ablation.py runs/quad_a runs/quad_b runs/quad_c [--episodes 1000] [--seed 0]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from compare.results.stats import PairedCounts, newcombe_paired_interval
from rl.env.world import NavWorld
from rl.pilots.learned import Policy, load_policy
from rl.task.config import NavConfig
from rl.training.evaluation import EvalResult, eval_config, evaluate, rates_by_level
from uam_fdm.episode import Outcome

COLLISION_WEIGHT = 2.0  # the score's, as the training's selection (`TrainConfig.collision_weight`)
MIN_EPISODES_FOR_INTERVALS = 10


def arm_task(arm: NavConfig, first: NavConfig) -> NavConfig:
    """`arm`'s task (its observation, route and reward) flown in `first`'s space: its cities, legs, air, sensing and
    map-error levels (and whether perfect sensing keeps to exact maps).

    Raises:
        ValueError: the arms are for different vehicles.
    """
    if arm.vehicle != first.vehicle:
        raise ValueError(f"arms for {arm.vehicle!r} and {first.vehicle!r}: an ablation compares one vehicle's arms")
    return replace(arm, cities=first.cities, tasks=first.tasks, air=first.air, sensing=first.sensing,
                   map_error=first.map_error, map_error_draws=first.map_error_draws,
                   exact_maps_at_perfect=first.exact_maps_at_perfect)


def _pilot(policy: Policy) -> Callable[[np.ndarray, object], np.ndarray]:
    """`policy` as `evaluate` flies a batched pilot (deterministic)."""
    return lambda obs, _batch: policy.act_batch(obs)


def score(r: EvalResult) -> float:
    """Success - 2 x collisions."""
    return r.success_rate - COLLISION_WEIGHT * r.collision_rate


def comparison_score(r: EvalResult) -> float:
    """Success - 2 x collisions on the legs a comparison pilot can meet: all but `perfect` sensing over a map with
    error (there the env hands the policy the truth's senses, the comparison a sensorless pilot the prior's)."""
    kept = [o for o, (sensing, map_error) in zip(r.per_episode, r.per_episode_levels, strict=True)
            if sensing != "perfect" or map_error == "exact"]
    n = max(len(kept), 1)
    return kept.count(Outcome.SUCCESS) / n - COLLISION_WEIGHT * kept.count(Outcome.COLLISION) / n


def paired(first: EvalResult, other: EvalResult, outcome: str) -> tuple[float, tuple[float, float]]:
    """`other` - `first` in the rate of `outcome` on the same legs, and its Newcombe 95 % interval."""
    a = np.array([o == outcome for o in other.per_episode])
    b = np.array([o == outcome for o in first.per_episode])
    return float(a.mean() - b.mean()), newcombe_paired_interval(PairedCounts.of(a, b))


def pick(results: list[EvalResult]) -> int:
    """The arm the rule picks (an index of `results`; 0 is the plain recipe)."""
    best = 0
    for k in range(1, len(results)):
        _, (s_lo, _) = paired(results[0], results[k], Outcome.SUCCESS)
        _, (_, c_hi) = paired(results[0], results[k], Outcome.COLLISION)
        better = s_lo > 0.0 or c_hi < 0.0
        if better and score(results[k]) > score(results[best]):
            best = k
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("arms", type=Path, nargs="+", help="trained policy folders, the plain recipe first")
    ap.add_argument("--episodes", type=int, default=1000, help="validation legs (default 1000)")
    ap.add_argument("--seed", type=int, default=0, help="the evaluation seed (default 0)")
    args = ap.parse_args()
    if args.episodes < 1:
        ap.error(f"--episodes {args.episodes}: must be >= 1")
    import torch

    torch.set_num_threads(1)
    policies: list[Policy] = [load_policy(folder) for folder in args.arms]
    first = policies[0].nav
    results = []
    for folder, policy in zip(args.arms, policies):
        nav = eval_config(arm_task(policy.nav, first), args.episodes, pool="validation")
        res = evaluate(_pilot(policy), nav, args.episodes, seed=args.seed, pool="validation", world=NavWorld(nav))
        results.append(res)
        print(f"flown {folder}: {res.outcomes}", flush=True)
    chosen = pick(results)
    print(f"{args.episodes} validation legs of {args.arms[0]}'s task ({first.vehicle}; "
          f"{'/'.join(first.sensing)} sensing, {'/'.join(first.map_error)} maps), seed {args.seed}, Wilson and "
          f"Newcombe 95 % intervals")
    print(f"{'arm':28s} {'success':>22s} {'collisions':>22s} {'time-outs':>10s} {'score':>7s}  paired vs first")
    out: dict = {"episodes": args.episodes, "seed": args.seed, "pool": "validation", "arms": {}}
    for k, (folder, res) in enumerate(zip(args.arms, results)):
        timeouts = res.outcomes.get(Outcome.TIMEOUT, 0) / res.episodes
        row = {"success_rate": res.success_rate, "success_ci95": list(res.success_ci95),
               "collision_rate": res.collision_rate, "collision_ci95": list(res.collision_ci95),
               "timeout_rate": timeouts, "score": score(res), "score_comparison_legs": comparison_score(res),
               "outcomes": res.outcomes}
        note = ""
        if k:
            ds, s_ci = paired(results[0], res, Outcome.SUCCESS)
            dc, c_ci = paired(results[0], res, Outcome.COLLISION)
            row.update(success_diff=ds, success_diff_ci95=list(s_ci), collision_diff=dc, collision_diff_ci95=list(c_ci))
            note = (f"success {ds:+.1%} [{s_ci[0]:+.1%}, {s_ci[1]:+.1%}], collisions {dc:+.1%} "
                    f"[{c_ci[0]:+.1%}, {c_ci[1]:+.1%}]")
        out["arms"][str(folder)] = row
        if res.episodes < MIN_EPISODES_FOR_INTERVALS:  # too few to say anything with an interval
            print(f"{str(folder):28s} {res.success_rate:22.1%} {res.collision_rate:22.1%} {timeouts:10.1%} "
                  f"{score(res):7.3f}  (fewer than {MIN_EPISODES_FOR_INTERVALS} episodes: no intervals)")
            continue
        s_lo, s_hi = res.success_ci95
        c_lo, c_hi = res.collision_ci95
        print(f"{str(folder):28s} {res.success_rate:6.1%} [{s_lo:5.1%}, {s_hi:5.1%}] {res.collision_rate:6.1%} "
              f"[{c_lo:5.1%}, {c_hi:5.1%}] {timeouts:10.1%} {score(res):7.3f}  {note}")
    out["picked"] = str(args.arms[chosen])
    print(f"picked by the rule: {args.arms[chosen]}")
    print("score on the legs a comparison pilot can meet (no perfect sensing over a map with error), for the record: "
          + ", ".join(f"{folder} {comparison_score(res):.3f}" for folder, res in zip(args.arms, results)))
    print("per sensing and map-error level (success / collisions, Wilson 95 %):")
    for folder, res in zip(args.arms, results):
        groups = rates_by_level(res)
        out["arms"][str(folder)]["by_level"] = [dataclasses.asdict(g) for g in groups]
        for g in groups:
            print(f"  {str(folder):26s} {g.label:<20s} n {g.episodes:>4}  {g.success_rate:6.1%} "
                  f"[{g.success_ci95[0]:5.1%}, {g.success_ci95[1]:5.1%}]  {g.collision_rate:5.1%} "
                  f"[{g.collision_ci95[0]:5.1%}, {g.collision_ci95[1]:5.1%}]  {g.outcomes}")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
