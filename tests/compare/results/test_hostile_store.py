"""Hostile run stores: rows are checked before they are believed (by `run --resume` too), one bad episode costs only
itself (and is named on stderr), a FIFO is never opened, a flight is read with a bounded number of samples, and a
link planted inside a run folder (a folder of it, its store) is never followed by a writer or a reader.

The stores are a real run's (the tiny scenario flown by the potential field with seeds 0 and 1: two rows, two
flights in one samples file), rewritten with pyarrow as a hostile or careless hand would. Cases go through
`compare.cli.main` where a command reaches them, else through `compare.results.episodes`.
"""
from __future__ import annotations

import json
import logging
import os
import shutil
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import compare.results.episodes as episodes_module
from cli_checks import error_line, fails, snapshot
from compare.cli import main
from compare.results.episodes import open_episodes
from compare.results.store import ROW_GROUP_ROWS, WRITE_OPTIONS, compact
from run_data import TINY
from synthetic_run import to_store, write_run

FLY = ["run", str(TINY), "--pilots", "apf", "--pilot", "apf", "--seeds", "0,1", "--videos", "none", "--no-progress"]
S0, S1 = "tiny__ep000__apf__s0", "tiny__ep000__apf__s1"


@pytest.fixture(scope="module")
def flown_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny scenario flown with seeds 0 and 1, compacted into one samples file."""
    out = tmp_path_factory.mktemp("flown") / "run"
    assert main([*FLY, "--out", str(out)]) == 0
    return out


@pytest.fixture
def run(flown_run: Path, tmp_path: Path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(flown_run, out)
    return out


def _table(run: Path) -> Path:
    return run / "store" / "episodes.parquet"


def _samples(run: Path) -> Path:
    (path,) = sorted((run / "store").glob("samples-*.parquet"))
    return path


def _rows(run: Path) -> list[dict[str, Any]]:
    return pq.read_table(_table(run)).to_pylist()


def _write_rows(run: Path, rows: list[dict[str, Any]]) -> None:
    schema = pq.read_schema(_table(run))
    pq.write_table(pa.Table.from_pylist(rows, schema=schema), _table(run))


def _set_samples(run: Path, column: str, first: int, end: int, value: float) -> None:
    """Samples rows first..end-1 of `column` set to `value`."""
    table = pq.read_table(_samples(run))
    i = table.schema.get_field_index(column)
    values = table.column(column).to_numpy().copy()
    values[first:end] = value
    pq.write_table(table.set_column(i, table.schema.field(i), pa.array(values, table.schema.field(i).type)),
                   _samples(run), row_group_size=ROW_GROUP_ROWS, **WRITE_OPTIONS)


def _warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def _page_cells(page: Path) -> list[str]:
    data = page.read_text(encoding="utf-8").split('<script type="application/json" id="uam-data">')[1]
    return [g["spec"] for g in json.loads(data.split("</script>")[0])["groups"]]


# ---- 1: a row is believed only as far as it is checked -------------------------------------------------------
def test_rows_pointing_at_each_others_samples_are_refused(run: Path, tmp_path: Path, capsys: pytest.CaptureFixture,
                                                          caplog: pytest.LogCaptureFixture) -> None:
    """Seed 0's row points at seed 1's samples and the other way round: neither flight is drawn as the other's;
    each is skipped naming the table, the row and the column that disagrees."""
    rows = _rows(run)
    for k in ("row_start", "samples"):
        rows[0][k], rows[1][k] = rows[1][k], rows[0][k]
    _write_rows(run, rows)
    assert main(["view", str(run), "--out", str(tmp_path / "v.html")]) == 2  # nothing left to show
    err = capsys.readouterr().err
    assert "no readable saved episodes" in error_line(err)
    table = str(_table(run))
    warned = _warnings(caplog)
    assert any(table in w and f"row 0 ({S0})" in w and "seed 1, its row says 0" in w for w in warned), warned
    assert any(table in w and f"row 1 ({S1})" in w and "seed 0, its row says 1" in w for w in warned), warned


def test_rows_of_cells_never_flown_are_skipped_in_one_line(run: Path, caplog: pytest.LogCaptureFixture) -> None:
    rows = _rows(run)
    _write_rows(run, rows + [{**rows[0], "seed": s} for s in (7, 8, 9)])  # run.json plans seeds 0 and 1
    assert main(["report", str(run)]) == 0
    lines = [w for w in _warnings(caplog) if "does not plan" in w]
    assert len(lines) == 1 and str(_table(run)) in lines[0] and "rows 2, 3 and 4" in lines[0], lines
    with (run / "metrics.csv").open() as f:
        assert [line.split(",")[3] for line in f.read().splitlines()[1:]] == ["0", "1"]


def test_a_table_far_larger_than_the_run_is_refused_unread(run: Path, monkeypatch: pytest.MonkeyPatch,
                                                           capsys: pytest.CaptureFixture) -> None:
    rows = _rows(run)
    _write_rows(run, rows + [{**rows[0], "seed": 100 + s} for s in range(5_000)])
    read: list[int] = []
    real = pq.ParquetFile.read

    def spy(self: pq.ParquetFile, *args: object, **kwargs: object) -> pa.Table:
        read.append(self.metadata.num_rows)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(pq.ParquetFile, "read", spy)
    episodes = open_episodes(run)
    assert episodes.entries == ()
    (bad,) = episodes.unreadable
    assert bad.path == _table(run) and "5,002 rows" in bad.reason and "refused unread" in bad.reason
    before = (run / "metrics.csv").read_bytes()
    assert main(["report", str(run)]) == 2
    assert "no readable saved episodes" in error_line(capsys.readouterr().err)
    assert (run / "metrics.csv").read_bytes() == before
    assert 5_002 not in read  # the table's footer read, its rows never


def test_a_cell_held_twice_is_read_from_neither_row(run: Path) -> None:
    """Compaction never writes a cell twice; which of two rows is the flight cannot be told: neither is read, both
    are named (and `run --resume` flies the cell again)."""
    rows = _rows(run)
    _write_rows(run, [*rows, dict(rows[0])])
    episodes = open_episodes(run)
    assert [e.key.stem for e in episodes.entries] == [S1]
    (bad,) = episodes.unreadable
    assert str(_table(run)) in bad.reason and "rows 0 and 2" in bad.reason and S0 in bad.reason
    assert {k.seed for k in episodes_module.kept_keys(run)} == {1}


# ---- 2: one flight that cannot be drawn costs only itself ----------------------------------------------------
@pytest.mark.parametrize("value, why", [(float("nan"), "finite position"), (float("inf"), "finite position"),
                                        (1e300, "from its start")])
def test_a_flight_that_cannot_be_drawn_is_left_out_by_name(run: Path, tmp_path: Path, value: float, why: str,
                                                            caplog: pytest.LogCaptureFixture) -> None:
    """Seed 1's positions NaN, inf or 1e300 m throughout: the viewer, the animation and the report leave that
    flight out with a warning naming it, and draw the rest."""
    row = _rows(run)[1]
    _set_samples(run, "x_m", row["row_start"], row["row_start"] + row["samples"], value)
    page = tmp_path / "v.html"
    assert main(["view", str(run), "--out", str(page)]) == 0
    (line,) = _warnings(caplog)
    assert _samples(run).name in line and S1 in line and why in line
    assert _page_cells(page) == ["tiny:0:0"]
    assert main(["animate", str(run), "--all", "--format", "gif", "--fps", "2", "--duration", "1",
                 "--size", "320x240", "--no-progress"]) == 0
    assert sorted(p.name for p in (run / "videos").iterdir()) == ["tiny__ep000__s0.gif"]
    assert main(["report", str(run)]) == 0


# ---- 3: a FIFO named like a store's file is never opened -----------------------------------------------------
@pytest.mark.parametrize("command", [["report"], ["view"]])
def test_a_fifo_named_like_a_samples_file_is_never_opened(run: Path, tmp_path: Path, command: list[str],
                                                          capsys: pytest.CaptureFixture,
                                                          caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO)  # (the report's pages log what they leave out at INFO)
    fifo = _samples(run)
    fifo.unlink()
    os.mkfifo(fifo)
    opened: list[str] = []
    stop = threading.Event()

    def writer() -> None:  # opens without waiting whenever a reader has the FIFO open (or waits in open)
        while not stop.is_set():
            try:
                fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
            except OSError:  # no reader
                stop.wait(0.005)
                continue
            opened.append(command[0])
            os.close(fd)  # the reader sees an empty file rather than waiting for ever

    thread = threading.Thread(target=writer, daemon=True)
    thread.start()
    try:
        code = main([command[0], str(run), *(["--out", str(tmp_path / "v.html")] if command == ["view"] else [])])
    finally:
        stop.set()
        thread.join()
    err = capsys.readouterr().err
    assert code in (0, 2) and "Traceback" not in err, err
    assert opened == [], f"{command[0]} opened the FIFO"
    assert fifo.name in err, err  # named in the last line (and on the report's failures page)
    assert any(str(fifo) in m and "not a regular file" in m for m in caplog.messages), caplog.messages


# ---- 4: a flight is read with a bounded number of samples -----------------------------------------------------
def test_a_flight_of_many_samples_is_thinned_as_it_is_read(run: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Seed 1's flight inflated to 70,000 samples in one row group (larger than this tool writes: read in
    batches): read as about MAX_SAMPLES_READ of them, keeping its last sample and its least clearance."""
    rows = _rows(run)
    table = pq.read_table(_samples(run))
    first, n = rows[1]["row_start"], rows[1]["samples"]
    flight = table.slice(first, n)
    big = pa.concat_tables([flight] * (70_000 // n + 1)).slice(0, 70_000)
    big = big.set_column(big.schema.get_field_index("t_s"), big.schema.field("t_s"), pa.array(np.arange(70_000) * 0.02))
    clearance = big.column("clearance_m").to_numpy().copy()
    clearance[12_345] = -1.5  # the least clearance, at a sample no thinning keeps by its index
    big = big.set_column(big.schema.get_field_index("clearance_m"), big.schema.field("clearance_m"),
                         pa.array(clearance, pa.float32()))
    pq.write_table(pa.concat_tables([table.slice(0, first), big]).combine_chunks(), _samples(run),
                   row_group_size=70_000 + first, **WRITE_OPTIONS)
    rows[1]["samples"] = 70_000
    _write_rows(run, rows)
    monkeypatch.setattr(episodes_module, "MAX_SAMPLES_READ", 2_000, raising=False)
    episodes = open_episodes(run)
    saved = episodes.load(episodes.entries[1])
    t = saved.trajectory.t_s
    assert 2_000 <= len(t) <= 2_010
    assert t[-1] == pytest.approx(69_999 * 0.02) and np.all(np.diff(t) > 0)
    assert float(np.min(saved.trajectory.clearance_m)) == -1.5
    assert len(episodes.load(episodes.entries[0]).trajectory.t_s) == rows[0]["samples"]  # short: read whole


# ---- a part compacted while a reader holds its listing ------------------------------------------------------------
@pytest.fixture
def parts_run(tmp_path: Path) -> Path:
    """A synthetic run whose four episodes are parts, not compacted yet (a run still flying)."""
    out = tmp_path / "parts"
    write_run(out, None)
    to_store(out, compacted=False)
    return out


def test_a_part_compacted_after_listing_is_read_from_its_samples_file(parts_run: Path) -> None:
    episodes = open_episodes(parts_run)
    assert len(episodes.entries) == 4 and all(e.part for e in episodes.entries)
    compact(parts_run)  # the run compacts: every part is now in a samples file, and gone
    assert not list((parts_run / "store" / "parts").glob("*.parquet"))
    for e in episodes.entries:
        assert episodes.load(e).meta.key == e.key


def test_a_part_compacted_while_listing_is_found_in_the_table(parts_run: Path,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    real = episodes_module.part_files

    def listed_then_compacted(run_dir: Path) -> list[Path]:
        listed = real(run_dir)
        compact(run_dir)
        return listed

    monkeypatch.setattr(episodes_module, "part_files", listed_then_compacted)
    episodes = open_episodes(parts_run)
    assert episodes.unreadable == ()
    assert len(episodes.entries) == 4 and not any(e.part for e in episodes.entries)


# ---- 5: a link planted inside a run folder is never followed -------------------------------------------------
def _user_folder(tmp_path: Path) -> tuple[Path, dict[str, str]]:
    """A user's folder elsewhere (one file of theirs), and its snapshot."""
    home = tmp_path / "home"
    home.mkdir()
    (home / "notes.txt").write_text("mine")
    return home, snapshot(home)


@pytest.mark.parametrize("link, argv", [
    ("maps", [*FLY, "--resume"]),  # resume rewrites maps/tiny.yaml
    ("figures", ["report"]),  # the report's pages as PNGs
    ("videos", ["animate", "--format", "gif", "--fps", "2", "--duration", "1", "--size", "320x240", "--no-progress"]),
    ("failed", ["view"]),  # a reader too: nothing in a run folder is read through a link
])
def test_a_folder_link_planted_in_a_run_folder_is_refused(run: Path, tmp_path: Path, capsys: pytest.CaptureFixture,
                                                          link: str, argv: list[str]) -> None:
    """`RUN/<folder>` a link to a user's folder: every command refuses the run in one line naming the link, and
    nothing is written there (before: the maps, the report's PNGs and the video were written into it)."""
    home, before = _user_folder(tmp_path)
    if (run / link).exists():
        shutil.copytree(run / link, home, dirs_exist_ok=True)
        shutil.rmtree(run / link)
        before = snapshot(home)
    (run / link).symlink_to(home, target_is_directory=True)
    if argv[0] == "run":
        argv = [*argv, "--out", str(run)]
    else:
        argv = [argv[0], str(run), *argv[1:], *(["--out", str(tmp_path / "v.html")] if argv[0] == "view" else [])]
    assert main(argv) == 2
    line = error_line(capsys.readouterr().err)
    assert f"{run / link}: a symbolic link inside {run}" in line, line
    assert snapshot(home) == before


def test_a_writer_makes_its_folders_without_following_a_link(run: Path, tmp_path: Path) -> None:
    """The one helper every writer goes through: a folder it makes below the run folder is made there, and a link
    on the way (here `store/parts`, planted while a run flies) is refused before anything is written."""
    from compare.results.store import part_path, write_part
    from compare.results.trajectory import EpisodeKey
    from uam_fdm.files.atomic import write_text_atomic
    from uam_fdm.files.inside import LinkInFolder

    home, before = _user_folder(tmp_path)
    new = write_text_atomic(run / "maps" / "prior" / "tiny.yaml", "x", root=run)
    assert new.read_text() == "x" and not (run / "maps" / "prior").is_symlink()
    shutil.rmtree(run / "store" / "parts", ignore_errors=True)
    (run / "store" / "parts").symlink_to(home, target_is_directory=True)
    key = EpisodeKey("tiny", 0, "apf", 5)
    with pytest.raises(LinkInFolder, match="store/parts: a symbolic link inside"):
        write_part(part_path(run, key), b"part", root=run)
    assert snapshot(home) == before


# ---- 6: a store that is another run's is neither compacted nor read ------------------------------------------
@pytest.mark.parametrize("command", ["report", "view"])
def test_a_store_linked_to_another_run_is_refused_before_any_work(parts_run: Path, run: Path, tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture, command: str) -> None:
    """`RUN/store -> OTHER/store`, OTHER a run still flying (its parts not compacted): `report RUN` would compact
    OTHER's store without OTHER's lock, `view RUN` draw OTHER's flights as RUN's. Both refuse in one line naming
    the link; OTHER is left byte for byte."""
    shutil.rmtree(run / "store")
    (run / "store").symlink_to(parts_run / "store", target_is_directory=True)
    before = snapshot(parts_run)
    argv = [command, str(run), *(["--out", str(tmp_path / "v.html")] if command == "view" else [])]
    code = main(argv)
    assert snapshot(parts_run) == before
    assert code == 2 and f"{run / 'store'}: a symbolic link inside {run}" in error_line(capsys.readouterr().err)


# ---- 7: report names each flight it cannot draw on stderr --------------------------------------------------
def test_report_warns_once_for_each_flight_it_cannot_draw(run: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Seed 1's positions NaN: `report` leaves it out of its pages and says so in one warning line naming the file,
    the cell and why (before: only on the report's failures page and at INFO)."""
    row = _rows(run)[1]
    _set_samples(run, "x_m", row["row_start"], row["row_start"] + row["samples"], float("nan"))
    assert main(["report", str(run)]) == 0
    lines = [w for w in _warnings(caplog) if S1 in w]
    assert len(lines) == 1, lines
    assert _samples(run).name in lines[0] and "finite position" in lines[0]


# ---- 8: run --resume checks the store's rows against run.json before flying -----------------------------------
@pytest.mark.parametrize("extra, expected", [
    (lambda rows: [{**rows[0], "seed": s} for s in (7, 8)], ("rows 2 and 3 hold cells run.json does not plan",
                                                             "tiny__ep000__apf__s7")),
    (lambda rows: [dict(rows[0])], ("rows 0 and 2 hold one cell", S0)),
])
def test_resume_refuses_a_store_of_rows_the_run_does_not_plan(run: Path, capsys: pytest.CaptureFixture,
                                                              extra: Any, expected: tuple[str, ...]) -> None:
    """Rows of seeds run.json does not plan, or a cell held twice: `run --resume` refuses in one line naming the
    table and the first bad rows, and writes nothing (before: it flew, and compaction kept the rows)."""
    rows = _rows(run)
    _write_rows(run, rows + extra(rows))
    fails([*FLY, "--resume", "--out", str(run)], capsys, run, f"{run}: cannot resume: {_table(run)}", *expected)
