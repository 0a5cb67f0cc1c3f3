"""`SplitVecEnv`: the batch stepped by several processes gives exactly the transitions of one `UAMNavVecEnv`
(slot i seeded seed + i whichever process holds it), across resets, sensing levels, map error, routes redrawn
around sensed obstacles and a change of the curriculum's difficulty; bad process counts are refused before anything
is built."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rl.env.split_vec_env import SplitVecEnv, shares
from rl.env.vec_env import UAMNavVecEnv
from rl.sensing.route import RouteConfig
from rl.task.air import AirDistribution
from rl.task.config import NavConfig

# every sensing level and map-error level drawn, light turbulence: what a training batch meets, small and quick
TASK = NavConfig(city_pool_size=3, wind_pool_size=2, wind_series_s=150.0, sensing=("perfect", "nominal", "degraded"),
                 map_error=("exact", "wrong"), map_error_draws=1, route=RouteConfig(refresh_s=0.5),
                 air=AirDistribution(turbulence=("light",), steady_wind_max_m_s=3.0))


def test_shares_cover_the_slots_evenly():
    assert shares(7, 3) == [3, 2, 2] and shares(8, 2) == [4, 4] and sum(shares(256, 5)) == 256


def test_split_steps_exactly_as_one_batch():
    n, seed = 5, 11
    one = UAMNavVecEnv(n, TASK, seed=seed)
    split = SplitVecEnv(n, TASK, seed=seed, processes=3)
    try:
        for env in (one, split):
            env.difficulty = 0.3  # short legs: several episodes end and restart in the steps below
        assert np.array_equal(one.reset(), split.reset())
        rng = np.random.default_rng(0)
        ended = 0
        for step in range(120):
            if step == 60:
                one.difficulty = split.difficulty = 0.6
            act = rng.uniform(-1.0, 1.0, (n, 3))
            a, b = one.step(act), split.step(act)
            for x, y in zip(a[:3], b[:3]):
                assert np.array_equal(x, y), step
            assert [sorted(i) for i in a[3]] == [sorted(i) for i in b[3]]
            for ia, ib in zip(a[3], b[3]):
                if "outcome" in ia:
                    ended += 1
                    assert ia["outcome"] == ib["outcome"] and ia["episode"] == ib["episode"]
                    assert np.array_equal(ia["terminal_observation"], ib["terminal_observation"])
        assert ended >= 3  # resets were exercised
        assert split.difficulty == 0.6 and split.num_envs == n and split.world.config == TASK
    finally:
        split.close()


@pytest.mark.parametrize("processes", [0, 4])
def test_a_process_count_that_cannot_hold_the_slots_is_refused(processes):
    with pytest.raises(ValueError, match=f"processes must be in .* got {processes}"):
        SplitVecEnv(3, replace(TASK, city_pool_size=1), processes=processes)


def test_held_out_episodes_shared_by_processes_are_those_one_process_flies():
    """An evaluation's episodes flown by two processes, a share each, end as when one process flies them all: the
    same outcomes, returns and times, episode by episode; a share flown alone is that share of the whole."""
    import torch

    from rl.env.held_out import PolicyWeights, fly_episodes, policy_pilot
    from rl.env.split_vec_env import evaluation_world
    from rl.policies.folder import NetworkConfig
    from rl.policies.network import ActorCritic
    from rl.policies.reader import ObsNorm
    from rl.training.evaluation import eval_config

    split = SplitVecEnv(2, TASK, seed=3, processes=2)
    try:
        world = evaluation_world(eval_config(TASK, 7, "validation"), split.world)
        torch.manual_seed(0)
        n = world.obs_size
        rng = np.random.default_rng(1)
        norm = ObsNorm(rng.normal(0.0, 0.1, n), rng.uniform(0.5, 2.0, n), 100.0, 1e-8, 10.0)
        weights = PolicyWeights.of(ActorCritic(n, NetworkConfig()).state_dict(), n, NetworkConfig(), norm)
        one = fly_episodes(policy_pilot(weights), world, 0, 7, seed=5)
        shared = split.fly_held_out(world, 7, 5, weights)
        assert shared.outcomes == one.outcomes and len(set(one.times_s)) > 1
        assert shared.levels == one.levels and {lv[0] for lv in one.levels} <= set(TASK.sensing)
        assert len(set(one.levels)) > 1 and {lv[1] for lv in one.levels} <= set(TASK.map_error)
        # bit for bit on the Intel machines this ran on before; on an AMD EPYC (AVX2, no AVX-512) a batch of another
        # size differs in the last bits (likely numpy's SIMD loops by array length): ~2e-7 of a return at the end
        np.testing.assert_allclose(shared.returns, one.returns, rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(shared.times_s, one.times_s)
        tail = fly_episodes(policy_pilot(weights, 4, 7), world, 4, 3, seed=5)
        assert tail.outcomes == one.outcomes[4:]
        np.testing.assert_allclose(tail.returns, one.returns[4:], rtol=1e-6, atol=1e-6)
        with pytest.raises(ValueError, match="1 episodes cannot be shared by 2 processes"):
            split.fly_held_out(world, 1, 5, weights)
    finally:
        split.close()
