"""How long a benchmark-sized run takes to summarise and report (reports that never pool vehicles).

Builds a synthetic run folder shaped like a benchmark run (no simulation; `tests/synthetic_run.py`):
by default 2 vehicles x 25 scenarios x 10 episodes x 3 seeds = 1500 tasks, each flown by 4 pilots
(one a plug-in named `module:Class` that cannot be imported here): 6000 episode files and metrics rows.
Then times, in this process, the summary (`summarize_run` + `write_summary_json`, what `finalize` does
after scoring) and `build_report` (every page, PDF and PNGs), and counts the pages.

    OMP_NUM_THREADS=1 python perf/report_scale.py [--scenarios 25] [--episodes 10] [--seeds 3] [--keep DIR]

Prints a table and, as its last line, one JSON object of the figures.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the synthetic run folder builder
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the packages before tests/'s mirrored folders

from pypdf import PdfReader  # noqa: E402

from compare.report.report import build_report  # noqa: E402
from compare.results.summary import summarize_run, write_summary_json  # noqa: E402
from synthetic_run import write_benchmark_run  # noqa: E402

PILOT_LABELS = {"ppo": "PPO policy", "rrt_mpc": "RRT* + MPC", "apf": "Potential field",
                "mypkg.pilots:MyPilot": "My pilot (plug-in)"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", type=int, default=25, help="scenarios per vehicle")
    ap.add_argument("--episodes", type=int, default=10, help="episodes per scenario")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--keep", type=Path, default=None, help="build the run folder here and keep it")
    args = ap.parse_args()
    root = args.keep or Path(tempfile.mkdtemp(prefix="report_scale_"))
    run_dir = root / "run"
    try:
        t0 = time.perf_counter()
        rows = write_benchmark_run(run_dir, scenarios_per_vehicle=args.scenarios, episodes=args.episodes,
                                   seeds=tuple(range(args.seeds)), pilots=PILOT_LABELS)
        t1 = time.perf_counter()
        write_summary_json(summarize_run(rows), run_dir / "summary.json")
        t2 = time.perf_counter()
        pdf = build_report(run_dir)
        t3 = time.perf_counter()
        pages = len(PdfReader(pdf).pages)
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)
    tasks = len({(r.scenario, r.episode, r.seed) for r in rows})
    figures = {"scenarios": 2 * args.scenarios, "tasks": tasks, "episodes": len(rows), "pilots": len(PILOT_LABELS),
               "write_synthetic_run_s": round(t1 - t0, 1), "summary_s": round(t2 - t1, 1),
               "report_s": round(t3 - t2, 1), "report_pages": pages,
               "summary_json_kb": None if args.keep is None else round((run_dir / "summary.json").stat().st_size / 1e3)}
    print(f"{'synthetic run':<28}{figures['scenarios']} scenarios, {tasks} tasks, {len(rows)} episodes, "
          f"{len(PILOT_LABELS)} pilots ({t1 - t0:.1f} s to write)")
    print(f"{'summary (summarize_run)':<28}{t2 - t1:.1f} s")
    print(f"{'report (build_report)':<28}{t3 - t2:.1f} s, {pages} pages")
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
