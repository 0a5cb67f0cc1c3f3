"""PPO training of the learned pilot (Stable-Baselines3) on the batched environment.

`train(TrainConfig(...), out_dir)` trains across the training city pool, evaluates periodically on
held-out cities, and writes a policy folder:

```
out_dir/model.zip          SB3 PPO model (policy and value networks)
out_dir/obs_norm.npz       observation-normalisation statistics (mean, var, epsilon, clip)
out_dir/vecnormalize.pkl   the same statistics as SB3's VecNormalize (for resuming)
out_dir/config.json        the TrainConfig (preset, PPO settings, NavConfig)
out_dir/reward_curve.csv   timesteps, mean_episode_reward, success_rate, collision_rate, eval_episodes
out_dir/provenance.json    command, seed, wall time, machine, library versions, final evaluation
out_dir/checkpoints/       periodic checkpoints (model + normalisation), for --resume
out_dir/tb/                TensorBoard logs
```
"""
from __future__ import annotations

import csv
import json
import os
import platform
import shutil
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from rl.nav import NavConfig, NavWorld
from rl.policy import FrozenRunningMeanStd, TanhMeanPolicy
from rl.vec_env import UAMNavVecEnv
from uam_fdm.atomic import atomic_open, atomic_path, write_text_atomic


@dataclass(frozen=True)
class PPOPreset:
    """PPO settings. `paper`: the original demo's network (two dense layers of 128 units) and clip 0.2."""

    net_arch: tuple[int, ...] = (128, 128)
    clip_range: float = 0.2
    learning_rate: float = 3e-4
    n_steps: int = 64
    batch_size: int = 4096
    n_epochs: int = 5
    gamma: float = 0.998  # 50 Hz decisions: a 10 s horizon (0.99 would see only 2 s ahead)
    gae_lambda: float = 0.95
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    log_std_init: float = -0.5
    use_sde: bool = False
    sde_sample_freq: int = -1
    bc_samples: int = 0
    bc_noise: float = 0.3
    bc_epochs: int = 4
    value_warmup_steps: int = 0
    target_kl: float | None = None
    bc_anchor_steps: int = 0
    bc_anchor_decay_steps: int = 0


PRESETS: dict[str, PPOPreset] = {
    "paper": PPOPreset(),
    # The paper's network and clip, started from behaviour cloning of the reactive potential-field
    # pilot (`rl.expert`, 2 M noisy expert-driven samples), the value function fitted for 1 M steps
    # with the actor frozen, then PPO with a behaviour-cloning auxiliary loss (5 steps on the expert
    # data after every rollout, DAPG-style). Measured: plain PPO (`paper`) levelled off near 55 %
    # held-out success after 12 M steps, flying into buildings at full speed; PPO from the clone
    # without the auxiliary loss unlearned it (92 % -> 43 % in 6 M steps). docs/learned_pilot.md.
    "tuned": PPOPreset(learning_rate=3e-5, clip_range=0.1, gamma=0.9995, gae_lambda=0.98, target_kl=0.015,
                       log_std_init=-1.6, bc_samples=2_000_000, value_warmup_steps=1_000_000,
                       bc_anchor_steps=5),
}


@dataclass(frozen=True)
class TrainConfig:
    """One training run.

    Attributes:
        preset: PPO preset name (see PRESETS).
        total_timesteps: environment steps to train for (all vehicles together).
        n_envs: vehicles stepped together.
        seed: the one seed (environment slots, PPO's torch and numpy generators).
        nav: the task definition (training cities).
        eval_every: evaluate every this many timesteps; eval_episodes: held-out episodes per evaluation.
        checkpoint_every: save a checkpoint every this many timesteps (0 = never).
        torch_threads: torch intra-op threads (1: small-tensor work is fastest single-threaded here).
    """

    preset: str = "paper"
    total_timesteps: int = 30_000_000
    n_envs: int = 256
    seed: int = 0
    nav: NavConfig = field(default_factory=NavConfig)
    eval_every: int = 1_000_000
    eval_episodes: int = 100
    checkpoint_every: int = 2_000_000
    torch_threads: int = 1

    def __post_init__(self) -> None:
        if self.preset not in PRESETS:
            raise ValueError(f"unknown preset {self.preset!r}; choose from {sorted(PRESETS)}")
        for k in ("total_timesteps", "n_envs", "eval_every", "eval_episodes"):
            if getattr(self, k) < 1:
                raise ValueError(f"{k} must be >= 1, got {getattr(self, k)}")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["ppo"] = asdict(PRESETS[self.preset])
        return d

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        d = {k: v for k, v in d.items() if k != "ppo"}
        d["nav"] = NavConfig.from_dict(d["nav"])
        return cls(**d)


@dataclass(frozen=True)
class EvalResult:
    """Outcome counts of an evaluation on held-out cities."""

    episodes: int
    success_rate: float
    collision_rate: float
    outcomes: dict[str, int]
    mean_return: float
    mean_time_s: float

    def as_dict(self) -> dict:
        return asdict(self)


VALIDATION_OFFSET = 50_000  # validation cities (model selection during training): eval seeds 1,050,000 on


def eval_config(nav: NavConfig, episodes: int, turbulence: str | None = None, validation: bool = False) -> NavConfig:
    """A held-out task: the same distribution on evaluation-split cities, one city per episode.

    Test cities (`validation=False`, what `evaluate-policy` reports) start at seed 1,000,000;
    validation cities (`validation=True`, used during training to pick the best checkpoint) at
    1,050,000, so the reported figure never comes from cities that chose the model.
    """
    return replace(nav, city_split="eval", city_pool_size=episodes,
                   city_pool_offset=VALIDATION_OFFSET if validation else 0,
                   turbulence=turbulence or nav.turbulence)


def evaluate(policy_fn, nav: NavConfig, episodes: int, seed: int = 0, world: NavWorld | None = None) -> EvalResult:
    """Fly `episodes` held-out episodes at once (episode i in evaluation city i) with a deterministic policy.

    Args:
        policy_fn: maps raw observations (N, obs) to actions (N, 3).
        nav: the task definition; its evaluation split is used (see `eval_config`).
        episodes: number of episodes.
        seed: slot i is seeded with seed + i.
    """
    world = world or NavWorld(eval_config(nav, episodes))
    venv = UAMNavVecEnv(episodes, world=world, seed=seed)
    venv.batch.city_of_slot = np.arange(episodes) % len(world.cities)
    obs = venv.reset()
    done = np.zeros(episodes, dtype=bool)
    outcomes: list[str | None] = [None] * episodes
    returns = np.zeros(episodes)
    times = np.zeros(episodes)
    while not done.all():
        obs, _, d, infos = venv.step(policy_fn(obs))
        for i in np.flatnonzero(d & ~done):
            outcomes[i] = infos[i]["outcome"]
            returns[i] = infos[i]["episode"]["r"]
            times[i] = infos[i]["t_s"]
        done |= d
    counts = {k: outcomes.count(k) for k in sorted(set(outcomes))}
    return EvalResult(episodes, counts.get("success", 0) / episodes, counts.get("collision", 0) / episodes,
                      counts, float(returns.mean()), float(times.mean()))


def _versions() -> dict[str, str]:
    import gymnasium
    import stable_baselines3
    import torch
    return {"python": platform.python_version(), "numpy": np.__version__, "torch": torch.__version__,
            "stable-baselines3": stable_baselines3.__version__, "gymnasium": gymnasium.__version__}


def _write_json(path: Path, data: dict) -> None:
    write_text_atomic(path, json.dumps(data, indent=2, sort_keys=True) + "\n")


def save_obs_norm(path: Path, venv_norm) -> None:
    """Write the observation statistics the policy agent needs (atomic)."""
    with atomic_open(path, "wb") as f:
        np.savez(f, mean=venv_norm.obs_rms.mean, var=venv_norm.obs_rms.var, count=venv_norm.obs_rms.count,
                 epsilon=venv_norm.epsilon, clip_obs=venv_norm.clip_obs)


def normalize_obs(obs: np.ndarray, stats: dict) -> np.ndarray:
    """SB3 VecNormalize's observation transform with frozen statistics."""
    z = (obs - stats["mean"]) / np.sqrt(stats["var"] + stats["epsilon"])
    return np.clip(z, -stats["clip_obs"], stats["clip_obs"]).astype(np.float32)


def train(cfg: TrainConfig, out_dir: Path, resume: Path | None = None, progress: bool = True,
          command: str | None = None, log=print) -> EvalResult:
    """Train (or resume) a PPO policy and write the policy folder `out_dir` (see the module docstring).

    Returns:
        The final evaluation on `cfg.eval_episodes` held-out episodes.
    """
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import VecNormalize

    torch.set_num_threads(cfg.torch_threads)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "checkpoints").mkdir(exist_ok=True)
    preset = PRESETS[cfg.preset]
    t_start = time.perf_counter()
    log(f"building {cfg.nav.city_pool_size} training cities and the batched environment ({cfg.n_envs} vehicles)")
    base = UAMNavVecEnv(cfg.n_envs, cfg.nav, seed=cfg.seed)
    eval_world = NavWorld(eval_config(cfg.nav, cfg.eval_episodes, validation=True), dynamics=base.world.dynamics,
                          atmosphere=base.world.atmosphere)
    curve_path = out_dir / "reward_curve.csv"
    if resume is not None:
        resume = Path(resume)
        venv = VecNormalize.load(str(resume / "vecnormalize.pkl"), base)
        venv.training = True
        model = PPO.load(str(resume / "model.zip"), env=venv, device="cpu",
                         tensorboard_log=str(out_dir / "tb"))
        log(f"resumed from {resume} at {model.num_timesteps} timesteps")
    else:
        venv = VecNormalize(base, norm_obs=True, norm_reward=True, clip_obs=10.0, gamma=preset.gamma)
        model = PPO(
            TanhMeanPolicy, venv, learning_rate=preset.learning_rate, n_steps=preset.n_steps,
            batch_size=preset.batch_size, n_epochs=preset.n_epochs, gamma=preset.gamma,
            gae_lambda=preset.gae_lambda, clip_range=preset.clip_range, ent_coef=preset.ent_coef,
            vf_coef=preset.vf_coef, max_grad_norm=preset.max_grad_norm, use_sde=preset.use_sde,
            sde_sample_freq=preset.sde_sample_freq, target_kl=preset.target_kl, seed=cfg.seed, device="cpu",
            policy_kwargs={"net_arch": {"pi": list(preset.net_arch), "vf": list(preset.net_arch)},
                           "log_std_init": preset.log_std_init},
            tensorboard_log=str(out_dir / "tb"), verbose=0)
    if resume is None or not curve_path.exists():
        with open(curve_path, "w", newline="") as f:
            csv.writer(f).writerow(["timesteps", "mean_episode_reward", "success_rate", "collision_rate",
                                    "eval_episodes", "wall_s"])

    def policy_fn(obs: np.ndarray) -> np.ndarray:
        stats = {"mean": venv.obs_rms.mean, "var": venv.obs_rms.var, "epsilon": venv.epsilon, "clip_obs": venv.clip_obs}
        act, _ = model.predict(normalize_obs(obs, stats), deterministic=True)
        return act

    def save_to(folder: Path) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        _write_json(folder / "config.json", cfg.to_dict())
        with atomic_path(folder / "model.zip", suffix=".zip") as tmp:
            model.save(str(tmp))
        with atomic_path(folder / "vecnormalize.pkl") as tmp:
            venv.save(str(tmp))
        save_obs_norm(folder / "obs_norm.npz", venv)

    state = {"next_eval": (model.num_timesteps // cfg.eval_every + 1) * cfg.eval_every,
             "next_ckpt": (model.num_timesteps // max(cfg.checkpoint_every, 1) + 1) * max(cfg.checkpoint_every, 1),
             "last": None, "best": None}

    def run_eval() -> EvalResult:
        res = evaluate(policy_fn, cfg.nav, cfg.eval_episodes, seed=cfg.seed + 10_000, world=eval_world)
        rewards = [e["r"] for e in (model.ep_info_buffer or [])]
        mean_r = float(np.mean(rewards)) if rewards else float("nan")
        with open(curve_path, "a", newline="") as f:
            csv.writer(f).writerow([model.num_timesteps, f"{mean_r:.4f}", f"{res.success_rate:.4f}",
                                    f"{res.collision_rate:.4f}", res.episodes,
                                    f"{time.perf_counter() - t_start:.1f}"])
        if getattr(model, "_logger", None) is not None:  # no logger before the first learn() call
            model.logger.record("eval/success_rate", res.success_rate)
            model.logger.record("eval/collision_rate", res.collision_rate)
        log(f"{model.num_timesteps:>11,d} steps  {time.perf_counter() - t_start:7.0f} s  mean episode reward "
            f"{mean_r:8.2f}  held-out success {res.success_rate:6.1%}  collisions {res.collision_rate:6.1%}")
        state["last"] = res
        best = state["best"]
        # ties go to the later (more trained) checkpoint
        if best is None or (res.success_rate, -res.collision_rate) >= (best[1].success_rate, -best[1].collision_rate):
            state["best"] = (model.num_timesteps, res)
            save_to(out_dir / "best")
        return res

    anchor = {"data": None, "gen": None, "start": 0}

    class Periodic(BaseCallback):
        def _on_rollout_end(self) -> None:
            frozen = not any(q.requires_grad for q in model.policy.action_net.parameters())
            if anchor["data"] is None or preset.bc_anchor_steps <= 0 or frozen:
                return
            weight = 1.0  # constant unless a decay is set
            if preset.bc_anchor_decay_steps > 0:
                weight = 1.0 - (self.num_timesteps - anchor["start"]) / preset.bc_anchor_decay_steps
            if weight > 0.0:
                bc_anchor_step(model, anchor["data"], weight, preset.bc_anchor_steps, anchor["gen"])

        def _on_step(self) -> bool:
            if self.num_timesteps >= state["next_eval"]:
                state["next_eval"] += cfg.eval_every
                run_eval()
            if cfg.checkpoint_every and self.num_timesteps >= state["next_ckpt"]:
                state["next_ckpt"] += cfg.checkpoint_every
                save_to(out_dir / "checkpoints" / f"step_{self.num_timesteps:011d}")
            return True

    fresh = resume is None
    if fresh and preset.bc_samples > 0:
        from rl.expert import PotentialField
        expert = PotentialField(cfg.nav.k_buildings, cfg.nav.sensing_range_m)
        log(f"behaviour cloning: {preset.bc_samples:,d} samples of the potential-field pilot")
        anchor["data"] = clone_expert(model, venv, base, expert, preset, cfg.seed)
        import torch
        anchor["gen"] = torch.Generator().manual_seed(cfg.seed + 2)
        venv.obs_rms = FrozenRunningMeanStd(venv.obs_rms.mean, venv.obs_rms.var, venv.obs_rms.count)
        run_eval()
    actor = [model.policy.mlp_extractor.policy_net, model.policy.action_net]
    if fresh and preset.value_warmup_steps > 0:
        for m in actor:
            m.requires_grad_(False)
        model.policy.log_std.requires_grad_(False)
        model.learn(total_timesteps=preset.value_warmup_steps, callback=Periodic(), progress_bar=progress,
                    reset_num_timesteps=True, tb_log_name=f"ppo_{cfg.preset}")
        for m in actor:
            m.requires_grad_(True)
        model.policy.log_std.requires_grad_(True)
        fresh = False
    remaining = cfg.total_timesteps - model.num_timesteps
    if remaining > 0:
        model.learn(total_timesteps=remaining, callback=Periodic(), progress_bar=progress,
                    reset_num_timesteps=fresh, tb_log_name=f"ppo_{cfg.preset}")
    run_eval()
    # The shipped model is the best on the validation cities (SB3 EvalCallback's best_model rule).
    best_steps, final = state["best"]
    for name in ("model.zip", "vecnormalize.pkl", "obs_norm.npz", "config.json"):
        os.replace(out_dir / "best" / name, out_dir / name)
    shutil.rmtree(out_dir / "best", ignore_errors=True)
    log(f"kept the checkpoint at {best_steps:,d} timesteps: validation success {final.success_rate:.1%}, "
        f"collisions {final.collision_rate:.1%}")
    wall = time.perf_counter() - t_start
    prov = {
        "command": command or " ".join(sys.argv), "seed": cfg.seed, "preset": cfg.preset,
        "timesteps": int(model.num_timesteps), "wall_time_s": round(wall, 1), "kept_timesteps": int(best_steps),
        "behaviour_cloning_samples": preset.bc_samples if resume is None else 0,
        "timesteps_per_s": round(model.num_timesteps / wall, 1) if resume is None else None,
        "resumed_from": str(resume) if resume else None,
        "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                    "cpus": os.cpu_count(), "torch_threads": cfg.torch_threads},
        "versions": _versions(), "validation_of_kept_model": final.as_dict(),
    }
    _write_json(out_dir / "provenance.json", prov)
    return final


def clone_expert(model, venv, base: UAMNavVecEnv, expert, preset: PPOPreset, seed: int):
    """Behaviour cloning: fit the policy mean to the expert's actions on states the expert visits.

    The expert flies the training env with temporally correlated noise (held for 10 decisions) so
    that the data covers states slightly off its own path; labels are its clean actions. The
    observation-normalisation statistics are initialised from the same data.
    """
    import torch

    rng = np.random.default_rng(seed + 1)
    n = base.num_envs
    obs = base.reset()
    chunks_o, chunks_a = [], []
    noise = np.zeros((n, 3))
    for t in range(max(1, preset.bc_samples // n)):
        a = expert.act(obs)
        chunks_o.append(obs.copy())
        chunks_a.append(a)
        if t % 10 == 0:
            noise = rng.normal(0.0, preset.bc_noise, size=(n, 3))
        obs, _, _, _ = base.step(np.clip(a + noise, -1.0, 1.0))
    o_all = np.concatenate(chunks_o)
    a_all = np.clip(np.concatenate(chunks_a), -0.98, 0.98)  # tanh reaches ±1 only asymptotically
    venv.obs_rms.update(o_all)
    stats = {"mean": venv.obs_rms.mean, "var": venv.obs_rms.var, "epsilon": venv.epsilon, "clip_obs": venv.clip_obs}
    x = torch.as_tensor(normalize_obs(o_all, stats))
    y = torch.as_tensor(a_all, dtype=torch.float32)
    pol = model.policy
    params = list(pol.mlp_extractor.policy_net.parameters()) + list(pol.action_net.parameters())
    opt = torch.optim.Adam(params, lr=1e-3)
    gen = torch.Generator().manual_seed(seed)
    for _ in range(preset.bc_epochs):
        perm = torch.randperm(len(x), generator=gen)
        for i in range(0, len(x), 4096):
            idx = perm[i:i + 4096]
            latent = pol.mlp_extractor.forward_actor(pol.extract_features(x[idx], pol.pi_features_extractor))
            loss = torch.mean((pol.action_net(latent) - y[idx]) ** 2)
            opt.zero_grad()
            loss.backward()
            opt.step()
    base.reset()
    return x, y


def bc_anchor_step(model, data, weight: float, steps: int, gen) -> None:
    """A few behaviour-cloning gradient steps (loss scaled by `weight`) on the expert data: keeps
    PPO near the demonstrations while its critic and updates settle (DAPG-style, decaying)."""
    import torch

    x, y = data
    pol = model.policy
    opt = pol.optimizer
    for _ in range(steps):
        idx = torch.randint(len(x), (4096,), generator=gen)
        latent = pol.mlp_extractor.forward_actor(pol.extract_features(x[idx], pol.pi_features_extractor))
        loss = weight * torch.mean((pol.action_net(latent) - y[idx]) ** 2)
        opt.zero_grad()
        loss.backward()
        opt.step()

