"""Failed cells: a cell that produced no episode, and why, `RUN_DIR/failed/<episode stem>.json`.

A cell fails when its pilot or the runner raised (`FailureKind.ERROR`), when the worker process flying it
died (`CRASH`: a segfault, `os._exit`, the kernel's out-of-memory killer, a lost cluster node) or when it
gave no result within its wall-time limit (`HANG`: the worker is killed and replaced). A failed cell is
not an episode: it has no metrics row; the run goes on with the other cells and `--resume` flies it again
(a success then removes its record). `FailedCell` is written by `write_failure` and read by
`read_failure`, nowhere else; each record is written atomically.
"""
from __future__ import annotations

import errno
import json
import logging
import signal
import traceback
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from enum import Enum
from pathlib import Path
from typing import Any

from compare.flying.episode_loop import PilotError
from compare.results.trajectory import EpisodeKey
from uam_fdm.files.atomic import write_text_atomic
from uam_fdm.files.inside import inside_no_links
from uam_fdm.files.strict import strict_json_loads

log = logging.getLogger(__name__)

FAILED_DIR = "failed"
FORMAT_VERSION = 1
_DETAIL_CHARS = 20_000  # a traceback of a deep recursion would otherwise fill the record


class FailureKind(str, Enum):
    """How a cell failed."""

    ERROR = "error"  # a Python exception in the pilot or the runner
    CRASH = "crash"  # the worker process died
    HANG = "hang"  # no result within the cell's wall-time limit
    PILOT_ERROR = "pilot error"  # the pilot commanded what cannot be flown (not finite, wrong shape)
    DISK_FULL = "disk full"  # its episode file could not be saved: the disk is full (the run stops)

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True)
class FailedCell:
    """One cell that produced no episode.

    Attributes:
        key: the cell (its part of the run store would be `store/parts/<key.stem>.parquet`).
        kind: error, crash or hang.
        reason: one line: the exception's type, message and innermost frame; the worker's exit code or
            signal; or the time limit that passed.
        elapsed_s: wall time from the cell's start (error) or dispatch (crash, hang) to the failure [s].
        backend: where it flew: "local" (this process or a local worker process) or "ray".
        worker: which process: "in-process", "pid 1234", or a Ray node and pid.
        limit_s: the cell's wall-time limit [s] (None: none, in this process).
        detail: the full traceback of an error ("" otherwise).
    """

    key: EpisodeKey
    kind: FailureKind
    reason: str
    elapsed_s: float
    backend: str
    worker: str = ""
    limit_s: float | None = None
    detail: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", FailureKind(self.kind))


def error_failure(key: EpisodeKey, exc: BaseException, elapsed_s: float, backend: str, worker: str,
                  limit_s: float | None = None) -> FailedCell:
    """The failed cell of an exception raised while flying `key`: its type, message and innermost frame
    (where it was raised) as the reason, the whole traceback as the detail."""
    if isinstance(exc, PilotError):  # the message names the pilot, the time and the value
        return FailedCell(key, FailureKind.PILOT_ERROR, str(exc), elapsed_s, backend, worker, limit_s)
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return FailedCell(key, FailureKind.DISK_FULL, f"{key.stem}.parquet: {exc.strerror or exc}", elapsed_s, backend,
                          worker, limit_s)
    frames = traceback.extract_tb(exc.__traceback__)
    where = f" (at {Path(frames[-1].filename).name}:{frames[-1].lineno} in {frames[-1].name})" if frames else ""
    message = str(exc).strip().splitlines()
    reason = f"{type(exc).__name__}: {message[0] if message else ''}".rstrip(": ") + where
    detail = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    return FailedCell(key, FailureKind.ERROR, reason, elapsed_s, backend, worker, limit_s, detail[-_DETAIL_CHARS:])


def exit_reason(exitcode: int | None) -> str:
    """Why a worker process died, from its exit code (negative: the signal that killed it)."""
    if exitcode is None:
        return "the worker process died (exit code unknown)"
    if exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        oom = "; the kernel's out-of-memory killer sends it too" if -exitcode == signal.SIGKILL else ""
        return f"the worker process was killed by {name} (signal {-exitcode}{oom})"
    return f"the worker process exited with code {exitcode} while flying the cell"


def failure_path(run_dir: Path, key: EpisodeKey) -> Path:
    """Where the record of failed cell `key` is kept."""
    return Path(run_dir) / FAILED_DIR / f"{key.stem}.json"


def write_failure(run_dir: Path, failure: FailedCell) -> Path:
    """Write `failure` to `run_dir/failed/<stem>.json` atomically; returns the path."""
    data: dict[str, Any] = {"format_version": FORMAT_VERSION, **asdict(failure), "kind": failure.kind.value}
    return write_text_atomic(failure_path(run_dir, failure.key), json.dumps(data, indent=2) + "\n", root=run_dir)


def read_failure(path: Path) -> FailedCell:
    """Read a record written by `write_failure`.

    Raises:
        ValueError: not a failed-cell record (or of another format version), naming the file.
    """
    path = Path(path)
    try:
        data = strict_json_loads(path.read_text(encoding="utf-8"))
        if data.get("format_version") != FORMAT_VERSION:
            raise ValueError(f"format {data.get('format_version')!r}, expected {FORMAT_VERSION}")
        limit = data.get("limit_s")
        return FailedCell(key=EpisodeKey(**data["key"]), kind=FailureKind(data["kind"]), reason=str(data["reason"]),
                          elapsed_s=float(data["elapsed_s"]), backend=str(data["backend"]),
                          worker=str(data.get("worker", "")), limit_s=None if limit is None else float(limit),
                          detail=str(data.get("detail", "")))
    except (OSError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"{path}: not a failed-cell record ({exc})") from exc


def read_failures(run_dir: Path) -> list[FailedCell]:
    """The failed cells recorded in a run folder, by file name (an unreadable record is skipped with a warning)."""
    out = []
    for path in sorted((Path(run_dir) / FAILED_DIR).glob("[!.]*.json")):
        try:
            out.append(read_failure(path))
        except ValueError as exc:
            log.warning("skipping %s", exc)  # the message names the file
    return out


def describe_failures(failures: Sequence[FailedCell]) -> str:
    """How many cells failed, by kind and by pilot, in one phrase: "3 cells failed (error 2, hang 1; apf 3)"."""
    kinds = Counter(f.kind.value for f in failures)
    per_pilot = Counter(f.key.method for f in failures)
    by_kind = ", ".join(f"{k.value} {kinds[k.value]}" for k in FailureKind if kinds[k.value])
    by_pilot = ", ".join(f"{m} {n}" for m, n in sorted(per_pilot.items()))
    noun = "cell" if len(failures) == 1 else "cells"
    return f"{len(failures)} {noun} failed ({by_kind}; {by_pilot})"


def remove_failure(run_dir: Path, key: EpisodeKey) -> bool:
    """Remove the record of `key` (its cell has flown since); True when there was one.

    Raises:
        LinkInFolder: (a ValueError) a link on the way to it (`uam_fdm.files.inside`): nothing is removed there.
    """
    path = inside_no_links(run_dir, failure_path(run_dir, key))
    existed = path.exists()
    path.unlink(missing_ok=True)
    return existed
