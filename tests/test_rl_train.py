"""Training plumbing on a tiny configuration (seconds, not a real training run)."""
from __future__ import annotations

import csv
import json
from dataclasses import replace

import numpy as np
import pytest

from rl.agent import load_policy
from rl.env import UAMNavEnv
from rl.expert import PotentialField
from rl.nav import FixedEpisodes, NavConfig, NavWorld
from rl.train import PRESETS, TrainConfig, evaluate, train
from uam_fdm.agent import Task
from uam_fdm.city import Building, BuildingMap

TINY_NAV = NavConfig(city_pool_size=2, wind_pool_size=1, wind_series_s=150.0)


def test_train_writes_a_loadable_policy_and_resumes(tmp_path):
    cfg = TrainConfig(preset="paper", total_timesteps=2 * 8 * 64, n_envs=8, nav=TINY_NAV, eval_every=8 * 64,
                      eval_episodes=3, checkpoint_every=8 * 64)
    out = tmp_path / "pol"
    res = train(cfg, out, progress=False, command="test", log=lambda *_: None)
    for name in ("model.zip", "obs_norm.npz", "vecnormalize.pkl", "config.json", "reward_curve.csv", "provenance.json"):
        assert (out / name).is_file(), name
    assert not (out / "best").exists() and sorted(p.name for p in (out / "checkpoints").iterdir())
    with open(out / "reward_curve.csv") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["timesteps"]) for r in rows] == [512, 1024, 1024]
    prov = json.loads((out / "provenance.json").read_text())
    assert prov["command"] == "test" and prov["seed"] == 0 and prov["validation_of_kept_model"]["episodes"] == 3
    assert 0.0 <= res.success_rate <= 1.0
    assert TrainConfig.from_dict(json.loads((out / "config.json").read_text())) == cfg
    policy = load_policy(out)
    assert policy.act_batch(np.zeros((2, 36), dtype=np.float32)).shape == (2, 3)
    ckpt = sorted((out / "checkpoints").iterdir())[0]
    more = replace(cfg, total_timesteps=3 * 8 * 64)
    train(more, tmp_path / "resumed", resume=ckpt, progress=False, log=lambda *_: None)
    assert json.loads((tmp_path / "resumed" / "provenance.json").read_text())["timesteps"] == 3 * 8 * 64


def test_presets_keep_the_paper_network():
    for name, p in PRESETS.items():
        assert p.net_arch == (128, 128), name
    assert PRESETS["paper"].clip_range == 0.2
    with pytest.raises(ValueError, match="preset"):
        TrainConfig(preset="huge")


def test_potential_field_flies_past_a_building_in_the_way():
    city = BuildingMap([Building(0, (60.0, 60.0), (20.0, 18.0), 40.0)], (0, 0, 0), (120, 100, 60), name="block")
    cfg = NavConfig(city_pool_size=1, turbulence="none", steady_wind_max_m_s=0.0)
    fixed = FixedEpisodes((city,), ((0, Task((20.0, 50.0, 10.0), (100.0, 50.0, 10.0), 3.0, 60.0)),))
    world = NavWorld(cfg, fixed=fixed)
    expert = PotentialField(cfg.k_buildings, cfg.sensing_range_m)
    env = UAMNavEnv(world=world)
    obs, _ = env.reset(seed=0)
    min_clear = np.inf
    for _ in range(5000):
        obs, _, term, trunc, info = env.step(expert.act(obs[None])[0].astype(np.float32))
        min_clear = min(min_clear, info["clearance_m"])
        if term or trunc:
            break
    assert info["outcome"] == "success" and min_clear > 0.5  # the line passes 1 m from the wall: pushed away


def test_evaluate_counts_outcomes():
    res = evaluate(lambda o: np.zeros((len(o), 3)), replace(TINY_NAV, turbulence="none"), 3, seed=0)
    assert res.episodes == 3 and sum(res.outcomes.values()) == 3
    assert res.outcomes.get("timeout", 0) == 3  # hovering in place never arrives
