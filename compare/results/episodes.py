"""The episodes of a run folder, whatever wrote them: the store (`compare.results.store`) or, in a folder
saved before it, one `.npz` per episode (`compare.results.trajectory`).

`open_episodes(run_dir)` lists them (reading only the episode table and the parts' footers) in cell order;
`RunEpisodes.load(entry)` reads one episode (the row groups holding it, never the run), `RunEpisodes.metrics`
gives its metrics.csv row: the one the cell computed from the physics-rate flight for a stored episode, or
computed from the file for an `.npz` (which holds the physics-rate flight). Where one cell is held twice, a part
wins over the episode table (a compaction cut short) and both over an `.npz`.

What a store says is checked before it is believed: the episode table holds the cells run.json plans and no others
(rows of other cells are skipped, named in one line; a table of far more rows than the run plans is refused
unread), no cell twice (both rows are skipped, named: which one is the flight cannot be told; `run --resume`
refuses such a store, `refuse_bad_rows`), and the samples a row points at are of its cell (else the episode is
skipped, naming the table, the row and what disagrees). An episode is read with at most `MAX_SAMPLES_READ` samples
(a longer one is thinned as it is read, a row group at a time), and one with no finite position, or positions
beyond `FLIGHT_REACH_M` of its start, is refused by name: the pages draw it with the rest left out, not instead of
the rest.
"""
from __future__ import annotations

import logging
from collections import OrderedDict
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from compare.results.metrics import EpisodeMetrics, episode_metrics
from compare.results.run_folder import check_run_folder_links
from compare.results.run_info import read_run_info
from compare.results.store import (
    EPISODE_TABLE,
    PARTS_DIR,
    ROW_GROUP_ROWS,
    Unreadable,
    check_inflated,
    key_of,
    open_samples,
    other_cell,
    part_files,
    part_row,
    read_episode_table,
    read_part,
    samples_path,
    store_dir,
)
from compare.results.tables import POSITION, episode_from_tables, meta_from_row, metrics_from_row
from compare.results.trajectory import EpisodeKey, SavedEpisode, episode_files, load_episode

log = logging.getLogger(__name__)

MAX_SAMPLES_READ = 100_000
"""Samples read per flight at most. The pages draw far fewer (the viewer 1,200 per cell, the report 2,000 per
plot); a longer flight (over 33 min at the control rate, over 200 s of `--store full`) is thinned as it is read,
one row group at a time: every k-th sample, plus each row group's sample of least clearance and its last with a
finite position, plus the last. So a store whose rows claim millions of samples costs memory for one row group
and the thinned flight, never for its columns whole."""

FLIGHT_REACH_M = 100_000.0
"""Farthest a stored position lies from its episode's start [m]: a flight ends as it leaves its volume, and the
pages size their maps by the flights (a position at 1e300 m would ask for an index of 1e600 cells)."""

ROWS_BEYOND_PLAN = 2
"""An episode table of more than this many times the episodes run.json plans (plus 100) is refused unread."""


@dataclass(frozen=True)
class EpisodeEntry:
    """Where one episode of a run is.

    Attributes:
        key: its cell.
        path: the file holding it: a part, a samples file of the store, or an `.npz`.
        row: its episode-table row (None for an `.npz`, whose metadata is inside the file).
        part: `path` is a part (a cell not compacted yet), not a samples file.
        table_row: its row's index in the episode table (None: a part or an `.npz`).
    """

    key: EpisodeKey
    path: Path
    row: Mapping[str, Any] | None = None
    part: bool = False
    table_row: int | None = None

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

    def rows(self, path: Path, start: int, count: int, row: Mapping[str, Any], where: str, *,
             part: bool = False) -> pa.Table:
        """Samples `start`.. `start + count` of `path`, checked to be of `row`'s cell, thinned to about
        `MAX_SAMPLES_READ`.

        Args:
            where: who names these rows, for messages (the episode table and its row, or the part).
            part: `path` is a part, which holds the episode's samples and nothing else (neither it nor its row
                groups are kept: a part is replaced by its compacted copy).

        Raises:
            ValueError: the file does not read, does not hold the rows, or holds another cell's, naming it.
        """
        f = None if part else self.files.get(path)
        if f is None:
            f = open_samples(path)
            if not part:
                self.files[path] = f
        try:
            if part and f.metadata.num_rows != count:
                raise ValueError(f"{path}: {f.metadata.num_rows} samples, its episode row says {count}")
            return self._rows(f, path, start, count, row, where, part, max(1, -(-count // MAX_SAMPLES_READ)))
        finally:
            if part:
                f.close(force=True)

    def _rows(self, f: pq.ParquetFile, path: Path, start: int, count: int, row: Mapping[str, Any], where: str,
              part: bool, step: int) -> pa.Table:
        pieces, got, first, end = [], 0, 0, start + count
        for g in range(f.metadata.num_row_groups):
            n = f.metadata.row_group(g).num_rows
            if first < end and first + n > start:
                for at, chunk in self._chunks(path, f, g, first, keep=not part):
                    lo, hi = max(start, at), min(end, at + chunk.num_rows)
                    if lo >= hi:
                        continue
                    piece = chunk.slice(lo - at, hi - lo)
                    other = other_cell(piece, row)
                    if other:
                        raise ValueError(f"{where}: its samples ({path.name} rows {start}..{end - 1}) are of "
                                         f"another cell: {other}")
                    pieces.append(piece if step == 1 else _thinned(piece, lo - start, step, count))
                    got += hi - lo
            first += n
        if got != count:
            raise ValueError(f"{path}: holds {got} of the {count} samples rows {start}.. its episode table names")
        if not pieces:
            return f.schema_arrow.empty_table()
        return pa.concat_tables(pieces) if len(pieces) != 1 else pieces[0]

    def _chunks(self, path: Path, f: pq.ParquetFile, g: int, first: int, keep: bool) -> Iterator[tuple[int, pa.Table]]:
        """Row group `g` (its first row `first`), whole as this tool writes it, or in batches of `ROW_GROUP_ROWS`
        where it is larger (a file not written by this tool: never held whole): (first row, table) each."""
        group = f.metadata.row_group(g)
        check_inflated(path, [group])
        try:
            if group.num_rows <= ROW_GROUP_ROWS:
                yield first, self._group(path, f, g) if keep else f.read_row_group(g)
                return
            for batch in f.iter_batches(batch_size=ROW_GROUP_ROWS, row_groups=[g]):
                yield first, pa.Table.from_batches([batch])
                first += batch.num_rows
        except (OSError, ValueError, pa.ArrowException) as exc:
            raise ValueError(f"{path}: row group {g} is corrupt ({' '.join(str(exc).split())[:200]})") from exc

    def _group(self, path: Path, f: pq.ParquetFile, g: int) -> pa.Table:
        if (path, g) not in self.groups:
            self.groups[(path, g)] = f.read_row_group(g)
            while len(self.groups) > self.size:
                self.groups.popitem(last=False)
        return self.groups[(path, g)]


def _thinned(piece: pa.Table, offset: int, step: int, count: int) -> pa.Table:
    """Every `step`-th sample of a flight's `count` (counted from its first; `piece` starts at sample `offset`),
    plus the piece's sample of least clearance and its last with a finite position, plus the flight's last."""
    n = piece.num_rows
    keep = [np.arange((-offset) % step, n, step)]
    clear = piece.column("clearance_m").to_numpy(zero_copy_only=False).astype(float)
    if np.any(np.isfinite(clear)):
        keep.append(np.array([np.nanargmin(clear)]))
    pos = np.column_stack([piece.column(c).to_numpy(zero_copy_only=False) for c in POSITION])
    finite = np.flatnonzero(np.all(np.isfinite(pos), axis=1))
    keep.append(finite[-1:])
    if offset + n == count:
        keep.append(np.array([n - 1]))
    return piece.take(pa.array(np.unique(np.concatenate(keep)).astype(np.int64)))


def _drawable(saved: SavedEpisode) -> SavedEpisode:
    """`saved`, if it is a flight the pages can draw (see `FLIGHT_REACH_M`).

    Raises:
        ValueError: its start or goal is not finite, no sample has a finite position, or a position lies beyond
            `FLIGHT_REACH_M` of its start.
    """
    ends = np.array([saved.meta.start_m, saved.meta.goal_m], float)
    if not np.all(np.isfinite(ends)):
        raise ValueError("its start_m or goal_m is not finite")
    pos = np.asarray(saved.trajectory.states, float)[:, 0:3]
    finite = np.all(np.isfinite(pos), axis=1)
    if not np.any(finite):
        raise ValueError("no sample has a finite position (x_m, y_m, z_m are NaN or inf throughout)")
    reach = float(np.max(np.abs(np.vstack([pos[finite], ends[1:]]) - ends[0])))
    if reach > FLIGHT_REACH_M:
        raise ValueError(f"a position (x_m, y_m, z_m) or its goal lies {reach:.3g} m from its start; a flight "
                         f"reaches {FLIGHT_REACH_M / 1000:g} km at most")
    return saved


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
    _moved: dict[EpisodeKey, EpisodeEntry] = field(default_factory=dict, repr=False, compare=False)

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
        """Read one episode (its samples as stored: thinned to the control rate unless the run kept all; at most
        about `MAX_SAMPLES_READ` of them).

        A file that went away since it was listed (a part compacted into a samples file by a run still writing
        the folder, a samples file replaced by a later compaction) is looked for again in the store as it is now.

        Raises:
            ValueError: it does not read, is not of its cell or is not a flight to draw (`_drawable`), naming the
                file (and for a stored episode, the cell).
        """
        try:
            if entry.row is None:
                return _drawable(load_episode(entry.path))
            try:
                return self._load_stored(entry)
            except ValueError:
                if entry.path.exists():
                    raise
                moved = self._relisted(entry)
                if moved is None:
                    raise
            return self._load_stored(moved)
        except ValueError as exc:
            text = str(exc)
            if text.startswith((str(entry.path), str(store_dir(self.run_dir)))):
                raise
            raise ValueError(f"{entry.path}: {entry.key.stem}: {text}") from exc

    def _load_stored(self, entry: EpisodeEntry) -> SavedEpisode:
        assert entry.row is not None
        if entry.part:  # the part's own row: a part replaced since it was listed reads whole and of one piece
            row: Mapping[str, Any] = part_row(entry.path)
            samples = self._cache.rows(entry.path, 0, int(row["samples"]), row, str(entry.path), part=True)
        else:
            row = entry.row
            where = f"{store_dir(self.run_dir) / EPISODE_TABLE}: row {entry.table_row} ({entry.key.stem})"
            samples = self._cache.rows(entry.path, int(row["row_start"]), int(row["samples"]), row, where)
        return _drawable(episode_from_tables(meta_from_row(row), samples))

    def _relisted(self, entry: EpisodeEntry) -> EpisodeEntry | None:
        """Where `entry`'s cell is now that its file is gone (None: nowhere else), listing the run again at most
        once per file gone."""
        moved = self._moved.get(entry.key)
        if moved is None or moved.path == entry.path or not moved.path.exists():
            self._moved.clear()
            self._moved.update((e.key, e) for e in open_episodes(self.run_dir).entries)
            moved = self._moved.get(entry.key)
        return moved if moved is not None and moved.path != entry.path and moved.row is not None else None

    def metrics(self, entry: EpisodeEntry) -> EpisodeMetrics:
        """The episode's metrics.csv row.

        Raises:
            ValueError: an `.npz` that does not read or score, naming it.
        """
        if entry.row is not None:
            return metrics_from_row(entry.row)
        return episode_metrics(load_episode(entry.path))


@dataclass(frozen=True)
class _Plan:
    """The cells run.json says the run flies: per scenario its episode count, seeds and pilots."""

    scenarios: Mapping[str, tuple[int, frozenset[int], frozenset[str]]]

    @property
    def episodes(self) -> int:
        return sum(n * len(seeds) * len(pilots) for n, seeds, pilots in self.scenarios.values())

    def holds(self, key: EpisodeKey) -> bool:
        cell = self.scenarios.get(key.scenario)
        return cell is not None and 0 <= key.episode < cell[0] and key.seed in cell[1] and key.method in cell[2]


def _run_plan(run_dir: Path) -> _Plan | None:
    """The cells `run_dir/run.json` plans (None: no readable run.json, or one that does not say: nothing bounded)."""
    try:
        info = read_run_info(run_dir)
    except ValueError:
        return None
    cells: dict[str, tuple[int, frozenset[int], frozenset[str]]] = {}
    for s in info.scenarios:
        pilots = s.pilots or tuple(info.pilots)
        if s.episodes is None or not s.seeds or not pilots:
            return None
        n, seeds, names = cells.get(s.name, (0, frozenset(), frozenset()))
        cells[s.name] = (max(n, s.episodes), seeds | set(s.seeds), names | set(pilots))
    return _Plan(cells) if cells else None


def _rows_named(rows: list[int]) -> str:
    """Row indices in words: "rows 3, 7 and 9" (the first 5, then how many more)."""
    shown = [str(i) for i in rows[:5]]
    if len(rows) > 5:
        return f"rows {', '.join(shown)} and {len(rows) - 5:,} more"
    return "row " + shown[0] if len(shown) == 1 else f"rows {', '.join(shown[:-1])} and {shown[-1]}"


def open_episodes(run_dir: Path) -> RunEpisodes:
    """List a run folder's episodes (see the module docstring); nothing but run.json, the episode table and the
    parts' footers is read.

    An unreadable part or `.npz` is listed in `unreadable`; an unreadable episode table too (its episodes are
    then missing), and its rows that are not read (one entry for each reason).

    Raises:
        LinkInFolder: (a ValueError) a link in the run folder (`compare.results.run_folder`): what it leads to
            is another folder's, never read as this run's.
    """
    run_dir = Path(run_dir)
    check_run_folder_links(run_dir)
    plan = _run_plan(run_dir)
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
    # the parts before the table: a part compacted meanwhile is gone from the one and in the other
    parts: dict[EpisodeKey, EpisodeEntry] = {}
    unplanned_parts: list[str] = []
    for p in part_files(run_dir):
        try:
            row = part_row(p)
            key = key_of(row)
        except (ValueError, TypeError) as exc:
            if p.exists():
                bad.append(Unreadable(p, str(exc)))
            continue
        if plan is not None and not plan.holds(key):
            unplanned_parts.append(p.name)
            continue
        parts[key] = EpisodeEntry(key, p, row, part=True)
    table = store_dir(run_dir) / EPISODE_TABLE
    try:
        if plan is None:
            rows = read_episode_table(run_dir)
        else:
            rows = read_episode_table(run_dir, ROWS_BEYOND_PLAN * plan.episodes + 100,
                                      f"run.json plans ({plan.episodes:,} episodes)")
    except ValueError as exc:
        bad.append(Unreadable(table, str(exc)))
        rows = []
    held: dict[EpisodeKey, list[int]] = {}
    stored: dict[EpisodeKey, EpisodeEntry] = {}
    unplanned: list[int] = []
    for i, row in enumerate(rows):
        try:
            key, samples = key_of(row), samples_path(run_dir, row)
        except (ValueError, TypeError) as exc:  # a row names a cell or a file this tool never writes: skipped
            bad.append(Unreadable(table, f"{table}: row {i}: {exc}"))
            continue
        if plan is not None and not plan.holds(key):
            unplanned.append(i)
            continue
        held.setdefault(key, []).append(i)
        stored[key] = EpisodeEntry(key, samples, row, table_row=i)
    for key, at in held.items():
        if len(at) > 1:  # compaction never writes one cell twice: neither row is believed
            del stored[key]
            bad.append(Unreadable(table, f"{table}: {_rows_named(at)} hold one cell, {key.stem}: none of them is "
                                         "read (which is its flight cannot be told)"))
    if unplanned:
        bad.append(Unreadable(table, f"{table}: {_rows_named(unplanned)} hold cells run.json does not plan "
                                     f"(first {key_of(rows[unplanned[0]]).stem}): skipped", planned=False))
    if unplanned_parts:
        folder = store_dir(run_dir) / PARTS_DIR
        bad.append(Unreadable(folder, f"{folder}: {len(unplanned_parts):,} parts hold cells run.json does not plan "
                                      f"(first {unplanned_parts[0]}): skipped", planned=False))
    found.update(stored)
    found.update(parts)
    order = sorted(found, key=lambda k: (k.scenario, k.episode, k.method, k.seed))
    return RunEpisodes(run_dir, tuple(found[k] for k in order), tuple(bad))


def refuse_bad_rows(run_dir: Path) -> None:
    """Refuse to add to a run whose store holds what the readers skip as not the run's: an episode table that does
    not read or is far larger than the plan, a row whose cell or samples file is not readable, rows of cells
    run.json does not plan (parts too), a cell held twice (`open_episodes`'s checks). Compaction would keep them
    beside the new episodes. A part that does not read is not refused: `run --resume` flies its cell again.

    Raises:
        ValueError: naming the run, the file and its first bad row (the readers' reason).
    """
    table = store_dir(run_dir) / EPISODE_TABLE
    for bad in open_episodes(run_dir).unreadable:
        if bad.path == table or not bad.planned:
            raise ValueError(f"{run_dir}: cannot resume: {bad.reason}; nothing was flown or written (fly into a "
                             f"new folder; `uam-compare report` reports this one without them)")


def kept_keys(run_dir: Path) -> set[EpisodeKey]:
    """The cells whose episode `run --resume` keeps: each part reads whole, each samples file of the episode
    table opens and holds the rows named, each `.npz` reads; any other is flown again (logged, naming it)."""
    episodes = open_episodes(run_dir)
    for b in episodes.unreadable:
        log.warning("%s%s", "flying again: " if b.planned else "", b.reason)
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
