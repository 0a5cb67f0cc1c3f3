"""A training's validation evaluation flown by one process against the same episodes shared by the training
environment's processes (`SplitVecEnv.fly_held_out`), in the same run, with the same policy weights.

The task is the sensing ablation's recipe (the quad's envelope at every sensing and map-error level, the route
redrawn every second), the episodes those of `train`'s periodic validation (`--eval-episodes`, validation pool). A
policy folder given with --policy flies (its task must match: a checkpoint of the recipe); without one, the paper
network with its initial weights (seed 0), which flies until it collides or times out: episodes as long as a
trained policy's or longer, so the time is the evaluation's cost, not a figure of any policy. Both runs must end
each episode alike (checked: the split is exact).

Prints a table, then (last line) one JSON object: `eval_s_one_process`, `eval_s_split`, `eval_split_speedup`,
`episodes`, `processes`.

    python perf/held_out_split.py [--episodes 500] [--processes 2] [--policy DIR]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from rl.env.held_out import PolicyWeights, fly_episodes, policy_pilot  # noqa: E402
from rl.env.split_vec_env import SplitVecEnv, evaluation_world  # noqa: E402
from rl.policies.folder import NetworkConfig  # noqa: E402
from rl.policies.network import ActorCritic  # noqa: E402
from rl.policies.reader import ObsNorm  # noqa: E402
from rl.sensing.route import RouteConfig  # noqa: E402
from rl.task.vehicles import task_for  # noqa: E402
from rl.training.evaluation import eval_config  # noqa: E402

CITIES = 128  # training cities of the environment (the evaluation builds its own): a short start-up


def _weights(policy: Path | None, n_obs: int) -> PolicyWeights:
    if policy is None:
        torch.manual_seed(0)
        net = ActorCritic(n_obs, NetworkConfig())
        return PolicyWeights.of(net.state_dict(), n_obs, NetworkConfig(),
                                ObsNorm(np.zeros(n_obs), np.ones(n_obs), 1.0, 1e-8, 10.0))
    from rl.pilots.learned import load_policy

    loaded = load_policy(policy)
    # the hidden layers' widths; the initial log std the config would give is overwritten by the loaded one
    arch = tuple(m.out_features for m in loaded.network.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear))
    return PolicyWeights.of(loaded.network.state_dict(), n_obs, NetworkConfig(arch), loaded.obs_norm)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--episodes", type=int, default=500)
    ap.add_argument("--processes", type=int, default=2)
    ap.add_argument("--policy", type=Path, default=None)
    args = ap.parse_args()
    torch.set_num_threads(1)
    nav = replace(task_for("small_quad", envelope=True), sensing=("perfect", "nominal", "degraded"),
                  map_error=("exact", "outdated", "wrong"), route=RouteConfig(refresh_s=1.0), city_pool_size=CITIES)
    env = SplitVecEnv(args.processes * 8, nav, seed=3, processes=args.processes)
    try:
        t0 = time.perf_counter()
        world = evaluation_world(eval_config(nav, args.episodes, pool="validation"), env.world)
        build_s = time.perf_counter() - t0
        weights = _weights(args.policy, world.obs_size)
        seed = 3 + 10_000  # train's validation seed for --seed 3
        # the workers build their evaluation world at their first evaluation: a first short one builds them
        env.fly_held_out(world, args.processes, seed, weights)
        t0 = time.perf_counter()
        one = fly_episodes(policy_pilot(weights, 0, args.episodes), world, 0, args.episodes, seed)
        one_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        split = env.fly_held_out(world, args.episodes, seed, weights)
        split_s = time.perf_counter() - t0
    finally:
        env.close()
    if split.outcomes != one.outcomes or not np.array_equal(split.returns, one.returns):
        raise SystemExit("the split evaluation ended episodes otherwise than one process: not exact")
    ended = {o: one.outcomes.count(o) for o in sorted(set(one.outcomes))}
    who = f"policy {args.policy}" if args.policy else "initial weights, seed 0"
    print(f"validation evaluation, {args.episodes} episodes of the sensing recipe's task ({who}); "
          f"{platform.processor() or platform.machine()}")
    print(f"  evaluation world built in {build_s:.1f} s; outcomes {ended}, mean flight {one.times_s.mean():.1f} s")
    print(f"  {'one process':<22} {one_s:8.1f} s")
    print(f"  {f'{args.processes} processes (split)':<22} {split_s:8.1f} s   x{one_s / split_s:.2f}")
    print(json.dumps({"episodes": args.episodes, "processes": args.processes, "eval_s_one_process": round(one_s, 2),
                      "eval_s_split": round(split_s, 2), "eval_split_speedup": round(one_s / split_s, 3)}))


if __name__ == "__main__":
    main()
