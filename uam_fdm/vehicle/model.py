"""The multirotor flight-dynamics model, written once as a CasADi expression.

Everything that needs the physics (the simulator, the batched training step, the MPC, any
linearisation, the energy metric) uses Functions generated here; there is no second copy.

State x (13 + n), world ENU / body FLU, SI units::

    x[0:3]    position p [m], world ENU (z above the field)
    x[3:6]    velocity v [m/s], world ENU
    x[6:10]   attitude quaternion q = [w, x, y, z], body FLU -> world ENU
    x[10:13]  body rates ω [rad/s], body FLU
    x[13:]    rotor speeds Ω [rad/s] (non-negative)

Input u (n): rotor-speed commands [rad/s], saturated to [Ω_min, Ω_max] by the motors.
Environment e (5): wind [m/s] world ENU (e, n, u), the air-density ratio σ = ρ/ρ0, and the
height h [m] of the centre of mass above the surface directly below it (ground or roof).

Equations::

    ṗ = v
    m v̇ = R(q) (Σ T_i ẑ + F_drag) − m g ẑ,     T_i = G_i kf σ Ω_i²
    F_drag = −D_lin ⊙ v_a − σ D_quad ⊙ v_a ‖v_a‖,   v_a = R(q)ᵀ (v − wind)      (body axes)
    q̇ = ½ q ⊗ [0, ω]
    J ω̇ = Σ r_i × (T_i ẑ) − Σ s_i km σ Ω_i² ẑ − ω × J ω
    Ω̇_i = (sat(u_i) − Ω_i) / τ_m
    shaft power P = Σ km σ Ω_i³   (Q_i Ω_i, the energy metric's integrand)

G_i is rotor i's ground-effect gain (Cheeseman-Bennett, `uam_fdm.vehicle.ground_effect`; 1 when the
vehicle's `ground_effect` is off or the rotor is more than 10 radii above the surface).

Not modelled (documented choices): rotor inertia and gyroscopic torques, blade flapping,
rotor-rotor and coaxial interference, angular (rotational) drag.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeVar

import casadi as ca
import numpy as np

from uam_fdm.vehicle.ground_effect import thrust_gain_expr
from uam_fdm.vehicle.params import GRAVITY_M_S2, VehicleParams

N_ENV = 5  # wind e, n, u [m/s], density ratio σ, height above the surface below [m]
FAR_FROM_SURFACES_M = 1.0e6  # a height input that no rotor feels (ground effect ends at 10 radii)


def make_env(wind_enu_m_s=(0.0, 0.0, 0.0), density_ratio: float = 1.0,
             height_above_surface_m: float = FAR_FROM_SURFACES_M) -> np.ndarray:
    """The environment input (N_ENV,) of the model's Functions: wind [m/s, world ENU], σ = ρ/ρ0 and the
    centre of mass's height above the surface below it [m] (default: far from any surface)."""
    env = np.zeros(N_ENV)
    env[0:3] = wind_enu_m_s
    env[3] = density_ratio
    env[4] = height_above_surface_m
    return env


@dataclass(frozen=True)
class StateLayout:
    """Index ranges of the state vector for a vehicle with `n_rotors` rotors."""

    n_rotors: int

    pos = slice(0, 3)
    vel = slice(3, 6)
    quat = slice(6, 10)
    rate = slice(10, 13)

    @property
    def rotor(self) -> slice:
        return slice(13, 13 + self.n_rotors)

    @property
    def nx(self) -> int:
        return 13 + self.n_rotors


Symbolic = TypeVar("Symbolic", ca.SX, ca.MX)


def quat_product(a: Symbolic, b: Symbolic) -> Symbolic:
    """Hamilton product a ⊗ b of quaternions [w, x, y, z] (SX or MX)."""
    return ca.vertcat(
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    )


def quat_to_rotation(q: ca.SX) -> ca.SX:
    """Rotation matrix (3, 3) body -> world of a unit quaternion [w, x, y, z]."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return ca.vertcat(
        ca.horzcat(1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        ca.horzcat(2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        ca.horzcat(2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )


def _quat_rate(q: ca.SX, w: ca.SX) -> ca.SX:
    """q̇ = ½ q ⊗ [0, ω] for body rates ω."""
    return 0.5 * ca.vertcat(
        -q[1] * w[0] - q[2] * w[1] - q[3] * w[2],
        q[0] * w[0] + q[2] * w[2] - q[3] * w[1],
        q[0] * w[1] + q[3] * w[0] - q[1] * w[2],
        q[0] * w[2] + q[1] * w[1] - q[2] * w[0],
    )


# ‖v_a‖ is taken as sqrt(v_a·v_a + ε²): differentiable at rest (Jacobians, the MPC's gradients), at most ε too large
AIRSPEED_SMOOTHING_M_S = 1e-6


def drag_force_body(p: VehicleParams, v_air_body: ca.SX, sigma: ca.SX) -> ca.SX:
    """Body drag [N] (body FLU) for the air-relative velocity `v_air_body` [m/s] (body FLU) at density ratio σ.

    The quadratic part scales with the airspeed's magnitude, ‖v_a‖ v_a, with a coefficient per body axis:
    its size for a given airspeed does not depend on how the body is turned in the flow beyond the
    coefficients themselves (a per-axis |v_a| ⊙ v_a would drop to 1/√3 for flow along a diagonal).
    """
    airspeed = ca.sqrt(ca.dot(v_air_body, v_air_body) + AIRSPEED_SMOOTHING_M_S ** 2)
    return (-ca.DM(p.drag_linear_N_s_m) * v_air_body
            - sigma * ca.DM(p.drag_quadratic_N_s2_m2) * airspeed * v_air_body)


def ground_effect_gain(p: VehicleParams, x: ca.SX, env: ca.SX) -> ca.SX | ca.DM:
    """Each rotor's ground-effect thrust gain G_i (n,) in state x and environment env."""
    lay = StateLayout(p.n_rotors)
    rot = quat_to_rotation(x[lay.quat])
    return thrust_gain_expr(p, rot, x[lay.rotor], rot.T @ (x[lay.vel] - env[0:3]), env[4])


def dynamics_expr(p: VehicleParams, x: ca.SX, u: ca.SX, env: ca.SX,
                  gain: ca.SX | ca.DM | None = None) -> tuple[ca.SX, ca.SX]:
    """Continuous dynamics ẋ and shaft power P [W] as CasADi expressions (see module docstring).

    `gain`: the rotors' ground-effect gains (n,) if the caller holds them (the RK4 step does), else
    evaluated here at x.
    """
    lay = StateLayout(p.n_rotors)
    v, q, w, omega = x[lay.vel], x[lay.quat], x[lay.rate], x[lay.rotor]
    wind, sigma = env[0:3], env[3]
    rot = quat_to_rotation(q)
    v_air_body = rot.T @ (v - wind)

    omega_sq = omega * omega
    if gain is None:  # (n,) ground effect, 1 away from surfaces
        gain = thrust_gain_expr(p, rot, omega, v_air_body, env[4])
    thrust = gain * p.thrust_coeff_N_s2 * sigma * omega_sq          # (n,) N
    drag_torque = p.torque_coeff_Nm_s2 * sigma * omega_sq           # (n,) N·m, opposes each rotor's spin

    f_body = ca.vertcat(0, 0, ca.sum1(thrust)) + drag_force_body(p, v_air_body, sigma)
    accel = rot @ f_body / p.mass_kg - ca.DM([0.0, 0.0, GRAVITY_M_S2])

    r = p.rotor_positions
    spins = ca.DM(np.array(p.rotor_spins, dtype=float))
    torque = ca.vertcat(
        ca.dot(ca.DM(r[:, 1]), thrust),
        -ca.dot(ca.DM(r[:, 0]), thrust),
        -ca.dot(spins, drag_torque),
    )
    inertia = ca.DM(p.inertia)
    w_dot = ca.solve(inertia, torque - ca.cross(w, inertia @ w))

    u_sat = ca.fmin(ca.fmax(u, p.rotor_speed_min_rad_s), p.rotor_speed_max_rad_s)
    omega_dot = (u_sat - omega) / p.motor_time_constant_s

    x_dot = ca.vertcat(v, accel, _quat_rate(q, w), w_dot, omega_dot)
    power = ca.dot(drag_torque, omega)
    return x_dot, power


def rk4_step_expr(p: VehicleParams, x: ca.SX, u: ca.SX, env: ca.SX, dt: ca.SX) -> tuple[ca.SX, ca.SX]:
    """One classical RK4 step of the state and of the shaft energy; quaternion renormalised.

    The ground-effect gains are evaluated once, at the step's start, and held over its four stages:
    they change with height over centimetres, while a 2 ms step moves the vehicle millimetres
    (the difference is far below the RK4 error), and the term would otherwise cost the batched
    physics a fifth of its speed.

    Returns:
        (x_next, energy_J) with the energy integrated by the same RK4 stages.
    """
    gain = ca.SX.sym("gain", p.n_rotors)
    f = ca.Function("f_aug", [x, u, env, gain], list(dynamics_expr(p, x, u, env, gain)))
    g = ground_effect_gain(p, x, env)
    x_next, energy = rk4_expr(lambda s: f.call([s, u, env, g]), x, dt)
    return x_next, energy


def rk4_expr(f: Callable[[ca.SX], Sequence[ca.SX]], x: ca.SX, dt: ca.SX | float) -> list[ca.SX]:
    """One classical RK4 step of ẋ = f(x)[0], the attitude quaternion x[6:10] renormalised.

    Any further outputs of f (e.g. the shaft power) are integrated by the same stages. The one RK4 of
    the project: the simulator's physics step and the MPC's prediction both take theirs from here.

    Returns:
        [x_next, *integrals of the further outputs over the step].
    """
    k1 = f(x)
    k2 = f(x + 0.5 * dt * k1[0])
    k3 = f(x + 0.5 * dt * k2[0])
    k4 = f(x + dt * k3[0])
    out = [dt / 6.0 * (a + 2 * b + 2 * c + d) for a, b, c, d in zip(k1, k2, k3, k4)]
    x_next = x + out[0]
    q = x_next[StateLayout.quat]
    x_next[StateLayout.quat] = q / ca.norm_2(q)
    return [x_next, *out[1:]]


@dataclass(frozen=True)
class ModelFunctions:
    """CasADi Functions generated from the one model expression (all SX, ready to compile).

    Attributes:
        dynamics: (x, u, env) -> x_dot.
        shaft_power: (x, env) -> P [W].
        rk4_step: (x, u, env, dt) -> (x_next, energy_J).
        jacobians: (x, u, env) -> (A = ∂ẋ/∂x, B = ∂ẋ/∂u).
    """

    dynamics: ca.Function
    shaft_power: ca.Function
    rk4_step: ca.Function
    jacobians: ca.Function


def build_model_functions(p: VehicleParams) -> ModelFunctions:
    """Generate the model's CasADi Functions for one vehicle."""
    lay = StateLayout(p.n_rotors)
    x = ca.SX.sym("x", lay.nx)
    u = ca.SX.sym("u", p.n_rotors)
    env = ca.SX.sym("env", N_ENV)
    dt = ca.SX.sym("dt")
    x_dot, power = dynamics_expr(p, x, u, env)
    x_next, energy = rk4_step_expr(p, x, u, env, dt)
    names_in = ["x", "u", "env"]
    return ModelFunctions(
        dynamics=ca.Function("dynamics", [x, u, env], [x_dot], names_in, ["x_dot"]),
        shaft_power=ca.Function("shaft_power", [x, env], [power], ["x", "env"], ["power_W"]),
        rk4_step=ca.Function("rk4_step", [x, u, env, dt], [x_next, energy],
                             names_in + ["dt"], ["x_next", "energy_J"]),
        jacobians=ca.Function("jacobians", [x, u, env],
                              [ca.jacobian(x_dot, x), ca.jacobian(x_dot, u)], names_in, ["A", "B"]),
    )


def hover_state(p: VehicleParams, position_m=(0.0, 0.0, 0.0), yaw_rad: float = 0.0,
                density_ratio: float = 1.0) -> np.ndarray:
    """State (13 + n,) at rest at `position_m` (world ENU), heading `yaw_rad`, rotors at hover trim."""
    lay = StateLayout(p.n_rotors)
    x = np.zeros(lay.nx)
    x[lay.pos] = position_m
    x[lay.quat] = [np.cos(yaw_rad / 2), 0.0, 0.0, np.sin(yaw_rad / 2)]
    x[lay.rotor] = p.hover_rotor_speeds_rad_s(density_ratio)
    return x

