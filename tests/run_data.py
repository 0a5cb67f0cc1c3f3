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


def deterministic_rows(path: Path, leave_out: frozenset[str] = frozenset()) -> list[dict[str, str]]:
    """The rows of a metrics.csv without the wall-clock columns (and `leave_out`): equal for equal runs."""
    with open(path, newline="") as f:
        return [{k: v for k, v in r.items() if k not in WALL_CLOCK_COLUMNS | leave_out} for r in csv.DictReader(f)]
