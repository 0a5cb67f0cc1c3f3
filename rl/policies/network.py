"""The paper's policy network in plain PyTorch, to fly a trained policy without Stable-Baselines3.

Two dense layers of 128 tanh units for the actor and for the critic (`NetworkConfig`), the action mean
bounded by tanh (`rl.training.ppo.TanhMeanPolicy`, the class PPO trains, says why). The modules carry
SB3's actor-critic parameter names, so the `policy.pth` of a model.zip written by training loads into
it strictly (every name and shape checked); flying evaluates the actor's mean only, as SB3's
deterministic `predict` does (the same float32 layers in the same order, then the clip to the action
box), so the actions are the ones SB3 would give (tests/rl/policies). Importing this module loads
PyTorch, not Stable-Baselines3 (whose package imports its PPO): flying imports no training code.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn

from rl.policies.folder import NetworkConfig

ACTIONS = 3
"""The action: a 3D velocity command in the goal frame, each component in [-1, 1]."""


def _mlp(n_in: int, layers: tuple[int, ...]) -> nn.Sequential:
    """Dense layers with tanh activations (SB3's MlpExtractor with its default activation)."""
    mods: list[nn.Module] = []
    for n_out in layers:
        mods += [nn.Linear(n_in, n_out), nn.Tanh()]
        n_in = n_out
    return nn.Sequential(*mods)


class _Extractor(nn.Module):
    """The actor's and the critic's hidden layers (SB3's `mlp_extractor`)."""

    def __init__(self, n_obs: int, layers: tuple[int, ...]) -> None:
        super().__init__()
        self.policy_net = _mlp(n_obs, layers)
        self.value_net = _mlp(n_obs, layers)


class ActorCritic(nn.Module):
    """The policy network of a policy folder (parameter names as SB3's `ActorCriticPolicy`).

    Args:
        n_obs: observation size.
        config: the network's shape (config.json's "ppo").
    """

    def __init__(self, n_obs: int, config: NetworkConfig) -> None:
        super().__init__()
        last = config.net_arch[-1]
        self.log_std = nn.Parameter(torch.full((ACTIONS,), float(config.log_std_init)))
        self.mlp_extractor = _Extractor(n_obs, config.net_arch)
        self.action_net = nn.Sequential(nn.Linear(last, ACTIONS), nn.Tanh())
        self.value_net = nn.Linear(last, 1)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic actions (N, 3) float32 in [-1, 1] for normalised observations (N, obs) float32."""
        with torch.no_grad():
            mean = self.action_net(self.mlp_extractor.policy_net(torch.as_tensor(obs)))
        return np.clip(mean.numpy().reshape(-1, ACTIONS), -1.0, 1.0)
