"""What flying on its sensors costs the classical pilot in flight time at the `exact` map (issue 43).

Reads a run folder's metrics.csv (a run of `benchmark`, or any set with sensing levels), takes the classical
pilot's (`rrt_mpc`) episodes on the exact map at a sensing level other than `perfect`, and flies each again with the
same seed at `perfect` sensing (the truth handed through: the privileged pilot, which plans once on the exact state
and map, as before sensing existed). Paired per leg, over the legs both flights arrived on, it prints per vehicle
and sensing level the mean flight time of each and their difference (sensed - perfect) with its 95 %
percentile-bootstrap interval (the run summary's method and seed); the target is "not longer beyond the interval".
It prints the legs only one of the two arrived on too.

    OMP_NUM_THREADS=1 python perf/sensing_time_cost.py RUN_DIR [--set benchmark] [--jobs 2]

Prints the table and, as its last line, one JSON object of the figures (per vehicle and level: `legs_paired`,
`time_sensed_s_mean`, `time_perfect_s_mean`, `time_diff_s_mean`, `time_diff_s_low`, `time_diff_s_high`).
"""
from __future__ import annotations

import argparse
import os
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from compare.cli.printout import json_line
from compare.results.metrics import EpisodeMetrics, episode_metrics, read_metrics_csv
from compare.results.stats import Bootstrap
from compare.results.trajectory import SavedEpisode
from compare.run.cells import Cell, CellRunner
from compare.scenarios.benchmark import build_task_set
from compare.scenarios.levels import with_levels

PILOT = "rrt_mpc"
BOOTSTRAP = Bootstrap(resamples=2000, confidence=0.95, seed=0)  # as the run summary's

Leg = tuple[str, int, int]  # scenario, episode, seed


def _fly(job: tuple[str, list[Leg]]) -> list[tuple[Leg, bool, float]]:
    """One worker's share: each leg of the set `job[0]` flown at `perfect` sensing on the exact map."""
    set_name, legs = job
    scenarios = [with_levels(sc, "perfect", "exact") for sc in build_task_set(set_name).scenarios]
    index = {sc.name: i for i, sc in enumerate(scenarios)}
    out = []
    with tempfile.TemporaryDirectory(prefix="uam_exact_") as tmp:
        runner = CellRunner(scenarios, Path(tmp), {})
        for leg in legs:
            meta, traj = runner.fly(Cell(index[leg[0]], leg[1], leg[2], PILOT))
            m = episode_metrics(SavedEpisode(meta, traj))
            out.append((leg, bool(m.success), float(m.time_s)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", type=Path, help="a run folder of the set (its metrics.csv is read)")
    ap.add_argument("--set", default="benchmark", help="the built-in set the run flew (default benchmark)")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    args = ap.parse_args()
    csv = args.run_dir / "metrics.csv"
    if not csv.is_file():
        raise SystemExit(f"{csv}: no metrics.csv in the run folder")
    rows = [r for r in read_metrics_csv(csv)
            if r.method == PILOT and r.map_error == "exact" and r.sensing != "perfect"]
    if not rows:
        raise SystemExit(f"{csv}: no {PILOT} episode on the exact map at a sensing level other than perfect")
    names = {sc.name for sc in build_task_set(args.set).scenarios}
    unknown = sorted({r.scenario for r in rows} - names)
    if unknown:
        raise SystemExit(f"{csv}: scenarios {unknown[:3]} are not in the set {args.set!r} (--set)")
    legs = sorted((r.scenario, r.episode, r.seed) for r in rows)
    jobs = max(1, args.jobs)
    shares = [(args.set, legs[i::jobs]) for i in range(jobs)]
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        perfect = {leg: (ok, t) for share in pool.map(_fly, shares) for leg, ok, t in share}
    figures: dict[str, dict[str, float | int]] = {}
    print(f"classical pilot, {args.set} exact-map legs: flown on its sensors (the run) against at perfect sensing")
    print(f"{'vehicle':16s} {'sensing':9s} {'paired':>6s} {'sensed s':>9s} {'perfect s':>9s} "
          f"{'difference s [95 %]':>26s} {'only sensed':>11s} {'only perfect':>12s}")
    for key in sorted({(r.vehicle, r.sensing) for r in rows}):
        group: list[EpisodeMetrics] = [r for r in rows if (r.vehicle, r.sensing) == key]
        twin = [perfect[(r.scenario, r.episode, r.seed)] for r in group]  # each leg's flight at perfect sensing
        both = [(r.time_s, t) for r, (ok, t) in zip(group, twin, strict=True) if r.success and ok]
        only_sensed = sum(r.success and not ok for r, (ok, _) in zip(group, twin, strict=True))
        only_perfect = sum(not r.success and ok for r, (ok, _) in zip(group, twin, strict=True))
        a = np.array([s for s, _ in both])
        b = np.array([p for _, p in both])
        mean, low, high = BOOTSTRAP.mean_ci(a - b)
        fig: dict[str, float | int] = {
            "legs": len(group), "legs_paired": len(both), "only_sensed": only_sensed, "only_perfect": only_perfect,
            "time_sensed_s_mean": float(a.mean()) if a.size else float("nan"),
            "time_perfect_s_mean": float(b.mean()) if b.size else float("nan"),
            "time_diff_s_mean": float("nan") if mean is None else mean,
            "time_diff_s_low": float("nan") if low is None else low,
            "time_diff_s_high": float("nan") if high is None else high}
        figures[f"{key[0]}/{key[1]}"] = fig
        interval = "too few legs" if low is None or high is None else f"[{low:+.2f}, {high:+.2f}]"
        print(f"{key[0]:16s} {key[1]:9s} {len(both):6d} {fig['time_sensed_s_mean']:9.2f} "
              f"{fig['time_perfect_s_mean']:9.2f} {fig['time_diff_s_mean']:+9.2f} {interval:>16s} "
              f"{only_sensed:11d} {only_perfect:12d}")
    print(json_line({"set": args.set, "pilot": PILOT, "by_vehicle_sensing": figures}))


if __name__ == "__main__":
    main()
