"""Training plumbing on tiny configurations (seconds, not a real training run), and the baseline pilot."""
from __future__ import annotations

import csv
import json
from dataclasses import replace

import numpy as np
import pytest

from rl.env.gym_env import UAMNavEnv
from rl.env.world import NavWorld
from rl.pilots.learned import load_policy
from rl.pilots.potential_field import BatchedPotentialField
from rl.sensing.observation import obs_size
from rl.task.air import AirDistribution
from rl.task.config import FixedEpisodes, NavConfig
from rl.training.config import Curriculum, TrainConfig
from rl.training.evaluation import evaluate, paired_counts
from rl.training.loop import train
from rl.training.ppo import PRESETS
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.pilot import Task
from uam_fdm.stats import wilson_interval
from uam_fdm.vehicle.dynamics import VehicleDynamics
from uam_fdm.vehicle.params import load_vehicle

TINY_NAV = NavConfig(city_pool_size=2, wind_pool_size=1, wind_series_s=150.0)

CALM = AirDistribution(turbulence=("none",), steady_wind_max_m_s=0.0)  # no gusts, no wind


def _rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def _open_field(n_tasks: int = 32, seed: int = 0) -> FixedEpisodes:
    """An empty 200 m field with short legs: an easy task that PPO learns within seconds."""
    city = BuildingMap([], (0, 0, 0), (200, 200, 60), name="open-field")
    rng = np.random.default_rng(seed)
    tasks = []
    for _ in range(n_tasks):
        start = rng.uniform([60, 60, 8], [140, 140, 20])
        ang = rng.uniform(-np.pi, np.pi)
        goal = start + np.array([25 * np.cos(ang), 25 * np.sin(ang), rng.uniform(-3, 3)])
        tasks.append((0, Task(tuple(start), tuple(goal), 3.0, 15.0)))
    return FixedEpisodes((city,), tuple(tasks))


def test_tiny_training_run_increases_the_return(tmp_path):
    """Plain PPO on an easy configuration: the training return rises (seeded, seconds)."""
    nav = replace(TINY_NAV, air=CALM, city_pool_size=1)
    world = NavWorld(nav, fixed=_open_field())
    cfg = TrainConfig(total_timesteps=24 * 32 * 64, n_envs=32, nav=nav, curriculum=Curriculum(start=1.0),
                      eval_every=10**9, eval_episodes=2, checkpoint_every=0, seed=3)
    train(cfg, tmp_path / "easy", progress=False, log=lambda *_: None, world=world)
    ret = [float(r["mean_episode_reward"]) for r in _rows(tmp_path / "easy" / "reward_curve.csv")
           if r["mean_episode_reward"]]
    first, last = np.mean(ret[:4]), np.mean(ret[-4:])
    assert last > first + 20.0, (first, last, ret)


def test_a_curriculum_level_ends_after_its_timesteps(tmp_path):
    """With a gate no training can meet, the legs still lengthen every `level_steps`, and a resume keeps the clock."""
    cfg = TrainConfig(total_timesteps=4 * 8 * 64, n_envs=8, nav=TINY_NAV, eval_every=10**9, eval_episodes=2,
                      checkpoint_every=2 * 8 * 64,
                      curriculum=Curriculum(start=0.25, step=0.25, gate=1.0, window=10**6, level_steps=8 * 64))
    lines: list[str] = []
    train(cfg, tmp_path / "pol", progress=False, log=lines.append)
    levels = [float(r["difficulty"]) for r in _rows(tmp_path / "pol" / "reward_curve.csv")]
    assert levels[:4] == [0.5, 0.75, 1.0, 1.0], levels  # raised at the end of each 512-step update
    assert sum("timesteps are over" in ln for ln in lines) == 3
    state = json.loads((tmp_path / "pol" / "checkpoints" / "step_00000001024" / "curriculum.json").read_text())
    assert state == {"difficulty": 0.75, "level_since": 1024}
    with pytest.raises(ValueError, match="level_steps"):
        Curriculum(level_steps=-1)


def test_presets_keep_the_paper_network():
    assert set(PRESETS) == {"paper", "paper-shrinking-noise"}
    for preset in PRESETS.values():  # every preset is PPO with the paper's network and clip
        assert preset.net_arch == (128, 128) and preset.clip_range == 0.2
    shrinking = PRESETS["paper-shrinking-noise"]
    assert PRESETS["paper"].log_std_cap(0.5) is None
    assert (shrinking.log_std_cap(0.0), shrinking.log_std_cap(0.5), shrinking.log_std_cap(1.0)) == (-1.0, -2.0, -3.0)
    with pytest.raises(ValueError, match="log_std_end"):
        replace(shrinking, log_std_end=0.5)
    with pytest.raises(ValueError, match="preset"):
        TrainConfig(preset="huge")
    with pytest.raises(ValueError, match="curriculum"):
        Curriculum(start=0.0)
    with pytest.raises(ValueError, match="collision_weight"):
        TrainConfig(collision_weight=-1.0)


def test_discount_keeps_its_horizon_in_seconds():
    pr = PRESETS["paper"]
    assert pr.gamma(10.0) == 0.99 and pr.gamma(50.0) == pytest.approx(0.998)
    # the weight of a reward 10 s ahead is the same at either rate (1/e in the continuous limit)
    assert pr.gamma(50.0) ** 500 == pytest.approx(pr.gamma(10.0) ** 100, rel=5e-3)
    assert TrainConfig().to_dict()["ppo"]["gamma"] == 0.99


@pytest.mark.parametrize(("n_envs", "minibatch"), [(1, 64), (32, 2048), (64, 4096), (100, 3200), (256, 4096)])
def test_the_minibatch_follows_the_vehicles(n_envs, minibatch):
    """Whole mini-batches of the rollout (n_steps x n_envs decisions), as large as the preset's and no larger."""
    pr = PRESETS["paper"]
    size = pr.minibatch_size(n_envs)
    assert size == minibatch and (pr.n_steps * n_envs) % size == 0
    assert TrainConfig(n_envs=n_envs).to_dict()["ppo"]["batch_size"] == minibatch  # config.json says what PPO took


def test_vehicles_that_split_the_rollout_into_tiny_minibatches_are_refused():
    with pytest.raises(ValueError, match=r"^n_envs 4099: .*mini-batches of 64"):
        TrainConfig(n_envs=4099)


def test_the_model_takes_the_fitted_minibatch_without_a_warning(recwarn):
    from rl.env.vec_env import UAMNavVecEnv
    from rl.training.ppo import make_model, normalized_env

    nav = replace(TINY_NAV, air=CALM, city_pool_size=1)
    venv = normalized_env(UAMNavVecEnv(32, world=NavWorld(nav, fixed=_open_field(4))), PRESETS["paper"], 10.0)
    model = make_model(PRESETS["paper"], venv, 0, 10.0)
    assert model.batch_size == 2048
    assert [w for w in recwarn.list if "stable_baselines3" in w.filename] == []


def test_the_scenario_trained_on_is_kept_in_the_config():
    cfg = TrainConfig(scenario="my.yaml", curriculum=Curriculum(start=1.0))
    assert TrainConfig.from_dict(cfg.to_dict()) == cfg
    old = TrainConfig().to_dict()
    del old["scenario"]  # written before training took a scenario
    assert TrainConfig.from_dict(old).scenario is None


def test_potential_field_flies_past_a_building_in_the_way():
    city = BuildingMap([Building(0, (60.0, 60.0), (20.0, 18.0), 40.0)], (0, 0, 0), (120, 100, 60), name="block")
    cfg = NavConfig(city_pool_size=1, air=CALM, decision_hz=50.0)
    fixed = FixedEpisodes((city,), ((0, Task((20.0, 50.0, 10.0), (100.0, 50.0, 10.0), 3.0, 60.0)),))
    env = UAMNavEnv(world=NavWorld(cfg, fixed=fixed))
    obs, _ = env.reset(seed=0)
    pilot = BatchedPotentialField(env.batch)
    min_clear = np.inf
    for _ in range(5000):
        obs, _, term, trunc, info = env.step(pilot(obs[None], env.batch)[0].astype(np.float32))
        min_clear = min(min_clear, info["clearance_m"])
        if term or trunc:
            break
    assert info["outcome"] == "success" and min_clear > 0.5  # the line passes 1 m from the wall: pushed away


def test_evaluate_counts_outcomes_with_intervals():
    calm = replace(TINY_NAV, air=AirDistribution(turbulence=("none",)))
    res = evaluate(lambda o, _b: np.zeros((len(o), 3)), calm, 3, seed=0)
    assert res.episodes == 3 and sum(res.outcomes.values()) == 3
    assert res.outcomes.get("timeout", 0) == 3 and res.per_episode == ("timeout",) * 3  # hovering never arrives
    assert res.success_ci95 == wilson_interval(0, 3) and res.success_ci95[0] == 0.0
    assert paired_counts(res, res) == {"only_a": 0, "only_b": 0, "both": 0, "neither": 3}


def test_wilson_interval_matches_the_formula():
    lo, hi = wilson_interval(95, 100)
    assert lo == pytest.approx(0.8882, abs=1e-4) and hi == pytest.approx(0.9785, abs=1e-4)
    assert wilson_interval(0, 50)[0] == 0.0 and wilson_interval(50, 50)[1] == 1.0


def test_a_policy_trained_in_drawn_air_observing_it_flies_in_the_runner(tmp_path):
    """Training across fields, levels and wind with the air and a history in the observation: the folder
    records the envelope and the observation, and the runner's pilot flies the policy (the same layout)."""
    from compare.flying.episode_loop import run_episode
    from rl.pilots.learned import PolicyPilot
    from rl.sensing.observation import ObservedContext
    from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions
    from uam_fdm.air.wind import WindField
    from uam_fdm.pilot import World

    air = AirDistribution(elevation_m=(0.0, 3000.0), isa_offset_k=(-15.0, 30.0), turbulence=("none", "moderate"),
                          steady_wind_max_m_s=8.0, pool_size=3)
    nav = replace(TINY_NAV, air=air, observe=ObservedContext(air=True, history=2))
    cfg = TrainConfig(total_timesteps=8 * 64, n_envs=8, nav=nav, eval_every=8 * 64, eval_episodes=2, checkpoint_every=0)
    train(cfg, tmp_path / "pol", progress=False, command="test", log=lambda *_: None)
    policy = load_policy(tmp_path / "pol")
    assert policy.nav.air == air and policy.nav.observe.history == 2
    assert policy.obs_norm.mean.shape == (obs_size(nav.perception, nav.observe),)
    city = BuildingMap([], (0, 0, 0), (200, 200, 60), name="open-field")
    world = World(policy_vehicle := load_vehicle(nav.vehicle), VehicleDynamics(policy_vehicle, nav.physics_hz,
                                                                                nav.control_hz),
                  city, Atmosphere.from_jsbsim(AtmosphereConditions(2500.0, 25.0), z_max_m=100.0))
    traj = run_episode(world, PolicyPilot(policy), Task((50, 50, 10), (80, 60, 12), 3.0, 5.0), WindField.calm(), seed=0)
    assert traj.outcome in ("success", "timeout", "collision", "out_of_bounds")


def test_train_names_a_bad_observe_option(capsys):
    from compare.cli import main

    assert main(["train", "--observe", "air,wings", "--out", "unused"]) == 2
    assert "--observe air,wings: 'wings' is not air, geofence, history=N" in capsys.readouterr().err


def test_observe_parses_every_item():
    from compare.cli.train import parse_observed
    from rl.sensing.observation import ObservedContext

    assert parse_observed("air, geofence,history=3,uncertainty") == ObservedContext(True, True, 3, True)
    assert parse_observed("none") == ObservedContext()
    assert ObservedContext(uncertainty=True).size() == 1
