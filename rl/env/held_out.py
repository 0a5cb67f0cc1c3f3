"""Held-out episodes flown by a batched pilot: episode i in the world's city i (cycled), its slot seeded seed + i, so
that any share of the episodes, flown in any process, gives each episode exactly as the whole batch would (a
slot's episode comes from its own generator and its city alone; tested across processes).

`fly_episodes` flies a share; `PolicyWeights` carries a policy between processes (its network's weights and its
observation statistics, plain arrays) and `policy_pilot` flies it as `rl.policies.network.ActorCritic`, the actions
SB3's deterministic `predict` gives.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from rl.env.world import NavBatch, NavWorld
from rl.policies.folder import NetworkConfig
from rl.policies.reader import ObsNorm

BatchedPilot = Callable[[np.ndarray, NavBatch], np.ndarray]
"""A pilot flying a whole batch, for evaluation (not a `uam_fdm.pilot.Pilot`): (raw observations (N, obs),
the batch) -> actions (N, 3) in [-1, 1]."""

Progress = Callable[[int, int], object]
"""Told how an evaluation goes: (episodes ended so far, episodes in all), each time more have ended."""


@dataclass(frozen=True)
class FlownEpisodes:
    """How a run of held-out episodes ended, in episode order.

    Attributes:
        outcomes: each episode's outcome; returns: (n,) episode returns; times_s: (n,) flight times [s].
        levels: each episode's (sensing level, map-error level).
    """

    outcomes: tuple[str, ...]
    returns: np.ndarray
    times_s: np.ndarray
    levels: tuple[tuple[str, str], ...]

    @staticmethod
    def joined(parts: Sequence[FlownEpisodes]) -> FlownEpisodes:
        """Consecutive shares as one run, in their order."""
        return FlownEpisodes(tuple(o for p in parts for o in p.outcomes), np.concatenate([p.returns for p in parts]),
                             np.concatenate([p.times_s for p in parts]), tuple(lv for p in parts for lv in p.levels))


def fly_episodes(pilot: BatchedPilot, world: NavWorld, first: int, count: int, seed: int,
                 progress: Progress | None = None) -> FlownEpisodes:
    """Fly episodes first .. first + count - 1 at once, deterministically: episode i in city i (mod the world's
    cities), its slot seeded seed + i.

    Args:
        pilot: (observations, batch) -> actions.
        world: the world whose cities the episodes fly.
        first, count: the share's first episode and how many (count >= 1).
        seed: episode i's slot is seeded seed + i.
        progress: told (ended, count) after each decision in which episodes ended.
    """
    batch = NavBatch(world, count)
    batch.city_of_slot = (first + np.arange(count)) % len(world.cities)
    batch.seed([seed + first + i for i in range(count)])
    batch.reset_slots(range(count))
    obs = batch.observations.copy()
    done = np.zeros(count, dtype=bool)
    outcomes: list[str] = [""] * count
    levels: list[tuple[str, str]] = [("", "")] * count
    returns = np.zeros(count)
    times = np.zeros(count)
    while not done.all():
        # an episode that ended stays where it ended: only those still flying fly (their numbers are the same)
        obs, _, term, trunc, infos = batch.step(pilot(obs, batch), active=~done)
        d = term | trunc
        ended = np.flatnonzero(d & ~done)
        for i in ended:
            outcomes[i] = infos[i]["outcome"]
            levels[i] = (infos[i]["sensing"], infos[i]["map_error"])
            returns[i] = batch.episode_return[i]
            times[i] = infos[i]["t_s"]
        done |= d
        if progress is not None and len(ended):
            progress(int(done.sum()), count)
    return FlownEpisodes(tuple(outcomes), returns, times, tuple(levels))


@dataclass(frozen=True)
class PolicyWeights:
    """A policy as plain data, to fly in another process: its observation size, network shape, parameters (SB3's
    names, as `rl.policies.network.ActorCritic` loads them) and observation statistics.

    Attributes:
        n_obs: observation size. network: the network's shape.
        state: parameter name -> array (a copy: the process that trains goes on changing its own).
        obs_norm: the observation statistics frozen at the time (copies).
    """

    n_obs: int
    network: NetworkConfig
    state: Mapping[str, np.ndarray]
    obs_norm: ObsNorm

    @staticmethod
    def of(policy_state: Mapping[str, object], n_obs: int, network: NetworkConfig, obs_norm: ObsNorm
           ) -> PolicyWeights:
        """From a PyTorch state dict (tensors) and the live statistics, copied."""
        state = {k: np.array(v.detach().cpu().numpy() if hasattr(v, "detach") else v, copy=True)
                 for k, v in policy_state.items()}
        frozen = ObsNorm(np.array(obs_norm.mean, copy=True), np.array(obs_norm.var, copy=True), obs_norm.count,
                         obs_norm.epsilon, obs_norm.clip_obs)
        return PolicyWeights(int(n_obs), network, state, frozen)


def policy_pilot(weights: PolicyWeights, first: int = 0, total: int | None = None) -> BatchedPilot:
    """`weights` flown deterministically: the normalised observation through the actor's float32 layers, the clip to
    the action box (`rl.policies.network.ActorCritic.act`: SB3's deterministic `predict`).

    Args:
        weights: the policy.
        first, total: the pilot flies episodes first .. of a run of `total` (None: the batch is the whole run). Its
            rows then stand at their episodes' places in a batch of `total` rows: a float32 matrix product's row can
            change in its last bits with the batch's size and the row's place in it, and so, over a flight, the
            episode; placed so, a share's episodes fly as in the whole run.
    """
    import torch  # PyTorch: only where a policy flies

    from rl.policies.network import ActorCritic

    with torch.random.fork_rng(devices=[]):  # its initial weights, overwritten below, draw nothing from a training's
        net = ActorCritic(weights.n_obs, weights.network)
    net.load_state_dict({k: torch.as_tensor(v) for k, v in weights.state.items()}, strict=True)
    net.eval()

    def pilot(obs: np.ndarray, _batch: NavBatch) -> np.ndarray:
        z = weights.obs_norm.normalize(obs)
        if total is None:
            return net.act(z)
        rows = np.zeros((total, z.shape[1]), dtype=z.dtype)
        rows[first:first + len(z)] = z
        return net.act(rows)[first:first + len(z)]

    return pilot
