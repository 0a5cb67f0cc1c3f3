"""`load_run(RUN_DIR)`: a run folder's episodes, samples and decisions as pyarrow Tables, the same the run's own
readers see; a folder that is not a run is one clear error naming the path and what is missing; a link inside the
folder is refused; an interrupted run, a store written before the decisions were recorded and a run saved before
the store load too, saying what they lack."""
from __future__ import annotations

import csv
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from compare.results.episodes import open_episodes
from compare.results.run_tables import load_run
from compare.results.store import WRITE_OPTIONS, samples_files
from compare.results.store_schema import DECISION_COLUMNS, DECISIONS_VIEW, ROTOR_SPEEDS, VELOCITY_YAW
from compare.results.tables import METRIC_COLUMNS, SAMPLE_SCHEMA
from synthetic_run import to_store, write_run
from uam_fdm.files.inside import LinkInFolder

NPZ_RUN = Path(__file__).resolve().parents[2] / "data" / "npz_run"


@pytest.fixture
def run(flown_tiny_run: Path, tmp_path: Path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(flown_tiny_run, out)
    return out


def _same(text: str, value: object) -> bool:
    """A metrics.csv cell and the table's value agree (numbers to 1e-9, NaN to NaN, flags as 0/1)."""
    if isinstance(value, bool):
        return text == str(int(value))
    if isinstance(value, float):
        return (math.isnan(value) and text == "nan") or float(text) == pytest.approx(value, rel=1e-9, abs=1e-12)
    return text == str(value)


def test_load_run_gives_the_tables_the_run_s_readers_see(flown_tiny_run: Path) -> None:
    run = load_run(flown_tiny_run)
    assert run.notes == () and run.info.pilots.keys() >= {"ppo", "rrt_mpc", "apf"}
    assert run.episodes.column("method").to_pylist() == ["apf", "ppo", "rrt_mpc"]  # cell order
    with open(flown_tiny_run / "metrics.csv", newline="") as f:
        rows = {r["method"]: r for r in csv.DictReader(f)}
    assert run.metrics.column_names == list(METRIC_COLUMNS)
    for row in run.metrics.to_pylist():
        bad = [c for c in METRIC_COLUMNS if c in rows[row["method"]] and not _same(rows[row["method"]][c], row[c])]
        assert not bad, (row["method"], bad)
    assert run.samples.num_rows == sum(run.episodes.column("samples").to_pylist())
    assert run.samples.column_names == SAMPLE_SCHEMA.names
    assert run.decisions is not None and run.decisions.column_names == list(DECISIONS_VIEW)
    episodes = open_episodes(flown_tiny_run)
    for entry in episodes.entries:  # one decisions row per decision the episode made, at its time
        traj = episodes.load(entry).trajectory
        mine = run.decisions.filter(pc.equal(run.decisions.column("method"), entry.key.method))
        np.testing.assert_array_equal(mine.column("decision_t_s").to_numpy(), traj.decision_t_s)
        kinds = set(mine.column("action_kind").to_pylist())
        sizes = set(pc.list_value_length(mine.column("observation")).to_pylist())
        assert (kinds, sizes) == {"ppo": ({VELOCITY_YAW}, {115}), "rrt_mpc": ({ROTOR_SPEEDS}, {None}),
                                  "apf": ({VELOCITY_YAW}, {None})}[entry.key.method]
    fewer = load_run(flown_tiny_run, sample_columns=("z_m",))
    assert fewer.samples.column_names == ["scenario", "episode", "method", "seed", "t_s", "z_m"]
    assert fewer.samples.column("z_m").equals(run.samples.column("z_m")) and fewer.decisions.equals(run.decisions)


def test_a_folder_that_is_not_a_run_is_one_clear_error(tmp_path: Path, flown_tiny_run: Path) -> None:
    with pytest.raises(ValueError, match=f"{tmp_path / 'nowhere'}: not a run folder \\(no such folder\\)"):
        load_run(tmp_path / "nowhere")
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="not a run folder \\(a file\\)"):
        load_run(tmp_path / "file")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match=f"{empty}: not a run folder \\(no run.json\\)"):
        load_run(empty)
    shutil.copy(flown_tiny_run / "run.json", empty / "run.json")
    with pytest.raises(ValueError, match=f"{empty}: a run folder with no episode to read .*store/episodes.parquet"):
        load_run(empty)
    with pytest.raises(ValueError, match=r"sample_columns \['speed'\]: not columns of the samples table"):
        load_run(flown_tiny_run, sample_columns=("speed",))


def test_a_link_inside_the_run_folder_is_refused_naming_it(run: Path, tmp_path: Path) -> None:
    [samples] = samples_files(run)
    elsewhere = tmp_path / "elsewhere.parquet"
    shutil.move(samples, elsewhere)
    samples.symlink_to(elsewhere)
    with pytest.raises(LinkInFolder, match=f"{samples}: a symbolic link inside {run}"):
        load_run(run)
    samples.unlink()
    shutil.move(run / "store", tmp_path / "other_store")
    shutil.move(elsewhere, tmp_path / "other_store" / samples.name)
    (run / "store").symlink_to(tmp_path / "other_store")
    with pytest.raises(LinkInFolder, match=f"{run / 'store'}: a symbolic link"):
        load_run(run)


def test_a_store_written_before_the_decisions_were_recorded_loads_without_them(run: Path) -> None:
    [samples] = samples_files(run)
    old = pq.read_table(samples).drop_columns([c.name for c in DECISION_COLUMNS])
    pq.write_table(old, samples, **WRITE_OPTIONS)
    loaded = load_run(run)
    assert loaded.decisions is None and loaded.notes[0].startswith("no decisions table")
    assert loaded.samples.num_rows == old.num_rows and loaded.samples.column("action").null_count == old.num_rows
    with pytest.raises(ValueError, match="holds no decisions' commands"):
        loaded.imitation_pairs("ppo")
    episodes = open_episodes(run)  # what the report and viewer read: the older samples file opens and reads
    assert episodes.unreadable == () and len(episodes.entries) == 3
    assert all(len(episodes.load(e).trajectory.decision_t_s) > 50 for e in episodes.entries)


def test_an_interrupted_run_and_a_run_saved_before_the_store_load(tmp_path: Path) -> None:
    write_run(tmp_path / "parts", None)
    to_store(tmp_path / "parts", compacted=False)  # the cells' parts only, as an interrupted run leaves them
    loaded = load_run(tmp_path / "parts")
    assert loaded.episodes.num_rows == 4 and set(loaded.episodes.column("samples_file").to_pylist()) == {""}
    assert loaded.samples.num_rows == sum(loaded.episodes.column("samples").to_pylist())
    assert loaded.decisions is None  # synthetic flights record no commands: said so
    assert any("no decisions table" in n for n in loaded.notes)
    npz = load_run(NPZ_RUN)  # one .npz per episode at the physics rate
    assert npz.episodes.column("store").to_pylist() == ["full", "full"] and npz.decisions is None
    with np.load(NPZ_RUN / "episodes" / "legacy__ep000__ppo__s0.npz") as f:
        rows = len(f["t_s"])
    assert npz.samples.filter(pc.equal(npz.samples.column("method"), "ppo")).num_rows == rows
    assert json.loads(npz.episodes.column("meta_json")[0].as_py())["key"]["method"] in ("ppo", "rrt_mpc")


def test_a_samples_file_that_does_not_read_is_left_out_and_named(run: Path) -> None:
    [samples] = samples_files(run)
    samples.write_bytes(samples.read_bytes()[:1000])
    loaded = load_run(run)
    assert loaded.episodes.num_rows == 0 and loaded.samples.num_rows == 0
    assert any(str(samples) in n and "3 episodes left out" in n for n in loaded.notes), loaded.notes
    assert isinstance(loaded.samples, pa.Table)
