"""Physics validation of the flight model against closed-form and textbook results."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions
from uam_fdm.sim import Simulator
from uam_fdm.vehicle.dynamics import VehicleDynamics
from uam_fdm.vehicle.model import StateLayout, hover_state, make_env
from uam_fdm.vehicle.params import GRAVITY_M_S2

PRESETS = ("small_quad", "uam_multicopter")


@pytest.fixture(scope="module")
def sea_level() -> Atmosphere:
    return Atmosphere.from_jsbsim(AtmosphereConditions(elevation_m=0.0), z_max_m=500.0)


@pytest.mark.parametrize("name", PRESETS)
def test_hover_at_trim_holds_position_for_10_s(name, vehicles, compiled_dynamics, sea_level):
    p, dyn = vehicles[name], compiled_dynamics[name]
    z0 = 50.0
    sigma = sea_level.density_ratio(z0)
    sim = Simulator(dyn, sea_level)
    sim.reset(hover_state(p, (10.0, -5.0, z0), yaw_rad=0.3, density_ratio=sigma))
    u = p.hover_rotor_speeds_rad_s(sigma)
    drift = 0.0
    for _ in range(int(10.0 * dyn.control_hz)):
        r = sim.advance(u)
        drift = max(drift, float(np.max(np.linalg.norm(r.states[:, 0:3] - [10.0, -5.0, z0], axis=1))))
    assert sim.state.t_s == pytest.approx(10.0)
    assert drift < 0.01, f"hover drifted {drift:.4f} m in 10 s"


@pytest.mark.parametrize("name", PRESETS)
def test_free_fall_with_rotors_stopped_and_no_drag(name, vehicles, sea_level):
    p = dataclasses.replace(vehicles[name], drag_linear_N_s_m=(0.0, 0.0, 0.0), drag_quadratic_N_s2_m2=(0.0, 0.0, 0.0),
                            rotor_speed_min_rad_s=0.0)
    dyn = VehicleDynamics(p, physics_hz=500.0, control_hz=50.0)
    sim = Simulator(dyn, sea_level)
    x0 = hover_state(p, (0.0, 0.0, 400.0))
    x0[StateLayout(p.n_rotors).rotor] = 0.0
    sim.reset(x0)
    u = np.zeros(p.n_rotors)
    for k in range(1, 251):   # 5 s
        r = sim.advance(u)
        t = np.arange(1, dyn.n_substeps + 1) * dyn.dt_s + (k - 1) / dyn.control_hz
        np.testing.assert_allclose(r.states[:, 2], 400.0 - 0.5 * GRAVITY_M_S2 * t**2, atol=1e-9, rtol=0)
        np.testing.assert_allclose(r.states[:, 5], -GRAVITY_M_S2 * t, atol=1e-9, rtol=0)
        np.testing.assert_allclose(r.states[:, 0:2], 0.0, atol=1e-12)


@pytest.mark.parametrize("name", PRESETS)
@pytest.mark.parametrize("elevation_m", [0.0, 2000.0])
def test_trim_rotor_speed_matches_closed_form(name, elevation_m, vehicles, compiled_dynamics):
    p, dyn = vehicles[name], compiled_dynamics[name]
    atm = Atmosphere.from_jsbsim(AtmosphereConditions(elevation_m=elevation_m), z_max_m=100.0)
    sigma = atm.density_ratio(0.0)
    expected = math.sqrt(p.mass_kg * GRAVITY_M_S2 / (p.n_rotors * p.thrust_coeff_N_s2 * sigma))
    trim = p.hover_rotor_speeds_rad_s(sigma)
    np.testing.assert_allclose(trim, expected, rtol=1e-9)
    # ... and the model agrees: no acceleration at that trim with that density.
    x = hover_state(p, (0.0, 0.0, 0.0), density_ratio=sigma)
    x_dot = dyn.x_dot(x, trim, make_env(density_ratio=sigma))
    np.testing.assert_allclose(x_dot[3:6], 0.0, atol=1e-9)
    np.testing.assert_allclose(x_dot[10:13], 0.0, atol=1e-9)
    if elevation_m > 0:   # thinner air needs faster rotors: ρ(2000 m)/ρ0 = 0.8216 (ICAO)
        assert sigma == pytest.approx(0.8216, rel=5e-3)
        assert expected == pytest.approx(p.hover_rotor_speeds_rad_s(1.0)[0] / math.sqrt(sigma), rel=1e-12)


@pytest.mark.parametrize("name", PRESETS)
def test_differential_yaw_command_gives_predicted_angular_acceleration(name, vehicles, compiled_dynamics):
    p, dyn = vehicles[name], compiled_dynamics[name]
    lay = StateLayout(p.n_rotors)
    spins = np.array(p.rotor_spins, float)
    hover = p.hover_rotor_speeds_rad_s()
    delta = 0.05
    omega = hover * np.sqrt(1.0 - spins * delta)   # clockwise rotors (s = -1) faster: total thrust unchanged
    x = hover_state(p, (0.0, 0.0, 100.0))
    x[lay.rotor] = omega
    env = make_env()
    predicted = -np.sum(spins * p.torque_coeff_Nm_s2 * omega**2) / p.inertia[2, 2]
    assert predicted > 0, "clockwise rotors faster must yaw the body counter-clockwise (+z, FLU)"
    assert predicted == pytest.approx(p.torque_coeff_Nm_s2 * np.sum(hover**2) * delta / p.inertia[2, 2], rel=1e-9)
    x_dot = dyn.x_dot(x, omega, env)
    assert x_dot[12] == pytest.approx(predicted, rel=1e-9)
    assert x_dot[5] == pytest.approx(0.0, abs=1e-9)
    # Integrated: holding those speeds for 0.1 s, the yaw rate grows linearly at that rate.
    r = dyn.period_rotor(x, omega, env)
    for _ in range(4):
        r = dyn.period_rotor(r.final_state, omega, env)
    assert r.final_state[12] == pytest.approx(predicted * 0.1, rel=1e-3)


@pytest.mark.parametrize("name", PRESETS)
def test_shaft_power_and_energy_at_hover(name, vehicles, compiled_dynamics):
    p, dyn = vehicles[name], compiled_dynamics[name]
    x = hover_state(p, (0.0, 0.0, 100.0))
    hover = p.hover_rotor_speeds_rad_s()
    expected = float(np.sum(p.torque_coeff_Nm_s2 * hover**3))
    env = make_env()
    assert dyn.shaft_power_W(x, env) == pytest.approx(expected, rel=1e-12)
    r = dyn.period_rotor(x, hover, env)
    assert r.energy_J == pytest.approx(expected / dyn.control_hz, rel=1e-9)


@pytest.mark.parametrize("name", PRESETS)
def test_jacobians_match_finite_differences(name, vehicles, compiled_dynamics):
    p, dyn = vehicles[name], compiled_dynamics[name]
    rng = np.random.default_rng(3)
    x = hover_state(p, (0.0, 0.0, 100.0), yaw_rad=0.4)
    x[3:6] = rng.normal(size=3)
    x[10:13] = 0.2 * rng.normal(size=3)
    u = p.hover_rotor_speeds_rad_s() * (1 + 0.05 * rng.normal(size=p.n_rotors))
    env = make_env((2.0, -1.0, 0.0), 0.95)
    a, b = dyn.jacobians(x, u, env)
    for j in range(x.size):
        h = 1e-6 * max(1.0, abs(x[j]))
        e = np.zeros_like(x)
        e[j] = h
        fd = (dyn.x_dot(x + e, u, env) - dyn.x_dot(x - e, u, env)) / (2 * h)
        np.testing.assert_allclose(a[:, j], fd, rtol=1e-5, atol=1e-5 * max(1.0, np.abs(fd).max()))
    for j in range(u.size):
        h = 1e-3 * u[j]
        e = np.zeros_like(u)
        e[j] = h
        fd = (dyn.x_dot(x, u + e, env) - dyn.x_dot(x, u - e, env)) / (2 * h)
        np.testing.assert_allclose(b[:, j], fd, rtol=1e-5, atol=1e-8)
