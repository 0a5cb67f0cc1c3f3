"""`uam-compare export --rerun`: a run's flights and a policy's training flights as a Rerun recording,
read back with Rerun's own reader (rerun-sdk, the `rerun` extra, in the `test` extra so CI runs these)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from compare.cli import main
from compare.playback.flights import flight_groups
from rl.policies.flights import TrainingFlights
from synthetic_run import write_run

rerun = pytest.importorskip("rerun", reason="rerun-sdk is not installed (pip install -e '.[test]')")


def _chunks(path: Path) -> dict[str, list]:
    """Entity path -> its chunks' record batches, read with Rerun's RrdReader."""
    from rerun.chunk import RrdReader

    out: dict[str, list] = {}
    for chunk in RrdReader(str(path)).stream():
        out.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    return out


def _column(batches: list, name: str) -> list:
    return [v for b in batches for v in b.column(name).to_pylist()]


def test_training_flights_read_back(tiny_flights_policy, tmp_path, capsys):
    out = tmp_path / "training.rrd"
    assert main(["export", str(tiny_flights_policy), "--rerun", "--out", str(out)]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    chunks = _chunks(out)
    flights = TrainingFlights.open(tiny_flights_policy)
    city = flights.tasks.cities[flights.tasks.tasks[1].city]
    boxes = _column(chunks["/tasks/task_1/city"], "Boxes3D:centers")
    assert len(boxes[0]) == len(city.boxes)
    f = flights.checkpoint(512).flights[1]
    entity = "/tasks/task_1/step_00000000512"
    pos = np.array([p[0] for p in _column(chunks[f"{entity}/vehicle"], "Points3D:positions")])
    assert np.array_equal(pos, f.pos_m)  # float32, written and read unchanged
    t = _column(chunks[f"{entity}/vehicle"], "t")
    assert len(t) == len(f.pos_m)
    clear = [v[0] for v in _column(chunks[f"{entity}/clearance_m"], "Scalars:scalars")]
    assert np.allclose(clear, f.clearance_m, atol=1e-5)
    assert f"{entity}/speed_m_s" in chunks and f"{entity}/path" in chunks and "/tasks/task_0/goal" in chunks
    assert sum(k.endswith("/vehicle") for k in chunks) == len(flights.steps) * len(flights.tasks.tasks)


def test_run_flights_read_back(tmp_path, capsys):
    run_dir = tmp_path / "run"
    write_run(run_dir, None)
    assert main(["export", str(run_dir), "--rerun"]) == 0
    out = run_dir / "flights.rrd"
    assert capsys.readouterr().out.strip() == str(out)
    chunks = _chunks(out)
    for g in flight_groups(run_dir):
        assert f"/cells/{g.stem}/city" in chunks
        for p in g.flights:
            base = f"/cells/{g.stem}/{p.pilot}"
            pos = np.array([v[0] for v in _column(chunks[f"{base}/vehicle"], "Points3D:positions")])
            last = np.asarray(p.episode.trajectory.states, float)[-1, 0:3]
            assert np.allclose(pos[-1], last, atol=1e-3) and len(pos) >= 2
            assert f"{base}/clearance_m" in chunks and f"{base}/speed_m_s" in chunks
    assert main(["export", str(run_dir), "--rerun"]) == 0  # the run's own default file: rewritten
    assert main(["export", str(run_dir), "--rerun", "--out", str(out)]) == 2  # a file named: never unasked
    assert "the file exists" in capsys.readouterr().err


def test_refusals_are_one_line(tiny_flights_policy, tmp_path, capsys, monkeypatch):
    assert main(["export", str(tmp_path), "--rerun"]) == 2
    assert "neither a run folder" in capsys.readouterr().err
    assert main(["export", str(tiny_flights_policy), "--out", str(tmp_path / "default.rrd")]) == 0  # Rerun: the default
    assert (tmp_path / "default.rrd").is_file()
    monkeypatch.setitem(sys.modules, "rerun", None)  # rerun-sdk not installed: `import rerun` fails
    assert main(["export", str(tiny_flights_policy), "--rerun", "--out", str(tmp_path / "x.rrd")]) == 2
    err = capsys.readouterr().err.strip()
    assert "uam-compare[rerun]" in err and "pip install -e '.[rerun]'" in err  # an installed package, and a clone
    assert err.count("\n") == 0 and not (tmp_path / "x.rrd").exists()
