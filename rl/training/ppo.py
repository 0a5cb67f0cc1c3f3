"""PPO as the learned pilot is trained with it (Stable-Baselines3): the presets, the model and its
normalised environment. The network is the paper's (shape `NetworkConfig`; flown by `rl.policies.network`)."""
from __future__ import annotations

from pathlib import Path

from stable_baselines3 import PPO
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env import VecEnv, VecNormalize
from torch import nn

from rl.training.presets import PRESETS, LinearSchedule, PPOConfig

__all__ = ["PRESETS", "LinearSchedule", "PPOConfig", "TanhMeanPolicy", "make_model", "normalized_env"]
# LinearSchedule stays importable here: the shipped policies' model.zip pickle it as rl.training.ppo.LinearSchedule


class TanhMeanPolicy(ActorCriticPolicy):
    """`MlpPolicy` whose Gaussian mean is tanh(linear(latent)), inside [-1, 1]: the network PPO trains.

    SB3's Gaussian policy has an unbounded mean and clips actions to [-1, 1] only in the
    environment. Measured here: after 12 M steps more than half of the horizontal action means sat
    beyond ±1 (up to ±2.2), so the vehicle flew bang-bang at full speed and the clipped actions gave
    PPO no gradient to brake near buildings (41 % collisions). A tanh on the mean keeps it inside the
    action box, where the velocity command responds to it; exploration noise is unchanged.
    """

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        # Same Linear (and parameters, already in the optimizer), followed by tanh.
        self.action_net = nn.Sequential(self.action_net, nn.Tanh())


def normalized_env(base: VecEnv, preset: PPOConfig, decision_hz: float) -> VecNormalize:
    """`base` (a VecEnv) behind SB3's VecNormalize: observations and rewards, as training uses it."""
    return VecNormalize(base, norm_obs=True, norm_reward=True, clip_obs=10.0, gamma=preset.gamma(decision_hz))


def make_model(preset: PPOConfig, venv: VecEnv, seed: int, decision_hz: float, tb: Path | None = None) -> PPO:
    """A fresh PPO model of `preset` (tanh-bounded mean, separate 2-layer actor and critic) on `venv`, its
    mini-batch fitted to the vehicles (`PPOConfig.minibatch_size`)."""
    return PPO(
        TanhMeanPolicy, venv, learning_rate=preset.learning_rate_schedule(), n_steps=preset.n_steps,
        batch_size=preset.minibatch_size(venv.num_envs), n_epochs=preset.n_epochs, gamma=preset.gamma(decision_hz),
        gae_lambda=preset.gae_lambda, clip_range=preset.clip_range, ent_coef=preset.ent_coef,
        vf_coef=preset.vf_coef, max_grad_norm=preset.max_grad_norm, target_kl=preset.target_kl, seed=seed,
        device="cpu", policy_kwargs=preset.network.policy_kwargs(),
        tensorboard_log=str(tb) if tb is not None else None, verbose=0)
