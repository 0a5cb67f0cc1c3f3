"""The PPO presets the learned pilot is trained with, as plain settings: reading them (a training config, the
command line's help) needs neither PyTorch nor Stable-Baselines3 (`rl.training.ppo` builds the model)."""
from __future__ import annotations

from dataclasses import dataclass

from rl.policies.folder import NetworkConfig


@dataclass(frozen=True)
class PPOConfig:
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
    log_std_end: float | None = None  # the exploration noise's cap at the run's end (None: no cap; `log_std_cap`)
    target_kl: float | None = None

    def __post_init__(self) -> None:
        if self.log_std_end is not None and not -20.0 <= self.log_std_end <= self.log_std_init:
            raise ValueError(f"log_std_end must be in [-20, log_std_init = {self.log_std_init:g}], got "
                             f"{self.log_std_end!r}")

    def log_std_cap(self, fraction_done: float) -> float | None:
        """The most the policy's log standard deviation may be after `fraction_done` of the run (0..1): falling
        linearly from `log_std_init` to `log_std_end`, so the exploration noise shrinks however the policy learns
        it (it may shrink faster on its own). None: no cap."""
        if self.log_std_end is None:
            return None
        f = min(max(float(fraction_done), 0.0), 1.0)
        return self.log_std_init + (self.log_std_end - self.log_std_init) * f

    @property
    def network(self) -> NetworkConfig:
        """The policy network's shape (written into config.json with the other settings)."""
        return NetworkConfig(self.net_arch, self.log_std_init)

    def learning_rate_schedule(self) -> float | LinearSchedule:
        """The learning rate SB3 gets: constant, or falling linearly to `learning_rate_end` over the run."""
        return self.learning_rate if self.learning_rate_end is None else \
            LinearSchedule(self.learning_rate, self.learning_rate_end)

    def minibatch_size(self, n_envs: int) -> int:
        """The mini-batch PPO takes with `n_envs` vehicles: `batch_size`, or the rollout (`n_steps` x `n_envs`
        decisions) when that is smaller, or else the largest divisor of the rollout under `batch_size`, so that
        every mini-batch of an epoch is whole.

        Raises:
            ValueError: no divisor of the rollout reaches half of `batch_size` (an `n_envs` with a large prime
                factor), naming `n_envs` and counts that work.
        """
        rollout = self.n_steps * n_envs
        if rollout <= self.batch_size:
            return rollout
        size = max(d for d in range(1, self.batch_size + 1) if rollout % d == 0)
        if 2 * size < self.batch_size:
            raise ValueError(f"n_envs {n_envs}: its rollout of {rollout} decisions ({self.n_steps} per vehicle) "
                             f"splits into mini-batches of {size} at most, far under {self.batch_size}; give at "
                             f"most {self.batch_size // self.n_steps} vehicles or a multiple of "
                             f"{self.batch_size // self.n_steps}")
        return size

    def gamma(self, decision_hz: float) -> float:
        """The discount per decision at `decision_hz` [Hz] (0.99 at 10 Hz): the same horizon in
        seconds at any decision rate, as the reward is per second."""
        return 1.0 - 1.0 / (self.horizon_s * decision_hz)


PRESETS: dict[str, PPOConfig] = {
    "paper": PPOConfig(),
    # the same PPO whose exploration noise is capped by a falling ceiling: std e^-1 = 0.37 of the action range at
    # the start to e^-3 = 0.05 at the end (the shipped quad policy learned its horizontal noise down to about that
    # by itself; the UAM's stayed at e^-1.5 = 0.22)
    "paper-shrinking-noise": PPOConfig(log_std_end=-3.0),
}


class LinearSchedule:
    """Learning rate falling linearly from `start` to `end` over the run (SB3 passes the fraction left)."""

    def __init__(self, start: float, end: float) -> None:
        self.start, self.end = float(start), float(end)

    def __call__(self, progress_remaining: float) -> float:
        return self.end + (self.start - self.end) * progress_remaining
