"""The classical pilot's mapping and replanning in flight, per scenario and level, on the tracker pages and in the
summary (not paired); nothing of it at perfect sensing."""
from __future__ import annotations

import math

from compare.report.tracker_pages import mapping_pages
from compare.results.metrics import MAPPING_METRICS, EpisodeMetrics
from compare.results.summary import summarize

BASE = {"map": "town-map", "vehicle": "small_quad", "min_clearance_m": 3.0, "time_below_2m_s": 0.0,
        "time_below_5m_s": 1.0, "time_s": 20.0, "path_length_m": 100.0, "straight_line_m": 90.0, "spl": 0.9,
        "energy_kj": 50.0, "compute_ms_mean": 1.0, "compute_ms_max": 2.0, "plan_time_s": 0.5}


def _row(episode: int, sensed: bool, outcome: str = "success") -> EpisodeMetrics:
    mapping = {name: float(episode + 1) for name in MAPPING_METRICS} if sensed else {}
    return EpisodeMetrics(scenario="town", episode=episode, method="rrt_mpc", seed=0, outcome=outcome,
                          success=outcome == "success", collision=outcome == "collision",
                          failure_reason="" if outcome == "success" else outcome,
                          sensing="nominal" if sensed else "perfect", map_error="wrong" if sensed else "exact",
                          replans_clearance=1.0, unmapped_sensed=1.0, unmapped_first_sensed_m_min=40.0 + episode,
                          min_clearance_unmapped_m=5.0 - episode, **BASE, **mapping)


def test_flights_on_sensors_get_a_mapping_table_and_perfect_flights_none():
    rows = [_row(0, True), _row(1, True, "collision"), _row(2, False)]
    assert mapping_pages("RRT* + MPC", [r for r in rows if r.sensing == "perfect"], "rrt_mpc") == []
    assert mapping_pages("RRT* + MPC", rows, "ppo") == []
    pages = mapping_pages("RRT* + MPC", rows, "rrt_mpc")
    assert len(pages) == 1
    cells = [cell for ax in pages[0].axes for table in ax.tables for cell in table.get_celld().values()]
    texts = [t.get_text() for ax in pages[0].axes for t in ax.texts] + [cell.get_text().get_text() for cell in cells]
    texts = [t.replace("\n", " ") for t in texts]
    joined = " | ".join(texts)
    assert "nominal / wrong" in joined and "perfect / exact" not in joined
    # 2 episodes: success 50 %, 1 collision, blocked replans 1 + 2 (uncertainty 3, tracking not recorded, clearance
    # 2), the least first-sensed range and clearance
    for cell in ("50", "3 / 3 / n/a / 2", "2 / 40.0", "4.00"):
        assert cell in texts, cell


def test_the_summary_carries_the_mapping_columns_unpaired():
    rows = [_row(e, True) for e in range(3)]
    rows += [EpisodeMetrics(**{**r.__dict__, "method": "ppo", **{m: math.nan for m in MAPPING_METRICS}})
             for r in rows]
    s = summarize(rows, resamples=200, seed=1)
    assert s.pilots["rrt_mpc"].stats["replans_blocked"].mean == 2.0
    assert s.pilots["ppo"].stats["replans_blocked"].n == 0
    assert all("replans_blocked" not in p.stats for p in s.paired)
