"""The episodes of a run folder, whatever wrote them: the store (`compare.results.store`) or, in a folder
saved before it, one `.npz` per episode (`compare.results.trajectory`).

`open_episodes(run_dir)` lists them (reading only the episode table and the parts' footers) in cell order;
`RunEpisodes.load(entry)` reads one episode (the row groups holding it, never the run), `RunEpisodes.metrics`
gives its metrics.csv row: the one the cell computed from the physics-rate flight for a stored episode, or
computed from the file for an `.npz` (which holds the physics-rate flight). Where one cell is held twice, a part
wins over the episode table (a compaction cut short) and both over an `.npz`.
"""
from __future__ import annotations

import logging
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from compare.results.metrics import EpisodeMetrics, episode_metrics
from compare.results.store import (
    Unreadable,
    check_inflated,
    key_of,
    open_samples,
    part_files,
    part_row,
    read_episode_table,
    read_part,
    samples_path,
    store_dir,
)
from compare.results.tables import episode_from_tables, meta_from_row, metrics_from_row
from compare.results.trajectory import EpisodeKey, SavedEpisode, episode_files, load_episode

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EpisodeEntry:
    """Where one episode of a run is.

    Attributes:
        key: its cell.
        path: the file holding it: a part, a samples file of the store, or an `.npz`.
        row: its episode-table row (None for an `.npz`, whose metadata is inside the file).
        part: `path` is a part (a cell not compacted yet), not a samples file.
    """

    key: EpisodeKey
    path: Path
    row: Mapping[str, Any] | None = None
    part: bool = False

    @property
    def name(self) -> str:
        """The file's name as messages and the report's failures page give it."""
        return self.path.name if self.row is None or self.part else (
            f"{self.path.name} ({self.key.stem})")


class _RowGroupCache:
    """The samples files opened so far and the row groups read last: episodes read in cell order decode each
    row group once."""

    def __init__(self, size: int = 2) -> None:
        self.files: dict[Path, pq.ParquetFile] = {}
        self.groups: OrderedDict[tuple[Path, int], pa.Table] = OrderedDict()
        self.size = size

    def rows(self, path: Path, start: int, count: int) -> pa.Table:
        if path not in self.files:
            self.files[path] = open_samples(path)
        f = self.files[path]
        pieces, first = [], 0
        for g in range(f.metadata.num_row_groups):
            n = f.metadata.row_group(g).num_rows
            lo, hi = max(start, first), min(start + count, first + n)
            if lo < hi:
                pieces.append(self._group(path, f, g).slice(lo - first, hi - lo))
            first += n
        got = sum(p.num_rows for p in pieces)
        if got != count:
            raise ValueError(f"{path}: holds {got} of the {count} samples rows {start}.. its episode table names")
        return pa.concat_tables(pieces) if len(pieces) != 1 else pieces[0]

    def _group(self, path: Path, f: pq.ParquetFile, g: int) -> pa.Table:
        if (path, g) not in self.groups:
            check_inflated(path, [f.metadata.row_group(g)])
            try:
                self.groups[(path, g)] = f.read_row_group(g)
            except (OSError, ValueError, pa.ArrowException) as exc:
                raise ValueError(f"{path}: row group {g} is corrupt ({' '.join(str(exc).split())[:200]})") from exc
            while len(self.groups) > self.size:
                self.groups.popitem(last=False)
        return self.groups[(path, g)]


@dataclass(frozen=True)
class RunEpisodes:
    """A run folder's episodes (see the module docstring).

    Attributes:
        run_dir: the run folder.
        entries: one per cell held, in cell order (scenario, episode, pilot, seed).
        unreadable: files found that do not read (each also logged by whoever acts on it).
    """

    run_dir: Path
    entries: tuple[EpisodeEntry, ...]
    unreadable: tuple[Unreadable, ...] = ()
    _cache: _RowGroupCache = field(default_factory=_RowGroupCache, repr=False, compare=False)
    _recent: OrderedDict[EpisodeKey, SavedEpisode] = field(default_factory=OrderedDict, repr=False, compare=False)

    def load_recent(self, entry: EpisodeEntry, keep: int = 8) -> SavedEpisode:
        """`load`, keeping the last `keep` episodes read (a cell's pilots are asked for again and again while it
        is drawn; a run's episodes are never all held).

        Raises:
            ValueError: it does not read, naming the file.
        """
        if entry.key in self._recent:
            self._recent.move_to_end(entry.key)
            return self._recent[entry.key]
        saved = self.load(entry)
        self._recent[entry.key] = saved
        while len(self._recent) > keep:
            self._recent.popitem(last=False)
        return saved

    def load(self, entry: EpisodeEntry) -> SavedEpisode:
        """Read one episode (its samples as stored: thinned to the control rate unless the run kept all).

        Raises:
            ValueError: it does not read, naming the file.
        """
        if entry.row is None:
            return load_episode(entry.path)
        try:
            meta = meta_from_row(entry.row)
            if entry.part:
                _, samples = read_part(entry.path)
            else:
                samples = self._cache.rows(entry.path, int(entry.row["row_start"]), int(entry.row["samples"]))
            return episode_from_tables(meta, samples)
        except ValueError as exc:
            text = str(exc)
            raise ValueError(text if text.startswith(str(entry.path)) else f"{entry.path}: {entry.key.stem}: {text}"
                             ) from exc

    def metrics(self, entry: EpisodeEntry) -> EpisodeMetrics:
        """The episode's metrics.csv row.

        Raises:
            ValueError: an `.npz` that does not read or score, naming it.
        """
        if entry.row is not None:
            return metrics_from_row(entry.row)
        return episode_metrics(load_episode(entry.path))


def open_episodes(run_dir: Path) -> RunEpisodes:
    """List a run folder's episodes (see the module docstring); nothing but the episode table and the parts'
    footers is read.

    An unreadable part or `.npz` is listed in `unreadable`; an unreadable episode table too (its episodes are
    then missing).
    """
    run_dir = Path(run_dir)
    found: dict[EpisodeKey, EpisodeEntry] = {}
    bad: list[Unreadable] = []
    for f in episode_files(run_dir):  # a folder saved before the store: one .npz per episode
        key = EpisodeKey.from_stem(f.stem)
        if key is None:  # not named by EpisodeKey.stem: ask the file
            try:
                key = load_episode(f).meta.key
            except ValueError as exc:
                bad.append(Unreadable(f, str(exc)))
                continue
        found[key] = EpisodeEntry(key, f)
    try:
        rows = read_episode_table(run_dir)
    except ValueError as exc:
        bad.append(Unreadable(store_dir(run_dir) / "episodes.parquet", str(exc)))
        rows = []
    table = store_dir(run_dir) / "episodes.parquet"
    for i, row in enumerate(rows):
        try:
            key, samples = key_of(row), samples_path(run_dir, row)
        except (ValueError, TypeError) as exc:  # a row names a cell or a file this tool never writes: skipped
            bad.append(Unreadable(table, f"row {i}: {exc}"))
            continue
        found[key] = EpisodeEntry(key, samples, row)
    for p in part_files(run_dir):
        try:
            row = part_row(p)
            key = key_of(row)
        except (ValueError, TypeError) as exc:
            bad.append(Unreadable(p, str(exc)))
            continue
        found[key] = EpisodeEntry(key, p, row, part=True)
    order = sorted(found, key=lambda k: (k.scenario, k.episode, k.method, k.seed))
    return RunEpisodes(run_dir, tuple(found[k] for k in order), tuple(bad))


def kept_keys(run_dir: Path) -> set[EpisodeKey]:
    """The cells whose episode `run --resume` keeps: each part reads whole, each samples file of the episode
    table opens and holds the rows named, each `.npz` reads; any other is flown again (logged, naming it)."""
    episodes = open_episodes(run_dir)
    for b in episodes.unreadable:
        log.warning("flying again: %s", b.reason)
    kept: set[EpisodeKey] = set()
    opened: dict[Path, pq.ParquetFile | None] = {}
    for e in episodes.entries:
        try:
            if e.row is None:
                load_episode(e.path)
            elif e.part:
                read_part(e.path)
            else:
                if e.path not in opened:
                    try:
                        opened[e.path] = open_samples(e.path)
                    except ValueError:
                        opened[e.path] = None
                        raise
                f = opened[e.path]
                if f is None or f.metadata.num_rows < int(e.row["row_start"]) + int(e.row["samples"]):
                    raise ValueError(f"{e.path}: does not hold the samples of {e.key.stem}")
        except ValueError as exc:
            log.warning("flying again: %s", exc)
            continue
        kept.add(e.key)
    return kept
