"""A scenario's map and air as the ground the task is learned on (`rl.env.ground`), and `UAMNav-v0` on it: legs
drawn in the scenario's city, its atmosphere, its rates; what the batch cannot fly is refused naming file and key."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

import rl  # noqa: F401  (registers UAMNav-v0)
from compare.scenarios.scenario import load_scenario
from rl.env.ground import TrainingGround, load_ground
from rl.task.vehicles import task_for
from run_data import TINY
from uam_fdm.city.buildings import BuildingMap, Prism


def _calm(tmp_path: Path, **changes: object) -> Path:
    """The tiny test scenario in still air at 1,200 m (no gusts to tabulate), with `changes` to its keys."""
    data = yaml.safe_load(TINY.read_text())
    data["atmosphere"] = {"elevation_m": 1200.0, "isa_offset_k": 10.0, "wind_mps": [3.0, 4.0, 0.0],
                          "turbulence": "none"}
    data.update(changes)
    path = tmp_path / "calm.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_the_env_flies_legs_in_the_scenarios_map_and_air(tmp_path: Path) -> None:
    path = _calm(tmp_path)
    env = gym.make("UAMNav-v0", scenario=str(path))
    obs, info = env.reset(seed=3)
    assert env.observation_space.contains(obs)
    world = env.unwrapped.world
    scenario = load_scenario(path)
    [city], [atmosphere] = world.cities, world.atmospheres
    assert city.buildings == scenario.city.buildings and np.array_equal(city.bounds_max_m, scenario.city.bounds_max_m)
    heights = np.linspace(0.0, 60.0, 7)
    assert np.array_equal(atmosphere.density_ratio(heights), scenario.air.density_ratio(heights))
    assert atmosphere.density_ratio(0.0) < 0.95  # 1,200 m up on a warm day
    air = env.unwrapped.config.air
    assert air.elevation_m == (1200.0, 1200.0) and air.turbulence == ("none",)
    assert air.steady_wind_max_m_s == pytest.approx(5.0)
    lo, hi = np.array(scenario.city.bounds_min_m), np.array(scenario.city.bounds_max_m)
    for _, task in world.fixed.tasks[:50]:
        for point in (task.start_m, task.goal_m):
            assert np.all(np.array(point) > lo) and np.all(np.array(point) < hi)
            assert scenario.city.clearance_one(*point, 0.42) > 0.0
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert np.isfinite(reward) and env.observation_space.contains(obs)
    env.close()


def test_a_file_a_scenario_and_its_ground_give_the_same_legs(tmp_path: Path) -> None:
    path = _calm(tmp_path)
    ground = load_ground(path)
    nav = ground.task(task_for("small_quad"))
    from_file = gym.make("UAMNav-v0", scenario=path).unwrapped.world.fixed
    from_scenario = gym.make("UAMNav-v0", scenario=load_scenario(path)).unwrapped.world.fixed
    assert from_file.tasks == from_scenario.tasks == ground.legs(nav, len(from_file.tasks), 0).tasks
    assert ground.legs(nav, 8, 0).tasks != ground.legs(nav, 8, 0, stream=1).tasks  # another stream, other legs


def test_the_scenarios_rates_are_the_tasks(tmp_path: Path) -> None:
    ground = load_ground(_calm(tmp_path, physics_hz=400.0, control_hz=20.0))
    nav = ground.task(task_for("small_quad"))
    assert (nav.physics_hz, nav.control_hz, nav.action_repeat) == (400.0, 20.0, 2)
    with pytest.raises(ValueError, match=r"calm\.yaml: control_hz: 25 Hz is not a multiple"):
        load_ground(_calm(tmp_path, physics_hz=500.0, control_hz=25.0)).task(task_for("small_quad"))


@pytest.mark.parametrize(("changes", "expected"), [
    ({"atmosphere": {"turbulence": "gale"}}, r"calm\.yaml: atmosphere\.turbulence: .*gale"),
    ({"bounds": {"min": [0, 0, 0], "max": [20, 20, 60]}, "map": {"buildings": []},
      "episodes": [{"start": [5, 5, 10], "goal": [15, 15, 10]}]}, r"calm\.yaml: map: no free start and goal"),
])
def test_a_bad_scenario_file_is_named_with_its_key(tmp_path: Path, changes: dict, expected: str) -> None:
    with pytest.raises(ValueError, match=expected):
        gym.make("UAMNav-v0", scenario=_calm(tmp_path, **changes))


def test_what_the_batch_cannot_fly_is_refused_naming_the_key(tmp_path: Path) -> None:
    scenario = load_scenario(_calm(tmp_path))
    city = scenario.city
    prism = replace(scenario, city=BuildingMap([*city.buildings, Prism(9, ((0, 0), (10, 0), (5, 8)), 10.0)],
                                               city.bounds_min_m, city.bounds_max_m))
    with pytest.raises(ValueError, match=r"calm\.yaml: map: obstacle 9 is not a box"):
        TrainingGround.from_scenario(prism)
    heavier = replace(scenario, vehicle=replace(scenario.vehicle, mass_kg=scenario.vehicle.mass_kg * 1.05))
    with pytest.raises(ValueError, match=r"calm\.yaml: vehicle: .*other parameters"):
        TrainingGround.from_scenario(heavier)
    ground = TrainingGround.from_scenario(scenario)
    with pytest.raises(ValueError, match=r"calm\.yaml: vehicle: 'small_quad'; the task is for 'uam_multicopter'"):
        ground.task(task_for("uam_multicopter"))
    with pytest.raises(ValueError, match="scenario"):
        gym.make("UAMNav-v0", scenario=ground, world=object())
