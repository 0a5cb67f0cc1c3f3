"""The planning ladder: the order of its steps, which step found the path, and a failure only when none did."""
from __future__ import annotations

import dataclasses
import math

import pytest

import planners.ladder as ladder_module
from alley import alley_city
from planners.clearance import MarginTaper
from planners.ladder import (
    CANDIDATE_SEED_STRIDE,
    IN_FLIGHT_ITERATIONS,
    IN_FLIGHT_LADDER,
    LADDER,
    PlanStep,
    plan_with_escalation,
)
from planners.margins import SpeedMargins
from planners.rrt_star import PlannerConfig

R_QUAD = 0.42
MARGINS = SpeedMargins((2.0, 6.0), (1.0, 2.0, 4.0))   # 1 m at rest, 4 m at cruise
CONFIG = PlannerConfig(safety_margin_m=MARGINS.cruise_m, max_iterations=3000)


def _tapers(start, goal, accel=5.0):
    return tuple(MarginTaper(p, *MARGINS.taper(accel)) for p in (start, goal))


def test_the_ladder_order():
    assert [(s.algorithm, s.iteration_factor, s.max_iterations, s.floor_margin) for s in LADDER] == [
        (None, 1, None, False), ("rrtconnect", 1, 2000, False), (None, 1, None, True), ("rrtconnect", 4, None, True)]
    assert [s.candidates for s in LADDER] == [2, 4, 2, 1]
    with pytest.raises(ValueError, match="algorithm"):
        PlanStep("x", "astar")
    with pytest.raises(ValueError, match="candidates"):
        PlanStep("x", candidates=0)


def test_an_open_goal_is_found_by_the_first_step():
    city, start, _ = alley_city(R_QUAD)
    goal = (-5.0, 25.0, 10.0)          # in the open, far from the alley
    found = plan_with_escalation(city, start, goal, R_QUAD, CONFIG, 0, MARGINS.floor_m, _tapers(start, goal))
    assert found.ok and found.step == 1 and len(found.attempts) == 1 and found.margin_m == MARGINS.cruise_m


def test_a_goal_inside_the_cruise_margin_is_found_at_the_floor_margin():
    city, start, goal = alley_city(R_QUAD)
    found = plan_with_escalation(city, start, goal, R_QUAD, CONFIG, 0, MARGINS.floor_m, _tapers(start, goal))
    # the cruise margin (4 m) does not fit the alley (3 m) with either planner: the floor margin does
    assert found.ok and found.step == 3 and found.step_name == LADDER[2].name
    assert not any(a.ok for a in found.attempts[:2])
    assert found.attempts[1].algorithm == "rrtconnect" and found.attempts[1].iterations <= 2001  # the quick step
    assert found.margin_m == MARGINS.floor_m and found.tapers == ()
    assert found.plan.min_clearance_m >= MARGINS.floor_m - 1e-9
    assert found.plan_time_s >= sum(a.plan_time_s for a in found.attempts)  # the ladder's wall time: all of it
    # deterministic: the same seed, the same path
    again = plan_with_escalation(city, start, goal, R_QUAD, CONFIG, 0, MARGINS.floor_m, _tapers(start, goal))
    assert (again.plan.path_m == found.plan.path_m).all()


def test_a_walled_in_goal_is_a_planner_failure_that_says_so():
    city, start, goal = alley_city(R_QUAD, closed=True)
    found = plan_with_escalation(city, start, goal, R_QUAD, CONFIG, 0, MARGINS.floor_m, _tapers(start, goal))
    assert not found.ok and found.step == 0 and len(found.attempts) == len(LADDER)
    assert found.plan.status in ("approximate", "no_solution")
    assert "no path at the floor margin 1.00 m in 4 attempts" in found.plan.message
    assert found.reachability is not None and found.reachability.verdict == "unreachable"
    assert "unreachable: no connected free space joins start and goal" in found.plan.message


def test_in_flight_the_ladder_is_smaller_and_a_failure_is_not_diagnosed(monkeypatch: pytest.MonkeyPatch):
    """A replan in flight (`IN_FLIGHT_LADDER`): one seed per step, the optimising planner's budget cut, the floor
    margin tried by the quick planner only; no path means a hold and another try, not the reachability search."""
    assert [(s.algorithm, s.max_iterations, s.floor_margin, s.candidates) for s in IN_FLIGHT_LADDER] == [
        (None, IN_FLIGHT_ITERATIONS, False, 1), ("rrtconnect", 2000, False, 1), (None, IN_FLIGHT_ITERATIONS, True, 1),
        ("rrtconnect", 4000, True, 1)]
    city, start, goal = alley_city(R_QUAD)
    found = plan_with_escalation(city, start, goal, R_QUAD, CONFIG, 0, MARGINS.floor_m, _tapers(start, goal),
                                 ladder=IN_FLIGHT_LADDER, diagnose=False)
    assert found.ok and found.step == 3 and found.margin_m == MARGINS.floor_m  # the alley, at the floor margin

    def searched(*_args, **_kwargs):
        raise AssertionError("the reachability search ran")

    monkeypatch.setattr(ladder_module, "check_reachable", searched)
    city, start, goal = alley_city(R_QUAD, closed=True)
    found = plan_with_escalation(city, start, goal, R_QUAD, CONFIG, 0, MARGINS.floor_m, _tapers(start, goal),
                                 ladder=IN_FLIGHT_LADDER, diagnose=False)
    assert not found.ok and found.reachability is None and "not checked for a path" in found.plan.message


def test_a_step_that_repeats_an_earlier_query_is_skipped():
    city, start, goal = alley_city(R_QUAD, closed=True)
    flat = PlannerConfig(safety_margin_m=1.0, max_iterations=1000)
    found = plan_with_escalation(city, start, goal, R_QUAD, flat, 0, floor_margin_m=1.0)
    # floor = cruise: step 3 would be step 1 again; step 4 (more iterations) is a new query
    assert len(found.attempts) == 3 and "in 3 attempts" in found.plan.message


def test_a_path_that_fails_the_final_check_climbs_on(monkeypatch: pytest.MonkeyPatch):
    """A found path that fails the exact re-check ("invalid_path") is no reason to give up: the next step plans
    another; only an invalid start or goal ends the ladder at once."""
    import planners.ladder as ladder

    city, start, _ = alley_city(R_QUAD)
    goal = (-5.0, 25.0, 10.0)
    real = ladder.plan_path
    calls: list[str] = []

    def first_invalid(*args, **kwargs):
        plan = real(*args, **kwargs)
        calls.append(plan.status)
        if len(calls) == 1:
            return dataclasses.replace(plan, status="invalid_path", message="re-check failed")
        return plan

    monkeypatch.setattr(ladder, "plan_path", first_invalid)
    single = tuple(dataclasses.replace(s, candidates=1) for s in LADDER)
    found = plan_with_escalation(city, start, goal, R_QUAD, CONFIG, 0, MARGINS.floor_m, _tapers(start, goal),
                                 ladder=single)
    assert found.ok and found.step == 2 and [a.status for a in found.attempts] == ["invalid_path", "exact"]
    # with the shipped ladder, step 1's other seed (half its budget each) finds another path
    calls.clear()
    shared = plan_with_escalation(city, start, goal, R_QUAD, CONFIG, 0, MARGINS.floor_m, _tapers(start, goal))
    assert shared.ok and shared.step == 1 and shared.plan.seed == CANDIDATE_SEED_STRIDE
    assert calls == ["exact", "exact"] and len(shared.candidates) == 1
    inside = (0.0, 0.0, -5.0)  # below the ground: an invalid goal ends the ladder at its first step
    stopped = plan_with_escalation(city, start, inside, R_QUAD, CONFIG, 0, MARGINS.floor_m, _tapers(start, inside))
    assert not stopped.ok and stopped.plan.status == "invalid_goal" and len(stopped.attempts) == 1
    assert stopped.reachability is None


def _length_judge(calls: list):
    """A judge that flies every path at 5 m/s and records what it saw."""
    def judge(plan, margin_m, tapers):
        calls.append((plan.seed, margin_m, tapers))
        return plan.length_m / 5.0
    return judge


def test_a_step_keeps_its_fastest_candidate():
    city, start, _ = alley_city(R_QUAD)
    goal = (46.0 + R_QUAD, 0.0, 10.0)  # behind the alley's end block: round it on either side
    steps = (dataclasses.replace(LADDER[0], candidates=3), *LADDER[1:])
    calls: list = []
    found = plan_with_escalation(city, start, goal, R_QUAD, CONFIG, 7, MARGINS.floor_m, _tapers(start, goal),
                                 ladder=steps, judge=_length_judge(calls))
    assert found.ok and found.step == 1 and len(found.attempts) == 1 and len(found.candidates) == 3
    # candidate k plans with seed + k * the stride, each judged with the margin and tapers it was planned with
    assert [c[0] for c in calls] == [7 + k * CANDIDATE_SEED_STRIDE for k in range(3)]
    assert all(c.iterations <= CONFIG.max_iterations // 3 + 1 for c in found.candidates)  # the budget, shared
    assert all(c[1] == MARGINS.cruise_m and c[2] == _tapers(start, goal) for c in calls)
    assert found.duration_s == min(found.durations_s) == found.plan.length_m / 5.0
    assert len({round(c.length_m, 6) for c in found.candidates}) > 1  # the seeds do find other paths
    # without a judge: the planner's own cost decides, the shortest path (here also the fastest at 5 m/s)
    first = plan_with_escalation(city, start, goal, R_QUAD, CONFIG, 7, MARGINS.floor_m, _tapers(start, goal),
                                 ladder=steps)
    assert first.plan.length_m == min(c.length_m for c in found.candidates) and math.isnan(first.duration_s)
    assert first.durations_s == () and len(first.candidates) == 3
    # deterministic
    again = plan_with_escalation(city, start, goal, R_QUAD, CONFIG, 7, MARGINS.floor_m, _tapers(start, goal),
                                 ladder=steps, judge=_length_judge([]))
    assert (again.plan.path_m == found.plan.path_m).all() and again.durations_s == found.durations_s


def test_a_path_too_slow_for_the_time_left_climbs_on_and_the_fastest_is_flown():
    city, start, _ = alley_city(R_QUAD)
    goal = (-5.0, 25.0, 10.0)
    single = tuple(dataclasses.replace(s, candidates=1) for s in LADDER)
    found = plan_with_escalation(city, start, goal, R_QUAD, CONFIG, 0, MARGINS.floor_m, _tapers(start, goal),
                                 ladder=single, judge=_length_judge([]), time_available_s=1.0)
    # no path takes under 1 s: every step is tried, and the fastest of all their paths is flown
    assert found.ok and len(found.attempts) == len(LADDER) and len(found.candidates) == len(LADDER)
    assert found.duration_s == min(found.durations_s) > 1.0
    assert found.step == 1 + found.durations_s.index(found.duration_s)
    assert found.margin_m == (MARGINS.cruise_m if found.step <= 2 else MARGINS.floor_m)
    # with time enough the first step's path is flown
    easy = plan_with_escalation(city, start, goal, R_QUAD, CONFIG, 0, MARGINS.floor_m, _tapers(start, goal),
                                ladder=single, judge=_length_judge([]), time_available_s=found.durations_s[0])
    assert easy.step == 1 and len(easy.attempts) == 1


def test_plans_cut_by_the_wall_cap_are_counted(monkeypatch: pytest.MonkeyPatch):
    """Every plan the wall-time cap cut is counted (the episode may not repeat on another machine), whichever step
    it belonged to and whether or not a later one found the path; none are counted when none were cut."""
    import planners.ladder as ladder

    city, start, goal = alley_city(R_QUAD)
    real = ladder.plan_path
    calls: list[int] = []

    def second_capped(*args, **kwargs):
        plan = real(*args, **kwargs)
        calls.append(1)
        return dataclasses.replace(plan, wall_cap_hit=True) if len(calls) == 2 else plan

    plain = plan_with_escalation(city, start, goal, R_QUAD, CONFIG, 0, MARGINS.floor_m, _tapers(start, goal))
    assert plain.ok and plain.wall_caps == 0
    monkeypatch.setattr(ladder, "plan_path", second_capped)
    found = plan_with_escalation(city, start, goal, R_QUAD, CONFIG, 0, MARGINS.floor_m, _tapers(start, goal))
    assert found.ok and found.step == 3 and len(calls) > 2 and found.wall_caps == 1
    calls[:] = [1]  # the next plan is cut
    below = (0.0, 0.0, -5.0)  # an invalid goal: a failure reports its count too
    failed = plan_with_escalation(city, start, below, R_QUAD, CONFIG, 0, MARGINS.floor_m, _tapers(start, below))
    # step 1 plans both of its seeds (an optimising planner's shared budget) before the invalid goal ends the climb
    assert not failed.ok and len(calls) == 3 and failed.wall_caps == 1
