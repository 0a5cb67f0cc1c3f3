"""Each decision's command, hold and observation go into the store on the decision's row and come back as recorded:
exactly as float32 with `--store full`, within the stated quanta at the control rate; an episode without them, or a
part written before they were stored, reads with none."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from compare.flying.episode_loop import ROTOR_SPEEDS, VELOCITY_YAW, DecisionRecord
from compare.results.metrics import episode_metrics
from compare.results.store import part_bytes, read_part, write_part
from compare.results.tables import (
    QUANTA,
    SAMPLE_SCHEMA_BEFORE_DECISIONS,
    episode_from_tables,
    episode_row,
    kept_rows,
    meta_from_row,
    samples_table,
)
from compare.results.trajectory import EpisodeKey, EpisodeMeta, SavedEpisode
from synthetic_run import GOAL, START, trajectory

PERIOD = 10  # physics steps per control period


def _episode(with_decisions: bool = True) -> SavedEpisode:
    """A synthetic flight deciding every control period: rotor speeds at even decisions (held 1), velocity and
    heading at odd ones (held 1), observations of 7 values at every third decision."""
    traj = trajectory(601, 1.2, 5.0, 1.0, "success", 3, shaft_power=True)
    t = traj.t_s[:-1:PERIOD]
    rng = np.random.default_rng(5)
    kinds = tuple(ROTOR_SPEEDS if i % 2 == 0 else VELOCITY_YAW for i in range(len(t)))
    commands = tuple(600.0 + 50.0 * rng.random(4) if k == ROTOR_SPEEDS else np.append(3.0 * rng.standard_normal(3),
                                                                                      rng.uniform(-3.1, 3.1))
                     for k in kinds)
    observations = tuple(rng.uniform(-1.0, 1.0, 7) if i % 3 == 0 else None for i in range(len(t)))
    record = DecisionRecord(kinds, commands, np.ones(len(t), np.int64), observations)
    traj = replace(traj, decision_t_s=t, compute_s=np.full(len(t), 1e-3),
                   decisions=record if with_decisions else None)
    meta = EpisodeMeta(EpisodeKey("toy-quad", 0, "mixed", 0), "toy", "small_quad", START, GOAL, 3.0, 60.0, 0.42, 4,
                       1234.5, "success", 0.0, "synthetic success")
    return SavedEpisode(meta, traj)


def _round_trip(saved: SavedEpisode, mode: str, path: Path) -> DecisionRecord | None:
    rows = kept_rows(saved.trajectory, mode, PERIOD)
    data = part_bytes(episode_row(saved.meta, episode_metrics(saved), None, mode, len(rows)),
                      samples_table(saved.meta.key, saved.trajectory, 4, mode, PERIOD))
    row, samples = read_part(write_part(path, data))
    return episode_from_tables(meta_from_row(row), samples, with_decisions=True).trajectory.decisions


def test_full_rate_keeps_every_decision_as_float32(tmp_path: Path) -> None:
    saved = _episode()
    got, want = _round_trip(saved, "full", tmp_path / "p.parquet"), saved.trajectory.decisions
    assert got is not None and want is not None
    assert got.kinds == want.kinds and got.hold_periods.tolist() == want.hold_periods.tolist()
    for a, b in zip(got.commands, want.commands):
        np.testing.assert_array_equal(a, b.astype(np.float32))
    for a, b in zip(got.observations, want.observations):
        assert (a is None) == (b is None)
        if b is not None:
            np.testing.assert_array_equal(a, b.astype(np.float32))


def test_control_rate_rounds_each_command_to_its_kind_s_quantum(tmp_path: Path) -> None:
    saved = _episode()
    got, want = _round_trip(saved, "control", tmp_path / "p.parquet"), saved.trajectory.decisions
    assert got is not None and want is not None and got.kinds == want.kinds
    for kind, a, b in zip(want.kinds, got.commands, want.commands):
        steps = ([QUANTA["rotors"]] * 4 if kind == ROTOR_SPEEDS
                 else [QUANTA["velocity"]] * 3 + [QUANTA["heading"]])
        half = 0.5 * 2.0 ** -np.array(steps, float)
        assert np.all(np.abs(a - b) <= half), (kind, a - b)  # grid values this size are exact in float32
        assert np.all(np.round(a * 2.0 ** np.array(steps)) == a * 2.0 ** np.array(steps))  # on the grid
    for a, b in zip(got.observations, want.observations):
        assert (a is None) == (b is None)
        if b is not None:
            assert np.max(np.abs(a - b)) <= 0.5 * 2.0 ** -QUANTA["observation"]


def test_an_episode_without_them_and_an_older_part_read_with_none(tmp_path: Path) -> None:
    assert _round_trip(_episode(with_decisions=False), "control", tmp_path / "a.parquet") is None
    saved = _episode()
    rows = kept_rows(saved.trajectory, "control", PERIOD)
    row = episode_row(saved.meta, episode_metrics(saved), None, "control", len(rows))
    older = samples_table(saved.meta.key, saved.trajectory, 4, "control", PERIOD).select(
        SAMPLE_SCHEMA_BEFORE_DECISIONS.names)
    back_row, back = read_part(write_part(tmp_path / "b.parquet", part_bytes(row, older)))
    assert back.column("action").null_count == back.num_rows  # upgraded: the columns there, null
    assert episode_from_tables(meta_from_row(back_row), back, with_decisions=True).trajectory.decisions is None
    assert episode_from_tables(meta_from_row(row), samples_table(saved.meta.key, saved.trajectory, 4, "control", PERIOD)
                               ).trajectory.decisions is None  # read only when asked


def test_commands_of_another_count_than_the_decisions_are_refused() -> None:
    saved = _episode()
    d = saved.trajectory.decisions
    assert d is not None
    short = replace(saved.trajectory, decisions=replace(d, commands=d.commands[:-1], kinds=d.kinds[:-1]))
    with pytest.raises(ValueError, match="recorded commands for"):
        samples_table(saved.meta.key, short, 4, "control", PERIOD)


def test_only_decision_rows_hold_a_command() -> None:
    saved = _episode()
    table = samples_table(saved.meta.key, saved.trajectory, 4, "control", PERIOD)
    decided = table.column("decision_t_s").is_valid()
    for name in ("action_kind", "action", "action_hold_periods"):
        assert table.column(name).is_valid().equals(decided), name
    assert table.column("observation").null_count == table.num_rows - (len(saved.trajectory.decision_t_s) + 2) // 3
    assert isinstance(table.column("action").type, pa.ListType)
