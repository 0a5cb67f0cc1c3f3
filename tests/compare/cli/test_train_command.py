"""`uam-compare train` as a user meets it: the mini-batch follows --envs, the final validation is said once, the
reward curve has one row per update, the last lines say what to do next; `--scenario FILE` trains in a scenario's
map and air, and a file or option it cannot train on is one line before anything is built."""
from __future__ import annotations

import csv
import json
import re
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
import yaml

import rl.training.loop
from cli_checks import fails
from compare.cli import main
from rl.task.air import AirDistribution
from run_data import TINY

CALM = AirDistribution(turbulence=("none",), steady_wind_max_m_s=0.0)
QUICK = ["--timesteps", "1024", "--envs", "8", "--eval-every", "512", "--eval-episodes", "2", "--record-flights", "1",
         "--no-progress"]


@pytest.fixture
def quick_training(monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """The command's own training, in one calm generated city (no gusts to tabulate) unless it trains on a
    scenario: seconds. Holds what the command asked for ("cfg", "ground")."""
    real = rl.training.loop.train
    seen: dict[str, Any] = {}

    def train(cfg: Any, out: Path, **kwargs: Any) -> Any:
        seen.update(cfg=cfg, ground=kwargs.get("ground"))
        if kwargs.get("ground") is None:
            cfg = replace(cfg, nav=replace(cfg.nav, city_pool_size=1, wind_pool_size=1, wind_series_s=150.0, air=CALM))
        return real(cfg, out, **kwargs)

    monkeypatch.setattr(rl.training.loop, "train", train)
    return seen


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _scenario(tmp_path: Path, name: str = "calm.yaml", **changes: Any) -> Path:
    """The tiny test scenario (three buildings in 160 x 130 m) in still air, with `changes` to its keys."""
    data = yaml.safe_load(TINY.read_text())
    data["atmosphere"] = {"elevation_m": 1200.0, "isa_offset_k": 10.0, "wind_mps": [2.0, 1.5, 0.0],
                          "turbulence": "none"}
    data.update(changes)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def test_train_says_its_final_validation_once_and_what_to_do_next(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                                 recwarn: pytest.WarningsRecorder,
                                                                 quick_training: dict[str, Any]) -> None:
    out = tmp_path / "policy"
    assert main(["train", *QUICK, "--out", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    # the evaluation at 512 as it happens, and the final one only in the closing line (the curriculum keeps the last)
    assert sum("validation success" in ln for ln in lines) == 2, lines
    assert not any(re.search(r"\b1,024 steps", ln) for ln in lines), lines
    assert any(ln.startswith(f"policy written to {out} (the model at 1,024 timesteps)") for ln in lines), lines
    steps = lines[lines.index("next:") + 1:]
    assert [s.split()[:2] for s in steps] == [["uam-compare", "view-training"], ["tensorboard", "--logdir"],
                                              ["uam-compare", "run"]]
    assert f"--policy {out}" in steps[-1] and str(out / "tb") in steps[1]
    rows = _rows(out / "reward_curve.csv")
    assert [int(r["timesteps"]) for r in rows] == [512, 1024]  # one row per update, none repeated
    assert rows[-1]["eval_episodes"] == "2" and rows[-1]["train_episodes"] != "" and rows[-1]["difficulty"] != ""
    assert [w for w in recwarn.list if "stable_baselines3" in w.filename] == []  # the mini-batch fits the rollout
    config = json.loads((out / "config.json").read_text())
    assert config["ppo"]["batch_size"] == 8 * 64 and config["scenario"] is None


def test_envs_that_split_the_rollout_badly_are_refused_before_anything_is_built(tmp_path: Path,
                                                                                capsys: pytest.CaptureFixture) -> None:
    line = fails(["train", "--envs", "4099", "--out", str(tmp_path / "p")], capsys, tmp_path, "--envs 4099")
    assert "n_envs" not in line


def test_train_on_a_scenario_trains_in_its_map_and_air(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                       quick_training: dict[str, Any]) -> None:
    scenario = _scenario(tmp_path)
    out = tmp_path / "mine"
    assert main(["train", "--scenario", str(scenario), *QUICK, "--out", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    cfg, ground = quick_training["cfg"], quick_training["ground"]
    assert cfg.scenario == str(scenario) and ground.source == str(scenario)
    assert cfg.curriculum.start == 1.0  # legs drawn once, at full length
    air = cfg.nav.air
    assert (air.elevation_m, air.isa_offset_k, air.turbulence) == ((1200.0, 1200.0), (10.0, 10.0), ("none",))
    assert air.steady_wind_max_m_s == pytest.approx(2.5)  # the scenario's horizontal wind speed, any heading
    config = json.loads((out / "config.json").read_text())
    assert config["scenario"] == str(scenario) and config["nav"]["air"]["elevation_m"] == [1200.0, 1200.0]
    tasks = json.loads((out / "training_flights" / "tasks.json").read_text())
    assert [c["bounds_max_m"] for c in tasks["cities"]] == [[160.0, 130.0, 60.0]]  # flown in the scenario's map
    pools = json.loads((out / "provenance.json").read_text())["pools"]
    assert str(scenario) in pools["training"] and "own 1 episode" in pools["test"]
    assert lines[-1].split()[:3] == ["uam-compare", "run", str(scenario)]


@pytest.mark.parametrize(("changes", "expected"), [
    ({"atmosphere": {"turbulence": "gale"}}, ("atmosphere.turbulence", "gale")),
    ({"episodes": [{"start": [60.0, 40.0, 10.0], "goal": [110.0, 45.0, 12.0]}]}, ("episodes[0].start", "building")),
    ({"vehicle": "uam_multicopter", "episodes": [{"start": [20.0, 40.0, 30.0], "goal": [120.0, 45.0, 30.0]}]},
     ("map", "no free start and goal")),  # the UAM's legs (300 m and more) do not fit in 160 x 130 m
    ({"map": {"geojson": "triangle.geojson"}}, ("map", "not a box")),
])
def test_a_scenario_it_cannot_train_on_is_one_line_naming_file_and_key(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                                      changes: dict, expected: tuple[str, ...]) -> None:
    triangle = {"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {"height": 20.0},
                "geometry": {"type": "Polygon", "coordinates": [[[40, 40], [80, 40], [60, 90], [40, 40]]]}}]}
    (tmp_path / "triangle.geojson").write_text(json.dumps(triangle))
    scenario = _scenario(tmp_path, **changes)
    fails(["train", "--scenario", str(scenario), "--out", str(tmp_path / "p"), "--no-progress"], capsys, tmp_path,
          str(scenario), *expected)


@pytest.mark.parametrize(("argv", "expected"), [
    (["--envelope"], ("--scenario and --envelope",)), (["--turbulence", "light"], ("--turbulence",)),
    (["--city-pool", "4"], ("--city-pool",)), (["--vehicle", "uam_multicopter"], ("--vehicle uam_multicopter",)),
])
def test_options_the_scenario_states_otherwise_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                           argv: list[str], expected: tuple[str, ...]) -> None:
    scenario = _scenario(tmp_path)
    fails(["train", "--scenario", str(scenario), *argv, "--out", str(tmp_path / "p")], capsys, tmp_path, *expected)
    fails(["train", "--scenario", str(tmp_path / "none.yaml"), "--out", str(tmp_path / "p")], capsys, tmp_path,
          "--scenario", "no such file")


def test_train_draws_the_sensing_and_map_error_levels_it_is_given(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                                   quick_training: dict[str, Any]) -> None:
    out = tmp_path / "sensing"
    assert main(["train", *QUICK, "--sensing", "perfect,degraded", "--map-error", "exact, wrong",
                 "--route-refresh", "1", "--out", str(out)]) == 0
    nav = quick_training["cfg"].nav
    assert (nav.sensing, nav.map_error, nav.route.refresh_s) == (("perfect", "degraded"), ("exact", "wrong"), 1.0)
    config = json.loads((out / "config.json").read_text())["nav"]
    assert (config["sensing"], config["map_error"]) == (["perfect", "degraded"], ["exact", "wrong"])
    assert config["exact_maps_at_perfect"] is False
    kept = tmp_path / "kept"
    assert main(["train", *QUICK, "--sensing", "perfect,degraded", "--map-error", "exact,wrong",
                 "--exact-maps-at-perfect", "--out", str(kept)]) == 0
    assert quick_training["cfg"].nav.exact_maps_at_perfect is True
    assert json.loads((kept / "config.json").read_text())["nav"]["exact_maps_at_perfect"] is True
    fails(["train", "--map-error", "outdated,wrong", "--exact-maps-at-perfect", "--out", str(tmp_path / "p")], capsys,
          tmp_path, "--exact-maps-at-perfect with --map-error outdated,wrong", "add exact")


@pytest.mark.parametrize(("argv", "expected"), [
    (["--sensing", "nominal,foggy"], ("--sensing nominal,foggy", "foggy")),
    (["--sensing", "nominal,nominal"], ("--sensing nominal,nominal",)),
    (["--map-error", "stale"], ("--map-error stale", "stale")),
    (["--route-refresh", "0.25"], ("--route-refresh 0.25", "whole number of decisions")),
    (["--route-refresh", "-1"], ("--route-refresh -1.0", "refresh_s")),
])
def test_unknown_or_repeated_levels_are_refused_by_their_option(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                                 argv: list[str], expected: tuple[str, ...]) -> None:
    fails(["train", *argv, "--out", str(tmp_path / "p")], capsys, tmp_path, *expected)
    assert not (tmp_path / "p").exists()


def test_a_batch_split_over_processes_trains_the_same_policy(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                               quick_training: dict[str, Any]) -> None:
    runs = {}
    for processes in (1, 2):
        out = tmp_path / f"p{processes}"
        assert main(["train", *QUICK, "--record-flights", "0", "--env-processes", str(processes),
                     "--out", str(out)]) == 0
        curve = [{k: v for k, v in row.items() if k != "wall_s"} for row in _rows(out / "reward_curve.csv")]
        runs[processes] = curve, (out / "obs_norm.npz").read_bytes()
    assert quick_training["cfg"].env_processes == 2
    assert runs[1] == runs[2]  # the same episodes, the same statistics, the same updates


def test_env_processes_are_checked_by_their_option(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    fails(["train", "--envs", "8", "--env-processes", "9", "--out", str(tmp_path / "p")], capsys, tmp_path,
          "--env-processes 9", "between 1 and 8")
    fails(["train", "--scenario", str(_scenario(tmp_path)), "--env-processes", "2", "--out", str(tmp_path / "p")],
          capsys, tmp_path, "--env-processes 2 and --scenario")


def test_the_shrinking_noise_preset_caps_the_exploration_by_the_run_s_progress(tmp_path: Path,
                                                                            capsys: pytest.CaptureFixture,
                                                                            quick_training: dict[str, Any]) -> None:
    import io
    import zipfile

    import torch

    log_std = {}
    for preset in ("paper", "paper-shrinking-noise"):
        out = tmp_path / preset
        assert main(["train", *QUICK, "--record-flights", "0", "--preset", preset, "--out", str(out)]) == 0
        with zipfile.ZipFile(out / "model.zip") as z:
            log_std[preset] = torch.load(io.BytesIO(z.read("policy.pth")), map_location="cpu")["log_std"]
    # the second rollout starts half-way: its cap is -1 + (-3 + 1) x 0.5 = -2; one update moves it by far less
    assert torch.all(log_std["paper-shrinking-noise"] < -1.99) and torch.all(log_std["paper"] > -1.05)
    config = json.loads((tmp_path / "paper-shrinking-noise" / "config.json").read_text())
    assert config["ppo"]["log_std_end"] == -3.0 and config["preset"] == "paper-shrinking-noise"
