"""The classical pilot: plan once with OMPL RRT* (timed), time-parameterise, track with NMPC.

Implements the `uam_fdm.agent.Agent` protocol and emits rotor-speed commands. Optionally
replans from the current position when the tracking error exceeds a threshold (the replanning
time is counted as planning time).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from planners.mpc import MPCConfig, MPCSolution, MPCTracker
from planners.rrt_star import PlannerConfig, PlanResult, plan_path
from planners.timing import Reference, TimingLimits, time_parameterize
from uam_fdm.agent import Observation, ResetInfo, RotorCommand, Task, World

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ClassicalConfig:
    """Settings of the plan-and-track pilot.

    Attributes:
        planner: OMPL planner settings (algorithm, deterministic iteration budget, safety margin).
        mpc: NMPC settings.
        speed_fraction: share of the vehicle's speed caps the reference may use.
        accel_fraction: share of the vehicle's acceleration capability the reference may use.
        replan_error_m: replan from the current position when the position error to the reference
            exceeds this [m]; None disables replanning.
        max_replans: at most this many replans per episode.
    """

    planner: PlannerConfig = field(default_factory=PlannerConfig)
    mpc: MPCConfig = field(default_factory=MPCConfig)
    speed_fraction: float = 0.8
    accel_fraction: float = 0.5
    replan_error_m: float | None = 5.0
    max_replans: int = 3


@dataclass
class ClassicalStats:
    """Per-episode counters of the classical pilot (read by the runner for metrics)."""

    plan_time_s: float = 0.0
    replans: int = 0
    mpc_solves: int = 0
    mpc_failures: int = 0
    mpc_solve_times_s: list[float] = field(default_factory=list)
    mpc_iterations: list[int] = field(default_factory=list)
    mpc_statuses: dict[str, int] = field(default_factory=dict)


class ClassicalAgent:
    """RRT* + time-parameterisation + NMPC, flying by rotor-speed commands.

    Args:
        config: pilot settings.
        cache_dir: cache for the compiled MPC (default `uam_fdm.codegen.default_cache_dir()`).
    """

    name = "rrt_mpc"

    def __init__(self, config: ClassicalConfig | None = None, cache_dir: Path | None = None) -> None:
        self.config = config if config is not None else ClassicalConfig()
        self._cache_dir = cache_dir
        self._trackers: dict[str, MPCTracker] = {}
        self._world: World | None = None
        self.plan: PlanResult | None = None
        self.reference: Reference | None = None
        self.last_solution: MPCSolution | None = None
        self.stats = ClassicalStats()

    # -- episode set-up -------------------------------------------------------------------------
    def tracker_for(self, world: World) -> MPCTracker:
        """The MPC for this world's vehicle (built and compiled once per vehicle)."""
        key = world.vehicle.fingerprint()
        if key not in self._trackers:
            self._trackers[key] = MPCTracker(world.vehicle, self.config.mpc, self._cache_dir)
        return self._trackers[key]

    def reset(self, world: World, task: Task, seed: int) -> ResetInfo:
        """Plan from the task's start to its goal (timed) and prepare the tracker."""
        self._world, self._task, self._seed = world, task, int(seed)
        self._tracker = self.tracker_for(world)
        self._tracker.reset()
        self.stats = ClassicalStats()
        self.last_solution = None
        self._last_t: float | None = None
        ok, status, detail = self._plan(np.asarray(task.start_m, float), t_start=0.0)
        return ResetInfo(ok=ok, status=status, plan_time_s=self.stats.plan_time_s, detail=detail)

    def _plan(self, start: np.ndarray, t_start: float) -> tuple[bool, str, str]:
        world, task, cfg = self._world, self._task, self.config
        radius = world.vehicle.collision_radius_m
        plan = plan_path(world.city, start, task.goal_m, radius, cfg.planner,
                         seed=self._seed + self.stats.replans)
        self.stats.plan_time_s += plan.plan_time_s
        if not plan.ok:
            return False, "planner_failure", f"{plan.status}: {plan.message}"
        limits = TimingLimits.from_vehicle(world.vehicle, cfg.speed_fraction, cfg.accel_fraction)
        reference = time_parameterize(plan.path_m, limits, world.city, radius, cfg.planner.safety_margin_m)
        if not reference.ok:
            return False, "planner_failure", f"time-parameterisation: {reference.status}"
        self.plan, self.reference, self._t_ref0 = plan, reference, t_start
        return True, "ok", ""

    # -- flying ---------------------------------------------------------------------------------
    def act(self, obs: Observation) -> RotorCommand:
        """Track the reference with one MPC solve; hover in place if there is no plan."""
        world = self._world
        if world is None:
            raise RuntimeError("act() before reset()")
        mpc = self._tracker
        sigma = float(world.atmosphere.density_ratio_clamped(float(obs.x[2])))
        if self.reference is None:
            return RotorCommand(world.vehicle.hover_rotor_speeds_rad_s(sigma))
        self._maybe_replan(obs)
        n_stages, h = mpc.config.horizon_steps, mpc.config.step_s
        ref_pos, ref_vel, _ = self.reference.sample_horizon(obs.t_s - self._t_ref0, h, n_stages + 1)
        normals, offsets = self._halfspaces(obs, ref_pos)
        elapsed = 0.0 if self._last_t is None else obs.t_s - self._last_t
        # the map is known to this pilot: its MPC predicts the ground effect of the surface below it now
        height = float(obs.x[2] - world.city.surface_height_m(obs.x[None, 0:3])[0])
        sol = mpc.solve(obs.x, ref_pos, ref_vel, self._task.start_yaw_rad, sigma, normals, offsets, elapsed,
                        height_above_surface_m=height)
        self._last_t = obs.t_s
        self._record(sol)
        return RotorCommand(sol.rotor_speeds_rad_s)

    def _maybe_replan(self, obs: Observation) -> None:
        cfg = self.config
        if cfg.replan_error_m is None or self.stats.replans >= cfg.max_replans:
            return
        ref_now, _, _ = self.reference.sample(obs.t_s - self._t_ref0)
        if np.linalg.norm(obs.x[0:3] - ref_now) <= cfg.replan_error_m:
            return
        self.stats.replans += 1
        log.info("tracking error above %.1f m at t = %.2f s: replanning", cfg.replan_error_m, obs.t_s)
        previous = (self.plan, self.reference, self._t_ref0)
        ok, _, _ = self._plan(obs.x[0:3].copy(), t_start=obs.t_s)
        if not ok:   # keep tracking the old reference rather than give up
            self.plan, self.reference, self._t_ref0 = previous
        else:
            self._tracker.reset()
            self._last_t = None

    def _halfspaces(self, obs: Observation, ref_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Clearance half-spaces (N, K, 3), (N, K) around the last prediction (or the reference).

        Rows: the K−1 nearest buildings or no-fly volumes, facing the vehicle through their nearest
        points, and the ground; each offset by the collision radius plus the MPC's clearance margin.
        """
        world, mpc = self._world, self._tracker
        obstacles = world.city.planning_map()  # the no-fly volumes are kept at the same margin
        n_stages, k = mpc.config.horizon_steps, mpc.config.n_halfspaces
        if k == 0:
            return np.zeros((n_stages, 0, 3)), np.zeros((n_stages, 0))
        pred = self.last_solution.predicted_states[1:, 0:3] if self.last_solution is not None else ref_pos[1:]
        required = world.vehicle.collision_radius_m + mpc.config.clearance_margin_m
        normals = np.zeros((n_stages, k, 3))
        offsets = np.full((n_stages, k), -1.0)
        normals[:, k - 1] = (0.0, 0.0, 1.0)
        offsets[:, k - 1] = required
        if k > 1 and len(obstacles.buildings) > 0:
            pts, dist, ids = obstacles.nearest_obstacles_batch(pred, k - 1, 0.0)
            for stage in range(n_stages):
                for j in range(k - 1):
                    if ids[stage, j] < 0:
                        continue
                    away = pred[stage] - pts[stage, j]
                    norm = np.linalg.norm(away)
                    if norm < 1e-9:
                        continue
                    normal = away / norm * (1.0 if dist[stage, j] >= 0 else -1.0)
                    normals[stage, j] = normal
                    offsets[stage, j] = normal @ pts[stage, j] + required
        return normals, offsets

    def _record(self, sol: MPCSolution) -> None:
        self.last_solution = sol
        s = self.stats
        s.mpc_solves += 1
        s.mpc_failures += int(not sol.success)
        s.mpc_solve_times_s.append(sol.solve_time_s)
        s.mpc_iterations.append(sol.iterations)
        s.mpc_statuses[sol.status] = s.mpc_statuses.get(sol.status, 0) + 1
