"""Reading a policy folder without running code from it: weights, statistics and settings as plain data.

A policy folder is shared between researchers, so loading one must not execute anything it holds.
SB3's own `PPO.load` unpickles the entries of `model.zip`'s `data` (spaces, schedules, buffers) and
`VecNormalize.load` unpickles a whole object; a crafted file runs arbitrary code in either. Here:

- the network's weights come from `model.zip`'s `policy.pth` through `torch.load(weights_only=True)`
  (tensors only) into a network built from `config.json`;
- normalisation statistics are `.npz` arrays read with `allow_pickle=False`;
- resuming training (`rl.training.checkpoints`) loads `model.zip` through `PPO.load` with *every* pickled entry
  of `data`
  replaced by an object built here (`custom_objects`, which SB3 uses instead of unpickling), and
  refuses a file with a pickled entry it does not know.
"""
from __future__ import annotations

import io
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rl.policies.folder import NetworkConfig
from uam_fdm.files.atomic import atomic_open
from uam_fdm.files.npz import npz_read_errors

if TYPE_CHECKING:  # PyTorch loads only with a network
    import torch

    from rl.policies.network import ActorCritic

OBS_NORM_KEYS = ("mean", "var", "count", "epsilon", "clip_obs")


def load_arrays(path: Path, keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The arrays `keys` of an `.npz` file, read without unpickling; all finite.

    Raises:
        ValueError: the file is missing, not an npz, holds objects, lacks a key or has a non-finite
            value (naming the file and the key).
    """
    path = Path(path)
    with npz_read_errors(path, "plain-number"), np.load(path, allow_pickle=False) as z:
        missing = [k for k in keys if k not in z.files]
        if missing:
            raise ValueError(f"{path}: missing arrays {missing}")
        out = {k: np.array(z[k], dtype=np.float64) for k in keys}
    for k, v in out.items():
        if not np.isfinite(v).all():
            raise ValueError(f"{path}: array {k!r} has non-finite values")
    return out


@dataclass(frozen=True, eq=False)
class ObsNorm:
    """A policy's observation-normalisation statistics (SB3 VecNormalize's, frozen), `obs_norm.npz`.

    Attributes:
        mean, var: (obs,) running mean and variance of the raw observations.
        count: observations the statistics were estimated from.
        epsilon: added to the variance; clip_obs: normalised observations are clipped to +-this.
    """

    mean: np.ndarray
    var: np.ndarray
    count: float
    epsilon: float
    clip_obs: float

    @classmethod
    def load(cls, path: Path) -> ObsNorm:
        """Read `obs_norm.npz` (`load_arrays`: no unpickling, all finite).

        Raises:
            ValueError: as `load_arrays`, naming the file.
        """
        a = load_arrays(path, OBS_NORM_KEYS)
        return cls(a["mean"], a["var"], float(a["count"]), float(a["epsilon"]), float(a["clip_obs"]))

    @classmethod
    def of(cls, venv_norm: Any) -> ObsNorm:
        """The current statistics of a training VecNormalize (shared arrays, not copies)."""
        rms = venv_norm.obs_rms
        return cls(rms.mean, rms.var, float(rms.count), float(venv_norm.epsilon), float(venv_norm.clip_obs))

    def save(self, path: Path) -> None:
        """Write them as `obs_norm.npz` (plain arrays, atomic)."""
        with atomic_open(path, "wb") as f:
            np.savez(f, mean=self.mean, var=self.var, count=self.count, epsilon=self.epsilon, clip_obs=self.clip_obs)

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        """SB3 VecNormalize's observation transform with these frozen statistics: (N, obs) -> float32."""
        z = (obs - self.mean) / np.sqrt(self.var + self.epsilon)
        return np.clip(z, -self.clip_obs, self.clip_obs).astype(np.float32)


def zip_entry(path: Path, name: str) -> bytes:
    """The bytes of entry `name` of the zip file `path` (ValueError naming both when absent or unreadable)."""
    try:
        with zipfile.ZipFile(path) as z:
            if name not in z.namelist():
                raise ValueError(f"{path}: no {name!r} inside (not a model written by `uam-compare train`?)")
            return z.read(name)
    except (OSError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: not a readable zip file ({exc})") from None


def policy_weights(path: Path) -> dict[str, torch.Tensor]:
    """The tensors of `model.zip`'s `policy.pth` at `path` (SB3 parameter names), read as tensors only.

    Raises:
        ValueError: the file is unreadable, holds anything but tensors or a non-finite weight (naming it).
    """
    # PyTorch is loaded only here: reading a folder's statistics and settings (fingerprints, reports) needs none
    import torch

    raw = zip_entry(path, "policy.pth")
    try:
        state = torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises UnpicklingError, RuntimeError, ... for a bad file
        raise ValueError(f"{path}: policy.pth holds something other than tensors; "
                         f"refused ({type(exc).__name__})") from None
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise ValueError(f"{path}: policy.pth is not a table of tensors")
    bad = next((k for k, v in state.items() if v.is_floating_point() and not bool(torch.isfinite(v).all())), None)
    if bad is not None:
        raise ValueError(f"{path}: policy.pth's {str(bad)[:80]} holds non-finite weights")
    return state


def network_shape(path: Path) -> tuple[int, tuple[int, ...]]:
    """What `model.zip`'s weights at `path` take and are: (observation size, the actor's units per hidden layer).

    Raises:
        ValueError: as `policy_weights`, or the weights hold no actor layers of the paper's network (naming it).
    """
    state = policy_weights(path)
    layers: list[torch.Tensor] = []
    while (w := state.get(f"mlp_extractor.policy_net.{2 * len(layers)}.weight")) is not None and w.ndim == 2:
        layers.append(w)
    if not layers:
        raise ValueError(f"{path}: policy.pth holds no actor layers (mlp_extractor.policy_net)")
    return int(layers[0].shape[1]), tuple(int(w.shape[0]) for w in layers)


def load_network(path: Path, n_obs: int, config: NetworkConfig) -> ActorCritic:
    """The actor-critic of `model.zip` at `path`, built from settings and filled with its weights only.

    Args:
        n_obs: observation size the network must take; config: the network's shape (config.json's "ppo").

    Raises:
        ValueError: the file is unreadable, holds anything but tensors, or its weights do not fit
            the network (e.g. another observation size; both sizes named).
    """
    from rl.policies.network import ActorCritic

    state = policy_weights(path)
    first = state.get("mlp_extractor.policy_net.0.weight")
    if first is not None and first.shape[1] != n_obs:
        raise ValueError(f"{path}: the network takes {first.shape[1]} observations; "
                         f"the task (config.json) gives {n_obs}")
    net = ActorCritic(n_obs, config)
    try:
        net.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        raise ValueError(f"{path}: weights do not fit the network of config.json ({exc})") from None
    return net.eval()
