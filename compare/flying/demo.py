"""Demo flight of a vehicle preset: a quick check that the flight model and its low-level controller fly.

Flies waypoints (climb, a square, return, descend) through the low-level velocity controller in
JSBSim light turbulence over a steady breeze, and reports what happened.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions
from uam_fdm.air.wind import TurbulenceLevel, WindConditions, WindField, probe_heights_up_to
from uam_fdm.sim import Simulator
from uam_fdm.vehicle.dynamics import VehicleDynamics
from uam_fdm.vehicle.model import hover_state
from uam_fdm.vehicle.params import load_vehicle


@dataclass(frozen=True)
class DemoResult:
    """Summary of one demo flight (SI units)."""

    vehicle: str
    backend: str
    mass_kg: float
    n_rotors: int
    hover_rotor_speed_rad_s: float
    waypoints_reached: int
    waypoints: int
    flight_time_s: float
    path_length_m: float
    max_speed_m_s: float
    max_tilt_deg: float
    final_position_m: tuple[float, float, float]
    max_cross_track_m: float
    energy_kj: float
    mean_shaft_power_kw: float
    wall_time_s: float


def _waypoints(side_m: float) -> np.ndarray:
    """Climb 20 m, fly a square of `side_m`, return and descend (world ENU, m)."""
    return np.array([[0, 0, 40], [side_m, 0, 40], [side_m, side_m, 40], [0, side_m, 40], [0, 0, 40], [0, 0, 20]],
                    dtype=float)


def demo_flight(preset: str, seed: int = 0) -> DemoResult:
    """Fly the demo waypoints with `preset` (a preset name or vehicle YAML path).

    A position loop (v_cmd = K (waypoint − p), saturated at the cruise speed) drives the velocity
    controller; a waypoint counts as reached within `2 + collision radius` metres, the last one when
    within 0.5 m and slower than 0.2 m/s.
    """
    p = load_vehicle(preset)
    speed = min(0.5 * p.controller.max_speed_m_s, 10.0)
    gain = 0.5 * p.controller.velocity_gain_1_s
    waypoints = _waypoints(side_m=20.0 * speed)
    reach_m = 2.0 + p.collision_radius_m
    timeout_s = 300.0
    t0 = time.perf_counter()
    dyn = VehicleDynamics(p, physics_hz=500.0, control_hz=50.0)
    atmosphere = Atmosphere.from_jsbsim(AtmosphereConditions(elevation_m=0.0), z_max_m=500.0)
    wind = WindField.from_conditions(WindConditions((2.0, 1.0, 0.0), TurbulenceLevel.LIGHT), seed=seed,
                                     duration_s=timeout_s + 1.0, airspeed_m_s=speed,
                                     heights_m=probe_heights_up_to(float(waypoints[:, 2].max()) + 10.0))
    sim = Simulator(dyn, atmosphere, wind)
    sim.reset(hover_state(p, (0.0, 0.0, 20.0), density_ratio=atmosphere.density_ratio(20.0)))
    states, target = [sim.state.x[None]], 0
    while target < len(waypoints) and sim.state.t_s < timeout_s:
        error = waypoints[target] - sim.state.x[0:3]
        last = target == len(waypoints) - 1   # the last waypoint is a stop: close in and settle
        if np.linalg.norm(error) < (0.5 if last else reach_m) and (
                not last or np.linalg.norm(sim.state.x[3:6]) < 0.2):
            target += 1
            continue
        v_cmd = gain * error
        v_cmd *= min(1.0, speed / max(float(np.linalg.norm(v_cmd)), 1e-9))
        states.append(sim.advance_velocity(np.append(v_cmd, 0.0)).states)
    traj = np.concatenate(states)
    wall = time.perf_counter() - t0

    pos, vel, q = traj[:, 0:3], traj[:, 3:6], traj[:, 6:10]
    tilt = np.degrees(np.arccos(np.clip(1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2), -1, 1)))
    # Largest horizontal distance from the square between the waypoints.
    d = np.full(len(pos), np.inf)
    for a, b in zip(waypoints[:-1, :2], waypoints[1:, :2]):
        ab = b - a
        s = np.clip(((pos[:, :2] - a) @ ab) / max(ab @ ab, 1e-12), 0, 1)
        d = np.minimum(d, np.linalg.norm(pos[:, :2] - (a + s[:, None] * ab), axis=1))
    t_flight = sim.state.t_s
    return DemoResult(
        vehicle=p.name, backend=dyn.backend, mass_kg=p.mass_kg, n_rotors=p.n_rotors,
        hover_rotor_speed_rad_s=float(p.hover_rotor_speeds_rad_s()[0]), waypoints_reached=target,
        waypoints=len(waypoints), flight_time_s=t_flight,
        path_length_m=float(np.sum(np.linalg.norm(np.diff(pos, axis=0), axis=1))),
        max_speed_m_s=float(np.linalg.norm(vel, axis=1).max()), max_tilt_deg=float(tilt.max()),
        final_position_m=(float(pos[-1, 0]), float(pos[-1, 1]), float(pos[-1, 2])), max_cross_track_m=float(d.max()),
        energy_kj=sim.state.energy_J / 1e3, mean_shaft_power_kw=sim.state.energy_J / t_flight / 1e3,
        wall_time_s=wall,
    )
