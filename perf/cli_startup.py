"""How long the command line takes to start: `import compare.cli` and `uam-compare --help` (as `python -m compare
--help`) against the bare interpreter's start (`python -c pass`), each the median of `--runs` fresh processes.

The CLI imports PyTorch, Ray, matplotlib, the planners and the learned pilot only inside the commands that use
them (tests/test_architecture.py), so that printing help or refusing a bad option is quick; this script keeps
that measured. The three commands take turns, run after run, so that a slower moment of this shared machine
weighs on each alike. `--root` times another source tree (e.g. an earlier commit unpacked with
`git archive HEAD~1 compare uam_fdm planners rl | tar -x -C /tmp/before`): its folder is the processes' working
folder, which `python -c` and `python -m` put first on the import path.

    OMP_NUM_THREADS=1 python perf/cli_startup.py [--runs 15] [--root DIR] [--before /tmp/before]

Prints a table and, as its last line, one JSON object: `python_start_s`, `import_cli_s`, `help_s` (medians [s])
and `import_cli_ratio`, `help_ratio` (each over `python_start_s`); with `--before`, also `import_cli_before_s`,
`help_before_s` and the ratios now / before, `import_cli_vs_before` and `help_vs_before`.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = {  # JSON key -> (what the table calls it, the interpreter's arguments)
    "python_start_s": ("python -c pass", ["-c", "pass"]),
    "import_cli_s": ('python -c "import compare.cli"', ["-c", "import compare.cli"]),
    "help_s": ("python -m compare --help", ["-m", "compare", "--help"]),
    "train_help_s": ("python -m compare train --help", ["-m", "compare", "train", "--help"]),
    "animate_help_s": ("python -m compare animate --help", ["-m", "compare", "animate", "--help"]),
}


def wall_time_s(args: list[str], cwd: Path) -> float:
    """Wall time [s] of one fresh `python <args>` in `cwd`, its output discarded; a failure stops the script."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, *args], cwd=cwd, env=env, stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True)
    elapsed = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"python {' '.join(args)} failed in {cwd}:\n{done.stderr[-2000:]}")
    return elapsed


def _measure(roots: dict[str, Path], runs: int) -> dict[str, dict[str, list[float]]]:
    """Wall times [s] per tree and command, the trees and commands taking turns run after run."""
    times = {tree: {key: [] for key in COMMANDS} for tree in roots}
    for root in roots.values():  # one unmeasured run each: the file cache warm for all alike
        for _label, argv in COMMANDS.values():
            wall_time_s(argv, root)
    for _ in range(runs):
        for tree, root in roots.items():
            for key, (_, argv) in COMMANDS.items():
                times[tree][key].append(wall_time_s(argv, root))
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=15, help="processes per command; the median is kept (default 15)")
    ap.add_argument("--root", type=Path, default=ROOT, help="the source tree to time (default: this checkout)")
    ap.add_argument("--before", type=Path, default=None,
                    help="an earlier source tree, timed in the same run for the ratio after / before")
    args = ap.parse_args()
    if args.runs < 1:
        raise SystemExit("--runs must be >= 1")
    roots = {"now": args.root, **({"before": args.before} if args.before is not None else {})}
    times = _measure(roots, args.runs)
    median = {tree: {key: statistics.median(v) for key, v in per.items()} for tree, per in times.items()}
    print(f"{args.runs} runs each, median (min - max) wall time; ratio to the bare interpreter")
    print(f"{'tree':<7} {'command':<32} {'median [s]':>10} {'min - max [s]':>15} {'ratio':>7}")
    for tree, per in times.items():
        base = median[tree]["python_start_s"]
        for key, (label, _) in COMMANDS.items():
            print(f"{tree:<7} {label:<32} {median[tree][key]:>10.3f} {min(per[key]):>7.3f} - {max(per[key]):<5.3f} "
                  f"{median[tree][key] / base:>7.2f}")
    now = median["now"]
    figures = {"import_cli_s": round(now["import_cli_s"], 4), "help_s": round(now["help_s"], 4),
               "python_start_s": round(now["python_start_s"], 4),
               "import_cli_ratio": round(now["import_cli_s"] / now["python_start_s"], 3),
               "help_ratio": round(now["help_s"] / now["python_start_s"], 3)}
    if "before" in median:
        before = median["before"]
        print(f"now / before: import {now['import_cli_s'] / before['import_cli_s']:.3f}, "
              f"--help {now['help_s'] / before['help_s']:.3f}")
        figures |= {"train_help_s": round(now["train_help_s"], 4), "animate_help_s": round(now["animate_help_s"], 4),
                    "import_cli_before_s": round(before["import_cli_s"], 4),
                    "help_before_s": round(before["help_s"], 4),
                    "import_cli_vs_before": round(now["import_cli_s"] / before["import_cli_s"], 3),
                    "help_vs_before": round(now["help_s"] / before["help_s"], 3)}
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
