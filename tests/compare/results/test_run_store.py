"""The run store: an episode's part round-trips, parts compact into the episode table and samples
files with the same bytes every time, a compaction cut short or a corrupt part loses nothing, and pandas and
DuckDB read the tables without our code."""
from __future__ import annotations

import math
from dataclasses import astuple, replace

import numpy as np
import pyarrow.parquet as pq
import pytest
from pypdf import PdfReader

from compare.cli import main
from compare.results.episodes import kept_keys, open_episodes
from compare.results.metrics import episode_metrics
from compare.results.store import (
    EPISODE_TABLE,
    compact,
    part_bytes,
    part_files,
    part_path,
    read_part,
    samples_files,
    store_dir,
    write_part,
)
from compare.results.tables import (
    QUANTA,
    EpisodeConditions,
    episode_from_tables,
    episode_row,
    kept_rows,
    meta_from_row,
    metrics_from_row,
    samples_table,
)
from compare.results.trajectory import EpisodeKey, EpisodeMeta, SavedEpisode
from synthetic_run import GOAL, START, to_store, trajectory, write_run

CONDITIONS = EpisodeConditions(1.0581, 1000.0, "light", (3.0, 4.0, 0.0), 0.25)
PERIOD = 10  # physics steps per control period (500 Hz / 50 Hz)


def _episode(episode: int = 0, pilot: str = "ppo", n: int = 1201, outcome: str = "success",
             scenario: str = "toy-quad") -> SavedEpisode:
    """A synthetic flight on the runner's grid (2 ms), decisions every control period but the last row."""
    traj = trajectory(n, (n - 1) * 0.002, 10.0, 1.0, outcome, episode, shaft_power=True)
    t = traj.t_s
    decisions = t[:-1:PERIOD] + 1e-15 * (np.arange(len(t[:-1:PERIOD])) % 3)  # the runner's clock: off in the last bit
    compute = 1e-3 * (1.0 + np.sin(np.arange(len(decisions))))
    traj = replace(traj, decision_t_s=decisions, compute_s=compute)
    key = EpisodeKey(scenario, episode, pilot, 0)
    meta = EpisodeMeta(key, "toy", "small_quad", START, GOAL, 3.0, 60.0, 0.42, 4, 1234.5, outcome,
                       0.3 if pilot == "rrt_mpc" else 0.0, f"synthetic {outcome}", wind_seed=7, agent_seed=8,
                       mean_decision_ms=1.0, vehicle_fingerprint="0123456789abcdef")
    return SavedEpisode(meta, traj)


def _same(a, b) -> bool:
    """Equal metrics rows, NaN equal to NaN (floats compared by their exact repr)."""
    return repr(astuple(a)) == repr(astuple(b))


def _part(saved: SavedEpisode, mode: str = "control") -> bytes:
    metrics = episode_metrics(saved)
    rows = kept_rows(saved.trajectory, mode, PERIOD)
    return part_bytes(episode_row(saved.meta, metrics, CONDITIONS, mode, len(rows)),
                      samples_table(saved.meta.key, saved.trajectory, 4, mode, PERIOD))


def _write_parts(run_dir, episodes) -> None:
    for saved in episodes:
        write_part(part_path(run_dir, saved.meta.key), _part(saved))


def test_control_rate_keeps_periods_the_least_clearance_and_the_end():
    saved = _episode(n=1205)  # the last row is not on the control grid (never so in a run; kept all the same)
    rows = kept_rows(saved.trajectory, "control", PERIOD)
    least = int(np.nanargmin(saved.trajectory.clearance_m))
    assert set(range(0, 1205, PERIOD)) | {1204, least} == set(rows.tolist())
    assert kept_rows(saved.trajectory, "full", PERIOD).tolist() == list(range(1205))


def test_part_round_trip_full_rate_is_exact_where_float64_and_float32_elsewhere(tmp_path):
    saved = _episode()
    path = write_part(tmp_path / "p.parquet", _part(saved, "full"))
    row, samples = read_part(path)
    back = episode_from_tables(meta_from_row(row), samples)
    a, b = saved.trajectory, back.trajectory
    assert back.meta == saved.meta
    np.testing.assert_array_equal(b.t_s, a.t_s)
    np.testing.assert_array_equal(b.states[:, 0:3], a.states[:, 0:3])  # position float64, unrounded
    np.testing.assert_allclose(b.states, a.states, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(b.rotor_commands, a.rotor_commands, rtol=1e-7)
    np.testing.assert_allclose(b.shaft_power_W, a.shaft_power_W, rtol=1e-7)
    np.testing.assert_array_equal(b.decision_t_s, a.decision_t_s)  # exact, though off the rows' times in the last bit
    np.testing.assert_allclose(b.compute_s, a.compute_s, rtol=1e-7)
    assert _same(metrics_from_row(row), episode_metrics(saved))  # exact floats, NaN included


def test_control_rate_part_is_rounded_to_the_stated_quanta_and_keeps_every_decision(tmp_path):
    saved = _episode(pilot="rrt_mpc")
    row, samples = read_part(write_part(tmp_path / "p.parquet", _part(saved)))
    back = episode_from_tables(meta_from_row(row), samples).trajectory
    rows = kept_rows(saved.trajectory, "control", PERIOD)
    a = saved.trajectory
    np.testing.assert_array_equal(back.t_s, a.t_s[rows])
    assert np.max(np.abs(back.states[:, 0:3] - a.states[rows, 0:3])) <= 2.0 ** -QUANTA["position"] / 2
    assert np.max(np.abs(back.states[:, 13:] - a.states[rows, 13:])) <= 2.0 ** -QUANTA["rotors"] / 2 + 1e-3
    assert float(np.min(back.clearance_m)) == pytest.approx(float(np.min(a.clearance_m)), abs=1e-6)  # the least kept
    np.testing.assert_array_equal(back.decision_t_s, a.decision_t_s)
    metrics = metrics_from_row(row)
    assert _same(metrics, episode_metrics(saved))  # computed before thinning, stored exactly
    assert math.isnan(metrics.mpc_solve_ms_median)  # NaN survives the JSON of a part


def test_part_bytes_are_deterministic():
    saved = _episode()
    assert _part(saved) == _part(saved)


def _compacted(run_dir, episodes):
    _write_parts(run_dir, episodes)
    assert compact(run_dir) == []
    return {p.name: p.read_bytes() for p in sorted(store_dir(run_dir).glob("*.parquet"))}


def test_compaction_moves_parts_into_the_store_with_the_same_bytes_every_time(tmp_path):
    episodes = [_episode(e, m) for e in range(3) for m in ("ppo", "rrt_mpc")]
    first = _compacted(tmp_path / "a", episodes)
    second = _compacted(tmp_path / "b", list(reversed(episodes)))  # the order cells end in does not matter
    assert first == second and set(first) == {EPISODE_TABLE, "samples-0001-000.parquet"}
    assert part_files(tmp_path / "a") == []
    run = open_episodes(tmp_path / "a")
    assert [e.key for e in run.entries] == sorted((s.meta.key for s in episodes),
                                                  key=lambda k: (k.scenario, k.episode, k.method, k.seed))
    for saved, entry in zip(sorted(episodes, key=lambda s: (s.meta.key.episode, s.meta.key.method)), run.entries):
        loaded = run.load(entry)
        assert loaded.meta == saved.meta and _same(run.metrics(entry), episode_metrics(saved))
        rows = kept_rows(saved.trajectory, "control", PERIOD)
        np.testing.assert_array_equal(loaded.trajectory.t_s, saved.trajectory.t_s[rows])


def test_episodes_span_row_groups(tmp_path, monkeypatch):
    monkeypatch.setattr("compare.results.store.ROW_GROUP_ROWS", 50)  # every episode over several row groups
    monkeypatch.setattr("compare.results.store.ROWS_PER_FILE", 150)  # and one episode per file
    episodes = [_episode(e, "ppo", n=1001 + 10 * e) for e in range(4)]
    _compacted(tmp_path, episodes)
    assert len(samples_files(tmp_path)) == 4
    assert pq.ParquetFile(samples_files(tmp_path)[0]).metadata.num_row_groups > 1
    run = open_episodes(tmp_path)
    for saved, entry in zip(episodes, run.entries):
        rows = kept_rows(saved.trajectory, "control", PERIOD)
        np.testing.assert_array_equal(run.load(entry).trajectory.t_s, saved.trajectory.t_s[rows])


def test_a_later_compaction_appends_and_a_cut_short_one_is_completed(tmp_path):
    _compacted(tmp_path, [_episode(0, "ppo")])
    _write_parts(tmp_path, [_episode(1, "ppo")])
    assert compact(tmp_path) == []
    assert [f.name for f in samples_files(tmp_path)] == ["samples-0001-000.parquet", "samples-0002-000.parquet"]
    # cut short after the table was written, before the parts were removed: the part is read (it wins)
    _write_parts(tmp_path, [_episode(1, "ppo")])
    run = open_episodes(tmp_path)
    assert [e.part for e in run.entries] == [False, True]
    assert compact(tmp_path) == []  # compacted again; the samples file no row points at any more is removed
    assert [f.name for f in samples_files(tmp_path)] == ["samples-0001-000.parquet", "samples-0003-000.parquet"]
    assert len(open_episodes(tmp_path).entries) == 2


def test_a_corrupt_part_is_skipped_named_left_in_place_and_flown_again(tmp_path, caplog):
    good, bad = _episode(0, "ppo"), _episode(1, "ppo")
    _write_parts(tmp_path, [good, bad])
    path = part_path(tmp_path, bad.meta.key)
    path.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 2])  # truncated
    skipped = compact(tmp_path)
    assert [s.path for s in skipped] == [path] and str(path) in skipped[0].reason
    assert path.exists() and part_files(tmp_path) == [path]
    assert str(path) in caplog.text
    run = open_episodes(tmp_path)
    assert [e.key for e in run.entries] == [good.meta.key] and [u.path for u in run.unreadable] == [path]
    assert kept_keys(tmp_path) == {good.meta.key}  # run --resume flies the other again


def test_pandas_and_duckdb_read_the_store(tmp_path):
    pd = pytest.importorskip("pandas")
    duckdb = pytest.importorskip("duckdb")
    episodes = [_episode(e, m, outcome="collision" if (e, m) == (1, "ppo") else "success")
                for e in range(2) for m in ("ppo", "rrt_mpc")]
    _compacted(tmp_path, episodes)
    store = store_dir(tmp_path)
    # queries of the kind docs/comparison.md shows ("The run store")
    episodes = pd.read_parquet(store / "episodes.parquet")
    rates = episodes.groupby(["vehicle", "method", "density_altitude_m"]).success.mean()
    assert rates.to_dict() == {("small_quad", "ppo", 1000.0): 0.5, ("small_quad", "rrt_mpc", 1000.0): 1.0}
    by_air = duckdb.sql(f"SELECT method, density_altitude_m, avg(success::INT) FROM '{store}/episodes.parquet' "
                        f"GROUP BY ALL ORDER BY ALL").fetchall()
    assert by_air == [("ppo", 1000.0, 0.5), ("rrt_mpc", 1000.0, 1.0)]
    table = duckdb.sql(f"SELECT method, avg(success::INT) AS success, count(*) AS n "
                       f"FROM '{store}/episodes.parquet' GROUP BY method ORDER BY method").fetchall()
    assert table == [("ppo", 0.5, 2), ("rrt_mpc", 1.0, 2)]
    climbs = duckdb.sql(f"SELECT method, max(z_m) FROM '{store}/samples-*.parquet' GROUP BY method "
                        f"ORDER BY method").fetchall()
    assert [m for m, _ in climbs] == ["ppo", "rrt_mpc"] and all(z > 9.0 for _, z in climbs)


@pytest.mark.parametrize("damage", ["truncated", "corrupt"])
def test_report_and_view_skip_an_unreadable_part_naming_it(tmp_path, capsys, caplog, damage):
    run = tmp_path / "run"
    write_run(run, None)
    to_store(run, compacted=False)  # an interrupted run: its cells' parts, not compacted yet
    bad = part_path(run, EpisodeKey("toy-quad", 1, "ppo", 0))
    data = bad.read_bytes()
    data = {"truncated": data[:len(data) // 2], "corrupt": data[:200] + bytes(3000) + data[3200:]}[damage]
    bad.write_bytes(data)
    with caplog.at_level("WARNING"):
        assert main(["report", str(run)]) == 0
    assert "Traceback" not in capsys.readouterr().err
    assert any(r.levelname == "WARNING" and str(bad) in r.getMessage() for r in caplog.records), caplog.text
    rows = (run / "metrics.csv").read_text().splitlines()
    assert len(rows) == 1 + 3 and not any(",1,ppo," in r for r in rows)  # scored from the other three
    failures = [p.extract_text() for p in PdfReader(str(run / "report.pdf")).pages]
    failures = " ".join(t for t in failures if t.lstrip().startswith("Failures"))
    assert "Unreadable episode files skipped" in failures and bad.name in failures.replace("\n", "")
    assert (run / "viewer.html").is_file() and bad.read_bytes() == data  # the bad part is kept as it was
    assert part_files(run) == [bad] and len(open_episodes(run).entries) >= 3  # the rest compacted
    assert kept_keys(run) == {EpisodeKey("toy-quad", e, m, 0) for e, m in ((0, "ppo"), (0, "rrt_mpc"), (1, "rrt_mpc"))}
    caplog.clear()
    with caplog.at_level("WARNING"):
        assert main(["view", str(run), "--out", str(tmp_path / "v.html")]) == 0
    assert (tmp_path / "v.html").is_file() and str(bad) in caplog.text


def test_a_corrupt_episode_table_is_one_line_naming_it(tmp_path, capsys):
    run = tmp_path / "run"
    write_run(run, None)
    to_store(run)
    table = store_dir(run) / EPISODE_TABLE
    table.write_bytes(table.read_bytes()[:100])
    assert main(["report", str(run)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("uam-compare: error: ") and str(table) in err[0], err
    assert "truncated or corrupt" in err[0] and table.stat().st_size == 100  # left as it was


def test_a_store_from_before_the_newer_sensing_columns_reads_them_as_nan(tmp_path):
    """A store written before `est_nees_in_bounds` and the first-sensed columns existed still reads: those columns
    at NaN, every other one as stored."""
    episodes = [_episode(e, "ppo") for e in range(2)]
    _compacted(tmp_path, episodes)
    path = store_dir(tmp_path) / EPISODE_TABLE
    newer = ["est_nees_in_bounds", "unmapped_sensed", "unmapped_first_sensed_m_min", "unmapped_first_sensed_m_median"]
    pq.write_table(pq.read_table(path).drop_columns(newer), path)
    run = open_episodes(tmp_path)
    assert len(run.entries) == 2
    for saved, entry in zip(episodes, run.entries):
        got, want = run.metrics(entry), episode_metrics(saved)
        assert all(math.isnan(getattr(got, n)) for n in newer)
        assert _same(got, replace(want, **dict.fromkeys(newer, math.nan)))
        assert run.load(entry).meta == saved.meta
