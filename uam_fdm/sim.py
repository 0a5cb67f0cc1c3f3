"""Simulator: the compiled vehicle dynamics flying in an atmosphere and a wind field.

Pure steps take the state and return the next one (`step`, `step_velocity`, batched `step_batch`,
`step_velocity_batch`); `reset`/`advance*` are a thin stateful shell over them. Over each control
period the environment input (wind, density ratio) is held, sampled at the period's midpoint in
time and at the vehicle's altitude at the start: within 20 ms the altitude changes by centimetres
(Δσ ~ 1e-6), while JSBSim's turbulence is tabulated at 120 Hz. The wind field must cover the
episode plus one control period.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from uam_fdm.atmosphere import Atmosphere
from uam_fdm.control import N_CTRL_STATE
from uam_fdm.dynamics import PeriodResult, VehicleDynamics
from uam_fdm.wind import WindField


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

    def env(self, x: np.ndarray, t_s: float) -> np.ndarray:
        """Environment input [wind_e, wind_n, wind_u (m/s), σ] held over the period starting at t_s."""
        wind = self.wind.wind_enu_m_s(t_s + 0.5 * self.control_period_s)
        sigma = self.atmosphere.density_ratio_clamped(float(x[2]))
        return np.array([wind[0], wind[1], wind[2], sigma])

    def step(self, x: np.ndarray, u: np.ndarray, t_s: float) -> PeriodResult:
        """One control period from state x at time t_s with rotor-speed commands u [rad/s] held."""
        return self.dynamics.period_rotor(x, u, self.env(x, t_s))

    def step_velocity(self, x: np.ndarray, ctrl_state: np.ndarray, cmd: np.ndarray, t_s: float) -> PeriodResult:
        """One control period under the low-level controller; cmd = [v_e, v_n, v_u (m/s), yaw (rad)]."""
        return self.dynamics.period_velocity(x, ctrl_state, cmd, self.env(x, t_s))

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

    def advance(self, u: np.ndarray) -> PeriodResult:
        """Advance the held state one control period with rotor commands u [rad/s]."""
        s = self.state
        r = self.step(s.x, u, s.t_s)
        self._state = SimState(s.t_s + self.control_period_s, r.final_state, s.ctrl_state, s.energy_J + r.energy_J)
        return r

    def advance_velocity(self, cmd: np.ndarray) -> PeriodResult:
        """Advance the held state one control period under the velocity controller."""
        s = self.state
        r = self.step_velocity(s.x, s.ctrl_state, cmd, s.t_s)
        self._state = SimState(s.t_s + self.control_period_s, r.final_state, r.ctrl_state,
                               s.energy_J + r.energy_J)
        return r


class BatchSimulator:
    """N vehicles of one type, each with its own wind field, stepped in one compiled call.

    Args:
        dynamics: the compiled vehicle.
        atmosphere: shared atmosphere.
        winds: one wind field per vehicle (N of them).
    """

    def __init__(self, dynamics: VehicleDynamics, atmosphere: Atmosphere, winds: Sequence[WindField]) -> None:
        self.dynamics = dynamics
        self.atmosphere = atmosphere
        self.winds = list(winds)
        self.control_period_s = 1.0 / dynamics.control_hz

    @property
    def n(self) -> int:
        return len(self.winds)

    def env(self, x: np.ndarray, t_s: np.ndarray) -> np.ndarray:
        """Environment inputs (N, 4) for states x (N, nx) at times t_s (N,) [s]."""
        t_mid = np.broadcast_to(np.asarray(t_s, float), (self.n,)) + 0.5 * self.control_period_s
        env = np.empty((self.n, 4))
        for i, wind in enumerate(self.winds):
            env[i, :3] = wind.wind_enu_m_s(float(t_mid[i]))
        env[:, 3] = self.atmosphere.density_ratio_clamped(x[:, 2])
        return env

    def step_batch(self, x: np.ndarray, u: np.ndarray, t_s: np.ndarray) -> PeriodResult:
        """One control period for every vehicle, rotor commands u (N, n) [rad/s] held."""
        return self.dynamics.period_rotor_batch(x, u, self.env(x, t_s))

    def step_velocity_batch(self, x: np.ndarray, ctrl_state: np.ndarray, cmd: np.ndarray,
                            t_s: np.ndarray) -> PeriodResult:
        """One control period for every vehicle under the velocity controller; cmd (N, 4)."""
        return self.dynamics.period_velocity_batch(x, ctrl_state, cmd, self.env(x, t_s))
