"""The boundary between a pilot and the simulator: what every pilot is given and what it returns.

Both pilots are complete autonomy stacks flying the same `uam_fdm` vehicle at the same physics
rate. Each decision, a pilot returns an `Actuation`:

* `RotorCommand`: rotor-speed commands [rad/s], held for the decision period (what the MPC emits);
* `VelocityCommand`: a world-frame velocity (and heading) setpoint for the vehicle's own low-level
  controller (`uam_fdm.vehicle.control`), which then computes rotor-speed commands at the physics rate
  (what the learned pilot emits: policy -> velocity command -> low-level controller -> rotors).

Either way the simulator applies rotor-speed commands at every physics step and records them.
An actuation may be held for several control periods (`hold_periods`): the learned pilot decides
at 10 Hz over a 50 Hz low-level controller. The runner then flies the held command period by
period, checking the episode's end rules after each, and counts one decision.
What both pilots know (the fairness statement): the vehicle's parameters, the building map, the
air density, the forecast turbulence level (the scenario's category: none, light, moderate, severe),
and the full vehicle state at each decision (perfect state estimation). Neither knows the wind or
its gusts: the steady wind and the turbulence realisation are the simulator's alone. (The classical
pilot sizes its clearance margins from the forecast level; the learned pilot does not use it.)

At the end of an episode the runner's caller asks the pilot for its `episode_report()`: a typed
`PilotReport` of what it did (the classical pilot: planning, replans, its MPC), saved with the
episode and read back as the same type, or None when the pilot has nothing to add.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from uam_fdm.air.atmosphere import Atmosphere
from uam_fdm.air.wind import TurbulenceLevel
from uam_fdm.episode import Outcome
from uam_fdm.renamed import renamed
from uam_fdm.vehicle.dynamics import VehicleDynamics
from uam_fdm.vehicle.params import VehicleParams

if TYPE_CHECKING:  # the city module is imported lazily by its users; only its type is named here
    from uam_fdm.city.buildings import BuildingMap


@dataclass(frozen=True)
class Task:
    """One flight: from `start_m` to within `goal_radius_m` of `goal_m` (world ENU, m) before `timeout_s`."""

    start_m: tuple[float, float, float]
    goal_m: tuple[float, float, float]
    goal_radius_m: float = 2.0
    timeout_s: float = 120.0
    start_yaw_rad: float = 0.0


@dataclass(frozen=True)
class World:
    """What a pilot may know about the world it flies in (no wind: see the module docstring).

    `turbulence` is the forecast level, a category, not the gusts the vehicle will meet.
    """

    vehicle: VehicleParams
    dynamics: VehicleDynamics
    city: BuildingMap
    atmosphere: Atmosphere
    turbulence: TurbulenceLevel = TurbulenceLevel.NONE

    def __post_init__(self) -> None:
        object.__setattr__(self, "turbulence", TurbulenceLevel.parse(self.turbulence))  # "light" accepted


@dataclass(frozen=True)
class Observation:
    """What the pilot sees at a decision: time [s] and the full vehicle state (13 + n,)."""

    t_s: float
    x: np.ndarray


@dataclass(frozen=True)
class RotorCommand:
    """Rotor-speed commands [rad/s] (n,), held over `hold_periods` control periods."""

    rotor_speeds_rad_s: np.ndarray
    hold_periods: int = 1


@dataclass(frozen=True)
class VelocityCommand:
    """Velocity setpoint [m/s] world ENU and heading [rad] for the low-level controller, held over
    `hold_periods` control periods."""

    velocity_enu_m_s: np.ndarray
    yaw_rad: float = 0.0
    hold_periods: int = 1


Actuation = RotorCommand | VelocityCommand


@dataclass(frozen=True)
class ResetInfo:
    """What a pilot reports after `reset`: whether it can fly the task, and why not.

    Attributes:
        ok: False when the pilot has no way to fly the task (e.g. no path found in the budget).
        status: a short machine-readable status ("ok", "planner_failure", "invalid_start", ...).
        plan_time_s: wall time spent planning inside reset [s] (0 for pilots that do not plan).
        detail: human-readable detail.
    """

    ok: bool
    status: str = "ok"
    plan_time_s: float = 0.0
    detail: str = ""


@runtime_checkable
class PilotReport(Protocol):
    """What a pilot reports about one episode when it ends: a frozen dataclass, saved in the episode
    file (`to_json`) and read back as the same type (`from_json`)."""

    @property
    def plan_time_s(self) -> float:
        """Planning over the whole episode [s] (at reset and at every replan); it replaces the planning
        time the runner measured around `reset`."""
        ...

    def failure_reason(self, outcome: Outcome) -> Outcome | None:
        """A more specific reason than `outcome` for a failed episode (e.g. the solver), else None."""
        ...

    def to_json(self) -> dict[str, Any]:
        """JSON-ready fields (NaN as null)."""
        ...

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> PilotReport | None:
        """The report saved by `to_json` (missing fields of older files as NaN or empty), or None when
        `data` holds none of its fields."""
        ...


@runtime_checkable
class Pilot(Protocol):
    """A pilot. The runner calls `reset` once per episode, then `act` once per decision (every
    control period, or every `hold_periods` of the previous actuation); after the episode its caller
    asks for `episode_report`."""

    name: str

    def reset(self, world: World, task: Task, seed: int) -> ResetInfo:
        """Prepare for an episode (the classical pilot plans here; the runner times it)."""
        ...

    def act(self, obs: Observation) -> Actuation:
        """Decide the actuation for the next decision period."""
        ...

    def episode_report(self) -> PilotReport | None:
        """What the pilot did in the episode flown since `reset` (None: nothing beyond the trajectory)."""
        ...


if not TYPE_CHECKING:  # hidden from the type checker: our own code must use the new names (`uam_fdm.renamed`)
    def __getattr__(name: str) -> Any:
        """The old name `Agent` (kept for one release, for plug-ins written against it): `Pilot`, with a warning."""
        return renamed(__name__, name, {"Agent": "Pilot"})
