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
