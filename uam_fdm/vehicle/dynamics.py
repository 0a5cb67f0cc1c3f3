"""Compiled vehicle dynamics: the model's Functions plus fused control-period steps, NumPy in and out.

A control period of `n_substeps` physics steps is one call into compiled code, either with the
rotor commands held (zero-order hold; what an MPC emits) or with the low-level velocity controller
evaluated at every physics step (what the learned pilot's velocity command drives). Batched
variants step N vehicles in one call (CasADi `map` over the compiled function).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from uam_fdm.errors import ConfigError
from uam_fdm.vehicle.codegen import compile_functions
from uam_fdm.vehicle.control import N_CMD, N_CTRL_STATE, build_controller_function
from uam_fdm.vehicle.fastcall import BatchCaller, map_rows
from uam_fdm.vehicle.model import N_ENV, StateLayout, build_model_functions, quat_product
from uam_fdm.vehicle.params import VehicleParams

log = logging.getLogger(__name__)

_BATCHED = ("rk4_step", "controller", "period_rotor", "period_velocity", "shaft_power")
# A control period is unrolled into one generated function of this many RK4 steps at most: its code,
# compile time and memory grow with the count (10 at 500 Hz / 50 Hz is ~0.5 MB of machine code).
MAX_PHYSICS_STEPS_PER_CONTROL_PERIOD = 100
# The motor lag dΩ/dt = (u - Ω)/τ under RK4 is stable only for dt < 2.8 τ; at dt <= τ/2 its error
# per step stays below 0.05 %, so τ must span at least this many physics steps.
MIN_PHYSICS_STEPS_PER_MOTOR_TIME_CONSTANT = 2.0


def control_ratio_problem(physics_hz: float, control_hz: float) -> str | None:
    """Why `control_hz` does not fit `physics_hz`, or None.

    It must divide `physics_hz` into at most MAX_PHYSICS_STEPS_PER_CONTROL_PERIOD physics steps per control period.
    """
    if not (physics_hz > 0 and control_hz > 0):
        return f"physics_hz {physics_hz:g} and control_hz {control_hz:g} must be positive"
    ratio = physics_hz / control_hz
    if round(ratio) < 1 or abs(ratio - round(ratio)) > 1e-9 * ratio:
        return f"physics_hz {physics_hz:g} Hz must be a positive integer multiple of control_hz {control_hz:g} Hz"
    if round(ratio) > MAX_PHYSICS_STEPS_PER_CONTROL_PERIOD:
        return (f"control_hz {control_hz:g} Hz gives {round(ratio)} physics steps per control period at "
                f"{physics_hz:g} Hz; "
                f"at most {MAX_PHYSICS_STEPS_PER_CONTROL_PERIOD} (control_hz >= "
                f"{physics_hz / MAX_PHYSICS_STEPS_PER_CONTROL_PERIOD:g} Hz)")
    return None


def motor_lag_problem(params: VehicleParams, physics_hz: float) -> str | None:
    """Why `params.motor_time_constant_s` is too short to integrate at `physics_hz`, or None."""
    steps = params.motor_time_constant_s * physics_hz
    if steps < MIN_PHYSICS_STEPS_PER_MOTOR_TIME_CONSTANT:
        return (f"motor_time_constant_s {params.motor_time_constant_s:g} s spans {steps:.3g} physics steps at "
                f"{physics_hz:g} Hz; it must span at least {MIN_PHYSICS_STEPS_PER_MOTOR_TIME_CONSTANT:g} (RK4 "
                f"diverges once a step exceeds 2.8 time constants): a physics rate of at least "
                f"{MIN_PHYSICS_STEPS_PER_MOTOR_TIME_CONSTANT / params.motor_time_constant_s:.4g} Hz")
    return None


@dataclass(frozen=True)
class PeriodResult:
    """What one control period produced (single vehicle: leading axis = substep; batched: vehicle, substep).

    Attributes:
        states: state after each physics substep, (n_substeps, nx) or (N, n_substeps, nx).
        rotor_commands: rotor-speed command applied during each substep [rad/s], (.., n_substeps, n).
        ctrl_state: controller integral state after the period [m/s²], (3,) or (N, 3).
        energy_J: rotor shaft energy ∫ Σ Q_i Ω_i dt over the period [J], scalar or (N,).
    """

    states: np.ndarray
    rotor_commands: np.ndarray
    ctrl_state: np.ndarray
    energy_J: np.ndarray | float

    @property
    def final_state(self) -> np.ndarray:
        return self.states[..., -1, :]


def _period_functions(p: VehicleParams, rk4: ca.Function, ctrl: ca.Function,
                      n_sub: int) -> tuple[ca.Function, ca.Function]:
    """Fused control-period Functions built from the one model (MX graph of calls, compiled as a whole)."""
    lay = StateLayout(p.n_rotors)
    x0 = ca.MX.sym("x", lay.nx)
    u = ca.MX.sym("u", p.n_rotors)
    xi0 = ca.MX.sym("xi", N_CTRL_STATE)
    cmd = ca.MX.sym("cmd", N_CMD)
    env = ca.MX.sym("env", N_ENV)
    dt = ca.MX.sym("dt")

    energy: ca.MX | int  # the sum of the substeps' energies, starting from 0
    x, states, energy = x0, [], 0
    for _ in range(n_sub):
        x, e = rk4(x, u, env, dt)
        states.append(x)
        energy += e
    period_rotor = ca.Function("period_rotor", [x0, u, env, dt], [ca.horzcat(*states), energy],
                               ["x", "u", "env", "dt"], ["states", "energy_J"])

    x, xi, states, cmds, energy = x0, xi0, [], [], 0
    for _ in range(n_sub):
        u_k, xi = ctrl(x, xi, cmd, env, dt)
        x, e = rk4(x, u_k, env, dt)
        states.append(x)
        cmds.append(u_k)
        energy += e
    period_velocity = ca.Function(
        "period_velocity", [x0, xi0, cmd, env, dt],
        [ca.horzcat(*states), ca.horzcat(*cmds), xi, energy],
        ["x", "xi", "cmd", "env", "dt"], ["states", "rotor_commands", "xi_next", "energy_J"])
    return period_rotor, period_velocity


N_SEEN_OFFSET = 13  # [δp (3) m, δv (3) m/s, δq (4) body-frame quaternion, δω (3) rad/s]: estimate minus truth


def _period_velocity_seen_function(p: VehicleParams, rk4: ca.Function, ctrl: ca.Function, n_sub: int) -> ca.Function:
    """The control period under the velocity controller flying on the navigation estimate, not the truth.

    The controller sees, at every physics step, the true state moved by the estimate's error at the period's start
    (`offset`: position and velocity added, the attitude error δq = q_true⁻¹ ⊗ q_est applied in the body frame, the
    rate error added): the filter's error changes over seconds, a period lasts tens of milliseconds, so holding it
    over the period is what a flight controller running on its estimator's output does between updates.
    """
    lay = StateLayout(p.n_rotors)
    x0 = ca.MX.sym("x", lay.nx)
    xi0 = ca.MX.sym("xi", N_CTRL_STATE)
    cmd = ca.MX.sym("cmd", N_CMD)
    env = ca.MX.sym("env", N_ENV)
    dt = ca.MX.sym("dt")
    offset = ca.MX.sym("offset", N_SEEN_OFFSET)
    energy: ca.MX | int  # the sum of the substeps' energies, starting from 0
    x, xi, states, cmds, energy = x0, xi0, [], [], 0
    for _ in range(n_sub):
        q_seen = quat_product(x[lay.quat], offset[6:10])
        seen = ca.vertcat(x[lay.pos] + offset[0:3], x[lay.vel] + offset[3:6], q_seen / ca.norm_2(q_seen),
                          x[lay.rate] + offset[10:13], x[lay.rotor])
        u_k, xi = ctrl(seen, xi, cmd, env, dt)
        x, e = rk4(x, u_k, env, dt)
        states.append(x)
        cmds.append(u_k)
        energy += e
    return ca.Function("period_velocity_seen", [x0, xi0, cmd, env, dt, offset],
                       [ca.horzcat(*states), ca.horzcat(*cmds), xi, energy],
                       ["x", "xi", "cmd", "env", "dt", "offset"], ["states", "rotor_commands", "xi_next", "energy_J"])


class VehicleDynamics:
    """All dynamics Functions of one vehicle at one physics/control rate, compiled when possible.

    Args:
        params: the vehicle.
        physics_hz: physics (RK4) rate [Hz]; the low-level controller runs at this rate too.
        control_hz: decision rate [Hz]; must divide physics_hz.
        compiled: True to require compiled code (raises without a compiler), False for CasADi's
            virtual machine, None (default) to compile when a compiler exists and fall back otherwise.
        cache_dir: cache for compiled libraries (default `codegen.default_cache_dir()`).
    """

    def __init__(self, params: VehicleParams, physics_hz: float = 500.0, control_hz: float = 50.0,
                 compiled: bool | None = None, cache_dir: Path | None = None) -> None:
        problem = control_ratio_problem(physics_hz, control_hz)
        if problem is not None:
            raise ValueError(problem)
        problem = motor_lag_problem(params, physics_hz)
        if problem is not None:  # before compiling anything: a diverging model is not worth the wait
            raise ConfigError(params.source, "motor_time_constant_s", problem)
        ratio = physics_hz / control_hz
        self.params = params
        self.layout = StateLayout(params.n_rotors)
        self.physics_hz, self.control_hz = float(physics_hz), float(control_hz)
        self.dt_s = 1.0 / physics_hz
        self.n_substeps = int(round(ratio))

        model = build_model_functions(params)
        ctrl = build_controller_function(params)
        period_rotor, period_velocity = _period_functions(params, model.rk4_step, ctrl, self.n_substeps)
        vm = {f.name(): f for f in (model.dynamics, model.shaft_power, model.rk4_step, model.jacobians,
                                    ctrl, period_rotor.expand(), period_velocity.expand())}
        self.model = model
        self._compiled, self._cache_dir = compiled, cache_dir
        self._rk4, self._ctrl = model.rk4_step, ctrl
        lib = None
        if compiled is not False:
            name = f"uam_{params.fingerprint()}_{self.n_substeps}"
            lib = compile_functions(list(vm.values()), name, cache_dir)
            if lib is None and compiled:
                raise RuntimeError("compiled=True but the model could not be compiled (see the log)")
        self.backend = "compiled" if lib is not None else "vm"
        self.functions: dict[str, ca.Function] = lib.functions if lib is not None else vm
        self._callers: dict[str, BatchCaller] = {}
        if lib is not None:
            for fname in _BATCHED:
                self._callers[fname] = BatchCaller(lib.path, vm[fname])
        self._maps: dict[tuple[str, int], ca.Function] = {}

    def _add_seen_period(self) -> None:
        """Build (and compile, in its own library, when the model is compiled) `period_velocity_seen` on first use:
        a run where every pilot flies on the truth never builds it."""
        f = _period_velocity_seen_function(self.params, self._rk4, self._ctrl, self.n_substeps).expand()
        lib = None
        if self.backend == "compiled":
            lib = compile_functions([f], f"uam_seen_{self.params.fingerprint()}_{self.n_substeps}", self._cache_dir)
        if lib is None:
            self.functions["period_velocity_seen"] = f
        else:
            self.functions["period_velocity_seen"] = lib.functions["period_velocity_seen"]
            self._callers["period_velocity_seen"] = BatchCaller(lib.path, f)

    def _eval(self, name: str, n: int, *inputs) -> list[np.ndarray]:
        """Evaluate `name` for n vehicles; each output as (n, rows*cols), column-major per vehicle."""
        if name == "period_velocity_seen" and name not in self.functions:
            self._add_seen_period()
        caller = self._callers.get(name)
        if caller is not None:
            return caller(n, *inputs)
        return map_rows(self.functions[name], self._maps, n, *inputs)

    # -- single vehicle ------------------------------------------------------------------------
    def x_dot(self, x: np.ndarray, u: np.ndarray, env: np.ndarray) -> np.ndarray:
        """Continuous dynamics ẋ (nx,) for state x, rotor commands u [rad/s], env [wind ENU m/s, σ]."""
        return self.functions["dynamics"](x, u, env).full().ravel()

    def jacobians(self, x: np.ndarray, u: np.ndarray, env: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(∂ẋ/∂x (nx, nx), ∂ẋ/∂u (nx, n)) at a point."""
        a, b = self.functions["jacobians"](x, u, env)
        return a.full(), b.full()

    def shaft_power_W(self, x: np.ndarray, env: np.ndarray) -> float:
        """Total rotor shaft power Σ Q_i Ω_i [W]."""
        return float(self.functions["shaft_power"](x, env))

    def shaft_power_batch_W(self, x: np.ndarray, env: np.ndarray) -> np.ndarray:
        """Total rotor shaft power Σ Q_i Ω_i [W] of N states x (N, nx), in one environment env (N_ENV,) or one
        per state (N, N_ENV); returns (N,)."""
        x = np.asarray(x, float)
        return self._eval("shaft_power", x.shape[0], x, np.asarray(env, float))[0][:, 0]

    def physics_step(self, x: np.ndarray, u: np.ndarray, env: np.ndarray) -> tuple[np.ndarray, float]:
        """One RK4 physics step of dt_s: (x_next, shaft energy [J])."""
        xn, e = self._eval("rk4_step", 1, x, u, env, self.dt_s)
        return xn[0], float(e[0, 0])

    def controller(self, x: np.ndarray, xi: np.ndarray, cmd: np.ndarray,
                   env: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Velocity controller once: (rotor commands [rad/s], next integral state)."""
        u, xin = self._eval("controller", 1, x, xi, cmd, env, self.dt_s)
        return u[0], xin[0]

    def period_rotor(self, x: np.ndarray, u: np.ndarray, env: np.ndarray) -> PeriodResult:
        """One control period with rotor commands u (n,) [rad/s] held; env held over the period."""
        r = self.period_rotor_batch(np.asarray(x, float)[None], np.asarray(u, float)[None],
                                    np.asarray(env, float)[None])
        return PeriodResult(r.states[0], r.rotor_commands[0], r.ctrl_state[0], float(np.asarray(r.energy_J)[0]))

    def period_velocity(self, x: np.ndarray, ctrl_state: np.ndarray, cmd: np.ndarray,
                        env: np.ndarray) -> PeriodResult:
        """One control period under the velocity controller; cmd = [v_e, v_n, v_u, yaw_ref]."""
        r = self.period_velocity_batch(np.asarray(x, float)[None], np.asarray(ctrl_state, float)[None],
                                       np.asarray(cmd, float)[None], np.asarray(env, float)[None])
        return PeriodResult(r.states[0], r.rotor_commands[0], r.ctrl_state[0], float(np.asarray(r.energy_J)[0]))

    def period_velocity_seen(self, x: np.ndarray, ctrl_state: np.ndarray, cmd: np.ndarray, env: np.ndarray,
                             offset: np.ndarray) -> PeriodResult:
        """`period_velocity` with the controller flying on the estimate: `offset` (`N_SEEN_OFFSET`,) is the
        estimate's error at the period's start ([δp m, δv m/s ENU, δq body quaternion, δω rad/s])."""
        r = self.period_velocity_seen_batch(np.asarray(x, float)[None], np.asarray(ctrl_state, float)[None],
                                            np.asarray(cmd, float)[None], np.asarray(env, float)[None],
                                            np.asarray(offset, float)[None])
        return PeriodResult(r.states[0], r.rotor_commands[0], r.ctrl_state[0], float(np.asarray(r.energy_J)[0]))

    # -- batched -------------------------------------------------------------------------------
    def period_rotor_batch(self, x: np.ndarray, u: np.ndarray, env: np.ndarray) -> PeriodResult:
        """`period_rotor` for N vehicles in one call: x (N, nx), u (N, n), env (N, 4)."""
        n = x.shape[0]
        states, energy = self._eval("period_rotor", n, x, u, env, self.dt_s)
        cmds = np.repeat(np.asarray(u, float)[:, None, :], self.n_substeps, axis=1)
        return PeriodResult(states.reshape(n, self.n_substeps, self.layout.nx), cmds,
                            np.zeros((n, N_CTRL_STATE)), energy[:, 0])

    def period_velocity_batch(self, x: np.ndarray, ctrl_state: np.ndarray, cmd: np.ndarray,
                              env: np.ndarray) -> PeriodResult:
        """`period_velocity` for N vehicles in one call: x (N, nx), ctrl_state (N, 3), cmd (N, 4), env (N, 4)."""
        n = x.shape[0]
        states, cmds, xi, energy = self._eval("period_velocity", n, x, ctrl_state, cmd, env, self.dt_s)
        return PeriodResult(states.reshape(n, self.n_substeps, self.layout.nx),
                            cmds.reshape(n, self.n_substeps, self.params.n_rotors), xi, energy[:, 0])

    def period_velocity_seen_batch(self, x: np.ndarray, ctrl_state: np.ndarray, cmd: np.ndarray, env: np.ndarray,
                                   offset: np.ndarray) -> PeriodResult:
        """`period_velocity_seen` for N vehicles in one call: x (N, nx), ctrl_state (N, 3), cmd (N, 4), env (N, 5),
        offset (N, `N_SEEN_OFFSET`) each vehicle's estimate error at the period's start."""
        n = x.shape[0]
        states, cmds, xi, energy = self._eval("period_velocity_seen", n, x, ctrl_state, cmd, env, self.dt_s, offset)
        return PeriodResult(states.reshape(n, self.n_substeps, self.layout.nx),
                            cmds.reshape(n, self.n_substeps, self.params.n_rotors), xi, energy[:, 0])
