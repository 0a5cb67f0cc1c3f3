"""PPO training of the learned pilot (Stable-Baselines3) on the batched environment: plain PPO, from scratch.

`train(TrainConfig(...), out_dir)` trains across the training city pool with a success-gated
curriculum on the task distance, evaluates periodically on validation cities (never the test
cities), keeps the best checkpoint on validation, and writes a policy folder (its files and the
reward curve's columns: `rl.policies.folder`): the kept model, its normalisation statistics and
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
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import stable_baselines3
import torch
from stable_baselines3.common.callbacks import BaseCallback

from rl.env.vec_env import UAMNavVecEnv
from rl.env.world import NavWorld
from rl.policies.folder import CHECKPOINT_FILES, CURVE_COLUMNS, PolicyFolder
from rl.policies.reader import ObsNorm
from rl.training.checkpoints import load_model_for_resume, restore_vec_normalize, save_vec_normalize
from rl.training.config import TrainConfig
from rl.training.evaluation import EvalResult, eval_config, evaluate
from rl.training.ppo import PRESETS, make_model, normalized_env
from uam_fdm.episode import Outcome
from uam_fdm.files.atomic import atomic_path, write_text_atomic
from uam_fdm.files.version import code_version


def _versions() -> dict[str, str]:
    return {"python": platform.python_version(), "numpy": np.__version__, "torch": torch.__version__,
            "stable-baselines3": stable_baselines3.__version__, "gymnasium": gymnasium.__version__}


def _write_json(path: Path, data: dict) -> None:
    write_text_atomic(path, json.dumps(data, indent=2, sort_keys=True) + "\n")


def train(cfg: TrainConfig, out_dir: Path, resume: Path | None = None, progress: bool = True,
          command: str | None = None, log=print, world: NavWorld | None = None) -> EvalResult:
    """Train (or resume) a PPO policy and write the policy folder `out_dir` (see the module docstring).

    `world` replaces the training world built from `cfg.nav` (e.g. fixed episodes for a test).

    Returns:
        The kept model's evaluation on `cfg.eval_episodes` validation episodes.
    """
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
        model = load_model_for_resume(src.model, venv, preset, out.tensorboard)
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
        act, _ = model.predict(ObsNorm.of(venv).normalize(obs), deterministic=True)
        return act

    def save_to(folder: Path) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        pf = PolicyFolder(folder)
        _write_json(pf.config_file, cfg.to_dict())
        _write_json(pf.curriculum, {"difficulty": base.batch.difficulty})
        with atomic_path(pf.model, suffix=".zip") as tmp:
            model.save(str(tmp))
        save_vec_normalize(pf.vec_normalize, venv)
        ObsNorm.of(venv).save(pf.obs_norm)

    state: dict[str, Any] = {"next_eval": (model.num_timesteps // cfg.eval_every + 1) * cfg.eval_every,
                             "next_ckpt": (model.num_timesteps // max(cfg.checkpoint_every, 1) + 1)
                             * max(cfg.checkpoint_every, 1),
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
