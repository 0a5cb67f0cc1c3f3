"""One training run's settings: the task, the PPO preset, the success-gated curriculum, evaluation and checkpoints."""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from rl.task.config import NavConfig
from rl.training.presets import PRESETS

MAX_RECORDED_FLIGHTS = 64  # the recorded tasks are meant to be looked at, one by one
MAX_ENV_PROCESSES = 64  # processes stepping a training batch (`rl.env.split_vec_env`): far beyond one machine


@dataclass(frozen=True)
class Curriculum:
    """Success-gated task difficulty (`TaskDistribution.sample`'s `difficulty`, the leg length).

    Starts at `start`; whenever the success rate of the last `window` training episodes reaches
    `gate`, the difficulty rises by `step` (to 1 at most; the window then starts afresh).
    `level_steps` > 0 also raises it once a level has lasted that many timesteps: across the air,
    exploration noise in thin air and gusts can hold training success under the gate long after
    the deterministic policy flies full-length legs, and the gate alone then spends most
    of a run on short legs. `start` = 1 turns the curriculum off.
    """

    start: float = 0.25
    step: float = 0.25
    gate: float = 0.8
    window: int = 512
    level_steps: int = 0  # timesteps a level lasts at most (0: until the gate is met)

    def __post_init__(self) -> None:
        if not (0 < self.start <= 1 and 0 < self.step <= 1 and 0 < self.gate <= 1 and self.window >= 1
                and self.level_steps >= 0):
            raise ValueError(f"curriculum needs 0 < start, step, gate <= 1, window >= 1 and level_steps >= 0; "
                             f"got {self}")


@dataclass(frozen=True)
class TrainConfig:
    """One training run.

    Attributes:
        preset: PPO preset name (see PRESETS).
        total_timesteps: decisions to train for (all vehicles together).
        n_envs: vehicles stepped together.
        seed: the one seed (environment slots, PPO's torch and numpy generators, evaluation).
        nav: the task definition (training cities).
        curriculum: the success-gated difficulty schedule.
        eval_every: evaluate on validation cities every this many timesteps; eval_episodes: episodes each.
        collision_weight: the kept checkpoint maximises validation success - collision_weight x
            collision rate (a crash costs more than a time-out: it is the failure a user cannot accept).
        checkpoint_every: save a checkpoint every this many timesteps (0 = never).
        torch_threads: torch intra-op threads (1: small-tensor work is fastest single-threaded here).
        record_flights: fixed validation tasks flown and recorded at step 0 and at every evaluation
            (`rl.training.recording`; 0 = none).
        env_processes: processes stepping the vehicles (`rl.env.split_vec_env`; 1: all in this one). The
            transitions are the same for any count (generated cities; a scenario's run steps in one process).
        scenario: the scenario file whose map and air the run trains and validates in (`rl.env.ground`; its
            ground is given to `rl.training.loop.train`), as the user named it; None: generated cities.
    """

    preset: str = "paper"
    total_timesteps: int = 10_000_000
    n_envs: int = 256
    seed: int = 0
    nav: NavConfig = field(default_factory=NavConfig)
    curriculum: Curriculum = field(default_factory=Curriculum)
    eval_every: int = 1_000_000
    eval_episodes: int = 500
    collision_weight: float = 2.0
    checkpoint_every: int = 2_000_000
    torch_threads: int = 1
    record_flights: int = 8
    env_processes: int = 1
    scenario: str | None = None

    def __post_init__(self) -> None:
        if self.preset not in PRESETS:
            raise ValueError(f"unknown preset {self.preset!r}; choose from {sorted(PRESETS)}")
        for k in ("total_timesteps", "n_envs", "eval_every", "eval_episodes"):
            if getattr(self, k) < 1:
                raise ValueError(f"{k} must be >= 1, got {getattr(self, k)}")
        if not 1 <= self.env_processes <= min(self.n_envs, MAX_ENV_PROCESSES):
            raise ValueError(f"env_processes must be 1 to {min(self.n_envs, MAX_ENV_PROCESSES)} (at most one per "
                             f"vehicle), got {self.env_processes}")
        if not 0 <= self.record_flights <= MAX_RECORDED_FLIGHTS:
            raise ValueError(f"record_flights must be 0 to {MAX_RECORDED_FLIGHTS}, got {self.record_flights}")
        if not (np.isfinite(self.collision_weight) and self.collision_weight >= 0):
            raise ValueError(f"collision_weight must be a finite number >= 0, got {self.collision_weight!r}")
        PRESETS[self.preset].minibatch_size(self.n_envs)  # the vehicles split the rollout into whole mini-batches

    def to_dict(self) -> dict:
        d = asdict(self)
        preset = PRESETS[self.preset]
        d["ppo"] = asdict(preset)
        d["ppo"]["gamma"] = preset.gamma(self.nav.decision_hz)
        d["ppo"]["batch_size"] = preset.minibatch_size(self.n_envs)  # what PPO took with these vehicles
        return d

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        d = {k: v for k, v in d.items() if k != "ppo"}
        d["nav"] = NavConfig.from_dict(d["nav"])
        if "curriculum" in d:
            d["curriculum"] = Curriculum(**d["curriculum"])
        return cls(**d)
