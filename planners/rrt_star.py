"""Geometric path planning in the city with OMPL: RRT*, InformedRRT*, BIT* or RRTConnect in 3-D.

All OMPL usage of the project lives in this module; callers get plain NumPy back.

The configuration space is the vehicle's position (world ENU, metres) inside the map bounds shrunk
by the required clearance.  A position is valid when the vehicle's collision sphere keeps at least
`safety_margin_m` from every building and the ground, i.e. when the point clearance exceeds
R = radius + margin (`BuildingMap.clearance_one`, the fast scalar path).  Motions are checked by
`BuildingMap.segment_free`: an exact swept-sphere (capsule) test, so no edge can tunnel through a
wall however thin it is.  The final path is re-checked the same way and its clearance measured
densely.

Determinism: OMPL's random generators are seeded from `seed` right before the planner is built
(`ou.RNG.setSeed`; every OMPL RNG created afterwards derives its seed from it), and the default
budget is an iteration count polled from a termination condition, so the same seed gives the same
path bit for bit.  A wall-time cap is kept as a safety net; when it fires the result says so.
"""
from __future__ import annotations

import itertools
import logging
import math
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from planners.clearance import MarginTaper, RequiredClearance
from uam_fdm.city.buildings import BuildingMap

logger = logging.getLogger(__name__)

ALGORITHMS = ("rrtstar", "informed_rrtstar", "bitstar", "rrtconnect")
FIRST_PATH = ("rrtconnect",)  # the planners that stop at their first solution; the others optimise their budget
_OMPL_CLASS = {"rrtstar": "RRTstar", "informed_rrtstar": "InformedRRTstar", "bitstar": "BITstar",
               "rrtconnect": "RRTConnect"}
_SIMPLIFY_POLLS = 2000  # termination polls allowed to the simplifier (it converges in far fewer)
STATUSES = ("exact", "approximate", "no_solution", "timeout", "invalid_start", "invalid_goal", "invalid_path")

# Per-algorithm default iteration budgets (one iteration = one poll of the termination condition,
# i.e. one main-loop pass of the planner).  Chosen by measurement on the shipped maps: see
# docs/planner.md and perf/classical.py.
DEFAULT_ITERATIONS = {"rrtstar": 10000, "informed_rrtstar": 10000, "bitstar": 20000, "rrtconnect": 20000}


@dataclass(frozen=True)
class PlannerConfig:
    """How to plan.

    Attributes:
        algorithm: "rrtstar", "informed_rrtstar", "bitstar" or "rrtconnect".
        max_iterations: deterministic budget: planner iterations (polls of the termination
            condition).  0 means the algorithm's default (`DEFAULT_ITERATIONS`); None means a pure
            time budget of `time_budget_s` (not reproducible).  RRTConnect stops at its first
            solution either way.
        time_budget_s: with an iteration budget, the wall-time safety cap (reported in
            `PlanResult.wall_cap_hit`); without one, the time budget [s]. A plan the cap cuts is another plan, and
            an episode another episode, on a slower or busier machine: 30 s is a net that should never fire (the
            pilot's slowest plan took 1.85 s on a busy machine; docs/planner.md, "After the round").
        safety_margin_m: clearance required beyond the vehicle's collision radius [m].
        goal_tolerance_m: OMPL's goal threshold [m]; the returned path always ends exactly at
            the goal when that last piece is free.
        simplify: shortcut the solution (OMPL's PathSimplifier) before returning it.
        range_m: longest edge the tree may add [m] (RRT*, InformedRRT*, RRTConnect); None = OMPL's
            default (20 % of the space's extent).
        rewire_factor: RRT*/BIT* rewiring radius factor (OMPL default 1.1).
        k_nearest: RRT* and InformedRRT* rewire to the k nearest neighbours (OMPL's default) instead
            of all neighbours within the shrinking r-disc radius; the radius version was about
            twice as fast per iteration here at equal path quality.  BIT* keeps OMPL's default.
        clearance_spacing_m: spacing of the dense clearance measurement of the result [m].
        climb_weight: what a metre of height change costs in metres of level flight: the planner minimises the
            path's length in (x, y, climb_weight * z), a Euclidean metric, so OMPL's own cost, nearest neighbours
            and informed sampling stay exact. 1 (the default, which the classical pilot flies) is the plain length;
            the reference's horizontal over vertical speed limit (4 for the small quad) makes the cost the flight
            time at those limits to within sqrt(2). Tried for the classical pilot, it made long street detours in
            the canyon (docs/planner.md, "Planning for time").
    """

    algorithm: str = "informed_rrtstar"
    max_iterations: int | None = 0
    time_budget_s: float = 30.0
    safety_margin_m: float = 1.0
    goal_tolerance_m: float = 0.5
    simplify: bool = True
    range_m: float | None = 60.0
    rewire_factor: float = 1.1
    k_nearest: bool = False
    clearance_spacing_m: float = 0.05
    climb_weight: float = 1.0

    def __post_init__(self) -> None:
        if self.algorithm not in ALGORITHMS:
            raise ValueError(f"algorithm must be one of {ALGORITHMS}, got {self.algorithm!r}")
        if self.max_iterations is not None and (
                isinstance(self.max_iterations, bool) or not isinstance(self.max_iterations, (int, np.integer))
                or self.max_iterations < 0):
            raise ValueError(f"max_iterations must be None or an integer >= 0, got {self.max_iterations!r}")
        for name in ("time_budget_s", "goal_tolerance_m", "rewire_factor", "clearance_spacing_m", "climb_weight"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive finite number, got {v!r}")
        if not (isinstance(self.safety_margin_m, (int, float)) and math.isfinite(self.safety_margin_m)
                and self.safety_margin_m >= 0):
            raise ValueError(f"safety_margin_m must be finite and >= 0, got {self.safety_margin_m!r}")
        if self.range_m is not None and not (math.isfinite(self.range_m) and self.range_m > 0):
            raise ValueError(f"range_m must be None or positive, got {self.range_m!r}")

    @property
    def iteration_budget(self) -> int | None:
        """The iteration budget in force (None = time budget)."""
        if self.max_iterations is None:
            return None
        return int(self.max_iterations) or DEFAULT_ITERATIONS[self.algorithm]


@dataclass(frozen=True)
class PlanResult:
    """Outcome of one planning query (all positions world ENU, metres).

    Attributes:
        status: "exact" (a verified collision-free path to the goal), "approximate" (OMPL's best
            try, not reaching the goal), "no_solution" (budget spent without a path), "timeout"
            (the wall-time cap fired before the iteration budget, without a path),
            "invalid_start" / "invalid_goal" (in collision or out of bounds), "invalid_path" (the
            final exact re-check failed; should not happen).
        path_m: (K, 3) waypoints from start to goal; (0, 3) when there is none.
        length_m: path length [m] (nan without a path).
        raw_length_m: length of the planner's solution before simplification [m].
        plan_time_s: wall time of the whole query (set-up, solve, simplification, checks) [s].
        solve_time_s: wall time inside the planner's solve [s].
        first_solution_time_s: time from the start of solve to the first solution [s] (nan if none).
        first_solution_iterations: iterations until the first solution (-1 if none).
        first_solution_length_m: cost (length; in (x, y, climb_weight z)) of that first solution [m] (nan if none).
        iterations: iterations run.
        wall_cap_hit: the wall-time cap ended an iteration budget early (not reproducible).
        min_clearance_m: smallest clearance of the vehicle's sphere (radius `radius_m`) along the
            path, measured every `clearance_spacing_m` [m] (nan without a path).
        ompl_clearance_m: OMPL's `PathGeometric.clearance()` (vehicle sphere, at the waypoints) [m].
        algorithm: the planner used.
        seed: the seed given.
        radius_m: the vehicle collision radius [m].
        required_clearance_m: the clearance asked of the sphere, i.e. the safety margin [m]
            (relaxed near a start or goal that is itself closer: see `plan_path`).
        message: a human-readable reason for a failure status ("" when exact).
        extra: diagnostics: OMPL's status string, motion checks, simplifier polls, whether the
            exact goal was appended to OMPL's path.
    """

    status: str
    path_m: np.ndarray
    length_m: float
    raw_length_m: float
    plan_time_s: float
    solve_time_s: float
    first_solution_time_s: float
    first_solution_iterations: int
    first_solution_length_m: float
    iterations: int
    wall_cap_hit: bool
    min_clearance_m: float
    ompl_clearance_m: float
    algorithm: str
    seed: int
    radius_m: float
    required_clearance_m: float
    message: str = ""
    extra: dict = field(default_factory=dict, compare=False, repr=False)

    @property
    def ok(self) -> bool:
        """True when the path reaches the goal and passed the exact collision re-check."""
        return self.status == "exact"


# ---- free space: pure Python, no OMPL ----------------------------------------------------------------
class FreeSpace:
    """Validity of positions and straight motions for a sphere of radius r with margin m.

    A position p is valid when its point clearance exceeds R(p) = r + m, narrowed near a start or
    goal by its `MarginTaper` and relaxed inside the zone of a start or goal that is itself inside
    the margin (`planners.clearance.RequiredClearance`); a motion when every run of it
    (`RequiredClearance.runs`) is free for a capsule of that run's R (exact, `BuildingMap.segment_free`).
    """

    def __init__(self, city: BuildingMap, radius_m: float, margin_m: float,
                 endpoints: Sequence[Sequence[float]] = (), tapers: Sequence[MarginTaper] = ()) -> None:
        self.city = city
        self.required = RequiredClearance(city, radius_m, margin_m, endpoints, tapers)
        self.r = self.required.r
        self.R = self.required.R

    def state_ok(self, x: float, y: float, z: float) -> bool:
        """Whether a sphere centred at (x, y, z) (ENU metres) is valid."""
        return self.city.clearance_one(x, y, z, self.required.at_one(x, y, z)) > 0.0

    def edge_ok(self, a: tuple[float, float, float], b: tuple[float, float, float]) -> bool:
        """Whether the straight motion a -> b (ENU metres) is valid (exact swept-sphere test)."""
        if self.required.uniform or not self.required.near(a, b):
            return self.city.segment_free(a, b, self.R)
        return all(self.city.segment_free(p, q, big_r) for p, q, big_r in self.required.runs(a, b))

    def path_ok(self, path_m: np.ndarray) -> bool:
        """Whether every edge of a polyline (K, 3) is valid."""
        pts = [_xyz(p) for p in path_m]
        return all(self.edge_ok(a, b) for a, b in itertools.pairwise(pts))


def densify(path_m: np.ndarray, spacing_m: float) -> np.ndarray:
    """Points along a polyline no farther apart than `spacing_m`, vertices included: (N, 3)."""
    path_m = np.asarray(path_m, dtype=float)
    if len(path_m) < 2:
        return path_m.copy()
    out = [path_m[:1]]
    for a, b in itertools.pairwise(path_m):
        n = max(1, math.ceil(float(np.linalg.norm(b - a)) / spacing_m))
        u = np.arange(1, n + 1)[:, None] / n
        out.append(a + (b - a) * u)
    return np.vstack(out)


def path_min_clearance(city: BuildingMap, path_m: np.ndarray, radius_m: float, spacing_m: float = 0.05) -> float:
    """Smallest clearance [m] of a sphere of `radius_m` along a polyline, sampled every `spacing_m`."""
    if len(path_m) == 0:
        return math.nan
    return float(np.min(city.clearance(densify(path_m, spacing_m), radius_m).distance_m))


# ---- OMPL ----------------------------------------------------------------------------------------------
@contextmanager
def _ompl_log_silenced() -> Iterator[None]:
    """Silence OMPL's console output for the duration, restoring the previous level afterwards."""
    previous = ou.getLogLevel()
    ou.setLogLevel(ou.LOG_NONE)
    try:
        yield
    finally:
        ou.setLogLevel(previous)


class _ValidityChecker(ob.StateValidityChecker):
    """Validity (clearance > R) and OMPL's clearance hook (the vehicle sphere's clearance)."""

    def __init__(self, si: ob.SpaceInformation, free: FreeSpace, climb_weight: float) -> None:
        super().__init__(si)
        self._free = free
        self._clear = free.city.clearance_one
        self._r = free.r
        self._w = climb_weight  # the planning space's z is climb_weight x height

    def isValid(self, s: ob.State) -> bool:
        return self._free.state_ok(s[0], s[1], s[2] / self._w)

    def clearance(self, s: ob.State) -> float:
        return self._clear(s[0], s[1], s[2] / self._w, self._r)


class _MotionValidator(ob.MotionValidator):
    """Exact swept-sphere motion check (no sampling resolution, so no tunnelling)."""

    def __init__(self, si: ob.SpaceInformation, free: FreeSpace, climb_weight: float) -> None:
        super().__init__(si)
        self._edge_ok = free.edge_ok
        self._w = climb_weight
        self.calls = 0

    def checkMotion(self, s1: ob.State, s2: ob.State) -> bool:
        self.calls += 1
        w = self._w
        return self._edge_ok((s1[0], s1[1], s1[2] / w), (s2[0], s2[1], s2[2] / w))


@dataclass
class _Progress:
    """Mutable counters the termination condition updates while OMPL runs."""

    iterations: int = 0
    first_time_s: float = math.nan
    first_iterations: int = -1
    first_cost: float = math.nan
    wall_cap_hit: bool = False


def _termination(planner: ob.Planner, progress: _Progress, budget: int | None, wall_s: float,
                 t0: float) -> Callable[[], bool]:
    """A termination callback: counts iterations, records the first solution, enforces the budgets."""
    best = getattr(planner, "bestCost", None)

    def done() -> bool:
        progress.iterations += 1
        elapsed = time.perf_counter() - t0
        if best is not None and progress.first_iterations < 0:
            c = best().value()
            if math.isfinite(c):
                progress.first_time_s, progress.first_iterations, progress.first_cost = elapsed, progress.iterations, c
        if budget is not None and progress.iterations > budget:
            return True
        if elapsed > wall_s:
            progress.wall_cap_hit = budget is not None
            return True
        return False

    return done


def _make_planner(si: ob.SpaceInformation, config: PlannerConfig) -> ob.Planner:
    planner = getattr(og, _OMPL_CLASS[config.algorithm])(si)
    if config.range_m is not None and hasattr(planner, "setRange"):
        planner.setRange(float(config.range_m))
    if hasattr(planner, "setRewireFactor"):
        planner.setRewireFactor(float(config.rewire_factor))
    if config.algorithm in ("rrtstar", "informed_rrtstar"):
        planner.setKNearest(bool(config.k_nearest))
    return planner


def _states_xyz(path: og.PathGeometric, climb_weight: float) -> np.ndarray:
    """The path's states as ENU metres (K, 3) (the planning space's z is climb_weight x height)."""
    return np.array([[s[0], s[1], s[2] / climb_weight] for s in path.getStates()], dtype=float).reshape(-1, 3)


def ompl_seed(seed: int) -> int:
    """The OMPL seed for a project seed: OMPL treats 0 as "seed from the clock", so shift by one."""
    return int(seed) % (2**32 - 1) + 1


@dataclass
class _Solved:
    """What `_solve` hands back: NumPy and plain numbers only (positions world ENU, metres)."""

    solve_time_s: float
    progress: _Progress
    status: str  # OMPL's status string
    exact: bool
    approximate: bool
    path: np.ndarray  # (K, 3), simplified; (0, 3) without a solution
    raw_path: np.ndarray  # (K, 3), as the planner found it
    ompl_clearance: float
    motion_checks: int
    simplify_polls: int


def _solve(free: FreeSpace, lo: np.ndarray, hi: np.ndarray, start: tuple[float, float, float],
           goal: tuple[float, float, float], config: PlannerConfig, seed: int) -> _Solved:
    """Build the OMPL problem, solve, simplify."""
    ou.RNG.setSeed(ompl_seed(seed))  # before any OMPL object exists: every RNG below derives from it
    w = float(config.climb_weight)
    scale = (1.0, 1.0, w)  # the planning space: (x, y, w z), where the path length is the cost (PlannerConfig)
    space = ob.RealVectorStateSpace(3)
    bounds = ob.RealVectorBounds(3)
    for i in range(3):
        bounds.setLow(i, float(lo[i]) * scale[i])
        bounds.setHigh(i, float(hi[i]) * scale[i])
    space.setBounds(bounds)
    ss = og.SimpleSetup(space)
    si = ss.getSpaceInformation()
    checker = _ValidityChecker(si, free, w)
    ss.setStateValidityChecker(checker)
    motion = _MotionValidator(si, free, w)
    si.setMotionValidator(motion)
    s, g = space.allocState(), space.allocState()
    for i in range(3):
        s[i], g[i] = start[i] * scale[i], goal[i] * scale[i]
    ss.setStartAndGoalStates(s, g, float(config.goal_tolerance_m))
    ss.setOptimizationObjective(ob.PathLengthOptimizationObjective(si))
    planner = _make_planner(si, config)
    ss.setPlanner(planner)
    ss.setup()

    progress = _Progress()
    budget = config.iteration_budget
    t0 = time.perf_counter()
    status = ss.solve(ob.PlannerTerminationCondition(_termination(planner, progress, budget,
                                                                  config.time_budget_s, t0)))
    solve_time = time.perf_counter() - t0
    exact = status == ob.PlannerStatus.EXACT_SOLUTION
    raw_xyz, path_xyz, ompl_clearance, simplify_polls = np.zeros((0, 3)), np.zeros((0, 3)), math.nan, 0
    if bool(status):
        path = ss.getSolutionPath()
        raw_xyz = _states_xyz(path, w)
        if math.isnan(progress.first_time_s):  # RRTConnect has no bestCost: its first is its only solution
            progress.first_time_s, progress.first_iterations = solve_time, progress.iterations
            progress.first_cost = path.length()
        if config.simplify and exact:
            simplify_polls, capped = _simplify(ss, si, path, config.time_budget_s)
            progress.wall_cap_hit |= capped
        path_xyz = _states_xyz(path, w)
        ompl_clearance = float(path.clearance())
    return _Solved(solve_time_s=solve_time, progress=progress, status=status.asString(), exact=exact,
                   approximate=status == ob.PlannerStatus.APPROXIMATE_SOLUTION, path=path_xyz,
                   raw_path=raw_xyz, ompl_clearance=ompl_clearance, motion_checks=motion.calls,
                   simplify_polls=simplify_polls)


def _simplify(ss: og.SimpleSetup, si: ob.SpaceInformation, path: og.PathGeometric, wall_s: float
              ) -> tuple[int, bool]:
    """Shorten the path in place with OMPL's PathSimplifier: (termination polls, wall cap hit).

    `simplify` shortcuts (random segment pairs), B-spline-smooths, then removes vertices, until no
    vertex can be removed; every change goes through our exact motion check.  It is bounded by a
    poll count (deterministic) and a wall-time cap.
    """
    ps = og.PathSimplifier(si, ss.getGoal(), ss.getOptimizationObjective())
    polls = [0]
    capped = [False]
    t0 = time.perf_counter()

    def done() -> bool:
        polls[0] += 1
        capped[0] = time.perf_counter() - t0 > wall_s
        return polls[0] > _SIMPLIFY_POLLS or capped[0]

    ps.simplify(path, ob.PlannerTerminationCondition(done))
    return polls[0], capped[0]


# ---- the public entry point ----------------------------------------------------------------------------
def plan_path(city: BuildingMap, start_m: Sequence[float] | np.ndarray, goal_m: Sequence[float] | np.ndarray,
              radius_m: float, config: PlannerConfig = PlannerConfig(), seed: int = 0,
              tapers: Sequence[MarginTaper] = ()) -> PlanResult:
    """Plan a collision-free path for a sphere from start to goal.

    Args:
        city: the building map (its bounds are the flight volume); its no-fly volumes are obstacles
            here (`BuildingMap.planning_map`), kept at the same margin as the buildings.
        start_m: (3,) start position, ENU metres.
        goal_m: (3,) goal position, ENU metres.
        radius_m: vehicle collision radius [m]; the path keeps `config.safety_margin_m` beyond it.
        config: planner settings.
        seed: seed of OMPL's random generators (same seed and iteration budget -> same path).
        tapers: margins that narrow towards the start or goal (`planners.clearance.MarginTaper`: the
            reference is slow there, so it needs less clearance); none: `config.safety_margin_m`
            everywhere.

    A start or goal that is collision-free but inside the margin in force there is accepted: near it
    the required clearance is relaxed to its own (`planners.clearance.endpoint_allowance`).

    Returns:
        A PlanResult; an invalid start or goal, or no path within the budget, is a status, not an
        exception.

    Raises:
        ValueError: on bad arguments (non-finite points, negative radius, a radius that leaves no
            room in the bounds, a negative seed).
    """
    t_start = time.perf_counter()
    city = city.planning_map()
    start, goal, r, lo, hi = _checked_query(city, start_m, goal_m, radius_m, config.safety_margin_m, seed)
    common = _Common(algorithm=config.algorithm, seed=int(seed), radius_m=r,
                     required_clearance_m=config.safety_margin_m)
    for name, p in (("start", start), ("goal", goal)):
        problem = _endpoint_problem(city, p, r)
        if problem:
            return _failed(f"invalid_{name}", f"{name} {list(p)}: {problem}", t_start, common)
    free = FreeSpace(city, r, config.safety_margin_m, (start, goal), tapers)
    # The sampling box: bounds shrunk by R, stretched to hold a (relaxed) start and goal.
    lo = np.minimum(lo, np.minimum(start, goal))
    hi = np.maximum(hi, np.maximum(start, goal))

    if math.dist(start, goal) <= config.goal_tolerance_m:
        # already at the goal (a replan from where the vehicle holds on it): OMPL's informed sampling raises when its
        # foci coincide, and the one path is the straight piece
        path = np.array([start, goal])
        solved = _Solved(solve_time_s=0.0, progress=_Progress(first_time_s=0.0, first_iterations=0,
                                                               first_cost=math.dist(start, goal)),
                         status="Exact solution", exact=True, approximate=False, path=path, raw_path=path.copy(),
                         ompl_clearance=math.nan, motion_checks=0, simplify_polls=0)
    else:
        try:
            with _ompl_log_silenced():
                solved = _solve(free, lo, hi, start, goal, config, int(seed))
        except RuntimeError as e:  # OMPL's own failure is this query's failure, not the caller's crash
            return _failed("no_solution", f"OMPL raised: {e}", t_start, common)
    result = _result(solved, free, goal, config, t_start, common)
    logger.debug("plan %s seed %d: %s, %.1f m, %d it, %.3f s", config.algorithm, seed, result.status,
                 result.length_m, result.iterations, result.plan_time_s)
    return result


class _Common(TypedDict):
    """The `PlanResult` fields every outcome of a query shares."""

    algorithm: str
    seed: int
    radius_m: float
    required_clearance_m: float


def _checked_query(city: BuildingMap, start_m: Sequence[float] | np.ndarray, goal_m: Sequence[float] | np.ndarray,
                   radius_m: float, margin_m: float, seed: int
                   ) -> tuple[tuple[float, float, float], tuple[float, float, float], float, np.ndarray, np.ndarray]:
    """The query's arguments checked: (start, goal, radius [m], lo, hi), lo/hi the bounds shrunk by
    radius + margin (ENU metres). Raises ValueError on bad arguments (see `plan_path`)."""
    start = _point(start_m, "start_m")
    goal = _point(goal_m, "goal_m")
    r = float(radius_m)
    if not (math.isfinite(r) and r >= 0):
        raise ValueError(f"radius_m must be finite and >= 0, got {radius_m!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    R = r + margin_m
    lo = np.asarray(city.bounds_min_m, dtype=float) + R
    hi = np.asarray(city.bounds_max_m, dtype=float) - R
    if np.any(hi <= lo):
        raise ValueError(f"radius + margin {R} m leaves no room inside the map bounds")
    return start, goal, r, lo, hi


def _result(solved: _Solved, free: FreeSpace, goal: tuple[float, float, float], config: PlannerConfig,
            t_start: float, common: _Common) -> PlanResult:
    """The PlanResult of a solved query: the path finished at the goal, classified and measured."""
    progress = solved.progress
    path = solved.path
    goal_appended = False
    # OMPL stops within the goal tolerance; finish exactly at the goal when that piece is free.
    if solved.exact and len(path) and tuple(path[-1]) != goal and free.edge_ok(_xyz(path[-1]), goal):
        path = np.vstack([path, goal])
        goal_appended = True
    status, message = _classify(solved, free, path, config)
    length = float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1))) if len(path) else math.nan
    raw = solved.raw_path
    raw_length = float(np.sum(np.linalg.norm(np.diff(raw, axis=0), axis=1))) if len(raw) else math.nan
    min_clear = path_min_clearance(free.city, path, free.r, config.clearance_spacing_m) if len(path) else math.nan
    path.setflags(write=False)
    return PlanResult(
        status=status, path_m=path, length_m=length, raw_length_m=raw_length,
        plan_time_s=time.perf_counter() - t_start, solve_time_s=solved.solve_time_s,
        first_solution_time_s=progress.first_time_s, first_solution_iterations=progress.first_iterations,
        first_solution_length_m=progress.first_cost, iterations=progress.iterations,
        wall_cap_hit=progress.wall_cap_hit, min_clearance_m=min_clear, ompl_clearance_m=solved.ompl_clearance,
        message=message, extra={"ompl_status": solved.status, "motion_checks": solved.motion_checks,
               "simplify_polls": solved.simplify_polls, "goal_appended": goal_appended}, **common)


def _classify(solved: _Solved, free: FreeSpace, path: np.ndarray, config: PlannerConfig) -> tuple[str, str]:
    progress = solved.progress
    if solved.exact:
        if not free.path_ok(path):
            return "invalid_path", "the final path failed the exact swept-sphere re-check"
        return "exact", ""
    if progress.wall_cap_hit:
        return "timeout", (f"wall-time cap {config.time_budget_s} s hit after {progress.iterations} of "
                           f"{config.iteration_budget} iterations, without a path")
    if solved.approximate:
        return "approximate", "the planner only got near the goal (no path within the budget)"
    return "no_solution", f"no path after {progress.iterations} iterations ({solved.status})"


def _endpoint_problem(city: BuildingMap, p: tuple[float, float, float], r: float) -> str:
    """Why a start or goal cannot be used ("" if it can)."""
    if not bool(city.in_bounds(np.array([p]), r)[0]):
        return f"the vehicle sphere (r = {r} m) is not inside the map bounds"
    c = city.clearance_one(*p, r)
    if c <= 0.0:
        return f"in collision (clearance {c:.3f} m)"
    return ""


def _failed(status: str, message: str, t_start: float, common: _Common) -> PlanResult:
    nan = math.nan
    return PlanResult(status=status, path_m=_empty(), length_m=nan, raw_length_m=nan,
                      plan_time_s=time.perf_counter() - t_start, solve_time_s=0.0, first_solution_time_s=nan,
                      first_solution_iterations=-1, first_solution_length_m=nan, iterations=0,
                      wall_cap_hit=False, min_clearance_m=nan, ompl_clearance_m=nan, message=message,
                      **common)


def _empty() -> np.ndarray:
    a = np.zeros((0, 3))
    a.setflags(write=False)
    return a


def _point(p: Sequence[float] | np.ndarray, name: str) -> tuple[float, float, float]:
    a = np.asarray(p, dtype=float).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be 3 finite numbers (ENU metres), got {p!r}")
    return float(a[0]), float(a[1]), float(a[2])


def _xyz(p: np.ndarray) -> tuple[float, float, float]:
    """A position (3,) as a tuple of Python floats (the form `FreeSpace` keys its endpoints by)."""
    return float(p[0]), float(p[1]), float(p[2])
