"""The NMPC tracker on the full simulator: straight line and circle, with and without wind."""
from __future__ import annotations

import numpy as np
import pytest

from planners.mpc import MPCConfig, MPCTracker
from uam_fdm.atmosphere import Atmosphere, AtmosphereConditions
from uam_fdm.model import hover_state
from uam_fdm.sim import Simulator
from uam_fdm.wind import TurbulenceLevel, WindConditions, WindField


@pytest.fixture(scope="module")
def trackers(vehicles) -> dict[str, MPCTracker]:
    return {name: MPCTracker(p) for name, p in vehicles.items()}


def _line(speed, accel):
    """A straight line along (1, 0.5, 0), accelerating from rest at `accel` up to `speed`."""
    direction = np.array([1.0, 0.5, 0.0]) / np.hypot(1.0, 0.5)

    def ref(t):
        t_acc = speed / accel
        s = np.where(t < t_acc, 0.5 * accel * t**2, 0.5 * speed * t_acc + speed * (t - t_acc))
        v = np.where(t < t_acc, accel * t, speed)
        return np.outer(s, direction) + [0.0, 0.0, 30.0], np.outer(v, direction)
    return ref


def _circle(radius, speed):
    w = speed / radius
    return lambda t: (np.stack([radius * np.sin(w * t), radius * (1 - np.cos(w * t)), 30.0 + 0 * t], 1),
                      np.stack([speed * np.cos(w * t), speed * np.sin(w * t), 0 * t], 1))


def _track(p, dyn, mpc, reference, seconds, wind: WindField, settle_s=3.0):
    atm = Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=200.0)
    sim = Simulator(dyn, atm, wind)
    sim.reset(hover_state(p, (0.0, 0.0, 30.0), density_ratio=atm.density_ratio(30.0)))
    mpc.reset()
    n, h = mpc.config.horizon_steps, mpc.config.step_s
    errors, times, commands = [], [], []
    for _ in range(int(seconds * dyn.control_hz)):
        t = sim.state.t_s
        pos, vel = reference(t + h * np.arange(n + 1))
        sol = mpc.solve(sim.state.x, pos, vel, 0.0, atm.density_ratio(sim.state.x[2]), elapsed_s=1 / dyn.control_hz)
        times.append(sol.solve_time_s)
        commands.append(sol.rotor_speeds_rad_s)
        r = sim.advance(sol.rotor_speeds_rad_s)
        t_sub = t + dyn.dt_s * np.arange(1, dyn.n_substeps + 1)
        errors.append(np.linalg.norm(r.states[:, 0:3] - reference(t_sub)[0], axis=1))
    err = np.concatenate(errors)[int(settle_s * dyn.physics_hz):]
    return float(np.sqrt(np.mean(err**2))), np.array(times), np.array(commands)


# RMS position error bounds [m] after a 3 s settling (measured: quad calm 0.004 m on the circle).
@pytest.mark.parametrize("shape", ["line", "circle"])
@pytest.mark.parametrize("turbulence", [TurbulenceLevel.NONE, TurbulenceLevel.LIGHT])
def test_quad_tracks_line_and_circle(shape, turbulence, vehicles, compiled_dynamics, trackers):
    p, dyn, mpc = vehicles["small_quad"], compiled_dynamics["small_quad"], trackers["small_quad"]
    reference = _line(5.0, 3.0) if shape == "line" else _circle(20.0, 4.0)
    steady = (0.0, 0.0, 0.0) if turbulence is TurbulenceLevel.NONE else (2.0, -1.0, 0.0)
    wind = WindField.from_conditions(WindConditions(steady, turbulence), seed=4, duration_s=20.0,
                                     airspeed_m_s=5.0, heights_m=(30.0,))
    rms, times, commands = _track(p, dyn, mpc, reference, 15.0, wind)
    bound = 0.05 if turbulence is TurbulenceLevel.NONE else 0.5   # the MPC does not know the wind
    assert rms < bound, f"RMS tracking error {rms:.3f} m"
    assert mpc.n_failures == 0
    assert commands.min() >= p.rotor_speed_min_rad_s - 1e-9 and commands.max() <= p.rotor_speed_max_rad_s + 1e-9


def test_uam_tracks_a_line_with_wrench_inputs(vehicles, compiled_dynamics, trackers):
    p, dyn, mpc = vehicles["uam_multicopter"], compiled_dynamics["uam_multicopter"], trackers["uam_multicopter"]
    assert mpc.input_mode == "wrench" and mpc.motor_lag
    rms, _, commands = _track(p, dyn, mpc, _line(8.0, 1.0), 14.0, WindField.calm(), settle_s=0.0)
    assert rms < 0.5, f"RMS tracking error {rms:.3f} m"
    assert mpc.n_failures <= 0.02 * mpc.n_solves
    assert commands.min() >= p.rotor_speed_min_rad_s - 1e-9 and commands.max() <= p.rotor_speed_max_rad_s + 1e-9


def test_failed_solve_falls_back_and_is_counted(vehicles):
    p = vehicles["small_quad"]
    mpc = MPCTracker(p, MPCConfig(max_iterations=1, solver="ipopt"))   # one Ipopt iteration cannot converge
    x = hover_state(p, (0.0, 0.0, 30.0))
    n = mpc.config.horizon_steps
    far = np.tile([40.0, 0.0, 30.0], (n + 1, 1))
    sol = mpc.solve(x, far, np.zeros((n + 1, 3)), 0.0, 1.0)
    assert not sol.success and sol.fallback and sol.status.startswith("fallback_hover")
    np.testing.assert_allclose(sol.rotor_speeds_rad_s, p.hover_rotor_speeds_rad_s(1.0))
    assert mpc.n_failures == 1 and mpc.n_solves == 1


def test_halfspace_keeps_the_prediction_off_a_wall(vehicles, trackers):
    p, mpc = vehicles["small_quad"], trackers["small_quad"]
    mpc.reset()
    n, k = mpc.config.horizon_steps, mpc.config.n_halfspaces
    x = hover_state(p, (0.0, 0.0, 30.0))
    target = np.tile([10.0, 0.0, 30.0], (n + 1, 1))       # the reference goes through a wall at x = 5
    normals = np.zeros((n, k, 3))
    offsets = np.full((n, k), -1.0)
    normals[:, 0] = (-1.0, 0.0, 0.0)
    offsets[:, 0] = -(5.0 - p.collision_radius_m - 0.5)   # -x >= -(4.08): x <= 4.08
    for _ in range(5):
        sol = mpc.solve(x, target, np.zeros((n + 1, 3)), 0.0, 1.0, normals, offsets, elapsed_s=0.02)
    assert sol.success
    assert sol.predicted_states[:, 0].max() <= 5.0 - p.collision_radius_m - 0.5 + 0.05
