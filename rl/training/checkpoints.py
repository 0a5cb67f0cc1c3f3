"""A training checkpoint's resumable state, written and read back without running code from it.

`save_vec_normalize` / `restore_vec_normalize`: every VecNormalize statistic as plain arrays (SB3's own
`VecNormalize.load` unpickles a whole object). `load_model_for_resume`: `PPO.load` of `model.zip` with
*every* pickled entry of its `data` replaced by an object built here (`custom_objects`, which SB3 uses
instead of unpickling), refusing a file with a pickled entry it does not know. `check_resume`: whether a run
can resume from a folder, before anything is built or written. The flying files (network weights,
observation statistics) are read by `rl.policies.reader`.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from rl.policies.folder import CONFIG, MODEL, VEC_NORMALIZE, NetworkConfig, PolicyFolder
from rl.policies.reader import OBS_NORM_KEYS, ObsNorm, load_arrays, network_shape, zip_entry
from rl.sensing.observation import obs_size
from rl.training.config import TrainConfig
from rl.training.ppo import PRESETS, PPOConfig, TanhMeanPolicy
from uam_fdm.files.atomic import atomic_open
from uam_fdm.files.strict import json_object_file, strict_json_loads

VEC_NORM_KEYS = OBS_NORM_KEYS + ("ret_mean", "ret_var", "ret_count", "clip_reward", "gamma")
RESUME_FILES = (MODEL, VEC_NORMALIZE, CONFIG)  # and curriculum.json when there (difficulty 1 without)

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
    model_data(path)
    lr = preset.learning_rate_schedule()
    replaced = {"policy_class": TanhMeanPolicy, "observation_space": venv.observation_space,
                "action_space": venv.action_space, "lr_schedule": lambda _: 0.0, "learning_rate": lr,
                "clip_range": preset.clip_range, "clip_range_vf": None, "rollout_buffer_class": RolloutBuffer,
                "_last_obs": None, "_last_episode_starts": None, "_last_original_obs": None,
                "ep_info_buffer": None, "ep_success_buffer": None}
    model = PPO.load(str(path), env=venv, device="cpu", custom_objects=replaced, force_reset=True,
                     tensorboard_log=str(tb) if tb is not None else None)
    model.batch_size = preset.minibatch_size(venv.num_envs)  # the run's vehicles, not the saved run's
    return model


def model_data(path: Path) -> dict[str, Any]:
    """`model.zip`'s `data` entry (SB3's settings of the model) as JSON, its pickled entries left as they are.

    Raises:
        ValueError: not a JSON object, or it holds a pickled entry this version does not replace (naming the file).
    """
    try:
        data = strict_json_loads(zip_entry(path, "data").decode("utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        if str(exc).startswith(str(path)):
            raise
        raise ValueError(f"{path}: its 'data' entry is not JSON ({exc})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: its 'data' entry is not a JSON object")
    pickled = sorted(k for k, v in data.items() if isinstance(v, dict) and ":serialized:" in v)
    unknown = [k for k in pickled if k not in _REPLACED]
    if unknown:
        raise ValueError(f"{path}: pickled entries {unknown} would run code on loading; refused")
    return data


def read_curriculum(path: Path) -> tuple[float, int | None]:
    """curriculum.json: the difficulty (0 to 1] and the timestep its level began (None: not recorded).

    Raises:
        ValueError: unreadable, or a value of the wrong kind, naming the file and the key.
    """
    state = json_object_file(path)
    difficulty, since = state.get("difficulty"), state.get("level_since")
    if isinstance(difficulty, bool) or not isinstance(difficulty, (int, float)) or not 0 < difficulty <= 1:
        raise ValueError(f"{path}: difficulty must be a number in (0, 1], got {str(difficulty)[:40]}")
    if since is not None and (isinstance(since, bool) or not isinstance(since, int) or since < 0):
        raise ValueError(f"{path}: level_since must be a timestep count (an integer >= 0), got {str(since)[:40]}")
    return float(difficulty), since


def check_resume(folder: Path, cfg: TrainConfig) -> None:
    """Raise ValueError unless training `cfg` can resume from `folder` (a checkpoint or a policy folder); read
    before anything is built or written. Its files are there; its config.json says what its weights are (the
    network's layers and the observation size); it was trained for this run's vehicle, observation and network;
    its statistics are of that observation size and its curriculum state is readable.

    Raises:
        ValueError: one line naming the folder and what is missing, or the file and key that disagree.
    """
    src, where = PolicyFolder(folder), f"--resume {folder}"
    if not src.path.is_dir():
        raise ValueError(f"{where}: no such folder (give a policy folder or one of its checkpoints/step_*)")
    for name in RESUME_FILES:
        if not (src.path / name).is_file():
            raise ValueError(f"{where}: not a checkpoint or policy folder ({name} is missing)")
    saved = src.config()
    n_obs = obs_size(saved.nav.perception, saved.nav.observe)
    held_obs, held_arch = network_shape(src.model)
    if held_arch != saved.network.net_arch:
        raise ValueError(f"{src.config_file}: ppo.net_arch is {list(saved.network.net_arch)}; the weights of "
                         f"{MODEL} have layers of {list(held_arch)} units")
    if held_obs != n_obs:
        raise ValueError(f"{src.config_file}: nav.perception and nav.observe give {n_obs} observations; the "
                         f"weights of {MODEL} take {held_obs}")
    data = model_data(src.model)
    kwargs, space = data.get("policy_kwargs"), data.get("observation_space")
    built = kwargs.get("net_arch") if isinstance(kwargs, dict) else None
    if built != NetworkConfig(held_arch).policy_kwargs()["net_arch"]:
        raise ValueError(f"{src.model}: its data's policy_kwargs.net_arch is {str(built)[:80]}; its weights have "
                         f"layers of {list(held_arch)} units")
    shape = space.get("_shape") if isinstance(space, dict) else None
    if shape != [held_obs]:
        raise ValueError(f"{src.model}: its data's observation_space._shape is {str(shape)[:40]}; its weights "
                         f"take {held_obs} observations")
    stats = load_arrays(src.vec_normalize, VEC_NORM_KEYS)
    if stats["mean"].shape != (n_obs,) or stats["var"].shape != (n_obs,):
        raise ValueError(f"{src.vec_normalize}: statistics for {stats['mean'].size} observations; "
                         f"{CONFIG} gives {n_obs}")
    if src.curriculum.is_file():
        read_curriculum(src.curriculum)
    raw = strict_json_loads(src.config_file.read_text())
    trained_on = raw.get("scenario")
    if trained_on != cfg.scenario:
        def said(scenario: Any) -> str:
            return "generated cities" if scenario is None else repr(scenario)[:200]

        raise ValueError(f"{where}: trained on {said(trained_on)} ({CONFIG}'s scenario); this run trains on "
                         f"{said(cfg.scenario)} (give the --scenario it was trained on, or none)")
    if saved.nav.vehicle != cfg.nav.vehicle:
        raise ValueError(f"{where}: trained for vehicle {saved.nav.vehicle!r} ({CONFIG}'s nav.vehicle); this run "
                         f"trains {cfg.nav.vehicle!r} (give --vehicle {saved.nav.vehicle})")
    run_obs = obs_size(cfg.nav.perception, cfg.nav.observe)
    if run_obs != n_obs:
        raise ValueError(f"{where}: its policy takes {n_obs} observations ({CONFIG}'s nav.perception and "
                         f"nav.observe); this run's task gives {run_obs} (give the --observe or --envelope it "
                         f"was trained with)")
    run_arch = PRESETS[cfg.preset].net_arch
    if tuple(run_arch) != held_arch:
        raise ValueError(f"{where}: its network has layers of {list(held_arch)} units ({CONFIG}'s ppo.net_arch); "
                         f"this run's preset {cfg.preset!r} builds {list(run_arch)}")
    seed = raw.get("seed")
    if seed != cfg.seed:  # the model carries its seed, which the batched environment refuses once built
        raise ValueError(f"{where}: trained with seed {str(seed)[:40]} ({CONFIG}'s seed); this run has seed "
                         f"{cfg.seed} (give --seed {str(seed)[:40]})")
