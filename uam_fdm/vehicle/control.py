"""Low-level controller: world-frame velocity command -> rotor-speed commands.

Written as CasADi expressions so it compiles into the same code as the physics and a
control period (controller at physics rate + RK4 substeps) is one call into compiled code.

Cascade (gains normalised by mass and inertia, so they read as bandwidths):

1. Velocity loop (world ENU): v_ref = sat(v_cmd) (horizontal speed and vertical speed limits);
   a = K_v (v_ref − v) + ξ + drag feed-forward,  ξ̇ = K_i (v_ref − v) while |v_ref − v| < window,
   |ξ| ≤ ξ_max (anti-windup: conditional integration and a clamp).
2. Thrust direction: a_des = a + g ẑ, tilt limited to max_tilt_deg (the vertical component is kept,
   the horizontal one scaled down), vertical component kept within [0.3 g, 0.95 T_max/m].
3. Attitude (geometric control on SO(3), Lee, Leok & McClamroch 2010): desired R_d from a_des and the
   yaw reference; e_R = ½ vee(R_dᵀR − RᵀR_d); torque M = J(−ω_n² e_R − 2ζω_n ω) + ω × Jω, yaw using
   its own bandwidth; collective thrust T = m a_des · b3.
4. Mixer: Ω² = A⁺ [T, M]ᵀ with A the allocation matrix from the rotor geometry (`VehicleParams.
   allocation_matrix`, scaled by the measured density ratio as a barometric autopilot would). When a
   rotor would leave [Ω_min², Ω_max²], the yaw torque is scaled down first (thrust and roll/pitch keep
   priority), then each rotor is clipped.

The command vector is [v_e, v_n, v_u, yaw_ref] (m/s, world ENU; rad, from east, counter-clockwise).
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np

from uam_fdm.vehicle.model import N_ENV, StateLayout, drag_force_body, quat_to_rotation
from uam_fdm.vehicle.params import GRAVITY_M_S2, VehicleParams

N_CMD = 4   # v_e, v_n, v_u [m/s], yaw reference [rad]
N_CTRL_STATE = 3  # integral term ξ [m/s²], world ENU


def _vee_skew_error(rd: ca.SX, r: ca.SX) -> ca.SX:
    """½ vee(R_dᵀ R − Rᵀ R_d)."""
    e = 0.5 * (rd.T @ r - r.T @ rd)
    return ca.vertcat(e[2, 1], e[0, 2], e[1, 0])


def _saturate_command(p: VehicleParams, v_cmd: ca.SX) -> ca.SX:
    c = p.controller
    speed_h = ca.sqrt(v_cmd[0] ** 2 + v_cmd[1] ** 2 + 1e-12)
    scale = ca.fmin(1.0, c.max_speed_m_s / speed_h)
    vz = ca.fmin(ca.fmax(v_cmd[2], -c.max_vertical_speed_m_s), c.max_vertical_speed_m_s)
    return ca.vertcat(v_cmd[0] * scale, v_cmd[1] * scale, vz)


def _desired_acceleration(p: VehicleParams, x: ca.SX, xi: ca.SX, v_ref: ca.SX, sigma: ca.SX) -> ca.SX:
    """Desired specific force a_des (world ENU, m/s²) including gravity compensation and limits."""
    c = p.controller
    lay = StateLayout(p.n_rotors)
    v = x[lay.vel]
    rot = quat_to_rotation(x[lay.quat])
    # Feed-forward of the vehicle's own drag at the reference ground speed (the autopilot does not know
    # the wind; the integral term takes the rest).
    drag_body = drag_force_body(p, rot.T @ v_ref, sigma)  # the model's own drag law, written once
    a = c.velocity_gain_1_s * (v_ref - v) + xi - rot @ drag_body / p.mass_kg
    a_z = a[2] + GRAVITY_M_S2
    a_z_max = 0.95 * p.max_thrust_N() / p.mass_kg * sigma
    a_z = ca.fmin(ca.fmax(a_z, 0.3 * GRAVITY_M_S2), a_z_max)
    a_h_norm = ca.sqrt(a[0] ** 2 + a[1] ** 2 + 1e-12)
    a_h_max = math.tan(math.radians(c.max_tilt_deg)) * a_z
    scale = ca.fmin(1.0, a_h_max / a_h_norm)
    return ca.vertcat(a[0] * scale, a[1] * scale, a_z)


def _attitude_torque(p: VehicleParams, x: ca.SX, a_des: ca.SX, yaw_ref: ca.SX) -> tuple[ca.SX, ca.SX]:
    """Collective thrust [N] and body torque [N·m] (FLU) that steer the thrust axis along a_des."""
    c = p.controller
    lay = StateLayout(p.n_rotors)
    rot = quat_to_rotation(x[lay.quat])
    w = x[lay.rate]
    b3d = a_des / ca.norm_2(a_des)
    b1c = ca.vertcat(ca.cos(yaw_ref), ca.sin(yaw_ref), 0)
    b2d = ca.cross(b3d, b1c)
    b2d = b2d / ca.norm_2(b2d)
    b1d = ca.cross(b2d, b3d)
    rd = ca.horzcat(b1d, b2d, b3d)
    e_r = _vee_skew_error(rd, rot)
    # Bound the yaw error so a large heading change becomes a bounded yaw rate, not a saturating torque.
    yaw_err_max = c.max_yaw_rate_rad_s * 2 * c.attitude_damping / c.yaw_natural_freq_rad_s
    e_r[2] = ca.fmin(ca.fmax(e_r[2], -yaw_err_max), yaw_err_max)
    wn = ca.DM([c.attitude_natural_freq_rad_s, c.attitude_natural_freq_rad_s, c.yaw_natural_freq_rad_s])
    inertia = ca.DM(p.inertia)
    alpha = -(wn * wn) * e_r - 2 * c.attitude_damping * wn * w
    torque = inertia @ alpha + ca.cross(w, inertia @ w)
    thrust = ca.fmax(p.mass_kg * ca.dot(a_des, rot[:, 2]), 0.0)
    return thrust, torque


def _mix(p: VehicleParams, thrust: ca.SX, torque: ca.SX, sigma: ca.SX) -> ca.SX:
    """Rotor-speed commands (n,) [rad/s] for a wrench, yaw sacrificed first at the limits."""
    alloc_pinv = np.linalg.pinv(p.allocation_matrix(1.0))      # σ scales A uniformly: divide it out below
    base = ca.DM(alloc_pinv[:, :3]) @ ca.vertcat(thrust, torque[0], torque[1]) / sigma
    yaw = ca.DM(alloc_pinv[:, 3]) * torque[2] / sigma
    lo, hi = p.rotor_speed_min_rad_s ** 2, p.rotor_speed_max_rad_s ** 2
    k = ca.SX(1.0)
    for i in range(p.n_rotors):
        room = ca.if_else(yaw[i] > 0, (hi - base[i]) / yaw[i],
                          ca.if_else(yaw[i] < 0, (lo - base[i]) / yaw[i], 1.0))
        k = ca.fmin(k, room)
    k = ca.fmax(k, 0.0)
    omega_sq = ca.fmin(ca.fmax(base + k * yaw, lo), hi)
    return ca.sqrt(omega_sq)


def controller_expr(p: VehicleParams, x: ca.SX, xi: ca.SX, cmd: ca.SX, env: ca.SX,
                    dt: ca.SX) -> tuple[ca.SX, ca.SX]:
    """One evaluation of the velocity controller.

    Args:
        p: vehicle parameters (gains and limits in ``p.controller``).
        x: vehicle state (13 + n,).
        xi: integral state (3,) [m/s²], world ENU.
        cmd: [v_e, v_n, v_u, yaw_ref] (m/s world ENU, rad).
        env: the model's environment input (`uam_fdm.vehicle.model.N_ENV`); only σ is used (the autopilot senses
            neither the wind nor the ground effect: its integral term takes both).
        dt: time until the next evaluation [s] (integral update).

    Returns:
        (rotor-speed commands (n,) [rad/s], next integral state (3,)).
    """
    c = p.controller
    lay = StateLayout(p.n_rotors)
    sigma = env[3]
    v_ref = _saturate_command(p, cmd[0:3])
    a_des = _desired_acceleration(p, x, xi, v_ref, sigma)
    thrust, torque = _attitude_torque(p, x, a_des, cmd[3])
    u = _mix(p, thrust, torque, sigma)
    # Conditional integration: only near the reference, so a large step does not wind the integral
    # up during the transient (it is there to remove wind and model error, not to speed up steps).
    err = v_ref - x[lay.vel]
    window = ca.fabs(err) < c.integral_window_m_s
    xi_next = xi + dt * c.velocity_integral_gain_1_s2 * err * window
    xi_next = ca.fmin(ca.fmax(xi_next, -c.integral_limit_m_s2), c.integral_limit_m_s2)
    return u, xi_next


def build_controller_function(p: VehicleParams) -> ca.Function:
    """(x, xi, cmd, env, dt) -> (u, xi_next) as an SX Function."""
    lay = StateLayout(p.n_rotors)
    x = ca.SX.sym("x", lay.nx)
    xi = ca.SX.sym("xi", N_CTRL_STATE)
    cmd = ca.SX.sym("cmd", N_CMD)
    env = ca.SX.sym("env", N_ENV)
    dt = ca.SX.sym("dt")
    u, xi_next = controller_expr(p, x, xi, cmd, env, dt)
    return ca.Function("controller", [x, xi, cmd, env, dt], [u, xi_next],
                       ["x", "xi", "cmd", "env", "dt"], ["u", "xi_next"])
