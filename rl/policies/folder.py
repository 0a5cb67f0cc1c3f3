"""The policy folder: which files it holds, where the shipped ones are, and the one reader of its
settings (config.json) and training record (provenance.json).

```
folder/model.zip          SB3 PPO model (policy and value networks; read without unpickling: `rl.policies.reader`)
folder/obs_norm.npz       observation-normalisation statistics (mean, var, count, epsilon, clip)
folder/config.json        the training configuration (`rl.training.config.TrainConfig.to_dict`): preset, "ppo"
                          (the PPO settings the network is built from), "nav" (the task, `rl.task.config.NavConfig`)
folder/vecnormalize.npz   all of VecNormalize's statistics, as plain arrays (for resuming)
folder/curriculum.json    the curriculum's difficulty when written (for resuming)
folder/reward_curve.csv   one row per PPO update (training episodes) + validation columns (`CURVE_COLUMNS`)
folder/provenance.json    command, seed, wall time, machine, library versions, pools, validation
folder/checkpoints/       periodic checkpoints, each a folder of `CHECKPOINT_FILES` (for --resume)
folder/tb/                TensorBoard logs
```

reward_curve.csv columns: timesteps, mean_episode_reward (training episodes that ended in this
update, raw return), train_success_rate, train_collision_rate, train_timeout_rate, train_episodes,
difficulty (curriculum), success_rate, collision_rate, eval_episodes (validation pool; empty on
rows without an evaluation), wall_s.

`rl.training.loop` writes a folder through `PolicyFolder`'s paths; `rl.pilots.learned.load_policy` flies one
(`FLYING_FILES`); `compare` fingerprints the flying files, takes a policy's vehicle and rates from
its config and draws its reward curve and provenance in the report.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rl.task.config import NavConfig
from uam_fdm.files.strict import json_object_file, strict_json_loads
from uam_fdm.vehicle.params import preset_names

MODEL = "model.zip"
OBS_NORM = "obs_norm.npz"
CONFIG = "config.json"
VEC_NORMALIZE = "vecnormalize.npz"
CURRICULUM = "curriculum.json"
REWARD_CURVE = "reward_curve.csv"
PROVENANCE = "provenance.json"
CHECKPOINTS = "checkpoints"
TENSORBOARD = "tb"

# What the learned pilot flies with (and a run's fingerprint records): network, statistics, task.
FLYING_FILES = (MODEL, OBS_NORM, CONFIG)
# What a checkpoint holds: the flying files and what resuming needs besides.
CHECKPOINT_FILES = (MODEL, VEC_NORMALIZE, OBS_NORM, CONFIG, CURRICULUM)
CURVE_COLUMNS = ("timesteps", "mean_episode_reward", "train_success_rate", "train_collision_rate",
                 "train_timeout_rate", "train_episodes", "difficulty", "success_rate", "collision_rate",
                 "eval_episodes", "wall_s")

POLICIES_DIR = Path(__file__).parent
DEFAULT_POLICY_DIR = POLICIES_DIR / "default"
# The shipped policies, by the vehicle preset each was trained for (its config.json says so too).
SHIPPED_POLICIES: dict[str, Path] = {"small_quad": DEFAULT_POLICY_DIR,
                                     "uam_multicopter": POLICIES_DIR / "uam"}


def shipped_policy_dir(vehicle: str) -> Path | None:
    """The shipped policy folder for vehicle preset `vehicle`, or None when none is shipped."""
    folder = SHIPPED_POLICIES.get(vehicle)
    return folder if folder is not None and PolicyFolder(folder).config_file.is_file() else None


MAX_LAYERS, MAX_UNITS = 8, 4096  # a network far beyond the paper's 2 x 128 is not a policy folder we wrote


@dataclass(frozen=True)
class NetworkConfig:
    """The policy network's shape: the paper's two dense layers of 128 units for the actor and for the
    critic (`rl.policies.network.ActorCritic`), and the initial log standard deviation of its actions.

    Attributes:
        net_arch: hidden units per layer (the same for actor and critic).
        log_std_init: initial log standard deviation of the Gaussian action noise.
    """

    net_arch: tuple[int, ...] = (128, 128)
    log_std_init: float = -1.0

    @classmethod
    def from_settings(cls, ppo: Mapping[str, Any]) -> NetworkConfig:
        """From config.json's "ppo" settings (the PPO preset's fields).

        Raises:
            KeyError, TypeError, ValueError: a setting missing or not a number (list) of the right kind.
        """
        arch, log_std = ppo["net_arch"], ppo["log_std_init"]
        if (not isinstance(arch, (list, tuple)) or not 1 <= len(arch) <= MAX_LAYERS
                or not all(isinstance(u, int) and not isinstance(u, bool) and 1 <= u <= MAX_UNITS for u in arch)):
            raise ValueError(f"ppo.net_arch must be 1 to {MAX_LAYERS} layer sizes of 1 to {MAX_UNITS} units, "
                             f"got {str(arch)[:80]}")
        if isinstance(log_std, bool) or not isinstance(log_std, (int, float)) or not -20.0 <= log_std <= 5.0:
            raise ValueError(f"ppo.log_std_init must be a number in [-20, 5], got {str(log_std)[:80]}")
        return cls(tuple(arch), float(log_std))

    def policy_kwargs(self) -> dict[str, Any]:
        """The network's arguments to an SB3 actor-critic policy (separate actor and critic layers)."""
        return {"net_arch": {"pi": list(self.net_arch), "vf": list(self.net_arch)}, "log_std_init": self.log_std_init}


@dataclass(frozen=True)
class PolicyConfig:
    """What config.json says a policy is.

    Attributes:
        nav: the task it was trained on (vehicle, rates, perception, route field, ...).
        ppo: the PPO settings it was trained with (`rl.training.ppo.PPOConfig`'s fields, and gamma).
        network: the network's shape, read from `ppo`.
        preset: the PPO preset's name.
    """

    nav: NavConfig
    ppo: Mapping[str, Any]
    network: NetworkConfig
    preset: str | None = None


@dataclass(frozen=True)
class Provenance:
    """What provenance.json records about the training run (None: not recorded, e.g. an older folder).

    Attributes:
        method: how it was trained ("PPO from scratch").
        preset: the PPO preset's name.
        seed: the run's seed.
        timesteps: decisions trained over the whole run.
        wall_time_s: the whole run's wall time [s].
        kept_timesteps: the timestep of the kept checkpoint (the folder's model).
        command: the command line that trained it.
        raw: everything the file holds (machine, versions, code, pools, validation of the kept model).
    """

    method: str | None = None
    preset: str | None = None
    seed: int | None = None
    timesteps: int | None = None
    wall_time_s: float | None = None
    kept_timesteps: int | None = None
    command: str | None = None
    raw: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Provenance:
        """From the parsed file; a value of the wrong type counts as not recorded."""
        def text(k: str) -> str | None:
            return d[k] if isinstance(d.get(k), str) else None

        return cls(method=text("method"), preset=text("preset"), seed=_integer(d.get("seed")),
                   timesteps=_integer(d.get("timesteps")), wall_time_s=_real(d.get("wall_time_s")),
                   kept_timesteps=_integer(d.get("kept_timesteps")), command=text("command"), raw=dict(d))


@dataclass(frozen=True)
class PolicyFolder:
    """A policy folder: the paths of its files, and its settings and provenance read as plain data.

    Attributes:
        path: the folder.
    """

    path: Path

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", Path(self.path))

    @classmethod
    def open(cls, folder: Path | str | None = None) -> PolicyFolder:
        """The folder a pilot flies (default: the shipped small-quad policy), its flying files present.

        Raises:
            ValueError: "<folder>: not a policy folder (<file> is missing)", the first missing one.
        """
        pf = cls(Path(folder) if folder is not None else DEFAULT_POLICY_DIR)
        for name in FLYING_FILES:
            if not (pf.path / name).is_file():
                raise ValueError(f"{pf.path}: not a policy folder ({name} is missing)")
        return pf

    @property
    def model(self) -> Path:
        return self.path / MODEL

    @property
    def obs_norm(self) -> Path:
        return self.path / OBS_NORM

    @property
    def config_file(self) -> Path:
        return self.path / CONFIG

    @property
    def vec_normalize(self) -> Path:
        return self.path / VEC_NORMALIZE

    @property
    def curriculum(self) -> Path:
        return self.path / CURRICULUM

    @property
    def reward_curve(self) -> Path:
        return self.path / REWARD_CURVE

    @property
    def provenance_file(self) -> Path:
        return self.path / PROVENANCE

    @property
    def checkpoints(self) -> Path:
        return self.path / CHECKPOINTS

    @property
    def tensorboard(self) -> Path:
        return self.path / TENSORBOARD

    def checkpoint(self, timesteps: int) -> PolicyFolder:
        """The checkpoint written after `timesteps` decisions (a policy folder of `CHECKPOINT_FILES`)."""
        return PolicyFolder(self.checkpoints / f"step_{timesteps:011d}")

    def config(self) -> PolicyConfig:
        """config.json's task and PPO settings.

        Raises:
            ValueError: "<folder>/config.json: not a policy configuration (<why>)".
        """
        try:
            cfg = strict_json_loads(self.config_file.read_text())
            nav = NavConfig.from_dict(cfg["nav"])
            ppo = cfg["ppo"]
            preset = cfg.get("preset")
            if not isinstance(ppo, dict):
                raise TypeError(f"'ppo' must be an object, got {type(ppo).__name__}")
            network = NetworkConfig.from_settings(ppo)
            if nav.vehicle not in preset_names():  # a policy names its preset, never a file elsewhere on the machine
                raise ValueError(f"nav.vehicle {str(nav.vehicle)[:80]!r} is not a vehicle preset "
                                 f"({', '.join(preset_names())})")
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{self.config_file}: not a policy configuration ({exc})") from None
        return PolicyConfig(nav, ppo, network, preset if isinstance(preset, str) else None)

    def provenance(self) -> Provenance | None:
        """provenance.json's record, or None when the folder has none (an older folder, or a run
        still training) or it holds an empty object.

        Raises:
            ValueError: the file exists but cannot be read or is not a JSON object (naming it).
        """
        path = self.provenance_file
        if not path.is_file():
            return None
        loaded = json_object_file(path)
        return Provenance.from_dict(loaded) if loaded else None


def _real(v: Any) -> float | None:
    """A JSON number as a float (not a boolean), else None."""
    return float(v) if not isinstance(v, bool) and isinstance(v, (int, float)) else None


def _integer(v: Any) -> int | None:
    """A JSON number with an integer value as an int, else None."""
    x = _real(v)
    return int(x) if x is not None and math.isfinite(x) and x.is_integer() else None
