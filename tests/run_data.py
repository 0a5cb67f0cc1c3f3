"""What the tests that run comparisons share: the tiny scenario, the golden metrics and the columns of
metrics.csv that are measured on the wall clock (and so differ between two runs of the same command)."""
from __future__ import annotations

import csv
from pathlib import Path

DATA = Path(__file__).resolve().parent / "data"
TINY = DATA / "tiny_scenario.yaml"
GOLDEN = Path(__file__).resolve().parent / "golden" / "tiny_metrics.json"
WALL_CLOCK_COLUMNS = frozenset({"compute_ms_mean", "compute_ms_max", "plan_time_s", "mpc_solve_ms_median",
                                "mpc_solve_ms_p95"})


def without_wall_clock(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    """Rows of metrics.csv without the wall-clock columns: equal for equal runs."""
    return [{k: v for k, v in r.items() if k not in WALL_CLOCK_COLUMNS} for r in rows]


def deterministic_rows(path: Path) -> list[dict[str, str]]:
    """The rows of the metrics.csv at `path` without the wall-clock columns."""
    with open(path, newline="") as f:
        return without_wall_clock(list(csv.DictReader(f)))
