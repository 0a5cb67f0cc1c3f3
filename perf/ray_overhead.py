"""What Ray costs on one machine: the same cells flown by the local backend with 2 worker processes and by
Ray on a local instance of 2 CPUs.

Each backend flies the same set (default: the `default` scenario set, 12 cells) into its own run folder
through `compare.run.campaign.run_comparison`, without the PDF report and videos; the wall time runs from the
call to the scored metrics.csv, so it includes starting the workers (and Ray). Each backend runs
`--repeats` times in alternating order (local, ray, then ray, local, ...) and its fastest run counts (on a
shared machine, other work only ever adds time). Episodes per second = cells / wall time; the overhead
ratio = Ray's wall time / the local backend's. Every metrics.csv must agree apart from the wall-clock
columns (checked: the same episodes, whichever backend flew them).

    OMP_NUM_THREADS=1 python perf/ray_overhead.py [--set default] [--seeds 0] [--pilots P,..] [--repeats 2]

Prints a table and, as its last line, one JSON object: local_jobs2_episodes_per_s, ray_2cpu_episodes_per_s,
ray_overhead_ratio (and the wall times and cell count).
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

from compare.run.campaign import RunConfig, plan_cells, run_comparison, select_policies  # noqa: E402
from compare.scenarios.sets import resolve_scenarios  # noqa: E402

WALL_CLOCK_COLUMNS = {"compute_ms_mean", "compute_ms_max", "plan_time_s", "mpc_solve_ms_median",
                      "mpc_solve_ms_p95"}  # measured, not simulated (as tests/compare/cli/test_run_command.py)


def _rows(run_dir: Path) -> list[dict[str, str]]:
    with open(run_dir / "metrics.csv", newline="") as f:
        return [{k: v for k, v in r.items() if k not in WALL_CLOCK_COLUMNS} for r in csv.DictReader(f)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", default="default", help="scenario set, file or folder (default: default)")
    ap.add_argument("--seeds", default=None, help="comma-separated seeds (default: the scenarios' own)")
    ap.add_argument("--pilots", default=None, help="comma-separated pilots (default: the scenarios' own)")
    ap.add_argument("--repeats", type=int, default=2, help="runs per backend, alternating (default 2)")
    args = ap.parse_args()
    scenarios = resolve_scenarios(args.set)
    seeds = tuple(int(s) for s in args.seeds.split(",")) if args.seeds else None
    flown = tuple(args.pilots.split(",")) if args.pilots else None
    backends = {"local_jobs2": "local", "ray_2cpu": "ray"}
    walls: dict[str, list[float]] = {name: [] for name in backends}
    reference, cells = None, 0
    with tempfile.TemporaryDirectory(prefix="ray-overhead-") as tmp:
        for k in range(args.repeats):
            for name in (list(backends) if k % 2 == 0 else list(backends)[::-1]):
                opts = RunConfig(out_dir=Path(tmp) / f"{name}-{k}", pilots=flown, seeds=seeds, jobs=2,
                                 progress=False, report=False, videos="none", backend=backends[name],
                                 command=f"benchmark {name}")
                cells = len(plan_cells(scenarios, opts, select_policies(scenarios, opts))[0])
                t0 = time.perf_counter()
                run_comparison(scenarios, opts)
                walls[name].append(time.perf_counter() - t0)
                rows = _rows(opts.out_dir)
                reference = rows if reference is None else reference
                assert rows == reference, f"{name} run {k} flew different episodes"
                print(f"  {name} run {k}: {walls[name][-1]:.1f} s", flush=True)
    local_s, ray_s = min(walls["local_jobs2"]), min(walls["ray_2cpu"])
    print(f"{args.set}: {cells} cells ({platform.processor() or platform.machine()}, {os.cpu_count()} CPUs), "
          f"fastest of {args.repeats} runs each")
    print(f"{'backend':<22}{'wall [s]':>10}{'episodes/s':>12}   all runs [s]")
    for label, name in (("local, --jobs 2", "local_jobs2"), ("ray, 2 CPUs (local)", "ray_2cpu")):
        best = min(walls[name])
        print(f"{label:<22}{best:>10.1f}{cells / best:>12.3f}   {', '.join(f'{w:.1f}' for w in walls[name])}")
    print(f"Ray overhead ratio (Ray wall time / local wall time): {ray_s / local_s:.3f}; every metrics.csv "
          f"identical apart from the wall-clock columns")
    print(json.dumps({"set": args.set, "cells": cells, "repeats": args.repeats,
                      "local_jobs2_wall_s": round(local_s, 2), "ray_2cpu_wall_s": round(ray_s, 2),
                      "local_jobs2_episodes_per_s": round(cells / local_s, 4),
                      "ray_2cpu_episodes_per_s": round(cells / ray_s, 4),
                      "ray_overhead_ratio": round(ray_s / local_s, 4)}))


if __name__ == "__main__":
    main()
