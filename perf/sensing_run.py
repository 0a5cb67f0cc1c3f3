"""The default run at `nominal` sensing against the same run at `perfect` sensing, in one process tree, one after the
other (issue target: nominal <= 1.3x perfect's wall time).

Each run is the README's main command (`uam-compare run`, the built-in default scenarios) with `--sensing LEVEL`,
videos off (encoding is the same work at every level and would only dilute the ratio), in a fresh folder; the wall
time is the whole command's, from start to its last line. Run on an otherwise idle machine:

    OMP_NUM_THREADS=1 python perf/sensing_run.py [--scenario default] [--repeats 1]

Prints a table, then one JSON line: `default_run_perfect_s`, `default_run_nominal_s`, `nominal_wall_ratio`, and the
per-episode flight figures read back from each run's metrics.csv.
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
from pathlib import Path


def _run(scenario: str, level: str, out: Path) -> float:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "compare", "run", scenario, "--sensing", level, "--videos", "none", "--no-progress",
           "--out", str(out)]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def _rows(out: Path) -> list[dict[str, str]]:
    with open(out / "metrics.csv", newline="") as f:
        return list(csv.DictReader(f))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="default")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--keep", type=Path, default=None, help="keep the run folders here (default: deleted)")
    args = parser.parse_args()
    walls: dict[str, list[float]] = {"perfect": [], "nominal": []}
    rows: dict[str, list[dict[str, str]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.repeats):
            for level in ("perfect", "nominal"):
                out = (args.keep or Path(tmp)) / f"{level}-{k}"
                walls[level].append(_run(args.scenario, level, out))
                rows[level] = _rows(out)
    best = {level: min(v) for level, v in walls.items()}
    ratio = best["nominal"] / best["perfect"]
    flight = {level: sum(float(x["time_s"]) for x in rows[level]) for level in rows}
    # per second flown: the sensing's own cost, apart from flights that last longer when a pilot fails on sensors
    per_flight = (best["nominal"] / flight["nominal"]) / (best["perfect"] / flight["perfect"])
    print(f"`uam-compare run {args.scenario} --sensing LEVEL --videos none`, best of {args.repeats}")
    print(f"{'level':10s} {'wall [s]':>10s} {'episodes':>9s} {'flight [s]':>11s} {'success':>8s} "
          f"{'est. error h RMS [m]':>21s}")
    for level in ("perfect", "nominal"):
        r = rows[level]
        flight = sum(float(x["time_s"]) for x in r)
        success = sum(x["success"] == "1" for x in r)
        h = [float(x["est_error_h_rms_m"]) for x in r]
        print(f"{level:10s} {best[level]:10.1f} {len(r):9d} {flight:11.1f} {success:8d} {max(h):21.2f}")
    print(f"nominal / perfect wall time: {ratio:.2f} (target <= 1.3); per second flown: {per_flight:.2f}")
    print(json.dumps({"default_run_perfect_s": round(best["perfect"], 2),
                      "default_run_nominal_s": round(best["nominal"], 2),
                      "nominal_wall_ratio": round(ratio, 3), "nominal_wall_per_flight_s_ratio": round(per_flight, 3),
                      "flight_s_perfect": round(sum(float(x["time_s"]) for x in rows["perfect"]), 2),
                      "flight_s_nominal": round(sum(float(x["time_s"]) for x in rows["nominal"]), 2)}))


if __name__ == "__main__":
    main()
