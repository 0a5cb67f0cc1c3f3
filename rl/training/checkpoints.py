"""A training checkpoint's resumable state, written and read back without running code from it.

`save_vec_normalize` / `restore_vec_normalize`: every VecNormalize statistic as plain arrays (SB3's own
`VecNormalize.load` unpickles a whole object). `load_model_for_resume`: `PPO.load` of `model.zip` with
*every* pickled entry of its `data` replaced by an object built here (`custom_objects`, which SB3 uses
instead of unpickling), refusing a file with a pickled entry it does not know. The flying files
(network weights, observation statistics) are read by `rl.policies.reader`.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from rl.policies.reader import OBS_NORM_KEYS, ObsNorm, load_arrays, zip_entry
from rl.training.ppo import PPOConfig, TanhMeanPolicy
from uam_fdm.files.atomic import atomic_open

VEC_NORM_KEYS = OBS_NORM_KEYS + ("ret_mean", "ret_var", "ret_count", "clip_reward", "gamma")

# the pickled entries SB3 2.x writes in model.zip's `data`; each is replaced, never unpickled
_REPLACED = ("policy_class", "observation_space", "action_space", "lr_schedule", "learning_rate", "clip_range",
             "clip_range_vf", "rollout_buffer_class", "_last_obs", "_last_episode_starts", "_last_original_obs",
             "ep_info_buffer", "ep_success_buffer")


def save_vec_normalize(path: Path, venv_norm: VecNormalize) -> None:
    """Write all of a VecNormalize's statistics and settings (for resuming) as plain arrays (atomic)."""
    obs = ObsNorm.of(venv_norm)
    with atomic_open(path, "wb") as f:
        np.savez(f, mean=obs.mean, var=obs.var, count=obs.count, epsilon=obs.epsilon, clip_obs=obs.clip_obs,
                 ret_mean=venv_norm.ret_rms.mean,
                 ret_var=venv_norm.ret_rms.var, ret_count=venv_norm.ret_rms.count,
                 clip_reward=venv_norm.clip_reward, gamma=venv_norm.gamma)


def restore_vec_normalize(path: Path, base_venv: VecEnv) -> VecNormalize:
    """A VecNormalize over `base_venv` with the statistics of `path` (written by `save_vec_normalize`).

    Raises:
        ValueError: unreadable file, or statistics of another observation size (both sizes named).
    """
    s = load_arrays(path, VEC_NORM_KEYS)
    shape = base_venv.observation_space.shape
    n_obs = shape[0] if shape else 0
    if s["mean"].shape != (n_obs,) or s["var"].shape != (n_obs,):
        raise ValueError(f"{path}: statistics for {s['mean'].size} observations; the environment has {n_obs}")
    venv = VecNormalize(base_venv, norm_obs=True, norm_reward=True, clip_obs=float(s["clip_obs"]),
                        clip_reward=float(s["clip_reward"]), gamma=float(s["gamma"]), epsilon=float(s["epsilon"]))
    obs_rms = venv.obs_rms
    if not isinstance(obs_rms, RunningMeanStd):  # one Box observation: one set of statistics, not one per key
        raise ValueError(f"{path}: statistics for one observation vector; the environment's observations are a dict")
    obs_rms.mean, obs_rms.var, obs_rms.count = s["mean"], s["var"], float(s["count"])
    venv.ret_rms.mean, venv.ret_rms.var, venv.ret_rms.count = s["ret_mean"], s["ret_var"], float(s["ret_count"])
    return venv


def load_model_for_resume(path: Path, venv: VecNormalize, preset: PPOConfig, tb: Path | None = None) -> PPO:
    """`PPO.load` of `model.zip` with every pickled entry replaced (none is unpickled).

    Raises:
        ValueError: the file is unreadable or holds a pickled entry this version does not replace.
    """
    try:
        data = json.loads(zip_entry(path, "data"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: its 'data' entry is not JSON ({exc})") from None
    pickled = sorted(k for k, v in data.items() if isinstance(v, dict) and ":serialized:" in v)
    unknown = [k for k in pickled if k not in _REPLACED]
    if unknown:
        raise ValueError(f"{path}: pickled entries {unknown} would run code on loading; refused")
    lr = preset.learning_rate_schedule()
    replaced = {"policy_class": TanhMeanPolicy, "observation_space": venv.observation_space,
                "action_space": venv.action_space, "lr_schedule": lambda _: 0.0, "learning_rate": lr,
                "clip_range": preset.clip_range, "clip_range_vf": None, "rollout_buffer_class": RolloutBuffer,
                "_last_obs": None, "_last_episode_starts": None, "_last_original_obs": None,
                "ep_info_buffer": None, "ep_success_buffer": None}
    return PPO.load(str(path), env=venv, device="cpu", custom_objects=replaced, force_reset=True,
                    tensorboard_log=str(tb) if tb is not None else None)
