"""How long the command line takes to start: `import compare.cli`, `uam-compare --help` and `--version` (as
`python -m compare ...`) and two commands' help, against two baselines measured in the same run: the bare
interpreter's start (`python -c pass`) and the import of the stack the commands fly with (PyTorch,
Stable-Baselines3, CasADi, matplotlib, OMPL), each the median of `--runs` fresh processes.

`uam-compare --help` and `--version` import no command module (`compare.cli.entry.COMMANDS` names them and their
help), and a command imports only its own, so the heavy stack is imported only by the commands that fly or draw
(tests/compare/cli/test_entry.py); this script keeps that measured. The commands take turns, run after run, so
that a slower moment of this shared machine weighs on each alike. `--root` times another source tree (e.g. an
earlier commit unpacked with `git archive HEAD~1 compare uam_fdm planners rl | tar -x -C /tmp/before`): its folder
is the processes' working folder, which `python -c` and `python -m` put first on the import path.

    OMP_NUM_THREADS=1 python perf/cli_startup.py [--runs 15] [--root DIR] [--before /tmp/before]

Prints a table and, as its last line, one JSON object: `python_start_s`, `import_heavy_s`, `import_cli_s`,
`help_s`, `version_s`, `train_help_s`, `animate_help_s` (medians [s]), `import_cli_ratio`, `help_ratio` (each over
`python_start_s`) and `help_vs_heavy` (`help_s` over `import_heavy_s`); with `--before`, also
`import_cli_before_s`, `help_before_s` and the ratios now / before, `import_cli_vs_before` and `help_vs_before`.
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
HEAVY_STACK = "import torch, stable_baselines3, casadi, matplotlib.pyplot, ompl.base"
COMMANDS = {  # JSON key -> (what the table calls it, the interpreter's arguments)
    "python_start_s": ("python -c pass", ["-c", "pass"]),
    "import_heavy_s": ("python -c <import the heavy stack>", ["-c", HEAVY_STACK]),
    "import_cli_s": ('python -c "import compare.cli"', ["-c", "import compare.cli"]),
    "help_s": ("python -m compare --help", ["-m", "compare", "--help"]),
    "version_s": ("python -m compare --version", ["-m", "compare", "--version"]),
    "train_help_s": ("python -m compare train --help", ["-m", "compare", "train", "--help"]),
    "animate_help_s": ("python -m compare animate --help", ["-m", "compare", "animate", "--help"]),
}
NOW_ONLY = ("import_heavy_s", "version_s")
"""Measured in this checkout only: the baseline is the same for both trees, and an earlier tree has no --version."""


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


def _commands(tree: str) -> dict[str, tuple[str, list[str]]]:
    """The commands timed in `tree` ("now" or "before")."""
    return {k: v for k, v in COMMANDS.items() if tree == "now" or k not in NOW_ONLY}


def _measure(roots: dict[str, Path], runs: int) -> dict[str, dict[str, list[float]]]:
    """Wall times [s] per tree and command, the trees and commands taking turns run after run."""
    times: dict[str, dict[str, list[float]]] = {tree: {key: [] for key in _commands(tree)} for tree in roots}
    for tree, root in roots.items():  # one unmeasured run each: the file cache warm for all alike
        for _label, argv in _commands(tree).values():
            wall_time_s(argv, root)
    for _ in range(runs):
        for tree, root in roots.items():
            for key, (_, argv) in _commands(tree).items():
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
    print(f"{args.runs} runs each, median (min - max) wall time; ratio to the bare interpreter's start and to the "
          f"heavy stack's import ({HEAVY_STACK.removeprefix('import ')})")
    print(f"{'tree':<7} {'command':<36} {'median [s]':>10} {'min - max [s]':>15} {'/ start':>8} {'/ heavy':>8}")
    now = median["now"]
    for tree, per in times.items():
        base = median[tree]["python_start_s"]
        for key, (label, _) in _commands(tree).items():
            print(f"{tree:<7} {label:<36} {median[tree][key]:>10.3f} {min(per[key]):>7.3f} - {max(per[key]):<5.3f} "
                  f"{median[tree][key] / base:>8.2f} {median[tree][key] / now['import_heavy_s']:>8.3f}")
    figures = {"help_s": round(now["help_s"], 4), "version_s": round(now["version_s"], 4),
               "import_cli_s": round(now["import_cli_s"], 4), "train_help_s": round(now["train_help_s"], 4),
               "animate_help_s": round(now["animate_help_s"], 4), "python_start_s": round(now["python_start_s"], 4),
               "import_heavy_s": round(now["import_heavy_s"], 4),
               "import_cli_ratio": round(now["import_cli_s"] / now["python_start_s"], 3),
               "help_ratio": round(now["help_s"] / now["python_start_s"], 3),
               "help_vs_heavy": round(now["help_s"] / now["import_heavy_s"], 3)}
    if "before" in median:
        before = median["before"]
        print(f"now / before: import {now['import_cli_s'] / before['import_cli_s']:.3f}, "
              f"--help {now['help_s'] / before['help_s']:.3f}")
        figures |= {"import_cli_before_s": round(before["import_cli_s"], 4),
                    "help_before_s": round(before["help_s"], 4),
                    "import_cli_vs_before": round(now["import_cli_s"] / before["import_cli_s"], 3),
                    "help_vs_before": round(now["help_s"] / before["help_s"], 3)}
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
