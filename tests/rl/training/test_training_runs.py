"""One tiny training run (seconds), shared by the tests of what a run writes: the policy folder, its
determinism from the seed, resuming from a checkpoint, and the checkpoints' recorded flights (what is
recorded, the same bytes twice, and that recording does not change what is learned)."""
from __future__ import annotations

import json
import shutil
from dataclasses import replace

import numpy as np
import pytest
from test_training import TINY_NAV, _rows

from rl.env.world import NavBatch, NavWorld
from rl.pilots.learned import load_checkpoint_policy, load_policy
from rl.policies.flights import FLIGHTS_DIR, TrainingFlights, read_checkpoint
from rl.policies.folder import CURVE_COLUMNS
from rl.sensing.observation import obs_size
from rl.task.air import AirDistribution
from rl.training.config import TrainConfig
from rl.training.evaluation import eval_config
from rl.training.loop import train
from rl.training.recording import fixed_tasks
from uam_fdm.episode import OUTCOMES

CFG = TrainConfig(total_timesteps=2 * 8 * 64, n_envs=8, nav=TINY_NAV, eval_every=8 * 64, eval_episodes=3,
                  checkpoint_every=8 * 64, seed=5)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The same tiny run twice with recording (8 tasks, "a" and "b") and once without ("off"), "a" resumed
    from its first checkpoint for one more update ("resumed"), and what training "a" returned ("a_result")."""
    root = tmp_path_factory.mktemp("rec")
    out = {"a": root / "a", "b": root / "b", "off": root / "off", "resumed": root / "resumed"}
    results = {}
    for key in ("a", "b", "off"):
        cfg = replace(CFG, record_flights=0) if key == "off" else CFG
        results[key] = train(cfg, out[key], progress=False, command="test", log=lambda *_: None)
    train(replace(CFG, total_timesteps=3 * 8 * 64), out["resumed"], resume=out["a"] / "checkpoints" /
          "step_00000000512", progress=False, log=lambda *_: None)
    return {**out, "a_result": results["a"]}


def test_train_writes_a_loadable_policy_and_resumes(runs):
    out = runs["a"]
    for name in ("model.zip", "obs_norm.npz", "vecnormalize.npz", "config.json", "reward_curve.csv",
                 "provenance.json", "curriculum.json"):
        assert (out / name).is_file(), name
    assert not (out / "best").exists()
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["step_00000000512", "step_00000001024"]
    rows = _rows(out / "reward_curve.csv")
    assert tuple(rows[0]) == CURVE_COLUMNS
    # one row per PPO update (512 decisions each), validation filled where it ran: the last row holds the final
    # model's (evaluated after its update), never a second row of the same timesteps
    assert [int(r["timesteps"]) for r in rows] == [512, 1024]
    assert all(r["eval_episodes"] == "3" for r in rows) and float(rows[0]["difficulty"]) == 0.25
    assert rows[-1]["train_episodes"] != "" and rows[-1]["mean_episode_reward"] != ""
    prov = json.loads((out / "provenance.json").read_text())
    assert prov["command"] == "test" and prov["seed"] == 5 and prov["validation_of_kept_model"]["episodes"] == 3
    assert prov["method"] == "PPO from scratch" and "validation" in prov["pools"]["selection"]
    res = runs["a_result"]
    assert 0.0 <= res.success_rate <= 1.0 and res.pool == "validation"
    assert TrainConfig.from_dict(json.loads((out / "config.json").read_text())) == CFG
    policy = load_policy(out)
    assert policy.act_batch(np.zeros((2, obs_size(TINY_NAV.perception)), dtype=np.float32)).shape == (2, 3)
    resumed = json.loads((runs["resumed"] / "provenance.json").read_text())
    assert resumed["timesteps"] == 3 * 8 * 64 and resumed["resumed_from"].endswith("step_00000000512")


def test_training_is_deterministic_from_its_seed(runs):
    """The same configuration and seed twice: the same weights, normalisation statistics, reward curve
    (all but the wall-clock column) and kept model's validation (one thread, as `uam-compare train`)."""
    a, b = (load_policy(runs[k]) for k in "ab")
    for (name, wa), (_, wb) in zip(a.network.state_dict().items(), b.network.state_dict().items()):
        assert np.array_equal(wa.numpy(), wb.numpy()), name
    for key in ("mean", "var", "count", "epsilon", "clip_obs"):
        assert np.array_equal(getattr(a.obs_norm, key), getattr(b.obs_norm, key)), key
    rows_a, rows_b = (_rows(runs[k] / "reward_curve.csv") for k in "ab")
    assert [{k: v for k, v in r.items() if k != "wall_s"} for r in rows_a] == \
           [{k: v for k, v in r.items() if k != "wall_s"} for r in rows_b]
    prov_a, prov_b = (json.loads((runs[k] / "provenance.json").read_text()) for k in "ab")
    assert prov_a["validation_of_kept_model"] == prov_b["validation_of_kept_model"]


def test_recording_does_not_change_what_is_learned(runs):
    a, off = load_policy(runs["a"]), load_policy(runs["off"])
    for (name, wa), (_, wb) in zip(a.network.state_dict().items(), off.network.state_dict().items()):
        assert np.array_equal(wa.numpy(), wb.numpy()), name
    for key in ("mean", "var", "count"):
        assert np.array_equal(getattr(a.obs_norm, key), getattr(off.obs_norm, key)), key
    assert (runs["a"] / "model.zip").stat().st_size > 0 and not (runs["off"] / FLIGHTS_DIR).exists()
    assert json.loads((runs["off"] / "config.json").read_text())["record_flights"] == 0


def test_recording_is_the_same_bytes_twice(runs):
    files = sorted(p.name for p in (runs["a"] / FLIGHTS_DIR).iterdir())
    assert files == sorted(p.name for p in (runs["b"] / FLIGHTS_DIR).iterdir())
    assert files == ["step_00000000000.npz", "step_00000000512.npz", "step_00000001024.npz", "tasks.json"]
    for name in files:
        assert (runs["a"] / FLIGHTS_DIR / name).read_bytes() == (runs["b"] / FLIGHTS_DIR / name).read_bytes(), name


def test_each_checkpoint_flies_the_fixed_tasks_at_the_control_rate(runs):
    tf = TrainingFlights.open(runs["a"])
    assert tf.steps == (0, 512, 1024)
    tasks = tf.tasks
    assert len(tasks.tasks) == 8 and [t.leg for t in tasks.tasks] == ["short", "long"] * 4
    assert tasks.control_hz == 50.0 and "validation" in tasks.rule and tasks.vehicle == "small_quad"
    dist = [np.linalg.norm(np.subtract(t.goal_m, t.start_m)) for t in tasks.tasks]
    assert max(dist[0::2]) < min(dist[1::2])  # short legs are shorter than long ones
    assert len(tasks.cities) == 8 and all(c.boxes.shape[1] == 6 and len(c.boxes) for c in tasks.cities)
    for step in tf.steps:
        ckpt = tf.checkpoint(step)
        assert ckpt.timesteps == step and [f.task for f in ckpt.flights] == list(range(8))
        for f, t in zip(ckpt.flights, tasks.tasks):
            assert f.outcome in OUTCOMES and f.pos_m.dtype == np.float32
            # one sample per control period from t = 0 to the end
            assert len(f.pos_m) == round(f.time_s * tasks.control_hz) + 1
            assert np.allclose(f.pos_m[0], t.start_m, atol=1e-3)
            assert f.min_clearance_m == pytest.approx(float(f.clearance_m.min()))
            assert f.time_s <= t.timeout_s + 1.0 / tasks.control_hz + 1e-6  # ends within the period past it


def test_a_recorded_checkpoint_flies_again(runs):
    """The last checkpoint's stored weights are the kept model's (the curriculum never finished: the last
    model is kept), and the first checkpoint's differ."""
    kept = load_policy(runs["a"])
    last, first = load_checkpoint_policy(runs["a"], 1024), load_checkpoint_policy(runs["a"], 0)
    obs = np.random.default_rng(0).normal(size=(5, kept.obs_norm.mean.size))
    assert np.array_equal(last.act_batch(obs), kept.act_batch(obs))
    assert not np.array_equal(first.act_batch(obs), kept.act_batch(obs))
    with pytest.raises(ValueError, match="no training flights"):
        load_checkpoint_policy(runs["off"], 0)


def test_fixed_tasks_cover_each_air_level_and_both_ends_of_the_air():
    air = AirDistribution(elevation_m=(0.0, 3000.0), isa_offset_k=(0.0, 20.0), turbulence=("none", "moderate"),
                          pool_size=2)
    nav = replace(TINY_NAV, air=air)
    world = NavWorld(eval_config(nav, 8, pool="validation"))
    eps = fixed_tasks(NavBatch(world, 8), 8, seed=1)
    combos = {(e.leg, e.air.level, e.air.field) for e in eps}
    assert combos == {(leg, lv, f) for leg in ("short", "long") for lv in (0, 1) for f in (0, 1)}
    again = fixed_tasks(NavBatch(world, 8), 8, seed=1)
    assert again == eps and fixed_tasks(NavBatch(world, 8), 8, seed=2) != eps


def test_a_bad_checkpoint_file_is_named(runs, tmp_path):
    bad = tmp_path / "step_00000000000.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="step_00000000000.npz: unreadable"):
        read_checkpoint(bad, 8)
    with pytest.raises(ValueError, match=r"no training flights recorded .*uam-compare train"):
        TrainingFlights.open(runs["off"])


def test_a_resumed_run_continues_the_record_and_a_replaced_policy_loses_its_own(runs, tmp_path):
    first, resumed = runs["a"], runs["resumed"]
    assert TrainingFlights.open(resumed).steps == (0, 512, 1024, 1536)
    for name in ("step_00000000000.npz", "step_00000000512.npz", "tasks.json"):  # the history, as it was
        assert (resumed / FLIGHTS_DIR / name).read_bytes() == (first / FLIGHTS_DIR / name).read_bytes()
    # the same folder trained afresh (as `train --overwrite` does), shorter and with another seed: only its own
    again = tmp_path / "again"
    shutil.copytree(first, again)
    train(replace(CFG, total_timesteps=8 * 64, seed=6, checkpoint_every=0), again, progress=False,
          log=lambda *_: None)
    assert TrainingFlights.open(again).steps == (0, 512)
    assert TrainingFlights.open(again).tasks.seed == 6
