"""`UAMNavVecEnv`: N vehicles as one Stable-Baselines3 `VecEnv`, stepped in one batched call.

The paper's parallel agents without N processes: one `NavBatch` steps every vehicle through the
compiled model at once. Slot i seeded with `seed + i` produces exactly the transitions of a
`UAMNavEnv` seeded with `seed + i` (tests/rl/env/test_nav_env.py). Finished episodes reset automatically
(SB3 convention): the returned observation is the new episode's first, the last one is in
`infos[i]["terminal_observation"]`, and `infos[i]["TimeLimit.truncated"]` marks time-outs.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices

from rl.env.gym_env import ACTION_SPACE, observation_space
from rl.env.world import NavBatch, NavWorld
from rl.task.config import FixedEpisodes, NavConfig


class UAMNavVecEnv(VecEnv):
    """N navigation episodes stepped together.

    Args:
        n_envs: number of vehicles.
        config: the task definition.
        seed: slot i is seeded with seed + i.
        fixed: scenario episodes instead of sampled ones.
        world: a prebuilt shared world.
    """

    def __init__(self, n_envs: int, config: NavConfig | None = None, seed: int = 0,
                 fixed: FixedEpisodes | None = None, world: NavWorld | None = None) -> None:
        self.world = world or NavWorld(config or NavConfig(), fixed)
        self.config = self.world.config
        self.render_mode = None
        super().__init__(int(n_envs), observation_space(self.world.obs_size), ACTION_SPACE)
        self.batch = NavBatch(self.world, self.num_envs)
        self._base_seed = int(seed)
        self._actions: np.ndarray | None = None

    @property
    def difficulty(self) -> float:
        """The curriculum's difficulty in (0, 1] (`NavBatch.difficulty`): the next episodes' leg lengths."""
        return float(self.batch.difficulty)

    @difficulty.setter
    def difficulty(self, value: float) -> None:
        self.batch.difficulty = value

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        if seed is not None:
            self._base_seed = int(seed)
        return [self._base_seed + i for i in range(self.num_envs)]

    def reset(self) -> np.ndarray:
        self.batch.seed([self._base_seed + i for i in range(self.num_envs)])
        self.batch.reset_slots(range(self.num_envs))
        return self.batch.observations.copy()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions, dtype=np.float64).reshape(self.num_envs, 3)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        """`VecEnv.step` (step_async, then step_wait), typed with this environment's array observations."""
        self.step_async(actions)
        return self.step_wait()

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        assert self._actions is not None, "step_async comes before step_wait"
        obs, rew, term, trunc, infos = self.batch.step(self._actions)
        done = term | trunc
        ended = np.flatnonzero(done)
        for i in ended:
            infos[i]["terminal_observation"] = obs[i]
            infos[i]["TimeLimit.truncated"] = bool(trunc[i] and not term[i])
            infos[i]["episode"] = {"r": float(self.batch.episode_return[i]), "l": int(self.batch.episode_len[i])}
        if len(ended):
            self.batch.reset_slots(ended)
            obs = self.batch.observations.copy()
        return obs, rew, done, infos

    def close(self) -> None:
        pass

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        value = getattr(self, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        raise AttributeError(f"UAMNavVecEnv has no per-env method {method_name!r}")

    def env_is_wrapped(self, wrapper_class, indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None for _ in range(self.num_envs)]
