"""The NMPC tracker: straight line and circle on the full simulator, with and without wind, for the
real-time iteration (the default) and Ipopt; fallback; the clearance half-space; the solvers'
agreement on fixed problems."""
from __future__ import annotations

import numpy as np
import pytest

from planners.mpc import MPCConfig, MPCTracker
from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions
from uam_fdm.air.wind import TurbulenceLevel, WindConditions, WindField
from uam_fdm.sim import Simulator
from uam_fdm.vehicle.model import hover_state


@pytest.fixture(scope="module")
def trackers(vehicles) -> dict[str, dict[str, MPCTracker]]:
    """Per vehicle, the default MPC (the real-time iteration) and the Ipopt reference, compiled."""
    return {name: {s: MPCTracker(p, MPCConfig(solver=s)) for s in ("rti", "ipopt")} for name, p in vehicles.items()}


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
@pytest.mark.parametrize("solver", ["rti", "ipopt"])
@pytest.mark.parametrize("shape", ["line", "circle"])
@pytest.mark.parametrize("turbulence", [TurbulenceLevel.NONE, TurbulenceLevel.LIGHT])
def test_quad_tracks_line_and_circle(shape, turbulence, solver, vehicles, compiled_dynamics, trackers):
    p, dyn, mpc = vehicles["small_quad"], compiled_dynamics["small_quad"], trackers["small_quad"][solver]
    reference = _line(5.0, 3.0) if shape == "line" else _circle(20.0, 4.0)
    steady = (0.0, 0.0, 0.0) if turbulence is TurbulenceLevel.NONE else (2.0, -1.0, 0.0)
    wind = WindField.from_conditions(WindConditions(steady, turbulence), seed=4, duration_s=20.0,
                                     airspeed_m_s=5.0, heights_m=(30.0,))
    rms, times, commands = _track(p, dyn, mpc, reference, 15.0, wind)
    bound = 0.05 if turbulence is TurbulenceLevel.NONE else 0.5   # the MPC does not know the wind
    assert rms < bound, f"RMS tracking error {rms:.3f} m"
    assert mpc.n_failures == 0
    assert commands.min() >= p.rotor_speed_min_rad_s - 1e-9 and commands.max() <= p.rotor_speed_max_rad_s + 1e-9


@pytest.mark.parametrize("solver", ["rti", "ipopt"])
def test_uam_tracks_a_line_with_wrench_inputs(solver, vehicles, compiled_dynamics, trackers):
    p, dyn, mpc = vehicles["uam_multicopter"], compiled_dynamics["uam_multicopter"], trackers["uam_multicopter"][solver]
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
    assert not sol.success and sol.fallback and sol.status.startswith("fallback_hover") and sol.hover_trim
    np.testing.assert_allclose(sol.rotor_speeds_rad_s, p.hover_rotor_speeds_rad_s(1.0))
    assert mpc.n_failures == 1 and mpc.n_solves == 1


def test_a_failed_solve_flies_the_previous_plan_while_it_covers_now_then_hover_trim(vehicles, trackers,
                                                                                   monkeypatch):
    p, mpc = vehicles["small_quad"], trackers["small_quad"]["rti"]
    mpc.reset()
    n = mpc.config.horizon_steps
    x = hover_state(p, (0.0, 0.0, 30.0))
    ahead = np.tile([3.0, 0.0, 31.0], (n + 1, 1))
    planned = mpc.solve(x, ahead, np.zeros((n + 1, 3)), 0.0, 1.0)
    assert planned.success and not planned.hover_trim

    def fails(**_: object) -> None:
        raise RuntimeError("a solver that raises")

    monkeypatch.setattr(mpc, "_solver", fails)
    shifted = mpc.solve(x, ahead, np.zeros((n + 1, 3)), 0.0, 1.0, elapsed_s=mpc.step_s)
    assert shifted.fallback and shifted.status.startswith("fallback_shifted") and not shifted.hover_trim
    late = mpc.solve(x, ahead, np.zeros((n + 1, 3)), 0.0, 1.0, elapsed_s=mpc.step_s * n)  # past the plan's cover
    assert late.fallback and late.status.startswith("fallback_hover") and late.hover_trim
    monkeypatch.undo()
    mpc.reset()


@pytest.mark.parametrize("solver", ["rti", "ipopt"])
def test_halfspace_keeps_the_prediction_off_a_wall(solver, vehicles, trackers):
    p, mpc = vehicles["small_quad"], trackers["small_quad"][solver]
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


# -- solver agreement ------------------------------------------------------------------------------
# The real-time iteration (solver="rti": one Gauss-Newton SQP step per decision) and the NLP solvers
# share one OCP (planners.mpc_ocp). Iterated on a fixed problem (rti_iterations > 1: line-searched
# Gauss-Newton steps), it converges to the NLP's KKT point, so its first control must reach Ipopt's
# converged one. Tolerance 0.05 rad/s: 6e-5 of the quad's hover speed (794 rad/s), 7e-4 of the UAM's
# (75 rad/s); measured 0.007 rad/s at most. Both on CasADi's VM (no compile). One step per decision
# in closed loop is compared with Ipopt by perf/classical.py (RMS ratio on the same episodes).
AGREEMENT_TOL_RAD_S = 0.05


def _fixed_problem(p, case: str, n: int, k: int, step_s: float):
    """(state, ref positions, ref velocities, normals, offsets) of a fixed MPC problem at 30 m."""
    x = hover_state(p, (0.0, 0.0, 30.0))
    t = step_s * np.arange(n + 1)
    if case == "offset":      # hover 0.6 m from the target
        return x, np.tile([0.5, -0.3, 30.2], (n + 1, 1)), np.zeros((n + 1, 3)), None, None
    if case == "moving":      # flying at 3 m/s into a curving reference
        x[3] = 3.0
        return (x, np.stack([3.0 * t, 0.5 * t ** 2, 30.0 + 0 * t], 1), np.stack([3.0 + 0 * t, t, 0 * t], 1),
                None, None)
    if case == "step":        # a target 2.2 m away from hover: large residuals, full Gauss-Newton steps cycle
        return x, np.tile([2.0, 1.0, 30.0], (n + 1, 1)), np.zeros((n + 1, 3)), None, None
    x[3] = 1.0                # "wall": moving at 1 m/s towards a keep-out plane x <= 1 with the target behind it
    normals, offsets = np.zeros((n, k, 3)), np.full((n, k), -1.0)
    normals[:, 0] = (-1.0, 0.0, 0.0)
    offsets[:, 0] = -1.0
    return x, np.tile([3.0, 0.0, 30.0], (n + 1, 1)), np.zeros((n + 1, 3)), normals, offsets


@pytest.fixture(scope="module")
def vm_solvers(vehicles) -> dict[str, dict[str, MPCTracker]]:
    return {name: {"ipopt": MPCTracker(p, MPCConfig(solver="ipopt", compiled=False)),
                   "rti": MPCTracker(p, MPCConfig(solver="rti", rti_iterations=40, compiled=False)),
                   "fatrop": MPCTracker(p, MPCConfig(solver="fatrop", compiled=False))}
            for name, p in vehicles.items()}


@pytest.mark.parametrize("case", ["offset", "moving", "wall", "step"])
@pytest.mark.parametrize("vehicle", ["small_quad", "uam_multicopter"])
def test_rti_reaches_ipopts_first_control(vehicle, case, vehicles, vm_solvers):
    p, ipopt, rti = vehicles[vehicle], vm_solvers[vehicle]["ipopt"], vm_solvers[vehicle]["rti"]
    problem = _fixed_problem(p, case, ipopt.config.horizon_steps, ipopt.config.n_halfspaces, ipopt.config.step_s)
    ipopt.reset()
    rti.reset()
    ref = ipopt.solve(problem[0], *problem[1:3], 0.0, 1.0, *problem[3:])
    fast = rti.solve(problem[0], *problem[1:3], 0.0, 1.0, *problem[3:])
    assert ref.success and fast.success
    assert fast.iterations < rti.config.rti_iterations   # converged (step below tolerance), not capped
    np.testing.assert_allclose(fast.rotor_speeds_rad_s, ref.rotor_speeds_rad_s, atol=AGREEMENT_TOL_RAD_S, rtol=0)


@pytest.mark.parametrize("vehicle", ["small_quad", "uam_multicopter"])
def test_fatrop_solves_the_stage_structured_ocp(vehicle, vehicles, vm_solvers):
    """Fatrop raised inside every solve while the gap rows read F − x_{k+1}; on the stage-wise layout
    (x_{k+1} − F, previous input as a state) it detects N stages and agrees with Ipopt."""
    p, ipopt, fatrop = vehicles[vehicle], vm_solvers[vehicle]["ipopt"], vm_solvers[vehicle]["fatrop"]
    problem = _fixed_problem(p, "wall", ipopt.config.horizon_steps, ipopt.config.n_halfspaces, ipopt.config.step_s)
    ipopt.reset()
    fatrop.reset()
    ref = ipopt.solve(problem[0], *problem[1:3], 0.0, 1.0, *problem[3:])
    sol = fatrop.solve(problem[0], *problem[1:3], 0.0, 1.0, *problem[3:])
    stats = fatrop._solver.stats()
    lay = fatrop.layout
    assert sol.success, sol.status
    assert stats["N"] == lay.n_stages and list(stats["nx"]) == [lay.nx] * (lay.n_stages + 1)
    assert list(stats["ng"]) == list(fatrop.ocp.path_rows)
    np.testing.assert_allclose(sol.rotor_speeds_rad_s, ref.rotor_speeds_rad_s, atol=AGREEMENT_TOL_RAD_S, rtol=0)
