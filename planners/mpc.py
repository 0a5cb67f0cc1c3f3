"""Nonlinear MPC tracker: reference (position, velocity, heading) -> rotor-speed commands.

Built from the same CasADi expression as the simulator (`uam_fdm.model.dynamics_expr`), with two
documented reductions chosen automatically:

* Inputs. With four rotors the MPC decides each rotor's speed (``input_mode="rotors"``). With more
  (the 18-rotor UAM preset) the rotors are redundant for the four controllable axes, and an
  18-input NLP is too slow to solve in real time (measured: ~7 s per SQP iteration), so the MPC
  decides the wrench v = [T/(m g), M_x/(m g ℓ), M_y/(m g ℓ), M_z/(m g ℓ)] (ℓ = rotor arm) and the
  rotor speeds follow from the allocation pseudo-inverse, Ω² = A⁺ W(v) (``input_mode="wrench"``),
  the same allocation the low-level controller uses; rotor-speed limits become linear
  constraints on v. The predicted dynamics substitute these Ω into the model expression.
* Motor lag. Kept when τ_m ≥ step/2.5, where RK4 with the MPC's step is stable on it (the UAM
  preset, τ_m = 0.12 s), neglected when it is much shorter than a step (the small quad, 12.5 ms
  against 50 ms). In wrench mode it is a first-order lag of v with τ_m: Ω² obeys
  d(Ω²)/dt = 2Ω(Ω_cmd − Ω)/τ_m ≈ (Ω_cmd² − Ω²)/τ_m near the operating point, linear in v.

Formulation (multiple shooting, one RK4 step per interval, inputs scaled by the hover speed):

    min  Σ_k  w_p|p_k − p_ref,k|² + w_v|v_k − v_ref,k|² + w_tilt(q_x² + q_y²) + w_yaw|b1_xy − ψ_ref|²
              + w_ω|ω_k|² + w_u|u_k − u_hover|² + w_du|u_k − u_k−1|² + w_s1 s_k + w_s2 s_k²
         + terminal position/velocity terms
    s.t. x_0 = x_measured, x_k+1 = RK4(x_k, u_k), u_min ≤ u_k ≤ u_max, s_k ≥ 0,
         tilt(x_k) ≤ the vehicle's max tilt,
         n_kj · p_k ≥ c_kj − s_k,  k = 1 .. N−1             (soft clearance half-spaces)

The clearance half-spaces are parameters: for each stage, the nearest buildings to the previous
prediction give a plane through the nearest point, facing the vehicle, offset by the collision
radius plus a margin (computed by the agent from the city; inactive ones are 0 ≥ −1).

The NLP's functions are generated as C, compiled once and cached on disk (`uam_fdm.codegen`);
without a compiler the solver evaluates them on CasADi's virtual machine.
"""
from __future__ import annotations

import dataclasses
import logging
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from uam_fdm.codegen import compile_source
from uam_fdm.model import FAR_FROM_SURFACES_M, N_ENV, dynamics_expr, make_env, rk4_expr
from uam_fdm.params import VehicleParams

log = logging.getLogger(__name__)

SOLVERS = ("sqpmethod", "ipopt", "fatrop")


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


@dataclass(frozen=True)
class MPCConfig:
    """MPC settings.

    Attributes:
        horizon_steps: shooting intervals N; None: 15 with rotor inputs (0.75 s for the quad: 5.9 ms
            median solve, within a third of the 20 ms decision period; 20 steps took 7.2 ms), 20 with
            wrench inputs (3 s for the UAM).
        step_s: interval length [s] (one RK4 step each); None: max(0.05 s, 1.25 τ_m), so the horizon
            spans the vehicle's attitude response (quad 0.05 s → 1 s; UAM 0.15 s → 3 s: with a 1 s
            horizon the UAM tilts hard and cannot recover its attitude within the horizon).
        solver: "ipopt" (default, chosen by measurement: benchmarks/classical.py), "sqpmethod" or
            "fatrop". Measured here: exact-Hessian SQP + qrqp is faster when it converges (3.4 ms
            median on the quad's circle) but fails its line search on a diagonal step reference and
            on every wrench-mode problem; fatrop raises inside its solve on this problem; Ipopt
            solved every case (quad: 5 ms median warm).
        qp_solver: QP solver for sqpmethod ("qrqp"; "osqp"/"proxqp" need a convex QP).
        max_iterations: solver iteration cap per decision.
        n_halfspaces: clearance half-spaces per stage.
        clearance_margin_m: margin added to the collision radius in the half-spaces [m].
        input_mode: "rotors" or "wrench" (None: rotors for 4 rotors, wrench above; module docstring).
        motor_lag: keep the motor lag in the prediction (None: automatic, see the module docstring).
        tilt_constraint: constrain the tilt to the vehicle's max_tilt_deg at every stage. Without it
            the slow UAM tilts beyond what it can recover from, and the quad's solver fails on hard
            cases (a step target behind a wall: 100 iterations without convergence, vs 8 with it).
        compiled: compile the NLP functions (None: when a compiler exists).
        opt_level: optimisation flag for the generated code (-O1: 5x faster solves than the VM for a
            ~30 s one-off compile; -O2/-O3 compile far longer for little gain).
    """

    horizon_steps: int | None = None
    step_s: float | None = None
    solver: str = "ipopt"
    qp_solver: str = "qrqp"
    max_iterations: int = 200
    n_halfspaces: int = 3
    clearance_margin_m: float = 0.5
    input_mode: str | None = None
    motor_lag: bool | None = None
    tilt_constraint: bool = True
    compiled: bool | None = None
    opt_level: str = "-O1"
    weights: MPCWeights = field(default_factory=MPCWeights)

    def __post_init__(self) -> None:
        if self.solver not in SOLVERS:
            raise ValueError(f"MPC solver must be one of {SOLVERS}, got {self.solver!r}")
        if self.input_mode not in (None, "rotors", "wrench"):
            raise ValueError(f"input_mode must be None, 'rotors' or 'wrench', got {self.input_mode!r}")
        if ((self.horizon_steps is not None and self.horizon_steps < 2)
                or (self.step_s is not None and self.step_s <= 0) or self.max_iterations < 1
                or self.n_halfspaces < 0):
            raise ValueError(f"invalid MPC config {self}")


@dataclass(frozen=True)
class MPCSolution:
    """One MPC decision.

    Attributes:
        rotor_speeds_rad_s: the command to apply now (n,).
        success: the solver reported success.
        status: the solver's return status (or "fallback_shifted(...)" / "fallback_hover(...)").
        iterations: solver iterations.
        solve_time_s: wall time of the solve [s].
        fallback: the command came from the shifted previous plan or hover, not this solve.
        predicted_states: (N+1, 13) predicted [p, v, q, ω] (the previous plan's on fallback).
        max_slack_m: largest clearance slack used [m] (0 when every half-space holds).
    """

    rotor_speeds_rad_s: np.ndarray
    success: bool
    status: str
    iterations: int
    solve_time_s: float
    fallback: bool
    predicted_states: np.ndarray
    max_slack_m: float


class MPCTracker:
    """Nonlinear MPC for one vehicle (see the module docstring).

    Args:
        params: the vehicle.
        config: MPC settings.
        cache_dir: cache for the compiled NLP (default `uam_fdm.codegen.default_cache_dir()`).
    """

    def __init__(self, params: VehicleParams, config: MPCConfig | None = None, cache_dir: Path | None = None) -> None:
        self.params = params
        config = config if config is not None else MPCConfig()
        n = params.n_rotors
        self.input_mode = config.input_mode or ("rotors" if n == 4 else "wrench")
        if config.step_s is None:
            config = dataclasses.replace(config, step_s=max(0.05, 1.25 * params.motor_time_constant_s))
        if config.horizon_steps is None:
            config = dataclasses.replace(config, horizon_steps=15 if self.input_mode == "rotors" else 20)
        self.config = config
        self.motor_lag = (params.motor_time_constant_s >= config.step_s / 2.5
                          if config.motor_lag is None else config.motor_lag)
        self.n_v = n if self.input_mode == "rotors" else 4
        self.solver_name = config.solver
        self.tilt_constraint = config.tilt_constraint
        self.nx = 13 + (self.n_v if self.motor_lag else 0)
        self.u_scale = float(params.hover_rotor_speeds_rad_s().mean())
        # Wrench mode: Ω² = B v with B = A⁺ diag(m g, m g ℓ, m g ℓ, m g ℓ), A at sea-level density.
        arm = float(np.linalg.norm(params.rotor_positions[:, :2], axis=1).mean())
        scale = params.weight_N * np.array([1.0, arm, arm, arm])
        self._wrench_to_sq = np.linalg.pinv(params.allocation_matrix(1.0)) * scale
        self._omega_sq_lo = params.rotor_speed_min_rad_s ** 2
        self._omega_sq_hi = params.rotor_speed_max_rad_s ** 2
        self._build_nlp()
        self._solver, self.backend = self._make_solver(cache_dir)
        self.reset()

    # -- construction ---------------------------------------------------------------------------
    def _rotor_speeds_expr(self, v: ca.SX) -> ca.SX:
        """Rotor speeds [rad/s] for MPC input coordinates v (either mode)."""
        if self.input_mode == "rotors":
            return v * self.u_scale
        omega_sq = ca.DM(self._wrench_to_sq) @ v
        return ca.sqrt(ca.fmax(omega_sq, 0.25 * max(self._omega_sq_lo, 1.0)))

    def hover_input(self, density_ratio: float) -> np.ndarray:
        """MPC input coordinates of hover at density ratio σ."""
        if self.input_mode == "rotors":
            return self.params.hover_rotor_speeds_rad_s(density_ratio) / self.u_scale
        return np.array([1.0 / density_ratio, 0.0, 0.0, 0.0])

    def rotor_speeds(self, v: np.ndarray) -> np.ndarray:
        """Rotor-speed command [rad/s] (n,) for MPC input v, within the rotor limits."""
        if self.input_mode == "rotors":
            omega = np.asarray(v, float) * self.u_scale
            return np.clip(omega, self.params.rotor_speed_min_rad_s, self.params.rotor_speed_max_rad_s)
        omega_sq = np.clip(self._wrench_to_sq @ np.asarray(v, float), self._omega_sq_lo, self._omega_sq_hi)
        return np.sqrt(omega_sq)

    def _stage_functions(self) -> tuple[ca.Function, ca.Function, ca.Function]:
        """Discrete step F(x, u, env), stage cost L(x, u, ref, u_prev, u_hover, yaw), terminal cost LN(x, ref, yaw)."""
        p, w, h = self.params, self.config.weights, self.config.step_s
        x = ca.SX.sym("x", self.nx)
        u = ca.SX.sym("u", self.n_v)
        env = ca.SX.sym("env", N_ENV)
        v_applied = x[13:] if self.motor_lag else u
        omega = self._rotor_speeds_expr(v_applied)
        # The one model expression; with Ω given (states or algebraic), keep the rigid-body rows.
        x_dot, _ = dynamics_expr(p, ca.vertcat(x[:13], omega), omega, env)
        rows = [x_dot[:13]]
        if self.motor_lag:
            rows.append((u - x[13:]) / p.motor_time_constant_s)
        f = ca.Function("f", [x, u, env], [ca.vertcat(*rows)])
        xn, = rk4_expr(lambda s: [f(s, u, env)], x, h)
        step = ca.Function("mpc_step", [x, u, env], [xn])

        ref = ca.SX.sym("ref", 6)
        u_prev = ca.SX.sym("u_prev", self.n_v)
        u_hover = ca.SX.sym("u_hover", self.n_v)
        yaw = ca.SX.sym("yaw")
        q = x[6:10]
        heading = ca.vertcat(1 - 2 * (q[2] ** 2 + q[3] ** 2), 2 * (q[1] * q[2] + q[0] * q[3]))
        attitude = (w.tilt * (q[1] ** 2 + q[2] ** 2) + w.yaw * ca.sumsqr(heading - ca.vertcat(ca.cos(yaw), ca.sin(yaw)))
                    + w.body_rate * ca.sumsqr(x[10:13]))
        stage = (w.position * ca.sumsqr(x[0:3] - ref[0:3]) + w.velocity * ca.sumsqr(x[3:6] - ref[3:6]) + attitude
                 + w.effort * ca.sumsqr(u - u_hover) + w.input_rate * ca.sumsqr(u - u_prev))
        terminal = (w.terminal_position * ca.sumsqr(x[0:3] - ref[0:3])
                    + w.terminal_velocity * ca.sumsqr(x[3:6] - ref[3:6]) + attitude)
        return (step, ca.Function("mpc_stage_cost", [x, u, ref, u_prev, u_hover, yaw], [stage]),
                ca.Function("mpc_terminal_cost", [x, ref, yaw], [terminal]))

    def _input_bounds(self) -> tuple[list[float], list[float]]:
        if self.input_mode == "rotors":
            lo = self.params.rotor_speed_min_rad_s / self.u_scale
            hi = self.params.rotor_speed_max_rad_s / self.u_scale
            return [lo] * self.n_v, [hi] * self.n_v
        # Loose boxes; the rotor limits are the linear constraints added in _build_nlp.
        return [0.0, -10.0, -10.0, -10.0], [10.0, 10.0, 10.0, 10.0]

    def _build_nlp(self) -> None:
        cfg, nv, nx, k_h = self.config, self.n_v, self.nx, self.config.n_halfspaces
        big_n = cfg.horizon_steps
        step, stage, terminal = self._stage_functions()
        xs = [ca.MX.sym(f"x{k}", nx) for k in range(big_n + 1)]
        us = [ca.MX.sym(f"u{k}", nv) for k in range(big_n)]
        ss = [ca.MX.sym(f"s{k}") for k in range(big_n)]
        p_x0 = ca.MX.sym("x0", nx)
        p_ref = ca.MX.sym("ref", 6, big_n + 1)
        p_yaw = ca.MX.sym("yaw")
        p_env = ca.MX.sym("env", N_ENV)
        p_uprev = ca.MX.sym("u_prev", nv)
        p_uhover = ca.MX.sym("u_hover", nv)
        p_normals = ca.MX.sym("normals", 3 * k_h, big_n)
        p_offsets = ca.MX.sym("offsets", max(k_h, 1), big_n)
        w_ = cfg.weights
        wrench_to_sq = ca.DM(self._wrench_to_sq)
        variables, g, lbg, ubg, cost = [], [], [], [], 0
        # Variables interleaved stage by stage (x_k, u_k, s_k), constraints in stage order: the layout
        # structure-exploiting solvers (fatrop) detect.
        for k in range(big_n):
            variables += [xs[k], us[k], ss[k]]
            if k == 0:
                g.append(xs[0] - p_x0)
                lbg += [0.0] * nx
                ubg += [0.0] * nx
            cost += stage(xs[k], us[k], p_ref[:, k], us[k - 1] if k > 0 else p_uprev, p_uhover, p_yaw)
            cost += w_.slack_l1 * ss[k] + w_.slack_l2 * ss[k] ** 2
            g.append(step(xs[k], us[k], p_env) - xs[k + 1])
            lbg += [0.0] * nx
            ubg += [0.0] * nx
            if self.input_mode == "wrench":   # rotor limits, in units of the hover Ω² (well scaled)
                hover_sq = self.u_scale ** 2
                g.append(wrench_to_sq @ us[k] / hover_sq)
                lbg += [self._omega_sq_lo / hover_sq] * self.params.n_rotors
                ubg += [self._omega_sq_hi / hover_sq] * self.params.n_rotors
            if k > 0 and self.tilt_constraint:   # the vehicle's tilt limit: cos(tilt) = 1 - 2(q_x² + q_y²) >= cos(max tilt)
                g.append(1 - 2 * (xs[k][7] ** 2 + xs[k][8] ** 2))
                lbg.append(float(np.cos(np.radians(self.params.controller.max_tilt_deg))))
                ubg.append(1.0)
            # Clearance rows of stage k act on x_k (k = 1 .. N-1; x_0 is measured): rows of a stage
            # may only touch that stage's variables for stage-structured solvers.
            for j in range(k_h if k > 0 else 0):
                normal = p_normals[3 * j:3 * j + 3, k - 1]
                g.append(ca.dot(normal, xs[k][0:3]) - p_offsets[j, k - 1] + ss[k])
                lbg.append(0.0)
                ubg.append(ca.inf)
        variables.append(xs[big_n])
        cost += terminal(xs[big_n], p_ref[:, big_n], p_yaw)
        self._nlp = {"x": ca.vertcat(*variables), "f": cost, "g": ca.vertcat(*g),
                     "p": ca.vertcat(p_x0, ca.vec(p_ref), p_yaw, p_env, p_uprev, p_uhover,
                                     ca.vec(p_normals), ca.vec(p_offsets))}
        self._lbg, self._ubg = np.array(lbg), np.array(ubg)
        self._equality = [lo == hi for lo, hi in zip(lbg, ubg)]
        u_lo, u_hi = self._input_bounds()
        lbx, ubx = [], []
        for k in range(big_n + 1):
            lbx += [-np.inf] * 13 + (u_lo if self.motor_lag else [])
            ubx += [np.inf] * 13 + (u_hi if self.motor_lag else [])
            if k < big_n:
                lbx += u_lo + [0.0]
                ubx += u_hi + [np.inf]
        self._lbx, self._ubx = np.array(lbx), np.array(ubx)
        self._stage_len = nx + nv + 1

    def _solver_options(self) -> dict:
        # Trial points of a line search may evaluate to inf; the solver rejects them itself, so
        # CasADi's per-evaluation warnings are noise (failures still show in the solve status).
        return {"show_eval_warnings": False, **self._plugin_options()}

    def _plugin_options(self) -> dict:
        cfg = self.config
        if self.solver_name == "sqpmethod":
            return {"qpsol": cfg.qp_solver, "max_iter": cfg.max_iterations, "print_time": False,
                    "print_header": False, "print_iteration": False, "print_status": False, "error_on_fail": False,
                    "qpsol_options": {"error_on_fail": False, **({"print_iter": False, "print_header": False}
                                                                 if cfg.qp_solver == "qrqp" else {})}}
        if self.solver_name == "ipopt":
            return {"print_time": False, "error_on_fail": False,
                    "ipopt": {"print_level": 0, "sb": "yes", "max_iter": cfg.max_iterations,
                              "warm_start_init_point": "yes", "mu_init": 1e-3,
                              # Keep a warm start where it is (defaults push it 1e-3 into the bounds).
                              "warm_start_bound_push": 1e-6, "warm_start_mult_bound_push": 1e-6,
                              "warm_start_slack_bound_push": 1e-6,
                              # 1e-6 on positions in metres is far below what the simulator resolves.
                              "tol": 1e-6, "acceptable_tol": 1e-4, "acceptable_iter": 3}}
        return {"print_time": False, "error_on_fail": False, "structure_detection": "auto",
                "equality": self._equality, "fatrop": {"print_level": 0, "max_iter": cfg.max_iterations}}

    def _make_solver(self, cache_dir: Path | None) -> tuple[ca.Function, str]:
        cfg = self.config
        opts = self._solver_options()
        if cfg.compiled is not False:
            source = _nlp_functions_c(ca.nlpsol("mpc", self.solver_name, self._nlp, opts))
            tag = f"mpc_{self.params.fingerprint()}_{self.solver_name}"
            lib = compile_source(source, tag, cache_dir, opt_flags=(cfg.opt_level, "-march=native"))
            if lib is not None:
                return ca.nlpsol("mpc", self.solver_name, str(lib), opts), "compiled"
            if cfg.compiled:
                raise RuntimeError("compiled=True but the MPC could not be compiled (see the log)")
        return ca.nlpsol("mpc", self.solver_name, self._nlp, {**opts, "expand": True}), "vm"

    # -- solving --------------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the warm start (call at the start of an episode)."""
        self._w: np.ndarray | None = None
        self._lam_x: np.ndarray | None = None
        self._lam_g: np.ndarray | None = None
        self._last_u: np.ndarray | None = None
        self._plan_age_s = 0.0
        self.n_solves = 0
        self.n_failures = 0

    def _state_vector(self, x_full: np.ndarray) -> np.ndarray:
        x = np.asarray(x_full, float)
        if not self.motor_lag:
            return x[:13].copy()
        omega = x[13:13 + self.params.n_rotors]
        if self.input_mode == "rotors":
            return np.concatenate([x[:13], omega / self.u_scale])
        # The wrench coordinates that best explain the current rotor speeds.
        v = np.linalg.lstsq(self._wrench_to_sq, omega ** 2, rcond=None)[0]
        return np.concatenate([x[:13], v])

    def _initial_guess(self, x0: np.ndarray, ref: np.ndarray, u_hover: np.ndarray, shift_s: float) -> np.ndarray:
        big_n, nx, n = self.config.horizon_steps, self.nx, self.n_v
        if self._w is None:
            # Cold start: the current state held over the horizon. Unlike the reference, it satisfies
            # the clearance half-spaces (a reference may run through a wall the MPC must respect).
            guess = []
            for k in range(big_n + 1):
                guess.append(x0.copy())
                if k < big_n:
                    guess += [u_hover, [0.0]]
            w = np.concatenate(guess)
        else:
            # Shift the previous solution forward by the time elapsed (linear interpolation between stages).
            frac = min(shift_s / self.config.step_s, 1.0)
            stages = [self._w[k * self._stage_len:(k + 1) * self._stage_len] for k in range(big_n)]
            last_x = self._w[big_n * self._stage_len:]
            xs = [s[:nx] for s in stages] + [last_x]
            us = [s[nx:nx + n] for s in stages]
            guess = []
            for k in range(big_n + 1):
                nxt = xs[min(k + 1, big_n)]
                guess.append((1 - frac) * xs[k] + frac * nxt)
                if k < big_n:
                    guess += [(1 - frac) * us[k] + frac * us[min(k + 1, big_n - 1)], [0.0]]
            w = np.concatenate(guess)
        w[:nx] = x0
        return w

    def solve(self, x_full: np.ndarray, ref_pos_m: np.ndarray, ref_vel_m_s: np.ndarray, yaw_ref_rad: float,
              density_ratio: float, normals: np.ndarray | None = None, offsets: np.ndarray | None = None,
              elapsed_s: float = 0.0, height_above_surface_m: float = FAR_FROM_SURFACES_M) -> MPCSolution:
        """Solve for the rotor command to apply now.

        Args:
            x_full: the vehicle's full state (13 + n,).
            ref_pos_m, ref_vel_m_s: reference at the N+1 stage times, (N+1, 3) world ENU.
            yaw_ref_rad: heading reference [rad].
            density_ratio: σ = ρ/ρ0 at the vehicle.
            normals, offsets: clearance half-spaces per stage k = 1..N: normals (N, K, 3) unit vectors
                and offsets (N, K) [m], meaning normals·p_k ≥ offsets (enforced, softly, at stages
                1..N-1; the terminal stage carries none); None for no constraints.
            elapsed_s: time since the previous solve [s] (to shift the warm start).
            height_above_surface_m: the vehicle's height above the surface below it [m], held over the
                horizon (the model's ground effect; default: far from any surface).
        """
        cfg, n = self.config, self.n_v
        big_n, k_h = cfg.horizon_steps, cfg.n_halfspaces
        x0 = self._state_vector(x_full)
        ref = np.vstack([np.asarray(ref_pos_m, float).T, np.asarray(ref_vel_m_s, float).T])
        u_hover = self.hover_input(density_ratio)
        u_prev = self._last_u if self._last_u is not None else u_hover
        if normals is None or k_h == 0:
            normals_arr = np.zeros((3 * k_h, big_n))
            offsets_arr = np.full((max(k_h, 1), big_n), -1.0)
        else:
            normals_arr = np.asarray(normals, float).reshape(big_n, k_h * 3).T
            offsets_arr = np.asarray(offsets, float).reshape(big_n, k_h).T
        params = np.concatenate([x0, ref.ravel(order="F"), [yaw_ref_rad],
                                 make_env(density_ratio=density_ratio, height_above_surface_m=height_above_surface_m),
                                 u_prev, u_hover, normals_arr.ravel(order="F"), offsets_arr.ravel(order="F")])
        w0 = self._initial_guess(x0, ref, u_hover, elapsed_s)
        args = {"x0": w0, "p": params, "lbx": self._lbx, "ubx": self._ubx, "lbg": self._lbg, "ubg": self._ubg}
        if self._lam_x is not None:
            args.update(lam_x0=self._lam_x, lam_g0=self._lam_g)
        t0 = time.perf_counter()
        try:
            sol = self._solver(**args)
            stats = self._solver.stats()
            w = np.asarray(sol["x"]).ravel()
            success = bool(stats.get("success", False)) and bool(np.all(np.isfinite(w)))
            status = str(stats.get("return_status", "unknown"))
            iterations = int(stats.get("iter_count", -1))
        except RuntimeError as exc:   # a solver that raises is a failed solve like any other
            sol, success, iterations = None, False, -1
            status = "solver_error: " + str(exc).strip().splitlines()[-1][:160]
        solve_time = time.perf_counter() - t0
        self.n_solves += 1
        if success:
            self._w, self._lam_x, self._lam_g = w, np.asarray(sol["lam_x"]).ravel(), np.asarray(sol["lam_g"]).ravel()
            self._plan_age_s = 0.0
            u = w[self.nx:self.nx + n]
            fallback = False
        else:
            self.n_failures += 1
            self._plan_age_s += elapsed_s
            fallback = True
            u, status = self._fallback_input(u_hover, status)
        self._last_u = u
        pred = self._predicted_states()
        slack = self._w[[k * self._stage_len + self.nx + n for k in range(big_n)]] if self._w is not None else [0.0]
        return MPCSolution(self.rotor_speeds(u), success, status, iterations, solve_time, fallback, pred,
                           float(np.max(slack)))

    def _fallback_input(self, u_hover: np.ndarray, status: str) -> tuple[np.ndarray, str]:
        """The shifted previous plan's input while it still covers now, else hover trim."""
        if self._w is not None and self._plan_age_s < self.config.step_s * (self.config.horizon_steps - 1):
            k = int(self._plan_age_s / self.config.step_s)
            start = k * self._stage_len + self.nx
            return self._w[start:start + self.n_v].copy(), f"fallback_shifted({status})"
        return u_hover.copy(), f"fallback_hover({status})"

    def _predicted_states(self) -> np.ndarray:
        big_n = self.config.horizon_steps
        if self._w is None:
            return np.zeros((big_n + 1, 13))
        xs = [self._w[k * self._stage_len:k * self._stage_len + 13] for k in range(big_n)]
        xs.append(self._w[big_n * self._stage_len:big_n * self._stage_len + 13])
        return np.array(xs)


def _nlp_functions_c(solver: ca.Function) -> bytes:
    """The C source of an nlpsol's functions (objective, constraints and their derivatives).

    CasADi writes it only relative to the working directory (a path is rejected), and changing this
    process's directory would move it under every other thread: a child process loads the serialized
    solver and writes the file in a temporary folder (the same bytes; it runs once per cache miss).
    """
    with tempfile.TemporaryDirectory(prefix="uam_mpc_") as tmp:
        solver.save(str(Path(tmp, "solver.casadi")))
        code = "import casadi; casadi.Function.load('solver.casadi').generate_dependencies('mpc_nlp.c')"
        r = subprocess.run([sys.executable, "-c", code], cwd=tmp, capture_output=True, text=True, timeout=600)
        out = Path(tmp, "mpc_nlp.c")
        if r.returncode != 0 or not out.is_file():
            raise RuntimeError(f"generating the MPC's C code failed: {r.stderr.strip()[-500:]}")
        return out.read_bytes()
