"""The real-time iteration's QP handed to HPIPM directly: data and solve in one C call.

`planners/hpipm_step.c` is appended to the generated C of the QP's data Function and compiled
against the HPIPM and BLASFEO that ship in the casadi wheel (its headers and libraries). Python
fixes, once, where each nonzero of the data goes in HPIPM's stage blocks (`scatter_maps`); each
call then evaluates and solves in C, with memory allocated at creation. casadi.conic's HPIPM
plugin, which `planners.rti` keeps as "hpipm_conic", allocates and projects on every call and
boxes every variable (±`inf` where unbounded); measured on the quad's QPs that cost 0.2 ms of a
0.7 ms solve, and on the UAM's 0.55 ms of one iteration (docs/planner.md).
"""
from __future__ import annotations

import ctypes
import weakref
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import casadi as ca
import numpy as np

from planners.mpc_ocp import TrackingOcp
from uam_fdm.vehicle.codegen import compile_source

# HPIPM's modes (hpipm_common.h: enum hpipm_mode).
HPIPM_MODES = {"speed_abs": 0, "speed": 1, "balance": 2, "robust": 3}
# Block kinds per stage, in the order of the C driver's offsets (A, B, Q, S, R, C, D).
_BLOCKS = ("A", "B", "Q", "S", "R", "C", "D")
_I32 = np.int32


def driver_source() -> bytes:
    """The C driver, appended to the generated code of the QP's data Function `mpc_qp_data`."""
    return resources.files("planners").joinpath("hpipm_step.c").read_bytes()


def hpipm_build_args() -> tuple[str, ...] | None:
    """Compiler arguments for HPIPM's headers and libraries in the casadi wheel, or None when the
    wheel lacks them (the RTI then uses casadi.conic's plugin)."""
    root = Path(ca.__file__).parent
    if not (root / "include" / "hpipm_d_ocp_qp_ipm.h").is_file() or not (root / "libhpipm.so").exists():
        return None
    return (f"-I{root / 'include'}", f"-L{root}", f"-Wl,-rpath,{root}", "-lhpipm", "-lblasfeo")


def compile_with_driver(source: bytes, name: str, cache_dir: Path | None,
                        opt_flags: tuple[str, ...]) -> Path | None:
    """Compile generated C that defines `mpc_qp_data` together with the driver, linked to the wheel's
    HPIPM; None when the wheel lacks HPIPM's headers or the build fails (logged)."""
    build = hpipm_build_args()
    if build is None:
        return None
    return compile_source(source + driver_source(), f"{name}_hpipm", cache_dir, opt_flags=opt_flags, link_args=build)


@dataclass(frozen=True)
class HpipmOptions:
    """HPIPM's interior-point settings (hpipm_d_ocp_qp_ipm.h).

    Attributes:
        mode: "speed_abs", "speed", "balance" or "robust" (HPIPM's presets).
        iter_max: iteration cap.
        mu0: initial barrier parameter.
        tol: stationarity, equality, inequality and complementarity tolerance.
    """

    mode: str = "speed_abs"
    iter_max: int = 50
    mu0: float = 1e2
    tol: float = 1e-8

    def __post_init__(self) -> None:
        if self.mode not in HPIPM_MODES:
            raise ValueError(f"HPIPM mode must be one of {sorted(HPIPM_MODES)}, got {self.mode!r}")
        if self.iter_max < 1 or self.mu0 <= 0 or self.tol <= 0:
            raise ValueError(f"invalid HPIPM options {self}")


@dataclass(frozen=True)
class ScatterMaps:
    """Where the QP data's nonzeros go (indices into the driver's flat buffers; -1: not used).

    Attributes:
        offsets: (N+1, 7) start of each stage's A, B, Q, S, R, C, D (column-major blocks).
        n_blocks: length of the block buffer.
        h_dest: per Hessian nonzero (S from its input rows only; the transpose is not read).
        j_dest, j_sign: per Jacobian nonzero: A = −∂gap/∂x_k, B = −∂gap/∂u_k (gap rows read
            x_{k+1} − F), C, D from the path rows; the identity on x_{k+1} is dropped.
        g_dest: per constraint row: a path row's index into lg/ug, or −1 − index of a gap row into b.
        ng: path rows per stage (N+1).
        box_x, box_u: per stage, the state and input indices with a finite bound (x_0 excluded: fixed).
    """

    offsets: np.ndarray
    n_blocks: int
    h_dest: np.ndarray
    j_dest: np.ndarray
    j_sign: np.ndarray
    g_dest: np.ndarray
    ng: np.ndarray
    box_x: tuple[np.ndarray, ...]
    box_u: tuple[np.ndarray, ...]


def scatter_maps(ocp: TrackingOcp, h_sparsity: ca.Sparsity, j_sparsity: ca.Sparsity) -> ScatterMaps:
    """The maps of `ScatterMaps` for the OCP's layout and its QP data's sparsity patterns.

    Raises:
        ValueError: a nonzero outside the stage structure (a Hessian entry across stages, a gap row
            touching another interval), which HPIPM cannot represent.
    """
    lay = ocp.layout
    n, nx, nu, ln = lay.n_stages, lay.nx, lay.nu, lay.stage_len
    ng = np.asarray(ocp.path_rows, int)
    offsets = np.zeros((n + 1, len(_BLOCKS)), int)
    pos = 0
    for k in range(n + 1):
        nu_k = nu if k < n else 0   # stage N has no input (and no dynamics)
        sizes = {"A": nx * nx if k < n else 0, "B": nx * nu_k, "Q": nx * nx, "S": nu_k * nx, "R": nu_k * nu_k,
                 "C": int(ng[k]) * nx, "D": int(ng[k]) * nu_k}
        for b, name in enumerate(_BLOCKS):
            offsets[k, b] = pos
            pos += sizes[name]
    col_of = {name: b for b, name in enumerate(_BLOCKS)}

    def block(k: int, name: str, i: int, j: int, n_rows: int) -> int:
        return int(offsets[k, col_of[name]] + i + j * n_rows)

    # The Hessian: stage blocks only.
    h_rows, h_cols = h_sparsity.get_triplet()
    h_dest = np.full(len(h_rows), -1, int)
    for e, (r, c) in enumerate(zip(h_rows, h_cols)):
        kr, kc = r // ln, c // ln
        if kr != kc:
            raise ValueError(f"Hessian entry ({r}, {c}) couples stages {kr} and {kc}")
        i, j = r - kr * ln, c - kc * ln
        if i < nx and j < nx:
            h_dest[e] = block(kr, "Q", i, j, nx)
        elif i >= nx and j >= nx:
            h_dest[e] = block(kr, "R", i - nx, j - nx, nu)
        elif i >= nx:   # input row, state column: S (nu x nx)
            h_dest[e] = block(kr, "S", i - nx, j, nu)
    # The constraint rows: per interval k the gap rows (nx), then stage k's path rows.
    g_dest = np.zeros(ocp.g.size1(), int)
    row_stage: list[int] = []
    row_local: list[int] = []
    row_gap: list[bool] = []
    path = 0
    for k in range(n + 1):
        if k < n:
            g_dest[len(row_stage):len(row_stage) + nx] = -1 - (k * nx + np.arange(nx))
            row_stage += [k] * nx
            row_local += list(range(nx))
            row_gap += [True] * nx
        g_dest[len(row_stage):len(row_stage) + ng[k]] = path + np.arange(ng[k])
        row_stage += [k] * int(ng[k])
        row_local += list(range(int(ng[k])))
        row_gap += [False] * int(ng[k])
        path += int(ng[k])
    if len(row_stage) != ocp.g.size1():
        raise ValueError(f"{ocp.g.size1()} constraint rows, the stage structure accounts for {len(row_stage)}")
    j_rows, j_cols = j_sparsity.get_triplet()
    j_dest = np.full(len(j_rows), -1, int)
    j_sign = np.ones(len(j_rows))
    for e, (r, c) in enumerate(zip(j_rows, j_cols)):
        k, i = row_stage[r], row_local[r]
        kc, j = c // ln, c - (c // ln) * ln
        if row_gap[r]:
            if kc == k + 1 and j == i:   # the identity on x_{k+1}
                continue
            if kc != k:
                raise ValueError(f"gap row {r} of interval {k} touches stage {kc}")
            j_dest[e] = block(k, "A", i, j, nx) if j < nx else block(k, "B", i, j - nx, nx)
            j_sign[e] = -1.0
        else:
            if kc != k:
                raise ValueError(f"path row {r} of stage {k} touches stage {kc}")
            j_dest[e] = block(k, "C", i, j, int(ng[k])) if j < nx else block(k, "D", i, j - nx, int(ng[k]))
    finite = np.isfinite(ocp.lbx) | np.isfinite(ocp.ubx)
    box_x = tuple(np.zeros(0, int) if k == 0 else np.flatnonzero(finite[k * ln:k * ln + nx]) for k in range(n + 1))
    box_u = tuple(np.flatnonzero(finite[k * ln + nx:(k + 1) * ln]) if k < n else np.zeros(0, int)
                  for k in range(n + 1))
    return ScatterMaps(offsets, pos, h_dest, j_dest, j_sign, g_dest, ng, box_x, box_u)


@dataclass(frozen=True)
class QpStep:
    """One QP solved at the iterate w.

    Attributes:
        step: Δw (n_w,).
        lam_g: multipliers of the constraint rows (n_g,): the gap rows' and the path rows' (upper − lower).
        g, grad, f: the constraints, the cost's gradient and the cost at w.
        status: HPIPM's return flag (0 success; `planners.rti.HPIPM_STATUS`).
        iterations: interior-point iterations.
    """

    step: np.ndarray
    lam_g: np.ndarray
    g: np.ndarray
    grad: np.ndarray
    f: float
    status: int
    iterations: int


def _ptr(a: np.ndarray) -> ctypes.c_void_p:
    return ctypes.c_void_p(a.ctypes.data)


class HpipmStep:
    """The compiled data-and-solve call for one OCP (module docstring).

    Args:
        ocp: the tracking problem.
        qp_data: `planners.rti.qp_data_function(ocp)` (its sparsity patterns fix the maps).
        library: the shared library built from its generated C plus `driver_source()`.
        options: HPIPM's settings.
    """

    def __init__(self, ocp: TrackingOcp, qp_data: ca.Function, library: Path, options: HpipmOptions) -> None:
        maps = scatter_maps(ocp, qp_data.sparsity_out("H"), qp_data.sparsity_out("J"))
        lay = ocp.layout
        self.n_w, self.n_g = lay.n_w, ocp.g.size1()
        self._n_p = qp_data.sparsity_in("p").numel()
        lib = ctypes.CDLL(str(library))
        lib.uam_qp_step_new.restype = ctypes.c_void_p
        lib.uam_qp_step_new.argtypes = [ctypes.c_void_p] * 10 + [ctypes.c_int] + [ctypes.c_void_p] * 9
        lib.uam_qp_step_solve.restype = ctypes.c_int
        lib.uam_qp_step_solve.argtypes = [ctypes.c_void_p] * 11
        lib.uam_qp_step_free.restype = None
        lib.uam_qp_step_free.argtypes = [ctypes.c_void_p]
        n = lay.n_stages
        ln = lay.stage_len
        box_w, lmask, umask = [], [], []
        for k in range(n + 1):   # per stage: inputs, then states (the driver's order)
            for idx, base in ((maps.box_u[k], k * ln + lay.nx), (maps.box_x[k], k * ln)):
                box_w += list(base + idx)
                lmask += list(np.isfinite(ocp.lbx[base + idx]).astype(float))
                umask += list(np.isfinite(ocp.ubx[base + idx]).astype(float))
        grad_idx = np.asarray(qp_data.sparsity_out("grad").row(), _I32)
        g_idx = np.asarray(qp_data.sparsity_out("g").row(), _I32)
        dims = np.array([n, lay.nx, lay.nu, self.n_w, self.n_g, len(maps.h_dest), len(maps.j_dest), len(grad_idx),
                         len(g_idx), HPIPM_MODES[options.mode], options.iter_max, 0], _I32)
        self._keep = [np.ascontiguousarray(a) for a in (
            dims, maps.ng.astype(_I32), np.array([len(b) for b in maps.box_x], _I32),
            np.array([len(b) for b in maps.box_u], _I32),
            np.concatenate([*maps.box_x, np.zeros(0, int)]).astype(_I32),
            np.concatenate([*maps.box_u, np.zeros(0, int)]).astype(_I32),
            np.array(box_w, _I32), np.array(lmask, float), np.array(umask, float),
            maps.offsets.astype(_I32), maps.h_dest.astype(_I32), maps.j_dest.astype(_I32),
            maps.j_sign.astype(float), maps.g_dest.astype(_I32), ocp.lbg.astype(float), ocp.ubg.astype(float),
            np.array([options.mu0, options.tol, options.tol, options.tol, options.tol], float), grad_idx, g_idx)]
        k_ = self._keep
        handle = lib.uam_qp_step_new(*[_ptr(a) for a in k_[:10]], ctypes.c_int(maps.n_blocks),
                                     *[_ptr(a) for a in k_[10:]])
        if not handle:
            raise MemoryError("HPIPM's QP workspace could not be allocated")
        self._handle = handle
        self._lib = lib
        self._finalizer = weakref.finalize(self, lib.uam_qp_step_free, ctypes.c_void_p(handle))
        self._info = np.zeros(2, _I32)
        self._f = np.zeros(1)

    def __call__(self, w: np.ndarray, p: np.ndarray, lbx: np.ndarray, ubx: np.ndarray) -> QpStep:
        """Evaluate the QP at the iterate w (n_w,) with parameters p and solve it.

        lbx, ubx: the variable bounds (their x_0 block fixes the initial state).
        """
        w = np.ascontiguousarray(w, float)
        p = np.ascontiguousarray(p, float)
        lbx = np.ascontiguousarray(lbx, float)
        ubx = np.ascontiguousarray(ubx, float)
        if w.shape != (self.n_w,) or p.shape != (self._n_p,) or lbx.shape != w.shape or ubx.shape != w.shape:
            raise ValueError(f"HPIPM step: w, lbx, ubx must have {self.n_w} entries and p {self._n_p}; got "
                             f"{w.shape}, {lbx.shape}, {ubx.shape}, {p.shape}")
        step, grad = np.empty(self.n_w), np.empty(self.n_w)
        lam_g, g = np.empty(self.n_g), np.empty(self.n_g)
        status = self._lib.uam_qp_step_solve(self._handle, _ptr(w), _ptr(p), _ptr(lbx), _ptr(ubx), _ptr(step),
                                            _ptr(lam_g), _ptr(g), _ptr(grad), _ptr(self._f), _ptr(self._info))
        return QpStep(step, lam_g, g, grad, float(self._f[0]), int(status), int(self._info[1]))
