"""`SplitVecEnv`: the N vehicles of a `UAMNavVecEnv` stepped by several processes, one share each.

One process steps its share of the batch while the others step theirs: on a machine of K cores the training's
environment runs about K times as fast (the network's update stays in the main process). This process keeps the
first share (its `world` is the one evaluation shares dynamics and air with); each other share is a
`UAMNavVecEnv` in a worker process (spawned: nothing of this process's state is inherited), seeded so that slot i
is seeded `seed + i` whichever process holds it. As a `UAMNavVecEnv` slot's episodes come from its own generator
alone, the split gives exactly the transitions of `UAMNavVecEnv(n_envs, config, seed)` (tested), whatever the
number of processes.

Generated cities only: a fixed set of episodes (`FixedEpisodes`) is dealt to slots by their index in one batch.

Held-out evaluations split the same way (`fly_held_out`): each process flies its share of the episodes with the
policy's weights, in an evaluation world of its own built as this process built its (the same cities, air and
turbulence, from the same configuration); an episode's slot is seeded by its index, so the run is the one a single
process flies (`rl.env.held_out`, tested).
"""
from __future__ import annotations

import multiprocessing as mp
import traceback
from collections.abc import Sequence
from multiprocessing.connection import Connection
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices

from rl.env.gym_env import ACTION_SPACE, observation_space
from rl.env.held_out import FlownEpisodes, PolicyWeights, fly_episodes, policy_pilot
from rl.env.vec_env import UAMNavVecEnv
from rl.env.world import NavWorld
from rl.task.config import NavConfig


def shares(n_envs: int, processes: int) -> list[int]:
    """The slots each of `processes` holds of `n_envs` (as even as can be, the first ones one more)."""
    base, extra = divmod(n_envs, processes)
    return [base + (k < extra) for k in range(processes)]


def evaluation_world(config: NavConfig, training: NavWorld) -> NavWorld:
    """The world of a training's held-out evaluation on `config` (its `eval_config`): the training world's dynamics
    and fields shared, its turbulence stacks reused where they are the same."""
    return NavWorld(config, dynamics=training.dynamics, atmosphere=training.atmospheres, wind_from=training)


def _serve(conn: Connection, n_envs: int, config: NavConfig, seed: int) -> None:
    """A worker process: one share of the slots, stepped on the main process's commands until "close"."""
    try:
        env = UAMNavVecEnv(n_envs, config, seed=seed)
        held_out: NavWorld | None = None  # the evaluation's world, built at the first evaluation
        conn.send(("ready", None))
        while True:
            command, value = conn.recv()
            if command == "step":
                conn.send(("ok", env.step(value)))
            elif command == "evaluate":
                eval_config, first, count, total, eval_seed, weights = value
                if held_out is None or held_out.config != eval_config:
                    held_out = evaluation_world(eval_config, env.world)
                conn.send(("ok", fly_episodes(policy_pilot(weights, first, total), held_out, first, count,
                                              eval_seed)))
            elif command == "reset":
                conn.send(("ok", env.reset()))
            elif command == "difficulty":
                env.batch.difficulty = value
                conn.send(("ok", None))
            elif command == "close":
                conn.send(("ok", None))
                return
            else:
                raise ValueError(f"unknown command {command!r}")
    except Exception:  # said in the main process, which raises it there
        conn.send(("error", traceback.format_exc()))
    finally:
        conn.close()


class SplitVecEnv(VecEnv):
    """`UAMNavVecEnv(n_envs, config, seed)` stepped by `processes` processes (this one included).

    Args:
        n_envs: vehicles in all.
        config: the task definition (generated cities).
        seed: slot i is seeded with seed + i.
        processes: processes stepping the slots, this one included (1: all here, as `UAMNavVecEnv`).

    Raises:
        ValueError: `processes` outside [1, n_envs].
        RuntimeError: a worker process failed (its traceback in the message).
    """

    def __init__(self, n_envs: int, config: NavConfig, seed: int = 0, processes: int = 2) -> None:
        self._conns: list[Connection] = []
        self._procs: list[Any] = []
        self._closed = False
        n_envs, processes = int(n_envs), int(processes)
        if not 1 <= processes <= n_envs:
            raise ValueError(f"processes must be in [1, {n_envs}] for {n_envs} vehicles, got {processes}")
        sizes = shares(n_envs, processes)
        firsts = np.cumsum([0] + sizes).tolist()
        ctx = mp.get_context("spawn")
        try:
            for size, first in zip(sizes[1:], firsts[1:-1]):  # the workers build while this process builds its own
                here, there = ctx.Pipe()
                proc = ctx.Process(target=_serve, args=(there, size, config, seed + first), daemon=True)
                proc.start()
                there.close()
                self._conns.append(here)
                self._procs.append(proc)
            self.local = UAMNavVecEnv(sizes[0], config, seed=seed)
            for conn in self._conns:
                self._answer(conn)
        except BaseException:
            self.close()
            raise
        self.world: NavWorld = self.local.world
        self.config = self.local.config
        self.render_mode = None
        self._sizes, self._seed = sizes, int(seed)
        super().__init__(n_envs, observation_space(self.world.obs_size), ACTION_SPACE)
        self._actions: np.ndarray | None = None

    @staticmethod
    def _answer(conn: Connection) -> Any:
        """A worker's reply to its last command, or its failure raised here."""
        try:
            status, value = conn.recv()
        except EOFError:
            raise RuntimeError("an environment worker process ended without a reply") from None
        if status == "error":
            raise RuntimeError(f"an environment worker process failed:\n{value}")
        return value

    def _all(self, command: str, values: Sequence[Any] | None = None) -> None:
        """Send `command` to every worker (each its own value), without waiting."""
        for k, conn in enumerate(self._conns):
            conn.send((command, None if values is None else values[k]))

    @property
    def difficulty(self) -> float:
        """The curriculum's difficulty in (0, 1], every share's (`NavBatch.difficulty`)."""
        return float(self.local.batch.difficulty)

    @difficulty.setter
    def difficulty(self, value: float) -> None:
        self._all("difficulty", [value] * len(self._conns))
        self.local.batch.difficulty = value
        for conn in self._conns:
            self._answer(conn)

    def reset(self) -> np.ndarray:
        self._all("reset")
        parts = [self.local.reset()] + [self._answer(conn) for conn in self._conns]
        return np.concatenate(parts)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions, dtype=np.float64).reshape(self.num_envs, 3)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        assert self._actions is not None, "step_async comes before step_wait"
        cuts = np.cumsum(self._sizes)[:-1]
        own, *theirs = np.split(self._actions, cuts)
        self._all("step", theirs)  # they step while this process steps its own share
        parts = [self.local.step(own)] + [self._answer(conn) for conn in self._conns]
        obs = np.concatenate([p[0] for p in parts])
        rew = np.concatenate([p[1] for p in parts])
        done = np.concatenate([p[2] for p in parts])
        infos = [info for p in parts for info in p[3]]
        return obs, rew, done, infos

    def fly_held_out(self, world: NavWorld, episodes: int, seed: int, weights: PolicyWeights) -> FlownEpisodes:
        """Fly held-out episodes 0 .. episodes - 1 of `world` (`rl.env.held_out.fly_episodes`) with the policy
        `weights`, each process its share (this one the first, in `world`; the others in worlds they build from
        `world.config` as `evaluation_world` builds it, which `world` must have been built by).

        Raises:
            ValueError: fewer episodes than processes.
            RuntimeError: a worker process failed (its traceback in the message).
        """
        processes = len(self._conns) + 1
        if episodes < processes:
            raise ValueError(f"{episodes} episodes cannot be shared by {processes} processes")
        sizes = shares(episodes, processes)
        firsts = np.cumsum([0] + sizes).tolist()
        self._all("evaluate", [(world.config, first, size, episodes, seed, weights)
                               for first, size in zip(firsts[1:-1], sizes[1:])])
        own = fly_episodes(policy_pilot(weights, 0, episodes), world, 0, sizes[0], seed)  # the others fly theirs
        return FlownEpisodes.joined([own] + [self._answer(conn) for conn in self._conns])

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for conn in self._conns:
            try:
                conn.send(("close", None))
                conn.recv()
            except (EOFError, OSError, BrokenPipeError):
                pass
            conn.close()
        for proc in self._procs:
            proc.join(timeout=10)
            if proc.is_alive():
                proc.kill()

    def __del__(self) -> None:
        self.close()

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """The slots' seeds (SB3 gives the model's seed here; the slots are seeded when built, so only that)."""
        if seed is not None and int(seed) != self._seed:
            raise ValueError(f"SplitVecEnv is seeded when built (slot i with {self._seed} + i), not with {seed}")
        return [self._seed + i for i in range(self.num_envs)]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        value = getattr(self, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        raise AttributeError(f"SplitVecEnv sets no attribute {attr_name!r} across its processes")

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        raise AttributeError(f"SplitVecEnv has no per-env method {method_name!r}")

    def env_is_wrapped(self, wrapper_class, indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None for _ in range(self.num_envs)]
