"""`evaluate` flies only the episodes still flying: its outcomes, returns and times are those of flying every slot to
the end and restarting the ended ones (as the batched env does), episode for episode, at every sensing and map-error
level; a slot left idle by `NavBatch.step(active=...)` does not move and ends nothing."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rl.env.vec_env import UAMNavVecEnv
from rl.env.world import NavBatch, NavWorld
from rl.pilots.learned import load_policy
from rl.policies.folder import SHIPPED_POLICIES
from rl.training.evaluation import eval_config, evaluate

EPISODES = 9


@pytest.fixture(scope="module")
def policy():
    return load_policy(SHIPPED_POLICIES["small_quad"])


@pytest.fixture(scope="module")
def world(policy) -> NavWorld:
    nav = replace(eval_config(policy.nav, EPISODES, pool="validation"), sensing=("perfect", "nominal", "degraded"),
                  map_error=("exact", "wrong"), map_error_draws=1)
    return NavWorld(nav)


def _every_slot_to_the_end(pilot, world: NavWorld, seed: int) -> tuple[list[str], np.ndarray, np.ndarray]:
    """The former evaluation: the batched env flies every slot each step and restarts the ended ones."""
    venv = UAMNavVecEnv(EPISODES, world=world, seed=seed)
    venv.batch.city_of_slot = np.arange(EPISODES) % len(world.cities)
    obs = venv.reset()
    done = np.zeros(EPISODES, dtype=bool)
    outcomes, returns, times = [""] * EPISODES, np.zeros(EPISODES), np.zeros(EPISODES)
    while not done.all():
        obs, _, d, infos = venv.step(pilot(obs, venv.batch))
        for i in np.flatnonzero(d & ~done):
            outcomes[i], returns[i], times[i] = infos[i]["outcome"], infos[i]["episode"]["r"], infos[i]["t_s"]
        done |= d
    return outcomes, returns, times


def test_only_the_episodes_still_flying_fly_and_nothing_changes(policy, world):
    def pilot(obs, _batch):
        return policy.act_batch(obs)

    res = evaluate(pilot, world.config, EPISODES, seed=5, pool="validation", world=world)
    outcomes, returns, times = _every_slot_to_the_end(pilot, world, 5)
    assert list(res.per_episode) == outcomes
    assert res.mean_return == pytest.approx(float(returns.mean()), rel=0, abs=0)
    assert res.mean_time_s == pytest.approx(float(times.mean()), rel=0, abs=0)
    assert len(set(outcomes)) >= 1 and res.episodes == EPISODES


def test_an_idle_slot_stays_where_it_is(world):
    b = NavBatch(world, 2)
    b.seed([1, 2])
    b.reset_slots([0, 1])
    x, t, ret = b.x.copy(), b.t.copy(), b.episode_return.copy()
    _, _, term, trunc, infos = b.step(np.zeros((2, 3)), active=np.array([False, True]))
    assert np.array_equal(b.x[0], x[0]) and b.t[0] == t[0] and b.t[1] > t[1]
    assert not (term[0] or trunc[0]) and "outcome" not in infos[0]
    assert b.episode_return[0] == ret[0]


def test_rates_by_level_count_each_level_and_pair_in_the_presets_order() -> None:
    from rl.training.evaluation import EvalResult, rates_by_level

    levels = (("nominal", "wrong"), ("perfect", "exact"), ("nominal", "exact"), ("degraded", "wrong"),
              ("nominal", "wrong"))
    outcomes = ("success", "success", "collision", "timeout", "success")
    res = EvalResult(5, 0.6, 0.2, (0.0, 1.0), (0.0, 1.0), {}, 0.0, 0.0, outcomes, "validation", 0, levels)
    rows = {g.label: (g.episodes, g.success_rate, g.collision_rate, g.outcomes) for g in rates_by_level(res)}
    assert list(rows) == ["sensing perfect", "sensing nominal", "sensing degraded", "map exact", "map wrong",
                          "perfect / exact", "nominal / exact", "nominal / wrong", "degraded / wrong"]
    assert rows["sensing nominal"] == (3, 2 / 3, 1 / 3, {"collision": 1, "success": 2})
    assert rows["map wrong"] == (3, 2 / 3, 0.0, {"success": 2, "timeout": 1})
    assert rows["degraded / wrong"] == (1, 0.0, 0.0, {"timeout": 1})
    one_level = EvalResult(2, 1.0, 0.0, (0.0, 1.0), (0.0, 1.0), {}, 0.0, 0.0, ("success", "success"), "test", 0,
                           (("perfect", "exact"), ("perfect", "exact")))
    assert rates_by_level(one_level) == ()
    only_maps = EvalResult(2, 1.0, 0.0, (0.0, 1.0), (0.0, 1.0), {}, 0.0, 0.0, ("success", "success"), "test", 0,
                           (("nominal", "exact"), ("nominal", "outdated")))
    assert [g.label for g in rates_by_level(only_maps)] == ["map exact", "map outdated"]
