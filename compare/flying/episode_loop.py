"""THE episode loop: flies any pilot through the same simulator and records what happened.

The runner owns the clock: the pilot decides once per decision (timed with one stopwatch,
`time.perf_counter`; an actuation may be held for several control periods), the simulator
advances each control period at the physics rate, and
clearance to the city and the ground is checked at every physics step with the city's exact
clearance (the same geometry FCL holds). The episode ends on success (inside the goal radius),
collision, leaving the flight volume, a non-finite state or the timeout; a pilot that cannot fly
the task (e.g. no path found) ends it before the first step. The end rules are `uam_fdm.episode`'s,
the same the learned pilot's training environment applies.

Every decision is recorded as given: its command (rotor speeds, or a velocity and heading), how long it is held and,
for a pilot that tells it, the observation vector it decided on (`DecisionRecord`): what imitation learning or
offline RL trains on. A pilot tells its observation through `ObservingPilot.last_observation`; the shipped learned
pilot's is read as its policy is given it (`_PolicyTap`), without changing what it computes.

Truth and belief: the loop flies and scores against `Truth` (the city as it stands); the pilot gets the
`World` (the prior map) and, at `perfect` sensing, the true state; otherwise the vehicle's sensors (the scenario's, or
those the pilot states it flies with, `uam_fdm.pilot.flown_sensing`) and navigation filter
(`uam_fdm.sensing.onboard.Onboard`) turn each flown period into readings and an estimate, the decision acts on
the estimate of the latency ago, and a velocity command's controller flies on the current estimate.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace
from types import TracebackType
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from uam_fdm import episode
from uam_fdm.air.wind import WindField
from uam_fdm.episode import Outcome
from uam_fdm.pilot import (
    Observation,
    Pilot,
    ResetInfo,
    RotorCommand,
    Task,
    Truth,
    VelocityCommand,
    World,
    flown_sensing,
)
from uam_fdm.sim import Simulator
from uam_fdm.vehicle.ground_effect import height_above_surface
from uam_fdm.vehicle.model import hover_state

if TYPE_CHECKING:  # the sensors (Embree, the filter) load only when a vehicle senses
    from uam_fdm.sensing.onboard import NavRecord
    from uam_fdm.sensing.specs import SensingConfig

log = logging.getLogger(__name__)

ROTOR_SPEEDS, VELOCITY_YAW = "rotor_speeds_rad_s", "velocity_enu_m_s_yaw_rad"
"""What a decision commanded: rotor speeds [rad/s], or a velocity world ENU [m/s] and heading [rad]."""


@dataclass(frozen=True)
class DecisionRecord:
    """What the pilot commanded at each of an episode's D decisions (in the order of `Trajectory.decision_t_s`).

    Attributes:
        kinds: per decision, `ROTOR_SPEEDS` or `VELOCITY_YAW`.
        commands: per decision, the command as flown: (n,) rotor speeds [rad/s], or (4,) [v_east, v_north, v_up]
            world ENU [m/s] and the heading [rad].
        hold_periods: (D,) control periods each command is held.
        observations: per decision, the observation vector the pilot decided on (the learned pilot: its policy's
            raw input), None where the pilot tells none.
    """

    kinds: tuple[str, ...]
    commands: tuple[np.ndarray, ...]
    hold_periods: np.ndarray
    observations: tuple[np.ndarray | None, ...]


@runtime_checkable
class ObservingPilot(Protocol):
    """A pilot that tells the observation vector its last decision was made on (recorded with the decision)."""

    def last_observation(self) -> np.ndarray | None:
        """The (k,) observation vector of the last `act` (None: none for it)."""


@dataclass(frozen=True)
class Trajectory:
    """One flown episode, sampled at the physics rate (row 0 is the initial state).

    Attributes:
        t_s: (M,) time [s].
        states: (M, 13 + n) vehicle state (see `uam_fdm.vehicle.model`).
        rotor_commands: (M, n) rotor-speed command applied during the step ending at each row
            [rad/s] (row 0: the hover trim the episode starts from).
        wind_enu_m_s: (M, 3) wind the vehicle flew in [m/s] (held per decision period).
        clearance_m: (M,) signed distance from the vehicle's collision sphere to the nearest
            building or the ground [m].
        decision_t_s: (D,) times of the pilot's decisions [s].
        compute_s: (D,) wall time of each decision [s].
        energy_J: rotor shaft energy over the flight [J].
        outcome: how it ended: an end rule's outcome, or `Outcome.PLANNER_FAILURE` when the pilot could
            not fly the task (before the first step).
        plan_time_s: planning time the pilot reported at reset [s].
        detail: why the episode ended, in words.
        shaft_power_W: (M,) total rotor shaft power Σ Q_i·Ω_i of the model at each row's state, in the air
            density held over the control period that produced it (row 0: the first period's) [W]; the
            integrand of `energy_J`. None in an episode file saved before it was recorded.
        estimate_m: (M, 3) the navigation estimate's position at each row (held between the filter's outputs at
            the control periods' ends), world ENU [m]; None at perfect sensing (the estimate is the truth).
        unmapped_clearance_m: (M,) signed clearance of the collision sphere to the obstacles the prior map lacks
            [m]; None when it lacks none.
        nav: the onboard estimation's record (errors, GNSS epochs, when the lidar first sensed each unmapped
            obstacle); None at perfect sensing or read from a file.
        lidar_hits_m: (H, 4) [t_s, x, y, z] a thinned set of the lidar's true hit points, world ENU [m] (the
            viewer's layer); None at perfect sensing.
        decisions: what the pilot commanded at each decision, and the observation it decided on where it tells
            it; None in an episode saved before it was recorded, or read from the store without asking for it
            (`compare.results.tables.episode_from_tables(..., with_decisions=True)`).
    """

    t_s: np.ndarray
    states: np.ndarray
    rotor_commands: np.ndarray
    wind_enu_m_s: np.ndarray
    clearance_m: np.ndarray
    decision_t_s: np.ndarray
    compute_s: np.ndarray
    energy_J: float
    outcome: Outcome
    plan_time_s: float
    detail: str = ""
    shaft_power_W: np.ndarray | None = None
    estimate_m: np.ndarray | None = None
    unmapped_clearance_m: np.ndarray | None = None
    nav: NavRecord | None = None
    lidar_hits_m: np.ndarray | None = None
    decisions: DecisionRecord | None = None

    @property
    def success(self) -> bool:
        return self.outcome == Outcome.SUCCESS


def run_episode(world: World, pilot: Pilot, task: Task, wind: WindField, seed: int, *,
                pilot_name: str | None = None, truth: Truth | None = None) -> Trajectory:
    """Fly `pilot` on `task` in `world` under `wind` (which must cover `task.timeout_s` + one period).

    `truth`: the city as it stands and the sensing level; None: the world's map is the truth and the pilot flies
    on the true state (perfect sensing). Below perfect sensing the vehicle carries the sensors the pilot flies with
    (`uam_fdm.pilot.flown_sensing`: the scenario's unless the pilot states others, then its `World.sensing` says so).

    Raises:
        PilotError: the pilot commanded what cannot be flown, naming it (`pilot_name`, default `pilot.name`).
    """
    truth = Truth(world.city) if truth is None else truth
    p, dyn, city = world.vehicle, world.dynamics, truth.city
    radius = p.collision_radius_m
    sim = Simulator(dyn, world.atmosphere, wind)
    start = np.asarray(task.start_m, float)
    x0 = hover_state(p, start, task.start_yaw_rad, density_ratio=world.atmosphere.density_ratio(start[2]))
    sim.reset(x0)
    onboard = None
    if not truth.perfect and truth.sensing is not None:
        from uam_fdm.sensing.onboard import Onboard

        sensing = _sensing_flown(pilot_name or pilot.name, pilot, truth.sensing)
        if sensing is not truth.sensing:  # a pilot flying with other sensors than the scenario's is told them
            world = replace(world, sensing=sensing)
        lacks = () if truth.unmapped is None else truth.unmapped.building_ids.tolist()
        onboard = Onboard(sensing, city, truth.ray_caster(), world.atmosphere, x0, dyn.dt_s, truth.sensing_seed,
                          unmapped_ids=lacks)
    estimates = None if onboard is None else [onboard.estimated_position_m()[None]]
    unmapped = truth.unmapped
    near_unmapped = None if unmapped is None else [unmapped.obstacle_clearance_m(x0[None, 0:3], radius)]
    info = pilot.reset(world, task, seed)
    if not isinstance(info, ResetInfo):  # a plug-in's mistake: its cell fails naming it, not at `info.ok`
        raise PilotError(f"pilot {pilot_name or pilot.name!r}: reset returned {info!r:.60}, not a ResetInfo "
                         f"(uam_fdm.pilot.ResetInfo)")
    hover = x0[dyn.layout.rotor]
    times, states, cmds, winds, clear = [np.zeros(1)], [x0[None]], [hover[None]], [np.zeros((1, 3))], []
    clear.append(np.array([_clearance(city, x0[None, 0:3], radius)[0]]))
    power = [np.array([dyn.shaft_power_W(x0, sim.env(x0, 0.0))])]  # P(Ω, σ): needs no height above ground
    decision_t, compute = [], []
    goal = np.asarray(task.goal_m, float)
    outcome, detail = Outcome.TIMEOUT, f"not at the goal after {task.timeout_s:g} s"
    if not info.ok:
        outcome, detail = Outcome.PLANNER_FAILURE, f"{info.status}: {info.detail}"
    lo, hi = np.asarray(city.bounds_min_m, float), np.asarray(city.bounds_max_m, float)
    held = 0
    with _DecisionLog(pilot) as decided:  # the shipped learned pilot's observations are read while it flies
        while info.ok and not episode.timed_out(sim.state.t_s, task.timeout_s):
            s = sim.state
            if held <= 0:  # a decision (else the previous actuation is still held)
                obs = Observation(s.t_s, s.x.copy()) if onboard is None else onboard.observation(s.t_s)
                t0 = time.perf_counter()
                act = pilot.act(obs)
                compute.append(time.perf_counter() - t0)
                decision_t.append(s.t_s)
                command = _checked_command(pilot_name or pilot.name, act, p.n_rotors, s.t_s)
                held = act.hold_periods
                decided.add(act, command)
            held -= 1
            # ground effect: the height above the surface below, from the clearance at the period's start
            height = float(height_above_surface(city, s.x[None, 0:3], clear[-1][-1:], p)[0])
            env = sim.env(s.x, s.t_s, height)  # built once: flown, and recorded (wind, power)
            if isinstance(act, RotorCommand):
                r = sim.advance(command, env=env)
            else:
                offset = None if onboard is None else onboard.controller_offset(s.x)
                r = sim.advance_velocity(command, env=env, seen_offset=offset)
            n_sub = r.states.shape[0]
            t_sub = s.t_s + dyn.dt_s * np.arange(1, n_sub + 1)
            times.append(t_sub)
            states.append(r.states)
            cmds.append(r.rotor_commands)
            winds.append(np.tile(env[:3], (n_sub, 1)))
            power.append(dyn.shaft_power_batch_W(r.states, env))
            finite = bool(np.all(np.isfinite(r.states)))
            c = _clearance(city, r.states[:, 0:3], radius) if finite else np.full(n_sub, np.nan)
            clear.append(c)
            if near_unmapped is not None and unmapped is not None:
                near_unmapped.append(unmapped.obstacle_clearance_m(r.states[:, 0:3], radius) if finite
                                     else np.full(n_sub, np.nan))
            if onboard is not None and estimates is not None:
                held_estimate = np.repeat(estimates[-1][-1:], n_sub, axis=0)
                if finite:
                    onboard.advance(s.x, r.states, s.t_s)
                    held_estimate[-1] = onboard.estimated_position_m()
                estimates.append(held_estimate)
            code = int(episode.period_outcome(r.states[None], episode.collided(c[None]), lo, hi, goal,
                                              task.goal_radius_m)[0])
            ended = episode.OUTCOME_OF_CODE[code]  # None while running
            if ended is not None:
                outcome = ended
                detail = _detail(code, r.states, c, t_sub, s.t_s, sim.state.t_s, task, city)
                break
    record = None if onboard is None else onboard.record()
    return Trajectory(
        t_s=np.concatenate(times), states=np.concatenate(states), rotor_commands=np.concatenate(cmds),
        wind_enu_m_s=np.concatenate(winds), clearance_m=np.concatenate(clear),
        decision_t_s=np.array(decision_t), compute_s=np.array(compute), energy_J=sim.state.energy_J,
        outcome=outcome, plan_time_s=info.plan_time_s, detail=detail, shaft_power_W=np.concatenate(power),
        estimate_m=None if estimates is None else np.concatenate(estimates),
        unmapped_clearance_m=None if near_unmapped is None else np.concatenate(near_unmapped),
        nav=record, lidar_hits_m=None if record is None else record.lidar_hits, decisions=decided.record())


class _PolicyTap:
    """Stands in for a pilot's `policy` while it flies (the shipped learned pilot's, whose `act` gives its policy
    the raw observation): passes every call through unchanged and keeps the observation of the last
    `act_batch` call."""

    def __init__(self, policy: Any) -> None:
        self.wrapped = policy
        self.last: np.ndarray | None = None

    def act_batch(self, obs: np.ndarray) -> Any:
        """The policy's actions for `obs` (N, k), keeping `obs`'s single row (None for a batch of several)."""
        rows = np.asarray(obs, dtype=float)
        self.last = rows.reshape(-1).copy() if rows.ndim == 2 and rows.shape[0] == 1 else None
        return self.wrapped.act_batch(obs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.wrapped, name)


class _DecisionLog:
    """Records each decision's command and hold, and the observation vector the pilot decided on where it tells it
    (`ObservingPilot`) or where its policy is read (`_PolicyTap`, put in place for the episode and taken out after,
    whatever happens)."""

    def __init__(self, pilot: Pilot) -> None:
        self.pilot = pilot
        self.kinds: list[str] = []
        self.commands: list[np.ndarray] = []
        self.holds: list[int] = []
        self.observations: list[np.ndarray | None] = []
        self.tap: _PolicyTap | None = None
        self.observing = isinstance(pilot, ObservingPilot)

    def __enter__(self) -> _DecisionLog:
        policy = getattr(self.pilot, "policy", None)
        if not self.observing and callable(getattr(policy, "act_batch", None)):
            tap = _PolicyTap(policy)
            try:
                setattr(self.pilot, "policy", tap)  # noqa: B010 (a Pilot does not declare it)
                self.tap = tap
            except AttributeError:  # a pilot whose policy cannot be set: no observation recorded
                log.debug("pilot %s: its policy's observations are not recorded", getattr(self.pilot, "name", "?"))
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        if self.tap is not None:
            setattr(self.pilot, "policy", self.tap.wrapped)  # noqa: B010
            self.tap = None

    def add(self, act: RotorCommand | VelocityCommand, command: np.ndarray) -> None:
        """Record a decision's actuation `act` (checked: `command` is its vector, `_checked_command`)."""
        self.kinds.append(ROTOR_SPEEDS if isinstance(act, RotorCommand) else VELOCITY_YAW)
        self.commands.append(np.array(command, dtype=float))
        self.holds.append(int(act.hold_periods))
        seen: np.ndarray | None = None
        if self.observing:
            told = self.pilot.last_observation()  # type: ignore[attr-defined]
            seen = None if told is None else np.array(told, dtype=float).reshape(-1)
        elif self.tap is not None:
            seen, self.tap.last = self.tap.last, None
        self.observations.append(seen)

    def record(self) -> DecisionRecord:
        """What was recorded, as a `DecisionRecord`."""
        return DecisionRecord(tuple(self.kinds), tuple(self.commands), np.array(self.holds, dtype=np.int64),
                              tuple(self.observations))


class PilotError(RuntimeError):
    """A pilot gave a command that cannot be flown (not an actuation, not finite, the wrong shape, a bad hold):
    its cell fails as a "pilot error" naming the pilot and the value, rather than flying idle rotors into the
    ground and being scored as a collision."""


def _checked_command(name: str, act: object, n_rotors: int, t_s: float) -> np.ndarray:
    """The command vector of actuation `act` (rotor speeds [rad/s], or velocity ENU [m/s] and yaw [rad]).

    Raises:
        PilotError: naming the pilot, the time and the value.
    """
    where = f"pilot {name!r} at t = {t_s:.2f} s"
    if not isinstance(act, (RotorCommand, VelocityCommand)):
        raise PilotError(f"{where} returned {type(act).__name__}, not a RotorCommand or VelocityCommand")
    hold = act.hold_periods
    if isinstance(hold, bool) or not isinstance(hold, (int, np.integer)) or hold < 1:
        raise PilotError(f"{where} asked to hold its command for {hold!r} periods; expected an integer >= 1")
    raw = act.rotor_speeds_rad_s if isinstance(act, RotorCommand) else act.velocity_enu_m_s
    what, size = (f"{n_rotors} rotor speeds [rad/s]", n_rotors) if isinstance(act, RotorCommand) else (
        "a velocity [m/s] of 3 components", 3)
    try:
        vector = np.asarray(raw, dtype=float)
        command = vector if isinstance(act, RotorCommand) else np.append(vector, float(act.yaw_rad))
    except (TypeError, ValueError):
        raise PilotError(f"{where} commanded {_shown(raw)}: expected {what}") from None
    if vector.shape != (size,):
        raise PilotError(f"{where} commanded {_shown(raw)} of shape {vector.shape}: expected {what}")
    if not np.all(np.isfinite(command)):
        raise PilotError(f"{where} commanded {_shown(command)}: not finite")
    return command


def _sensing_flown(name: str, pilot: Pilot, scenario: SensingConfig) -> SensingConfig:
    """The sensors `pilot` flies with at the scenario's sensing `scenario` (`uam_fdm.pilot.flown_sensing`).

    Raises:
        PilotError: the pilot stated something other than sensors of the scenario's level, naming it.
    """
    from uam_fdm.sensing.specs import SensingConfig

    flown = flown_sensing(pilot, scenario)
    if not isinstance(flown, SensingConfig) or flown.level != scenario.level:
        raise PilotError(f"pilot {name!r}: sensing_flown gave {_shown(flown)}; expected a SensingConfig of the "
                         f"scenario's level {scenario.level!r}")
    return flown


def _shown(value: object) -> str:
    """A command as the error shows it (short)."""
    text = np.array2string(value, precision=4, threshold=8) if isinstance(value, np.ndarray) else repr(value)
    text = " ".join(text.split())
    return text if len(text) <= 120 else text[:120] + "..."


def _detail(code: int, states: np.ndarray, clearance: np.ndarray, t_sub: np.ndarray, t_start_s: float,
            t_end_s: float, task: Task, city) -> str:
    """Why the period ended the episode, in words (the substep where it happened)."""
    if code == episode.NONFINITE:
        return f"state became non-finite at t = {t_start_s:.2f} s"
    if code == episode.COLLISION:
        k = int(np.argmax(clearance < 0.0))
        return f"collision at t = {t_sub[k]:.3f} s, clearance {clearance[k]:.3f} m"
    if code == episode.OUT_OF_BOUNDS:
        k = int(np.argmin(city.in_bounds(states[:, 0:3])))
        return f"left the flight volume at t = {t_sub[k]:.3f} s"
    return f"within {task.goal_radius_m:g} m of the goal at t = {t_end_s:.2f} s"


def _clearance(city, points: np.ndarray, radius: float) -> np.ndarray:
    """Signed clearance of the sphere to buildings and the ground (the city includes the ground)."""
    return np.asarray(city.clearance(points, radius).distance_m)
