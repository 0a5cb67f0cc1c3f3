"""`UAMNav-v0`: one multirotor flying to a goal through a city, as a gymnasium environment.

The observation, action and reward are documented in `rl.sensing.observation` and `rl.task.reward`;
the episode mechanics in `rl.env.world`. Episodes end (terminated) on arrival, collision, leaving the flight
volume or a non-finite state, and are truncated at the task's time limit. `info["reward_terms"]`
holds each reward term of the step; the final step's info has `outcome` and `is_success`.

    import gymnasium as gym, rl
    env = gym.make("UAMNav-v0")                       # training cities, light turbulence
    env = gym.make("UAMNav-v0", config=NavConfig(city_split="eval"), render_mode="rgb_array")
"""
from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from rl.env.world import NavBatch, NavWorld
from rl.sensing.observation import OBS_CLIP
from rl.task.config import FixedEpisodes, NavConfig


def observation_space(size: int) -> gym.spaces.Box:
    return gym.spaces.Box(-OBS_CLIP, OBS_CLIP, shape=(size,), dtype=np.float32)


ACTION_SPACE = gym.spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)


class UAMNavEnv(gym.Env):
    """One vehicle (a `NavBatch` of one slot).

    Args:
        config: the task definition (defaults: small quadrotor, training cities, light turbulence).
        render_mode: None or "rgb_array" (a top-down image of the city, the path and the goal).
        fixed: scenario episodes instead of sampled ones.
        world: a prebuilt shared world (saves rebuilding cities and the compiled model).
    """

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, config: NavConfig | None = None, render_mode: str | None = None,
                 fixed: FixedEpisodes | None = None, world: NavWorld | None = None) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.world = world or NavWorld(config or NavConfig(), fixed)
        self.config = self.world.config
        self.batch = NavBatch(self.world, 1)
        self.render_mode = render_mode
        self.observation_space = observation_space(self.world.obs_size)
        self.action_space = ACTION_SPACE
        self._trail: list[np.ndarray] = []
        self._seeded = False

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self.batch.seed([seed])
        elif not self._seeded:
            self.batch.seed([int(self.np_random.integers(2**31))])
        self._seeded = True
        self.batch.reset_slots([0])
        self._trail = [self.batch.x[0, 0:3].copy()]
        info = {"task": self.batch.task(0), "city": self.world.cities[int(self.batch.city[0])].name}
        return self.batch.observations[0].copy(), info

    def step(self, action):
        obs, rew, term, trunc, infos = self.batch.step(np.asarray(action, dtype=np.float64)[None])
        self._trail.append(self.batch.x[0, 0:3].copy())
        return obs[0], float(rew[0]), bool(term[0]), bool(trunc[0]), infos[0]

    @property
    def state(self) -> np.ndarray:
        """The vehicle's full state (13 + n,)."""
        return self.batch.x[0].copy()

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        from matplotlib.backends.backend_agg import FigureCanvasAgg  # an explicit canvas: no backend to choose
        from matplotlib.figure import Figure

        from uam_fdm.city.plot import draw_map_topdown

        city = self.world.cities[int(self.batch.city[0])]
        fig = Figure(figsize=(4, 4), dpi=80)
        canvas = FigureCanvasAgg(fig)
        ax = fig.add_subplot(1, 1, 1)
        draw_map_topdown(ax, city)
        trail = np.array(self._trail)
        ax.plot(trail[:, 0], trail[:, 1], color="tab:orange", lw=1.5)
        ax.plot(*trail[-1, :2], "o", color="tab:orange", ms=5)
        ax.plot(*self.batch.goal[0, :2], "*", color="tab:green", ms=12)
        ax.set_title(f"t = {self.batch.t[0]:.1f} s", fontsize=8)
        ax.tick_params(labelsize=6)
        canvas.draw()
        return np.asarray(canvas.buffer_rgba())[..., :3].copy()
