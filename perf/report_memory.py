"""What `uam-compare report` costs in wall time and peak memory, on a run folder of `.npz` episodes by the code
before the run store and on the same episodes in the store by this code.

Builds a synthetic run folder shaped like a benchmark run (`tests/synthetic_run.py`: 2 vehicles x `--scenarios`
x `--episodes` x 1 seed x 3 pilots) whose episodes have `--samples` rows each at the physics rate (10,000:
20 s at 500 Hz, a typical quad leg of the benchmark), then a copy of it moved into the store (each episode
scored and written as its cell's part, then compacted, as a run leaves it). `report` (score, summary, PDF
report, viewer) then runs in a fresh process on each: the `.npz` folder with the code at `--before` (a
checkout before the store, e.g. `git worktree add /tmp/before 63dd56f`), the store with this checkout; each
process reports its peak resident memory. Two scales (`--episodes` and twice that) give the memory per episode,
from which the full benchmark (2,592 episodes) is extrapolated.

    OMP_NUM_THREADS=1 python perf/report_memory.py --before /tmp/before [--scenarios 2] [--episodes 3]

Prints a table and, as its last line, one JSON object: per scale and side the wall time [s] and peak RSS [MB],
the RSS slope per episode [MB] and the extrapolation to 2,592 episodes [MB].
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE / "tests"))  # the synthetic run folder builder
sys.path.insert(0, str(HERE))  # the packages before tests/'s folders that mirror them (tests/uam_fdm, ...)

from synthetic_run import to_store, write_benchmark_run  # noqa: E402

PILOT_LABELS = {"ppo": "PPO policy", "rrt_mpc": "RRT* + MPC", "apf": "Potential field"}
BENCHMARK_EPISODES = 2592
_CHILD = ("import atexit, resource, sys\n"
          "atexit.register(lambda: print('MAXRSS_KB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, "
          "file=sys.stderr))\n"
          "from compare.cli import main\n"
          "sys.exit(main(sys.argv[1:]))\n")


def report(run_dir: Path, code: Path) -> tuple[float, float]:
    """Wall time [s] and peak RSS [MB] of `uam-compare report run_dir` with the code at `code`."""
    env = {**os.environ, "PYTHONPATH": str(code), "OMP_NUM_THREADS": "1"}
    t0 = time.perf_counter()
    # cwd: `python -c` puts the working folder first on sys.path, before PYTHONPATH
    done = subprocess.run([sys.executable, "-c", _CHILD, "report", str(run_dir)], env=env, capture_output=True,
                          text=True, cwd=code)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"report of {run_dir} with {code} failed:\n{done.stderr[-2000:]}")
    kb = [int(line.split()[1]) for line in done.stderr.splitlines() if line.startswith("MAXRSS_KB")]
    return wall, kb[-1] / 1024.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", type=Path, required=True, help="a checkout of the code before the run store")
    ap.add_argument("--scenarios", type=int, default=2, help="scenarios per vehicle")
    ap.add_argument("--episodes", type=int, default=3, help="episodes per scenario at the smaller scale")
    ap.add_argument("--samples", type=int, default=10_000, help="physics-rate rows per episode")
    args = ap.parse_args()
    figures: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory(prefix="report_memory_") as tmp:
        for scale in (args.episodes, 2 * args.episodes):
            npz = Path(tmp) / f"npz-{scale}"
            rows = write_benchmark_run(npz, scenarios_per_vehicle=args.scenarios, episodes=scale, seeds=(0,),
                                       pilots=PILOT_LABELS, samples=args.samples)
            store = Path(tmp) / f"store-{scale}"
            shutil.copytree(npz, store)
            to_store(store)
            n = len(rows)
            before = report(npz, args.before)
            after = report(store, HERE)
            npz_mb = sum(p.stat().st_size for p in (npz / "episodes").glob("*.npz")) / 1e6
            store_mb = sum(p.stat().st_size for p in (store / "store").rglob("*.parquet")) / 1e6
            figures[str(n)] = {"npz_report_s": round(before[0], 1), "npz_peak_mb": round(before[1]),
                               "store_report_s": round(after[0], 1), "store_peak_mb": round(after[1]),
                               "npz_mb": round(npz_mb, 1), "store_mb": round(store_mb, 1)}
    print(f"synthetic benchmark-shaped runs, {args.samples} physics-rate rows per episode; `report` in a fresh process")
    print(f"{'episodes':>8s} {'npz (before)':>22s} {'store (this code)':>22s} {'files npz / store':>18s}")
    for n, f in figures.items():
        print(f"{n:>8s} {f['npz_report_s']:8.1f} s {f['npz_peak_mb']:8.0f} MB {f['store_report_s']:8.1f} s "
              f"{f['store_peak_mb']:8.0f} MB {f['npz_mb']:8.1f} / {f['store_mb']:.1f} MB")
    (n1, a), (n2, b) = list(figures.items())
    out: dict[str, object] = {"runs": figures}
    for side in ("npz", "store"):
        slope = (b[f"{side}_peak_mb"] - a[f"{side}_peak_mb"]) / (int(n2) - int(n1))
        out[f"{side}_peak_mb_per_episode"] = round(slope, 3)
        out[f"{side}_peak_mb_at_{BENCHMARK_EPISODES}"] = round(b[f"{side}_peak_mb"] + slope * (BENCHMARK_EPISODES
                                                                                               - int(n2)))
    print(f"peak memory per episode: npz {out['npz_peak_mb_per_episode']} MB, store "
          f"{out['store_peak_mb_per_episode']} MB; extrapolated to {BENCHMARK_EPISODES} episodes: npz "
          f"{out[f'npz_peak_mb_at_{BENCHMARK_EPISODES}']} MB, store {out[f'store_peak_mb_at_{BENCHMARK_EPISODES}']} MB")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
