"""A folder held by one writing command at a time: `run` flying into a run folder, `report` rescoring it.

The lock is an advisory `flock` on a hidden file in the folder (`LOCK_NAME`), so it ends with the
process however that ends (a killed run leaves no stale lock behind), and a second command that
finds the folder held stops at once with an error naming the holder, before it writes anything.
"""
from __future__ import annotations

import errno
import fcntl
import json
import os
import stat
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from uam_fdm.files.strict import strict_json_loads

LOCK_NAME = ".uam-compare.lock"  # hidden: the readers and the non-empty-folder checks pass it by


class FolderBusy(ValueError):
    """Another process is writing the folder (a ValueError: the CLI prints it as one line, exit 2)."""


@contextmanager
def folder_lock(folder: Path | str, command: str) -> Iterator[Path]:
    """Hold `folder`'s lock while the block runs (the folder is created if missing); yields the lock file.

    Args:
        folder: the folder a command is about to write.
        command: what holds it (shown to a second command that finds it held), e.g. "uam-compare run".

    Raises:
        FolderBusy: another live process holds the lock.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK_NAME
    while True:
        fd = _open_lock_file(path)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise FolderBusy(f"{folder}: another uam-compare process is writing this folder ({holder}); wait "
                             "for it to finish") from None
        # the holder before us may have removed the file between our open and our lock: lock the file that is there
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, json.dumps({"pid": os.getpid(), "command": command[:200],
                                 "since": time.strftime("%Y-%m-%d %H:%M:%S")}).encode())
        yield path
    finally:
        path.unlink(missing_ok=True)  # before the unlock: a waiter then finds the file gone and opens a new one
        os.close(fd)


def _open_lock_file(path: Path) -> int:
    """Open (or create) the lock file itself: never a link planted in its place (whose target would be
    overwritten), never a FIFO or device (which could block or be written).

    Raises:
        ValueError: something other than a regular file stands at `path` (a ValueError: the CLI prints it as one
            line, exit 2); it is left as it is.
    """
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, 0o644)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise ValueError(f"{path}: a symbolic link stands where this tool keeps its lock; it is not followed "
                             "(remove it to use the folder)") from None
        raise
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise ValueError(f"{path}: not a regular file where this tool keeps its lock (remove it to use the folder)")
    return fd


def _holder(fd: int) -> str:
    """Who holds the lock, from what it wrote in the file (a short phrase; the file's text is never trusted)."""
    try:
        info = strict_json_loads(os.pread(fd, 1024, 0).decode("utf-8"))
        return f"pid {int(info['pid'])}, {str(info['command'])[:80]!r} since {str(info['since'])[:19]}"
    except (ValueError, KeyError, TypeError, UnicodeDecodeError):
        return "a process that has just started"
