"""`UAMNav-v0`: one multirotor flying to a goal through a city, as a gymnasium environment.

The observation, action and reward are documented in `rl.sensing.observation` and `rl.task.reward`;
the episode mechanics in `rl.env.world`. Episodes end (terminated) on arrival, collision, leaving the flight
volume or a non-finite state, and are truncated at the task's time limit. `info["reward_terms"]`
holds each reward term of the step; the final step's info has `outcome` and `is_success`.

    import gymnasium as gym, rl
    env = gym.make("UAMNav-v0")                       # training cities, light turbulence
    env = gym.make("UAMNav-v0", config=NavConfig(city_split="eval"), render_mode="rgb_array")
    env = gym.make("UAMNav-v0", scenario="my.yaml")   # legs drawn in a scenario's map, in its air (rl.env.ground)
    env = gym.make("UAMNav-v0", config=NavConfig(sensing=("perfect", "nominal")))  # some episodes on its sensors
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from rl.env.ground import TRAINING_LEGS, TRAINING_STREAM, ScenarioLike, TrainingGround, load_ground
from rl.env.world import NavBatch, NavWorld
from rl.sensing.observation import OBS_CLIP
from rl.task.config import FixedEpisodes, NavConfig
from rl.task.vehicles import task_for


def scenario_world(scenario: str | Path | ScenarioLike | TrainingGround, config: NavConfig | None = None,
                   legs_seed: int = 0) -> NavWorld:
    """The world of `TRAINING_LEGS` legs drawn from `legs_seed` in a scenario's map, in its air (`rl.env.ground`).

    Args:
        scenario: a scenario file, a checked scenario or its `TrainingGround`.
        config: the task to fly there (default: the scenario's vehicle's training task).
    """
    if isinstance(scenario, TrainingGround):
        ground = scenario
    elif isinstance(scenario, (str, Path)):
        ground = load_ground(scenario)
    else:
        ground = TrainingGround.from_scenario(scenario)
    nav = ground.task(config if config is not None else task_for(ground.vehicle))
    return ground.world(nav, ground.legs(nav, TRAINING_LEGS, legs_seed, TRAINING_STREAM))


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
        scenario: fly legs drawn in a scenario's map, in its air and at its rates (`rl.env.ground`): a scenario
            file (read and checked by the comparison's strict loader), a checked scenario or a `TrainingGround`.
            `config` is then the vehicle's task to fly there (default: the scenario's vehicle's, `task_for`).
        legs_seed: the seed the scenario's legs are drawn from.

    Raises:
        ValueError: a bad scenario (naming its file, the key and the reason), or `scenario` with `fixed` or `world`.
    """

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, config: NavConfig | None = None, render_mode: str | None = None,
                 fixed: FixedEpisodes | None = None, world: NavWorld | None = None,
                 scenario: str | Path | ScenarioLike | TrainingGround | None = None, legs_seed: int = 0) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if scenario is not None:
            if fixed is not None or world is not None:
                raise ValueError("scenario: give a scenario, fixed episodes or a world, not several")
            world = scenario_world(scenario, config, legs_seed)
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
