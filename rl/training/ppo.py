"""PPO as the learned pilot is trained with it (Stable-Baselines3): the presets, the model and its
normalised environment. The network is the paper's (shape `NetworkConfig`; flown by `rl.policies.network`)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from stable_baselines3 import PPO
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env import VecEnv, VecNormalize
from torch import nn

from rl.policies.folder import NetworkConfig


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


@dataclass(frozen=True)
class PPOPreset:
    """PPO settings. `paper`: the original demo's network (two dense layers of 128 units) and clip 0.2;
    the rest chosen by measurement at 10 Hz decisions (docs/learned_pilot.md)."""

    net_arch: tuple[int, ...] = NetworkConfig.net_arch
    clip_range: float = 0.2
    learning_rate: float = 3e-4
    learning_rate_end: float | None = 0.0  # linear decay to this over the run (None: constant)
    n_steps: int = 64
    batch_size: int = 4096
    n_epochs: int = 5
    horizon_s: float = 10.0  # the discount's horizon in flight seconds: γ = 1 - 1 / (horizon_s x decision_hz)
    gae_lambda: float = 0.95
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    log_std_init: float = NetworkConfig.log_std_init
    target_kl: float | None = None

    @property
    def network(self) -> NetworkConfig:
        """The policy network's shape (written into config.json with the other settings)."""
        return NetworkConfig(self.net_arch, self.log_std_init)

    def learning_rate_schedule(self) -> float | LinearSchedule:
        """The learning rate SB3 gets: constant, or falling linearly to `learning_rate_end` over the run."""
        return self.learning_rate if self.learning_rate_end is None else \
            LinearSchedule(self.learning_rate, self.learning_rate_end)

    def gamma(self, decision_hz: float) -> float:
        """The discount per decision at `decision_hz` [Hz] (0.99 at 10 Hz): the same horizon in
        seconds at any decision rate, as the reward is per second."""
        return 1.0 - 1.0 / (self.horizon_s * decision_hz)


PRESETS: dict[str, PPOPreset] = {"paper": PPOPreset()}




class LinearSchedule:
    """Learning rate falling linearly from `start` to `end` over the run (SB3 passes the fraction left)."""

    def __init__(self, start: float, end: float) -> None:
        self.start, self.end = float(start), float(end)

    def __call__(self, progress_remaining: float) -> float:
        return self.end + (self.start - self.end) * progress_remaining


def normalized_env(base: VecEnv, preset: PPOPreset, decision_hz: float) -> VecNormalize:
    """`base` (a VecEnv) behind SB3's VecNormalize: observations and rewards, as training uses it."""
    return VecNormalize(base, norm_obs=True, norm_reward=True, clip_obs=10.0, gamma=preset.gamma(decision_hz))


def make_model(preset: PPOPreset, venv: VecEnv, seed: int, decision_hz: float, tb: Path | None = None) -> PPO:
    """A fresh PPO model of `preset` (tanh-bounded mean, separate 2-layer actor and critic) on `venv`."""
    return PPO(
        TanhMeanPolicy, venv, learning_rate=preset.learning_rate_schedule(), n_steps=preset.n_steps,
        batch_size=preset.batch_size, n_epochs=preset.n_epochs, gamma=preset.gamma(decision_hz),
        gae_lambda=preset.gae_lambda, clip_range=preset.clip_range, ent_coef=preset.ent_coef,
        vf_coef=preset.vf_coef, max_grad_norm=preset.max_grad_norm, target_kl=preset.target_kl, seed=seed,
        device="cpu", policy_kwargs=preset.network.policy_kwargs(),
        tensorboard_log=str(tb) if tb is not None else None, verbose=0)
