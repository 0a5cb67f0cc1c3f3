"""What `run`, `sweep` and `report` print at the end: per vehicle a table of the pilots and their paired success
differences, the files written, the task set flown (a sweep's rates per step, a benchmark's per level), and last
the headline figures as one JSON line for scripts."""
from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from compare.results.failures import FAILED_DIR, describe_failures, read_failures
from compare.results.level_rates import (
    level_json,
    level_mdd_json,
    level_mdds,
    level_pairs,
    level_rates,
    level_table_lines,
)
from compare.results.metrics import read_metrics_csv
from compare.results.run_info import read_run_info
from compare.results.stats import MIN_INTERVAL_N
from compare.results.summary import (
    NO_INTERVAL_NOTE,
    PairedStat,
    PairedSummary,
    PowerConfig,
    Stat,
    Summary,
    mdd_gap,
    pilots_table,
    read_summary_json,
)
from compare.results.sweep_rates import sweep_json, sweep_rates, sweep_table_lines
from compare.scenarios.benchmark import BENCHMARK_SETS
from compare.scenarios.sweep import SWEEP_SETS

SCENARIOS_PRINTED = 4
"""A vehicle's scenarios printed one by one at the end of a run when it has at most this many (else its table only)."""

TABLE_COLUMNS = ("pilot", "episodes", "success", "collision", "min clearance", "time", "SPL", "energy",
                 "compute mean")
"""The columns of `pilots_table` printed (by their name without unit or note); the report has them all."""


def print_run_results(run_dir: Path) -> None:
    """Everything a finished run prints: its tables, its task set, and last its headline JSON line."""
    print_summary(run_dir)
    print_task_set(run_dir)
    print_headline_json(run_dir)


def print_summary(run_dir: Path) -> None:
    """Per vehicle (never pooled: a quadrotor's and a multicopter's numbers do not average) one row per pilot,
    then its scenarios when there are few, then its paired success differences with their MDD; what "no CI"
    means when a cell says it; then the files written and the failed cells."""
    summary = read_summary_json(run_dir / "summary.json")
    scenarios = summary.by_scenario or {}
    per_vehicle = summary.per_vehicle()
    printed: list[str] = []
    if per_vehicle is None:  # a summary.json from before per-vehicle summaries: its scenarios, as then
        printed += _table(list((scenarios or {"all": summary}).items()))
        _print_lines(printed)
    for vehicle, part in (per_vehicle or {}).items():
        mine = [(name, s) for name, s in scenarios.items() if s.vehicle == vehicle]
        few = 1 < len(mine) <= SCENARIOS_PRINTED
        where = (f"scenario {mine[0][0]}" if len(mine) == 1 else
                 f"{len(mine)} scenarios" + ("" if few else f" (more than {SCENARIOS_PRINTED}: see report.pdf)"))
        lines = _table([(f"{vehicle}: {where}", part)] + [(f"{vehicle} / {name}", s) for name, s in mine if few])
        _print_lines(lines)
        printed += lines
        for pair in part.paired:
            print("  " + paired_success_line(pair, part.power))
    if any("no CI)" in line for line in printed):
        print(NO_INTERVAL_NOTE)
    note = wall_cap_note(run_dir)
    if note:
        print(note)
    _print_files(run_dir)


def wall_cap_note(run_dir: Path) -> str:
    """A line naming each pilot whose episodes had plans cut by the planner's wall-time cap (metrics.csv
    `planner_wall_caps`): those episodes depend on the machine's speed and load; "" when none had."""
    path = run_dir / "metrics.csv"
    if not path.is_file():
        return ""
    cut: dict[str, list[int]] = {}
    for r in read_metrics_csv(path):
        counts = cut.setdefault(r.method, [0, 0])
        counts[0] += int(math.isfinite(r.planner_wall_caps) and r.planner_wall_caps > 0)
        counts[1] += 1
    named = [f"{pilot} {n} of {total}" for pilot, (n, total) in cut.items() if n]
    if not named:
        return ""
    return (f"note: episodes with plans cut by the planner's wall-time cap ({', '.join(named)}; metrics.csv "
            f"planner_wall_caps): this machine was too slow or too loaded for their iteration budgets, and they may "
            f"not repeat on another machine or load")


def _table(blocks: list[tuple[str, Summary]]) -> list[str]:
    """The `TABLE_COLUMNS` of each block's pilots under the block's name, in aligned columns."""
    lines = []
    for name, part in blocks:
        full = pilots_table(part)
        keep = [i for i, h in enumerate(full[0]) if h.split(" [")[0].split(" (")[0] in TABLE_COLUMNS]
        lines.append([name] + [""] * (len(keep) - 1))
        lines += [[row[i] for i in keep] for row in full]
    widths = [max(len(str(r[i])) for r in lines) for i in range(len(lines[0]))]
    return ["  ".join(str(c).ljust(w) for c, w in zip(row, widths)).rstrip() for row in lines]


def _print_lines(lines: list[str]) -> None:
    for line in lines:
        print(line)


def _print_files(run_dir: Path) -> None:
    """The run folder's products, its videos, and its failed cells (what they are and how to fly them again)."""
    for name in ("report.pdf", "report-summary.pdf", "viewer.html", "metrics.csv", "summary.json"):
        if (run_dir / name).exists():
            print(run_dir / name)
    for video in sorted((run_dir / "videos").glob("[!.]*.*")):
        print(video)
    failed = read_failures(run_dir)
    if failed:
        print(f"{run_dir / FAILED_DIR}{os.sep}  {describe_failures(failed)}: no episode, no metrics row; one record "
              f"each, with the reason; `run --resume` flies them again")


def paired_success_line(pair: PairedSummary, power: PowerConfig) -> str:
    """One pair's success difference with its 95 % interval and whether it excludes zero (never below
    `MIN_INTERVAL_N` pairs), and the smallest difference this many pairs detect."""
    st = pair.stats.get("success")
    head = f"{pair.first} - {pair.second}: success difference"
    if st is None or st.mean is None:
        return f"{head} n/a (no paired episodes)"

    def pct(v: float | None, sign: str = "+") -> str:
        return "n/a" if v is None else f"{100.0 * v:{sign}.0f}%"

    def detectable(v: float | None) -> str:  # no difference of rates exceeds 100 %
        return "over 100%, too few pairs" if v is not None and v > 1.0 else pct(v, "")

    both = 100.0 * (power.design_rate or 0.5)
    design = "" if st.mdd_design is None else f"; before any run (both at {both:.0f} %): {detectable(st.mdd_design)}"
    gap = mdd_gap(st)
    seen = f"n/a ({gap})" if gap else detectable(st.mdd)
    test = "" if power.alpha is None else f" (alpha {power.alpha:g}, power {power.power:g})"
    return (f"{head} {pct(st.mean)} [{pct(st.ci_low)}, {pct(st.ci_high)}] over {st.n} paired episodes, "
            f"{verdict(st)}; smallest difference detectable{test}: {seen}{design}")


def verdict(st: PairedStat) -> str:
    """Whether a paired difference's interval excludes zero, in words (the report's star): never called below
    `MIN_INTERVAL_N` pairs."""
    excl = st.excludes_zero
    if excl is None:
        return f"too few pairs to call (fewer than {MIN_INTERVAL_N})" if st.n < MIN_INTERVAL_N else "no interval"
    return "the interval excludes 0" if excl else "the interval includes 0"


def print_task_set(run_dir: Path) -> None:
    """The task set a run flew, with its version (nothing for scenario files); a sweep's rates per step, a
    benchmark's per air, turbulence, sensing and map-error level with paired differences."""
    info = read_run_info(run_dir)
    task_set = info.task_set
    if task_set is not None and task_set.name in SWEEP_SETS:
        _print_lines(sweep_table_lines(sweep_rates(info, read_metrics_csv(run_dir / "metrics.csv"))))
    if task_set is not None and task_set.name in BENCHMARK_SETS and (run_dir / "metrics.csv").exists():
        rows = read_metrics_csv(run_dir / "metrics.csv")
        _print_lines(level_table_lines(level_rates(info, rows), level_pairs(info, rows)))
    if task_set is not None:
        print(f"task set {task_set.name}, version {task_set.version}: {task_set.description}")


def print_headline_json(run_dir: Path) -> None:
    """The run's headline figures as the last line, one JSON object (for scripts): per vehicle and pilot the
    episodes, success and collision rates with their 95 % Wilson intervals; per vehicle and pair of pilots the
    paired differences of those rates; the task set and its version (under the key "suite", as scripts read it);
    the failed cells; a sweep's rates per step ("sweep"), a benchmark's per level ("by_level") and its success MDDs
    per pair of pilots ("by_level_mdd")."""

    def rate(st: Stat | None) -> dict:
        return {"rate": st.mean, "ci95": [st.ci_low, st.ci_high]} if st is not None else {}

    def difference(st: PairedStat | None) -> dict:
        return {} if st is None else {"diff": st.mean, "ci95": [st.ci_low, st.ci_high], "pairs": st.n,
                                      "excludes_zero": st.excludes_zero}

    per_vehicle = read_summary_json(run_dir / "summary.json").per_vehicle() or {}
    info = read_run_info(run_dir)
    task_set = info.task_set
    out: dict[str, object] = {
        "run_dir": str(run_dir),
        "suite": None if task_set is None else {"name": task_set.name, "version": task_set.version},
        "vehicles": {v: {m: {"episodes": ms.episodes, "success": rate(ms.stats.get("success")),
                             "collision": rate(ms.stats.get("collision"))} for m, ms in part.pilots.items()}
                     for v, part in per_vehicle.items()},
        # per vehicle and pair of pilots: the paired differences of the rates (Newcombe intervals); excludes_zero
        # null below MIN_INTERVAL_N pairs, as in the report
        "paired": {v: {p.name: {k: difference(p.stats.get(k)) for k in ("success", "collision")}
                       for p in part.paired} for v, part in per_vehicle.items()},
        "failed_cells": len(read_failures(run_dir))}
    if task_set is not None and task_set.name in SWEEP_SETS:  # per vehicle, axis, step and pilot (printed above)
        out["sweep"] = sweep_json(sweep_rates(info, read_metrics_csv(run_dir / "metrics.csv")))
    if task_set is not None and task_set.name in BENCHMARK_SETS and (run_dir / "metrics.csv").exists():
        # per vehicle, air, turbulence, sensing and map-error level, with paired differences (printed above)
        rows = read_metrics_csv(run_dir / "metrics.csv")
        pairs = level_pairs(info, rows)
        out["by_level"] = level_json(level_rates(info, rows), pairs)
        # beside by_level, not in it: a vehicle's keys there are its axes (docs/benchmark.md), which readers iterate
        out["by_level_mdd"] = level_mdd_json(level_mdds(pairs))
    print(json_line(out))


def json_line(data: Any) -> str:
    """`data` as one line of strict JSON for scripts: a number that is not finite (a rate of no episodes is NaN)
    is null, as JSON has neither NaN nor Infinity and strict readers refuse them."""
    return json.dumps(_finite_or_null(data), allow_nan=False)


def _finite_or_null(value: Any) -> Any:
    if isinstance(value, float):  # NumPy's float64 too
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {k: _finite_or_null(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_null(v) for v in value]
    return value
