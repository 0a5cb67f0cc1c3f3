"""The compiled, virtual-machine and batched paths of the one model agree; the cache and fallback work."""
from __future__ import annotations

import logging

import numpy as np
import pytest

from uam_fdm.vehicle import codegen
from uam_fdm.vehicle.dynamics import VehicleDynamics
from uam_fdm.vehicle.model import hover_state

PRESETS = ("small_quad", "uam_multicopter")


def _random_flight_inputs(p, n, seed):
    rng = np.random.default_rng(seed)
    x = np.array([hover_state(p, (0, 0, 50), yaw_rad=rng.uniform(-3, 3)) for _ in range(n)])
    x[:, 3:6] += rng.normal(size=(n, 3))
    x[:, 10:13] += 0.3 * rng.normal(size=(n, 3))
    x[:, 13:] *= 1 + 0.1 * rng.normal(size=(n, p.n_rotors))
    cmd = np.column_stack([rng.uniform(-8, 8, size=(n, 3)), rng.uniform(-3, 3, size=n)])
    # heights 0.3-3 m above a surface: the ground-effect term is compared across the paths too
    env = np.column_stack([rng.normal(0, 4, size=(n, 3)), rng.uniform(0.8, 1.0, size=n), rng.uniform(0.3, 3.0, size=n)])
    u = x[:, 13:] * (1 + 0.05 * rng.normal(size=(n, p.n_rotors)))
    return x, np.zeros((n, 3)), cmd, env, u


@pytest.mark.parametrize("name", PRESETS)
def test_compiled_vm_and_batched_agree(name, vehicles, compiled_dynamics, vm_dynamics):
    p, comp, vm = vehicles[name], compiled_dynamics[name], vm_dynamics[name]
    assert comp.backend == "compiled" and vm.backend == "vm"
    n = 6
    x, xi, cmd, env, u = _random_flight_inputs(p, n, seed=11)
    xc, xic, xv, xiv = x.copy(), xi.copy(), x.copy(), xi.copy()
    for _ in range(25):   # half a second of closed-loop flight, errors would compound
        rb = comp.period_velocity_batch(xc, xic, cmd, env)
        rv = vm.period_velocity_batch(xv, xiv, cmd, env)
        np.testing.assert_allclose(rb.states, rv.states, rtol=0, atol=1e-9)
        np.testing.assert_allclose(rb.rotor_commands, rv.rotor_commands, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(rb.energy_J, rv.energy_J, rtol=1e-12, atol=1e-9)
        for i in (0, n - 1):   # a single-vehicle call equals its row of the batch
            rs = comp.period_velocity(xc[i], xic[i], cmd[i], env[i])
            rsv = vm.period_velocity(xv[i], xiv[i], cmd[i], env[i])
            np.testing.assert_array_equal(rs.states, rb.states[i])
            np.testing.assert_allclose(rsv.states, rb.states[i], rtol=0, atol=1e-9)
        xc, xic, xv, xiv = rb.final_state, rb.ctrl_state, rv.final_state, rv.ctrl_state
    rb = comp.period_rotor_batch(x, u, env)
    rv = vm.period_rotor_batch(x, u, env)
    np.testing.assert_allclose(rb.states, rv.states, rtol=0, atol=1e-9)
    for i in range(n):
        xs, es = comp.physics_step(x[i], u[i], env[i])
        xsv, esv = vm.physics_step(x[i], u[i], env[i])
        np.testing.assert_allclose(xs, rb.states[i, 0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(xs, xsv, rtol=0, atol=1e-9)
        np.testing.assert_allclose(comp.x_dot(x[i], u[i], env[i]), vm.x_dot(x[i], u[i], env[i]), rtol=1e-12, atol=1e-9)


def test_same_inputs_give_identical_results(vehicles, compiled_dynamics):
    p, d = vehicles["small_quad"], compiled_dynamics["small_quad"]
    x, xi, cmd, env, _ = _random_flight_inputs(p, 8, seed=5)
    a = d.period_velocity_batch(x, xi, cmd, env)
    b = d.period_velocity_batch(x.copy(), xi.copy(), cmd.copy(), env.copy())
    np.testing.assert_array_equal(a.states, b.states)
    np.testing.assert_array_equal(a.ctrl_state, b.ctrl_state)


def test_falls_back_to_vm_without_a_compiler(vehicles, monkeypatch, tmp_path, caplog):
    monkeypatch.setenv("CC", "/nonexistent/cc")
    with caplog.at_level(logging.WARNING, logger="uam_fdm.vehicle.codegen"):
        d = VehicleDynamics(vehicles["small_quad"], cache_dir=tmp_path)
    assert d.backend == "vm"
    assert "no C compiler" in caplog.text
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(RuntimeError, match="could not be compiled"):
        VehicleDynamics(vehicles["small_quad"], compiled=True, cache_dir=tmp_path)


def test_compiled_library_is_cached_and_reused(vehicles, monkeypatch, tmp_path):
    p = vehicles["small_quad"]
    first = VehicleDynamics(p, physics_hz=400.0, control_hz=40.0, cache_dir=tmp_path)
    libs = list(tmp_path.glob("*.so"))
    assert first.backend == "compiled" and len(libs) == 1

    def no_compiling(*args, **kwargs):
        raise AssertionError("the cached library should have been reused")

    monkeypatch.setattr(codegen.subprocess, "run", no_compiling)
    again = VehicleDynamics(p, physics_hz=400.0, control_hz=40.0, cache_dir=tmp_path)
    assert again.backend == "compiled" and list(tmp_path.glob("*.so")) == libs
    # A different vehicle is a different model: a different library.
    import dataclasses
    heavier = dataclasses.replace(p, mass_kg=p.mass_kg * 1.1)
    monkeypatch.undo()
    VehicleDynamics(heavier, physics_hz=400.0, control_hz=40.0, cache_dir=tmp_path)
    assert len(list(tmp_path.glob("*.so"))) == 2


def test_rates_must_divide(vehicles):
    with pytest.raises(ValueError, match="multiple of control_hz"):
        VehicleDynamics(vehicles["small_quad"], physics_hz=500.0, control_hz=30.0, compiled=False)
