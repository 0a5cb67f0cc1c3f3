"""`report`: rescore a run folder's saved episodes and rebuild its report and viewer, no simulation; or, with
`--summary`, rescore them and write the summary report (a few pages) beside the full one."""
from __future__ import annotations

import argparse
from pathlib import Path

from compare.cli.printout import print_run_results
from compare.run.campaign import finalize
from uam_fdm.files.lock import folder_lock


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add `report` to the command line."""
    rep = sub.add_parser("report",
                         help="rescore a run folder's saved episodes, rebuild its report and viewer (no simulation)")
    rep.add_argument("run_dir", type=Path, help="a folder written by `uam-compare run`")
    rep.add_argument("--summary", action="store_true",
                     help="write RUN_DIR/report-summary.pdf, a report of a few pages (the headline, the run, per "
                          "vehicle the pilots' table and paired differences, the failures), instead of rebuilding "
                          "report.pdf and viewer.html")
    rep.set_defaults(func=report)


def report(args: argparse.Namespace) -> int:
    """`report`: the run's results rebuilt from its episodes, printed as `run` prints them."""
    if not args.summary:
        print_run_results(finalize(args.run_dir))
        return 0
    run_dir = finalize(args.run_dir, report=False)  # rescored: the summary states today's numbers
    from compare.report.report import build_report  # matplotlib only when a report is drawn

    with folder_lock(run_dir, "uam-compare report"):  # as finalize: no run writes the folder meanwhile
        build_report(run_dir, summary=True, warn_unreadable=False)  # finalize named any unreadable file
    print_run_results(run_dir)
    return 0
