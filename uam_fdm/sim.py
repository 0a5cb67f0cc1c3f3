"""Simulator: the compiled vehicle dynamics flying in an atmosphere and a wind field.

Pure steps take the state and return the next one (`step`, `step_velocity`, batched `step_batch`,
`step_velocity_batch`); `reset`/`advance*` are a thin stateful shell over them. Over each control
period the environment input (wind, density ratio) is held: the wind at the period's midpoint in
time and, like the density, at the vehicle's altitude at the period's start (within 20 ms the
altitude changes by centimetres: Δσ ~ 1e-6, and the wind's height profile and turbulence rungs
change as little), while JSBSim's turbulence is tabulated at 120 Hz. The wind field must cover
the episode plus one control period.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from uam_fdm.air.atmosphere import Atmosphere, AtmosphereBank
from uam_fdm.air.wind import WindBank, WindField
from uam_fdm.vehicle.control import N_CTRL_STATE
from uam_fdm.vehicle.dynamics import PeriodResult, VehicleDynamics


def period_env(atmosphere: Atmosphere, wind_enu_m_s: np.ndarray, z_m: np.ndarray | float,
               height_above_surface_m: np.ndarray | float | None = None) -> np.ndarray:
    """The environment input [wind_e, wind_n, wind_u (m/s), σ, h (m)] held over a control period.

    The one rule every flight uses (the runner's `Simulator` and the learned pilot's batched
    environment alike): the wind sampled at the period's midpoint in time and at the vehicle's
    altitude at the period's start (the caller passes it: `WindField.wind_enu_m_s(t + T/2, z)` or
    `WindBank.wind_enu_m_s`), the density ratio at the vehicle's altitude at the period's start (clamped to the
    table), and the height above the surface below at the period's start (the caller's, from
    `uam_fdm.vehicle.ground_effect.height_above_surface`; None: open ground at z = 0, so h = z).

    Args:
        atmosphere: the density table.
        wind_enu_m_s: (3,) or (N, 3) wind at the period's midpoint in time, at the altitude z_m
            [m/s, world ENU].
        z_m: altitude(s) at the period's start [m], scalar or (N,).
        height_above_surface_m: scalar or (N,) [m], or None.

    Returns:
        (5,) for a scalar altitude, else (N, 5).
    """
    if np.ndim(z_m) == 0:  # the scalar lookup (same arithmetic) is much cheaper for one vehicle
        w = np.asarray(wind_enu_m_s, dtype=float).reshape(3)
        h = float(z_m) if height_above_surface_m is None else float(np.asarray(height_above_surface_m).reshape(-1)[0])
        return np.array([w[0], w[1], w[2], atmosphere.density_ratio_clamped(float(z_m)), h])
    z = np.asarray(z_m, dtype=float)
    env = np.empty((len(z), 5))
    env[:, 0:3] = wind_enu_m_s
    env[:, 3] = atmosphere.density_ratio_clamped(z)
    env[:, 4] = z if height_above_surface_m is None else height_above_surface_m
    return env


@dataclass(frozen=True)
class SimState:
    """Where one simulated vehicle is: time [s], state (13 + n,), controller integral (3,), energy [J]."""

    t_s: float
    x: np.ndarray
    ctrl_state: np.ndarray
    energy_J: float


class Simulator:
    """One vehicle in one atmosphere and wind field.

    Args:
        dynamics: the compiled vehicle (physics and control rates are its own).
        atmosphere: density table covering the flight's altitudes (z above the field).
        wind: steady wind plus turbulence series, world ENU.
    """

    def __init__(self, dynamics: VehicleDynamics, atmosphere: Atmosphere, wind: WindField | None = None) -> None:
        self.dynamics = dynamics
        self.atmosphere = atmosphere
        self.wind = wind if wind is not None else WindField.calm()
        self.control_period_s = 1.0 / dynamics.control_hz
        self._state: SimState | None = None

    def env(self, x: np.ndarray, t_s: float, height_above_surface_m: float | None = None) -> np.ndarray:
        """Environment input (`period_env`) held over the period starting at t_s; the height above the
        surface below [m] from the caller (None: open ground, h = z)."""
        z = float(x[2])
        return period_env(self.atmosphere, self.wind.wind_enu_m_s(t_s + 0.5 * self.control_period_s, z), z,
                          height_above_surface_m)

    def step(self, x: np.ndarray, u: np.ndarray, t_s: float, height_above_surface_m: float | None = None, *,
             env: np.ndarray | None = None) -> PeriodResult:
        """One control period from state x at time t_s with rotor-speed commands u [rad/s] held.

        `env`: the period's environment input when the caller has it already (`self.env(x, t_s, h)`, e.g. to
        record the wind and density flown), so it is built once (`height_above_surface_m` is then unused);
        None: built here."""
        return self.dynamics.period_rotor(x, u, self._period_env(x, t_s, height_above_surface_m, env))

    def step_velocity(self, x: np.ndarray, ctrl_state: np.ndarray, cmd: np.ndarray, t_s: float,
                      height_above_surface_m: float | None = None, *, env: np.ndarray | None = None,
                      seen_offset: np.ndarray | None = None) -> PeriodResult:
        """One control period under the low-level controller; cmd = [v_e, v_n, v_u (m/s), yaw (rad)]; `env` as
        in `step`; `seen_offset`: the navigation estimate's error the controller flies on
        (`VehicleDynamics.period_velocity_seen`), None: it flies on the true state."""
        env = self._period_env(x, t_s, height_above_surface_m, env)
        if seen_offset is None:
            return self.dynamics.period_velocity(x, ctrl_state, cmd, env)
        return self.dynamics.period_velocity_seen(x, ctrl_state, cmd, env, seen_offset)

    def _period_env(self, x: np.ndarray, t_s: float, height_above_surface_m: float | None,
                    env: np.ndarray | None) -> np.ndarray:
        return self.env(x, t_s, height_above_surface_m) if env is None else env

    # -- stateful shell ------------------------------------------------------------------------
    @property
    def state(self) -> SimState:
        if self._state is None:
            raise RuntimeError("call reset() before reading the state or advancing")
        return self._state

    def reset(self, x0: np.ndarray, t0_s: float = 0.0) -> SimState:
        """Start from state x0 at time t0_s with a zero controller integral and zero energy."""
        x0 = np.array(x0, dtype=float)
        if x0.shape != (self.dynamics.layout.nx,) or not np.all(np.isfinite(x0)):
            raise ValueError(f"x0 must be {self.dynamics.layout.nx} finite numbers, got shape {x0.shape}")
        self._state = SimState(float(t0_s), x0, np.zeros(N_CTRL_STATE), 0.0)
        return self._state

    def advance(self, u: np.ndarray, height_above_surface_m: float | None = None, *,
                env: np.ndarray | None = None) -> PeriodResult:
        """Advance the held state one control period with rotor commands u [rad/s]; `env` as in `step`."""
        s = self.state
        r = self.step(s.x, u, s.t_s, height_above_surface_m, env=env)
        self._state = SimState(s.t_s + self.control_period_s, r.final_state, s.ctrl_state,
                               s.energy_J + float(r.energy_J))
        return r

    def advance_velocity(self, cmd: np.ndarray, height_above_surface_m: float | None = None, *,
                         env: np.ndarray | None = None, seen_offset: np.ndarray | None = None) -> PeriodResult:
        """Advance the held state one control period under the velocity controller; `env` and `seen_offset` as in
        `step_velocity`."""
        s = self.state
        r = self.step_velocity(s.x, s.ctrl_state, cmd, s.t_s, height_above_surface_m, env=env, seen_offset=seen_offset)
        self._state = SimState(s.t_s + self.control_period_s, r.final_state, r.ctrl_state,
                               s.energy_J + float(r.energy_J))
        return r


class BatchSimulator:
    """N vehicles of one type, each with its own wind, stepped in one compiled call.

    Args:
        dynamics: the compiled vehicle.
        atmosphere: one atmosphere for every vehicle, or an `AtmosphereBank` (each vehicle in its own).
        winds: one wind field per vehicle, or a `WindBank` of N vehicles.
    """

    def __init__(self, dynamics: VehicleDynamics, atmosphere: Atmosphere | AtmosphereBank,
                 winds: Sequence[WindField] | WindBank) -> None:
        self.dynamics = dynamics
        self.atmosphere = atmosphere
        self.winds = winds if isinstance(winds, WindBank) else list(winds)
        self.control_period_s = 1.0 / dynamics.control_hz

    @property
    def n(self) -> int:
        return len(self.winds.steady) if isinstance(self.winds, WindBank) else len(self.winds)

    def env(self, x: np.ndarray, t_s: np.ndarray, idx: np.ndarray | None = None,
            height_above_surface_m: np.ndarray | None = None) -> np.ndarray:
        """Environment inputs (M, 5) for vehicles `idx` (default all) in states x (M, nx) at times t_s (M,) [s];
        heights above the surface below (M,) [m] from the caller (None: open ground, h = z)."""
        m = x.shape[0]
        first = 0 if idx is None else int(np.asarray(idx).reshape(-1)[0])
        if m == 1 and isinstance(self.winds, WindBank):
            return self._env_one(self.winds, x, t_s, first, height_above_surface_m)
        t = np.asarray(t_s, dtype=float)
        t_mid = (t if t.shape == (m,) else np.broadcast_to(t, (m,))) + 0.5 * self.control_period_s
        if isinstance(self.winds, WindBank):
            wind = self.winds.wind_enu_m_s(t_mid, x[:, 2], idx)
        else:
            which = range(m) if idx is None else idx
            wind = np.array([self.winds[int(i)].wind_enu_m_s(float(t), float(z))
                             for i, t, z in zip(which, t_mid, x[:, 2])]).reshape(m, 3)
        if m == 1:  # the scalar density lookup: the same numbers, cheaper
            return period_env(self._atmosphere(first), wind[0], float(x[0, 2]), height_above_surface_m)[None]
        if isinstance(self.atmosphere, AtmosphereBank):  # each vehicle's own density, the same arithmetic
            env = np.empty((m, 5))
            env[:, 0:3] = wind
            env[:, 3] = self.atmosphere.density_ratio_clamped(x[:, 2], idx)
            env[:, 4] = x[:, 2] if height_above_surface_m is None else height_above_surface_m
            return env
        return period_env(self.atmosphere, wind, x[:, 2], height_above_surface_m)

    def _atmosphere(self, i: int) -> Atmosphere:
        """Vehicle i's atmosphere."""
        return self.atmosphere.atmosphere(i) if isinstance(self.atmosphere, AtmosphereBank) else self.atmosphere

    def _env_one(self, bank: WindBank, x: np.ndarray, t_s: np.ndarray | float, i: int,
                 height_above_surface_m: np.ndarray | None) -> np.ndarray:
        """`env` (1, 5) of vehicle i of `bank` (this simulator's winds) alone, in plain Python (the same numbers:
        `WindBank._wind_one` and the scalar density lookup); NumPy's per-call overhead on one row dominated a
        single vehicle."""
        t_mid = float(np.asarray(t_s, dtype=float).reshape(-1)[0]) + 0.5 * self.control_period_s
        z = float(x[0, 2])
        we, wn, wu = bank._wind_one(i, t_mid, z)
        h = z if height_above_surface_m is None else float(np.asarray(height_above_surface_m).reshape(-1)[0])
        return np.array([[we, wn, wu, self._atmosphere(i).density_ratio_clamped(z), h]])

    def step_batch(self, x: np.ndarray, u: np.ndarray, t_s: np.ndarray, idx: np.ndarray | None = None,
                   height_above_surface_m: np.ndarray | None = None) -> PeriodResult:
        """One control period for vehicles `idx` (default all), rotor commands u (M, n) [rad/s] held."""
        return self.dynamics.period_rotor_batch(x, u, self.env(x, t_s, idx, height_above_surface_m))

    def step_velocity_batch(self, x: np.ndarray, ctrl_state: np.ndarray, cmd: np.ndarray,
                            t_s: np.ndarray, idx: np.ndarray | None = None,
                            height_above_surface_m: np.ndarray | None = None, *,
                            seen_offset: np.ndarray | None = None) -> PeriodResult:
        """One control period for vehicles `idx` (default all) under the velocity controller; cmd (M, 4);
        `seen_offset` (M, `N_SEEN_OFFSET`): the navigation estimates' errors the controller flies on
        (`VehicleDynamics.period_velocity_seen_batch`), None: it flies on the true states."""
        env = self.env(x, t_s, idx, height_above_surface_m)
        if seen_offset is None:
            return self.dynamics.period_velocity_batch(x, ctrl_state, cmd, env)
        return self.dynamics.period_velocity_seen_batch(x, ctrl_state, cmd, env, seen_offset)
