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
What every pilot knows (the fairness statement), at every sensing level: the vehicle's parameters, its sensors'
specifications (`World.sensing`), the prior map (`World.city`: the survey, which may miss buildings and cranes or
have them wrong; the scenario's `map_error`/`unmapped` keys), the air density, the forecast turbulence level (a
category: none, light, moderate, severe) and, each decision, an `Observation`:

* `perfect`: the exact vehicle state (the estimate is the truth, its covariance None) and no readings: the
  privileged reference, every figure before sensing existed;
* `nominal` / `degraded`: the navigation filter's estimate (`uam_fdm.sensing.nav_filter`: IMU, barometer, GNSS,
  heading aid) in the vehicle-state layout with its error-state covariance, as of `latency_s` ago, and the
  readings since the previous decision (lidar scans, GNSS fixes, barometer and heading readings; raw IMU for a
  pilot with its own filter). The velocity controller under a `VelocityCommand` flies on the current estimate.

No pilot knows the true city, the true state, the wind or its gusts: they are the simulator's (`Truth`), and
every metric is scored on them. (The classical pilot sizes its clearance margins from the forecast level; the
learned pilot does not use it.)

A pilot flies with the scenario's sensors unless it states others (`ChoosesSensors.sensing_flown`, looked up with
that default by `flown_sensing`): the learned pilot carries the reduced lidar it was trained on.

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

if TYPE_CHECKING:  # the city and sensor modules are imported lazily by their users; only their types are named here
    from uam_fdm.city.buildings import BuildingMap
    from uam_fdm.sensing.baro import BaroReading
    from uam_fdm.sensing.gnss import GnssFix
    from uam_fdm.sensing.heading import HeadingReading
    from uam_fdm.sensing.imu import ImuSamples
    from uam_fdm.sensing.lidar import LidarScan
    from uam_fdm.sensing.raycast import RayCaster
    from uam_fdm.sensing.specs import SensingConfig


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
    """What a pilot may know about the world it flies in (see the module docstring).

    `city` is the prior map, not the city as it stands; `turbulence` is the forecast level, a category, not the
    gusts the vehicle will meet; `sensing` the specifications of the vehicle's sensors (None: perfect sensing).
    """

    vehicle: VehicleParams
    dynamics: VehicleDynamics
    city: BuildingMap
    atmosphere: Atmosphere
    turbulence: TurbulenceLevel = TurbulenceLevel.NONE
    sensing: SensingConfig | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "turbulence", TurbulenceLevel.parse(self.turbulence))  # "light" accepted


@dataclass(frozen=True)
class SensorData:
    """The readings a pilot receives at a decision: those since the previous decision, each in time order, as old as
    the sensing latency. Empty at `perfect` sensing."""

    lidar: tuple[LidarScan, ...] = ()
    imu: tuple[ImuSamples, ...] = ()
    gnss: tuple[GnssFix, ...] = ()
    baro: tuple[BaroReading, ...] = ()
    heading: tuple[HeadingReading, ...] = ()


NO_READINGS = SensorData()


@dataclass(frozen=True)
class Observation:
    """What the pilot sees at a decision.

    Attributes:
        t_s: the decision's time [s].
        x: the vehicle state as the pilot knows it (13 + n,): at `perfect` sensing the true state, else the
            navigation estimate (position, velocity, attitude; body rates from the gyro less its estimated bias;
            rotor speeds from the motor controllers' telemetry).
        covariance: the estimate's error-state covariance (16, 16) [δp m, δv m/s ENU, δθ rad body, accelerometer
            bias m/s², gyro bias rad/s, barometer offset m]; None at `perfect` sensing (exact).
        sensors: the readings since the previous decision.
        estimate_t_s: the time the estimate is of [s] (earlier than `t_s` by the sensing latency).
    """

    t_s: float
    x: np.ndarray
    covariance: np.ndarray | None = None
    sensors: SensorData = NO_READINGS
    estimate_t_s: float | None = None


@dataclass(frozen=True, eq=False)
class Truth:
    """What the simulator holds and no pilot is given: the city as it stands, how the vehicle senses, and the
    obstacles the prior map lacks.

    Attributes:
        city: the true city (the prior map plus what the survey missed, errors undone).
        sensing: the sensing level flown.
        sensing_seed: the seed of every sensor's noise in the episode.
        unmapped: the true obstacles absent from the prior map, as a map of their own (for their clearance), or None.
        caster: a ray caster over `city` when the caller keeps one per city (else built on first use).
    """

    city: BuildingMap
    sensing: SensingConfig | None = None
    sensing_seed: int = 0
    unmapped: BuildingMap | None = None
    caster: RayCaster | None = None

    @property
    def perfect(self) -> bool:
        """True: the pilot flies on the truth (no sensors simulated)."""
        return self.sensing is None or self.sensing.perfect

    def ray_caster(self) -> RayCaster:
        """The ray caster over the true city (built on first use, then kept)."""
        if self.caster is None:
            from uam_fdm.sensing.raycast import RayCaster  # Embree is loaded only when something senses

            object.__setattr__(self, "caster", RayCaster(self.city))
        assert self.caster is not None
        return self.caster


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
    asks for `episode_report`. Optionally it states the sensors it flies with (`ChoosesSensors.sensing_flown`;
    without it: the scenario's)."""

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


@runtime_checkable
class ChoosesSensors(Protocol):
    """A pilot that flies with other sensors than the scenario's at a sensing level (optional: a pilot without
    `sensing_flown` flies with the scenario's, `flown_sensing`). The learned pilot carries a reduced lidar, the one
    it was trained on."""

    def sensing_flown(self, scenario: SensingConfig) -> SensingConfig:
        """The sensors this pilot flies with where the scenario states `scenario` (not `perfect`): its vehicle's
        `Onboard` is built from them, and its `World.sensing` states them."""
        ...


@runtime_checkable
class StatesMargins(Protocol):
    """A pilot that states the clearance it keeps (optional): the margin in force from each of its decisions on.
    The scorer measures the vehicle's true clearance against it (`compare.flying.promise`); the pilot never sees
    that truth."""

    def margins_in_force(self) -> tuple[np.ndarray, np.ndarray]:
        """Over the episode flown since `reset`: its decisions' times (D,) [s] and the margin in force from each
        (D,) [m], the clearance beyond its collision sphere it keeps to every obstacle there."""
        ...


def flown_sensing(pilot: object, scenario: SensingConfig) -> SensingConfig:
    """The sensors `pilot` flies with at the scenario's sensing `scenario`: its `sensing_flown` (`ChoosesSensors`)
    when it has one, else `scenario` itself."""
    choose = getattr(pilot, "sensing_flown", None)
    return scenario if choose is None else choose(scenario)


if not TYPE_CHECKING:  # hidden from the type checker: our own code must use the new names (`uam_fdm.renamed`)
    def __getattr__(name: str) -> Any:
        """The old name `Agent` (kept for one release, for plug-ins written against it): `Pilot`, with a warning."""
        return renamed(__name__, name, {"Agent": "Pilot"})
