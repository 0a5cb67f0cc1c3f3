"""The classical pilot's end-of-episode report (a `uam_fdm.pilot.PilotReport`).

Kept apart from `planners.classical_pilot` (which needs CasADi and OMPL) so that reading a saved episode
needs neither.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from uam_fdm.episode import Outcome

SOLVER_FAILURE_SHARE = 0.25
"""A failed episode with at least this share of failed MPC solves failed because of the solver."""


@dataclass(frozen=True)
class ClassicalReport:
    """What the classical pilot did in one episode (saved in the episode's metadata).

    Attributes:
        plan_time_s: planning at reset plus every replan [s]; replan_time_s: the replans' share [s].
        replans_tracking, replans_clearance: replans by cause (tracking error above the threshold;
            the MPC's prediction inside its clearance margin).
        mpc_solves, mpc_failures: MPC decisions and failed solves (fallback commands).
        mpc_solve_ms_median, mpc_solve_ms_p95: solver wall time per decision [ms] (NaN: none).
        mpc_statuses: solver return statuses and their counts.
        tracking_rms_m, tracking_max_m: RMS and largest distance from the vehicle to its reference
            curve over the decisions (`Reference.deviation_m`) [m] (NaN: none).
        planner_margin_m, mpc_margin_m: the margins flown at cruise speed (the largest) [m];
            margin_source: where they came from.
        planner_margin_floor_m: the planner margin at rest (the least outside a close start's or
            goal's zone) [m].
        planner_attempts: planning attempts at reset (`planners.ladder`; 1 = the first step found the
            path); planner_step: the step that found it ("" when none did).
        planner_wall_caps: plans cut short by the planner's wall-time cap over the episode (`planners.ladder`): 0
            unless the machine was too slow or too loaded for the iteration budgets; then the episode may not repeat
            on another machine or load.
        clearance_over_margin_min: least, over the flight's physics steps, of the vehicle's true sphere clearance
            (to the true world's buildings and the ground) over the margin in force at its reference point at the
            time (the promise: >= 0.5) [-]; measured by the scorer (`compare.flying.promise.scored_report`), NaN
            as the pilot reports it.
        replans_blocked, replans_uncertainty: replans flying on sensors because a newly sensed obstacle came
            within the margin of the path still to fly, or because k σ of the estimate outgrew the margin planned
            with (NaN at `perfect` sensing: nothing is sensed).
        hover_holds: times the pilot held (hovered) for want of a path in what it knew.
        replan_ms_median, replan_ms_p95: wall time of a replan in flight [ms] (what `replan_budget_s` must cover).
        map_update_ms_median: wall time to map one lidar scan [ms].
        uncertainty_margin_max_m: the largest k σ added to the margins [m].
        sensed_obstacles: obstacles in the fused map at the end that the prior lacked (clusters of sensed
            columns); cleared_prior_parts: prior parts taken out because beams passed through them.
        improvements_tried, improvements_taken: searches for a faster path while flying one found at the floor
            margin, and those that replaced it (arriving at least `improve_gain_s` earlier).

    Read from an episode file saved before a field existed, that field is NaN (a count too: the
    counts' `float`), {} or "".
    """

    plan_time_s: float
    replan_time_s: float
    replans_tracking: int | float
    replans_clearance: int | float
    mpc_solves: int | float
    mpc_failures: int | float
    mpc_solve_ms_median: float
    mpc_solve_ms_p95: float
    mpc_statuses: dict[str, int]
    tracking_rms_m: float
    tracking_max_m: float
    planner_margin_m: float
    mpc_margin_m: float
    margin_source: str
    planner_margin_floor_m: float = math.nan
    planner_attempts: int | float = math.nan
    planner_step: str = ""
    planner_wall_caps: int | float = math.nan
    clearance_over_margin_min: float = math.nan
    replans_blocked: int | float = math.nan
    replans_uncertainty: int | float = math.nan
    hover_holds: int | float = math.nan
    replan_ms_median: float = math.nan
    replan_ms_p95: float = math.nan
    map_update_ms_median: float = math.nan
    uncertainty_margin_max_m: float = math.nan
    sensed_obstacles: int | float = math.nan
    cleared_prior_parts: int | float = math.nan
    improvements_tried: int | float = math.nan
    improvements_taken: int | float = math.nan

    @property
    def replans(self) -> int | float:
        """Replans of every cause (those not recorded, as in an older file or at `perfect` sensing, count 0
        unless none is recorded)."""
        return self.replans_tracking + self.replans_clearance + sum(
            v for v in (self.replans_blocked, self.replans_uncertainty) if not math.isnan(v))

    def failure_reason(self, outcome: Outcome) -> Outcome | None:
        """`Outcome.SOLVER_FAILURE` for an episode that failed in flight (not for want of a plan) with at
        least `SOLVER_FAILURE_SHARE` of its MPC solves failed; else None."""
        if outcome in (Outcome.SUCCESS, Outcome.PLANNER_FAILURE) or not self.mpc_solves:
            return None
        return Outcome.SOLVER_FAILURE if self.mpc_failures >= SOLVER_FAILURE_SHARE * self.mpc_solves else None

    def to_json(self) -> dict[str, Any]:
        """The fields plus `replans`, JSON-ready (NaN as null)."""
        out = dataclasses.asdict(self)
        out["replans"] = self.replans
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in out.items()}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> ClassicalReport | None:
        """The report `to_json` wrote, or None when `data` holds none of its fields. Also reads the few
        counters an episode saved before the report kept at the top level of its metadata (`replans`
        then counted tracking replans only)."""
        if not any(f.name in data for f in dataclasses.fields(cls)) and "replans" not in data:
            return None

        def num(name: str, default: Any = None) -> float:
            v = data.get(name, default)
            return math.nan if v is None or isinstance(v, (str, dict, list)) else v

        statuses = data.get("mpc_statuses")
        return cls(
            plan_time_s=num("plan_time_s"), replan_time_s=num("replan_time_s"),
            replans_tracking=num("replans_tracking", data.get("replans")), replans_clearance=num("replans_clearance"),
            mpc_solves=num("mpc_solves"), mpc_failures=num("mpc_failures"),
            mpc_solve_ms_median=num("mpc_solve_ms_median"), mpc_solve_ms_p95=num("mpc_solve_ms_p95"),
            mpc_statuses={str(k): int(v) for k, v in statuses.items()} if isinstance(statuses, Mapping) else {},
            tracking_rms_m=num("tracking_rms_m"), tracking_max_m=num("tracking_max_m"),
            planner_margin_m=num("planner_margin_m"), mpc_margin_m=num("mpc_margin_m"),
            margin_source=str(data.get("margin_source") or ""), planner_margin_floor_m=num("planner_margin_floor_m"),
            planner_attempts=num("planner_attempts"), planner_step=str(data.get("planner_step") or ""),
            planner_wall_caps=num("planner_wall_caps"),
            clearance_over_margin_min=num("clearance_over_margin_min"),
            **{name: num(name) for name in _SENSING_FIELDS})


_SENSING_FIELDS = ("replans_blocked", "replans_uncertainty", "hover_holds", "replan_ms_median", "replan_ms_p95",
                   "map_update_ms_median", "uncertainty_margin_max_m", "sensed_obstacles", "cleared_prior_parts",
                   "improvements_tried", "improvements_taken")
