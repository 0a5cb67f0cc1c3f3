"""The navigation filter's model, written once as CasADi expressions: the IMU strapdown step, the error-state
maps, the measurement functions, and every Jacobian taken from them with `ca.jacobian`.

An error-state (indirect) Kalman filter after PX4's EKF2 and J. Solà, "Quaternion kinematics for the error-state
Kalman filter" (2017), §5-7. Frames: world ENU [m], body FLU; gravity (0, 0, -9.80665) m/s² in the world.

Nominal state x (17)::

    x[0:3]    position p [m], world ENU
    x[3:6]    velocity v [m/s], world ENU
    x[6:10]   attitude q = [w, x, y, z], body FLU -> world ENU
    x[10:13]  accelerometer bias b_a [m/s²], body
    x[13:16]  gyro bias b_g [rad/s], body
    x[16]     barometer offset b_baro [m] (baro altitude = z + b_baro)
    x[17]     heading-aid disturbance d [rad] (heading = yaw + d): the aid's slowly varying error, a first-order
              Gauss-Markov state as the HeadingSpec models it (EKF2 carries magnetic-field states for the same)

Error state δx (17): δp, δv, δθ (local: q_true = q ⊗ exp(δθ), body axes), δb_a, δb_g, δb_baro, δd. The first 16
are the navigation estimate's (`NavEstimate`); the last is internal to the filter.

The transition Jacobian is F = ∂/∂δx [f(x ⊕ δx, u) ⊖ f(x, u)] at δx = 0, and the noise Jacobian likewise with
respect to the IMU's noise: both by differentiation of the one nominal step below, so the covariance always
propagates through the same equations as the state. The reset Jacobian after injecting δx̂ is the derivative of
δx⁺ = (x ⊕ δx) ⊖ (x ⊕ δx̂) at δx = δx̂ (Solà eq. 285-287; PX4's EKF2 takes it as identity instead).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from uam_fdm.vehicle.model import quat_product, quat_to_rotation

GRAVITY_M_S2 = 9.80665
NX = 18  # nominal state
NDX = 17  # error state
NDX_PUBLIC = 16  # the error states of a NavEstimate (all but the heading-aid disturbance)
# accel and gyro white-noise densities, accel/gyro bias walks, baro-offset walk, heading-aid disturbance σ and
# correlation time
NOISE_PARAMS = 7

POS, VEL, QUAT, ACC_BIAS, GYRO_BIAS, BARO, HEADING = (slice(0, 3), slice(3, 6), slice(6, 10), slice(10, 13),
                                                      slice(13, 16), slice(16, 17), slice(17, 18))
D_POS, D_VEL, D_ATT, D_ACC_BIAS, D_GYRO_BIAS, D_BARO, D_HEADING = (slice(0, 3), slice(3, 6), slice(6, 9),
                                                                   slice(9, 12), slice(12, 15), slice(15, 16),
                                                                   slice(16, 17))


def quat_exp(theta: ca.SX) -> ca.SX:
    """exp of a rotation vector θ [rad] as a unit quaternion, by its Taylor series in |θ|².

    A series rather than sin(|θ|/2)/|θ|: smooth at θ = 0, where every Jacobian of the filter is taken. Terms to
    |θ|⁶: the error is below 1e-9 for |θ| < 0.5 rad (an IMU step turns by |ω| dt, milliradians).
    """
    a2 = ca.dot(theta, theta)
    c = 1 - a2 / 8 + a2 ** 2 / 384 - a2 ** 3 / 46080
    s = 0.5 - a2 / 48 + a2 ** 2 / 3840 - a2 ** 3 / 645120
    return ca.vertcat(c, s * theta)


def _normalised(q: ca.SX) -> ca.SX:
    return q / ca.norm_2(q)


def inject_expr(x: ca.SX, dx: ca.SX) -> ca.SX:
    """x ⊕ δx: the nominal state corrected by an error state."""
    q = _normalised(quat_product(x[QUAT], quat_exp(dx[D_ATT])))
    return ca.vertcat(x[POS] + dx[D_POS], x[VEL] + dx[D_VEL], q, x[ACC_BIAS] + dx[D_ACC_BIAS],
                      x[GYRO_BIAS] + dx[D_GYRO_BIAS], x[BARO] + dx[D_BARO], x[HEADING] + dx[D_HEADING])


def difference_expr(x1: ca.SX, x0: ca.SX) -> ca.SX:
    """x1 ⊖ x0: the error state taking x0 to x1 (attitude 2·vec(q0* ⊗ q1), the log map to first order, exact in
    its derivative where the two attitudes coincide, which is where it is differentiated)."""
    q0c = x0[QUAT] * ca.DM([1.0, -1.0, -1.0, -1.0])
    dq = quat_product(q0c, x1[QUAT])
    return ca.vertcat(x1[POS] - x0[POS], x1[VEL] - x0[VEL], 2 * dq[1:4], x1[ACC_BIAS] - x0[ACC_BIAS],
                      x1[GYRO_BIAS] - x0[GYRO_BIAS], x1[BARO] - x0[BARO], x1[HEADING] - x0[HEADING])


def nominal_step_expr(x: ca.SX, imu: ca.SX, dt: ca.SX, decay: ca.SX) -> ca.SX:
    """One strapdown step over dt [s] with the IMU sample imu = [specific force (3) m/s², rate (3) rad/s], body;
    the heading-aid disturbance decays by the factor `decay` = exp(-dt/τ).

    The sample stands for the interval ending at it. The attitude turns by (ω - b_g) dt; the specific force is
    rotated by the attitude at mid-interval (rotating by the start attitude would tilt it by ω dt/2, a
    systematic error that in a turn exceeds the accelerometer's noise).
    """
    accel = imu[0:3] - x[ACC_BIAS]
    dtheta = (imu[3:6] - x[GYRO_BIAS]) * dt
    q = x[QUAT]
    q_next = _normalised(quat_product(q, quat_exp(dtheta)))
    q_mid = _normalised(quat_product(q, quat_exp(0.5 * dtheta)))
    a_world = quat_to_rotation(q_mid) @ accel + ca.DM([0.0, 0.0, -GRAVITY_M_S2])
    v = x[VEL]
    return ca.vertcat(x[POS] + v * dt + 0.5 * a_world * dt ** 2, v + a_world * dt, q_next,
                      x[ACC_BIAS], x[GYRO_BIAS], x[BARO], decay * x[HEADING])


def _at_zero(expr: ca.SX, var: ca.SX) -> ca.SX:
    return ca.substitute(expr, var, ca.DM.zeros(var.shape))


def _symmetric(m: ca.SX) -> ca.SX:
    """The symmetric matrix from m's upper triangle (exactly symmetric; the lower half is never computed)."""
    upper = ca.triu(m)
    return ca.densify(upper + ca.triu(m, False).T)


def transition_expr(x: ca.SX, imu: ca.SX, dt: ca.SX, decay: ca.SX) -> tuple[ca.SX, ca.SX]:
    """The error-state transition F (17, 17) and the Jacobian (17, 6) of the step's error with respect to the
    IMU sample's noise [accel, gyro], both at zero error, by differentiation of `nominal_step_expr`."""
    x_next = nominal_step_expr(x, imu, dt, decay)
    dx = ca.SX.sym("dx", NDX)
    stepped = nominal_step_expr(inject_expr(x, dx), imu, dt, decay)
    f_jac = _at_zero(ca.jacobian(difference_expr(stepped, x_next), dx), dx)
    n = ca.SX.sym("n", 6)
    g_jac = _at_zero(ca.jacobian(difference_expr(nominal_step_expr(x, imu + n, dt, decay), x_next), n), n)
    return f_jac, g_jac


def predict_expr(x: ca.SX, p: ca.SX, imu: ca.SX, dt: ca.SX, noise: ca.SX) -> tuple[ca.SX, ca.SX]:
    """The filter's prediction: nominal state and error covariance after one IMU sample.

    Args:
        x: nominal state (17).
        p: error covariance (17, 17).
        imu: [specific force m/s², rate rad/s] (6), body.
        dt: step [s].
        noise: [accel white m/s²/√Hz, gyro white rad/s/√Hz, accel bias walk m/s³/√Hz, gyro bias walk
            rad/s²/√Hz, baro-offset walk m/√s, heading-aid disturbance σ rad, its correlation time s (> 0)].

    Returns:
        (x_next (18), P_next (17, 17)) with P_next = F P Fᵀ + G Σ Gᵀ + Q_walk: Σ the IMU sample noise (σ² =
        density²/dt, the sample σ at rate 1/dt), Q_walk the random walks over dt and the disturbance's
        Gauss-Markov driving noise σ²(1 - e^(-2 dt/τ)).
    """
    decay = ca.exp(-dt / noise[6])
    x_next = nominal_step_expr(x, imu, dt, decay)
    f_jac, g_jac = transition_expr(x, imu, dt, decay)
    sample_var = ca.vertcat(ca.repmat(noise[0] ** 2, 3, 1), ca.repmat(noise[1] ** 2, 3, 1)) / dt
    walk_var = ca.vertcat(ca.DM.zeros(9, 1), ca.repmat(noise[2] ** 2 * dt, 3, 1),
                          ca.repmat(noise[3] ** 2 * dt, 3, 1), noise[4] ** 2 * dt, noise[5] ** 2 * (1 - decay ** 2))
    p_next = f_jac @ p @ f_jac.T + g_jac @ ca.diag(sample_var) @ g_jac.T + ca.diag(walk_var)
    return x_next, _symmetric(p_next)


def yaw_expr(q: ca.SX) -> ca.SX:
    """Heading [rad] of a body FLU -> world ENU attitude: the body x axis's angle from east, counter-clockwise."""
    rot = quat_to_rotation(q)
    return ca.atan2(rot[1, 0], rot[0, 0])


def measurement_exprs(x: ca.SX) -> dict[str, ca.SX]:
    """Predicted measurements h(x) of each aid: GNSS [p, v] (6), baro altitude z + b_baro (1), heading yaw + d (1)."""
    return {"gnss": ca.vertcat(x[POS], x[VEL]), "baro": x[2] + x[16], "heading": yaw_expr(x[QUAT]) + x[17]}


@dataclass(frozen=True)
class FilterFunctions:
    """CasADi Functions of the filter, all generated from the expressions above (dense in and out).

    Attributes:
        predict: (x, P, imu, dt, noise) -> (x_next, P_next).
        transition: (x, imu, dt, decay) -> (F, G_noise), the Jacobians the prediction uses (for tests).
        measure: per aid name, x -> (h, H) with H = ∂h(x ⊕ δx)/∂δx at δx = 0.
        inject: (x, dx) -> x ⊕ dx.
        reset_jacobian: dx -> ∂[(x ⊕ δx) ⊖ (x ⊕ dx)]/∂δx at δx = dx (17, 17); independent of x.
        update: per scalar aid (barometer, heading), the whole update in one call: (x, P, z, r) -> (x_next, P_next,
            nis), the same arithmetic as the general path (Joseph form, injection, reset Jacobian), for the aids fused
            at the highest rates.
    """

    predict: ca.Function
    transition: ca.Function
    measure: dict[str, ca.Function]
    inject: ca.Function
    reset_jacobian: ca.Function
    update: dict[str, ca.Function]

    def all(self) -> list[ca.Function]:
        return [self.predict, self.transition, *self.measure.values(), self.inject, self.reset_jacobian,
                *self.update.values()]


SCALAR_AIDS = ("baro", "heading")


def scalar_update_function(name: str, measure: ca.Function, inject: ca.Function, reset: ca.Function) -> ca.Function:
    """(x, P, z, r) -> (x_next, P_next, nis): one scalar measurement fused (innovation wrapped for the heading)."""
    x = ca.SX.sym("x", NX)
    p = ca.SX.sym("P", NDX, NDX)
    z = ca.SX.sym("z")
    r = ca.SX.sym("r")
    h, jac = measure(x)
    y = z - h
    if name == "heading":
        y = ca.atan2(ca.sin(y), ca.cos(y))
    pht = p @ jac.T
    s = jac @ pht + r
    gain = pht / s
    ikh = ca.SX.eye(NDX) - gain @ jac
    p_new = ikh @ p @ ikh.T + gain @ (r * gain.T)
    dx = gain * y
    g = reset(dx)
    p_new = g @ p_new @ g.T
    return ca.Function(f"nav_update_{name}", [x, p, z, r], [inject(x, dx), 0.5 * (p_new + p_new.T), y * y / s],
                       ["x", "P", "z", "r"], ["x_next", "P_next", "nis"])


def build_filter_functions() -> FilterFunctions:
    """Generate the filter's Functions (SX, ready to compile)."""
    x = ca.SX.sym("x", NX)
    p = ca.SX.sym("P", NDX, NDX)
    imu = ca.SX.sym("imu", 6)
    dt = ca.SX.sym("dt")
    noise = ca.SX.sym("noise", NOISE_PARAMS)
    x_next, p_next = predict_expr(x, p, imu, dt, noise)
    predict = ca.Function("nav_predict", [x, p, imu, dt, noise], [x_next, p_next],
                          ["x", "P", "imu", "dt", "noise"], ["x_next", "P_next"])
    decay = ca.SX.sym("decay")
    f_jac, g_jac = transition_expr(x, imu, dt, decay)
    transition = ca.Function("nav_transition", [x, imu, dt, decay], [ca.densify(f_jac), ca.densify(g_jac)],
                             ["x", "imu", "dt", "decay"], ["F", "G_noise"])
    dx = ca.SX.sym("dx", NDX)
    measure = {}
    for name, h in measurement_exprs(x).items():
        h_err = ca.substitute(h, x, inject_expr(x, dx))
        jac = ca.densify(_at_zero(ca.jacobian(h_err, dx), dx))
        measure[name] = ca.Function(f"nav_measure_{name}", [x], [ca.densify(h), jac], ["x"], ["h", "H"])
    inject = ca.Function("nav_inject", [x, dx], [inject_expr(x, dx)], ["x", "dx"], ["x_next"])
    dx_hat = ca.SX.sym("dx_hat", NDX)
    after = difference_expr(inject_expr(x, dx), inject_expr(x, dx_hat))
    reset = ca.substitute(ca.jacobian(after, dx), dx, dx_hat)
    reset = ca.substitute(reset, x, ca.DM([0.0] * 6 + [1.0, 0.0, 0.0, 0.0] + [0.0] * 8))  # independent of x
    reset_jacobian = ca.Function("nav_reset_jacobian", [dx_hat], [ca.densify(reset)], ["dx"], ["G"])
    update = {name: scalar_update_function(name, measure[name], inject, reset_jacobian) for name in SCALAR_AIDS}
    return FilterFunctions(predict, transition, measure, inject, reset_jacobian, update)
