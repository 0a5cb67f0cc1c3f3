"""PPO training of the learned pilot (Stable-Baselines3) on the batched environment: plain PPO, from scratch.

`train(TrainConfig(...), out_dir)` trains across the training city pool with a success-gated
curriculum on the task distance, evaluates periodically on validation cities (never the test
cities), keeps the best checkpoint on validation, and writes a policy folder (its files and the
reward curve's columns: `rl.policies.folder`): the kept model, its normalisation statistics and
config, the reward curve (one row per PPO update; the last one holds the final model's validation),
the provenance, periodic checkpoints for --resume and TensorBoard logs. With a `ground`
(`rl.env.ground`: a scenario's map and air) it trains on legs drawn in that map and validates on
other legs drawn there.
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
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import stable_baselines3
import torch
from stable_baselines3.common.callbacks import BaseCallback

from rl.env.ground import TRAINING_LEGS, TRAINING_STREAM, VALIDATION_STREAM, TrainingGround
from rl.env.held_out import PolicyWeights
from rl.env.split_vec_env import SplitVecEnv, evaluation_world
from rl.env.vec_env import UAMNavVecEnv
from rl.env.world import NavBatch, NavWorld
from rl.policies.folder import CHECKPOINT_FILES, CHECKPOINTS, CURVE_COLUMNS, PolicyFolder
from rl.policies.reader import ObsNorm
from rl.task.config import FixedEpisodes
from rl.training.checkpoints import (
    check_resume,
    load_model_for_resume,
    read_curriculum,
    restore_vec_normalize,
    save_vec_normalize,
)
from rl.training.config import TrainConfig
from rl.training.evaluation import EvalResult, eval_config, evaluate, evaluate_split
from rl.training.ppo import PRESETS, make_model, normalized_env
from rl.training.recording import FlightRecorder
from uam_fdm.episode import Outcome
from uam_fdm.files.atomic import atomic_path, write_text_atomic
from uam_fdm.files.inside import inside_no_links, make_folders
from uam_fdm.files.version import code_version


def _versions() -> dict[str, str]:
    return {"python": platform.python_version(), "numpy": np.__version__, "torch": torch.__version__,
            "stable-baselines3": stable_baselines3.__version__, "gymnasium": gymnasium.__version__}


def command_line() -> str:
    """This process's command line as typed, the program by its name: provenance.json records no path of the
    machine it ran on that the user did not type (the options, `--out` among them, are kept as given)."""
    return " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]) if sys.argv else ""


def _write_json(path: Path, data: dict, root: Path) -> None:
    write_text_atomic(path, json.dumps(data, indent=2, sort_keys=True) + "\n", root=root)


def train(cfg: TrainConfig, out_dir: Path, resume: Path | None = None, progress: bool = True,
          command: str | None = None, log=print, world: NavWorld | None = None,
          ground: TrainingGround | None = None) -> EvalResult:
    """Train (or resume) a PPO policy and write the policy folder `out_dir` (see the module docstring).

    Args:
        world: replaces the training world built from `cfg.nav` (e.g. fixed episodes for a test).
        ground: a scenario's map and air to train and validate in (`cfg.scenario` names its file; `cfg.nav` is
            `ground.task(...)`'s); its legs are drawn once at full length, so the curriculum must be off.

    Returns:
        The kept model's evaluation on `cfg.eval_episodes` validation episodes.

    Raises:
        ValueError: `resume` is not a folder this run can resume from (`check_resume`), or `ground` does not fit
            `cfg`, before anything is built or written.
    """
    legs = None
    if ground is not None:  # its legs drawn before anything is written: a map with no room for them is said first
        check_ground(cfg, ground, world)
        legs = (ground.legs(cfg.nav, TRAINING_LEGS, cfg.seed, TRAINING_STREAM),
                ground.legs(cfg.nav, cfg.eval_episodes, cfg.seed, VALIDATION_STREAM))
    if resume is not None:
        check_resume(Path(resume), cfg)
    torch.set_num_threads(cfg.torch_threads)
    run = _TrainingRun(cfg, Path(out_dir), Path(resume) if resume is not None else None, log, world, ground, legs)
    try:
        if resume is None:
            run.record_flights()  # step 0: the untrained policy
        remaining = cfg.total_timesteps - run.model.num_timesteps
        if remaining > 0:
            run.model.learn(total_timesteps=remaining, callback=_Periodic(run), progress_bar=progress,
                            reset_num_timesteps=resume is None, tb_log_name=f"ppo_{cfg.preset}")
        final = run.evaluate(final=True)  # the last update's row waits for it (`update_ended`)
    finally:
        run.base.close()  # a split batch's worker processes end here, after they flew the last evaluation
    if remaining > 0:
        run.write_row(final)
    best_steps, kept = run.keep_best(final)
    _write_json(run.out.provenance_file, run.provenance(best_steps, kept, command or command_line()), run.out_dir)
    return kept


def check_ground(cfg: TrainConfig, ground: TrainingGround, world: NavWorld | None) -> None:
    """Raise ValueError unless `cfg` trains on `ground`: named by `cfg.scenario`, its task `ground.task`'s, the
    curriculum off, and no other training world given."""
    if world is not None:
        raise ValueError("a training world and a ground: give one or the other")
    if cfg.scenario != ground.source:
        raise ValueError(f"the ground is {ground.source!r}; the settings' scenario is {cfg.scenario!r}")
    if cfg.nav != ground.task(cfg.nav):
        raise ValueError(f"{ground.source}: the settings' task is not in the scenario's air and rates "
                         f"(TrainingGround.task)")
    if cfg.curriculum.start < 1.0:
        raise ValueError(f"{ground.source}: the scenario's legs are drawn once at full length; the curriculum must "
                         f"be off (Curriculum(start=1.0))")


class _TrainingRun:
    """One training run's environments, model and records: what the PPO callback and the end of the run use.

    Args:
        cfg: the run's settings; out_dir: the policy folder to write; resume: a checkpoint folder to resume
        from (None: a fresh model); log: where progress lines go; world: replaces the training world; ground: a
        scenario's map and air to train in instead, with its (training, validation) `legs`.
    """

    def __init__(self, cfg: TrainConfig, out_dir: Path, resume: Path | None, log: Callable[[str], object],
                 world: NavWorld | None, ground: TrainingGround | None = None,
                 legs: tuple[FixedEpisodes, FixedEpisodes] | None = None) -> None:
        self.cfg, self.out_dir, self.resume, self.log, self.ground = cfg, out_dir, resume, log, ground
        self.out = PolicyFolder(out_dir)
        make_folders(out_dir, self.out.checkpoints)  # no link planted in the policy folder is followed
        preset = PRESETS[cfg.preset]
        self.t_start = time.perf_counter()
        self.code = code_version()  # at the start: the code this run imported (HEAD may move while it trains)
        self.base: UAMNavVecEnv | SplitVecEnv
        if ground is None:
            split = f", {cfg.env_processes} processes" if cfg.env_processes > 1 and world is None else ""
            log(f"building {cfg.nav.city_pool_size} training cities and the batched environment "
                f"({cfg.n_envs} vehicles{split})")
            self.base = UAMNavVecEnv(cfg.n_envs, cfg.nav, seed=cfg.seed, world=world) \
                if cfg.env_processes == 1 or world is not None else \
                SplitVecEnv(cfg.n_envs, cfg.nav, seed=cfg.seed, processes=cfg.env_processes)
            self.eval_world = evaluation_world(eval_config(cfg.nav, cfg.eval_episodes, pool="validation"),
                                               self.base.world)
        else:
            assert legs is not None, "a ground comes with its legs (train)"
            log(f"building the batched environment ({cfg.n_envs} vehicles) on {len(legs[0].tasks)} training legs in "
                f"{ground.source}'s map, and {len(legs[1].tasks)} validation legs there")
            self.base = UAMNavVecEnv(cfg.n_envs, seed=cfg.seed, world=ground.world(cfg.nav, legs[0]))
            self.eval_world = ground.world(cfg.nav, legs[1], dynamics=self.base.world.dynamics,
                                           wind_from=self.base.world)
        if resume is not None:
            src = PolicyFolder(resume)
            self.venv = restore_vec_normalize(src.vec_normalize, self.base)
            self.model = load_model_for_resume(src.model, self.venv, preset, self.out.tensorboard)
            difficulty, since = read_curriculum(src.curriculum) if src.curriculum.is_file() else (1.0, None)
            self.level_since = int(self.model.num_timesteps if since is None else since)
            log(f"resumed from {resume} at {self.model.num_timesteps} timesteps (difficulty {difficulty:g})")
        else:
            self.venv = normalized_env(self.base, preset, cfg.nav.decision_hz)
            self.model = make_model(preset, self.venv, cfg.seed, cfg.nav.decision_hz, self.out.tensorboard)
            difficulty = cfg.curriculum.start
            self.level_since = 0  # the timestep the current curriculum level began
        self.base.difficulty = difficulty
        # the checkpoints' flights of fixed validation tasks, in a world of their own (rl.training.recording);
        # a resumed run continues the record of the folder it resumes from (a checkpoint's: its policy folder's)
        history = None if resume is None else resume.parent.parent if resume.parent.name == CHECKPOINTS else resume
        # a scenario's run records its flights in the scenario's map (its validation world), others in validation cities
        own = None if ground is None else self.eval_world
        self.recorder = (FlightRecorder(cfg.nav, cfg.record_flights, cfg.seed, out_dir, self.eval_world, history,
                                        int(self.model.num_timesteps), world=own) if cfg.record_flights else None)
        if resume is None or not inside_no_links(out_dir, self.out.reward_curve).exists():
            with open(self.out.reward_curve, "w", newline="") as f:
                csv.writer(f).writerow(CURVE_COLUMNS)
        steps = self.model.num_timesteps
        self.next_eval = (steps // cfg.eval_every + 1) * cfg.eval_every
        self.next_ckpt = (steps // max(cfg.checkpoint_every, 1) + 1) * max(cfg.checkpoint_every, 1)
        self.best: tuple[int, EvalResult] | None = None
        self.recent: deque[str] = deque(maxlen=cfg.curriculum.window)  # the curriculum's window of outcomes
        self.outcomes: list[str] = []  # training episodes that ended in this update
        self.returns: list[float] = []

    def pilot(self, obs: np.ndarray, _batch: NavBatch) -> np.ndarray:
        """The current policy, deterministic, with the current normalisation (for evaluation)."""
        act, _ = self.model.predict(ObsNorm.of(self.venv).normalize(obs), deterministic=True)
        return act

    def save_to(self, folder: Path) -> None:
        """Write the current model as a checkpoint folder (`CHECKPOINT_FILES`)."""
        make_folders(self.out_dir, folder)
        for name in CHECKPOINT_FILES:  # the writers below that take no root: none of their files is a link
            inside_no_links(self.out_dir, folder / name)
        pf = PolicyFolder(folder)
        _write_json(pf.config_file, self.cfg.to_dict(), self.out_dir)
        _write_json(pf.curriculum, {"difficulty": self.base.difficulty, "level_since": self.level_since},
                    self.out_dir)
        with atomic_path(pf.model, suffix=".zip", root=self.out_dir) as tmp:
            self.model.save(str(tmp))
        save_vec_normalize(pf.vec_normalize, self.venv)
        ObsNorm.of(self.venv).save(pf.obs_norm)

    def write_row(self, res: EvalResult | None) -> None:
        """Append this update's row to the reward curve (with the evaluation `res`, if one ran) and start afresh."""
        outs, rets = self.outcomes, self.returns
        n = len(outs)
        rate = (lambda k: f"{outs.count(k) / n:.4f}") if n else (lambda k: "")
        row = [self.model.num_timesteps, f"{np.mean(rets):.4f}" if rets else "", rate(Outcome.SUCCESS),
               rate(Outcome.COLLISION), rate(Outcome.TIMEOUT), n, f"{self.base.difficulty:.3f}",
               f"{res.success_rate:.4f}" if res else "", f"{res.collision_rate:.4f}" if res else "",
               res.episodes if res else "", f"{time.perf_counter() - self.t_start:.1f}"]
        with open(inside_no_links(self.out_dir, self.out.reward_curve), "a", newline="") as f:
            csv.writer(f).writerow(row)
        self.outcomes, self.returns = [], []

    def record_flights(self) -> None:
        """Fly the recorder's fixed tasks with the current model and write them (once per timestep count)."""
        rec, steps = self.recorder, int(self.model.num_timesteps)
        if rec is None or rec.has(steps):
            return
        actor = {k: v.detach().cpu().numpy().copy() for k, v in self.model.policy.state_dict().items()
                 if k == "log_std" or k.startswith(("mlp_extractor.policy_net.", "action_net."))}
        rec.record(steps, self.pilot, actor, ObsNorm.of(self.venv))

    def evaluate(self, final: bool = False) -> EvalResult:
        """Evaluate the current model on the validation pool; keep it (as `best/`) when it is the best so far.
        The recorder's fixed tasks are flown too. A periodic evaluation logs its line; the `final` one is said
        once, by the end of the run (`keep_best` and the caller)."""
        cfg, model = self.cfg, self.model
        self.record_flights()
        seed = cfg.seed + 10_000
        if isinstance(self.base, SplitVecEnv):  # the env's processes fly a share each
            weights = PolicyWeights.of(model.policy.state_dict(), self.base.world.obs_size,
                                       PRESETS[cfg.preset].network, ObsNorm.of(self.venv))
            res = evaluate_split(self.base, weights, cfg.eval_episodes, seed, "validation", self.eval_world)
        else:
            res = evaluate(self.pilot, cfg.nav, cfg.eval_episodes, seed=seed, pool="validation", world=self.eval_world)
        if getattr(model, "_logger", None) is not None:  # no logger before the first learn() call
            model.logger.record("eval/success_rate", res.success_rate)
            model.logger.record("eval/collision_rate", res.collision_rate)
        if not final:
            self.log(f"{model.num_timesteps:>11,d} steps  {time.perf_counter() - self.t_start:7.0f} s  difficulty "
                     f"{self.base.difficulty:4.2f}  validation success {res.success_rate:6.1%}  collisions "
                     f"{res.collision_rate:6.1%}  ({res.outcomes})")

        def score(r: EvalResult) -> float:
            return r.success_rate - cfg.collision_weight * r.collision_rate

        # only full-difficulty checkpoints compete; ties go to the later (more trained) one
        if self.base.difficulty >= 1.0 and (self.best is None or score(res) >= score(self.best[1])):
            self.best = (model.num_timesteps, res)
            self.save_to(self.out_dir / "best")
        return res

    def episodes_ended(self, infos: Sequence[dict], num_timesteps: int) -> None:
        """Record the training episodes that ended in a step; raise the curriculum's difficulty when earned."""
        for info in infos:
            if "outcome" in info:
                self.outcomes.append(info["outcome"])
                self.returns.append(info["episode"]["r"])
                self.recent.append(info["outcome"])
        cur, base, recent = self.cfg.curriculum, self.base, self.recent
        if base.difficulty >= 1.0:
            return
        gated = len(recent) == recent.maxlen and recent.count(Outcome.SUCCESS) / len(recent) >= cur.gate
        timed = cur.level_steps > 0 and num_timesteps - self.level_since >= cur.level_steps
        if gated or timed:
            base.difficulty = min(1.0, base.difficulty + cur.step)
            recent.clear()
            self.level_since = num_timesteps
            why = "" if gated else f" (the level's {cur.level_steps:,d} timesteps are over)"
            self.log(f"{num_timesteps:>11,d} steps  curriculum: difficulty {base.difficulty:.2f}{why}")

    def update_ended(self, num_timesteps: int) -> None:
        """After each rollout: the reward curve's row, an evaluation and a checkpoint when due. The last rollout's
        row and evaluation wait for the end of the run (`train`): its model is updated once more."""
        if self.cfg.checkpoint_every and num_timesteps >= self.next_ckpt:
            self.next_ckpt += self.cfg.checkpoint_every
            self.save_to(self.out.checkpoint(num_timesteps).path)
        if num_timesteps >= self.cfg.total_timesteps:
            return
        res = None
        if num_timesteps >= self.next_eval:
            self.next_eval += self.cfg.eval_every
            res = self.evaluate()
        self.write_row(res)

    def cap_exploration(self, num_timesteps: int) -> None:
        """Hold the policy's log std under the preset's cap for this point of the run (`PPOConfig.log_std_cap`),
        before a rollout is collected with it."""
        cap = PRESETS[self.cfg.preset].log_std_cap(num_timesteps / self.cfg.total_timesteps)
        if cap is not None:
            with torch.no_grad():
                self.model.policy.log_std.clamp_(max=cap)

    def keep_best(self, final: EvalResult) -> tuple[int, EvalResult]:
        """Move the best checkpoint's files into the policy folder: (its timesteps, its validation). `final` is
        the last model's validation (`evaluate(final=True)`), said here only where another model is kept."""
        steps = int(self.model.num_timesteps)
        if self.best is None:  # the curriculum never reached full difficulty: keep the last model
            self.best = (steps, final)
            self.save_to(self.out_dir / "best")
            self.log(f"the curriculum never reached full difficulty ({self.base.difficulty:.2f}); keeping the "
                     f"last model")
        best_steps, kept = self.best
        if kept is not final:
            self.log(f"the last model ({steps:,d} timesteps): validation success {final.success_rate:.1%}, "
                     f"collisions {final.collision_rate:.1%}; kept the better one at {best_steps:,d} timesteps")
        for name in CHECKPOINT_FILES:
            os.replace(self.out_dir / "best" / name, self.out_dir / name)
        shutil.rmtree(self.out_dir / "best", ignore_errors=True)
        return best_steps, kept

    def pools(self) -> dict[str, str]:
        """What the run trained, selected and left for testing on (provenance.json's "pools")."""
        return _pools(self.cfg, self.ground)

    def provenance(self, best_steps: int, kept: EvalResult, command: str) -> dict[str, Any]:
        """provenance.json's record of the finished run."""
        cfg, model, resume = self.cfg, self.model, self.resume
        wall = time.perf_counter() - self.t_start
        return {
            "command": command, "seed": cfg.seed, "preset": cfg.preset, "method": "PPO from scratch",
            "timesteps": int(model.num_timesteps), "wall_time_s": round(wall, 1), "kept_timesteps": int(best_steps),
            "timesteps_per_s": round(model.num_timesteps / wall, 1) if resume is None else None,
            "resumed_from": str(resume) if resume else None,
            "pools": self.pools(),
            "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                        "cpus": os.cpu_count(), "torch_threads": cfg.torch_threads},
            "versions": _versions(), "validation_of_kept_model": kept.as_dict(),
            "code": self.code,  # which physics the policy learned on (the flight model changes with the code)
        }


def _pools(cfg: TrainConfig, ground: TrainingGround | None) -> dict[str, str]:
    """provenance.json's words on what the run trained, selected and left for testing on."""
    selection = f"max success - {cfg.collision_weight:g} x collisions"
    if ground is not None:
        return {"training": f"{TRAINING_LEGS} legs drawn in the map of {ground.source} (seed {cfg.seed})",
                "selection": f"{cfg.eval_episodes} other legs drawn in the same map, {selection}",
                "test": f"the scenario's own {len(ground.episodes)} episode{'s' * (len(ground.episodes) != 1)}: "
                        f"never used here; `uam-compare run {ground.source} --policy POLICY_DIR` flies them"}
    first = cfg.nav.city_pool_offset
    return {"training": f"train seeds {first}..{first + cfg.nav.city_pool_size - 1}",
            "selection": f"validation pool, {cfg.eval_episodes} cities (eval seeds 1,050,000 on), {selection}",
            "test": "test pool (eval seeds 1,000,000 on): never used here; `uam-compare evaluate-policy` reports it"}


class _Periodic(BaseCallback):
    """SB3's hooks into the run: every step (episodes that ended, the curriculum) and every rollout's end."""

    def __init__(self, run: _TrainingRun) -> None:
        super().__init__()
        self.run = run

    def _on_step(self) -> bool:
        self.run.episodes_ended(self.locals["infos"], self.num_timesteps)
        return True

    def _on_rollout_start(self) -> None:
        self.run.cap_exploration(self.num_timesteps)

    def _on_rollout_end(self) -> None:
        self.run.update_ended(self.num_timesteps)
