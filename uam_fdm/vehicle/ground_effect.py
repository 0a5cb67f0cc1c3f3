"""Ground effect: the thrust gain of a rotor close to the ground or a roof below it.

The law (Cheeseman & Bennett 1955, "The effect of the ground on a helicopter rotor in forward
flight", ARC R&M 3021), for a rotor of radius R whose disc is a height z above the surface::

    T_IGE / T_OGE = 1 / (1 − k),   k = (R / 4z)² / (1 + (V / v_h)²)

V is the airspeed in the rotor plane and v_h = sqrt(T / (2 ρ A)) the rotor's hover induced velocity
at its present thrust (= Ω sqrt(kf / (2 ρ0 π R²)): the density cancels). At hover the gain is
1.07 at z = R, 1.016 at z = 2R, 1.004 at z = 4R; in forward flight at V = 2 v_h a fifth of that.

What we do with it, and its limits:
  * The surface is the one directly below the vehicle's centre of mass (the ground, or the highest
    roof under it, `BuildingMap.surface_height_m`), taken as a flat plane under every rotor; each
    rotor's height is that height plus its hub's vertical offset with the present attitude. A rotor
    whose disc overhangs a roof edge is treated as over the roof.
  * z is floored at `MIN_HEIGHT_RADII` R (the law is singular at z = R/4 and was fitted for
    z/R >= 0.5; below that the gain is held at 1.33).
  * The gain is made exactly 1 beyond `CUTOFF_RADII` R by subtracting the law's value there,
    (1/(4·10))² = 6.25e-4, from (R/4z)²: continuous, and off the published law by less than 0.07 %
    of thrust anywhere. Beyond the cut-off, so beyond `range_m` of the centre of mass, the surface
    need not be looked up at all (the simulators skip the query there).
  * One rotor in isolation: no rotor-rotor interaction (the "fountain" under a multirotor), no
    moment from partial ground effect, no change of the rotor's torque (the power metric keeps
    Σ km σ Ω³). Valid for hover and slow flight near a flat surface.
  * The environment input holds the height over a control period (20 ms), like the wind.
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np

from uam_fdm.vehicle.params import VehicleParams

RHO0_KG_M3 = 1.225  # ISA sea-level density: the thrust coefficient's reference
CUTOFF_RADII = 10.0  # gain exactly 1 above this rotor height [rotor radii]
MIN_HEIGHT_RADII = 0.5  # the law's height floor [rotor radii]
_DV_SMOOTHING = 1e-9  # [m²/s²] keeps V²/v_h² finite with stopped rotors


def range_m(p: VehicleParams) -> float:
    """Distance from the centre of mass beyond which no rotor of `p` can be in ground effect [m]."""
    reach = float(np.max(np.linalg.norm(p.rotor_positions, axis=1)))
    return CUTOFF_RADII * 0.5 * p.rotor_diameter_m + reach


def thrust_gain(height_over_radius: np.ndarray | float, speed_over_induced: np.ndarray | float = 0.0) -> np.ndarray:
    """T_IGE / T_OGE as the model applies it (module docstring), in NumPy: rotor height z/R and V/v_h."""
    zr = np.maximum(np.asarray(height_over_radius, dtype=float), MIN_HEIGHT_RADII)
    k = np.maximum((0.25 / zr) ** 2 - (0.25 / CUTOFF_RADII) ** 2, 0.0)
    return 1.0 / (1.0 - k / (1.0 + np.asarray(speed_over_induced, dtype=float) ** 2))


def cheeseman_bennett(height_over_radius: np.ndarray | float,
                      speed_over_induced: np.ndarray | float = 0.0) -> np.ndarray:
    """The published law, without the cut-off or floor (for tests and figures)."""
    k = (0.25 / np.asarray(height_over_radius, dtype=float)) ** 2
    return 1.0 / (1.0 - k / (1.0 + np.asarray(speed_over_induced, dtype=float) ** 2))


def thrust_gain_expr(p: VehicleParams, rot: ca.SX, omega: ca.SX, v_air_body: ca.SX,
                     height_m: ca.SX) -> ca.SX | ca.DM:
    """The gain (n,) of each rotor as a CasADi expression (the model's; `thrust_gain` in NumPy).

    Args:
        p: the vehicle (`p.ground_effect` False gives ones).
        rot: body -> world rotation (3, 3).
        omega: rotor speeds (n,) [rad/s].
        v_air_body: air-relative velocity, body FLU [m/s].
        height_m: the centre of mass's height above the surface below it [m].
    """
    n = p.n_rotors
    if not p.ground_effect:
        return ca.DM.ones(n)
    radius = 0.5 * p.rotor_diameter_m
    # Written for the physics loop (it runs at every RK4 stage): two divisions per rotor.
    hub_dz = ca.DM(p.rotor_positions) @ rot[2, :].T  # (n,) vertical offset of each hub [m]
    # R / 4z, floored at z = MIN_HEIGHT_RADII R. Comparisons rather than fmin/fmax: without -ffast-math
    # the C compiler calls libm for those, which cost the batched physics loop a quarter of its speed.
    z = height_m + hub_dz
    z_floor = MIN_HEIGHT_RADII * radius
    q = (0.25 * radius) / ca.if_else(z > z_floor, z, z_floor)
    k = q * q - (0.25 / CUTOFF_RADII) ** 2
    k = ca.if_else(k > 0.0, k, 0.0)
    speed2 = v_air_body[0] ** 2 + v_air_body[1] ** 2  # airspeed in the rotor plane, squared
    induced2 = omega * omega * (p.thrust_coeff_N_s2 / (2.0 * RHO0_KG_M3 * math.pi * radius ** 2)) + _DV_SMOOTHING
    # 1 / (1 - k a/(a + b)) = (a + b) / (a (1 - k) + b), a = v_h^2, b = V^2
    return (induced2 + speed2) / (induced2 * (1.0 - k) + speed2)


def height_above_surface(city, positions_m: np.ndarray, clearance_m: np.ndarray, p: VehicleParams) -> np.ndarray:
    """The environment's height input: each vehicle's height above the surface below it [m].

    The one rule for every flight (runner and learned-pilot env). Where the vehicle is farther than
    `range_m` from every surface (the sphere clearance `clearance_m` [m] plus the collision radius,
    or a lower bound of it), the surface is not looked up and the altitude z is given: every rotor is
    then above the cut-off, so the gain is exactly 1 whatever height is given.

    Args:
        city: a `BuildingMap`, or None for open ground at z = 0.
        positions_m: (M, 3) centres of mass, ENU.
        clearance_m: (M,) sphere clearance (or a lower bound) at the same positions [m].
        p: the vehicle.
    """
    pos = np.asarray(positions_m, dtype=float).reshape(-1, 3)
    h = pos[:, 2].copy()
    if city is None or not p.ground_effect:
        return h
    near = np.asarray(clearance_m, dtype=float).reshape(-1) + p.collision_radius_m < range_m(p)
    if np.any(near):
        h[near] -= city.surface_height_m(pos[near])
    return h
