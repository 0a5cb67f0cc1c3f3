"""The classical pilot: plan with OMPL RRT* (timed), time-parameterise, track with NMPC, map what it senses, replan.

Implements the `uam_fdm.pilot.Pilot` protocol and emits rotor-speed commands. Its clearance margins
follow from the vehicle's measured tracking error in the forecast turbulence and the air density
(`planners.margins`), widened by k σ of the navigation estimate's position when it flies on one. It replans
when the tracking error exceeds a threshold, or when the MPC's last prediction comes closer to an obstacle than
the MPC's margin (each bounded per episode; replanning time counts as planning time).

Flying on its sensors (any level but `perfect`) it also maps: each lidar scan goes into `planners.sensed_map`
(an OctoMap octree of what the prior map lacks; prior parts seen through are taken out), and the pilot plans and
tracks on the fused map. It replans when a newly sensed obstacle comes within the margin of the path still to fly
("blocked") or when k σ has grown past the margin it planned with ("uncertainty"). Such a replan costs flight
time: for `replan_budget_s` the vehicle brakes along its velocity, and the new plan starts from where the braking
leaves it then (deterministic: the budget, not the wall clock). When no path exists in what it knows it holds
there (a hover) and tries again every `hold_retry_s`. At `perfect` sensing nothing is sensed and a replan is
instantaneous, as before sensing existed (the privileged reference). `episode_report()` gives what the tracker
did, for the metrics.
"""
from __future__ import annotations

import dataclasses
import itertools
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from planners.clearance import MarginTaper, endpoint_allowance
from planners.ladder import IN_FLIGHT_LADDER, LADDER, LadderResult, PlanStep, plan_with_escalation
from planners.margins import (
    MarginRule,
    Margins,
    TrackingErrorTable,
    forecast_gust_m_s,
    load_tracking_table,
    margins_for,
)
from planners.mpc import MPCConfig, MPCSolution, MPCTracker
from planners.report import ClassicalReport
from planners.rrt_star import PlannerConfig, PlanResult, densify
from planners.sensed_map import MappingConfig, SensedMap, scaled_to_vehicle
from planners.timing import (
    Reference,
    TimingLimits,
    braking_along,
    braking_reference,
    then_straight,
    time_parameterize,
)
from planners.visibility import arc_in_sight_m, in_sight, stopping_speed_m_s
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.pilot import Actuation, Observation, ResetInfo, RotorCommand, Task, VelocityCommand, World
from uam_fdm.sensing.raycast import RayCaster
from uam_fdm.vehicle.attitude import rotation_matrix

log = logging.getLogger(__name__)

REPLAN_CAUSES = ("tracking", "clearance", "blocked", "uncertainty")
# the causes after which the path flown is still clear in what the pilot knows and the vehicle on it: it flies on
# while the replan runs (a blocked path flies on only when the block lies beyond where it could stop then)
_FLYING_ON = ("uncertainty", "improve")
# a stop's path is tested this often [m]: closer than the thinnest sensed face (`MappingConfig.column_fit_m`) plus the
# vehicle's sphere, so that no test skips across one
_FREE_STEP_M = 0.25
_HOLD_STEP_M = 1.0  # spacing of the points a hold may move to [m]
_SEE_STEP_S = 0.1  # spacing in reference time of the points of the path ahead tested for a line of sight [s]


@dataclass(frozen=True)
class ClassicalConfig:
    """Settings of the plan-and-track pilot.

    Attributes:
        planner: OMPL planner settings (algorithm, deterministic iteration budget; its
            `safety_margin_m` is the fixed margin used when `margin_rule` is None or the table does
            not know the vehicle).
        mpc: NMPC settings (its `clearance_margin_m`: the fixed MPC margin, likewise).
        speed_fraction: share of the vehicle's speed caps the reference may use.
        accel_fraction: share of the vehicle's acceleration capability the reference may use.
        margin_rule: how margins follow from the tracking-error table (`planners.margins`); None:
            the fixed margins of `planner` and `mpc`.
        tracking_table: the tracking-error table file (None: the shipped one).
        replan_error_m: replan from the current position when the position error to the reference
            exceeds this [m]; None disables it.
        max_replans: at most this many tracking-error replans per episode.
        replan_on_clearance: replan from the current position when the MPC's last predicted states
            come closer to an obstacle (the map it knows: the prior, fused with what it sensed) than the MPC's margin.
        max_clearance_replans: at most this many clearance replans per episode.
        replan_cooldown_s: no clearance replan within this time of the previous replan [s] (the new
            reference needs a moment to pull the prediction out).
        time_fraction: a plan fits the task's time when its reference takes at most this share of the time left
            (the tracker lags the reference); the planning ladder climbs on past a step whose fastest plan does
            not (`planners.ladder`).
        ladder: the planning attempts, in order (`planners.ladder.LADDER`).
        in_flight_ladder: the attempts of a replan in flight on sensors, in order (`planners.ladder.IN_FLIGHT_LADDER`:
            smaller budgets, so that they fit `replan_budget_s`).
        mapping: how scans are mapped (flying on sensors; columns widened to the vehicle's radius,
            `planners.sensed_map.scaled_to_vehicle`).
        uncertainty_k: margins grow by this many σ of the estimate's position (its covariance's largest axis); 3 kept
            against 2 and 4 on the tuning pool's legs (`perf/uncertainty_k.py`, docs/planner.md).
        uncertainty_replan_m: replan when k σ exceeds what the flown plan's margins took by this much [m].
        replan_budget_s: flight time a replan in flight takes (braking meanwhile) [s]; calibrated so that the
            in-flight ladder and the map refresh before it fit it on this machine (perf/mapping.py).
        hold_retry_s: holding for want of a path, try again after this long [s].
        refuse_margin_m: a newly sensed obstacle blocks the path still to fly when it comes within the collision
            radius plus the margin at rest plus this [m] of it (half a voxel's diagonal covers the voxel's extent).
        fuse_period_s: the map the MPC keeps clear of is refreshed with what was sensed at most this often [s]
            (a replan always refreshes it first).
        uncertainty_check_s: once k σ has grown past the planned margin by `uncertainty_replan_m`, the path still to
            fly is measured against the widened margin at most this often [s]; it is replanned only when it no
            longer keeps it (a path with room to spare needs no new plan).
        improve_period_s: flying a plan found at the floor margin (slow wherever it passes closer than a speed's
            margin), or one made for a k σ that has since fallen by `uncertainty_replan_m` (an outage ended), try
            this often [s] for a faster one from where the reference will be after the replan budget, flying on
            meanwhile.
        improve_gain_s: such a plan replaces the flown one only when it arrives this much earlier [s].
        in_flight_climb_weight: the in-flight planner's `PlannerConfig.climb_weight` (a metre climbed costs this many
            metres flown level). A replan in flight takes each step's one path, not the fastest of several, and
            the lidar sees only 15 degrees above the horizon: at length's weight the shortest path went over the top
            of what was seen of a wall, the next scans saw more of it, and the vehicle climbed replan after replan
            (validation legs quad-003/0, quad-031/6: time-outs; docs/planner.md). 4 is the small quad's ratio of level
            to vertical speed; 1 plans for length as at reset.
        autopilot_gain_1_s: when the MPC fails with no previous plan to fall back on, the vehicle's velocity
            autopilot is commanded the reference's velocity plus this gain [1/s] times the position error.
        hold_search_m: holding where the MPC's margin at rest does not fit, the pilot moves to the nearest point that
            keeps it straight above, or within this distance [m] around.
        margin_recovery_m_s: on sensors, the MPC's clearance half-spaces ask a vehicle inside its margin (a drifting
            estimate, a newly sensed face) back out at this rate [m/s] over the horizon; inf: at once (as always at
            `perfect` sensing, the privileged reference).
        see_to_stop: on sensors, fly a plan no faster than lets the vehicle stop, with its margin at rest, short of
            the first point of the path still to fly that has not yet been in its lidar's sight (a line of sight
            through what it knows, within the lidar's range and, on the estimated attitude, its fan; remembered for
            the reference flown): the reference's clock slows (`planners.visibility`; docs/planner.md).
        see_reaction_s: the time [s] between a face coming into view and the vehicle braking for it (a scan, its
            latency and a decision).
    """

    planner: PlannerConfig = field(default_factory=PlannerConfig)
    mpc: MPCConfig = field(default_factory=MPCConfig)
    speed_fraction: float = 0.8
    accel_fraction: float = 0.5
    margin_rule: MarginRule | None = field(default_factory=MarginRule)
    tracking_table: Path | None = None
    replan_error_m: float | None = 5.0
    max_replans: int = 3
    replan_on_clearance: bool = True
    max_clearance_replans: int = 3
    replan_cooldown_s: float = 1.0
    time_fraction: float = 0.8
    ladder: tuple[PlanStep, ...] = LADDER
    in_flight_ladder: tuple[PlanStep, ...] = IN_FLIGHT_LADDER
    mapping: MappingConfig = field(default_factory=MappingConfig)
    uncertainty_k: float = 3.0
    uncertainty_replan_m: float = 0.5
    replan_budget_s: float = 1.1
    hold_retry_s: float = 1.0
    refuse_margin_m: float = 0.9
    fuse_period_s: float = 1.0
    uncertainty_check_s: float = 1.0
    improve_period_s: float = 4.0
    improve_gain_s: float = 1.0
    in_flight_climb_weight: float = 4.0
    autopilot_gain_1_s: float = 1.0
    hold_search_m: float = 10.0
    margin_recovery_m_s: float = 1.0
    see_to_stop: bool = True
    see_reaction_s: float = 0.2

    def __post_init__(self) -> None:
        for name in ("in_flight_climb_weight", "autopilot_gain_1_s", "hold_search_m"):
            w = getattr(self, name)
            if not (isinstance(w, (int, float)) and math.isfinite(w) and w > 0.0):
                raise ValueError(f"ClassicalConfig.{name} must be positive and finite, got {w!r}")
        if not (isinstance(self.see_reaction_s, (int, float)) and math.isfinite(self.see_reaction_s)
                and self.see_reaction_s >= 0.0):
            raise ValueError(f"ClassicalConfig.see_reaction_s must be non-negative and finite, got "
                             f"{self.see_reaction_s!r}")
        r = self.margin_recovery_m_s
        if not (isinstance(r, (int, float)) and not math.isnan(r) and r > 0.0):
            raise ValueError(f"ClassicalConfig.margin_recovery_m_s must be positive (inf: at once), got {r!r}")


@dataclass
class ClassicalStats:
    """Per-episode counters of the classical pilot (mutable, internal; `ClassicalReport` is the result)."""

    plan_time_s: float = 0.0
    replan_time_s: float = 0.0
    replans_by_cause: dict[str, int] = field(default_factory=lambda: dict.fromkeys(REPLAN_CAUSES, 0))
    mpc_solves: int = 0
    mpc_failures: int = 0
    mpc_solve_times_s: list[float] = field(default_factory=list)
    mpc_iterations: list[int] = field(default_factory=list)
    mpc_statuses: dict[str, int] = field(default_factory=dict)
    deviations_m: list[float] = field(default_factory=list)
    # the reference's speed at each decision, paired with `deviations_m` (the margin table bins by it)
    reference_speeds_m_s: list[float] = field(default_factory=list)
    # each decision's time and the margin in force at its reference point (the promise; the scorer measures the
    # true clearance against it, `compare.flying.promise`)
    promise_t_s: list[float] = field(default_factory=list)
    promise_margin_m: list[float] = field(default_factory=list)
    planner_attempts: int = 0
    planner_step: str = ""
    planner_candidates: int = 0
    planner_wall_caps: int = 0  # plans cut by the planner's wall-time cap (at reset and in flight)
    in_flight_replan_s: list[float] = field(default_factory=list)  # wall time of each replan flown through
    hover_holds: int = 0
    improvements_tried: int = 0  # searches for a faster plan (flying one found at the floor margin, or k σ eased)
    improvements_taken: int = 0
    hold_moves: int = 0  # hold references that move to where the MPC's margin fits
    clock_scale_min: float = 1.0  # the slowest the reference's clock ran (`see_to_stop`)
    autopilot_decisions: int = 0  # decisions handed to the vehicle's velocity autopilot (the MPC failed, no plan left)
    map_update_s: list[float] = field(default_factory=list)
    uncertainty_margin_m: list[float] = field(default_factory=list)


class ClassicalPilot:
    """RRT* + time-parameterisation + NMPC, flying by rotor-speed commands.

    Args:
        config: pilot settings.
        cache_dir: cache for the compiled MPC (default `uam_fdm.vehicle.codegen.default_cache_dir()`).
    """

    name = "rrt_mpc"

    def __init__(self, config: ClassicalConfig | None = None, cache_dir: Path | None = None) -> None:
        self.config = config if config is not None else ClassicalConfig()
        self._cache_dir = cache_dir
        self._trackers: dict[str, MPCTracker] = {}
        self._world: World | None = None
        self._table: TrackingErrorTable | None = None
        if self.config.margin_rule is not None:
            self._table = load_tracking_table(*(() if self.config.tracking_table is None
                                                 else (self.config.tracking_table,)))
        self.plan: PlanResult | None = None
        self.ladder_result: LadderResult | None = None  # the last planning ladder's: every candidate, judged
        self.reference: Reference | None = None
        self.last_solution: MPCSolution | None = None
        self.margins: Margins | None = None
        self.stats = ClassicalStats()

    # -- episode set-up -------------------------------------------------------------------------
    def tracker_for(self, world: World) -> MPCTracker:
        """The MPC for this world's vehicle (built and compiled once per vehicle)."""
        key = world.vehicle.fingerprint()
        if key not in self._trackers:
            self._trackers[key] = MPCTracker(world.vehicle, self.config.mpc, self._cache_dir)
        return self._trackers[key]

    def margins_for(self, world: World, task: Task) -> Margins:
        """The planner's and the MPC's margins for this vehicle, forecast turbulence and the field's air."""
        cfg = self.config
        if cfg.margin_rule is None:
            return Margins(cfg.planner.safety_margin_m, cfg.mpc.clearance_margin_m, math.nan, "fixed (configured)")
        # the table's airs are fields (density ratio at the ground), so look it up at the ground too
        sigma = float(world.atmosphere.density_ratio(0.0))
        return margins_for(self._table, cfg.margin_rule, world.vehicle, world.turbulence, sigma,
                           cfg.planner.safety_margin_m, cfg.mpc.clearance_margin_m)

    def reset(self, world: World, task: Task, seed: int) -> ResetInfo:
        """Choose the margins, plan from the task's start to its goal (timed) and prepare the tracker."""
        self._world, self._task, self._seed = world, task, int(seed)
        self._tracker = self.tracker_for(world)
        self._tracker.reset()
        self.stats = ClassicalStats()
        self.last_solution = None
        self._last_t: float | None = None
        self._last_replan_t = -math.inf
        # the air the reference is timed for: density at the start, gusts of the forecast level there
        self._sigma = float(world.atmosphere.density_ratio(float(task.start_m[2])))
        self._gust_m_s = forecast_gust_m_s(world.turbulence, float(task.start_m[2]))
        # the reference asks only for what the rotors can give in this air (thrust scales with density)
        cfg = self.config
        self._limits = TimingLimits.from_vehicle(world.vehicle, cfg.speed_fraction, cfg.accel_fraction, self._sigma,
                                                 self._gust_m_s)
        self._known: BuildingMap = world.city
        self._sensed: SensedMap | None = None
        sigma_m = 0.0
        if world.sensing is not None and not world.sensing.perfect:
            from uam_fdm.sensing.onboard import initial_covariance  # the filter's start: what the pad survey gives

            lidar = world.sensing.lidar
            mapping = scaled_to_vehicle(self.config.mapping, world.vehicle.collision_radius_m)
            self._sensed = SensedMap(world.city, mapping, lidar.max_range_m, lidar.vertical_fov_deg[1])
            sigma_m = position_sigma_m(initial_covariance(world.sensing))
        self._base_margins = self.margins_for(world, task)
        self._planned_extra_m = self.config.uncertainty_k * sigma_m
        self.margins = self._base_margins.widened(self._planned_extra_m)
        self._pending: tuple | None = None  # a plan made in flight, flown once its budget has passed
        self._hold_retry_t = math.inf  # holding for want of a path: when to try again
        self._retries = 0  # tries while holding (each plans from another seed)
        self._on_floor = False  # the plan flown was found at the floor margin (the speed margins did not fit)
        self._blocked = False
        self._extra_now = self._planned_extra_m
        self._blocked_ref_t = math.inf  # the reference's earliest time within reach of a newly sensed obstacle
        self._uncertainty_checked_t = -math.inf
        self._tried_t = 0.0  # the last plan's time (reset or in flight): improvements are spaced from it
        self._tapers: tuple[MarginTaper, ...] = ()
        self._map_dirty, self._fused_t = False, -math.inf
        # the reference's clock (`see_to_stop`): it runs at `_scale` of real time from `_clock_t` on
        self._scale, self._clock_t, self._braking = 1.0, 0.0, False
        self._ref_speed = 0.0  # the reference's speed [m/s] where `_clock_target` last looked
        self._caster: tuple[BuildingMap, RayCaster] | None = None  # lines of sight through the map known
        self._seen: tuple[Reference, np.ndarray, np.ndarray] | None = None  # what of the reference has been in sight
        self._planner_cfg = dataclasses.replace(self.config.planner, safety_margin_m=self.margins.planner_m)
        self._stage_mpc_margins = np.full(self._tracker.horizon_steps, self.margins.mpc_m)
        self._relaxed_ends: list[tuple[np.ndarray, float]] = []
        self._promise_ends: list[tuple[np.ndarray, float, float]] = []
        log.debug("margins: planner %.2f m, MPC %.2f m (%s)", self.margins.planner_m, self.margins.mpc_m,
                  self.margins.source)
        ok, status, detail = self._plan(np.asarray(task.start_m, float), t_start=0.0)
        return ResetInfo(ok=ok, status=status, plan_time_s=self.stats.plan_time_s, detail=detail)

    def _plan(self, start: np.ndarray, t_start: float, velocity_m_s: np.ndarray | None = None,
              in_flight: bool = False, lead_in: np.ndarray | None = None, faster: bool = False
              ) -> tuple[bool, str, str]:
        """Plan from `start` (ENU m) at `t_start` [s] moving at `velocity_m_s` (None: at rest) to the task's goal
        with the ladder (in flight: `in_flight_ladder`, no reachability search on a failure; as at reset, a step
        whose path would not arrive within `time_fraction` of the time left does not end the climb); on success the
        plan and its reference become the pilot's. `lead_in` (3,): the vehicle is there at `t_start` and the path
        runs straight from it to `start` (where braking along its velocity would stop it), so that the reference
        starts along the velocity. `faster`: in flight, look for a plan at the speed margins even when the flown
        plan needed the floor margin. Returns (ok, status, detail)."""
        world, margins = self._flying()
        task, cfg = self._task, self.config
        radius = world.vehicle.collision_radius_m
        limits = self._limits
        by_speed = margins.by_speed
        moving = 0.0 if velocity_m_s is None else float(np.linalg.norm(velocity_m_s))
        # the reference changes speed by at most the horizontal and vertical limits together
        accel = math.hypot(limits.max_accel_m_s2, limits.max_vertical_accel_m_s2)
        goal = self._goal_in_known(radius)
        ends = [(start, moving), (goal, 0.0)]
        if lead_in is not None:
            ends.append((np.asarray(lead_in, float), moving))
        tapers = tuple(MarginTaper((float(p[0]), float(p[1]), float(p[2])), *by_speed.taper(accel, v0))
                       for p, v0 in ends)
        references: dict[int, tuple[PlanResult, Reference]] = {}

        def judge(plan: PlanResult, margin_m: float, plan_tapers: tuple[MarginTaper, ...]) -> float:
            """The plan's flight time: its reference timed as it would be flown [s]."""
            flown = plan
            if lead_in is not None and plan.ok:
                path = np.vstack([np.asarray(lead_in, float)[None, :], plan.path_m])
                flown = dataclasses.replace(plan, path_m=path, length_m=float(
                    np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1))))
            ref = self._reference(flown, limits, margin_m, plan_tapers, velocity_m_s)
            references[id(plan)] = (flown, ref)
            return ref.duration_s if ref.ok else math.inf

        time_left = cfg.time_fraction * (task.timeout_s - t_start)
        ladder = cfg.ladder
        if in_flight:  # as at reset, a path that would arrive late does not end the climb (the fastest is flown
            # when none arrives in time)
            ladder = cfg.in_flight_ladder
            if self._on_floor and not faster:  # the speed margins did not fit this route before: no budget on them
                ladder = tuple(step for step in ladder if step.floor_margin) or ladder
        planner_cfg = (dataclasses.replace(self._planner_cfg, climb_weight=cfg.in_flight_climb_weight) if in_flight
                       else self._planner_cfg)
        found = plan_with_escalation(self._known, start, goal, radius, planner_cfg,
                                     seed=(self._seed + sum(self.stats.replans_by_cause.values()) + self._retries
                                           + self.stats.improvements_tried),
                                     floor_margin_m=by_speed.floor_m, tapers=tapers, ladder=ladder, judge=judge,
                                     time_available_s=time_left, diagnose=not in_flight)
        plan, self.ladder_result = found.plan, found
        self.stats.plan_time_s += found.plan_time_s
        self.stats.planner_wall_caps += found.wall_caps
        if velocity_m_s is None:  # the plan at reset: which step of the ladder found it
            self.stats.planner_attempts, self.stats.planner_step = len(found.attempts), found.step_name
            self.stats.planner_candidates = len(found.candidates)
        if not plan.ok:
            return False, "planner_failure", f"{plan.status}: {plan.message}"
        plan, reference = references[id(plan)]
        if not reference.ok:
            return False, "planner_failure", f"time-parameterisation: {reference.status}"
        self.plan, self.reference, self._t_ref0, self._tapers = plan, reference, t_start, tapers
        self._on_floor = found.margin_m < self._planner_cfg.safety_margin_m - 1e-9
        # near a start or goal closer than the margin at rest the requirement is relaxed (as in the planner)
        self._relaxed_ends, self._promise_ends = [], []
        for end in (np.asarray(plan.path_m[0], float), np.asarray(plan.path_m[-1], float)):
            mpc_floor = by_speed.mpc_fraction * by_speed.floor_m
            _, zone = endpoint_allowance(self._known.planning_map(), end, radius, mpc_floor)
            if zone > 0.0:
                self._relaxed_ends.append((end, zone))
            r_e, zone = endpoint_allowance(self._known.planning_map(), end, radius, by_speed.floor_m)
            if zone > 0.0:
                self._promise_ends.append((end, zone, r_e - radius))
        return True, "ok", ""

    def _goal_in_known(self, radius_m: float) -> np.ndarray:
        """Where to plan to (ENU m): the task's goal when the vehicle's sphere (`radius_m` [m]) is clear there in what
        the pilot knows; else, the arrival being anywhere within the goal radius, the clearest point of that region's
        inner part (`GOAL_REGION_FRACTION` of the radius, `goal_region_points`; a sensed wall's voxels and columns
        stand up to a few metres proud of the real one and can swallow a goal beside it); the goal itself when no
        point there is clear (the planner then says so)."""
        task = self._task
        goal = np.asarray(task.goal_m, float)
        known = self._known.planning_map()
        if known.clearance_one(float(goal[0]), float(goal[1]), float(goal[2]), radius_m) > 0.0:
            return goal
        points = goal_region_points(goal, GOAL_REGION_FRACTION * task.goal_radius_m)
        points = points[known.in_bounds(points, radius_m)]
        if not len(points):
            return goal
        clearance = known.clearance(points, radius_m).distance_m
        best = int(np.argmax(clearance))
        if clearance[best] <= 0.0:
            return goal
        log.info("the goal is inside what the pilot knows: planning to %s, %.1f m from it",
                 np.round(points[best], 2).tolist(), float(np.linalg.norm(points[best] - goal)))
        return points[best]

    def _reference(self, plan: PlanResult, limits: TimingLimits, margin_m: float,
                   tapers: tuple[MarginTaper, ...], velocity_m_s: np.ndarray | None) -> Reference:
        """A plan's reference, timed within `limits`, keeping `margin_m` (narrowed by `tapers`) and slowed where it
        passes closer than the cruise margin; from a moving vehicle it starts at its speed along the path (not at
        rest: no hard brake)."""
        world, margins = self._flying()
        start_speed = 0.0
        if velocity_m_s is not None and len(plan.path_m) > 1:
            tangent = plan.path_m[1] - plan.path_m[0]
            start_speed = max(0.0, float(velocity_m_s @ tangent) / max(float(np.linalg.norm(tangent)), 1e-9))
        return time_parameterize(plan.path_m, limits, self._known, world.vehicle.collision_radius_m, margin_m,
                                 start_speed_m_s=start_speed, tapers=tapers,
                                 speed_limit=margins.by_speed.speed_limit_m_s)

    def episode_report(self) -> ClassicalReport:
        """What the tracker did in the episode so far (see `ClassicalReport`)."""
        s, m = self.stats, self.margins
        ms = 1e3 * np.asarray(s.mpc_solve_times_s, float)
        dev = np.asarray(s.deviations_m, float)
        return ClassicalReport(
            plan_time_s=s.plan_time_s, replan_time_s=s.replan_time_s,
            replans_tracking=s.replans_by_cause["tracking"], replans_clearance=s.replans_by_cause["clearance"],
            mpc_solves=s.mpc_solves, mpc_failures=s.mpc_failures,
            mpc_solve_ms_median=float(np.median(ms)) if ms.size else math.nan,
            mpc_solve_ms_p95=float(np.percentile(ms, 95)) if ms.size else math.nan,
            mpc_statuses=dict(s.mpc_statuses),
            tracking_rms_m=float(np.sqrt(np.mean(dev ** 2))) if dev.size else math.nan,
            tracking_max_m=float(dev.max()) if dev.size else math.nan,
            planner_margin_m=m.planner_m if m else math.nan, mpc_margin_m=m.mpc_m if m else math.nan,
            margin_source=m.source if m else "", planner_margin_floor_m=m.floor_m if m else math.nan,
            planner_attempts=s.planner_attempts, planner_step=s.planner_step, planner_wall_caps=s.planner_wall_caps,
            # measured on the truth by the scorer from `margins_in_force` (`compare.flying.promise`)
            clearance_over_margin_min=math.nan,
            **self._sensing_report())

    def _sensing_report(self) -> dict[str, float]:
        """The report's fields of flying on sensors (none at `perfect` sensing: they stay NaN)."""
        sensed, s = getattr(self, "_sensed", None), self.stats
        if sensed is None:
            return {}
        replan_ms = 1e3 * np.asarray(s.in_flight_replan_s, float)
        update_ms = 1e3 * np.asarray(s.map_update_s, float)
        fused = sensed.fused()
        return dict(
            replans_blocked=s.replans_by_cause["blocked"], replans_uncertainty=s.replans_by_cause["uncertainty"],
            hover_holds=s.hover_holds,
            replan_ms_median=float(np.median(replan_ms)) if replan_ms.size else math.nan,
            replan_ms_p95=float(np.percentile(replan_ms, 95)) if replan_ms.size else math.nan,
            map_update_ms_median=float(np.median(update_ms)) if update_ms.size else math.nan,
            uncertainty_margin_max_m=max(s.uncertainty_margin_m, default=math.nan),
            sensed_obstacles=len(fused.buildings) - (len(sensed.prior.buildings) - len(sensed.cleared_parts)),
            cleared_prior_parts=len(sensed.cleared_parts), improvements_tried=s.improvements_tried,
            improvements_taken=s.improvements_taken)

    # -- flying ---------------------------------------------------------------------------------
    def act(self, obs: Observation) -> Actuation:
        """Track the reference with one MPC solve; hover in place if there is no plan. When the solve fails and no
        previous MPC plan covers now, the vehicle's velocity autopilot steers back onto the reference (hover trim
        alone holds no vertical speed: validation leg quad-004/5 fell at 12 m/s on it)."""
        world = self._world
        if world is None:
            raise RuntimeError("act() before reset()")
        mpc = self._tracker
        sigma = float(world.atmosphere.density_ratio_clamped(float(obs.x[2])))
        if self._sensed is not None:
            self._sense(obs)
        if self.reference is None:
            return RotorCommand(world.vehicle.hover_rotor_speeds_rad_s(sigma))
        if self._pending is not None and obs.t_s + 1e-9 >= self._pending[2]:
            (self.plan, self.reference, self._t_ref0, self._relaxed_ends, self._promise_ends,
             self._tapers) = self._pending
            self._pending = None
            self._scale, self._clock_t, self._braking = 1.0, obs.t_s, False
            self._tracker.reset()
            self._last_t = None
            self.last_solution = None  # its prediction belonged to the braking
        self._run_clock(obs)
        if self._hold_retry_t <= obs.t_s:
            self._replan_in_flight(obs, None)
        else:
            self._maybe_replan(obs, self.reference)
        n_stages, h = mpc.horizon_steps, mpc.step_s
        # the reference as its clock runs: positions along it at `_scale` of its time, velocities scaled alike
        ref_pos, ref_vel, _ = self.reference.sample_horizon(obs.t_s - self._t_ref0, h * self._scale, n_stages + 1)
        ref_vel = ref_vel * self._scale
        # the MPC's margin at each stage follows the reference's speed there (and the estimate's σ now)
        by_speed = self._flying()[1].by_speed if self._sensed is None else \
            self._base_margins.by_speed.widened(self._extra_now)
        self._stage_mpc_margins = by_speed.mpc_fraction * by_speed.margin_m(np.linalg.norm(ref_vel[1:], axis=1))
        self._record_promise(obs, ref_pos[0], float(np.linalg.norm(ref_vel[0])))
        normals, offsets = self._halfspaces(obs, ref_pos)
        elapsed = 0.0 if self._last_t is None else obs.t_s - self._last_t
        # the map is known to this pilot: its MPC predicts the ground effect of the surface below it now
        height = float(obs.x[2] - self._known.surface_height_m(obs.x[None, 0:3])[0])
        sol = mpc.solve(obs.x, ref_pos, ref_vel, self._task.start_yaw_rad, sigma, normals, offsets, elapsed,
                        height_above_surface_m=height)
        self._last_t = obs.t_s
        self._record(sol)
        if sol.hover_trim:
            return self._autopilot_command(obs, ref_pos[0], ref_vel[0])
        return RotorCommand(sol.rotor_speeds_rad_s)

    def _autopilot_command(self, obs: Observation, ref_pos_m: np.ndarray, ref_vel_m_s: np.ndarray) -> VelocityCommand:
        """The reference's velocity plus `autopilot_gain_1_s` times the position error, for the vehicle's velocity
        autopilot (world ENU, from the estimate; the autopilot saturates it to the vehicle's limits)."""
        velocity = np.asarray(ref_vel_m_s, float) + self.config.autopilot_gain_1_s * (
            np.asarray(ref_pos_m, float) - obs.x[0:3])
        self.stats.autopilot_decisions += 1
        return VelocityCommand(velocity, float(self._task.start_yaw_rad))

    def _record_promise(self, obs: Observation, ref_pos: np.ndarray, ref_speed_m_s: float) -> None:
        """Record the margin in force from this decision on, at its reference point: M(reference speed), or a
        close start's or goal's own allowance inside its zone."""
        local = float(self._flying()[1].by_speed.margin_m(ref_speed_m_s))
        for end, zone, allowed in self._promise_ends:
            if float(np.linalg.norm(ref_pos - end)) <= zone:
                local = min(local, allowed)
        self.stats.promise_t_s.append(float(obs.t_s))
        self.stats.promise_margin_m.append(local)

    def margins_in_force(self) -> tuple[np.ndarray, np.ndarray]:
        """The decisions' times (D,) [s] and the margin in force from each (D,) [m] over the episode flown since
        `reset` (`uam_fdm.pilot.StatesMargins`): the scorer holds the true clearance to it."""
        return np.asarray(self.stats.promise_t_s, float), np.asarray(self.stats.promise_margin_m, float)

    def _sense(self, obs: Observation) -> None:
        """Map the scans handed over with `obs` on its estimate; flag the path still to fly as blocked when a newly
        sensed obstacle comes within the margin of it; refresh the fused map at most every `fuse_period_s`."""
        sensed, cfg = self._sensed, self.config
        assert sensed is not None
        sigma_m = position_sigma_m(obs.covariance) if obs.covariance is not None else 0.0
        self._extra_now = cfg.uncertainty_k * sigma_m
        self.stats.uncertainty_margin_m.append(self._extra_now)
        fresh = []
        for scan in obs.sensors.lidar:
            # placed on the pose estimated when it was taken (its stamp), as old as the scan
            t0 = time.perf_counter()
            update = sensed.integrate(scan, obs.x, sigma_m)
            self.stats.map_update_s.append(time.perf_counter() - t0)
            if update.changed:
                self._map_dirty = True
                fresh.append(update.new_voxels_m)
        if fresh and self.reference is not None and self._pending is None and self._hold_retry_t == math.inf:
            voxels = np.vstack(fresh)
            if len(voxels) and self._path_blocked(obs, voxels):
                self._blocked = True
        if self._map_dirty and obs.t_s - self._fused_t >= cfg.fuse_period_s:
            self._refresh_known(obs.t_s)

    def _refresh_known(self, t_s: float) -> None:
        assert self._sensed is not None
        self._known = self._sensed.fused()
        self._map_dirty, self._fused_t = False, t_s

    def _still_to_fly(self, obs: Observation) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The reference still to fly at `obs`, sampled every 0.2 s and at its end: reference times (K,) [s],
        positions (K, 3) [m] and velocities (K, 3) [m/s], world ENU."""
        ref = self.reference
        assert ref is not None
        times = np.append(np.arange(max(obs.t_s - self._t_ref0, 0.0), ref.duration_s, 0.2), ref.duration_s)
        pos, vel, _ = ref.sample_horizon(float(times[0]), 0.2, len(times))
        return times, pos, vel

    def _path_blocked(self, obs: Observation, voxels_m: np.ndarray) -> bool:
        """True when a voxel (K, 3) [m], standing as the fused map stands it (a column from the ground to its top),
        lies within the collision radius plus the margin at rest plus `refuse_margin_m` of the reference still to
        fly (sampled every 0.2 s): an overhang sensed above the path closes it as it closes the planner's map
        (validation leg quad-016/8: a jib seen 22 m above the path held the vehicle 4 m short of its goal)."""
        times, ahead, _ = self._still_to_fly(obs)
        world, _ = self._flying()
        reach = (world.vehicle.collision_radius_m + self._base_margins.by_speed.widened(self._extra_now).floor_m
                 + self.config.refuse_margin_m)
        voxels = np.asarray(voxels_m, float).reshape(-1, 3)
        lists = cKDTree(ahead[:, 0:2]).query_ball_point(voxels[:, 0:2], reach)
        counts = np.fromiter((len(found) for found in lists), np.int64, len(lists))
        if not counts.sum():
            return False
        v = np.repeat(np.arange(len(voxels)), counts)
        k = np.fromiter(itertools.chain.from_iterable(lists), np.int64, int(counts.sum()))
        top = voxels[v, 2] + 0.5 * self.config.mapping.resolution_m
        distance = np.hypot(np.linalg.norm(ahead[k, 0:2] - voxels[v, 0:2], axis=1), np.maximum(ahead[k, 2] - top, 0.0))
        near = distance <= reach
        if np.any(near):
            self._blocked_ref_t = float(times[int(np.min(k[near]))])
            log.info("a sensed obstacle %.1f m from the path still to fly at t = %.2f s: replanning",
                     float(np.min(distance[near])), obs.t_s)
            return True
        return False

    def _replan_in_flight(self, obs: Observation, cause: str | None) -> None:
        """Replan on the fused map; the new plan starts `replan_budget_s` later, where the vehicle will be then.

        Meanwhile the vehicle flies on along its reference when that stays clear in what it knows (the cause is the
        estimate's grown uncertainty, a search for a faster plan, or a block beyond where it could stop after the
        budget), else it brakes along the path flown. The new path begins with a straight lead-in from there to where
        braking along its velocity would stop it (when that is clear), so that the reference starts along the
        velocity. `cause` None: a retry while holding. No path: hold (hover), trying again every `hold_retry_s`.
        "improve" (a faster plan while on one found at the floor margin) replaces the flown plan only when it arrives
        `improve_gain_s` earlier, and never holds."""
        cfg, s = self.config, self.stats
        assert self._sensed is not None
        improving = cause == "improve"
        if improving:
            s.improvements_tried += 1
        elif cause is not None:
            s.replans_by_cause[cause] += 1
            self._last_replan_t = obs.t_s
        else:
            self._retries += 1
        self._tried_t = obs.t_s
        t0 = time.perf_counter()
        self._refresh_known(obs.t_s)
        refresh_s = time.perf_counter() - t0
        t_switch = obs.t_s + cfg.replan_budget_s
        flown, decel = self.reference, self._limits.max_accel_m_s2
        flying_on = flown is not None and (cause in _FLYING_ON or (
            cause == "blocked" and self._stops_short_of_block(flown, self._ref_t(t_switch))))
        self._blocked_ref_t = math.inf
        # stop along the path flown (clear in what the pilot knew), not straight along the velocity; but a vehicle far
        # off its reference (a tracking cause) stops from where it is, not from where the reference would have it
        off_path = cause == "tracking" or (flown is not None and cfg.replan_error_m is not None and float(
            np.linalg.norm(obs.x[0:3] - flown.sample(obs.t_s - self._t_ref0)[0])) > cfg.replan_error_m)
        brake = (braking_along(flown, obs.t_s - self._t_ref0, decel) if flown is not None and not off_path
                 else self._stop_from(obs))
        if flown is not None and not off_path and not self._free_in_known(brake.pos_m):
            # the stop along the path runs into something sensed since (the MPC keeps the vehicle short of it): stop
            # from where the vehicle is, or every retry would plan from inside it or behind it (a hold never ended,
            # tuning leg 3200004/2 at nominal, wrong map; a sensed face is as thin as its returns, so the stop's end
            # alone can lie behind it)
            brake = self._stop_from(obs)
        start, lead_in, velocity = np.zeros(3), None, None
        if flying_on and flown is not None:
            # from where the reference will be, along its velocity there: a lead-in when it is moving
            p_b, v_b, _ = flown.sample(self._ref_t(t_switch))
            v_b = self._scale * np.asarray(v_b, float)  # as fast as its clock runs
            start, lead_in, fits = self._lead_in(np.asarray(p_b, float), v_b, decel)
            velocity = v_b
            if not fits:  # no room to start along its velocity: no new plan could be flown from there at speed
                if improving:
                    return
                flying_on = False
        if not flying_on:
            # braking: the new plan starts at rest where the braking ends (a heavy vehicle braking for the whole
            # budget is still moving; a plan from there at its speed but across its velocity cannot be tracked)
            t_switch = max(t_switch, obs.t_s + brake.duration_s)
            start, lead_in, velocity = np.asarray(brake.pos_m[-1], float), None, None
        now: tuple[Reference, float] = (flown, self._t_ref0) if flying_on and flown is not None else (brake, obs.t_s)
        previous = (self.plan, self.reference, self._t_ref0, self._relaxed_ends, self._promise_ends, self._tapers,
                    self._on_floor, self._planned_extra_m, self.margins, self._planner_cfg)
        self._planned_extra_m = self._extra_now
        self.margins = self._base_margins.widened(self._extra_now)
        self._planner_cfg = dataclasses.replace(self.config.planner, safety_margin_m=self.margins.planner_m)
        before = s.plan_time_s
        ok, _, detail = self._plan(start, t_start=t_switch, velocity_m_s=velocity, in_flight=True, lead_in=lead_in,
                                   faster=improving)
        s.replan_time_s += s.plan_time_s - before
        s.in_flight_replan_s.append(refresh_s + s.plan_time_s - before)  # what the budget must cover
        if improving:
            assert flown is not None and self.reference is not None
            faster = ok and t_switch + self.reference.duration_s + cfg.improve_gain_s <= previous[2] + flown.duration_s
            log.info("a faster plan at t = %.2f s: %s", obs.t_s, "taken" if faster else "none")
            if faster:
                s.improvements_taken += 1
                self._pending = self._adopted()
                self.plan, self.reference, self._t_ref0, self._relaxed_ends, self._promise_ends = previous[:5]
            else:
                (self.plan, self.reference, self._t_ref0, self._relaxed_ends, self._promise_ends, self._tapers,
                 self._on_floor, self._planned_extra_m, self.margins, self._planner_cfg) = previous
            return
        if ok:
            self._pending = self._adopted()
            self._hold_retry_t = math.inf
        else:
            if self._hold_retry_t == math.inf:
                s.hover_holds += 1
                log.info("no path in what the pilot knows at t = %.2f s (%s): holding", obs.t_s, detail)
            self._hold_retry_t = obs.t_s + cfg.hold_retry_s
            now, flying_on = (self._hold_reference(brake), obs.t_s), False
        if not flying_on:  # braking (or holding) until the new plan's start: the MPC tracks the stop afresh
            self._scale, self._clock_t, self._braking = 1.0, obs.t_s, True
            self._tracker.reset()
            self._last_t = None
            self.last_solution = None
        self.reference, self._t_ref0 = now

    def _ref_t(self, t_s: float) -> float:
        """The flown reference's time [s] at time `t_s` [s], its clock running on at its present rate."""
        return (self._clock_t - self._t_ref0) + self._scale * (t_s - self._clock_t)

    def _run_clock(self, obs: Observation) -> None:
        """Advance the reference's clock to `obs.t_s` and set its rate from now on (`see_to_stop`): `_clock_target`,
        approached no faster than the acceleration limit allows either way (docs/planner.md)."""
        dt = obs.t_s - self._clock_t
        self._t_ref0 += (1.0 - self._scale) * dt  # it ran at `_scale` since `_clock_t`
        self._clock_t = obs.t_s
        if self._sensed is None or not self.config.see_to_stop or self._braking or self.reference is None:
            self._scale = 1.0
            return
        target = self._clock_target(obs)
        if target is None:
            return
        step = dt * self._limits.max_accel_m_s2 / max(self._ref_speed, 1.0)
        self._scale = float(np.clip(target, self._scale - step, self._scale + step))
        self.stats.clock_scale_min = min(self.stats.clock_scale_min, self._scale)

    def _clock_target(self, obs: Observation) -> float | None:
        """The rate for the reference's clock at `obs`: the ratio of the speed from which the vehicle stops, with its
        margin at rest, short of the first point of the path still to fly that has not been in sight (marking what
        is in sight now), to the reference's speed; at most 1. None where the estimate lies inside what the pilot
        knows (every line of sight is blocked there; the MPC takes it out)."""
        world, _ = self._flying()
        assert self.reference is not None and world.sensing is not None
        t_ref = obs.t_s - self._t_ref0
        speed = self._ref_speed = float(np.linalg.norm(self.reference.sample(t_ref)[1]))  # also the rate's step's
        if speed < 1e-6:
            return 1.0  # at rest: nothing to slow
        eye = np.asarray(obs.x[0:3], float)
        if float(self._known.clearance(eye[None, :], 0.0).distance_m[0]) <= 0.0:
            return None
        decel, reaction = self._limits.max_accel_m_s2, self.config.see_reaction_s
        # ahead, as far as the reference needs to stop from its speed here (and at most to its end)
        horizon = 2.0 * speed / decel + reaction + 1.0
        path, seen = self._seen_along(self.reference)
        first = min(int(t_ref / _SEE_STEP_S), len(path) - 1)
        last = min(int(math.ceil((t_ref + horizon) / _SEE_STEP_S)), len(path) - 1)
        ahead = slice(first, last + 1)
        # the stop, and the tube that must have been in sight round the path, keep the collision radius and the
        # MPC's margin at rest (no k σ: what comes into view is placed on the same estimate as the vehicle)
        by_speed = self._base_margins.by_speed
        keep = world.vehicle.collision_radius_m + float(by_speed.mpc_fraction * by_speed.margin_m(0.0))
        lidar = world.sensing.lidar
        q = np.asarray(obs.x[6:10], float)
        seen[ahead] |= in_sight(eye, path[ahead], self._line_of_sight(), lidar.max_range_m, keep,
                                rotation_matrix(q / np.linalg.norm(q)), lidar.vertical_fov_deg)
        return min(1.0, stopping_speed_m_s(arc_in_sight_m(path[ahead], seen[ahead]) - keep, decel, reaction) / speed)

    def _seen_along(self, reference: Reference) -> tuple[np.ndarray, np.ndarray]:
        """The points of `reference` every `_SEE_STEP_S` of its time (K, 3) [m] and whether each has been in sight
        (K,) (a mask written through; started afresh for each new reference)."""
        if self._seen is None or self._seen[0] is not reference:
            n = int(math.ceil(reference.duration_s / _SEE_STEP_S)) + 1
            path, _, _ = reference.sample_horizon(0.0, _SEE_STEP_S, n)
            self._seen = (reference, path, np.zeros(n, dtype=bool))
        return self._seen[1], self._seen[2]

    def _line_of_sight(self) -> RayCaster:
        """A ray caster over the map the pilot knows now (rebuilt when the fused map changes)."""
        if self._caster is None or self._caster[0] is not self._known:
            self._caster = (self._known, RayCaster(self._known, ground=False))
        return self._caster[1]

    def _rest_margin_m(self) -> float:
        """The MPC's margin at rest [m], widened by k σ now: what its half-spaces keep from every obstacle and the
        ground while the vehicle hovers."""
        by_speed = self._base_margins.by_speed.widened(self._extra_now)
        return float(by_speed.mpc_fraction * by_speed.margin_m(0.0))

    def _stop_from(self, obs: Observation) -> Reference:
        """A straight stop from the vehicle's estimate, its descent ending no lower than the MPC keeps from the
        ground (a vehicle falling off its reference stopped along its velocity below the ground: quad-004/5)."""
        world, _ = self._flying()
        return braking_reference(obs.x[0:3], obs.x[3:6], self._limits.max_accel_m_s2,
                                 floor_z_m=world.vehicle.collision_radius_m + self._rest_margin_m())

    def _hold_reference(self, brake: Reference) -> Reference:
        """Where to hold for want of a path: where `brake` stops; or, when that is closer to what the pilot knows than
        the MPC's margin at rest, the nearest point that keeps the margin, straight above (up to the map's top) or
        within `hold_search_m` around, the straight move to it clear in what the pilot knows; moved to at the
        vertical limits. Held in a gap narrower than twice the margin (grown with the estimate's σ) the MPC has no
        feasible hover: in validation leg quad-004/5 its slack pulled the vehicle down until its solves failed."""
        world, _ = self._flying()
        known = self._known.planning_map()
        radius, need = world.vehicle.collision_radius_m, self._rest_margin_m()
        p = np.asarray(brake.pos_m[-1], float)
        if float(known.clearance(p[None, :], radius).distance_m[0]) >= need:
            return brake
        reach, up = self.config.hold_search_m, np.array([0.0, 0.0, 1.0])
        # straight above: clear as far as the line up is (one query along it)
        rise = float(known.bounds_max_m[2]) - radius - need - p[2]
        line = p + np.arange(0.0, max(rise, 0.0) + _FREE_STEP_M, _FREE_STEP_M)[:, None] * up
        blocked = np.flatnonzero(known.clearance(line, radius).distance_m <= 0.0)
        clear_to = float(line[blocked[0], 2]) if blocked.size else math.inf
        column = p + np.arange(_HOLD_STEP_M, max(rise, 0.0) + 1e-9, _HOLD_STEP_M)[:, None] * up
        column = column[column[:, 2] < clear_to]
        column = column[known.clearance(column, radius).distance_m >= need]
        # around: each straight move tested every `_FREE_STEP_M` (one query for all)
        around = goal_region_points(p, reach, shells=max(int(round(reach / _HOLD_STEP_M)), 1))
        around = around[known.in_bounds(around, radius + need)]
        around = around[known.clearance(around, radius).distance_m >= need]
        samples = int(math.ceil(reach / _FREE_STEP_M)) + 1
        moves = p + np.linspace(0.0, 1.0, samples)[None, :, None] * (around - p)[:, None, :]
        free = known.clearance(moves.reshape(-1, 3), radius).distance_m.reshape(len(around), samples) > 0.0
        keeps = np.vstack([column, around[np.all(free, axis=1)]])
        if not len(keeps):
            return brake
        # the nearest; of two as near, the higher (the sky is open there, to the GNSS too)
        q = keeps[np.lexsort((-keeps[:, 2], np.linalg.norm(keeps - p, axis=1)))[0]]
        self.stats.hold_moves += 1
        return then_straight(brake, q, self._limits.max_vertical_speed_m_s, self._limits.max_vertical_accel_m_s2)

    def _free_in_known(self, points_m: np.ndarray) -> bool:
        """Whether the vehicle's sphere is clear of what the pilot knows now (as its planner tests a start: the
        buildings, the ground and the no-fly volumes) all along the polyline through points_m (K, 3) [m], tested
        every `_FREE_STEP_M`."""
        world, _ = self._flying()
        points = densify(np.asarray(points_m, float).reshape(-1, 3), _FREE_STEP_M)
        radius = world.vehicle.collision_radius_m
        return bool(np.all(self._known.planning_map().clearance(points, radius).distance_m > 0.0))

    def _adopted(self) -> tuple:
        """The plan just made, to be flown once its start comes (`_pending`)."""
        return self.plan, self.reference, self._t_ref0, self._relaxed_ends, self._promise_ends, self._tapers

    def _stops_short_of_block(self, reference: Reference, t_switch_ref_s: float) -> bool:
        """True when, flying on along `reference` until its time `t_switch_ref_s` [s] and braking from there, the
        vehicle would come to rest before the reference reaches the newly sensed block (`_blocked_ref_t`)."""
        speed = float(np.linalg.norm(reference.sample(t_switch_ref_s)[1]))
        # braking covers less ground than the reference does in the same time: its time to rest is a bound
        return t_switch_ref_s + speed / self._limits.max_accel_m_s2 + self.config.replan_budget_s < self._blocked_ref_t

    def _lead_in(self, p_m: np.ndarray, v_m_s: np.ndarray, decel_m_s2: float
                 ) -> tuple[np.ndarray, np.ndarray | None, bool]:
        """Where a new plan from `p_m` moving at `v_m_s` starts, the lead-in to it, and whether it fits: the point
        where braking straight along the velocity at `decel_m_s2` would stop it, when that segment keeps the margin at
        that speed in the fused map (the reference's timing will ask it there): (it, `p_m`, True); a vehicle that
        stops within a metre needs none: (`p_m`, None, True); no room: (`p_m`, None, False)."""
        speed = float(np.linalg.norm(v_m_s))
        stop_m = speed * speed / (2.0 * decel_m_s2)
        if stop_m < 1.0:
            return p_m, None, True
        q = p_m + v_m_s / speed * stop_m
        world, margins = self._flying()
        samples = p_m + np.linspace(0.0, 1.0, max(int(math.ceil(stop_m / 0.5)), 2) + 1)[:, None] * (q - p_m)
        clearance = self._known.planning_map().clearance(samples, world.vehicle.collision_radius_m).distance_m
        if float(np.min(clearance)) < float(self._base_margins.by_speed.widened(self._extra_now).margin_m(speed)):
            return p_m, None, False
        return q, p_m, True

    def _keeps_widened_margin(self, obs: Observation) -> bool:
        """True when the reference still to fly keeps, at every sample (every 0.2 s), the margin at its speed
        widened by k σ now (narrowed towards the start and goal as planned): a grown uncertainty needs no new
        plan while the path has that room."""
        _, pos, vel = self._still_to_fly(obs)
        world, _ = self._flying()
        cruise = self._base_margins.by_speed.widened(self._extra_now).margin_m(np.linalg.norm(vel, axis=1))
        need = np.array([min((t.margin_at(float(np.linalg.norm(p - np.asarray(t.point_m))), float(m))
                              for t in self._tapers), default=float(m)) for p, m in zip(pos, cruise, strict=True)])
        keep = np.ones(len(pos), dtype=bool)
        for end, zone in self._relaxed_ends:
            keep &= np.linalg.norm(pos - end, axis=1) > zone
        if not np.any(keep):
            return True
        clearance = self._known.planning_map().clearance(pos[keep], world.vehicle.collision_radius_m).distance_m
        return bool(np.all(clearance >= need[keep]))

    def _maybe_replan(self, obs: Observation, reference: Reference) -> None:
        """Replan if `_replan_cause` says so; `reference` is the one flown now (`self.reference`)."""
        t_ref = obs.t_s - self._t_ref0
        self.stats.deviations_m.append(reference.deviation_m(obs.x[0:3], t_ref))
        self.stats.reference_speeds_m_s.append(float(np.linalg.norm(reference.sample(t_ref)[1])))
        cause = self._replan_cause(obs, reference)
        if cause is None:
            return
        if self._sensed is not None:
            self._replan_in_flight(obs, cause)
            return
        self.stats.replans_by_cause[cause] += 1
        self._last_replan_t = obs.t_s
        previous = (self.plan, self.reference, self._t_ref0, self._relaxed_ends, self._promise_ends)
        before = self.stats.plan_time_s
        ok, _, _ = self._plan(obs.x[0:3].copy(), t_start=obs.t_s, velocity_m_s=obs.x[3:6].copy())
        self.stats.replan_time_s += self.stats.plan_time_s - before
        if not ok:   # keep tracking the old reference rather than give up
            self.plan, self.reference, self._t_ref0, self._relaxed_ends, self._promise_ends = previous
        else:
            self._tracker.reset()
            self._last_t = None
            self.last_solution = None   # its prediction belonged to the old reference

    def _replan_cause(self, obs: Observation, reference: Reference) -> str | None:
        """"blocked", "uncertainty", "tracking", "clearance", "improve" (on sensors, a plan found at the floor margin:
        look for a faster one) or None (no replan now; never while a plan made in flight waits for its start)."""
        cfg, s = self.config, self.stats
        if self._pending is not None:
            return None
        if self._blocked:
            self._blocked = False
            return "blocked"
        if (self._sensed is not None and self._extra_now > self._planned_extra_m + cfg.uncertainty_replan_m
                and obs.t_s - self._uncertainty_checked_t >= cfg.uncertainty_check_s):
            self._uncertainty_checked_t = obs.t_s
            if not self._keeps_widened_margin(obs):
                log.info("k sigma %.2f m (planned for %.2f m) leaves the path short of its margin at t = %.2f s: "
                         "replanning", self._extra_now, self._planned_extra_m, obs.t_s)
                return "uncertainty"
        t_ref = obs.t_s - self._t_ref0
        if cfg.replan_error_m is not None and s.replans_by_cause["tracking"] < cfg.max_replans:
            ref_now, _, _ = reference.sample(t_ref)
            error = float(np.linalg.norm(obs.x[0:3] - ref_now))
            if error > cfg.replan_error_m:
                log.info("tracking error %.1f m above %.1f m at t = %.2f s: replanning", error,
                         cfg.replan_error_m, obs.t_s)
                return "tracking"
        points = self._predicted_positions()
        if (cfg.replan_on_clearance and points is not None
                and s.replans_by_cause["clearance"] < cfg.max_clearance_replans
                and obs.t_s - self._last_replan_t >= cfg.replan_cooldown_s):
            clearances = self.predicted_clearances_m(points)
            # each predicted stage against the MPC margin at its reference speed when it was solved
            required = self._stage_mpc_margins[:len(points)]
            short = clearances - required
            if np.any(short < 0.0):
                i = int(np.argmin(short))
                log.info("predicted clearance %.2f m below the MPC margin %.2f m at t = %.2f s: replanning",
                         clearances[i], required[i], obs.t_s)
                return "clearance"
        # a faster plan may exist where the flown one was found at the floor margin, or with a wider uncertainty
        # margin than k σ asks now (a GNSS outage ended: the streets it closed may be open again)
        eased = self._extra_now < self._planned_extra_m - cfg.uncertainty_replan_m
        if (self._sensed is not None and (self._on_floor or eased) and obs.t_s - self._tried_t >= cfg.improve_period_s
                and reference.duration_s - t_ref > cfg.improve_period_s):
            return "improve"
        return None

    def predicted_clearance_m(self, points_m: np.ndarray) -> float:
        """Least sphere clearance [m] of predicted positions (M, 3) (`predicted_clearances_m`); +inf
        when every point is left out."""
        return float(np.min(self.predicted_clearances_m(points_m), initial=math.inf))

    def predicted_clearances_m(self, points_m: np.ndarray) -> np.ndarray:
        """Sphere clearance [m] of each predicted position (M, 3) to the planning map (buildings, no-fly
        volumes, ground); +inf for points inside a start's or goal's relaxed zone (closer than the
        margin by the task itself)."""
        keep = np.ones(len(points_m), dtype=bool)
        for end, zone in self._relaxed_ends:
            keep &= np.linalg.norm(points_m - end, axis=1) > zone
        out = np.full(len(points_m), math.inf)
        if np.any(keep):
            world, _ = self._flying()
            obstacles = self._known.planning_map()
            out[keep] = obstacles.clearance(points_m[keep], world.vehicle.collision_radius_m).distance_m
        return out

    def _halfspaces(self, obs: Observation, ref_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Clearance half-spaces (N, K, 3), (N, K) around the last prediction (or the reference).

        Rows: the K−1 nearest buildings or no-fly volumes, facing the vehicle through their nearest
        points, and the ground; each offset by the collision radius plus the MPC's clearance margin, or, on sensors
        where the vehicle is inside that now, by no more than it recovers at `margin_recovery_m_s` by the stage's
        time.
        """
        (world, _), mpc = self._flying(), self._tracker
        obstacles = self._known.planning_map()  # the no-fly volumes are kept at the same margin
        n_stages, k = mpc.horizon_steps, mpc.config.n_halfspaces
        if k == 0:
            return np.zeros((n_stages, 0, 3)), np.zeros((n_stages, 0))
        predicted = self._predicted_positions()
        pred = predicted if predicted is not None else ref_pos[1:]
        required = world.vehicle.collision_radius_m + self._stage_mpc_margins  # (N,): by the stage's speed
        normals = np.zeros((n_stages, k, 3))
        offsets = np.full((n_stages, k), -1.0)
        normals[:, k - 1] = (0.0, 0.0, 1.0)
        offsets[:, k - 1] = required
        if k > 1 and len(obstacles.buildings) > 0:
            pts, dist, ids = obstacles.nearest_obstacles_batch(pred, k - 1, 0.0)
            away = pred[:, None, :] - pts  # (N, K-1, 3)
            norm = np.sqrt(np.einsum("nkc,nkc->nk", away, away))
            found = (ids >= 0) & (norm >= 1e-9)  # else: no obstacle, or a point on its surface (no direction)
            with np.errstate(divide="ignore", invalid="ignore"):
                normal = away / norm[..., None] * np.where(dist >= 0, 1.0, -1.0)[..., None]
            normals[:, :k - 1] = np.where(found[..., None], normal, 0.0)
            offsets[:, :k - 1] = np.where(found, np.einsum("nkc,nkc->nk", normal, pts) + required[:, None], -1.0)
        if self._sensed is None:  # the privileged reference, as it was
            return normals, offsets
        # on sensors, a half-space the vehicle is inside now asks it out at `margin_recovery_m_s`, not at once: asked
        # at once, the slack's price outweighs every other term and the MPC tilts to its limit sideways, losing
        # height (a hold in a gap narrower than the margin sank 19 m to the ground in quad-004/5)
        t_k = mpc.step_s * np.arange(1, n_stages + 1)
        now = np.einsum("nkc,c->nk", normals, np.asarray(obs.x[0:3], float))
        offsets = np.minimum(offsets, now + self.config.margin_recovery_m_s * t_k[:, None])
        return normals, offsets

    def _predicted_positions(self) -> np.ndarray | None:
        """The last MPC solution's predicted positions at stages 1..N (N, 3) [m]; None when there is none, or when it
        fell back to hover trim (no plan of its own: its prediction is no trajectory, and half-spaces built around it
        were built around the map's origin, quad-004/5)."""
        sol = self.last_solution
        if sol is None or sol.hover_trim:
            return None
        return sol.predicted_states[1:, 0:3]

    def _flying(self) -> tuple[World, Margins]:
        """The episode's world and margins (both set by `reset`)."""
        if self._world is None or self.margins is None:
            raise RuntimeError("the classical pilot flies only after reset()")
        return self._world, self.margins

    def _record(self, sol: MPCSolution) -> None:
        self.last_solution = sol
        s = self.stats
        s.mpc_solves += 1
        s.mpc_failures += int(not sol.success)
        s.mpc_solve_times_s.append(sol.solve_time_s)
        s.mpc_iterations.append(sol.iterations)
        s.mpc_statuses[sol.status] = s.mpc_statuses.get(sol.status, 0) + 1


GOAL_REGION_FRACTION = 0.6
"""A goal swallowed by what the pilot knows is replaced by a point within this fraction of the goal radius (the rest
of the radius is left for tracking error at arrival)."""


def goal_region_points(goal_m: np.ndarray, reach_m: float, shells: int = 4) -> np.ndarray:
    """Candidate points around a goal (3,) [m], ENU: on `shells` spheres out to `reach_m` [m], each along the 26
    directions to a cube's faces, edges and corners (nearest shell first, a fixed order): (26 * shells, 3)."""
    steps = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if (i, j, k) != (0, 0, 0)],
                     dtype=float)
    units = steps / np.linalg.norm(steps, axis=1)[:, None]
    radii = reach_m * np.arange(1, shells + 1) / shells
    return (np.asarray(goal_m, float)[None, None, :] + radii[:, None, None] * units[None, :, :]).reshape(-1, 3)


def position_sigma_m(covariance: np.ndarray) -> float:
    """1 σ [m] of an error-state covariance's position block (16, 16) along its largest axis."""
    block = np.asarray(covariance, float)[0:3, 0:3]
    return float(math.sqrt(max(float(np.linalg.eigvalsh(0.5 * (block + block.T))[-1]), 0.0)))
