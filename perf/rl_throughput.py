"""Learned-pilot throughput and the shipped policy's results: env decisions/s, PPO timesteps/s, test success.

An env step is one decision of the pilot: at `NavConfig.decision_hz` = 10 Hz it holds its command
for `action_repeat` = 5 control periods of 20 ms, each 10 physics substeps at 500 Hz. Each env
figure is given as decisions per second and as simulated flight seconds per wall second
(`sim_s_per_s_*` = decisions/s / decision_hz, summed over all vehicles).

Baselines measured in the same run: SB3's `DummyVecEnv` of N single environments (what one would
write without the batched env), against which the batched `UAMNavVecEnv` is given as a ratio.
The environments fly the shipped policy's task with a pool of 128 training cities instead of the
1024 `NavConfig` trains on, to keep start-up short (the pool size does not change the cost of a
step). Torch runs on one thread (with two, small-tensor work is several times slower here).

From the shipped policy folder (rl/policies/default): the training wall time (provenance) and the
wall minutes until its validation success first reached 90 % (reward curve); then, unless
--skip-eval, the policy and the potential-field pilot on the same held-out test tasks, as
`uam-compare evaluate-policy` flies them (the potential field at its 50 Hz, decision_hz =
control_hz). A policy that cannot be loaded or cannot act (e.g. trained for another observation)
is reported and its figures are null.

Prints a table, then (last line) one JSON object of the figures.

    python perf/rl_throughput.py [--seconds 3] [--ppo-steps 500000] [--episodes 1000] [--skip-eval] [--sensing LEVEL]
                                 [--env-processes N]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from dataclasses import replace

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from compare.report.report import read_reward_curve
from rl.env.gym_env import UAMNavEnv
from rl.env.split_vec_env import SplitVecEnv
from rl.env.vec_env import UAMNavVecEnv
from rl.env.world import NavWorld
from rl.policies.folder import DEFAULT_POLICY_DIR, PolicyFolder, Provenance
from rl.task.config import NavConfig
from uam_fdm.sensing.specs import LEVELS as SENSING_LEVELS

BENCH_CITY_POOL = 128  # training cities of the benchmark world (NavConfig trains on 1024): short start-up
EVAL_SEED = 0          # `uam-compare evaluate-policy`'s default
EVAL_TURBULENCE = "light"


def single_rate(world: NavWorld, seconds: float) -> float:
    """Env steps (decisions)/s of one `UAMNavEnv` through the gymnasium API, random actions, resets included."""
    env = UAMNavEnv(world=world)
    env.reset(seed=0)
    acts = np.random.default_rng(0).uniform(-1, 1, (200_000, 3)).astype(np.float32) * 0.5
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for _ in range(100):
            _, _, term, trunc, _ = env.step(acts[n % len(acts)])
            n += 1
            if term or trunc:
                env.reset()
    return n / (time.perf_counter() - t0)


def vec_rate(venv, n_envs: int, seconds: float) -> float:
    """Env steps (decisions)/s, all vehicles, of a VecEnv: random actions, automatic resets."""
    venv.reset()
    acts = np.random.default_rng(1).uniform(-1, 1, (64, n_envs, 3)).astype(np.float32) * 0.5
    k, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        venv.step(acts[k % 64])
        k += 1
    return k * n_envs / (time.perf_counter() - t0)


def ppo_rate(base, steps: int) -> float:
    """PPO (paper preset, as `rl.training.loop` builds it) training timesteps/s on the batched env `base` (a
    `UAMNavVecEnv` or `SplitVecEnv`), after a warm-up."""
    import torch

    from rl.training.ppo import PRESETS, make_model, normalized_env

    torch.set_num_threads(1)
    pr = PRESETS["paper"]
    decision_hz = base.config.decision_hz
    n_envs = base.num_envs
    venv = normalized_env(base, pr, decision_hz)
    model = make_model(pr, venv, 0, decision_hz)
    model.learn(total_timesteps=n_envs * pr.n_steps)  # warm-up rollout + update
    t0 = time.perf_counter()
    model.learn(total_timesteps=steps, reset_num_timesteps=False)
    return steps / (time.perf_counter() - t0)


def shipped_training() -> dict:
    """The shipped policy's training figures (None where its folder lacks them).

    `train_minutes_to_90pct`: the `wall_s` column / 60 at the first row of the reward curve whose
    validation success rate is >= 0.90; `training_to_kept_model_s`: `wall_s` at the row of the kept
    checkpoint (`kept_timesteps`); `shipped_training_wall_s`, `shipped_training_timesteps`: the whole
    run, from provenance.json.
    """
    out: dict = {"train_minutes_to_90pct": None, "training_to_kept_model_s": None,
                 "shipped_training_wall_s": None, "shipped_training_timesteps": None}
    folder = PolicyFolder(DEFAULT_POLICY_DIR)
    try:
        read = folder.provenance()
    except ValueError as exc:
        read = None
        print(f"shipped policy: no readable provenance.json ({exc})")
    else:
        if read is None:
            print(f"shipped policy: no provenance.json in {folder.path}")
    prov = read or Provenance()
    out["shipped_training_wall_s"] = prov.wall_time_s
    out["shipped_training_timesteps"] = prov.timesteps
    try:
        curve = read_reward_curve(folder.reward_curve)
    except (OSError, ValueError) as exc:
        print(f"shipped policy: reward curve unreadable ({exc})")
        curve = None
    if curve is None:
        return out
    hit = np.flatnonzero(curve.success_rate >= 0.90)  # NaN (no evaluation on the row) compares False
    if len(hit) and math.isfinite(curve.wall_s[hit[0]]):
        out["train_minutes_to_90pct"] = float(curve.wall_s[hit[0]]) / 60.0
    kept_at = prov.kept_timesteps if prov.kept_timesteps is not None else math.nan
    kept = np.flatnonzero(curve.timesteps == kept_at)
    if len(kept) and math.isfinite(curve.wall_s[kept[0]]):
        out["training_to_kept_model_s"] = float(curve.wall_s[kept[0]])
    return out


def test_evaluation(episodes: int, seed: int = EVAL_SEED) -> dict:
    """The shipped policy and the potential-field pilot on the same `episodes` held-out test tasks.

    As `uam-compare evaluate-policy` (compare/cli/evaluate.py `evaluate_policy`): the policy's task on the test
    pool with light turbulence; the potential field on the same cities, legs and wind at
    decision_hz = control_hz (50 Hz, the rate it was tuned at). A policy that cannot be loaded or
    cannot act is reported on the console and its figures are None; the potential field then flies
    `NavConfig()`'s task on the test pool.
    """
    from rl.pilots.learned import load_policy
    from rl.training.evaluation import eval_config, evaluate, evaluate_potential_field, paired_counts

    out: dict = {"test_episodes": episodes, "test_success_rate": None, "test_success_ci95": None,
                 "test_collision_rate": None, "test_collision_ci95": None, "expert_success_rate": None,
                 "expert_success_ci95": None, "expert_collision_rate": None, "expert_collision_ci95": None,
                 "test_vs_expert_paired": None}
    policy = None
    try:
        policy = load_policy()
    except Exception as exc:  # noqa: BLE001 (any failure to load is reported, not fatal)
        print(f"shipped policy {DEFAULT_POLICY_DIR} not loaded ({type(exc).__name__}: {exc}): test_* figures null")
    nav = eval_config(policy.nav if policy is not None else NavConfig(), episodes, pool="test",
                      turbulence=EVAL_TURBULENCE)
    t0 = time.perf_counter()
    world = NavWorld(nav)
    res = None
    if policy is not None:
        try:
            res = evaluate(lambda obs, _batch: policy.act_batch(obs), nav, episodes, seed=seed, pool="test",
                           world=world)
        except Exception as exc:  # noqa: BLE001 (e.g. trained for another observation size)
            print(f"shipped policy {DEFAULT_POLICY_DIR} cannot fly this environment ({type(exc).__name__}: {exc}): "
                  "test_* figures null")
        else:
            out.update(test_success_rate=res.success_rate, test_success_ci95=res.success_ci95,
                       test_collision_rate=res.collision_rate, test_collision_ci95=res.collision_ci95,
                       test_outcomes=res.outcomes)
    ex = evaluate_potential_field(nav, episodes, seed=seed, pool="test", world=world)
    out.update(expert_success_rate=ex.success_rate, expert_success_ci95=ex.success_ci95,
               expert_collision_rate=ex.collision_rate, expert_collision_ci95=ex.collision_ci95,
               expert_outcomes=ex.outcomes, eval_wall_s=time.perf_counter() - t0)
    if res is not None:
        out["test_vs_expert_paired"] = paired_counts(res, ex)
    return out


def _rate_line(name: str, rate: float | None, ci: tuple[float, float] | None, outcomes: dict | None) -> str:
    if rate is None:
        return f"  {name:16s} n/a"
    interval = f" [{ci[0]:.1%}, {ci[1]:.1%}]" if ci else ""
    return f"  {name:16s} success {rate:6.1%}{interval}  {outcomes or ''}"


def _json_value(key: str, v):
    if isinstance(v, tuple | list):
        return [_json_value(key, x) for x in v]
    if isinstance(v, float):
        if not math.isfinite(v):
            return None
        if "rate" in key or "ci95" in key:
            return round(v, 4)
        return round(v, 2) if "minutes" in key else round(v, 1)
    return v


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="measuring time per env figure (default 3)")
    ap.add_argument("--ppo-steps", type=int, default=500_000, help="PPO timesteps to time (default 500,000)")
    ap.add_argument("--episodes", type=int, default=1000,
                    help="held-out test episodes for the policy and the potential field (default 1000)")
    ap.add_argument("--skip-eval", action="store_true", help="do not evaluate on test tasks (those figures null)")
    ap.add_argument("--env-processes", type=int, default=1, metavar="N",
                    help="also measure the env and PPO with the 256 vehicles split over N processes "
                         "(`rl.env.split_vec_env`, as `train --env-processes N`); ppo_fps is then the split's, "
                         "ppo_fps_one_process the one process's (default 1: one process only)")
    ap.add_argument("--sensing", default="perfect", choices=SENSING_LEVELS,
                    help="the sensing level every env and PPO episode flies at (default perfect; the shipped "
                         "policy's evaluation is unaffected)")
    args = ap.parse_args()
    if args.episodes < 1:
        ap.error(f"--episodes {args.episodes}: must be >= 1")
    if not 1 <= args.env_processes <= 256:
        ap.error(f"--env-processes {args.env_processes}: must be 1 to 256")
    fig: dict = {}
    nav = replace(NavConfig(), city_pool_size=BENCH_CITY_POOL, sensing=(args.sensing,))
    world = NavWorld(nav)
    fig["sensing"] = args.sensing
    hz = nav.decision_hz
    rows = []

    def env_figure(key: str, what: str, path: str, rate: float, note: str = "") -> None:
        fig[f"env_steps_per_s_{key}"] = rate
        fig[f"sim_s_per_s_{key}"] = rate / hz
        rows.append((what, path, rate, rate / hz, note))

    env_figure("single", "UAMNavEnv, one vehicle", "gymnasium API", single_rate(world, args.seconds))
    from stable_baselines3.common.vec_env import DummyVecEnv
    for n in (16, 64, 256):
        batched = vec_rate(UAMNavVecEnv(n, world=world, seed=0), n, args.seconds)
        note = ""
        if n in (16, 64):
            dummy = vec_rate(DummyVecEnv([lambda: UAMNavEnv(world=world) for _ in range(n)]), n, args.seconds)
            env_figure(f"dummyvec_{n}", f"DummyVecEnv of {n} UAMNavEnv", "baseline", dummy)
            fig[f"batched_vs_dummyvec_ratio_{n}"] = batched / dummy
            note = f"x{batched / dummy:.1f} vs DummyVecEnv"
        env_figure(f"batched_{n}", f"UAMNavVecEnv N={n}", "one batched call", batched, note)
    ppo = ppo_rate(UAMNavVecEnv(256, world=world, seed=0), args.ppo_steps)
    fig["ppo_fps_one_process"] = ppo
    rows.append(("PPO paper preset, N=256", "SB3 learn()", ppo, ppo / hz, "timesteps/s incl. updates"))
    fig["env_processes"] = args.env_processes
    if args.env_processes > 1:
        split = SplitVecEnv(256, nav, seed=0, processes=args.env_processes)
        try:
            rate = vec_rate(split, 256, args.seconds)
            env_figure("split_256", f"SplitVecEnv N=256, {args.env_processes} processes", "shares in parallel", rate,
                       f"x{rate / fig['env_steps_per_s_batched_256']:.2f} vs one process")
            ppo = ppo_rate(split, args.ppo_steps)
        finally:
            split.close()
        rows.append((f"PPO paper preset, N=256, {args.env_processes} proc.", "SB3 learn()", ppo, ppo / hz,
                     f"x{ppo / fig['ppo_fps_one_process']:.2f} vs one process"))
    fig["ppo_fps"] = ppo
    fig.update(shipped_training())
    if args.skip_eval:
        fig.update({k: None for k in ("test_success_rate", "test_success_ci95", "test_collision_rate",
                                      "test_collision_ci95", "expert_success_rate", "expert_success_ci95",
                                      "expert_collision_rate", "expert_collision_ci95")})
    else:
        fig.update(test_evaluation(args.episodes))

    print(f"rl throughput: {nav.vehicle}, {hz:g} Hz decisions ({nav.action_repeat} control periods of "
          f"{1000 / nav.control_hz:g} ms, {nav.physics_hz:g} Hz physics), {'/'.join(nav.air.turbulence)} turbulence, "
          f"{BENCH_CITY_POOL} training cities; {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          "torch 1 thread")
    print(f"{'what':34s} {'path':18s} {'decisions/s':>12s} {'sim s/s':>9s}  note")
    for what, path, value, sim, note in rows:
        print(f"{what:34s} {path:18s} {value:12,.0f} {sim:9,.0f}  {note}")
    wall, steps = fig["shipped_training_wall_s"], fig["shipped_training_timesteps"]
    to90, to_kept = fig["train_minutes_to_90pct"], fig["training_to_kept_model_s"]
    if wall is not None:
        print(f"shipped policy: trained {steps:,d} timesteps in {wall / 60:.1f} min; validation success first "
              + (f">= 90 % after {to90:.1f} min" if to90 is not None else "never >= 90 %")
              + (f"; kept checkpoint written after {to_kept / 60:.1f} min" if to_kept is not None else ""))
    if not args.skip_eval:
        print(f"{fig['test_episodes']} held-out test episodes ({EVAL_TURBULENCE} turbulence), Wilson 95 % intervals:")
        print(_rate_line("ppo", fig["test_success_rate"], fig["test_success_ci95"], fig.get("test_outcomes")))
        print(_rate_line("potential field", fig["expert_success_rate"], fig["expert_success_ci95"],
                         fig.get("expert_outcomes")))
        if fig.get("test_vs_expert_paired"):
            p = fig["test_vs_expert_paired"]
            print(f"  paired: only ppo succeeded {p['only_a']}, only the potential field {p['only_b']}, "
                  f"both {p['both']}, neither {p['neither']}")
    test, coll, expert = fig["test_success_rate"], fig["test_collision_rate"], fig["expert_success_rate"]
    # The step targets were set for 50 Hz steps (20 ms of flight each); at 10 Hz a step is 0.1 s of
    # flight, so the same simulated time per wall second is a fifth of the steps: both are shown.
    hz = NavConfig().decision_hz
    targets = [("env_steps_per_s_single >= 5,000", fig["env_steps_per_s_single"] >= 5e3),
               ("  = 100 simulated s/s (5,000 steps of 20 ms)", fig["env_steps_per_s_single"] / hz >= 100.0),
               ("env_steps_per_s_batched_256 >= 50,000", fig["env_steps_per_s_batched_256"] >= 5e4),
               ("  = 1,000 simulated s/s", fig["env_steps_per_s_batched_256"] / hz >= 1000.0),
               ("ppo_fps >= 20,000", ppo >= 2e4),
               ("  = 400 simulated s/s", ppo / hz >= 400.0),
               ("training the shipped policy < 45 min (whole run)", None if wall is None else wall < 45 * 60),
               ("validation success >= 90 % within 45 min of training", None if to90 is None else to90 < 45),
               ("test success >= 95 %", None if test is None else test >= 0.95),
               ("test collisions <= 1 %", None if coll is None else coll <= 0.01),
               ("test success above the potential field's",
                None if test is None or expert is None else test > expert)]
    for text, ok in targets:
        print(f"target {text}: {'not measured' if ok is None else 'met' if ok else 'NOT met'}")
    print(json.dumps({k: _json_value(k, v) for k, v in fig.items()}))


if __name__ == "__main__":
    main()
