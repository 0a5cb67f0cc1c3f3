"""Real-time iteration (RTI) for the tracking OCP: Gauss-Newton SQP steps on a structured QP.

Each decision linearises the OCP (`planners.mpc_ocp`) at the warm start (the previous solution,
shifted by the time elapsed), builds the QP in the step Δw

    min  ½ Δwᵀ H Δw + ∇fᵀ Δw       H = 2 JᵣᵀJᵣ (Gauss-Newton, block diagonal per stage, PSD)
    s.t. lbg − g(w) ≤ J_g Δw ≤ ubg − g(w),   lbx − w ≤ Δw ≤ ubx − w,

solves it with a QP solver from the casadi wheel and takes the full step (Diehl et al., "Real-time
optimization for large scale nonlinear processes", 2001; acados' SQP_RTI). One step per decision is
the RTI proper; more steps converge to the same KKT point as the NLP solvers, since the gradient is
exact and only the Hessian is approximated.

The QP's functions (H, ∇f, J_g, g) are one CasADi Function of (w, p) whose derivatives are those of
the per-stage model Functions, so its generated C stays small (one stage's code, called N times).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from planners.mpc_ocp import TrackingOcp

QP_SOLVERS = ("hpipm", "fatrop", "qrqp", "osqp")


def qp_data_function(ocp: TrackingOcp) -> ca.Function:
    """(w, p) -> (H, ∇f, J_g, g) of the Gauss-Newton QP at w (module docstring)."""
    return ca.Function("mpc_qp_data", [ocp.w, ocp.p], [ocp.gn_hessian, ocp.gradient, ocp.jacobian, ocp.g],
                       ["w", "p"], ["H", "grad", "J", "g"])


def qp_solver_options(ocp: TrackingOcp, qp_solver: str) -> dict:
    """Options of `casadi.conic` for the RTI's QP: the stage structure where the solver needs it."""
    lay = ocp.layout
    n = lay.n_stages
    if qp_solver == "hpipm":
        # The layout is given rather than detected: nx, nu per stage, path rows per stage (gap rows
        # excluded). The interface boxes every variable, an infinite bound becoming ±`inf`: at the
        # default 1e8 the interior point stalled at its iteration cap on converged solutions (its
        # residuals scale with the bounds); 1e4 is far outside any step in these units (m, m/s, rad).
        return {"N": n, "nx": [lay.nx] * (n + 1), "nu": [lay.nu] * n + [0], "ng": list(ocp.path_rows),
                "inf": 1e4, "error_on_fail": False, "hpipm": {"mode": "speed", "iter_max": 50}}
    if qp_solver == "fatrop":
        return {"structure_detection": "manual", "N": n, "nx": [lay.nx] * (n + 1), "nu": [lay.nu] * n + [0],
                "ng": list(ocp.path_rows), "error_on_fail": False, "fatrop": {"print_level": 0}}
    if qp_solver == "qrqp":
        return {"error_on_fail": False, "print_iter": False, "print_header": False, "print_info": False}
    if qp_solver == "osqp":
        return {"error_on_fail": False, "osqp": {"verbose": False, "eps_abs": 1e-6, "eps_rel": 1e-6,
                                                 "max_iter": 4000, "polish": True}}
    raise ValueError(f"RTI QP solver must be one of {QP_SOLVERS}, got {qp_solver!r}")


class GaussNewtonRTI:
    """Gauss-Newton SQP on the tracking OCP, called like an `nlpsol` Function.

    Args:
        ocp: the tracking problem.
        qp_data: `qp_data_function(ocp)` or its compiled twin (same signature).
        qp_solver: a `casadi.conic` plugin from `QP_SOLVERS`.
        iterations: SQP steps per call (1: real-time iteration).
        step_tol: stop early once the largest step component is below this (scaled units).
    """

    def __init__(self, ocp: TrackingOcp, qp_data: ca.Function, qp_solver: str = "hpipm", iterations: int = 1,
                 step_tol: float = 1e-6) -> None:
        if iterations < 1:
            raise ValueError(f"RTI needs at least one iteration, got {iterations}")
        self._qp_data = qp_data
        sparsity = {"h": qp_data.sparsity_out("H"), "a": qp_data.sparsity_out("J")}
        self._qp = ca.conic("mpc_qp", qp_solver, sparsity, qp_solver_options(ocp, qp_solver))
        self.qp_solver = qp_solver
        self.iterations = iterations
        self.step_tol = step_tol
        self._stats: dict = {}

    def __call__(self, x0: np.ndarray, p: np.ndarray, lbx: np.ndarray, ubx: np.ndarray, lbg: np.ndarray,
                 ubg: np.ndarray, lam_x0: np.ndarray | None = None, lam_g0: np.ndarray | None = None) -> dict:
        """Take up to `iterations` full Gauss-Newton steps from x0 (the multiplier guesses are unused).

        Returns:
            {"x", "lam_x", "lam_g"} like `nlpsol` (the multipliers of the last QP); `stats()` tells
            success (every QP solved), the QP's return status, SQP steps and QP iterations.
        """
        w = np.asarray(x0, float)
        qp_iterations, status, success, sol = 0, "not_run", True, None
        for it in range(self.iterations):
            hess, grad, jac, g = self._qp_data(w, p)
            g = np.asarray(g).ravel()
            sol = self._qp(h=hess, g=grad, a=jac, lba=lbg - g, uba=ubg - g, lbx=lbx - w, ubx=ubx - w)
            stats = self._qp.stats()
            qp_iterations += int(stats.get("iter_count", 0))
            status = str(stats.get("return_status", "unknown"))
            step = np.asarray(sol["x"]).ravel()
            if not stats.get("success", False) or not np.all(np.isfinite(step)):
                success = False
                break
            w = w + step
            if np.max(np.abs(step)) < self.step_tol:
                break
        self._stats = {"success": success, "return_status": status, "iter_count": it + 1,
                       "qp_iter_count": qp_iterations}
        lam_x = np.asarray(sol["lam_x"]).ravel() if sol is not None else np.zeros_like(w)
        lam_g = np.asarray(sol["lam_a"]).ravel() if sol is not None else np.zeros_like(lbg)
        return {"x": w, "lam_x": lam_x, "lam_g": lam_g}

    def stats(self) -> dict:
        """Statistics of the last call (keys as `nlpsol` stats: success, return_status, iter_count)."""
        return dict(self._stats)
