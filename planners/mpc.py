"""Nonlinear MPC tracker: reference (position, velocity, heading) -> rotor-speed commands.

Built from the same CasADi expression as the simulator (`uam_fdm.vehicle.model.dynamics_expr`), with two
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

Formulation (multiple shooting, one RK4 step per interval, inputs scaled by the hover speed; the
stage-wise layout and the reasons for it are in `planners.mpc_ocp`):

    min  Σ_k  w_p|p_k − p_ref,k|² + w_v|v_k − v_ref,k|² + w_tilt(q_x² + q_y²) + w_yaw|b1_xy − ψ_ref|²
              + w_ω|ω_k|² + w_u|u_k − u_hover|² + w_du|u_k − u_k−1|² + w_s1 s_k + w_s2 s_k²
         + terminal position/velocity terms
    s.t. x_0 = x_measured, x_k+1 = RK4(x_k, u_k), u_min ≤ u_k ≤ u_max, s_k ≥ 0,
         tilt(x_k) within the vehicle's max tilt (an inscribed 16-gon, k = 1 .. N−1),
         n_kj · p_k ≥ c_kj − s_k,  k = 1 .. N−1             (soft clearance half-spaces)

The clearance half-spaces are parameters: for each stage, the nearest buildings to the previous
prediction give a plane through the nearest point, facing the vehicle, offset by the collision
radius plus a margin (computed by the pilot from the city; inactive ones are 0 ≥ −1).

Solvers: ``"rti"`` (the default), the real-time iteration of `planners.rti`: one Gauss-Newton SQP
step per decision on the stage-structured QP, solved by HPIPM; or the NLP solvers ipopt (the
reference it is tested against), fatrop (structure-exploiting interior point) and sqpmethod. Their
functions are generated as C, compiled once and cached on disk (`uam_fdm.vehicle.codegen`); without a
compiler they run on CasADi's virtual machine.
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
from typing import Any

import casadi as ca
import numpy as np

from planners.hpipm_step import compile_with_driver
from planners.mpc_ocp import MPCWeights, OcpLayout, PredictionModel, build_tracking_ocp, pack_parameters
from planners.rti import QP_SOLVERS, GaussNewtonRTI, merit_data_function, qp_data_function
from uam_fdm.vehicle.codegen import compile_source
from uam_fdm.vehicle.model import FAR_FROM_SURFACES_M, make_env
from uam_fdm.vehicle.params import VehicleParams

log = logging.getLogger(__name__)

SOLVERS = ("sqpmethod", "ipopt", "fatrop", "rti")
__all__ = ["MPCConfig", "MPCSolution", "MPCTracker", "MPCWeights", "SOLVERS"]


@dataclass(frozen=True)
class MPCConfig:
    """MPC settings.

    Attributes:
        horizon_steps: shooting intervals N; None: 15 with rotor inputs (0.75 s for the quad; chosen
            when Ipopt was the solver: 5.9 ms median, 20 steps took 7.2 ms), 20 with wrench inputs
            (3 s for the UAM).
        step_s: interval length [s] (one RK4 step each); None: max(0.05 s, 1.25 τ_m), so the horizon
            spans the vehicle's attitude response (quad 0.05 s → 1 s; UAM 0.15 s → 3 s: with a 1 s
            horizon the UAM tilts hard and cannot recover its attitude within the horizon).
        solver: "rti" (default: the real-time iteration, chosen by measurement in
            perf/classical.py: quad 0.43 ms median, UAM 1.24 ms, 14.9x and 27.8x faster than
            Ipopt, tracking RMS within 1 % of Ipopt's, no failures; docs/planner.md),
            "ipopt" (the reference), "fatrop" or "sqpmethod" (module docstring; docs/planner.md).
        qp_solver: QP solver of "rti" (one of `planners.rti.QP_SOLVERS`: "hpipm" is HPIPM called from C,
            falling back to casadi.conic's plugin "hpipm_conic" when that cannot be built; `qp_solver`
            tells which runs) or of "sqpmethod" ("qrqp"; "osqp"/"proxqp" need a convex QP); None:
            "hpipm" for rti, "qrqp" for sqpmethod.
        max_iterations: NLP solver iteration cap per decision.
        rti_iterations: Gauss-Newton steps per decision of "rti" (1: the real-time iteration, a full
            step; more: steps damped by a line search, converging to the NLP's solution).
        rti_cold_iterations: Gauss-Newton steps (line-searched) of "rti" when there is no previous
            solution to start from (the first decision after `reset`: an episode start, a replan).
        n_halfspaces: clearance half-spaces per stage.
        clearance_margin_m: margin added to the collision radius in the half-spaces [m].
        input_mode: "rotors" or "wrench" (None: rotors for 4 rotors, wrench above; module docstring).
        motor_lag: keep the motor lag in the prediction (None: automatic, see the module docstring).
        tilt_constraint: constrain the tilt to the vehicle's max_tilt_deg at every stage. Without it
            the slow UAM tilts beyond what it can recover from, and the quad's solver fails on hard
            cases (a step target behind a wall: 100 iterations without convergence, vs 8 with it).
        compiled: compile the solver's functions (None: when a compiler exists).
        opt_level: optimisation flag for the generated code (-O1: 5x faster solves than the VM for a
            ~30 s one-off compile; -O2/-O3 compile far longer for little gain).
    """

    horizon_steps: int | None = None
    step_s: float | None = None
    solver: str = "rti"
    qp_solver: str | None = None
    max_iterations: int = 200
    rti_iterations: int = 1
    rti_cold_iterations: int = 5
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
        if self.solver == "rti" and self.qp_solver not in (None, *QP_SOLVERS):
            raise ValueError(f"the RTI's QP solver must be one of {QP_SOLVERS}, got {self.qp_solver!r}")
        if self.input_mode not in (None, "rotors", "wrench"):
            raise ValueError(f"input_mode must be None, 'rotors' or 'wrench', got {self.input_mode!r}")
        if ((self.horizon_steps is not None and self.horizon_steps < 2)
                or (self.step_s is not None and self.step_s <= 0) or self.max_iterations < 1
                or self.rti_iterations < 1 or self.rti_cold_iterations < 1 or self.n_halfspaces < 0):
            raise ValueError(f"invalid MPC config {self}")


@dataclass(frozen=True)
class MPCSolution:
    """One MPC decision.

    Attributes:
        rotor_speeds_rad_s: the command to apply now (n,).
        success: the solver reported success.
        status: the solver's return status (or "fallback_shifted(...)" / "fallback_hover(...)").
        iterations: solver iterations (SQP steps for "rti").
        solve_time_s: wall time of the solve [s].
        fallback: the command came from the shifted previous plan or hover, not this solve.
        predicted_states: (N+1, 13) predicted [p, v, q, ω] (the previous plan's on fallback).
        max_slack_m: largest clearance slack used [m] (0 when every half-space holds).
        qp_iterations: iterations of the QP solver summed over the RTI's steps (-1 for NLP solvers).
        hover_trim: a fallback with no previous plan covering now: the command is hover trim, which holds no
            position or vertical speed (a pilot with a velocity autopilot under it may hand over to that instead).
    """

    rotor_speeds_rad_s: np.ndarray
    success: bool
    status: str
    iterations: int
    solve_time_s: float
    fallback: bool
    predicted_states: np.ndarray
    max_slack_m: float
    qp_iterations: int = -1
    hover_trim: bool = False


class MPCTracker:
    """Nonlinear MPC for one vehicle (see the module docstring).

    Args:
        params: the vehicle.
        config: MPC settings.
        cache_dir: cache for the compiled functions (default `uam_fdm.vehicle.codegen.default_cache_dir()`).
    """

    def __init__(self, params: VehicleParams, config: MPCConfig | None = None,
                 cache_dir: Path | None = None) -> None:
        self.params = params
        config = config if config is not None else MPCConfig()
        input_mode = config.input_mode or ("rotors" if params.n_rotors == 4 else "wrench")
        # the settings left to the vehicle, resolved; `self.config` holds them from here on
        step_s = config.step_s if config.step_s is not None else max(0.05, 1.25 * params.motor_time_constant_s)
        horizon_steps = (config.horizon_steps if config.horizon_steps is not None
                         else 15 if input_mode == "rotors" else 20)
        self._qp_solver = (config.qp_solver if config.qp_solver is not None
                           else "hpipm" if config.solver == "rti" else "qrqp")
        config = dataclasses.replace(config, step_s=step_s, horizon_steps=horizon_steps, qp_solver=self._qp_solver)
        self.config = config
        motor_lag = (params.motor_time_constant_s >= step_s / 2.5
                     if config.motor_lag is None else config.motor_lag)
        self.model = PredictionModel(params, input_mode, motor_lag, step_s)
        self.solver_name = config.solver
        max_tilt = np.radians(params.controller.max_tilt_deg) if config.tilt_constraint else None
        self.ocp = build_tracking_ocp(self.model, config.weights, horizon_steps, config.n_halfspaces,
                                      max_tilt)
        self.layout: OcpLayout = self.ocp.layout
        self._solver, self.backend = self._make_solver(cache_dir)
        self.reset()

    @property
    def qp_solver(self) -> str | None:
        """The QP solver that runs: the RTI's ("hpipm" called from C, or a casadi.conic plugin when that
        could not be built) or sqpmethod's; None for the interior-point NLP solvers."""
        if isinstance(self._solver, GaussNewtonRTI):
            return self._solver.qp_solver
        return self._qp_solver if self.solver_name == "sqpmethod" else None

    @property
    def input_mode(self) -> str:
        return self.model.input_mode

    @property
    def step_s(self) -> float:
        """Shooting interval [s] (`MPCConfig.step_s`, resolved)."""
        return self.model.step_s

    @property
    def horizon_steps(self) -> int:
        """Shooting intervals N (`MPCConfig.horizon_steps`, resolved)."""
        return self.layout.n_stages

    @property
    def motor_lag(self) -> bool:
        return self.model.motor_lag

    def hover_input(self, density_ratio: float) -> np.ndarray:
        """MPC input coordinates of hover at density ratio σ."""
        return self.model.hover_input(density_ratio)

    def rotor_speeds(self, v: np.ndarray) -> np.ndarray:
        """Rotor-speed command [rad/s] (n,) for MPC input v, within the rotor limits."""
        return self.model.rotor_speeds(v)

    # -- construction ---------------------------------------------------------------------------
    def _nlp_options(self) -> dict:
        cfg = self.config
        # Trial points of a line search may evaluate to inf; the solver rejects them itself, so
        # CasADi's per-evaluation warnings are noise (failures still show in the solve status).
        common = {"show_eval_warnings": False, "print_time": False, "error_on_fail": False}
        if self.solver_name == "sqpmethod":
            return {**common, "qpsol": cfg.qp_solver, "max_iter": cfg.max_iterations, "print_header": False,
                    "print_iteration": False, "print_status": False,
                    "qpsol_options": {"error_on_fail": False, **({"print_iter": False, "print_header": False}
                                                                 if cfg.qp_solver == "qrqp" else {})}}
        if self.solver_name == "ipopt":
            return {**common,
                    "ipopt": {"print_level": 0, "sb": "yes", "max_iter": cfg.max_iterations,
                              "warm_start_init_point": "yes", "mu_init": 1e-3,
                              # Keep a warm start where it is (defaults push it 1e-3 into the bounds).
                              "warm_start_bound_push": 1e-6, "warm_start_mult_bound_push": 1e-6,
                              "warm_start_slack_bound_push": 1e-6,
                              # 1e-6 on positions in metres is far below what the simulator resolves.
                              "tol": 1e-6, "acceptable_tol": 1e-4, "acceptable_iter": 3}}
        # fatrop: the stage structure is detected from the Jacobian's pattern and the equality rows.
        return {**common, "structure_detection": "auto", "equality": self.ocp.equality,
                "fatrop": {"print_level": 0, "max_iter": cfg.max_iterations, "tol": 1e-6, "mu_init": 1e-3}}

    def _make_solver(self, cache_dir: Path | None) -> tuple[ca.Function | GaussNewtonRTI, str]:
        cfg = self.config
        tag = f"mpc_{self.params.fingerprint()}_{self.solver_name}"
        flags = (cfg.opt_level, "-march=native")
        if self.solver_name == "rti":
            functions = [qp_data_function(self.ocp), merit_data_function(self.ocp)]
            backend, library = "vm", None
            if cfg.compiled is not False:
                gen = ca.CodeGenerator(f"{tag}.c", {"with_header": False})
                for f in functions:
                    gen.add(f)
                source = gen.dump().encode()
                # HPIPM called from C needs its headers and libraries (the casadi wheel's); else the
                # QP goes through casadi.conic (GaussNewtonRTI falls back and says so in qp_solver).
                lib = compile_with_driver(source, tag, cache_dir, flags) if self._qp_solver == "hpipm" else None
                library = lib
                if lib is None:
                    lib = compile_source(source, tag, cache_dir, opt_flags=flags)
                if lib is not None:
                    functions, backend = [ca.external(f.name(), str(lib)) for f in functions], "compiled"
                elif cfg.compiled:
                    raise RuntimeError("compiled=True but the MPC could not be compiled (see the log)")
            if backend == "vm":
                functions = [f.expand() for f in functions]
            qp_data, merit_data = functions
            return GaussNewtonRTI(self.ocp, qp_data, merit_data, self._qp_solver, cfg.rti_iterations,
                                  library=library), backend
        opts = self._nlp_options()
        nlp = self.ocp.nlp()
        if cfg.compiled is not False:
            source = _nlp_functions_c(ca.nlpsol("mpc", self.solver_name, nlp, opts))
            lib = compile_source(source, tag, cache_dir, opt_flags=flags)
            if lib is not None:
                return ca.nlpsol("mpc", self.solver_name, str(lib), opts), "compiled"
            if cfg.compiled:
                raise RuntimeError("compiled=True but the MPC could not be compiled (see the log)")
        return ca.nlpsol("mpc", self.solver_name, nlp, {**opts, "expand": True}), "vm"

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

    def _initial_guess(self, x0: np.ndarray, u_hover: np.ndarray, shift_s: float) -> np.ndarray:
        lay = self.layout
        n = lay.n_stages
        if self._w is None:
            # Cold start: the current state held over the horizon. Unlike the reference, it satisfies
            # the clearance half-spaces (a reference may run through a wall the MPC must respect).
            return lay.pack(np.tile(x0, (n + 1, 1)), np.tile(u_hover, (n, 1)), np.zeros(n))
        # Shift the previous solution forward by the time elapsed (linear interpolation between stages).
        frac = min(shift_s / self.step_s, 1.0)
        xs, us = lay.states(self._w), lay.inputs(self._w)
        xs = (1 - frac) * xs + frac * np.vstack([xs[1:], xs[-1:]])
        us = (1 - frac) * us + frac * np.vstack([us[1:], us[-1:]])
        xs[0] = x0
        return lay.pack(xs, us, np.zeros(n))

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
        cfg, lay = self.config, self.layout
        u_hover = self.hover_input(density_ratio)
        u_prev = self._last_u if self._last_u is not None else u_hover
        # The initial state: the measured physical state and the input applied until now.
        x0 = np.concatenate([self.model.physical_state(x_full), u_prev])
        ref = np.vstack([np.asarray(ref_pos_m, float).T, np.asarray(ref_vel_m_s, float).T])
        env = make_env(density_ratio=density_ratio, height_above_surface_m=height_above_surface_m)
        params = pack_parameters(self.horizon_steps, cfg.n_halfspaces, ref, yaw_ref_rad, env, u_hover,
                                 normals, offsets)
        lbx, ubx = self.ocp.bounds(x0)
        args: dict[str, Any] = {"x0": self._initial_guess(x0, u_hover, elapsed_s), "p": params, "lbx": lbx, "ubx": ubx,
                "lbg": self.ocp.lbg, "ubg": self.ocp.ubg}
        if self._lam_x is not None:
            args.update(lam_x0=self._lam_x, lam_g0=self._lam_g)
        if self.solver_name == "rti" and self._w is None:   # no previous solution to iterate in real time
            args["iterations"] = max(cfg.rti_iterations, cfg.rti_cold_iterations)
        t0 = time.perf_counter()
        try:
            sol = self._solver(**args)
            stats = self._solver.stats()
            w = np.asarray(sol["x"]).ravel()
            success = bool(stats.get("success", False)) and bool(np.all(np.isfinite(w)))
            status = str(stats.get("return_status", "unknown"))
            iterations = int(stats.get("iter_count", -1))
            qp_iterations = int(stats.get("qp_iter_count", -1))
        except RuntimeError as exc:   # a solver that raises is a failed solve like any other
            success, iterations, qp_iterations = False, -1, -1
            status = "solver_error: " + str(exc).strip().splitlines()[-1][:160]
        solve_time = time.perf_counter() - t0
        self.n_solves += 1
        if success:
            self._w = w
            self._lam_x, self._lam_g = np.asarray(sol["lam_x"]).ravel(), np.asarray(sol["lam_g"]).ravel()
            self._plan_age_s = 0.0
            u = lay.inputs(w)[0].copy()
            fallback = hover_trim = False
        else:
            self.n_failures += 1
            self._plan_age_s += elapsed_s
            fallback = True
            u, status, hover_trim = self._fallback_input(u_hover, status)
        self._last_u = u
        pred = lay.states(self._w)[:, :13] if self._w is not None else np.zeros((lay.n_stages + 1, 13))
        slack = float(np.max(lay.slacks(self._w))) if self._w is not None else 0.0
        return MPCSolution(self.rotor_speeds(u), success, status, iterations, solve_time, fallback, pred,
                           slack, qp_iterations, hover_trim)

    def _fallback_input(self, u_hover: np.ndarray, status: str) -> tuple[np.ndarray, str, bool]:
        """The shifted previous plan's input while it still covers now, else hover trim; and whether hover trim."""
        if self._w is not None and self._plan_age_s < self.step_s * (self.horizon_steps - 1):
            k = int(self._plan_age_s / self.step_s)
            return self.layout.inputs(self._w)[k].copy(), f"fallback_shifted({status})", False
        return u_hover.copy(), f"fallback_hover({status})", True


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
