"""Shared fixtures: vehicles and their compiled dynamics, built once per test session."""
from __future__ import annotations

import pytest

from uam_fdm.vehicle.dynamics import VehicleDynamics
from uam_fdm.vehicle.params import VehicleParams, load_vehicle

PRESETS = ("small_quad", "uam_multicopter")


@pytest.fixture(scope="session")
def vehicles() -> dict[str, VehicleParams]:
    return {name: load_vehicle(name) for name in PRESETS}


@pytest.fixture(scope="session")
def compiled_dynamics(vehicles) -> dict[str, VehicleDynamics]:
    return {name: VehicleDynamics(p, physics_hz=500.0, control_hz=50.0, compiled=True)
            for name, p in vehicles.items()}


@pytest.fixture(scope="session")
def vm_dynamics(vehicles) -> dict[str, VehicleDynamics]:
    return {name: VehicleDynamics(p, physics_hz=500.0, control_hz=50.0, compiled=False)
            for name, p in vehicles.items()}


@pytest.fixture(scope="session")
def tiny_flights_policy(tmp_path_factory):
    """A policy folder from the tiny training configuration, with its recorded training flights
    (checkpoints at 0, 512 and 1024 timesteps; seconds)."""
    from rl.task.config import NavConfig
    from rl.training.config import TrainConfig
    from rl.training.loop import train

    out = tmp_path_factory.mktemp("flights") / "pol"
    cfg = TrainConfig(total_timesteps=2 * 8 * 64, n_envs=8, nav=NavConfig(city_pool_size=2, wind_pool_size=1,
                                                                           wind_series_s=150.0),
                      eval_every=8 * 64, eval_episodes=2, checkpoint_every=0, seed=5, record_flights=4)
    train(cfg, out, progress=False, command="test", log=lambda *_: None)
    return out
