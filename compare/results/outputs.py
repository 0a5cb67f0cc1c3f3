"""Checks of where the command line is asked to write, made before any work starts.

A run or a render that fails at its first write after minutes of work, with a traceback, is the
failure these prevent: a folder that is a file, a path under a file, a folder the user cannot
write to. Each raises ValueError naming the option and the path (the CLI prints it, exit code 2).
"""
from __future__ import annotations

import os
from pathlib import Path


def check_output_dir(path: Path, option: str) -> None:
    """Raise ValueError unless `path` is a folder that exists or can be made, and can be written.

    Args:
        path: the folder to write into.
        option: how the command line names it (e.g. "--out"), for the message.
    """
    path = Path(path)
    _check_not_a_dead_link(path, option)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{option} {path}: is a file, not a folder")
    _check_writable_ancestor(path, option)


def check_output_file(path: Path, option: str) -> None:
    """Raise ValueError unless `path` can be written as a file (its folder exists or can be made).

    Args:
        path: the file to write.
        option: how the command line names it (e.g. "--out"), for the message.
    """
    path = Path(path)
    _check_not_a_dead_link(path, option)
    if path.is_dir():
        raise ValueError(f"{option} {path}: is a folder; give a file name")
    _check_writable_ancestor(path.parent, option, shown=path)


def check_not_replacing(path: Path | None, option: str, overwrite: bool) -> None:
    """Raise ValueError when the file `path` given with `option` exists and `overwrite` is not set: a file the
    user named is never replaced without being asked (None: the command's default file, its own to replace)."""
    if path is not None and not overwrite and Path(path).is_file():
        raise ValueError(f"{option} {path}: the file exists; give another name, or --overwrite to replace it")


def _check_not_a_dead_link(path: Path, option: str) -> None:
    """A link that leads nowhere (a loop, or a target that is gone) is neither a folder nor a place to make one."""
    if path.is_symlink() and not path.exists():
        raise ValueError(f"{option} {path}: is a link that leads nowhere (a loop of links, or a missing target)")


def _check_writable_ancestor(folder: Path, option: str, shown: Path | None = None) -> None:
    """The nearest existing folder on the way to `folder` must be a folder we may write into."""
    shown = folder if shown is None else shown
    existing = folder.absolute()
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"{option} {shown}: {existing} is a file, so nothing can be written under it")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"{option} {shown}: cannot write in {existing} (permission denied)")
