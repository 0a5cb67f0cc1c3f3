"""Every decision is recorded as given: the command (rotor speeds, or a velocity and heading), its hold, and the
observation vector the pilot decided on: the learned pilot's is its policy's input, element for element as the
training environment builds it; a plug-in tells its own (`ObservingPilot`); the learned pilot is left as it was."""
from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from compare.flying.episode_loop import ROTOR_SPEEDS, VELOCITY_YAW, ObservingPilot, PilotError, run_episode
from compare.run.cells import CellRunner
from compare.scenarios.scenario import scenario_from_dict
from rl.env.gym_env import UAMNavEnv
from rl.env.world import NavWorld
from rl.pilots.learned import PolicyPilot, load_policy
from rl.policies.folder import SHIPPED_POLICIES
from rl.training.evaluation import eval_config
from run_data import TINY
from uam_fdm.air.wind import WindField
from uam_fdm.files.yamlfile import load_yaml_file
from uam_fdm.pilot import Observation, ResetInfo, RotorCommand, Task, VelocityCommand, World


def _tiny_world(tmp_path: Path) -> tuple[World, Task]:
    data = copy.deepcopy(load_yaml_file(TINY))
    data.update(name="decided", timeout_s=2.0)
    sc = scenario_from_dict(data, str(TINY), TINY.parent)
    return CellRunner([sc], tmp_path, {}).world(0), sc.episodes[0].task


class HoldingRotors:
    """Commands rotor speeds that drift a little each decision, each held for two control periods."""

    name = "holding"

    def reset(self, world: World, task: Task, seed: int) -> ResetInfo:
        self.n, self.k = world.vehicle.n_rotors, 0
        return ResetInfo(True)

    def act(self, obs: Observation) -> RotorCommand:
        self.k += 1
        return RotorCommand(obs.x[13:13 + self.n] + 0.25 * self.k, hold_periods=2)

    def episode_report(self) -> None:
        return None


class TellsItsObservation:
    """Flies at the goal and tells the vector it decided on: its position and time (`ObservingPilot`)."""

    name = "telling"

    def reset(self, world: World, task: Task, seed: int) -> ResetInfo:
        self.goal, self.last = np.asarray(task.goal_m, float), np.zeros(4)
        return ResetInfo(True)

    def act(self, obs: Observation) -> VelocityCommand:
        self.last = np.append(obs.x[0:3], obs.t_s)
        return VelocityCommand(np.clip(self.goal - obs.x[0:3], -2.0, 2.0), yaw_rad=0.5)

    def last_observation(self) -> np.ndarray | None:
        return self.last

    def episode_report(self) -> None:
        return None


def test_rotor_commands_are_recorded_as_given_with_their_hold(tmp_path: Path) -> None:
    world, task = _tiny_world(tmp_path)
    traj = run_episode(world, HoldingRotors(), task, WindField.calm(), 0)
    d = traj.decisions
    assert d is not None and len(d.commands) == len(traj.decision_t_s) > 10
    assert set(d.kinds) == {ROTOR_SPEEDS} and set(d.hold_periods.tolist()) == {2}
    assert all(o is None for o in d.observations)  # a pilot that tells none
    period = round(world.dynamics.physics_hz / world.dynamics.control_hz)
    for k, (t, cmd) in enumerate(zip(traj.decision_t_s, d.commands)):
        row = int(np.argmin(np.abs(traj.t_s - t)))
        # each decision's own command, made from the state at its time
        np.testing.assert_allclose(cmd, traj.states[row, 13:] + 0.25 * (k + 1), rtol=0, atol=1e-9)
        # and the one the simulator flew over its two periods (the motors' input)
        flown = traj.rotor_commands[row + 1:row + 2 * period + 1]
        np.testing.assert_allclose(flown, np.tile(cmd, (len(flown), 1)), rtol=0, atol=1e-9)


def test_a_pilot_that_tells_its_observation_has_it_recorded(tmp_path: Path) -> None:
    world, task = _tiny_world(tmp_path)
    pilot = TellsItsObservation()
    assert isinstance(pilot, ObservingPilot)
    traj = run_episode(world, pilot, task, WindField.calm(), 0)
    d = traj.decisions
    assert d is not None and set(d.kinds) == {VELOCITY_YAW}
    for t, cmd, seen in zip(traj.decision_t_s, d.commands, d.observations):
        assert seen is not None and seen[3] == t  # the vector of that decision, not the one before
        np.testing.assert_array_equal(cmd, np.append(np.clip(np.asarray(task.goal_m) - seen[0:3], -2.0, 2.0), 0.5))


class _Failing(PolicyPilot):
    def act(self, obs: Observation) -> Any:
        super().act(obs)
        return "not a command"


def test_the_learned_pilot_is_left_as_it_was_even_when_its_episode_fails(tmp_path: Path) -> None:
    policy = load_policy(SHIPPED_POLICIES["small_quad"])
    world, task = _tiny_world(tmp_path)
    pilot = _Failing(policy)
    with pytest.raises(PilotError):
        run_episode(world, pilot, task, WindField.calm(), 0)
    assert pilot.policy is policy
    flying = PolicyPilot(policy)
    traj = run_episode(world, flying, task, WindField.calm(), 0)
    assert flying.policy is policy and traj.decisions is not None
    assert {len(o) for o in traj.decisions.observations if o is not None} == {policy.obs_norm.mean.size}


def test_the_learned_pilot_s_recorded_observations_are_its_environment_s() -> None:
    """One held-out episode through the training environment and through the runner: the observation recorded at
    each decision is the environment's, element for element, and the command is the policy's action on it."""
    policy = load_policy(SHIPPED_POLICIES["small_quad"])
    base = NavWorld(eval_config(policy.nav, 3))
    env = UAMNavEnv(world=base)
    obs, _ = env.reset(seed=7)
    task, wind, city = env.batch.task(0), env.batch.wind_field(0), base.cities[int(env.batch.city[0])]
    seen = []
    for _ in range(100_000):
        seen.append(obs)
        obs, _, term, trunc, _ = env.step(policy.act_batch(obs[None])[0])
        if term or trunc:
            break
    world = World(base.vehicle, base.dynamics, city, env.batch.atmosphere(0), env.batch.turbulence(0))
    traj = run_episode(world, PolicyPilot(policy), task, wind, seed=0)
    d = traj.decisions
    assert d is not None and len(d.observations) == len(seen) > 5
    np.testing.assert_array_equal(np.array(d.observations), np.array(seen))
    assert set(d.kinds) == {VELOCITY_YAW} and set(d.hold_periods.tolist()) == {policy.nav.action_repeat}
    speeds = np.linalg.norm(np.array(d.commands)[:, 0:3], axis=1)
    assert np.all(speeds <= base.vehicle.controller.max_speed_m_s * np.sqrt(3) + 1e-9) and np.ptp(speeds) > 0.0
