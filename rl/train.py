"""PPO training of the learned pilot (Stable-Baselines3) on the batched environment: plain PPO, from scratch.

`train(TrainConfig(...), out_dir)` trains across the training city pool with a success-gated
curriculum on the task distance, evaluates periodically on validation cities (never the test
cities), keeps the best checkpoint on validation, and writes a policy folder (its files and the
reward curve's columns: `rl.policy_folder`): the kept model, its normalisation statistics and
config, the reward curve, the provenance, periodic checkpoints for --resume and TensorBoard logs.
"""
from __future__ import annotations

import csv
import json
import os
import platform
import shutil
import sys
import time
from collections import deque
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from rl.evaluation import EvalResult, eval_config, evaluate
from rl.nav import NavConfig, NavWorld
from rl.policy import TanhMeanPolicy
from rl.policy_file import load_model_for_resume, restore_vec_normalize, save_obs_norm, save_vec_normalize
from rl.policy_folder import CHECKPOINT_FILES, CURVE_COLUMNS, PolicyFolder
from rl.vec_env import UAMNavVecEnv
from uam_fdm.episode import Outcome
from uam_fdm.files.atomic import atomic_path, write_text_atomic
from uam_fdm.files.version import code_version


@dataclass(frozen=True)
class PPOPreset:
    """PPO settings. `paper`: the original demo's network (two dense layers of 128 units) and clip 0.2;
    the rest chosen by measurement at 10 Hz decisions (docs/learned_pilot.md)."""

    net_arch: tuple[int, ...] = (128, 128)
    clip_range: float = 0.2
    learning_rate: float = 3e-4
    learning_rate_end: float | None = 0.0  # linear decay to this over the run (None: constant)
    n_steps: int = 64
    batch_size: int = 4096
    n_epochs: int = 5
    horizon_s: float = 10.0  # the discount's horizon in flight seconds: γ = 1 - 1 / (horizon_s x decision_hz)
    gae_lambda: float = 0.95
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    log_std_init: float = -1.0
    target_kl: float | None = None


    def gamma(self, decision_hz: float) -> float:
        """The discount per decision at `decision_hz` [Hz] (0.99 at 10 Hz): the same horizon in
        seconds at any decision rate, as the reward is per second."""
        return 1.0 - 1.0 / (self.horizon_s * decision_hz)


PRESETS: dict[str, PPOPreset] = {"paper": PPOPreset()}


@dataclass(frozen=True)
class Curriculum:
    """Success-gated task difficulty (`TaskDistribution.sample`'s `difficulty`, the leg length).

    Starts at `start`; whenever the success rate of the last `window` training episodes reaches
    `gate`, the difficulty rises by `step` (to 1 at most; the window then starts afresh).
    `start` = 1 turns the curriculum off.
    """

    start: float = 0.25
    step: float = 0.25
    gate: float = 0.8
    window: int = 512

    def __post_init__(self) -> None:
        if not (0 < self.start <= 1 and 0 < self.step <= 1 and 0 < self.gate <= 1 and self.window >= 1):
            raise ValueError(f"curriculum needs 0 < start, step, gate <= 1 and window >= 1; got {self}")


@dataclass(frozen=True)
class TrainConfig:
    """One training run.

    Attributes:
        preset: PPO preset name (see PRESETS).
        total_timesteps: decisions to train for (all vehicles together).
        n_envs: vehicles stepped together.
        seed: the one seed (environment slots, PPO's torch and numpy generators, evaluation).
        nav: the task definition (training cities).
        curriculum: the success-gated difficulty schedule.
        eval_every: evaluate on validation cities every this many timesteps; eval_episodes: episodes each.
        collision_weight: the kept checkpoint maximises validation success - collision_weight x
            collision rate (a crash costs more than a time-out: it is the failure a user cannot accept).
        checkpoint_every: save a checkpoint every this many timesteps (0 = never).
        torch_threads: torch intra-op threads (1: small-tensor work is fastest single-threaded here).
    """

    preset: str = "paper"
    total_timesteps: int = 10_000_000
    n_envs: int = 256
    seed: int = 0
    nav: NavConfig = field(default_factory=NavConfig)
    curriculum: Curriculum = field(default_factory=Curriculum)
    eval_every: int = 1_000_000
    eval_episodes: int = 500
    collision_weight: float = 2.0
    checkpoint_every: int = 2_000_000
    torch_threads: int = 1

    def __post_init__(self) -> None:
        if self.preset not in PRESETS:
            raise ValueError(f"unknown preset {self.preset!r}; choose from {sorted(PRESETS)}")
        for k in ("total_timesteps", "n_envs", "eval_every", "eval_episodes"):
            if getattr(self, k) < 1:
                raise ValueError(f"{k} must be >= 1, got {getattr(self, k)}")
        if not (np.isfinite(self.collision_weight) and self.collision_weight >= 0):
            raise ValueError(f"collision_weight must be a finite number >= 0, got {self.collision_weight!r}")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["ppo"] = asdict(PRESETS[self.preset])
        d["ppo"]["gamma"] = PRESETS[self.preset].gamma(self.nav.decision_hz)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        d = {k: v for k, v in d.items() if k != "ppo"}
        d["nav"] = NavConfig.from_dict(d["nav"])
        if "curriculum" in d:
            d["curriculum"] = Curriculum(**d["curriculum"])
        return cls(**d)


def _versions() -> dict[str, str]:
    import gymnasium
    import stable_baselines3
    import torch
    return {"python": platform.python_version(), "numpy": np.__version__, "torch": torch.__version__,
            "stable-baselines3": stable_baselines3.__version__, "gymnasium": gymnasium.__version__}


def _write_json(path: Path, data: dict) -> None:
    write_text_atomic(path, json.dumps(data, indent=2, sort_keys=True) + "\n")


def normalize_obs(obs: np.ndarray, stats: dict) -> np.ndarray:
    """SB3 VecNormalize's observation transform with frozen statistics."""
    z = (obs - stats["mean"]) / np.sqrt(stats["var"] + stats["epsilon"])
    return np.clip(z, -stats["clip_obs"], stats["clip_obs"]).astype(np.float32)


class LinearSchedule:
    """Learning rate falling linearly from `start` to `end` over the run (SB3 passes the fraction left)."""

    def __init__(self, start: float, end: float) -> None:
        self.start, self.end = float(start), float(end)

    def __call__(self, progress_remaining: float) -> float:
        return self.end + (self.start - self.end) * progress_remaining


def normalized_env(base, preset: PPOPreset, decision_hz: float):
    """`base` (a VecEnv) behind SB3's VecNormalize: observations and rewards, as training uses it."""
    from stable_baselines3.common.vec_env import VecNormalize
    return VecNormalize(base, norm_obs=True, norm_reward=True, clip_obs=10.0, gamma=preset.gamma(decision_hz))


def make_model(preset: PPOPreset, venv, seed: int, decision_hz: float, tb: Path | None = None):
    """A fresh PPO model of `preset` (tanh-bounded mean, separate 2-layer actor and critic) on `venv`."""
    from stable_baselines3 import PPO
    lr = preset.learning_rate if preset.learning_rate_end is None else \
        LinearSchedule(preset.learning_rate, preset.learning_rate_end)
    return PPO(
        TanhMeanPolicy, venv, learning_rate=lr, n_steps=preset.n_steps,
        batch_size=preset.batch_size, n_epochs=preset.n_epochs, gamma=preset.gamma(decision_hz),
        gae_lambda=preset.gae_lambda, clip_range=preset.clip_range, ent_coef=preset.ent_coef,
        vf_coef=preset.vf_coef, max_grad_norm=preset.max_grad_norm, target_kl=preset.target_kl, seed=seed,
        device="cpu", policy_kwargs={"net_arch": {"pi": list(preset.net_arch), "vf": list(preset.net_arch)},
                                     "log_std_init": preset.log_std_init},
        tensorboard_log=str(tb) if tb is not None else None, verbose=0)


def train(cfg: TrainConfig, out_dir: Path, resume: Path | None = None, progress: bool = True,
          command: str | None = None, log=print, world: NavWorld | None = None) -> EvalResult:
    """Train (or resume) a PPO policy and write the policy folder `out_dir` (see the module docstring).

    `world` replaces the training world built from `cfg.nav` (e.g. fixed episodes for a test).

    Returns:
        The kept model's evaluation on `cfg.eval_episodes` validation episodes.
    """
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    torch.set_num_threads(cfg.torch_threads)
    out_dir = Path(out_dir)
    out = PolicyFolder(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    out.checkpoints.mkdir(exist_ok=True)
    preset = PRESETS[cfg.preset]
    t_start = time.perf_counter()
    log(f"building {cfg.nav.city_pool_size} training cities and the batched environment ({cfg.n_envs} vehicles)")
    base = UAMNavVecEnv(cfg.n_envs, cfg.nav, seed=cfg.seed, world=world)
    eval_world = NavWorld(eval_config(cfg.nav, cfg.eval_episodes, pool="validation"), dynamics=base.world.dynamics,
                          atmosphere=base.world.atmosphere, wind_from=base.world)
    curve_path = out.reward_curve
    if resume is not None:
        resume = Path(resume)
        src = PolicyFolder(resume)
        venv = restore_vec_normalize(src.vec_normalize, base)
        model = load_model_for_resume(src.model, venv, preset, cfg.nav.decision_hz, out.tensorboard)
        state_file = src.curriculum
        difficulty = json.loads(state_file.read_text())["difficulty"] if state_file.is_file() else 1.0
        log(f"resumed from {resume} at {model.num_timesteps} timesteps (difficulty {difficulty:g})")
    else:
        venv = normalized_env(base, preset, cfg.nav.decision_hz)
        model = make_model(preset, venv, cfg.seed, cfg.nav.decision_hz, out.tensorboard)
        difficulty = cfg.curriculum.start
    base.batch.difficulty = difficulty
    if resume is None or not curve_path.exists():
        with open(curve_path, "w", newline="") as f:
            csv.writer(f).writerow(CURVE_COLUMNS)

    def pilot(obs: np.ndarray, _batch) -> np.ndarray:
        stats = {"mean": venv.obs_rms.mean, "var": venv.obs_rms.var, "epsilon": venv.epsilon, "clip_obs": venv.clip_obs}
        act, _ = model.predict(normalize_obs(obs, stats), deterministic=True)
        return act

    def save_to(folder: Path) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        pf = PolicyFolder(folder)
        _write_json(pf.config_file, cfg.to_dict())
        _write_json(pf.curriculum, {"difficulty": base.batch.difficulty})
        with atomic_path(pf.model, suffix=".zip") as tmp:
            model.save(str(tmp))
        save_vec_normalize(pf.vec_normalize, venv)
        save_obs_norm(pf.obs_norm, venv)

    state = {"next_eval": (model.num_timesteps // cfg.eval_every + 1) * cfg.eval_every,
             "next_ckpt": (model.num_timesteps // max(cfg.checkpoint_every, 1) + 1) * max(cfg.checkpoint_every, 1),
             "best": None}
    recent: deque[str] = deque(maxlen=cfg.curriculum.window)
    update: dict[str, list] = {"returns": [], "outcomes": []}

    def write_row(res: EvalResult | None) -> None:
        outs, rets = update["outcomes"], update["returns"]
        n = len(outs)
        rate = (lambda k: f"{outs.count(k) / n:.4f}") if n else (lambda k: "")
        row = [model.num_timesteps, f"{np.mean(rets):.4f}" if rets else "", rate(Outcome.SUCCESS),
               rate(Outcome.COLLISION), rate(Outcome.TIMEOUT), n, f"{base.batch.difficulty:.3f}",
               f"{res.success_rate:.4f}" if res else "", f"{res.collision_rate:.4f}" if res else "",
               res.episodes if res else "", f"{time.perf_counter() - t_start:.1f}"]
        with open(curve_path, "a", newline="") as f:
            csv.writer(f).writerow(row)
        update["outcomes"], update["returns"] = [], []

    def run_eval() -> EvalResult:
        res = evaluate(pilot, cfg.nav, cfg.eval_episodes, seed=cfg.seed + 10_000, pool="validation", world=eval_world)
        if getattr(model, "_logger", None) is not None:  # no logger before the first learn() call
            model.logger.record("eval/success_rate", res.success_rate)
            model.logger.record("eval/collision_rate", res.collision_rate)
        log(f"{model.num_timesteps:>11,d} steps  {time.perf_counter() - t_start:7.0f} s  difficulty "
            f"{base.batch.difficulty:4.2f}  validation success {res.success_rate:6.1%}  collisions "
            f"{res.collision_rate:6.1%}  ({res.outcomes})")
        best = state["best"]
        def score(r: EvalResult) -> float:
            return r.success_rate - cfg.collision_weight * r.collision_rate

        # only full-difficulty checkpoints compete; ties go to the later (more trained) one
        if base.batch.difficulty >= 1.0 and (best is None or score(res) >= score(best[1])):
            state["best"] = (model.num_timesteps, res)
            save_to(out_dir / "best")
        return res

    class Periodic(BaseCallback):
        def _on_step(self) -> bool:
            for info in self.locals["infos"]:
                if "outcome" in info:
                    update["outcomes"].append(info["outcome"])
                    update["returns"].append(info["episode"]["r"])
                    recent.append(info["outcome"])
            cur = cfg.curriculum
            if (base.batch.difficulty < 1.0 and len(recent) == recent.maxlen
                    and recent.count(Outcome.SUCCESS) / len(recent) >= cur.gate):
                base.batch.difficulty = min(1.0, base.batch.difficulty + cur.step)
                recent.clear()
                log(f"{self.num_timesteps:>11,d} steps  curriculum: difficulty {base.batch.difficulty:.2f}")
            return True

        def _on_rollout_end(self) -> None:
            res = None
            if self.num_timesteps >= state["next_eval"]:
                state["next_eval"] += cfg.eval_every
                res = run_eval()
            write_row(res)
            if cfg.checkpoint_every and self.num_timesteps >= state["next_ckpt"]:
                state["next_ckpt"] += cfg.checkpoint_every
                save_to(out.checkpoint(self.num_timesteps).path)

    remaining = cfg.total_timesteps - model.num_timesteps
    if remaining > 0:
        model.learn(total_timesteps=remaining, callback=Periodic(), progress_bar=progress,
                    reset_num_timesteps=resume is None, tb_log_name=f"ppo_{cfg.preset}")
    write_row(run_eval())
    if state["best"] is None:  # the curriculum never reached full difficulty: keep the last model
        state["best"] = (model.num_timesteps, run_eval())
        save_to(out_dir / "best")
        log("the curriculum never reached full difficulty; keeping the last model")
    best_steps, kept = state["best"]
    for name in CHECKPOINT_FILES:
        os.replace(out_dir / "best" / name, out_dir / name)
    shutil.rmtree(out_dir / "best", ignore_errors=True)
    log(f"kept the checkpoint at {best_steps:,d} timesteps: validation success {kept.success_rate:.1%}, "
        f"collisions {kept.collision_rate:.1%}")
    wall = time.perf_counter() - t_start
    prov = {
        "command": command or " ".join(sys.argv), "seed": cfg.seed, "preset": cfg.preset, "method": "PPO from scratch",
        "timesteps": int(model.num_timesteps), "wall_time_s": round(wall, 1), "kept_timesteps": int(best_steps),
        "timesteps_per_s": round(model.num_timesteps / wall, 1) if resume is None else None,
        "resumed_from": str(resume) if resume else None,
        "pools": {"training": f"train seeds {cfg.nav.city_pool_offset}.."
                              f"{cfg.nav.city_pool_offset + cfg.nav.city_pool_size - 1}",
                  "selection": f"validation pool, {cfg.eval_episodes} cities (eval seeds 1,050,000 on), "
                               f"max success - {cfg.collision_weight:g} x collisions",
                  "test": "test pool (eval seeds 1,000,000 on): never used here; "
                          "`uam-compare evaluate-policy` reports it"},
        "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                    "cpus": os.cpu_count(), "torch_threads": cfg.torch_threads},
        "versions": _versions(), "validation_of_kept_model": kept.as_dict(),
        "code": code_version(),  # which physics the policy learned on (the flight model changes with the code)
    }
    _write_json(out.provenance_file, prov)
    return kept
