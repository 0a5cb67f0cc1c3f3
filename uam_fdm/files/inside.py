"""Paths inside a folder this tool owns (a run folder, a policy folder) that never pass through a link.

The folder itself may be reached through links: the user chose it. Below it nothing is followed: a link
planted there (`RUN/maps -> ~/notes`, `RUN/store -> OTHER/store`) would lead a writer out of the folder, to
create or replace files the user never named, or lead a reader to another run's files (read, and compacted,
without that run's lock). So every writer checks the path it writes, and creates the folders on its way,
through here; readers check the folders they list before they list them.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path


class LinkInFolder(ValueError):
    """A link (or a file where a folder belongs) on the way to a path inside a folder this tool owns (a
    ValueError: the CLI prints it as one line, exit 2)."""


def inside_no_links(root: Path | str, path: Path | str) -> Path:
    """`path`, checked to lie inside `root` with no symbolic link between them (`path` itself included).

    Args:
        root: the folder this tool owns (a run or policy folder); whatever leads to it is not checked.
        path: a file or folder under `root`, built from it (`root / "maps" / name`); the parts that do not
            exist yet are not checked (`make_folders` creates them without following a link).

    Returns:
        `path`, as a Path.

    Raises:
        LinkInFolder: `path` is not under `root` (or climbs out with ".."), or a part of it below `root` is a
            link, naming that part.
    """
    root, path = Path(root), Path(path)
    try:
        rel = path.relative_to(root)
    except ValueError:
        raise LinkInFolder(f"{path}: not inside {root}") from None
    if ".." in rel.parts:
        raise LinkInFolder(f"{path}: climbs out of {root} ('..')")
    here = root
    for part in rel.parts:
        here = here / part
        try:
            mode = os.lstat(here).st_mode
        except (FileNotFoundError, NotADirectoryError):
            break  # nothing further exists: no link to follow
        if stat.S_ISLNK(mode):
            raise LinkInFolder(f"{here}: a symbolic link inside {root}; this tool never follows one there (remove "
                               f"it, or give a folder without links)")
    return path


def make_folders(root: Path | str, folder: Path | str) -> Path:
    """Create `folder` and the folders between `root` and it (as `mkdir -p`, `root` included), never following a
    link below `root`: each is made with `os.mkdir` and then looked at itself (`lstat`), not through a link.

    Returns:
        `folder`, as a Path.

    Raises:
        LinkInFolder: a part below `root` is a link or a file, naming it (`inside_no_links`).
    """
    root, folder = Path(root), Path(folder)
    rel = inside_no_links(root, folder).relative_to(root)
    root.mkdir(parents=True, exist_ok=True)
    here = root
    for part in rel.parts:
        here = here / part
        try:
            os.mkdir(here)
        except FileExistsError:
            pass
        mode = os.lstat(here).st_mode
        if stat.S_ISLNK(mode):  # put there between the check and the mkdir
            raise LinkInFolder(f"{here}: a symbolic link inside {root}; this tool never follows one there (remove "
                               f"it, or give a folder without links)")
        if not stat.S_ISDIR(mode):
            raise LinkInFolder(f"{here}: not a folder, where this tool keeps one")
    return folder
