"""The policy network: SB3's actor-critic MLP with the action mean bounded by tanh.

SB3's Gaussian policy has an unbounded mean and clips actions to [-1, 1] only in the
environment. Measured here: after 12 M steps more than half of the horizontal action means sat
beyond ±1 (up to ±2.2), so the vehicle flew bang-bang at full speed and the clipped actions gave
PPO no gradient to brake near buildings (41 % collisions). A tanh on the mean keeps it inside the
action box, where the velocity command responds to it; exploration noise is unchanged.
"""
from __future__ import annotations

from stable_baselines3.common.policies import ActorCriticPolicy
from torch import nn


class TanhMeanPolicy(ActorCriticPolicy):
    """`MlpPolicy` whose Gaussian mean is tanh(linear(latent)), inside [-1, 1]."""

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        # Same Linear (and parameters, already in the optimizer), followed by tanh.
        self.action_net = nn.Sequential(self.action_net, nn.Tanh())
