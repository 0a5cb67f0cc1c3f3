"""`report`: rescore a run folder's saved episodes and rebuild its report and viewer, no simulation."""
from __future__ import annotations

import argparse
from pathlib import Path

from compare.cli.printout import print_run_results
from compare.run.campaign import finalize


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add `report` to the command line."""
    rep = sub.add_parser("report",
                         help="rescore a run folder's saved episodes, rebuild its report and viewer (no simulation)")
    rep.add_argument("run_dir", type=Path, help="a folder written by `uam-compare run`")
    rep.set_defaults(func=report)


def report(args: argparse.Namespace) -> int:
    """`report`: the run's results rebuilt from its episodes, printed as `run` prints them."""
    print_run_results(finalize(args.run_dir))
    return 0
