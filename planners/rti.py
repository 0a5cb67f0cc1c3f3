"""Real-time iteration (RTI) for the tracking OCP: Gauss-Newton SQP steps on a structured QP.

Each decision linearises the OCP (`planners.mpc_ocp`) at the warm start (the previous solution,
shifted by the time elapsed), builds the QP in the step Δw

    min  ½ Δwᵀ H Δw + ∇fᵀ Δw       H = 2 JᵣᵀJᵣ (Gauss-Newton, block diagonal per stage, PSD)
    s.t. lbg − g(w) ≤ J_g Δw ≤ ubg − g(w),   lbx − w ≤ Δw ≤ ubx − w,

solves it with HPIPM and takes the full step (Diehl
et al., "Real-time optimization for large scale nonlinear processes", 2001; acados' SQP_RTI). One step
per decision is the RTI proper. More steps per call (`iterations` > 1) make a Gauss-Newton SQP whose
fixed points are the NLP's KKT points (the gradient is exact, only the Hessian approximated); those
steps are damped by a backtracking line search on the ℓ1 merit f + μ‖constraint violation‖₁, since
full Gauss-Newton steps can cycle when the residuals are large (measured: a 2 m step target from
hover for the quad, a 2-cycle with a 0.4 rad/s gap violation).

The QP's functions (H, ∇f, J_g, g) are one CasADi Function of (w, p) whose derivatives are those of
the per-stage model Functions, so its generated C stays small (one stage's code, called N times).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from planners.hpipm_step import HpipmOptions, HpipmStep
from planners.mpc_ocp import TrackingOcp

# HPIPM: a Riccati-based interior point for the stage structure (the default), called from C
# ("hpipm") or through casadi.conic's plugin ("hpipm_conic": 2.0-2.5x slower per decision, data
# included, docs/planner.md); qrqp (CasADi's sparse active set) and osqp (ADMM) solve the same QP more
# slowly still (measured 25 ms and 6 ms against HPIPM's 1.4 ms through casadi.conic on the quad's QP,
# VM, loaded machine). The wheel's fatrop QP interface failed on it (and prints).
QP_SOLVERS = ("hpipm", "hpipm_conic", "qrqp", "osqp")
# HPIPM called directly: "speed_abs" for one step per decision (as the conic's below), "balance" for
# converging steps. mu0 = 100 took the fewest iterations on the UAM's closed-loop QPs (4 against 5 at
# HPIPM's default), the same on the quad's.
DIRECT_OPTIONS = HpipmOptions(mode="speed_abs", mu0=1e2)
DIRECT_ACCURATE_OPTIONS = HpipmOptions(mode="balance", mu0=1e2)
# HPIPM's return flags (hpipm_common.h), reported as readable statuses.
HPIPM_STATUS = {0: "success", 1: "max_iterations", 2: "min_step_length", 3: "nan_solution",
                4: "inconsistent_equality"}


def qp_data_function(ocp: TrackingOcp) -> ca.Function:
    """(w, p) -> (H, ∇f, J_g, g, f) of the Gauss-Newton QP at w (module docstring)."""
    return ca.Function("mpc_qp_data", [ocp.w, ocp.p],
                       [ocp.gn_hessian, ocp.gradient, ocp.jacobian, ocp.g, ocp.nlp()["f"]],
                       ["w", "p"], ["H", "grad", "J", "g", "f"])


def merit_data_function(ocp: TrackingOcp) -> ca.Function:
    """(w, p) -> (f, g): what the line search of `GaussNewtonRTI` evaluates at trial points."""
    nlp = ocp.nlp()
    return ca.Function("mpc_merit_data", [ocp.w, ocp.p], [nlp["f"], nlp["g"]], ["w", "p"], ["f", "g"])


def _violation(g: np.ndarray, lbg: np.ndarray, ubg: np.ndarray) -> float:
    """ℓ1 norm of the constraint violation."""
    return float(np.sum(np.maximum(lbg - g, 0.0)) + np.sum(np.maximum(g - ubg, 0.0)))


def qp_solver_options(ocp: TrackingOcp, qp_solver: str, accurate: bool = False) -> dict:
    """Options of `casadi.conic` for the RTI's QP: the stage structure where the solver needs it.

    `accurate`: for several SQP steps per call, which converge only on accurately solved QPs.
    """
    lay = ocp.layout
    n = lay.n_stages
    if qp_solver == "hpipm_conic":
        # The layout is given rather than detected: nx, nu per stage, path rows per stage (gap rows
        # excluded). The interface boxes every variable, an infinite bound becoming ±`inf`: at the
        # default 1e8 the interior point stalled at its iteration cap on converged solutions (its
        # residuals scale with the bounds); 1e4 is far outside any step in these units (m, m/s, rad).
        # Mode "speed_abs" (a test on the barrier parameter only) took the fewest iterations in closed
        # loop (quad circle/wall median 4/8, "balance" 5/10; UAM 11/13 against 14/16) without failures
        # and at the same tracking error, but its solutions are too rough for SQP steps to converge
        # on (a fixed problem stalled 0.24 rad/s from Ipopt's solution after 40 steps): a solver
        # configured for several steps per call uses "balance". "speed" hit its iteration cap on UAM
        # QPs that were already solved.
        mode = "balance" if accurate else "speed_abs"
        return {"N": n, "nx": [lay.nx] * (n + 1), "nu": [lay.nu] * n + [0], "ng": list(ocp.path_rows),
                "inf": 1e4, "error_on_fail": False, "hpipm": {"mode": mode, "iter_max": 50}}
    if qp_solver == "qrqp":
        return {"error_on_fail": False, "print_iter": False, "print_header": False, "print_info": False}
    if qp_solver == "osqp":
        return {"error_on_fail": False, "osqp": {"verbose": False, "eps_abs": 1e-6, "eps_rel": 1e-6,
                                                 "max_iter": 4000, "polish": True}}
    raise ValueError(f"RTI QP solver must be one of {QP_SOLVERS}, got {qp_solver!r}")


@dataclass(frozen=True)
class _QpResult:
    """One Gauss-Newton QP at an iterate: its step and what the line search needs."""

    step: np.ndarray
    lam_g: np.ndarray
    lam_x: np.ndarray
    g: np.ndarray
    grad: np.ndarray
    f: float
    status: str
    iterations: int
    success: bool


class GaussNewtonRTI:
    """Gauss-Newton SQP on the tracking OCP, called like an `nlpsol` Function.

    Args:
        ocp: the tracking problem.
        qp_data: `qp_data_function(ocp)` or its compiled twin (same signature).
        merit_data: `merit_data_function(ocp)` or its compiled twin (used when iterations > 1).
        qp_solver: one of `QP_SOLVERS`. "hpipm" needs `library`; without it the QP goes through
            casadi.conic's HPIPM plugin and `qp_solver` reads "hpipm_conic".
        iterations: SQP steps per call (1: real-time iteration, full step).
        step_tol: stop early once the largest step component is below this (scaled units).
        library: the shared library of qp_data's generated C with `planners.hpipm_step`'s driver.
    """

    def __init__(self, ocp: TrackingOcp, qp_data: ca.Function, merit_data: ca.Function, qp_solver: str = "hpipm",
                 iterations: int = 1, step_tol: float = 1e-6, library: Path | None = None) -> None:
        if iterations < 1:
            raise ValueError(f"RTI needs at least one iteration, got {iterations}")
        if qp_solver not in QP_SOLVERS:
            raise ValueError(f"RTI QP solver must be one of {QP_SOLVERS}, got {qp_solver!r}")
        if qp_solver == "hpipm" and library is None:
            qp_solver = "hpipm_conic"
        self._qp_data = qp_data
        self._merit_data = merit_data
        self.qp_solver = qp_solver
        if qp_solver == "hpipm":
            assert library is not None
            self._direct = HpipmStep(ocp, qp_data, library, DIRECT_OPTIONS)
            self._direct_accurate = HpipmStep(ocp, qp_data, library, DIRECT_ACCURATE_OPTIONS)
        else:
            sparsity = {"h": qp_data.sparsity_out("H"), "a": qp_data.sparsity_out("J")}
            plugin = "hpipm" if qp_solver == "hpipm_conic" else qp_solver
            self._qp = ca.conic("mpc_qp", plugin, sparsity, qp_solver_options(ocp, qp_solver))
            self._qp_accurate = ca.conic("mpc_qp_accurate", plugin, sparsity,
                                         qp_solver_options(ocp, qp_solver, accurate=True))
        self.iterations = iterations
        self.step_tol = step_tol
        self._stats: dict = {}

    def _solve_qp(self, w: np.ndarray, p: np.ndarray, lbx: np.ndarray, ubx: np.ndarray, lbg: np.ndarray,
                  ubg: np.ndarray, accurate: bool) -> _QpResult:
        """The QP at w, by the configured solver (the direct call returns no bound multipliers: zeros)."""
        if self.qp_solver == "hpipm":
            q = (self._direct_accurate if accurate else self._direct)(w, p, lbx, ubx)
            ok = q.status == 0 and bool(np.all(np.isfinite(q.step)))
            return _QpResult(q.step, q.lam_g, np.zeros_like(w), q.g, q.grad, q.f,
                             HPIPM_STATUS.get(q.status, f"hpipm_{q.status}"), q.iterations, ok)
        hess, grad, jac, g, f = self._qp_data(w, p)
        g = np.asarray(g).ravel()
        qp = self._qp_accurate if accurate else self._qp
        sol = qp(h=hess, g=grad, a=jac, lba=lbg - g, uba=ubg - g, lbx=lbx - w, ubx=ubx - w)
        stats = qp.stats()
        status = stats.get("return_status", "unknown")
        status = (HPIPM_STATUS.get(status, f"hpipm_{status}") if self.qp_solver == "hpipm_conic" else str(status))
        step = np.asarray(sol["x"]).ravel()
        ok = bool(stats.get("success", False)) and bool(np.all(np.isfinite(step)))
        return _QpResult(step, np.asarray(sol["lam_a"]).ravel(), np.asarray(sol["lam_x"]).ravel(), g,
                         np.asarray(grad).ravel(), float(f), status, int(stats.get("iter_count", 0)), ok)

    def __call__(self, x0: np.ndarray, p: np.ndarray, lbx: np.ndarray, ubx: np.ndarray, lbg: np.ndarray,
                 ubg: np.ndarray, lam_x0: np.ndarray | None = None, lam_g0: np.ndarray | None = None,
                 iterations: int | None = None) -> dict:
        """Take up to `iterations` (default: the constructor's) Gauss-Newton steps from x0 (the
        multiplier guesses are unused).

        Returns:
            {"x", "lam_x", "lam_g"} like `nlpsol` (the multipliers of the last QP); `stats()` tells
            success (every QP solved), the QP's return status, SQP steps and QP iterations.
        """
        w = np.asarray(x0, float)
        p = np.asarray(p, float)
        n_steps = self.iterations if iterations is None else iterations
        # Accurate QPs when configured to converge (several steps per decision); a cold start's few
        # extra steps only need a good first control, and the rough QPs are half as costly.
        accurate = self.iterations > 1
        qp_iterations, status, success, last, penalty = 0, "not_run", True, None, 0.0
        for it in range(n_steps):  # noqa: B007 (read after the loop: the steps taken)
            q = self._solve_qp(w, p, lbx, ubx, lbg, ubg, accurate)
            qp_iterations += q.iterations
            status = q.status
            if not q.success:
                success = False
                break
            last = q
            alpha = 1.0
            if n_steps > 1:
                # ℓ1 merit with a penalty above the multipliers; the QP step satisfies the linearised
                # constraints, so the merit's directional derivative is ∇fᵀΔw − μ‖violation‖₁.
                penalty = max(penalty, 1.1 * float(np.max(np.abs(q.lam_g), initial=0.0)))
                violation = _violation(q.g, lbg, ubg)
                merit = q.f + penalty * violation
                slope = float(np.dot(q.grad, q.step)) - penalty * violation
                alpha = self._line_search(w, q.step, p, lbg, ubg, penalty, merit, slope)
            w = w + alpha * q.step
            if alpha * np.max(np.abs(q.step)) < self.step_tol:
                break
        self._stats = {"success": success, "return_status": status, "iter_count": it + 1,
                       "qp_iter_count": qp_iterations}
        lam_x = last.lam_x if last is not None else np.zeros_like(w)
        lam_g = last.lam_g if last is not None else np.zeros_like(lbg)
        return {"x": w, "lam_x": lam_x, "lam_g": lam_g}

    def _line_search(self, w: np.ndarray, step: np.ndarray, p: np.ndarray, lbg: np.ndarray, ubg: np.ndarray,
                     penalty: float, merit: float, slope: float) -> float:
        """Largest α in 1, ½, ¼, ... (at least 1/64) with Armijo decrease of the ℓ1 merit."""
        alpha = 1.0
        while alpha > 1.0 / 64:
            f, g = self._merit_data(w + alpha * step, p)
            trial = float(f) + penalty * _violation(np.asarray(g).ravel(), lbg, ubg)
            if trial <= merit + 1e-4 * alpha * min(slope, 0.0):
                break
            alpha *= 0.5
        return alpha

    def stats(self) -> dict:
        """Statistics of the last call (keys as `nlpsol` stats: success, return_status, iter_count)."""
        return dict(self._stats)
