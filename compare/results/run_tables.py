"""A run folder's results as typed tables for analysis, imitation learning or offline RL: `load_run(RUN_DIR)`.

```python
from compare.results.run_tables import load_run
run = load_run("runs/mine")
run.episodes     # pyarrow.Table, one row per episode: the metrics.csv columns, the conditions, where its samples are
run.samples      # pyarrow.Table, one row per kept sample (the control rate unless the run kept every physics step)
run.decisions    # pyarrow.Table, one row per decision: the state, the command given, the pilot's observation vector
                 # (None for a run stored before the commands were recorded: `run.notes` says so)
run.metrics      # the metrics.csv columns of run.episodes
run.info         # run.json (`compare.results.run_info.RunInfo`)
X, Y = run.imitation_pairs("ppo")   # (D, k) observations and (D, 4) velocity commands of the learned pilot
```

Every column's type, unit, frame and meaning: `RUN_DIR/store/schema.json` (`compare.results.store_schema`). The
episodes are found as every reader of this package finds them (`compare.results.episodes.open_episodes`: the cells
run.json plans, a part over its compacted copy, a run saved before the store as its `.npz` files at the physics
rate); a file that does not read is left out and named in `notes`, and a link inside the run folder is refused
before anything is read (`compare.results.run_folder`). The samples are read whole (about 0.5 kB per sample in
memory): give `sample_columns` to read fewer columns of a large run.
"""
from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from compare.results.episodes import EpisodeEntry, open_episodes
from compare.results.metrics import episode_metrics
from compare.results.run_folder import check_run_folder_links
from compare.results.run_info import RunInfo, read_run_info
from compare.results.store import EPISODE_TABLE, PARTS_DIR, open_samples, other_cell, read_part, store_dir
from compare.results.store_schema import DECISIONS_VIEW, KEY_COLUMNS
from compare.results.tables import EPISODE_SCHEMA, METRIC_COLUMNS, SAMPLE_SCHEMA, episode_row, samples_table
from compare.results.trajectory import load_episode
from uam_fdm.files.inside import inside_no_links

_KEYS = tuple(c.name for c in KEY_COLUMNS)


@dataclass(frozen=True)
class RunTables:
    """A run's results as pyarrow Tables (see the module docstring).

    Attributes:
        run_dir: the run folder.
        info: its run.json.
        episodes: one row per episode read, in cell order (`compare.results.tables.EPISODE_SCHEMA`).
        samples: one row per kept sample of those episodes, in cell order (the columns asked for, with the cell's
            and t_s; `compare.results.tables.SAMPLE_SCHEMA`).
        decisions: one row per decision, in cell order (`compare.results.store_schema.DECISIONS_VIEW`: the cell,
            decision_t_s [s], the true state at the decision (world ENU, body FLU), the navigation estimate's position,
            action_kind, action, action_hold_periods, observation); None when no episode recorded its commands (a
            store written before they were).
        notes: what was left out or is missing, one line each (unreadable files, episodes without commands).
    """

    run_dir: Path
    info: RunInfo
    episodes: pa.Table
    samples: pa.Table
    decisions: pa.Table | None
    notes: tuple[str, ...] = ()

    @property
    def metrics(self) -> pa.Table:
        """The metrics.csv columns of the episodes (one row per episode; values as computed in the cell)."""
        return self.episodes.select(list(METRIC_COLUMNS))

    def imitation_pairs(self, method: str, features: Sequence[str] = ("observation",)) -> tuple[np.ndarray, np.ndarray]:
        """What pilot `method` was given and what it commanded, decision by decision, as arrays to fit.

        Args:
            method: the pilot's name (the `method` column).
            features: decisions columns to put side by side as inputs, e.g. ("observation",) for the learned
                pilot, or `compare.results.store_schema.STATE_COLUMNS` (the true state: position world ENU [m],
                velocity [m/s], quaternion, body rates FLU [rad/s], rotor speeds [rad/s]).

        Returns:
            X (D, k) float32 and Y (D, a) float32: the features and the command (`action`) of each of the pilot's
            D decisions, in cell order.

        Raises:
            ValueError: no decisions recorded, none of `method`, an unknown or null feature, or vectors of
                different lengths (e.g. two vehicles' rotor counts), naming which.
        """
        if self.decisions is None:
            raise ValueError(f"{self.run_dir}: its store holds no decisions' commands ({'; '.join(self.notes)})")
        rows = self.decisions.filter(pc.equal(self.decisions.column("method"), method))
        if rows.num_rows == 0:
            raise ValueError(f"{self.run_dir}: no decision of pilot {method!r} is stored")
        unknown = [f for f in features if f not in rows.column_names]
        if unknown:
            raise ValueError(f"features {unknown}: not columns of the decisions table ({', '.join(DECISIONS_VIEW)})")
        x = np.hstack([_matrix(rows, f) for f in features]) if features else np.zeros((rows.num_rows, 0), np.float32)
        return x, _matrix(rows, "action")


def load_run(run_dir: Path | str, *, sample_columns: Sequence[str] | None = None) -> RunTables:
    """Read a run folder's episodes, samples and decisions into pyarrow Tables (nothing is written).

    Args:
        run_dir: a folder written by `uam-compare run` (complete, interrupted or saved before the store).
        sample_columns: the samples columns to read besides the cell's and t_s (None: all of them; () none).

    Raises:
        ValueError: `run_dir` is not a run folder (no such folder, no run.json, no episode held or none that reads),
            naming the path and what is missing; a sample column that does not exist; a link inside the run
            folder (`uam_fdm.files.inside.LinkInFolder`), naming it.
    """
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ValueError(f"{run_dir}: not a run folder ({'a file' if run_dir.exists() else 'no such folder'})")
    check_run_folder_links(run_dir)  # a link inside the folder is refused before anything is read
    info = read_run_info(run_dir)  # "not a run folder (no run.json)"
    wanted = list(SAMPLE_SCHEMA.names) if sample_columns is None else [*_KEYS, "t_s", *sample_columns]
    unknown = [c for c in wanted if c not in SAMPLE_SCHEMA.names]
    if unknown:
        raise ValueError(f"sample_columns {unknown}: not columns of the samples table "
                         f"({', '.join(SAMPLE_SCHEMA.names)})")
    read = [n for n in SAMPLE_SCHEMA.names if n in wanted or n in DECISIONS_VIEW]
    listed = open_episodes(run_dir)
    for e in listed.entries:  # a samples file, part or .npz that is a link leads out of the run: refused
        inside_no_links(run_dir, e.path)
    if not listed.entries:
        store = store_dir(run_dir)
        why = "; ".join(b.reason for b in listed.unreadable[:3]) or (
            f"no {store / EPISODE_TABLE}, no part in {store / PARTS_DIR} and no episodes/*.npz: nothing was flown "
            "into it yet")
        raise ValueError(f"{run_dir}: a run folder with no episode to read ({why})")
    notes = [b.reason for b in listed.unreadable]
    rows, pieces = _read_episodes(run_dir, listed.entries, read, notes)
    samples = pa.concat_tables(pieces) if pieces else pa.schema([SAMPLE_SCHEMA.field(n) for n in read]).empty_table()
    decisions = _decisions(samples, notes)
    episodes = pa.Table.from_pylist(rows, schema=EPISODE_SCHEMA)
    return RunTables(run_dir, info, episodes, samples.select([n for n in read if n in wanted]), decisions,
                     tuple(notes))


def _read_episodes(run_dir: Path, entries: Sequence[EpisodeEntry], columns: list[str], notes: list[str]
                   ) -> tuple[list[dict[str, Any]], list[pa.Table]]:
    """The episode rows and samples (`columns`) of `entries`, in their order; an episode that does not read is
    left out and named in `notes`."""
    by_file: dict[Path, list[int]] = defaultdict(list)
    for i, e in enumerate(entries):
        if e.row is not None and not e.part:
            by_file[e.path].append(i)
    got: dict[int, tuple[dict[str, Any], pa.Table]] = {}
    for path, at in by_file.items():  # each samples file read once, its episodes sliced out
        try:
            f = open_samples(path)
            table = _with_columns(f.read(columns=[c for c in columns if c in f.schema_arrow.names]), columns)
        except (ValueError, OSError, pa.ArrowException) as exc:
            notes.append(f"{path}: not read, {len(at)} episodes left out ({exc})")
            continue
        for i in at:
            row = dict(entries[i].row or {})
            piece = table.slice(int(row["row_start"]), int(row["samples"]))
            other = other_cell(piece, row) if piece.num_rows == int(row["samples"]) else "rows missing"
            if other:
                notes.append(f"{path}: the samples of {entries[i].key.stem} are not its own ({other}): left out")
                continue
            got[i] = row, piece
    for i, e in enumerate(entries):
        if i in got or (e.row is not None and not e.part):
            continue
        try:
            got[i] = _part_or_npz(e, columns)
        except ValueError as exc:
            notes.append(f"{e.path}: left out ({exc})")
    order = sorted(got)
    return [got[i][0] for i in order], [got[i][1] for i in order]


def _part_or_npz(entry: EpisodeEntry, columns: list[str]) -> tuple[dict[str, Any], pa.Table]:
    """The row and samples of a part, or of an `.npz` of a run saved before the store (at the physics rate, as
    `run --store full` keeps them; no conditions recorded)."""
    if entry.part:
        row, samples = read_part(entry.path)
        return row, _with_columns(samples, columns)
    saved = load_episode(entry.path)
    traj, meta = saved.trajectory, saved.meta
    row = episode_row(meta, episode_metrics(saved), None, "full", len(traj.t_s))
    return row, _with_columns(samples_table(meta.key, traj, meta.n_rotors, "full", 1), columns)


def _with_columns(table: pa.Table, columns: list[str]) -> pa.Table:
    """`table`'s `columns`, those a file written before they existed lacks given as nulls."""
    n = table.num_rows
    return pa.table({c: table.column(c) if c in table.column_names else pa.nulls(n, SAMPLE_SCHEMA.field(c).type)
                     for c in columns}, schema=pa.schema([SAMPLE_SCHEMA.field(c) for c in columns]))


def _decisions(samples: pa.Table, notes: list[str]) -> pa.Table | None:
    """The decision rows of `samples` (`DECISIONS_VIEW`), or None when none holds a command (noted)."""
    rows = samples.filter(pc.is_valid(samples.column("decision_t_s"))).select(list(DECISIONS_VIEW))
    missing = pc.is_null(rows.column("action_kind"))
    if rows.num_rows and pc.all(missing).as_py():
        notes.append("no decisions table: the run holds no pilot's commands (saved before they were recorded: "
                     "fly the run again with this version to record them)")
        return None
    lacking = rows.filter(missing)
    cells = {tuple(r[k] for k in _KEYS) for r in lacking.select(list(_KEYS)).to_pylist()}
    if cells:
        notes.append(f"{len(cells)} episodes were stored before the pilots' commands were recorded: their "
                     f"decisions are left out of the decisions table")
    return rows.filter(pc.invert(missing))


def _matrix(rows: pa.Table, name: str) -> np.ndarray:
    """Column `name` of `rows` as a (D, k) float32 matrix (a list column: its vectors, one per row)."""
    col = rows.column(name).combine_chunks()
    if col.null_count:
        raise ValueError(f"{name}: null in {col.null_count} of {len(col)} decisions (this pilot has none there)")
    if not pa.types.is_list(col.type):
        return col.to_numpy(zero_copy_only=False).astype(np.float32)[:, None]
    lengths = pc.unique(pc.list_value_length(col)).to_pylist()
    if len(lengths) != 1:
        raise ValueError(f"{name}: vectors of {sorted(lengths)} values; select decisions of one length (one vehicle)")
    return pc.list_flatten(col).to_numpy(zero_copy_only=False).astype(np.float32).reshape(len(col), lengths[0])
