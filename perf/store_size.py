"""What the run store costs and saves: the same flown episodes written as the `.npz` files a run
wrote before the store (one per episode, physics rate, float64) and as the store (each cell's part at the
control rate, then compacted into the episode table and samples files), in this process.

For each cell (in run order, the first `--tasks` tasks of each vehicle, every pilot): fly it
(`CellRunner.fly`, timed: the cell's wall time), then time and size its `.npz` (`episode_bytes`) and its part
(`CellRunner.stored`: scoring, thinning, the Parquet bytes) and the part's write to disk. Then the parts are
compacted (timed) and the store's files summed. The write overhead is the part (bytes and file) over the
cell's wall time, per cell after the first: the first part of a process also pays pyarrow's start (about
0.1-0.8 s here, once per worker process, like an import), reported apart; the compaction is reported per episode
beside it.

    OMP_NUM_THREADS=1 python perf/store_size.py [--set benchmark-quick] [--tasks 4] [--store control]

Prints a table per vehicle and in total and, as its last line, one JSON object: store_bytes_per_episode,
npz_bytes_per_episode, ratio_vs_npz, write_overhead_pct (mean over the cells after the first; also its median and
worst cell), first_part_ms, compaction_ms_per_episode, episodes, set.
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from collections import defaultdict
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

from compare.results.store import compact, part_path, store_dir, write_part  # noqa: E402
from compare.results.trajectory import episode_bytes  # noqa: E402
from compare.run.campaign import RunConfig, plan_cells, select_policies  # noqa: E402
from compare.run.cells import CellRunner  # noqa: E402
from compare.scenarios.sets import resolve_scenarios  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", default="benchmark-quick", help="scenario set or file (default benchmark-quick)")
    ap.add_argument("--tasks", type=int, default=0, help="tasks (scenario, episode, seed) per vehicle; 0: all")
    ap.add_argument("--store", choices=("control", "full"), default="control")
    args = ap.parse_args()
    scenarios = resolve_scenarios(args.set)
    with tempfile.TemporaryDirectory(prefix="store_size_") as tmp:
        run_dir = Path(tmp) / "run"
        opts = RunConfig(out_dir=run_dir, progress=False, report=False, videos="none", store=args.store)
        cells, _ = plan_cells(scenarios, opts, select_policies(scenarios, opts))
        tasks: dict[str, list] = defaultdict(list)  # per vehicle, in run order
        for c in cells:
            task = (c.scenario, c.episode, c.seed)
            vehicle = scenarios[c.scenario].vehicle_name
            if task not in tasks[vehicle]:
                tasks[vehicle].append(task)
        keep = {t for ts in tasks.values() for t in (ts[:args.tasks] if args.tasks else ts)}
        cells = [c for c in cells if (c.scenario, c.episode, c.seed) in keep]
        policies = {fp: f.folder for fp, f in select_policies(scenarios, opts).items()}
        runner = CellRunner(scenarios, run_dir, policies, args.store)
        per: dict[str, dict[str, float]] = defaultdict(lambda: defaultdict(float))
        overheads, part_ms = [], []
        for c in cells:
            t0 = time.perf_counter()
            meta, traj = runner.fly(c)
            t1 = time.perf_counter()
            npz = episode_bytes(meta, traj)
            t2 = time.perf_counter()
            data = runner.stored(c, meta, traj)
            write_part(part_path(run_dir, meta.key), data)
            t3 = time.perf_counter()
            overheads.append((t3 - t2) / (t1 - t0))
            part_ms.append(1e3 * (t3 - t2))
            v = per[scenarios[c.scenario].vehicle_name]
            v["episodes"] += 1
            v["npz_bytes"] += len(npz)
            v["part_bytes"] += len(data)
            v["cell_s"] += t1 - t0
            v["npz_s"] += t2 - t1
            v["part_s"] += (t3 - t2) if len(part_ms) > 1 else 0.0  # the first: pyarrow's start, apart
            v["samples_physics"] += len(traj.t_s)
        t0 = time.perf_counter()
        compact(run_dir)
        compact_s = time.perf_counter() - t0
        store_bytes = sum(p.stat().st_size for p in store_dir(run_dir).rglob("*.parquet"))
    n = sum(v["episodes"] for v in per.values())
    npz_total = sum(v["npz_bytes"] for v in per.values())
    print(f"set {args.set}: {n} episodes ({args.tasks or 'all'} tasks per vehicle, every pilot), store {args.store}")
    print(f"{'vehicle':18s} {'episodes':>8s} {'npz kB/ep':>10s} {'part kB/ep':>11s} {'part/npz':>9s} "
          f"{'cell s/ep':>9s} {'npz ms/ep':>9s} {'part ms/ep':>10s} {'overhead':>9s}")
    for name, v in per.items():
        k = v["episodes"]
        print(f"{name:18s} {k:8.0f} {v['npz_bytes'] / k / 1e3:10.1f} {v['part_bytes'] / k / 1e3:11.1f} "
              f"{v['npz_bytes'] / v['part_bytes']:8.1f}x {v['cell_s'] / k:9.2f} {1e3 * v['npz_s'] / k:9.1f} "
              f"{1e3 * v['part_s'] / k:10.1f} {100 * v['part_s'] / v['cell_s']:8.2f}%")
    print(f"compacted store: {store_bytes / 1e3:.1f} kB in all, {store_bytes / n / 1e3:.1f} kB per episode, "
          f"{npz_total / store_bytes:.1f}x smaller than the .npz files ({npz_total / 1e6:.1f} MB); compaction "
          f"{compact_s:.2f} s ({1e3 * compact_s / n:.1f} ms per episode)")
    steady = sorted(overheads[1:]) or overheads
    print(f"writing a part: {100 * sum(steady) / len(steady):.2f} % of a cell's wall time on average (median "
          f"{100 * steady[len(steady) // 2]:.2f} %, worst {100 * steady[-1]:.2f} %), "
          f"{sum(part_ms[1:]) / max(1, n - 1):.1f} ms per part; the first part of a process {part_ms[0]:.0f} ms "
          f"(pyarrow's start)")
    print(json.dumps({
        "set": args.set, "store": args.store, "episodes": int(n), "tasks_per_vehicle": args.tasks or None,
        "npz_bytes_per_episode": round(npz_total / n), "compaction_ms_per_episode": round(1e3 * compact_s / n, 2),
        "write_overhead_pct": round(100 * sum(steady) / len(steady), 3),
        "write_overhead_pct_median": round(100 * steady[len(steady) // 2], 3),
        "write_overhead_pct_max": round(100 * steady[-1], 3), "first_part_ms": round(part_ms[0], 1),
        "store_bytes_per_episode": round(store_bytes / n), "ratio_vs_npz": round(npz_total / store_bytes, 2)}))


if __name__ == "__main__":
    main()
