"""Reading a policy folder without running code from it: weights, statistics and settings as plain data.

A policy folder is shared between researchers, so loading one must not execute anything it holds.
SB3's own `PPO.load` unpickles the entries of `model.zip`'s `data` (spaces, schedules, buffers) and
`VecNormalize.load` unpickles a whole object; a crafted file runs arbitrary code in either. Here:

- the network's weights come from `model.zip`'s `policy.pth` through `torch.load(weights_only=True)`
  (tensors only) into a network built from `config.json`;
- normalisation statistics are `.npz` arrays read with `allow_pickle=False`;
- resuming training loads `model.zip` through `PPO.load` with *every* pickled entry of `data`
  replaced by an object built here (`custom_objects`, which SB3 uses instead of unpickling), and
  refuses a file with a pickled entry it does not know.
"""
from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np

from uam_fdm.files.atomic import atomic_open

OBS_NORM_KEYS = ("mean", "var", "count", "epsilon", "clip_obs")
VEC_NORM_KEYS = OBS_NORM_KEYS + ("ret_mean", "ret_var", "ret_count", "clip_reward", "gamma")

# the pickled entries SB3 2.x writes in model.zip's `data`; each is replaced, never unpickled
_REPLACED = ("policy_class", "observation_space", "action_space", "lr_schedule", "learning_rate", "clip_range",
             "clip_range_vf", "rollout_buffer_class", "_last_obs", "_last_episode_starts", "_last_original_obs",
             "ep_info_buffer", "ep_success_buffer")


def load_arrays(path: Path, keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The arrays `keys` of an `.npz` file, read without unpickling; all finite.

    Raises:
        ValueError: the file is missing, not an npz, holds objects, lacks a key or has a non-finite
            value (naming the file and the key).
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in keys if k not in z.files]
            if missing:
                raise ValueError(f"{path}: missing arrays {missing}")
            out = {k: np.array(z[k], dtype=np.float64) for k in keys}
    except ValueError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise ValueError(f"{path}: not a plain-number .npz file ({exc})") from None
    except (OSError, zipfile.BadZipFile, EOFError) as exc:
        raise ValueError(f"{path}: unreadable ({exc})") from None
    for k, v in out.items():
        if not np.isfinite(v).all():
            raise ValueError(f"{path}: array {k!r} has non-finite values")
    return out


def save_obs_norm(path: Path, venv_norm) -> None:
    """Write the observation statistics the flying policy needs (`OBS_NORM_KEYS`, atomic)."""
    with atomic_open(path, "wb") as f:
        np.savez(f, mean=venv_norm.obs_rms.mean, var=venv_norm.obs_rms.var, count=venv_norm.obs_rms.count,
                 epsilon=venv_norm.epsilon, clip_obs=venv_norm.clip_obs)


def save_vec_normalize(path: Path, venv_norm) -> None:
    """Write all of a VecNormalize's statistics and settings (for resuming) as plain arrays (atomic)."""
    with atomic_open(path, "wb") as f:
        np.savez(f, mean=venv_norm.obs_rms.mean, var=venv_norm.obs_rms.var, count=venv_norm.obs_rms.count,
                 epsilon=venv_norm.epsilon, clip_obs=venv_norm.clip_obs, ret_mean=venv_norm.ret_rms.mean,
                 ret_var=venv_norm.ret_rms.var, ret_count=venv_norm.ret_rms.count,
                 clip_reward=venv_norm.clip_reward, gamma=venv_norm.gamma)


def restore_vec_normalize(path: Path, base_venv):
    """A VecNormalize over `base_venv` with the statistics of `path` (written by `save_vec_normalize`).

    Raises:
        ValueError: unreadable file, or statistics of another observation size (both sizes named).
    """
    from stable_baselines3.common.running_mean_std import RunningMeanStd
    from stable_baselines3.common.vec_env import VecNormalize

    s = load_arrays(path, VEC_NORM_KEYS)
    n_obs = base_venv.observation_space.shape[0]
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


def _zip_entry(path: Path, name: str) -> bytes:
    try:
        with zipfile.ZipFile(path) as z:
            if name not in z.namelist():
                raise ValueError(f"{path}: no {name!r} inside (not a model written by `uam-compare train`?)")
            return z.read(name)
    except (OSError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: not a readable zip file ({exc})") from None


def load_network(path: Path, n_obs: int, ppo: dict):
    """The actor-critic of `model.zip` at `path`, built from settings and filled with its weights only.

    Args:
        n_obs: observation size the network must take; ppo: the policy's PPO settings (config.json's
            "ppo": net_arch, log_std_init).

    Raises:
        ValueError: the file is unreadable, holds anything but tensors, or its weights do not fit
            the network (e.g. another observation size; both sizes named).
    """
    import gymnasium as gym
    import torch

    from rl.policy import TanhMeanPolicy

    raw = _zip_entry(path, "policy.pth")
    try:
        state = torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises UnpicklingError, RuntimeError, ... for a bad file
        raise ValueError(f"{path}: policy.pth holds something other than tensors; "
                         f"refused ({type(exc).__name__})") from None
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise ValueError(f"{path}: policy.pth is not a table of tensors")
    first = state.get("mlp_extractor.policy_net.0.weight")
    if first is not None and first.shape[1] != n_obs:
        raise ValueError(f"{path}: the network takes {first.shape[1]} observations; "
                         f"the task (config.json) gives {n_obs}")
    arch = [int(u) for u in ppo["net_arch"]]
    net = TanhMeanPolicy(gym.spaces.Box(-np.inf, np.inf, (n_obs,), np.float32),
                         gym.spaces.Box(-1.0, 1.0, (3,), np.float32),
                         lambda _: 0.0, net_arch={"pi": arch, "vf": arch}, log_std_init=float(ppo["log_std_init"]))
    try:
        net.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        raise ValueError(f"{path}: weights do not fit the network of config.json ({exc})") from None
    net.set_training_mode(False)
    return net


def load_model_for_resume(path: Path, venv, preset, decision_hz: float, tb: Path | None = None):
    """`PPO.load` of `model.zip` with every pickled entry replaced (none is unpickled).

    Raises:
        ValueError: the file is unreadable or holds a pickled entry this version does not replace.
    """
    from stable_baselines3 import PPO
    from stable_baselines3.common.buffers import RolloutBuffer

    from rl.policy import TanhMeanPolicy
    from rl.train import LinearSchedule

    try:
        data = json.loads(_zip_entry(path, "data"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: its 'data' entry is not JSON ({exc})") from None
    pickled = sorted(k for k, v in data.items() if isinstance(v, dict) and ":serialized:" in v)
    unknown = [k for k in pickled if k not in _REPLACED]
    if unknown:
        raise ValueError(f"{path}: pickled entries {unknown} would run code on loading; refused")
    lr = preset.learning_rate if preset.learning_rate_end is None else \
        LinearSchedule(preset.learning_rate, preset.learning_rate_end)
    replaced = {"policy_class": TanhMeanPolicy, "observation_space": venv.observation_space,
                "action_space": venv.action_space, "lr_schedule": lambda _: 0.0, "learning_rate": lr,
                "clip_range": preset.clip_range, "clip_range_vf": None, "rollout_buffer_class": RolloutBuffer,
                "_last_obs": None, "_last_episode_starts": None, "_last_original_obs": None,
                "ep_info_buffer": None, "ep_success_buffer": None}
    return PPO.load(str(path), env=venv, device="cpu", custom_objects=replaced, force_reset=True,
                    tensorboard_log=str(tb) if tb is not None else None)
