"""The NMPC's optimal-control problem, written once in a stage-wise layout for every solver.

The prediction model comes from the same CasADi expression as the simulator
(`uam_fdm.vehicle.model.dynamics_expr`, one RK4 step per interval through `uam_fdm.vehicle.model.rk4_expr`), with
the two reductions documented in `planners.mpc` (wrench inputs above four rotors, motor lag kept
only when it is slow against a step).

Layout (what structure-exploiting solvers need, and why each choice was made):

* Decision vector w = [x_0, u_0, x_1, u_1, ..., x_{N-1}, u_{N-1}, x_N], stage by stage.
* State x_k = [p, v, q, ω, (lagged input), previous input]: the previous input is a state
  (x_{k+1}'s copy of u_k), so the input-rate cost |u_k − u_{k−1}|² touches one stage only. Written
  across two stages it makes a Hessian entry outside the stage blocks, which fatrop's interface
  silently drops (casadi_project onto the block pattern): fatrop then converged only linearly.
* Stage input u_k = [MPC input, clearance slack s_k].
* The initial state is fixed through equal bounds on x_0 (not a constraint row).
* Constraints in stage order: the gap-closing rows x_{k+1} − F(x_k, u_k) = 0 of interval k, then
  the path rows of stage k that touch only x_k and u_k (rotor limits in wrench mode, tilt, the
  soft clearance half-spaces). The gap rows must read x_{k+1} − F, with +1 on x_{k+1}: CasADi's
  fatrop runtime checks those entries and raises otherwise ("gap-closing constraints must be like
  this: x_{k+1}-F(xk,uk)").
* Cost Σ_k |r_k(x_k, u_k)|² + w_s1 s_k + |r_N(x_N)|² with stage residuals r_k, so a Gauss-Newton
  Hessian 2 JᵀJ is block diagonal and positive semidefinite (the real-time iteration's QP).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from uam_fdm.vehicle.model import N_ENV, dynamics_expr, rk4_expr
from uam_fdm.vehicle.params import VehicleParams

# The tilt limit as a polygon in (q_x, q_y): the tilt θ satisfies cos θ = 1 − 2(q_x² + q_y²), a disc of
# radius sin(θ_max/2) whatever the heading. As linear rows (eight two-sided pairs: a 16-gon) its
# linearisation is exact; the disc's own constraint has a zero gradient at level attitude, so a
# Gauss-Newton QP saw no limit there, stepped far beyond it, and cycled (measured: a 2-cycle with 0.42
# violation on a 2 m step). Eight pairs, not four: the limit is active when the UAM accelerates from
# hover, and the octagon's 8 % smaller tilt made its circle's RMS error 20 % larger (2.03 m against
# 1.69 m with the disc; 1.73 m with the 16-gon).
TILT_DIRECTIONS = np.array([[np.cos(j * np.pi / 8), np.sin(j * np.pi / 8)] for j in range(8)])


def tilt_polygon_bound(max_tilt_rad: float) -> float:
    """Bound on |n_j · (q_x, q_y)|: the 16-gon inscribed in the disc of tilt ≤ max_tilt_rad.

    Its vertices lie on the disc and its edges cos(π/16) = 0.98 of the radius from the centre, so the
    tilt limit holds in every direction and is at most 2 % (in sin θ/2) tighter than the disc.
    """
    return float(np.sin(max_tilt_rad / 2) * np.cos(np.pi / 16))


@dataclass(frozen=True)
class MPCWeights:
    """Cost weights (position in m, velocity in m/s, inputs as fractions of the hover speed)."""

    position: float = 10.0
    velocity: float = 1.0
    terminal_position: float = 20.0
    terminal_velocity: float = 2.0
    tilt: float = 5.0
    yaw: float = 5.0
    body_rate: float = 0.1
    effort: float = 2.0
    input_rate: float = 5.0
    slack_l1: float = 1e3
    slack_l2: float = 1e4


class PredictionModel:
    """The MPC's model of one vehicle: inputs, their map to rotor speeds, and the discrete step.

    Args:
        params: the vehicle.
        input_mode: "rotors" (the MPC decides each rotor's speed, as fractions of the mean hover
            speed) or "wrench" (v = [T/(m g), M/(m g ℓ)], rotor speeds by the allocation pseudo-inverse).
        motor_lag: keep the first-order motor lag as states.
        step_s: interval length [s] (one RK4 step).
    """

    def __init__(self, params: VehicleParams, input_mode: str, motor_lag: bool, step_s: float) -> None:
        self.params = params
        self.input_mode = input_mode
        self.motor_lag = motor_lag
        self.step_s = step_s
        self.n_v = params.n_rotors if input_mode == "rotors" else 4
        self.u_scale = float(params.hover_rotor_speeds_rad_s().mean())
        # Wrench mode: Ω² = B v with B = A⁺ diag(m g, m g ℓ, m g ℓ, m g ℓ), A at sea-level density.
        arm = float(np.linalg.norm(params.rotor_positions[:, :2], axis=1).mean())
        scale = params.weight_N * np.array([1.0, arm, arm, arm])
        self.wrench_to_sq = np.linalg.pinv(params.allocation_matrix(1.0)) * scale
        self.omega_sq_lo = params.rotor_speed_min_rad_s ** 2
        self.omega_sq_hi = params.rotor_speed_max_rad_s ** 2

    @property
    def n_body(self) -> int:
        """Physical states predicted: 13 rigid-body states plus the lagged input when kept."""
        return 13 + (self.n_v if self.motor_lag else 0)

    def rotor_speeds_expr(self, v: ca.SX) -> ca.SX:
        """Rotor speeds [rad/s] for MPC input coordinates v (either mode)."""
        if self.input_mode == "rotors":
            return v * self.u_scale
        omega_sq = ca.DM(self.wrench_to_sq) @ v
        return ca.sqrt(ca.fmax(omega_sq, 0.25 * max(self.omega_sq_lo, 1.0)))

    def hover_input(self, density_ratio: float) -> np.ndarray:
        """MPC input coordinates of hover at density ratio σ."""
        if self.input_mode == "rotors":
            return self.params.hover_rotor_speeds_rad_s(density_ratio) / self.u_scale
        return np.array([1.0 / density_ratio, 0.0, 0.0, 0.0])

    def rotor_speeds(self, v: np.ndarray) -> np.ndarray:
        """Rotor-speed command [rad/s] (n,) for MPC input v, within the rotor limits."""
        p = self.params
        if self.input_mode == "rotors":
            omega = np.asarray(v, float) * self.u_scale
            return np.clip(omega, p.rotor_speed_min_rad_s, p.rotor_speed_max_rad_s)
        omega_sq = np.clip(self.wrench_to_sq @ np.asarray(v, float), self.omega_sq_lo, self.omega_sq_hi)
        return np.sqrt(omega_sq)

    def input_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Box bounds of the MPC input (n_v,) each."""
        if self.input_mode == "rotors":
            lo = self.params.rotor_speed_min_rad_s / self.u_scale
            hi = self.params.rotor_speed_max_rad_s / self.u_scale
            return np.full(self.n_v, lo), np.full(self.n_v, hi)
        # Loose boxes; the rotor limits are linear path constraints (`rotor_limit_rows`).
        return np.array([0.0, -10.0, -10.0, -10.0]), np.full(4, 10.0)

    def physical_state(self, x_full: np.ndarray) -> np.ndarray:
        """The predicted physical state (n_body,) from the vehicle's full state (13 + n,)."""
        x = np.asarray(x_full, float)
        if not self.motor_lag:
            return x[:13].copy()
        omega = x[13:13 + self.params.n_rotors]
        if self.input_mode == "rotors":
            return np.concatenate([x[:13], omega / self.u_scale])
        # The wrench coordinates that best explain the current rotor speeds.
        return np.concatenate([x[:13], np.linalg.lstsq(self.wrench_to_sq, omega ** 2, rcond=None)[0]])

    def step_function(self) -> ca.Function:
        """Discrete step (x_body, v, env) -> x_body after one interval (SX, one RK4 step)."""
        p, h = self.params, self.step_s
        x = ca.SX.sym("x", self.n_body)
        u = ca.SX.sym("u", self.n_v)
        env = ca.SX.sym("env", N_ENV)
        v_applied = x[13:] if self.motor_lag else u
        omega = self.rotor_speeds_expr(v_applied)
        # The one model expression; with Ω given (states or algebraic), keep the rigid-body rows.
        x_dot, _ = dynamics_expr(p, ca.vertcat(x[:13], omega), omega, env)
        rows = [x_dot[:13]]
        if self.motor_lag:
            rows.append((u - x[13:]) / p.motor_time_constant_s)
        f = ca.Function("f", [x, u, env], [ca.vertcat(*rows)])
        xn, = rk4_expr(lambda s: [f(s, u, env)], x, h)
        return ca.Function("mpc_step", [x, u, env], [xn])


@dataclass(frozen=True)
class OcpLayout:
    """Sizes and offsets of w = [x_0, u_0, ..., x_{N-1}, u_{N-1}, x_N] (see the module docstring).

    Attributes:
        n_stages: shooting intervals N.
        n_body: physical states per stage (13, plus the lagged input when kept).
        n_v: MPC inputs per stage.
    """

    n_stages: int
    n_body: int
    n_v: int

    @property
    def nx(self) -> int:
        """States per stage: physical states and the previous input."""
        return self.n_body + self.n_v

    @property
    def nu(self) -> int:
        """Stage inputs: the MPC input and the clearance slack."""
        return self.n_v + 1

    @property
    def stage_len(self) -> int:
        return self.nx + self.nu

    @property
    def n_w(self) -> int:
        return self.n_stages * self.stage_len + self.nx

    def x_start(self, k: int) -> int:
        """Offset of x_k in w."""
        return k * self.stage_len

    def states(self, w: np.ndarray) -> np.ndarray:
        """States (N+1, nx) of a decision vector."""
        n, ln = self.n_stages, self.stage_len
        return np.vstack([w[:n * ln].reshape(n, ln)[:, :self.nx], w[n * ln:][None, :]])

    def inputs(self, w: np.ndarray) -> np.ndarray:
        """MPC inputs (N, n_v) of a decision vector."""
        n, ln = self.n_stages, self.stage_len
        return w[:n * ln].reshape(n, ln)[:, self.nx:self.nx + self.n_v]

    def slacks(self, w: np.ndarray) -> np.ndarray:
        """Clearance slacks (N,) [m] of a decision vector."""
        n, ln = self.n_stages, self.stage_len
        return w[:n * ln].reshape(n, ln)[:, -1]

    def pack(self, states: np.ndarray, inputs: np.ndarray, slacks: np.ndarray) -> np.ndarray:
        """The decision vector of states (N+1, nx), inputs (N, n_v) and slacks (N,)."""
        n = self.n_stages
        body = np.hstack([states[:n], inputs, np.asarray(slacks, float).reshape(n, 1)])
        return np.concatenate([body.ravel(), states[n]])


@dataclass(frozen=True)
class TrackingOcp:
    """The tracking problem in CasADi MX, shared by the NLP solvers and the real-time iteration.

    Attributes:
        layout: sizes and offsets.
        w: decision vector (n_w,).
        p: parameters: ref (6, N+1) column-major, yaw, env, hover input, normals (3K, N), offsets (K, N).
        residual: stacked least-squares residuals (the cost's quadratic part is |residual|²).
        linear_cost: w_s1 Σ s_k.
        g: constraints (gap rows, then path rows, stage by stage).
        lbg, ubg: constraint bounds.
        lbx, ubx: variable bounds, the x_0 block to be overwritten by the measured state.
        path_rows: path-constraint rows per stage 0..N (the structure of the QP).
        gn_hessian: 2 JᵣᵀJᵣ, block diagonal (n_w, n_w), from the stage residuals' Jacobians.
        gradient: ∇f (n_w,).
        jacobian: ∂g/∂w (n_g, n_w), assembled from the stage Jacobians with an exact identity on
            x_{k+1} in the gap rows (the block structured QP solvers read).
    """

    layout: OcpLayout
    w: ca.MX
    p: ca.MX
    residual: ca.MX
    linear_cost: ca.MX
    g: ca.MX
    lbg: np.ndarray
    ubg: np.ndarray
    lbx: np.ndarray
    ubx: np.ndarray
    path_rows: tuple[int, ...]
    gn_hessian: ca.MX
    gradient: ca.MX
    jacobian: ca.MX

    def nlp(self) -> dict:
        """The problem as an `nlpsol` dict."""
        return {"x": self.w, "f": ca.sumsqr(self.residual) + self.linear_cost, "g": self.g, "p": self.p}

    @property
    def equality(self) -> list[bool]:
        """Which constraint rows are equalities (fatrop's structure detection needs it)."""
        return [bool(lo == hi) for lo, hi in zip(self.lbg, self.ubg)]

    def bounds(self, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Variable bounds with the initial state x_0 (nx,) fixed."""
        lbx, ubx = self.lbx.copy(), self.ubx.copy()
        lbx[:self.layout.nx] = x0
        ubx[:self.layout.nx] = x0
        return lbx, ubx


def _with_jacobian(f: ca.Function, wrt: tuple[int, ...]) -> ca.Function:
    """f's inputs -> (f, ∂f/∂[inputs wrt]) as one SX Function (a stage's linearisation)."""
    args = [ca.SX.sym(f.name_in(i), f.sparsity_in(i)) for i in range(f.n_in())]
    out = f(*args)
    return ca.Function(f"{f.name()}_lin", args, [out, ca.jacobian(out, ca.vertcat(*[args[i] for i in wrt]))])


def _stage_functions(model: PredictionModel, weights: MPCWeights, n_halfspaces: int,
                     max_tilt_rad: float | None) -> dict[str, ca.Function]:
    """The OCP's per-stage SX Functions, each over one stage's state x (nx) and input u (nu).

    dynamics (x, u, env) -> x_{k+1} (the previous input copies u); stage_residual (x, u, ref, yaw,
    u_hover); terminal_residual (x, ref, yaw); path_first (x, u) and path (x, u, normals, offsets):
    the rows of stage 0 and of stages 1..N-1.
    """
    w, nb, nv, k_h = weights, model.n_body, model.n_v, n_halfspaces
    x = ca.SX.sym("x", nb + nv)
    u = ca.SX.sym("u", nv + 1)
    env = ca.SX.sym("env", N_ENV)
    ref = ca.SX.sym("ref", 6)
    yaw = ca.SX.sym("yaw")
    u_hover = ca.SX.sym("u_hover", nv)
    normals = ca.SX.sym("normals", 3 * k_h)
    offsets = ca.SX.sym("offsets", max(k_h, 1))
    step = model.step_function()
    q = x[6:10]
    heading = ca.vertcat(1 - 2 * (q[2] ** 2 + q[3] ** 2), 2 * (q[1] * q[2] + q[0] * q[3]))
    attitude = [np.sqrt(w.tilt) * q[1:3], np.sqrt(w.yaw) * (heading - ca.vertcat(ca.cos(yaw), ca.sin(yaw))),
                np.sqrt(w.body_rate) * x[10:13]]
    v_now, v_prev, slack = u[:nv], x[nb:], u[nv]
    stage = ca.vertcat(np.sqrt(w.position) * (x[0:3] - ref[0:3]), np.sqrt(w.velocity) * (x[3:6] - ref[3:6]),
                       *attitude, np.sqrt(w.effort) * (v_now - u_hover),
                       np.sqrt(w.input_rate) * (v_now - v_prev), np.sqrt(w.slack_l2) * slack)
    terminal = ca.vertcat(np.sqrt(w.terminal_position) * (x[0:3] - ref[0:3]),
                          np.sqrt(w.terminal_velocity) * (x[3:6] - ref[3:6]), *attitude)
    first_rows, rows = [], []
    if model.input_mode == "wrench":   # rotor limits, in units of the hover Ω² (well scaled)
        first_rows.append(ca.DM(model.wrench_to_sq) @ v_now / model.u_scale ** 2)
    rows += first_rows
    if max_tilt_rad is not None:       # |n_j · (q_x, q_y)| ≤ bound, j = 0..7 (TILT_DIRECTIONS)
        rows.append(ca.mtimes(ca.DM(TILT_DIRECTIONS), x[7:9]))
    # Soft clearance n_j·p_k ≥ c_j − s_k (stages 1..N-1; x_0 is measured).
    rows += [ca.dot(normals[3 * j:3 * j + 3], x[0:3]) - offsets[j] + slack for j in range(k_h)]
    return {
        "dynamics": ca.Function("mpc_dynamics", [x, u, env], [ca.vertcat(step(x[:nb], v_now, env), v_now)]),
        "stage_residual": ca.Function("mpc_stage_residual", [x, u, ref, yaw, u_hover], [stage]),
        "terminal_residual": ca.Function("mpc_terminal_residual", [x, ref, yaw], [terminal]),
        "path_first": ca.Function("mpc_path_first", [x, u], [ca.vertcat(*first_rows)]),
        "path": ca.Function("mpc_path", [x, u, normals, offsets], [ca.vertcat(*rows)]),
    }


def _path_bounds(model: PredictionModel, n_halfspaces: int, max_tilt_rad: float | None,
                 first: bool) -> tuple[list[float], list[float]]:
    """Bounds of the rows of `path_first` (first=True) or `path`."""
    lo, hi = [], []
    if model.input_mode == "wrench":
        hover_sq = model.u_scale ** 2
        lo += [model.omega_sq_lo / hover_sq] * model.params.n_rotors
        hi += [model.omega_sq_hi / hover_sq] * model.params.n_rotors
    if first:
        return lo, hi
    if max_tilt_rad is not None:
        bound = tilt_polygon_bound(max_tilt_rad)
        lo += [-bound] * len(TILT_DIRECTIONS)
        hi += [bound] * len(TILT_DIRECTIONS)
    return lo + [0.0] * n_halfspaces, hi + [np.inf] * n_halfspaces


def _band(block: ca.MX, col: int, n_cols: int) -> ca.MX:
    """block placed at column `col` of a row band n_cols wide (structural zeros elsewhere)."""
    rows = block.size1()
    return ca.horzcat(ca.MX(rows, col), block, ca.MX(rows, n_cols - col - block.size2()))


def build_tracking_ocp(model: PredictionModel, weights: MPCWeights, n_stages: int, n_halfspaces: int,
                       max_tilt_rad: float | None) -> TrackingOcp:
    """Assemble the tracking OCP (module docstring) for N = `n_stages` intervals.

    Args:
        model: the prediction model.
        weights: cost weights.
        n_stages: shooting intervals N.
        n_halfspaces: clearance half-spaces per stage K (stages 1 .. N-1).
        max_tilt_rad: tilt limit at stages 1 .. N-1 [rad] (as `tilt_polygon_bound`); None for none.
    """
    lay = OcpLayout(n_stages, model.n_body, model.n_v)
    nx, nv, k_h, n_w = lay.nx, lay.n_v, n_halfspaces, lay.n_w
    fn = _stage_functions(model, weights, n_halfspaces, max_tilt_rad)
    lin = {"dynamics": _with_jacobian(fn["dynamics"], (0, 1)),
           "stage_residual": _with_jacobian(fn["stage_residual"], (0, 1)),
           "terminal_residual": _with_jacobian(fn["terminal_residual"], (0,)),
           "path_first": _with_jacobian(fn["path_first"], (0, 1)), "path": _with_jacobian(fn["path"], (0, 1))}
    xs = [ca.MX.sym(f"x{k}", nx) for k in range(n_stages + 1)]
    us = [ca.MX.sym(f"u{k}", lay.nu) for k in range(n_stages)]
    p_ref = ca.MX.sym("ref", 6, n_stages + 1)
    p_yaw = ca.MX.sym("yaw")
    p_env = ca.MX.sym("env", N_ENV)
    p_uhover = ca.MX.sym("u_hover", nv)
    p_normals = ca.MX.sym("normals", 3 * k_h, n_stages)
    p_offsets = ca.MX.sym("offsets", max(k_h, 1), n_stages)
    slack_weight = ca.DM.zeros(lay.stage_len)
    slack_weight[-1] = weights.slack_l1
    residuals, g, lbg, ubg, path_rows = [], [], [], [], []
    hessians, gradients, jac_rows = [], [], []
    for k in range(n_stages):
        x, u, col = xs[k], us[k], lay.x_start(k)
        res_args = (x, u, p_ref[:, k], p_yaw, p_uhover)
        path_args: tuple[ca.MX, ...] = (x, u) if k == 0 else (x, u, p_normals[:, k - 1], p_offsets[:, k - 1])
        path_name = "path_first" if k == 0 else "path"
        lo, hi = _path_bounds(model, k_h, max_tilt_rad, first=k == 0)
        # The NLP: residuals, gap rows x_{k+1} − F(x_k, u_k), path rows.
        residuals.append(fn["stage_residual"](*res_args))
        g += [xs[k + 1] - fn["dynamics"](x, u, p_env), fn[path_name](*path_args)]
        lbg += [0.0] * nx + lo
        ubg += [0.0] * nx + hi
        path_rows.append(len(lo))
        # The Gauss-Newton QP's blocks from the same Functions' Jacobians.
        r, dr = lin["stage_residual"](*res_args)
        hessians.append(2 * ca.mtimes(dr.T, dr))
        gradients.append(2 * ca.mtimes(dr.T, r) + slack_weight)
        _, df = lin["dynamics"](x, u, p_env)
        jac_rows.append(_band(ca.horzcat(-df, ca.MX(ca.DM.eye(nx))), col, n_w))
        _, dc = lin[path_name](*path_args)
        jac_rows.append(_band(dc, col, n_w))
    path_rows.append(0)
    residuals.append(fn["terminal_residual"](xs[n_stages], p_ref[:, n_stages], p_yaw))
    r, dr = lin["terminal_residual"](xs[n_stages], p_ref[:, n_stages], p_yaw)
    hessians.append(2 * ca.mtimes(dr.T, dr))
    gradients.append(2 * ca.mtimes(dr.T, r))
    w = ca.vertcat(*[v for k in range(n_stages) for v in (xs[k], us[k])], xs[n_stages])
    p = ca.vertcat(ca.vec(p_ref), p_yaw, p_env, p_uhover, ca.vec(p_normals), ca.vec(p_offsets))
    u_lo, u_hi = model.input_bounds()
    x_lo = np.r_[np.full(13, -np.inf), u_lo if model.motor_lag else [], np.full(nv, -np.inf)]
    x_hi = np.r_[np.full(13, np.inf), u_hi if model.motor_lag else [], np.full(nv, np.inf)]
    lbx = lay.pack(np.tile(x_lo, (n_stages + 1, 1)), np.tile(u_lo, (n_stages, 1)), np.zeros(n_stages))
    ubx = lay.pack(np.tile(x_hi, (n_stages + 1, 1)), np.tile(u_hi, (n_stages, 1)), np.full(n_stages, np.inf))
    linear_cost = weights.slack_l1 * ca.sum1(ca.vertcat(*[u[nv] for u in us]))
    return TrackingOcp(lay, w, p, ca.vertcat(*residuals), linear_cost, ca.vertcat(*g), np.array(lbg, float),
                       np.array(ubg, float), lbx, ubx, tuple(path_rows), ca.diagcat(*hessians),
                       ca.vertcat(*gradients), ca.vertcat(*jac_rows))


def pack_parameters(n_stages: int, n_halfspaces: int, ref: np.ndarray, yaw_rad: float, env: np.ndarray,
                    u_hover: np.ndarray, normals: np.ndarray | None,
                    offsets: np.ndarray | None) -> np.ndarray:
    """The parameter vector of `TrackingOcp.p`.

    Args:
        ref: (6, N+1) reference position [m] and velocity [m/s], world ENU, per stage.
        normals, offsets: (N, K, 3) and (N, K) half-spaces for stages 1..N (None: inactive ones).
    """
    k_h = n_halfspaces
    if normals is None or k_h == 0:
        normals_arr = np.zeros((3 * k_h, n_stages))
        offsets_arr = np.full((max(k_h, 1), n_stages), -1.0)
    else:
        normals_arr = np.asarray(normals, float).reshape(n_stages, k_h * 3).T
        offsets_arr = np.asarray(offsets, float).reshape(n_stages, k_h).T
    return np.concatenate([ref.ravel(order="F"), [yaw_rad], env, u_hover,
                           normals_arr.ravel(order="F"), offsets_arr.ravel(order="F")])
