"""Simulator shell: explicit state, determinism under seeded turbulence, batch = N single vehicles."""
from __future__ import annotations

import numpy as np
import pytest

from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions
from uam_fdm.air.wind import TurbulenceLevel, WindConditions, WindField, WindShear
from uam_fdm.sim import BatchSimulator, Simulator
from uam_fdm.vehicle.model import hover_state


@pytest.fixture(scope="module")
def atmosphere() -> Atmosphere:
    return Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=300.0)


def _wind(seed: int, level=TurbulenceLevel.MODERATE) -> WindField:
    # three turbulence rungs around the flights' heights and a power-law steady profile
    return WindField.from_conditions(WindConditions((4.0, -2.0, 0.0), level, WindShear("power", 10.0, 0.3)),
                                     seed=seed, duration_s=12.0, airspeed_m_s=8.0, heights_m=(20.0, 40.0, 80.0))


def _fly(sim: Simulator, p, seconds: float) -> tuple[np.ndarray, float]:
    sim.reset(hover_state(p, (0.0, 0.0, 50.0)))
    states = []
    for k in range(int(seconds * sim.dynamics.control_hz)):
        cmd = np.array([4.0 * np.cos(0.3 * k / 50), 4.0 * np.sin(0.3 * k / 50), 0.5, 0.0])
        states.append(sim.advance_velocity(cmd).states)
    return np.concatenate(states), sim.state.energy_J


def test_seeded_turbulent_flight_repeats_exactly(vehicles, compiled_dynamics, atmosphere):
    p, dyn = vehicles["small_quad"], compiled_dynamics["small_quad"]
    a, ea = _fly(Simulator(dyn, atmosphere, _wind(7)), p, 10.0)
    b, eb = _fly(Simulator(dyn, atmosphere, _wind(7)), p, 10.0)
    c, _ = _fly(Simulator(dyn, atmosphere, _wind(8)), p, 10.0)
    np.testing.assert_array_equal(a, b)
    assert ea == eb
    assert np.abs(a[:, :3] - c[:, :3]).max() > 0.05   # another gust realisation moves the vehicle differently
    # Moderate turbulence visibly disturbs the flight compared with the same steady wind alone.
    calm, _ = _fly(Simulator(dyn, atmosphere, _wind(7, TurbulenceLevel.NONE)), p, 10.0)
    assert np.abs(a[:, :3] - calm[:, :3]).max() > 0.1


def test_pure_step_equals_stateful_advance(vehicles, compiled_dynamics, atmosphere):
    p, dyn = vehicles["small_quad"], compiled_dynamics["small_quad"]
    sim = Simulator(dyn, atmosphere, _wind(3))
    x0 = hover_state(p, (5.0, 5.0, 40.0))
    sim.reset(x0, t0_s=1.0)
    u = p.hover_rotor_speeds_rad_s() * 1.01
    pure = sim.step(x0, u, 1.0)
    advanced = sim.advance(u)
    np.testing.assert_array_equal(pure.states, advanced.states)
    assert sim.state.t_s == pytest.approx(1.0 + 1.0 / dyn.control_hz)
    assert sim.state.energy_J == pure.energy_J
    np.testing.assert_array_equal(sim.state.x, pure.final_state)
    with pytest.raises(ValueError, match="finite"):
        sim.reset(np.full(dyn.layout.nx, np.nan))


def test_a_period_flown_with_the_callers_env_is_the_same_period(vehicles, compiled_dynamics, atmosphere):
    """The runner builds a period's environment input once (to record its wind and power) and hands it over."""
    p, dyn = vehicles["small_quad"], compiled_dynamics["small_quad"]
    own, given = Simulator(dyn, atmosphere, _wind(5)), Simulator(dyn, atmosphere, _wind(5))
    for sim in (own, given):
        sim.reset(hover_state(p, (0.0, 0.0, 30.0)))
    for k in range(25):
        cmd = np.array([3.0, -1.0, 0.5 * (k % 2), 0.0])
        height = 30.0 - 0.1 * k
        s = given.state
        a = own.advance_velocity(cmd, height) if k % 3 else own.advance(p.hover_rotor_speeds_rad_s(), height)
        env = given.env(s.x, s.t_s, height)
        b = (given.advance_velocity(cmd, env=env) if k % 3 else
             given.advance(p.hover_rotor_speeds_rad_s(), env=env))
        np.testing.assert_array_equal(a.states, b.states)
    assert own.state.energy_J == given.state.energy_J
    np.testing.assert_array_equal(own.state.ctrl_state, given.state.ctrl_state)


def test_batch_simulator_equals_single_simulators(vehicles, compiled_dynamics, atmosphere):
    p, dyn = vehicles["small_quad"], compiled_dynamics["small_quad"]
    winds = [_wind(s) for s in (1, 2, 3)]
    batch = BatchSimulator(dyn, atmosphere, winds)
    singles = [Simulator(dyn, atmosphere, w) for w in winds]
    x = np.array([hover_state(p, (float(i), 0.0, 30.0 + 10 * i)) for i in range(3)])
    xi = np.zeros((3, 3))
    t = np.array([0.0, 0.5, 1.0])
    cmd = np.array([[3.0, 0.0, 0.0, 0.0], [0.0, -2.0, 1.0, 0.5], [1.0, 1.0, -1.0, -0.5]])
    for _ in range(50):
        rb = batch.step_velocity_batch(x, xi, cmd, t)
        for i, sim in enumerate(singles):
            rs = sim.step_velocity(x[i], xi[i], cmd[i], t[i])
            np.testing.assert_array_equal(rs.states, rb.states[i])
            np.testing.assert_array_equal(rs.ctrl_state, rb.ctrl_state[i])
        x, xi, t = rb.final_state, rb.ctrl_state, t + 1.0 / dyn.control_hz


def test_hot_and_high_needs_faster_rotors(vehicles, compiled_dynamics):
    """At 2000 m and ISA+20 K the sea-level trim no longer holds the vehicle up."""
    p, dyn = vehicles["uam_multicopter"], compiled_dynamics["uam_multicopter"]
    hot_high = Atmosphere.from_jsbsim(AtmosphereConditions(elevation_m=2000.0, isa_offset_k=20.0), z_max_m=200.0)
    sigma = hot_high.density_ratio(50.0)
    assert 0.75 < sigma < 0.80   # ρ = p/(R T) with p(2000 m) = 79.5 kPa, T = 295.15 K -> 0.766 of ρ0
    sim = Simulator(dyn, hot_high)
    sim.reset(hover_state(p, (0.0, 0.0, 50.0)))
    for _ in range(50):
        sim.advance(p.hover_rotor_speeds_rad_s(1.0))
    assert sim.state.x[2] < 50.0 - 0.5 * 9.80665 * (1 - sigma) * 1.0**2 * 0.8   # sinks at ≈ (1-σ) g
    sim.reset(hover_state(p, (0.0, 0.0, 50.0), density_ratio=sigma))
    for _ in range(50):
        sim.advance(p.hover_rotor_speeds_rad_s(sigma))
    assert abs(sim.state.x[2] - 50.0) < 1e-3
