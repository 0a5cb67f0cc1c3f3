"""The classical pilot's tracker per scenario: the margins it flew against the clearance it kept, its MPC solver,
its replans and planning attempts (metrics.csv's tracker columns, `TRACKER_METRICS`); and, flying on its sensors,
its mapping and replanning in flight (`MAPPING_METRICS`)."""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

from compare.report.layout import table_pages
from compare.results.metrics import EpisodeMetrics


def _column(rows: Sequence[EpisodeMetrics], name: str) -> np.ndarray:
    """One metrics.csv column of `rows` as floats (booleans as 0/1)."""
    return np.array([float(getattr(r, name)) for r in rows])


def tracker_pages(label: str, rows: Sequence[EpisodeMetrics], pilot: str) -> list[Figure]:
    """A pilot's tracker per scenario (margins flown vs clearance kept, solver, replans), from metrics.csv rows;
    `label`: the pilot's display label. Nothing for a pilot without tracker columns (e.g. the learned pilot), one
    that did not fly, or a file that predates the tracker columns."""
    mine = [r for r in rows if r.method == pilot]
    if not mine or all(not math.isfinite(r.planner_margin_m) for r in mine):
        return []
    table = [_tracker_row(scenario, [r for r in mine if r.scenario == scenario])
             for scenario in dict.fromkeys(r.scenario for r in mine)]
    header = ["scenario", "episodes", "success [%]", "margin rest-cruise / MPC [m]", "min clearance [m]",
              "min clearance / margin", "tracking RMS [m]", "tracking max [m]", "solve median [ms]",
              "solve p95 max [ms]", "failures", "replans track / clear", "plan attempts max / >1"]
    notes = [("Margins: from the vehicle's measured tracking error at each reference speed in the scenario's "
              "forecast turbulence and air, narrowing from cruise towards start and goal (docs/planner.md). "
              "Min clearance / margin: over the margin in force where the vehicle was. Target: >= 0.5."),
             ("Plan attempts: planning attempts at reset (1: the first planner found the path; more: the "
              "escalation ladder of planners/ladder.py), largest / episodes with more than one."),
             ("Min clearance: least over the episodes. Tracking: distance to the reference curve (RMS: mean over "
              "episodes; max: over all)."),
             ("Solve: median of the episodes' medians, largest episode p95. Failures and replans: summed over the "
              "episodes.")]
    return table_pages(f"Metrics: the {label} tracker per scenario", header, table, notes=notes, font_size=8)


def _tracker_row(scenario: str, rs: list[EpisodeMetrics]) -> list[str]:
    """One scenario's row of the tracker table."""
    def agg(f, x: np.ndarray, digits: int) -> str:
        x = x[np.isfinite(x)]
        return f"{f(x):.{digits}f}" if x.size else "n/a"

    col = {k: _column(rs, k) for k in
           ("success", "min_clearance_m", "planner_margin_m", "mpc_margin_m", "tracking_rms_m", "tracking_max_m",
            "mpc_solve_ms_median", "mpc_solve_ms_p95", "mpc_failures", "replans_tracking", "replans_clearance",
            "planner_margin_floor_m", "planner_attempts", "clearance_over_margin_min")}
    # the margin in force where the vehicle was when recorded (speed-dependent), else the one margin flown
    local = col["clearance_over_margin_min"]
    ratio = np.where(np.isfinite(local), local, col["min_clearance_m"] / col["planner_margin_m"])
    floor = col["planner_margin_floor_m"]
    margins = (agg(np.max, col["planner_margin_m"], 2) if not np.any(np.isfinite(floor)) else
               agg(np.min, floor, 2) + "-" + agg(np.max, col["planner_margin_m"], 2))
    attempts = col["planner_attempts"]

    return [scenario, str(len(rs)), agg(np.mean, 100.0 * col["success"], 0),
            margins + " / " + agg(np.max, col["mpc_margin_m"], 2),
            agg(np.min, col["min_clearance_m"], 2), agg(np.min, ratio, 2),
            agg(np.mean, col["tracking_rms_m"], 3), agg(np.max, col["tracking_max_m"], 2),
            agg(np.median, col["mpc_solve_ms_median"], 2), agg(np.max, col["mpc_solve_ms_p95"], 2),
            agg(np.sum, col["mpc_failures"], 0),
            agg(np.sum, col["replans_tracking"], 0) + " / " + agg(np.sum, col["replans_clearance"], 0),
            agg(np.max, attempts, 0) + " / " + agg(np.sum, attempts > 1, 0)]


def mapping_pages(label: str, rows: Sequence[EpisodeMetrics], pilot: str) -> list[Figure]:
    """A pilot's mapping and replanning in flight per scenario and sensing / map-error level, from metrics.csv rows;
    nothing for a pilot without those columns or flights at `perfect` sensing only (where it maps nothing)."""
    mine = [r for r in rows if r.method == pilot and math.isfinite(r.map_update_ms_median)]
    if not mine:
        return []
    groups = dict.fromkeys((r.scenario, r.sensing, r.map_error) for r in mine)
    table = [_mapping_row(key, [r for r in mine if (r.scenario, r.sensing, r.map_error) == key]) for key in groups]
    header = ["scenario", "sensing / map", "episodes", "success [%]", "collisions", "replans blocked / uncert. / "
              "track / clear", "hover holds", "replan median / p95 max [ms]", "map update median [ms]",
              "k sigma max [m]", "unmapped sensed / first at min [m]", "min clearance unmapped [m]",
              "sensed obstacles median"]
    notes = [("Replans in flight by cause: a newly sensed obstacle within the margin of the path still to fly "
              "(blocked), the estimate's k sigma outgrowing the margins planned with (uncert.), the tracking error, "
              "the MPC's predicted clearance. Replan time: wall time of the map refresh and the in-flight planning "
              "ladder; the flight spends the pilot's fixed replan budget whatever it is (docs/planner.md)."),
             ("Unmapped: obstacles the prior map lacks (missing buildings, cranes, masts); first at: the least true "
              "range at which a lidar beam first hit one. Min clearance unmapped: least over the episodes."),
             ("Sensed obstacles: boxes of the fused map standing for what the prior lacked, at the episode's end "
              "(median over episodes).")]
    return table_pages(f"Metrics: the {label} mapping and replanning in flight per scenario", header, table,
                       notes=notes, font_size=8)


def _mapping_row(key: tuple[str, str, str], rs: list[EpisodeMetrics]) -> list[str]:
    """One (scenario, sensing, map error) row of the mapping table."""
    def agg(f, name: str, digits: int) -> str:
        x = _column(rs, name)
        x = x[np.isfinite(x)]
        return f"{f(x):.{digits}f}" if x.size else "n/a"

    scenario, sensing, map_error = key
    replans = " / ".join(agg(np.sum, name, 0) for name in
                         ("replans_blocked", "replans_uncertainty", "replans_tracking", "replans_clearance"))
    success = f"{100.0 * float(np.mean(_column(rs, 'success'))):.0f}"
    return [scenario, f"{sensing} / {map_error}", str(len(rs)), success, agg(np.sum, "collision", 0), replans,
            agg(np.sum, "hover_holds", 0),
            agg(np.median, "replan_ms_median", 0) + " / " + agg(np.max, "replan_ms_p95", 0),
            agg(np.median, "map_update_ms_median", 1), agg(np.max, "uncertainty_margin_max_m", 2),
            agg(np.sum, "unmapped_sensed", 0) + " / " + agg(np.min, "unmapped_first_sensed_m_min", 1),
            agg(np.min, "min_clearance_unmapped_m", 2), agg(np.median, "sensed_obstacles", 0)]
