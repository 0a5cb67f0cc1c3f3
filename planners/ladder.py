"""No give-up while a path exists: the classical pilot's planning attempts, in order.

RRT* with its deterministic budget sometimes ends with only an approximate path: the goal sits in a narrow
spot that the tree did not enter, or every way there is narrower than twice the cruise margin. Neither
means the goal is unreachable. The ladder tries, in this order, until one finds an exact path:

1. the configured planner (InformedRRT*) with the speed-dependent margins (the cruise margin, narrowing
   towards the start and goal: `planners.clearance.MarginTaper`);
2. RRTConnect (bidirectional; it stops at its first path, which the simplifier then shortens) with the same
   margins and a small budget (`QUICK_ITERATIONS`);
3. the configured planner at the floor margin everywhere (the margin at rest, `SpeedMargins.floor_m`); the
   reference is then slowed wherever the path passes closer than the cruise margin
   (`planners.timing.time_parameterize(..., speed_limit=...)`), so the margin in force still follows the speed;
4. RRTConnect at the floor margin with `LAST_STEP_ITERATIONS` times its budget.

A step plans with several seeds (`PlanStep.candidates`): an optimising planner's iteration budget is shared
by its seeds; a first-path planner's seeds each get the whole budget and are tried only once the first
found a path. With a judge (the pilot's own timing of the reference,
`planners.classical_pilot.ClassicalPilot`), the step keeps its fastest plan, and when even that does not fit
the time left (`time_available_s`), the ladder climbs on and flies the fastest plan of every step tried;
without a judge a step keeps its shortest path.

A goal none of them reaches is a planner failure whose message says so, and says whether a path at the
floor margin exists at all (`planners.reachability`: proved reachable, proved unreachable, or undetermined
at the finest grid). Every step is seeded from the same seed (deterministic). Why these steps, in this
order: docs/design_notes.md, "planners.ladder".
"""
from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from planners.clearance import MarginTaper
from planners.reachability import Reachability, check_reachable
from planners.rrt_star import ALGORITHMS, FIRST_PATH, PlannerConfig, PlanResult, plan_path
from uam_fdm.city.buildings import BuildingMap

log = logging.getLogger(__name__)

LAST_STEP_ITERATIONS = 4
QUICK_ITERATIONS = 2000
# a failure no other planner or margin can cure: stop climbing. An "invalid_path" (a found path that failed the
# exact re-check) is not one: the next step's planner or margin finds another path (seen on the benchmark: a
# small-quad goal given up after step 1)
_FINAL_STATUSES = ("invalid_start", "invalid_goal")
CANDIDATE_SEED_STRIDE = 1_000_003
"""Candidate k of a step plans with seed + k * this (a prime far above the seeds episodes use, so that one
episode's candidates are not another seed's first plans)."""

Judge = Callable[[PlanResult, float, tuple[MarginTaper, ...]], float]
"""How long a plan takes to fly [s], given the margin and tapers it was planned with; inf when it cannot be
flown (its reference fails)."""


@dataclass(frozen=True)
class PlanStep:
    """One rung of the ladder.

    Attributes:
        name: how reports call it.
        algorithm: the OMPL planner (`planners.rrt_star.ALGORITHMS`); None: the configured one.
        iteration_factor: multiple of the algorithm's iteration budget [-].
        floor_margin: plan at the floor margin everywhere instead of the speed-dependent margins.
        max_iterations: a fixed iteration budget instead (when the configuration counts iterations).
        candidates: seeds planned (1: one plan); the fastest exact plan is kept (with a judge; without one the
            shortest). An optimising planner's budget is shared by them; a first-path planner's (`FIRST_PATH`) seeds
            each get the whole, after the first has found a path.
    """

    name: str
    algorithm: str | None = None
    iteration_factor: int = 1
    floor_margin: bool = False
    max_iterations: int | None = None
    candidates: int = 1

    def __post_init__(self) -> None:
        if self.algorithm is not None and self.algorithm not in ALGORITHMS:
            raise ValueError(f"algorithm must be None or one of {ALGORITHMS}, got {self.algorithm!r}")
        if self.iteration_factor < 1:
            raise ValueError(f"iteration_factor must be >= 1, got {self.iteration_factor!r}")
        if self.candidates < 1:
            raise ValueError(f"candidates must be >= 1, got {self.candidates!r}")


# candidates: RRT*'s budget spread over two seeds (the same plan time), RRTConnect's quick first path four times
# (cheap where a path exists); the last step, already 4x the budget, once
LADDER: tuple[PlanStep, ...] = (
    PlanStep("configured planner, speed margins", candidates=2),
    PlanStep("rrtconnect, speed margins", "rrtconnect", max_iterations=QUICK_ITERATIONS, candidates=4),
    PlanStep("configured planner, floor margin", floor_margin=True, candidates=2),
    PlanStep(f"rrtconnect, floor margin, {LAST_STEP_ITERATIONS}x iterations", "rrtconnect",
             LAST_STEP_ITERATIONS, floor_margin=True),
)


IN_FLIGHT_ITERATIONS = 3000
"""The configured planner's iteration budget for a replan in flight: one seed (the reset's plan shares twice 5,000
over two). 2,000 was tried (docs/planner.md, "After the round"): on replayed queries its paths were 2.7 % longer for a
third fewer motion checks, but flown, validation legs it had arrived on collided or timed out."""

# a replan in flight: the same steps with one seed each, the optimising planner's budget cut to fit the time the
# vehicle brakes meanwhile, and the last one at twice the quick budget, not four times: a pilot that finds nothing
# holds and tries again (another seed, a map that has grown) instead of searching for seconds in the air
IN_FLIGHT_LADDER: tuple[PlanStep, ...] = (
    PlanStep("configured planner, speed margins, in flight", max_iterations=IN_FLIGHT_ITERATIONS),
    PlanStep("rrtconnect, speed margins", "rrtconnect", max_iterations=QUICK_ITERATIONS),
    PlanStep("configured planner, floor margin, in flight", floor_margin=True, max_iterations=IN_FLIGHT_ITERATIONS),
    PlanStep("rrtconnect, floor margin", "rrtconnect", max_iterations=2 * QUICK_ITERATIONS, floor_margin=True),
)


@dataclass(frozen=True)
class LadderResult:
    """What the ladder found.

    Attributes:
        plan: the plan flown (the fastest found, with a judge), or the last attempt's failure (its message then
            says the goal was not reached at the floor margin in any attempt).
        step: 1-based index in the ladder of the step whose plan it is (0: none found one). A step that
            would repeat an earlier query exactly (the floor margin equal to the cruise margin) is skipped.
        step_name: that step's name ("" when none did).
        attempts: one plan per step tried, in order (its first exact plan, else its first plan): what
            `planner_attempts` counts.
        margin_m: the cruise margin the path keeps away from the start and goal [m].
        tapers: the margin tapers the path keeps (none for a floor-margin step).
        reachability: for a failure after every step, whether a path at the floor margin exists (None
            when a step found the path or the failure is final: an invalid start or goal).
        candidates: every exact path found, over every step's seeds, in order.
        durations_s: the judge's flight time of each of `candidates` [s] (empty without a judge).
        plan_time_s: wall time of the whole ladder: every plan and every judgement [s].
        wall_caps: plans cut short by the planner's wall-time cap (`PlanResult.wall_cap_hit`): 0 unless the machine
            was too slow or too loaded for the iteration budgets, when the result depends on it.
    """

    plan: PlanResult
    step: int
    step_name: str
    attempts: tuple[PlanResult, ...]
    margin_m: float
    tapers: tuple[MarginTaper, ...]
    reachability: Reachability | None = None
    candidates: tuple[PlanResult, ...] = ()
    durations_s: tuple[float, ...] = ()
    plan_time_s: float = 0.0
    wall_caps: int = 0

    @property
    def ok(self) -> bool:
        return self.plan.ok

    @property
    def duration_s(self) -> float:
        """The judged flight time of the plan flown [s] (nan without a judge or a plan)."""
        for plan, d in zip(self.candidates, self.durations_s, strict=False):
            if plan is self.plan:
                return d
        return math.nan


@dataclass(frozen=True)
class _Found:
    """A path found by a step, with what it was planned with and (with a judge) its flight time [s]."""

    plan: PlanResult
    step: int
    margin_m: float
    tapers: tuple[MarginTaper, ...]
    duration_s: float


def plan_with_escalation(city: BuildingMap, start_m: Sequence[float] | np.ndarray,
                         goal_m: Sequence[float] | np.ndarray, radius_m: float, config: PlannerConfig,
                         seed: int, floor_margin_m: float, tapers: Sequence[MarginTaper] = (),
                         ladder: Sequence[PlanStep] = LADDER, judge: Judge | None = None,
                         time_available_s: float = math.inf, diagnose: bool = True) -> LadderResult:
    """Climb the ladder (module docstring) until a step finds an exact path (that fits the time, with a judge).

    Args:
        city: the map (`plan_path`'s).
        start_m, goal_m: (3,) ENU metres.
        radius_m: vehicle collision radius [m].
        config: the configured planner; its `safety_margin_m` is the cruise margin [m].
        seed: OMPL seed of each step's first plan (candidate k: + k * `CANDIDATE_SEED_STRIDE`).
        floor_margin_m: the margin at rest [m] (<= the cruise margin).
        tapers: the speed-dependent narrowing towards start and goal.
        ladder: the steps (`LADDER`).
        judge: a plan's flight time [s] (`Judge`); None: a step's shortest path is flown.
        time_available_s: a step whose fastest path takes longer than this [s] does not end the climb.
        diagnose: when no step finds a path, say whether one exists at the floor margin (`planners.reachability`,
            seconds to a minute on a large map); False: the message names the attempts only (a replan in flight,
            whose time the vehicle spends braking, holds and tries again instead).

    Returns:
        A LadderResult; a goal no step reaches is a failure status in it, never an exception.
    """
    if not ladder:
        raise ValueError("the ladder needs at least one step")
    t0 = time.perf_counter()
    floor = min(float(floor_margin_m), float(config.safety_margin_m))
    attempts: list[PlanResult] = []
    names: list[str] = []
    found: list[_Found] = []
    tried: set[tuple] = set()
    caps = 0  # plans cut by the wall-time cap

    def result(best: _Found) -> LadderResult:
        return LadderResult(best.plan, best.step, ladder[best.step - 1].name, tuple(attempts), best.margin_m,
                            best.tapers, None, tuple(f.plan for f in found),
                            tuple(f.duration_s for f in found) if judge is not None else (),
                            time.perf_counter() - t0, caps)

    for i, step in enumerate(ladder, start=1):
        algorithm = step.algorithm or config.algorithm
        shared = algorithm not in FIRST_PATH  # an optimising planner's budget is shared by the step's seeds
        share = step.candidates if shared else 1
        budget: int | None = None  # the step's; a pure time budget stays one (scaled below)
        if config.max_iterations is not None:
            per_step = PlannerConfig(algorithm=algorithm, max_iterations=config.max_iterations).iteration_budget
            budget = step.max_iterations or step.iteration_factor * int(per_step or 0)
        margin = floor if step.floor_margin else config.safety_margin_m
        cfg = dataclasses.replace(config, algorithm=algorithm, safety_margin_m=margin,
                                  max_iterations=None if budget is None else max(1, -(-budget // share)),
                                  time_budget_s=config.time_budget_s * step.iteration_factor / share)
        used = () if step.floor_margin else tuple(tapers)
        key = (algorithm, budget, margin, used if margin > floor else ())
        if key in tried:  # the same query again (calm air: the floor is the cruise margin) finds nothing new
            continue
        tried.add(key)
        plans = [plan_path(city, start_m, goal_m, radius_m, cfg, seed=seed, tapers=used)]
        if plans[0].ok or shared:
            plans += [plan_path(city, start_m, goal_m, radius_m, cfg, seed=seed + k * CANDIDATE_SEED_STRIDE,
                                tapers=used) for k in range(1, step.candidates)]
        caps += sum(p.wall_cap_hit for p in plans)
        mine = [p for p in plans if p.ok]
        attempts.append(mine[0] if mine else plans[0])
        names.append(step.name)
        if mine:
            for p in mine:
                found.append(_Found(p, i, margin, used, math.nan if judge is None else float(judge(p, margin, used))))
            if judge is None:  # the planner's own cost decides: the shortest
                return result(min(found[-len(mine):], key=lambda f: f.plan.length_m))
            best = min(found[-len(mine):], key=lambda f: f.duration_s)
            if best.duration_s <= time_available_s:
                if i > 1:
                    log.info("planner: step %d (%s) found the path after %s", i, step.name,
                             ", ".join(a.status for a in attempts[:-1]))
                return result(best)
            log.info("planner: step %d's fastest path takes %.1f s, more than the %.1f s left: climbing on", i,
                     best.duration_s, time_available_s)
        if plans[0].status in _FINAL_STATUSES:
            break
    if found:  # none fits the time: fly the fastest (it may still arrive; no path is sure not to)
        return result(min(found, key=lambda f: f.duration_s))
    summary = "; ".join(f"{n}: {a.status}" for n, a in zip(names, attempts, strict=True))
    last = attempts[-1]
    reach = None
    if last.status not in _FINAL_STATUSES:
        verdict = "not checked for a path"
        if diagnose:
            reach = check_reachable(city, start_m, goal_m, radius_m, floor)
            verdict = f"{reach.verdict}: {reach.reason}"
        last = dataclasses.replace(last, message=f"no path at the floor margin {floor:.2f} m in {len(attempts)} "
                                                 f"attempts ({summary}); {verdict}; last: {last.message}")
    return LadderResult(last, 0, "", tuple(attempts), float(config.safety_margin_m), tuple(tapers), reach,
                        plan_time_s=time.perf_counter() - t0, wall_caps=caps)
