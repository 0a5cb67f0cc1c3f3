"""The headline benchmark's cost: its wall time with `--jobs 2`, projected from its quick set flown here,
beside benchmark-perfect's projected the same way in the same run, and the MPC's solve times.

    OMP_NUM_THREADS=1 python perf/benchmark_cost.py [--skip-mpc] [--jobs 2]

A quick set holds a few tasks per vehicle of its full set, spread over its levels (docs/benchmark.md).
Each task's cells fly independently, so at a fixed `--jobs` a full run's flights take about the quick
run's times the ratio of their tasks. The end of a run (scores, report, viewer) does not scale so: the
report draws a bounded number of flights. It is timed apart (`uam-compare report` on the quick run,
which rescores and redraws everything) and added once, unscaled: a lower bound of the full set's, whose
report has more rows and tables. benchmark-perfect was flown whole on 2026-11-22
(`PERFECT_MEASURED_MIN`, docs/benchmark.md): its projection from benchmark-perfect-quick in the same
run says how far the projection is off, and `benchmark_wall_min_calibrated` applies that ratio. The MPC
part is `perf/classical.py`'s closed loop (real-time iteration against Ipopt).

Prints a table and, as its last line, one JSON object: `benchmark_wall_min_projected`,
`benchmark_wall_min_calibrated`, `benchmark_perfect_wall_min_projected`, `ratio_to_perfect`,
`mpc_solve_ms_median`, `uam_mpc_solve_ms_median` (and their Ipopt ratios), per-(vehicle, pilot) simulated
seconds and decision compute.
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

sys.path.insert(0, str(Path(__file__).resolve().parent))

PERFECT_MEASURED_MIN = 67.5
"""benchmark-perfect flown whole with --jobs 2 on this kind of machine (2,592 episodes; docs/benchmark.md)."""
SETS = {"benchmark": "benchmark-quick", "benchmark-perfect": "benchmark-perfect-quick"}


def tasks(spec: str) -> int:
    """Episodes (tasks) in a built-in set, every vehicle."""
    from compare.scenarios.sets import resolve_scenarios
    return sum(len(sc.episodes) for sc in resolve_scenarios(spec))


def _timed(*args: str) -> float:
    """Wall time [s] of `uam-compare ARGS` in a fresh interpreter; stops the script when it fails."""
    cmd = [sys.executable, "-m", "compare", *args]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({done.returncode}):\n{done.stderr[-3000:]}")
    return wall


def fly(spec: str, jobs: int, out: Path) -> float:
    """Fly a set with the default pilots into `out`; its wall time [s]."""
    return _timed("run", spec, "--jobs", str(jobs), "--videos", "none", "--out", str(out), "--no-progress")


def report_time(run: Path) -> float:
    """Wall time [s] of rescoring a run folder and rebuilding its report and viewer (the end of a run)."""
    return _timed("report", str(run))


def breakdown(run: Path) -> dict[str, dict[str, float]]:
    """Per vehicle/pilot: episodes, simulated seconds, mean decision compute [ms] (from metrics.csv)."""
    acc: dict[str, dict[str, float]] = defaultdict(lambda: {"episodes": 0.0, "flight_s": 0.0, "compute_ms_sum": 0.0})
    with open(run / "metrics.csv", newline="") as fh:
        for row in csv.DictReader(fh):
            a = acc[f"{row['vehicle']}/{row['method']}"]
            a["episodes"] += 1
            a["flight_s"] += float(row["time_s"])
            a["compute_ms_sum"] += float(row["compute_ms_mean"] or "nan")
    return {k: {"episodes": int(v["episodes"]), "flight_s": round(v["flight_s"], 1),
                "compute_ms_mean": round(v["compute_ms_sum"] / max(v["episodes"], 1), 3)} for k, v in acc.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2, help="worker processes of each run (the target's: 2)")
    ap.add_argument("--skip-mpc", action="store_true", help="skip the MPC closed loop")
    args = ap.parse_args()
    print(f"benchmark cost; OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}, --jobs {args.jobs}, "
          f"load average {os.getloadavg()[0]:.2f}")
    figures: dict = {}
    rows = []
    with tempfile.TemporaryDirectory(prefix="uam_cost_") as tmp:
        for full, quick in SETS.items():
            n_full, n_quick = tasks(full), tasks(quick)
            wall = fly(quick, args.jobs, Path(tmp) / quick)
            end = min(report_time(Path(tmp) / quick), wall)
            projected = ((wall - end) * n_full / n_quick + end) / 60.0
            rows.append((full, quick, n_full, n_quick, wall, projected))
            figures[f"{quick}_wall_s"] = round(wall, 1)
            figures[f"{quick}_report_s"] = round(end, 1)
            figures[f"{quick}_by_vehicle_pilot"] = breakdown(Path(tmp) / quick)
            print(f"{quick:26s} {n_quick:4d} tasks  {wall:7.1f} s (of which the report {end:5.1f} s)  -> {full:18s} "
                  f"{n_full:4d} tasks  projected {projected:6.1f} min", flush=True)
    new, perfect = rows[0][5], rows[1][5]
    calibration = PERFECT_MEASURED_MIN / perfect
    figures.update({"benchmark_wall_min_projected": round(new, 1),
                    "benchmark_perfect_wall_min_projected": round(perfect, 1),
                    "benchmark_perfect_wall_min_measured": PERFECT_MEASURED_MIN,
                    "projection_calibration": round(calibration, 3),
                    "benchmark_wall_min_calibrated": round(new * calibration, 1),
                    "ratio_to_perfect": round(new / perfect, 3), "jobs": args.jobs})
    print(f"benchmark projected {new:.1f} min ({new / perfect:.2f}x benchmark-perfect's {perfect:.1f} min projected "
          f"the same way, which was measured at {PERFECT_MEASURED_MIN} min: calibrated {new * calibration:.1f} min); "
          f"target <= 90 min")
    for quick in SETS.values():
        for key, b in figures[f"{quick}_by_vehicle_pilot"].items():
            print(f"  {quick:26s} {key:28s} {b['episodes']:3d} episodes {b['flight_s']:8.1f} s flown, "
                  f"{b['compute_ms_mean']:7.2f} ms per decision")
    if not args.skip_mpc:
        import classical
        mpc_rows = classical.run_mpc_benchmark(["small_quad", "uam_multicopter"], ["ipopt", "rti"])
        mpc = classical.mpc_figures(mpc_rows, "rti")
        figures.update({k: v for k, v in mpc.items() if k.startswith(("mpc_", "uam_mpc_"))})
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
