"""A run's episodes in one columnar store (Apache Parquet): the files, their writer and their checks.

```
RUN_DIR/store/episodes.parquet                 the episode table, one row per episode (`tables.EPISODE_SCHEMA`)
RUN_DIR/store/samples-GGGG-KKK.parquet         the samples of many episodes, in cell order (`tables.SAMPLE_SCHEMA`)
RUN_DIR/store/parts/<cell>.parquet             one per cell flown since the store was last compacted
RUN_DIR/store/schema.json, SCHEMA.md           every table's columns: type, unit, frame, meaning (`store_schema`)
```

A cell writes its part as it ends (atomically: a part exists whole or not at all), so an interrupted run
loses only the cells in flight; a part holds the cell's samples, and its episode-table row as JSON in the
file's key-value metadata. `compact` (at the end of a run, and by `report`) appends the parts' samples to a
new samples file (generation GGGG, split into files KKK of at most `ROWS_PER_FILE` rows), rewrites the episode
table to point at them, and only then removes the parts: a crash at any point leaves either the parts or
their compacted copy readable (a part wins over the table's row for the same cell). Earlier samples files are
never rewritten; one that no row points at any more is removed. A part that does not read (truncated,
corrupt) is left where it is, named, and flown again by `run --resume`.

Every file is written with the same pinned settings (`WRITE_OPTIONS`: zstd at a fixed level, byte-stream-split
floats, dictionary-encoded names, fixed row-group and page sizes), so the same episodes give the same bytes.
pandas, polars or DuckDB read the two tables directly, `compare.results.run_tables.load_run` reads a run's tables
whole (docs/comparison.md, "The run store").
"""
from __future__ import annotations

import io
import json
import logging
import os
import re
import stat
import weakref
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from compare.results.store_schema import write_schema
from compare.results.tables import (
    EPISODE_SCHEMA,
    EPISODE_SCHEMA_BEFORE_SENSING,
    KEY_COLUMNS,
    SAMPLE_SCHEMA,
    SAMPLE_SCHEMA_BEFORE_DECISIONS,
    SAMPLE_SCHEMA_BEFORE_SENSING,
    upgraded_episodes,
    upgraded_samples,
    with_metric_defaults,
)
from compare.results.trajectory import MAX_EPISODE_BYTES, EpisodeKey
from uam_fdm.files.atomic import atomic_open, atomic_path
from uam_fdm.files.inside import inside_no_links

log = logging.getLogger(__name__)

STORE_DIR = "store"
PARTS_DIR = "parts"
EPISODE_TABLE = "episodes.parquet"
ROW_META_KEY = b"uam_compare.episode"
"""Key of a part's episode-table row (JSON) in its Parquet key-value metadata."""
ROW_GROUP_ROWS = 32_768
"""Samples per row group: large enough to compress well, small enough that one episode is read alone."""
ROWS_PER_FILE = 2_000_000
"""Samples per samples file (~100 MB at the control rate): many episodes per file, no file too large to copy."""
ZSTD_LEVEL = 6
_SAMPLES = re.compile(r"^samples-(?P<gen>\d{4})-(?P<k>\d{3})\.parquet$")


def _float_columns(schema: pa.Schema) -> list[str]:
    """Leaf paths of the float columns (byte-stream-split: their exponent bytes then compress apart)."""
    out = []
    for f in schema:
        if pa.types.is_floating(f.type):
            out.append(f.name)
        elif pa.types.is_list(f.type) and pa.types.is_floating(f.type.value_type):
            out.append(f"{f.name}.list.element")
    return out


def write_options(schema: pa.Schema) -> dict[str, Any]:
    """The pinned Parquet writer settings for a table of `schema` (the same bytes for the same table)."""
    return {"version": "2.6", "compression": "zstd", "compression_level": ZSTD_LEVEL,
            "use_dictionary": [f.name for f in schema if pa.types.is_string(f.type)],
            "use_byte_stream_split": _float_columns(schema),
            # min/max of every column but the metadata JSON (whose min and max would be two whole documents)
            "write_statistics": [f.name for f in schema if f.name != "meta_json"], "data_page_size": 1 << 20,
            "data_page_version": "1.0", "write_batch_size": 1024, "store_schema": True, "write_page_index": False}


WRITE_OPTIONS = write_options(SAMPLE_SCHEMA)


def store_dir(run_dir: Path) -> Path:
    """The run's store folder."""
    return Path(run_dir) / STORE_DIR


def part_path(run_dir: Path, key: EpisodeKey) -> Path:
    """Where cell `key`'s part is written."""
    return store_dir(run_dir) / PARTS_DIR / f"{key.stem}.parquet"


def part_files(run_dir: Path) -> list[Path]:
    """The run's parts, sorted by name (hidden temporaries and anything not a regular file left out)."""
    folder = store_dir(run_dir) / PARTS_DIR
    return sorted(p for p in folder.glob("*.parquet") if not p.name.startswith(".") and p.is_file())


def part_bytes(row: Mapping[str, Any], samples: pa.Table) -> bytes:
    """The content of a cell's part: its samples, with its episode-table row as JSON in the file's metadata."""
    text = json.dumps(dict(row), sort_keys=True, allow_nan=True)
    table = samples.replace_schema_metadata({ROW_META_KEY: text.encode("utf-8")})
    buffer = io.BytesIO()
    pq.write_table(table, buffer, row_group_size=ROW_GROUP_ROWS, **WRITE_OPTIONS)
    return buffer.getvalue()


def write_part(path: Path, data: bytes, *, root: Path | None = None) -> Path:
    """Write a part's content (`part_bytes`) to `path` atomically; returns the path.

    Args:
        root: the run folder `path` lies in: no link on the way is followed (`uam_fdm.files.atomic.atomic_path`).
    """
    with atomic_open(path, "wb", root=root) as f:
        f.write(data)
    return Path(path)


@dataclass(frozen=True)
class Unreadable:
    """A file of the run's episodes that does not read (or rows of it that are not read): its path and why (the
    reason names the file); `planned` False: cells run.json does not plan, which `run --resume` does not fly."""

    path: Path
    reason: str
    planned: bool = True


def part_row(path: Path) -> dict[str, Any]:
    """A part's episode-table row, from the file's footer alone (its samples are not read).

    Raises:
        ValueError: not a part (not Parquet, truncated, no row), naming the file.
    """
    with open_regular(path) as source:
        try:
            meta = pq.read_schema(source).metadata or {}
            row = json.loads(meta[ROW_META_KEY])
        except (KeyError, OSError, ValueError, pa.ArrowException) as exc:
            raise ValueError(f"{path}: not a stored episode, or truncated or corrupt ({_why(exc)})") from exc
    return _checked_row(row, path)


def read_part(path: Path) -> tuple[dict[str, Any], pa.Table]:
    """A part's episode-table row and samples, checked (schema, row count, cell).

    Raises:
        ValueError: truncated, corrupt or not a part, naming the file.
    """
    row = part_row(path)
    with open_regular(path) as source:
        try:
            f = pq.ParquetFile(source)
            check_inflated(path, [f.metadata.row_group(g) for g in range(f.metadata.num_row_groups)])
            table = f.read()
        except (OSError, ValueError, pa.ArrowException) as exc:
            raise ValueError(f"{path}: not a stored episode, or truncated or corrupt ({_why(exc)})") from exc
    return row, _checked_samples(table.replace_schema_metadata(None), row, path)


def open_regular(path: Path) -> IO[bytes]:
    """`path` opened for reading, if it is a regular file (a FIFO named like a store's file is never opened: its
    reader would wait for a writer for ever; one put in its place after the check is opened without waiting, and
    refused).

    Raises:
        ValueError: not a regular file, or it cannot be opened, naming it.
    """
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            raise ValueError(f"{path}: not a regular file")
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise ValueError(f"{path}: cannot be read ({exc.strerror or _why(exc)})") from exc
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise ValueError(f"{path}: not a regular file")
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def check_inflated(path: Path, groups: Sequence[Any]) -> None:
    """Refuse, unread, row groups that would inflate past `MAX_EPISODE_BYTES` (a hostile file's sizes)."""
    inflated = sum(g.total_byte_size for g in groups)
    if inflated > MAX_EPISODE_BYTES:
        raise ValueError(f"{path}: its samples would take {inflated / 2**20:,.0f} MiB in memory; at most "
                         f"{MAX_EPISODE_BYTES / 2**20:,.0f} MiB")


def _why(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text[:200] or type(exc).__name__


def _checked_row(row: object, where: Path) -> dict[str, Any]:
    if isinstance(row, dict):
        row = with_metric_defaults(row)  # a part of a run from before the vehicle sensed
    if not isinstance(row, dict) or any(name not in row for name in EPISODE_SCHEMA.names):
        raise ValueError(f"{where}: not a stored episode (its episode row is incomplete)")
    try:
        key_of(row)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: not a stored episode (its cell is not readable: {exc})") from exc
    return row


def _checked_samples(table: pa.Table, row: Mapping[str, Any], where: Path) -> pa.Table:
    table = upgraded_samples(table)
    if not table.schema.equals(SAMPLE_SCHEMA):
        raise ValueError(f"{where}: not a stored episode (its columns are not the samples table's)")
    if table.num_rows != row["samples"]:
        raise ValueError(f"{where}: {table.num_rows} samples, its episode row says {row['samples']}")
    other = other_cell(table, row)
    if other:
        raise ValueError(f"{where}: its samples are of another cell than its episode row ({other})")
    return table


def other_cell(samples: pa.Table, row: Mapping[str, Any]) -> str:
    """How the samples' cell columns (scenario, episode, method, seed) disagree with an episode row's, in words
    ("seed 1, its row says 0"); "" where every sample is of the row's cell."""
    for c in KEY_COLUMNS:
        found = pc.unique(samples.column(c)).to_pylist()
        others = [v for v in found if v != row[c]]
        if others:
            return f"{c} {str(others[0])[:80]}, its row says {str(row[c])[:80]}"
    return ""


def key_of(row: Mapping[str, Any]) -> EpisodeKey:
    """The cell of an episode-table row."""
    scenario, pilot = row["scenario"], row["method"]
    if not isinstance(scenario, str) or not isinstance(pilot, str):
        raise TypeError("the columns scenario and method must be text")
    return EpisodeKey(scenario, int(row["episode"]), pilot, int(row["seed"]))


def cell_rank(row: Mapping[str, Any]) -> tuple[str, int, str, int]:
    """Cell order of an episode-table row (the order of metrics.csv and of the samples files)."""
    return (row["scenario"], int(row["episode"]), row["method"], int(row["seed"]))


def read_episode_table(run_dir: Path, max_rows: int | None = None, planned: str = "") -> list[dict[str, Any]]:
    """The compacted episode table's rows ([] when the run has none yet).

    Args:
        max_rows: a table of more rows is refused before they are read (None: any size).
        planned: what `max_rows` comes from, for the message ("run.json plans 2 episodes").

    Raises:
        ValueError: the table does not read, or holds more than `max_rows` rows, naming it.
    """
    path = store_dir(run_dir) / EPISODE_TABLE
    if not path.exists():
        return []
    with open_regular(path) as source:
        try:
            f = pq.ParquetFile(source)
            rows = f.metadata.num_rows
            table = f.read() if max_rows is None or rows <= max_rows else None
        except (OSError, ValueError, pa.ArrowException) as exc:
            raise ValueError(f"{path}: the run's episode table is truncated or corrupt ({_why(exc)})") from exc
    if table is None:
        raise ValueError(f"{path}: {rows:,} rows, far more than {planned or 'the run plans'}: refused unread "
                         f"(at most {max_rows:,} are read)")
    table = upgraded_episodes(table)  # a run from before some of the sensing columns: at their defaults
    schema = table.schema.remove_metadata()
    if schema.equals(EPISODE_SCHEMA_BEFORE_SENSING):  # a run from before the vehicle sensed
        return [with_metric_defaults(r) for r in table.to_pylist()]
    if not schema.equals(EPISODE_SCHEMA):
        raise ValueError(f"{path}: not a run's episode table (its columns differ)")
    return table.to_pylist()


def episode_table_rows(run_dir: Path) -> int:
    """How many rows the episode table holds, from its footer alone (0 when the run has none yet).

    Raises:
        ValueError: the table does not open (not Parquet, truncated), naming it.
    """
    path = store_dir(run_dir) / EPISODE_TABLE
    if not path.exists():
        return 0
    with open_regular(path) as source:
        try:
            return int(pq.ParquetFile(source).metadata.num_rows)
        except (OSError, ValueError, pa.ArrowException) as exc:
            raise ValueError(f"{path}: the run's episode table is truncated or corrupt ({_why(exc)})") from exc


def samples_path(run_dir: Path, row: Mapping[str, Any]) -> Path:
    """The samples file an episode-table row names, inside the run's store.

    Raises:
        ValueError: the row names anything but a samples file of this store (another folder, a path, a link's
            way out): what a file says never chooses where the readers look.
    """
    name = row["samples_file"]
    if not isinstance(name, str) or not _SAMPLES.match(name):
        raise ValueError(f"samples_file {str(name)[:80]!r}: not a samples file of this store "
                         f"(samples-GGGG-NNN.parquet)")
    return store_dir(run_dir) / name


def samples_files(run_dir: Path) -> list[Path]:
    """The store's samples files, by name (generation, then number)."""
    return sorted(p for p in store_dir(run_dir).glob("samples-*.parquet") if _SAMPLES.match(p.name))


def compact(run_dir: Path) -> list[Unreadable]:
    """Move the run's parts into its samples files and episode table (see the module docstring).

    Returns:
        The parts that did not read (left in place; each also logged).

    Raises:
        ValueError: the existing episode table does not read, or the store (its folder, its parts folder or its
            table) is a link (`LinkInFolder`): nothing is changed.
        OSError: a file could not be written (nothing is lost: the parts stay until their copy is complete).
    """
    folder = store_dir(run_dir)
    # before anything is read or written: a store that is a link is another run's, whose lock is not held here
    inside_no_links(run_dir, folder / PARTS_DIR)
    inside_no_links(run_dir, folder / EPISODE_TABLE)
    parts = part_files(run_dir)
    bad: list[Unreadable] = []
    rows: list[tuple[dict[str, Any], Path]] = []
    for p in parts:
        try:
            rows.append((part_row(p), p))
        except ValueError as exc:
            bad.append(Unreadable(p, str(exc)))
    if not rows:  # nothing to move in: the table's footer is checked, its rows are left to its readers
        episode_table_rows(run_dir)
    else:
        old = read_episode_table(run_dir)
        rows.sort(key=lambda rp: cell_rank(rp[0]))
        gen = 1 + max((int(m["gen"]) for f in samples_files(run_dir) if (m := _SAMPLES.match(f.name))), default=0)
        new_rows, done, failed = _write_samples(folder, gen, rows, Path(run_dir))
        bad += failed
        fresh = {key_of(r) for r in new_rows}
        table = [r for r in old if key_of(r) not in fresh] + new_rows
        table.sort(key=cell_rank)
        write_episode_table(folder / EPISODE_TABLE, table, root=Path(run_dir))
        write_schema(folder, Path(run_dir))  # what every column holds, beside the tables (store_schema)
        for p in done:
            p.unlink(missing_ok=True)
        used = {r["samples_file"] for r in table}
        for f in samples_files(run_dir):
            if f.name not in used:
                f.unlink(missing_ok=True)
    for b in bad:
        log.warning("skipping unreadable episode part %s", b.reason)  # the reason names the file
    return bad


def write_episode_table(path: Path, rows: Sequence[Mapping[str, Any]], *, root: Path | None = None) -> Path:
    """Write the episode table (rows in cell order) atomically (`root`: the run folder, as `write_part`'s); returns
    the path."""
    table = pa.Table.from_pylist(list(rows), schema=EPISODE_SCHEMA)
    with atomic_path(path, ".parquet", root=root) as tmp:
        pq.write_table(table, tmp, row_group_size=ROW_GROUP_ROWS, **write_options(EPISODE_SCHEMA))
    return path


def _write_samples(folder: Path, gen: int, rows: Iterable[tuple[dict[str, Any], Path]], root: Path
                   ) -> tuple[list[dict[str, Any]], list[Path], list[Unreadable]]:
    """Append the parts' samples, in the given order, to new samples files of generation `gen`.

    Returns the parts' rows pointing at their samples, the parts copied, and those that did not read.
    """
    new_rows: list[dict[str, Any]] = []
    done: list[Path] = []
    bad: list[Unreadable] = []
    writer = _SamplesWriter(folder, gen, root)
    try:
        for row, path in rows:
            try:
                _, samples = read_part(path)
            except ValueError as exc:
                bad.append(Unreadable(path, str(exc)))
                continue
            name, start = writer.add(samples)
            new_rows.append({**row, "samples_file": name, "row_start": start})
            done.append(path)
        writer.close()
    except BaseException:
        writer.abandon()
        raise
    return new_rows, done, bad


class _SamplesWriter:
    """Writes samples in full row groups into files of at most `ROWS_PER_FILE` rows, each renamed into place
    when complete (`atomic_path`, no link below the run folder `root` followed)."""

    def __init__(self, folder: Path, gen: int, root: Path) -> None:
        self.folder, self.gen, self.k, self.root = folder, gen, 0, root
        self._buffer: list[pa.Table] = []
        self._buffered = 0
        self._rows = 0  # rows in the current file, buffered ones included
        self._file: Any = None  # the atomic_path context of the current file
        self._writer: pq.ParquetWriter | None = None

    @property
    def name(self) -> str:
        return f"samples-{self.gen:04d}-{self.k:03d}.parquet"

    def add(self, samples: pa.Table) -> tuple[str, int]:
        """Queue one episode's samples; returns the file they go to and their first row there."""
        if self._rows and self._rows + samples.num_rows > ROWS_PER_FILE:
            self._finish_file()
        start = self._rows
        self._buffer.append(samples)
        self._buffered += samples.num_rows
        self._rows += samples.num_rows
        while self._buffered >= ROW_GROUP_ROWS:
            self._flush(ROW_GROUP_ROWS)
        return self.name, start

    def _flush(self, n: int) -> None:
        """Write the first `n` buffered rows as one row group."""
        table = pa.concat_tables(self._buffer)
        if self._writer is None:
            self._file = atomic_path(self.folder / self.name, ".parquet", root=self.root)
            tmp = self._file.__enter__()
            self._writer = pq.ParquetWriter(tmp, SAMPLE_SCHEMA, **WRITE_OPTIONS)
        self._writer.write_table(table.slice(0, n), row_group_size=n)
        rest = table.slice(n)
        self._buffer, self._buffered = ([rest] if rest.num_rows else []), rest.num_rows

    def _finish_file(self) -> None:
        if self._buffered:
            self._flush(self._buffered)
        if self._writer is not None:
            self._writer.close()
            self._writer = None
            self._file.__exit__(None, None, None)  # renamed into place
            self._file = None
        self.k += 1
        self._rows = 0

    def close(self) -> None:
        """Write what is buffered and put the last file in place."""
        self._finish_file()

    def abandon(self) -> None:
        """Drop the file being written (its temporary is removed)."""
        if self._writer is not None:
            try:
                self._writer.close()
            finally:
                self._writer = None
                exc = RuntimeError("compaction abandoned")
                self._file.__exit__(RuntimeError, exc, None)


def open_samples(path: Path) -> pq.ParquetFile:
    """A samples file (or a part) opened for reading (its footer read; closed with `close(force=True)`).

    Raises:
        ValueError: not a regular file, truncated, corrupt or not a samples file, naming it.
    """
    source = open_regular(path)
    try:
        f = pq.ParquetFile(source)
    except (OSError, ValueError, pa.ArrowException) as exc:
        source.close()
        raise ValueError(f"{path}: truncated or corrupt samples file ({_why(exc)})") from exc
    weakref.finalize(f, source.close)  # closed with the reader, as a file pyarrow opened itself would be
    schema = f.schema_arrow.remove_metadata()
    # a run from before the vehicle sensed, or before the decisions' commands were recorded: read, without them
    if not any(schema.equals(s) for s in (SAMPLE_SCHEMA, SAMPLE_SCHEMA_BEFORE_DECISIONS, SAMPLE_SCHEMA_BEFORE_SENSING)):
        source.close()
        raise ValueError(f"{path}: not a samples file (its columns differ)")
    return f
