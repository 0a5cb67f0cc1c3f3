"""No give-up while a path exists: the classical pilot's planning attempts, in order.

RRT* with its deterministic budget sometimes ends with only an approximate path: the goal sits in
a narrow spot that the tree did not enter, or every way there is narrower than twice the cruise
margin. Neither means the goal is unreachable. The ladder tries, in this order, until one finds an
exact path:

1. the configured planner (InformedRRT*) with the speed-dependent margins (the cruise margin,
   narrowing towards the start and goal: `planners.clearance.MarginTaper`);
2. RRTConnect with the same margins and a small budget (`QUICK_ITERATIONS`): another OMPL planner of
   the family, bidirectional, so it grows a tree out of the goal's narrow spot too; it stops at its
   first path (the simplifier then shortens it). Where a path exists at these margins it finds one in
   far fewer iterations; where none does, the small budget keeps the failure cheap (on validation
   legs, hot and high, the quad's cruise margin left 11 of 40 plans to the ladder, and this step
   found 1 of them: the floor margin found the rest);
3. the configured planner at the floor margin everywhere (the margin at rest, `SpeedMargins.floor_m`):
   relaxed towards the floor; the reference is then slowed wherever the path passes closer than the
   cruise margin (`planners.timing.time_parameterize(..., speed_limit=...)`), so the margin in force
   still follows the speed;
4. RRTConnect at the floor margin with `LAST_STEP_ITERATIONS` times its budget (more time).

A goal none of them reaches is a planner failure whose message says so: no path at the floor
margin within these attempts, and whether a path at the floor margin exists at all
(`planners.reachability`: proved reachable, proved unreachable, or undetermined at the finest grid), so
that a failure on a reachable goal is told from one on a walled-in goal. Every step is seeded from the
same seed (deterministic).
"""
from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from planners.clearance import MarginTaper
from planners.reachability import Reachability, check_reachable
from planners.rrt_star import ALGORITHMS, PlannerConfig, PlanResult, plan_path
from uam_fdm.city.buildings import BuildingMap

log = logging.getLogger(__name__)

LAST_STEP_ITERATIONS = 4
QUICK_ITERATIONS = 2000
# a failure no other planner or margin can cure: stop climbing. An "invalid_path" (a found path that failed the
# exact re-check) is not one: the next step's planner or margin finds another path (seen on the benchmark: a
# small-quad goal given up after step 1)
_FINAL_STATUSES = ("invalid_start", "invalid_goal")


@dataclass(frozen=True)
class PlanStep:
    """One rung of the ladder.

    Attributes:
        name: how reports call it.
        algorithm: the OMPL planner (`planners.rrt_star.ALGORITHMS`); None: the configured one.
        iteration_factor: multiple of the algorithm's iteration budget [-].
        floor_margin: plan at the floor margin everywhere instead of the speed-dependent margins.
        max_iterations: a fixed iteration budget instead (when the configuration counts iterations).
    """

    name: str
    algorithm: str | None = None
    iteration_factor: int = 1
    floor_margin: bool = False
    max_iterations: int | None = None

    def __post_init__(self) -> None:
        if self.algorithm is not None and self.algorithm not in ALGORITHMS:
            raise ValueError(f"algorithm must be None or one of {ALGORITHMS}, got {self.algorithm!r}")
        if self.iteration_factor < 1:
            raise ValueError(f"iteration_factor must be >= 1, got {self.iteration_factor!r}")


LADDER: tuple[PlanStep, ...] = (
    PlanStep("configured planner, speed margins"),
    PlanStep("rrtconnect, speed margins", "rrtconnect", max_iterations=QUICK_ITERATIONS),
    PlanStep("configured planner, floor margin", floor_margin=True),
    PlanStep(f"rrtconnect, floor margin, {LAST_STEP_ITERATIONS}x iterations", "rrtconnect",
             LAST_STEP_ITERATIONS, floor_margin=True),
)


@dataclass(frozen=True)
class LadderResult:
    """What the ladder found.

    Attributes:
        plan: the exact plan found, or the last attempt's failure (its message then says the goal
            was not reached at the floor margin in any attempt).
        step: 1-based index in the ladder of the step that found the path (0: none did). A step that
            would repeat an earlier query exactly (the floor margin equal to the cruise margin) is skipped.
        step_name: that step's name ("" when none did).
        attempts: every attempt's result, in order.
        margin_m: the cruise margin the path keeps away from the start and goal [m].
        tapers: the margin tapers the path keeps (none for a floor-margin step).
        reachability: for a failure after every step, whether a path at the floor margin exists (None
            when a step found the path or the failure is final: an invalid start or goal).
    """

    plan: PlanResult
    step: int
    step_name: str
    attempts: tuple[PlanResult, ...]
    margin_m: float
    tapers: tuple[MarginTaper, ...]
    reachability: Reachability | None = None

    @property
    def ok(self) -> bool:
        return self.plan.ok

    @property
    def plan_time_s(self) -> float:
        """Wall time of every attempt together [s]."""
        return float(sum(a.plan_time_s for a in self.attempts))


def plan_with_escalation(city: BuildingMap, start_m: Sequence[float] | np.ndarray,
                         goal_m: Sequence[float] | np.ndarray, radius_m: float, config: PlannerConfig,
                         seed: int, floor_margin_m: float, tapers: Sequence[MarginTaper] = (),
                         ladder: Sequence[PlanStep] = LADDER) -> LadderResult:
    """Climb the ladder (module docstring) until a step finds an exact path.

    Args:
        city: the map (`plan_path`'s).
        start_m, goal_m: (3,) ENU metres.
        radius_m: vehicle collision radius [m].
        config: the configured planner; its `safety_margin_m` is the cruise margin [m].
        seed: OMPL seed, the same for every step.
        floor_margin_m: the margin at rest [m] (<= the cruise margin).
        tapers: the speed-dependent narrowing towards start and goal.
        ladder: the steps (`LADDER`).

    Returns:
        A LadderResult; a goal no step reaches is a failure status in it, never an exception.
    """
    if not ladder:
        raise ValueError("the ladder needs at least one step")
    floor = min(float(floor_margin_m), float(config.safety_margin_m))
    attempts: list[PlanResult] = []
    names: list[str] = []
    tried: set[tuple] = set()
    for i, step in enumerate(ladder, start=1):
        algorithm = step.algorithm or config.algorithm
        budget: int | None = None  # a pure time budget stays one (scaled below)
        if config.max_iterations is not None:
            per_step = PlannerConfig(algorithm=algorithm, max_iterations=config.max_iterations).iteration_budget
            budget = step.max_iterations or step.iteration_factor * int(per_step or 0)
        margin = floor if step.floor_margin else config.safety_margin_m
        cfg = dataclasses.replace(config, algorithm=algorithm, max_iterations=budget, safety_margin_m=margin,
                                  time_budget_s=config.time_budget_s * step.iteration_factor)
        used = () if step.floor_margin else tuple(tapers)
        key = (algorithm, budget, margin, used if margin > floor else ())
        if key in tried:  # the same query again (calm air: the floor is the cruise margin) finds nothing new
            continue
        tried.add(key)
        plan = plan_path(city, start_m, goal_m, radius_m, cfg, seed=seed, tapers=used)
        attempts.append(plan)
        names.append(step.name)
        if plan.ok:
            if i > 1:
                log.info("planner: step %d (%s) found the path after %s", i, step.name,
                         ", ".join(a.status for a in attempts[:-1]))
            return LadderResult(plan, i, step.name, tuple(attempts), margin, used)
        if plan.status in _FINAL_STATUSES:
            break
    summary = "; ".join(f"{n}: {a.status}" for n, a in zip(names, attempts, strict=True))
    last = attempts[-1]
    reach = None
    if last.status not in _FINAL_STATUSES:
        reach = check_reachable(city, start_m, goal_m, radius_m, floor)
        last = dataclasses.replace(last, message=f"no path at the floor margin {floor:.2f} m in {len(attempts)} "
                                                 f"attempts ({summary}); {reach.verdict}: {reach.reason}; "
                                                 f"last: {last.message}")
    return LadderResult(last, 0, "", tuple(attempts), float(config.safety_margin_m), tuple(tapers), reach)
