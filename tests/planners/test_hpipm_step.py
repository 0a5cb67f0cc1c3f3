"""HPIPM called from C on the real-time iteration's QP: the same step as casadi.conic's HPIPM plugin
solved tightly, on the quad (rotor inputs) and the UAM (wrench rows at stage 0, boxed lag states),
with an active clearance half-space and a moved initial state; bit-identical repeats; the MPC's
default and its fallback; the structure checks."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from planners.hpipm_step import HpipmOptions, HpipmStep, compile_with_driver, scatter_maps
from planners.mpc import MPCConfig, MPCTracker
from planners.mpc_ocp import pack_parameters
from planners.rti import qp_data_function, qp_solver_options
from uam_fdm.vehicle.model import hover_state, make_env


@pytest.fixture(scope="module")
def steps(vehicles) -> dict:
    """Per vehicle: the MPC (for its OCP), the QP data Function and the compiled library."""
    out = {}
    for name, p in vehicles.items():
        mpc = MPCTracker(p, MPCConfig(compiled=False))
        f = qp_data_function(mpc.ocp)
        gen = ca.CodeGenerator(f"test_{name}_qp.c", {"with_header": False})
        gen.add(f)
        lib = compile_with_driver(gen.dump().encode(), f"test_{name}_qp", None, ("-O1",))
        assert lib is not None, "HPIPM's headers and libraries ship in the casadi wheel"
        out[name] = (mpc, f, lib)
    return out


def _problem(mpc: MPCTracker, wall: bool, moved_x0: bool):
    """An iterate, parameters and bounds: a step target 3 m ahead (behind a wall at 1.5 m if `wall`)."""
    p = mpc.params
    x = hover_state(p, (0.0, 0.0, 30.0))
    u_h = mpc.hover_input(1.0)
    x0 = np.concatenate([mpc.model.physical_state(x), u_h])
    n, k = mpc.horizon_steps, mpc.config.n_halfspaces
    ref = np.zeros((6, n + 1))
    ref[0] = 3.0
    ref[2] = 30.0
    normals, offsets = None, None
    if wall:
        normals = np.zeros((n, k, 3))
        offsets = np.full((n, k), -1.0)
        normals[:, 0] = (-1.0, 0.0, 0.0)
        offsets[:, 0] = -1.5
    params = pack_parameters(n, k, ref, 0.1, make_env(), u_h, normals, offsets)
    w = mpc._initial_guess(x0, u_h, 0.0)
    if moved_x0:   # the iterate's x_0 away from the measured state: the fixed step folded into stage 0
        x0 = x0.copy()
        x0[0:3] += (0.2, -0.1, 0.05)
        x0[3] += 0.3
    lbx, ubx = mpc.ocp.bounds(x0)
    return w, params, lbx, ubx


@pytest.mark.parametrize("vehicle", ["small_quad", "uam_multicopter"])
@pytest.mark.parametrize("wall,moved_x0", [(False, False), (True, False), (True, True)])
def test_direct_step_equals_the_conic_plugins(vehicle, wall, moved_x0, steps):
    mpc, f, lib = steps[vehicle]
    ocp = mpc.ocp
    w, params, lbx, ubx = _problem(mpc, wall, moved_x0)
    hess, grad, jac, g, fv = f(w, params)
    g = np.asarray(g).ravel()
    sparsity = {"h": f.sparsity_out("H"), "a": f.sparsity_out("J")}
    reference = ca.conic("reference", "hpipm", sparsity, {**qp_solver_options(ocp, "hpipm_conic"),
                                                         "hpipm": {"mode": "robust", "iter_max": 200}})
    sol = reference(h=hess, g=grad, a=jac, lba=ocp.lbg - g, uba=ocp.ubg - g, lbx=lbx - w, ubx=ubx - w)
    expected = np.asarray(sol["x"]).ravel()
    q = HpipmStep(ocp, f, lib, HpipmOptions(mode="balance", tol=1e-10))(w, params, lbx, ubx)
    assert q.status == 0
    # the data handed back dense, structural zeros included
    np.testing.assert_array_equal(q.g, g)
    np.testing.assert_array_equal(q.grad, np.asarray(ca.densify(grad)).ravel())
    assert q.f == float(fv)
    # the same QP solution (up to the solvers' tolerances), the fixed initial state's step exact
    scale = 1.0 + np.max(np.abs(expected))
    assert np.max(np.abs(q.step - expected)) < 1e-5 * scale
    np.testing.assert_array_equal(q.step[:ocp.layout.nx], lbx[:ocp.layout.nx] - w[:ocp.layout.nx])
    if wall:   # the half-space is active: the prediction stops at the plane (slack ~ 0)
        xs = mpc.layout.states(w + q.step)
        assert np.max(xs[1:-1, 0]) <= 1.5 + 1e-6 + np.max(mpc.layout.slacks(w + q.step))


def test_direct_step_repeats_bit_for_bit(steps):
    mpc, f, lib = steps["uam_multicopter"]
    w, params, lbx, ubx = _problem(mpc, wall=True, moved_x0=False)
    first = HpipmStep(mpc.ocp, f, lib, HpipmOptions())
    second = HpipmStep(mpc.ocp, f, lib, HpipmOptions())
    runs = [first(w, params, lbx, ubx), first(w, params, lbx, ubx), second(w, params, lbx, ubx)]
    for r in runs[1:]:
        np.testing.assert_array_equal(r.step, runs[0].step)
        np.testing.assert_array_equal(r.lam_g, runs[0].lam_g)
        assert r.iterations == runs[0].iterations


def test_direct_step_rejects_wrong_sizes(steps):
    mpc, f, lib = steps["small_quad"]
    w, params, lbx, ubx = _problem(mpc, wall=False, moved_x0=False)
    step = HpipmStep(mpc.ocp, f, lib, HpipmOptions())
    with pytest.raises(ValueError, match="entries"):
        step(w[:-1], params, lbx, ubx)


def test_scatter_maps_reject_a_hessian_across_stages(steps):
    mpc, f, _ = steps["small_quad"]
    h = f.sparsity_out("H")
    rows, cols = h.get_triplet()
    ln = mpc.layout.stage_len
    coupled = ca.Sparsity.triplet(h.size1(), h.size2(), [*rows, 0, ln], [*cols, ln, 0])
    with pytest.raises(ValueError, match="couples stages"):
        scatter_maps(mpc.ocp, coupled, f.sparsity_out("J"))


def test_options_are_checked():
    with pytest.raises(ValueError, match="mode"):
        HpipmOptions(mode="fast")
    with pytest.raises(ValueError, match="invalid"):
        HpipmOptions(iter_max=0)


def test_the_mpc_runs_hpipm_from_c_when_compiled_and_the_conic_plugin_otherwise(vehicles):
    p = vehicles["small_quad"]
    assert MPCTracker(p, MPCConfig()).qp_solver == "hpipm"
    assert MPCTracker(p, MPCConfig(compiled=False)).qp_solver == "hpipm_conic"
    assert MPCTracker(p, MPCConfig(qp_solver="hpipm_conic")).qp_solver == "hpipm_conic"
    assert MPCTracker(p, MPCConfig(solver="ipopt")).qp_solver is None
