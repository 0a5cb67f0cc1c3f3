"""A run folder's own folders and files, checked for links before a command reads or writes them.

Nothing in a run folder is a link when this tool wrote it. One planted there (`RUN/store -> OTHER/store`,
`RUN/maps -> ~/notes`) would lead a writer out of the folder (files created in a user's folder, another run's
store compacted without that run's lock) or a reader into another run: every command that reads or writes a
run folder refuses it first, naming the link, before any work (`uam_fdm.files.inside`). Each writer checks
its own path again as it writes (a link planted while the command runs).
"""
from __future__ import annotations

from pathlib import Path

from compare.results.failures import FAILED_DIR
from compare.results.run_info import PRIOR_MAPS, RUN_INFO_NAME
from compare.results.store import EPISODE_TABLE, PARTS_DIR, STORE_DIR
from uam_fdm.files.inside import inside_no_links

RUN_PATHS = (RUN_INFO_NAME, f"maps/{PRIOR_MAPS}", f"{STORE_DIR}/{PARTS_DIR}", f"{STORE_DIR}/{EPISODE_TABLE}",
             FAILED_DIR, "episodes", "figures", "videos", "metrics.csv", "summary.json", "report.pdf",
             "viewer.html", "flights.rrd")
"""The paths a run folder holds (each checked with the folders on its way: `maps/prior` checks `maps` too)."""


def check_run_folder_links(run_dir: Path | str) -> None:
    """Refuse a run folder in which any of `RUN_PATHS` (or a folder on its way) is a symbolic link.

    Raises:
        LinkInFolder: (a ValueError: one line, exit 2 in the CLI) naming the link.
    """
    for name in RUN_PATHS:
        inside_no_links(run_dir, Path(run_dir) / name)
