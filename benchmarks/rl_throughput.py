"""Learned-pilot throughput: environment steps/s (single, batched) and PPO training timesteps/s.

Baselines measured in the same run: SB3's `DummyVecEnv` of N single environments (what one would
write without the batched env), against which the batched `UAMNavVecEnv` is given as a ratio.
Training time to the success bar is read from the shipped policy's provenance and reward curve.
Torch runs on one thread (with two, small-tensor work is several times slower here).

Prints a table, then (last line) one JSON object of the figures.

    python benchmarks/rl_throughput.py [--seconds 3] [--ppo-steps 500000]
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from rl.agent import DEFAULT_POLICY_DIR
from rl.env import UAMNavEnv
from rl.nav import NavConfig, NavWorld
from rl.vec_env import UAMNavVecEnv


def single_rate(world: NavWorld, seconds: float) -> float:
    """Env steps/s of one `UAMNavEnv` through the gymnasium API, random actions, resets included."""
    env = UAMNavEnv(world=world)
    env.reset(seed=0)
    acts = np.random.default_rng(0).uniform(-1, 1, (200_000, 3)).astype(np.float32) * 0.5
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for _ in range(500):
            _, _, term, trunc, _ = env.step(acts[n % len(acts)])
            n += 1
            if term or trunc:
                env.reset()
    return n / (time.perf_counter() - t0)


def vec_rate(venv, n_envs: int, seconds: float) -> float:
    """Env steps/s (all vehicles) of a VecEnv, random actions, automatic resets."""
    venv.reset()
    acts = np.random.default_rng(1).uniform(-1, 1, (64, n_envs, 3)).astype(np.float32) * 0.5
    k, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        venv.step(acts[k % 64])
        k += 1
    return k * n_envs / (time.perf_counter() - t0)


def ppo_rate(world: NavWorld, n_envs: int, steps: int) -> float:
    """PPO (paper preset) training timesteps/s on the batched env, after a short warm-up."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from rl.policy import TanhMeanPolicy
    from rl.train import PRESETS

    torch.set_num_threads(1)
    pr = PRESETS["paper"]
    venv = VecNormalize(UAMNavVecEnv(n_envs, world=world, seed=0), gamma=pr.gamma)
    model = PPO(TanhMeanPolicy, venv, learning_rate=pr.learning_rate, n_steps=pr.n_steps, batch_size=pr.batch_size,
                n_epochs=pr.n_epochs, gamma=pr.gamma, gae_lambda=pr.gae_lambda, clip_range=pr.clip_range, seed=0,
                device="cpu", policy_kwargs={"net_arch": {"pi": list(pr.net_arch), "vf": list(pr.net_arch)}})
    model.learn(total_timesteps=n_envs * pr.n_steps)  # warm-up rollout + update
    t0 = time.perf_counter()
    model.learn(total_timesteps=steps, reset_num_timesteps=False)
    return steps / (time.perf_counter() - t0)


def training_to_bar() -> tuple[float | None, float | None, int | None]:
    """(wall seconds until the shipped model's checkpoint was evaluated, whole run seconds, timesteps).

    The shipped model is the checkpoint kept by validation (`kept_timesteps` in its provenance);
    its row in the reward curve gives the wall time the run had taken when it was written.
    """
    prov_path, curve_path = DEFAULT_POLICY_DIR / "provenance.json", DEFAULT_POLICY_DIR / "reward_curve.csv"
    if not prov_path.is_file() or not curve_path.is_file():
        return None, None, None
    prov = json.loads(prov_path.read_text())
    with open(curve_path) as f:
        rows = [r for r in csv.DictReader(f) if int(r["timesteps"]) == prov.get("kept_timesteps")]
    return (float(rows[0]["wall_s"]) if rows else None), prov.get("wall_time_s"), prov.get("timesteps")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="measuring time per env figure")
    ap.add_argument("--ppo-steps", type=int, default=500_000, help="PPO timesteps to time")
    args = ap.parse_args()
    world = NavWorld(NavConfig())  # the shipped policy's task: 128 training cities, light turbulence
    fig: dict[str, float | int | str | None] = {}
    rows = []
    single = single_rate(world, args.seconds)
    fig["env_steps_per_s_single"] = single
    rows.append(("UAMNavEnv, one vehicle", "gymnasium API", single, ""))
    from stable_baselines3.common.vec_env import DummyVecEnv
    for n in (16, 64, 256):
        batched = vec_rate(UAMNavVecEnv(n, world=world, seed=0), n, args.seconds)
        fig[f"env_steps_per_s_batched_{n}"] = batched
        note = ""
        if n in (16, 64):
            dummy = vec_rate(DummyVecEnv([lambda: UAMNavEnv(world=world) for _ in range(n)]), n, args.seconds)
            fig[f"env_steps_per_s_dummyvec_{n}"] = dummy
            fig[f"batched_vs_dummyvec_ratio_{n}"] = batched / dummy
            rows.append((f"DummyVecEnv of {n} UAMNavEnv", "baseline", dummy, ""))
            note = f"x{batched / dummy:.1f} vs DummyVecEnv"
        rows.append((f"UAMNavVecEnv N={n}", "one batched call", batched, note))
    ppo = ppo_rate(world, 256, args.ppo_steps)
    fig["ppo_fps"] = ppo
    rows.append(("PPO paper preset, N=256", "SB3 learn()", ppo, "timesteps/s incl. updates"))
    to_bar, wall, steps = training_to_bar()
    fig.update(training_to_kept_model_s=to_bar, shipped_training_wall_s=wall, shipped_training_timesteps=steps)

    print(f"rl throughput: small_quad, 50 Hz decisions (500 Hz physics), light turbulence; "
          f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, torch 1 thread")
    print(f"{'what':34s} {'path':18s} {'per second':>12s}  note")
    for what, path, value, note in rows:
        print(f"{what:34s} {path:18s} {value:12,.0f}  {note}")
    if to_bar is not None:
        print(f"shipped policy: the kept checkpoint was reached after {to_bar / 60:.1f} min of training "
              f"(whole run {wall / 60:.1f} min, {steps:,d} timesteps)")
    targets = [("env_steps_per_s_single >= 5,000", single >= 5e3),
               ("env_steps_per_s_batched_256 >= 50,000", fig["env_steps_per_s_batched_256"] >= 5e4),
               ("ppo_fps >= 20,000", ppo >= 2e4),
               ("training the shipped policy < 45 min", wall is not None and wall < 45 * 60)]
    for text, ok in targets:
        print(f"target {text}: {'met' if ok else 'NOT met'}")
    print(json.dumps({k: (round(v, 1) if isinstance(v, float) else v) for k, v in fig.items()}))


if __name__ == "__main__":
    main()
