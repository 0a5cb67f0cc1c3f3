"""Atomic file output: write beside the target under a temporary name, then rename.

Every output the project writes goes through here, so an interrupted run never leaves a
half-written file: a file either exists complete (the previous version or the new one) or not at
all. The temporary file is hidden (leading dot, `TEMP_MARK` in its name) and removed if the writer fails
(a full disk included: the error then names the output that could not be written). A process killed
mid-write cannot remove its own: `remove_stale_temporaries` does, on the next run or report.
"""
from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from uam_fdm.files.inside import inside_no_links, make_folders

TEMP_MARK = ".partial-"  # in every temporary name (".<final name>.partial-<random><suffix>"), and only there


@contextmanager
def atomic_path(path: Path | str, suffix: str = ".tmp", *, root: Path | str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside `path` for a writer that takes a file name; rename on success.

    Args:
        path: the final file.
        suffix: the temporary name's ending (some writers choose the format from it, e.g. ".pdf").
        root: the folder this tool owns that `path` lies in (a run or policy folder; None: a file the user
            named): no link between it and `path` is followed (`uam_fdm.files.inside`), and the folders on the
            way are made without following one.

    Raises:
        LinkInFolder: (a ValueError) a link below `root` on the way to `path`, or `path` itself a link.
    """
    path = Path(path)
    if root is None:
        path.parent.mkdir(parents=True, exist_ok=True)
    else:
        make_folders(root, path.parent)
        inside_no_links(root, path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}{TEMP_MARK}", suffix=suffix, dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        # mkstemp makes the file private (0600); an output gets the permissions `open` would give it
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        if exc.filename is None:  # a failed write (disk full) names no file: name the output it was for
            raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from exc
        raise
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0o022)  # reading the umask means setting it; put it straight back
    os.umask(mask)
    return mask


@contextmanager
def atomic_open(path: Path | str, mode: str = "w", *, root: Path | str | None = None, **kwargs: Any) -> Iterator[IO]:
    """Open a temporary file beside `path` (`open` arguments); renamed to `path` when the block ends cleanly
    (`root`: as `atomic_path`'s)."""
    with atomic_path(path, root=root) as tmp, open(tmp, mode, **kwargs) as f:
        yield f


def write_text_atomic(path: Path | str, text: str, *, root: Path | str | None = None) -> Path:
    """Write `text` (UTF-8, newlines as given) to `path` atomically (`root`: as `atomic_path`'s); returns the
    path."""
    with atomic_open(path, "w", root=root, encoding="utf-8", newline="") as f:
        f.write(text)
    return Path(path)


def remove_stale_temporaries(folder: Path | str) -> list[Path]:
    """Remove the temporary files that interrupted writes left anywhere under `folder`; returns them.

    Call it only where no other writer is at work in `folder` (a run before it flies, a report before
    it scores): a temporary there can only be the remains of a killed process. Links are never followed: a link
    planted in the folder (to a user's home, say) leads the sweep nowhere, and a link named like a temporary is
    not one of ours.
    """
    stale = []
    for here, _dirs, files in os.walk(folder, followlinks=False):
        for name in files:
            p = Path(here) / name
            if name.startswith(".") and TEMP_MARK in name and not p.is_symlink() and p.is_file():
                stale.append(p)
    stale.sort()
    for p in stale:
        p.unlink(missing_ok=True)
    return stale
