"""The shipped policy and the policy agent: loads, flies held-out cities, equals the environment."""
from __future__ import annotations

import json

import numpy as np
import pytest

from compare.runner import run_episode
from rl.agent import DEFAULT_POLICY_DIR, PolicyAgent, load_policy
from rl.env import UAMNavEnv
from rl.nav import NavWorld
from rl.train import eval_config, evaluate
from uam_fdm.agent import ResetInfo, World
from uam_fdm.params import load_vehicle


@pytest.fixture(scope="module")
def policy():
    return load_policy()


def test_shipped_policy_has_provenance():
    for name in ("model.zip", "obs_norm.npz", "vecnormalize.pkl", "config.json", "reward_curve.csv", "provenance.json"):
        assert (DEFAULT_POLICY_DIR / name).is_file(), name
    prov = json.loads((DEFAULT_POLICY_DIR / "provenance.json").read_text())
    assert prov["command"].startswith("uam-compare train") and prov["wall_time_s"] > 0
    assert prov["machine"]["cpus"] >= 1 and "seed" in prov
    lines = (DEFAULT_POLICY_DIR / "reward_curve.csv").read_text().splitlines()
    assert lines[0].startswith("timesteps,mean_episode_reward,success_rate") and len(lines) > 5


def test_shipped_policy_succeeds_on_fixed_held_out_seeds(policy):
    """20 held-out cities (light turbulence): the bar is 90 % over 200; allow sampling noise on 20."""
    res = evaluate(policy.act_batch, policy.nav, 20, seed=0)
    assert res.success_rate >= 0.8, res
    assert res.collision_rate <= 0.1, res


def test_agent_flies_exactly_like_the_environment(policy):
    """One held-out episode (light turbulence) through the env and through the runner + PolicyAgent."""
    base = NavWorld(eval_config(policy.nav, 3))
    env = UAMNavEnv(world=base)
    obs, _ = env.reset(seed=7)
    task, wind, city = env.batch.task(0), env.batch.wind_field(0), base.cities[int(env.batch.city[0])]
    env_states, outcome = [], None
    for _ in range(100_000):
        obs, _, term, trunc, info = env.step(policy.act_batch(obs[None])[0])
        env_states.append(env.state)
        if term or trunc:
            outcome = info["outcome"]
            break
    world = World(base.vehicle, base.dynamics, city, base.atmosphere)
    traj = run_episode(world, PolicyAgent(policy), task, wind, seed=0)
    n_sub = base.dynamics.n_substeps
    assert traj.outcome == outcome
    np.testing.assert_array_equal(traj.states[n_sub::n_sub], np.array(env_states))


def test_agent_refuses_other_vehicles(policy, compiled_dynamics):
    from uam_fdm.agent import Task
    from uam_fdm.atmosphere import Atmosphere, AtmosphereConditions
    from uam_fdm.city import load_named_map

    p = load_vehicle("uam_multicopter")
    world = World(p, compiled_dynamics["uam_multicopter"], load_named_map("suburb"),
                  Atmosphere.from_jsbsim(AtmosphereConditions(0.0, 0.0), z_max_m=300.0))
    info = PolicyAgent(policy).reset(world, Task((100, 100, 30), (200, 200, 30)), 0)
    assert isinstance(info, ResetInfo) and not info.ok and info.status == "unsupported_vehicle"


def test_load_policy_names_missing_folder(tmp_path):
    with pytest.raises(ValueError, match="model.zip"):
        load_policy(tmp_path)
