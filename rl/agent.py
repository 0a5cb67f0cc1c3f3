"""The learned pilot as an `Agent`: policy -> velocity command -> the vehicle's low-level controller.

Loads a policy folder (the shipped `rl/policies/default` or one written by `uam-compare train`),
builds the same observation the environment builds (`rl.observation`, `rl.sensor`), normalises
it with the training statistics and acts deterministically. It returns a `VelocityCommand`, which
the runner hands to the same low-level controller the environment uses, so the rotor-speed
commands and the flight are those of the environment (tests/test_rl_agent.py flies one episode
both ways and compares the trajectories).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rl.cities import boxes_only
from rl.nav import NavConfig
from rl.observation import action_to_command, build_observations
from rl.sensor import BoxSensor
from rl.train import normalize_obs
from uam_fdm.agent import Observation, ResetInfo, Task, VelocityCommand, World
from uam_fdm.city import BuildingMap
from uam_fdm.params import load_vehicle

DEFAULT_POLICY_DIR = Path(__file__).parent / "policies" / "default"


@dataclass
class Policy:
    """A trained policy: the SB3 model, its observation statistics and the task it was trained on."""

    folder: Path
    model: object
    obs_stats: dict
    nav: NavConfig

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic actions (N, 3) in [-1, 1] for raw observations (N, obs)."""
        act, _ = self.model.predict(normalize_obs(np.asarray(obs, dtype=np.float64), self.obs_stats),
                                    deterministic=True)
        return np.asarray(act, dtype=np.float64).reshape(-1, 3)


def load_policy(folder: Path | str | None = None) -> Policy:
    """Load a policy folder (default: the shipped policy).

    Raises:
        ValueError: the folder or one of its files is missing, naming it.
    """
    import torch
    from stable_baselines3 import PPO

    folder = Path(folder) if folder is not None else DEFAULT_POLICY_DIR
    for name in ("model.zip", "obs_norm.npz", "config.json"):
        if not (folder / name).is_file():
            raise ValueError(f"{folder}: not a policy folder ({name} is missing)")
    torch.set_num_threads(1)
    model = PPO.load(str(folder / "model.zip"), device="cpu")
    with np.load(folder / "obs_norm.npz") as z:
        stats = {k: np.array(z[k]) for k in ("mean", "var", "epsilon", "clip_obs")}
    cfg = json.loads((folder / "config.json").read_text())
    return Policy(folder, model, stats, NavConfig.from_dict(cfg["nav"]))


class _CitySensor:
    """The environment's sensor for one city (boxes), or the city's own exact query for other shapes."""

    def __init__(self, city: BuildingMap, k: int, range_m: float, radius_m: float) -> None:
        self.city, self.k, self.range_m, self.radius_m = city, k, range_m, radius_m
        self.boxes = BoxSensor([city], k, range_m, radius_m) if boxes_only(city) else None

    def read(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.boxes is not None:
            r = self.boxes.query(p[None], np.zeros(1, dtype=np.int64))
            return r.nearest_m, r.distance_m
        near, dist, ids = self.city.nearest_obstacles_batch(p[None], self.k, self.radius_m)
        far = (dist > self.range_m) | (ids < 0)
        return np.where(far[..., None], p[None, None, :], near), np.where(far, self.range_m, dist)


class PolicyAgent:
    """The learned pilot (implements `uam_fdm.agent.Agent`).

    Args:
        policy: a loaded `Policy`, a policy folder, or None for the shipped policy.
    """

    name = "ppo"

    def __init__(self, policy: Policy | Path | str | None = None) -> None:
        self.policy = policy if isinstance(policy, Policy) else load_policy(policy)
        self._sensor: _CitySensor | None = None
        self._world: World | None = None
        self._trained_fingerprint = load_vehicle(self.policy.nav.vehicle).fingerprint()

    def reset(self, world: World, task: Task, seed: int) -> ResetInfo:
        """Prepare the observation for `task` (no planning; deterministic, so `seed` is unused)."""
        nav = self.policy.nav
        p = world.vehicle
        if p.fingerprint() != self._trained_fingerprint:
            return ResetInfo(False, "unsupported_vehicle", 0.0,
                             f"the policy was trained for {nav.vehicle!r}; {p.name!r} has other parameters")
        if self._world is None or self._world.city is not world.city:
            self._sensor = _CitySensor(world.city, nav.k_buildings, nav.sensing_range_m, p.collision_radius_m)
        self._world = world
        self._goal = np.asarray(task.goal_m, dtype=float)[None]
        self._lo = np.asarray(world.city.bounds_min_m, dtype=float)[None]
        self._hi = np.asarray(world.city.bounds_max_m, dtype=float)[None]
        self._yaw = float(task.start_yaw_rad)
        return ResetInfo(True)

    def observe(self, x: np.ndarray) -> np.ndarray:
        """The raw observation (1, obs) for state x (what the environment would return)."""
        nav = self.policy.nav
        near, dist = self._sensor.read(np.asarray(x[0:3], dtype=float))
        return build_observations(np.asarray(x, dtype=float)[None], self._goal, self._lo, self._hi, near, dist,
                                  nav.sensing_range_m, self._world.vehicle.controller.max_speed_m_s)

    def act(self, obs: Observation) -> VelocityCommand:
        action = self.policy.act_batch(self.observe(obs.x))
        cmd = action_to_command(action, self._world.vehicle, self._yaw)[0]
        return VelocityCommand(cmd[0:3], float(cmd[3]))
