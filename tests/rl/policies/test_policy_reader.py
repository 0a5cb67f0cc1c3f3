"""A policy folder is data: loading it (to fly, evaluate or resume training) runs nothing it holds."""
from __future__ import annotations

import base64
import io
import json
import os
import shutil
import zipfile
from pathlib import Path

import cloudpickle
import numpy as np
import pytest
import torch

from rl.env.vec_env import UAMNavVecEnv
from rl.pilots.learned import load_policy
from rl.sensing.observation import obs_size
from rl.task.config import NavConfig
from rl.training.checkpoints import VEC_NORM_KEYS, load_model_for_resume, restore_vec_normalize
from rl.training.config import TrainConfig
from rl.training.loop import train
from rl.training.ppo import PRESETS

TINY_NAV = NavConfig(city_pool_size=2, wind_pool_size=1, wind_series_s=150.0)


class Payload:
    """Unpickling this runs a shell command that creates `marker`."""

    def __init__(self, marker) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("pol") / "policy"
    train(TrainConfig(total_timesteps=8 * 64, n_envs=8, nav=TINY_NAV, eval_every=8 * 64, eval_episodes=2,
                      checkpoint_every=0), out, progress=False, command="test", log=lambda *_: None)
    return out


@pytest.fixture
def folder(trained, tmp_path):
    dst = tmp_path / "shared_policy"
    shutil.copytree(trained, dst)
    return dst


def _rewrite_zip(path, name, content: bytes) -> None:
    with zipfile.ZipFile(path) as z:
        entries = {n: z.read(n) for n in z.namelist()}
    entries[name] = content
    with zipfile.ZipFile(path, "w") as z:
        for n, c in entries.items():
            z.writestr(n, c)


def _armed(marker) -> bytes:
    """The payload, checked to run when unpickled naively (so the tests below can fail)."""
    blob = cloudpickle.dumps(Payload(marker))
    cloudpickle.loads(blob)
    assert marker.exists()
    marker.unlink()
    return blob


def test_flying_loads_weights_only_and_acts_like_sb3(folder):
    from stable_baselines3 import PPO

    policy = load_policy(folder)
    obs = np.random.default_rng(0).normal(size=(16, obs_size(TINY_NAV.perception)))
    sb3 = PPO.load(str(folder / "model.zip"), device="cpu")  # trusted here: written by this test's training
    ref, _ = sb3.predict(policy.obs_norm.normalize(obs), deterministic=True)
    assert np.array_equal(policy.act_batch(obs), np.asarray(ref, dtype=np.float64))


def test_pickled_entries_in_model_data_never_run(folder, tmp_path):
    marker = tmp_path / "pwned"
    blob = base64.b64encode(_armed(marker)).decode()
    with zipfile.ZipFile(folder / "model.zip") as z:
        data = json.loads(z.read("data"))
    data["lr_schedule"] = {":type:": "x", ":serialized:": blob}
    data["observation_space"] = {":type:": "x", ":serialized:": blob}
    _rewrite_zip(folder / "model.zip", "data", json.dumps(data).encode())
    load_policy(folder)  # flying never reads `data`
    venv = restore_vec_normalize(folder / "vecnormalize.npz", UAMNavVecEnv(2, TINY_NAV, seed=0))
    model = load_model_for_resume(folder / "model.zip", venv, PRESETS["paper"], TINY_NAV.decision_hz)
    assert model.num_timesteps == 8 * 64 and not marker.exists()
    # an entry this version does not know how to replace is refused, not unpickled
    data["my_callback"] = {":type:": "x", ":serialized:": blob}
    _rewrite_zip(folder / "model.zip", "data", json.dumps(data).encode())
    with pytest.raises(ValueError, match=r"model\.zip.*my_callback.*refused"):
        load_model_for_resume(folder / "model.zip", venv, PRESETS["paper"], TINY_NAV.decision_hz)
    assert not marker.exists()


def test_code_in_the_weights_file_is_refused(folder, tmp_path):
    marker = tmp_path / "pwned"
    _armed(marker)
    buf = io.BytesIO()
    torch.save({"mlp_extractor.policy_net.0.weight": Payload(marker)}, buf)
    _rewrite_zip(folder / "model.zip", "policy.pth", buf.getvalue())
    with pytest.raises(ValueError, match=r"model\.zip: policy\.pth holds something other than tensors; refused"):
        load_policy(folder)
    assert not marker.exists()


@pytest.mark.parametrize("name", ["obs_norm.npz", "vecnormalize.npz"])
def test_code_in_the_statistics_is_refused(folder, tmp_path, name):
    marker = tmp_path / "pwned"
    _armed(marker)
    arr = np.empty(1, dtype=object)
    arr[0] = Payload(marker)
    with open(folder / name, "wb") as f:
        np.savez(f, **{k: arr for k in VEC_NORM_KEYS})
    with pytest.raises(ValueError, match=rf"{name}: not a plain-number \.npz file"):
        if name == "obs_norm.npz":
            load_policy(folder)
        else:
            restore_vec_normalize(folder / name, UAMNavVecEnv(2, TINY_NAV, seed=0))
    assert not marker.exists()


def test_statistics_of_another_observation_size_are_named(folder):
    with np.load(folder / "obs_norm.npz") as z:
        stats = {k: z[k] for k in z.files}
    stats["mean"], stats["var"] = stats["mean"][:-3], stats["var"][:-3]
    np.savez(folder / "obs_norm.npz", **stats)
    n = obs_size(TINY_NAV.perception)
    with pytest.raises(ValueError,
                       match=rf"obs_norm\.npz: statistics for {n - 3} observations; config.json's task gives {n}"):
        load_policy(folder)


def test_run_checks_the_whole_policy_before_creating_its_folder(folder, tmp_path, capsys):
    from compare.cli import main

    (folder / "obs_norm.npz").write_bytes(b"not an npz")
    out = tmp_path / "run"
    tiny = Path(__file__).resolve().parents[2] / "data" / "tiny_scenario.yaml"
    assert main(["run", str(tiny), "--policy", str(folder), "--out", str(out), "--no-progress"]) == 2
    assert "obs_norm.npz: not a plain-number .npz file" in capsys.readouterr().err
    assert not out.exists()
