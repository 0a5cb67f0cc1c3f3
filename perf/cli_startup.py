"""How long the command line takes to start: `import compare.cli` and `uam-compare --help` (as `python -m compare
--help`) against the bare interpreter's start (`python -c pass`), each the median of `--runs` fresh processes.

The CLI imports PyTorch, Ray, matplotlib, the planners and the learned pilot only inside the commands that use
them (tests/test_architecture.py), so that printing help or refusing a bad option is quick; this script keeps
that measured. The three commands take turns, run after run, so that a slower moment of this shared machine
weighs on each alike. `--root` times another source tree (e.g. an earlier commit unpacked with
`git archive HEAD~1 compare uam_fdm planners rl | tar -x -C /tmp/before`): its folder is the processes' working
folder, which `python -c` and `python -m` put first on the import path.

    OMP_NUM_THREADS=1 python perf/cli_startup.py [--runs 15] [--root /tmp/before]

Prints a table and, as its last line, one JSON object: `python_start_s`, `import_cli_s`, `help_s` (medians [s])
and `import_cli_ratio`, `help_ratio` (each over `python_start_s`).
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=15, help="processes per command; the median is kept (default 15)")
    ap.add_argument("--root", type=Path, default=ROOT, help="the source tree to time (default: this checkout)")
    args = ap.parse_args()
    if args.runs < 1:
        raise SystemExit("--runs must be >= 1")
    times: dict[str, list[float]] = {key: [] for key in COMMANDS}
    for _label, argv in COMMANDS.values():  # one unmeasured run each: the file cache warm for all alike
        wall_time_s(argv, args.root)
    for _ in range(args.runs):
        for key, (_, argv) in COMMANDS.items():
            times[key].append(wall_time_s(argv, args.root))
    median = {key: statistics.median(values) for key, values in times.items()}
    base = median["python_start_s"]
    print(f"{args.runs} runs each in {args.root}, median (min - max) wall time; ratio to the bare interpreter")
    print(f"{'command':<32} {'median [s]':>10} {'min - max [s]':>15} {'ratio':>7}")
    for key, (label, _) in COMMANDS.items():
        print(f"{label:<32} {median[key]:>10.3f} {min(times[key]):>7.3f} - {max(times[key]):<5.3f} "
              f"{median[key] / base:>7.2f}")
    print(json.dumps({"import_cli_s": round(median["import_cli_s"], 4), "help_s": round(median["help_s"], 4),
                      "python_start_s": round(base, 4),
                      "import_cli_ratio": round(median["import_cli_s"] / base, 3),
                      "help_ratio": round(median["help_s"] / base, 3)}))


if __name__ == "__main__":
    main()
