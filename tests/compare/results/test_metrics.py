"""Episode metrics, metrics.csv and summary.json, on hand-built trajectories with hand-computed numbers."""
from __future__ import annotations

import json
import math
import os
import random
from dataclasses import astuple

import numpy as np
import pytest

from compare.flying.episode_loop import Trajectory
from compare.results import metrics as M
from compare.results import summary as S
from compare.results.metrics import (
    CLEARANCE_THRESHOLDS_M,
    COLUMNS,
    EpisodeMetrics,
    episode_metrics,
    read_metrics_csv,
    write_metrics_csv,
)
from compare.results.stats import MIN_INTERVAL_N
from compare.results.summary import (
    BootstrapConfig,
    Stat,
    Summary,
    pilots_table,
    read_summary_json,
    summarize,
    summarize_run,
    summary_to_json,
    write_summary_json,
)
from compare.results.trajectory import EpisodeKey, EpisodeMeta, SavedEpisode, load_episode, save_episode
from planners.report import ClassicalReport
from uam_fdm.files import atomic

N_ROTORS = 4
DT = 0.002

# A polyline 3 m east, 4 m north, 12 m up: 19 m flown, 13 m start to goal.
POLYLINE = [(0.0, 0.0, 10.0), (3.0, 0.0, 10.0), (3.0, 4.0, 10.0), (3.0, 4.0, 22.0)]


def make_episode(positions=POLYLINE, clearance=(0.5, 1.5, 4.0, 1.0), compute_s=(0.001, 0.003, 0.002),
                 outcome="success", pilot="rrt_mpc", plan_time_s=0.7, energy_J=1234.5,
                 start=(0.0, 0.0, 10.0), goal=(3.0, 4.0, 22.0), scenario="town", episode=0, seed=0,
                 t_s=None, report=None) -> SavedEpisode:
    pos = np.asarray(positions, float)
    m = pos.shape[0]
    states = np.zeros((m, 13 + N_ROTORS))
    states[:, 0:3] = pos
    states[:, 6] = 1.0                                   # identity quaternion
    t = DT * np.arange(m) if t_s is None else np.asarray(t_s, float)
    compute = np.asarray(compute_s, float)
    traj = Trajectory(t_s=t, states=states, rotor_commands=np.full((m, N_ROTORS), 400.0),
                      wind_enu_m_s=np.zeros((m, 3)), clearance_m=np.asarray(clearance, float),
                      decision_t_s=0.02 * np.arange(compute.size), compute_s=compute, energy_J=energy_J,
                      outcome=outcome, plan_time_s=plan_time_s, detail="hand-made")
    meta = EpisodeMeta(key=EpisodeKey(scenario, episode, pilot, seed), map_name="town-map",
                       vehicle="small_quad", start_m=tuple(start), goal_m=tuple(goal), goal_radius_m=1.0,
                       timeout_s=60.0, collision_radius_m=0.3, n_rotors=N_ROTORS, energy_J=energy_J,
                       outcome=outcome, plan_time_s=plan_time_s, detail="hand-made", report=report)
    return SavedEpisode(meta, traj)


def row(pilot="ppo", episode=0, seed=0, scenario="town", success=True, **values) -> EpisodeMetrics:
    """A metrics row with defaults; `values` override numeric fields."""
    outcome = values.pop("outcome", "success" if success else "timeout")
    base = {"scenario": scenario, "episode": episode, "method": pilot, "seed": seed, "map": "town-map",
            "vehicle": "small_quad", "outcome": outcome, "success": success,
            "collision": outcome == "collision", "failure_reason": "" if success else outcome,
            "min_clearance_m": 3.0, "time_below_2m_s": 0.0, "time_below_5m_s": 1.0, "time_s": 20.0,
            "path_length_m": 100.0, "straight_line_m": 90.0, "spl": 0.9 if success else 0.0,
            "energy_kj": 50.0, "compute_ms_mean": 1.0, "compute_ms_max": 2.0,
            "plan_time_s": math.nan if pilot == "ppo" else 0.5}
    base.update(values)
    return EpisodeMetrics(**base)


def same(a: EpisodeMetrics, b: EpisodeMetrics) -> bool:
    """Field-by-field equality where NaN equals NaN."""
    return [repr(v) for v in astuple(a)] == [repr(v) for v in astuple(b)]


# --------------------------------------------------------------------------------------------------
# One episode
# --------------------------------------------------------------------------------------------------

def test_metrics_of_a_known_polyline():
    m = episode_metrics(make_episode())
    assert (m.scenario, m.episode, m.method, m.seed) == ("town", 0, "rrt_mpc", 0)
    assert (m.map, m.vehicle, m.outcome) == ("town-map", "small_quad", "success")
    assert m.success is True and m.collision is False and m.failure_reason == ""
    assert m.path_length_m == pytest.approx(19.0)
    assert m.straight_line_m == pytest.approx(13.0)
    assert m.spl == pytest.approx(13.0 / 19.0)
    assert m.min_clearance_m == 0.5                       # row 0 counts for the minimum ...
    assert m.time_below_2m_s == pytest.approx(2 * DT)     # ... but not for time below (samples 1, 3)
    assert m.time_below_5m_s == pytest.approx(3 * DT)     # samples 1, 2, 3
    assert m.time_s == pytest.approx(3 * DT)
    assert m.energy_kj == pytest.approx(1.2345)
    assert m.compute_ms_mean == pytest.approx(2.0)
    assert m.compute_ms_max == pytest.approx(3.0)
    assert m.plan_time_s == 0.7
    assert all(type(getattr(m, f)) is float for f in COLUMNS if M._KINDS[f] == "float")


TRACKER = {"mpc_solve_ms_median": 1.25, "mpc_solve_ms_p95": 2.5, "mpc_failures": 1, "replans_tracking": 0,
           "replans_clearance": 2, "tracking_rms_m": 0.125, "tracking_max_m": 0.75, "planner_margin_m": 1.5,
           "mpc_margin_m": 0.75, "mpc_statuses": {"ok": 3}, "margin_source": "table", "replans": 3,
           "planner_margin_floor_m": 1.0, "planner_attempts": 2, "planner_step": "rrtconnect, speed margins",
           "clearance_over_margin_min": 0.625, "replans_blocked": 1, "replans_uncertainty": 0, "hover_holds": 0,
           "replan_ms_median": 120.0, "replan_ms_p95": 300.0, "map_update_ms_median": 8.5,
           "uncertainty_margin_max_m": 0.875, "sensed_obstacles": 4, "cleared_prior_parts": 1,
           "improvements_tried": 3, "improvements_taken": 1, "planner_wall_caps": 1}


def _save_with_extra(tmp_path, extra: dict, pilot: str = "rrt_mpc") -> SavedEpisode:
    """An episode file whose metadata's "extra" is `extra`, as written on disk, read back."""
    saved = make_episode(pilot=pilot)
    path = save_episode(tmp_path / "ep.npz", saved.meta, saved.trajectory)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(str(arrays.pop("meta_json")))
    header["meta"]["extra"] = extra
    np.savez_compressed(path, meta_json=np.array(json.dumps(header)), **arrays)
    return load_episode(path)


def test_tracker_columns_come_from_the_episode_report(tmp_path):
    report = ClassicalReport.from_json({**TRACKER, "plan_time_s": 0.7, "replan_time_s": 0.2, "mpc_solves": 3})
    assert isinstance(report, ClassicalReport) and report.replans_clearance == 2
    m = episode_metrics(make_episode(report=report))
    columns = (*M.TRACKER_METRICS, *M.MAPPING_METRICS)
    assert {k: getattr(m, k) for k in columns} == {k: float(TRACKER[k]) for k in columns}
    # a pilot without a tracker (ppo): NaN in every tracker column, finite elsewhere
    ppo = episode_metrics(make_episode(pilot="ppo", plan_time_s=0.0))
    assert all(math.isnan(getattr(ppo, k)) for k in M.TRACKER_METRICS)
    # the report is saved in the episode file and read back as the same typed report
    saved = make_episode(report=report)
    loaded = load_episode(save_episode(tmp_path / "report.npz", saved.meta, saved.trajectory))
    assert loaded.meta.report == report
    # NaN saved as null (no decision flown) reads back as NaN
    empty = episode_metrics(_save_with_extra(tmp_path, {"tracker": {**TRACKER, "tracking_rms_m": None}}))
    assert math.isnan(empty.tracking_rms_m) and empty.replans_clearance == 2.0
    # an episode saved before the report: its old top-level counters, NaN for the rest
    old = episode_metrics(_save_with_extra(tmp_path, {"replans": 1, "mpc_failures": 0, "mpc_solve_ms_median": 1.5}))
    assert (old.replans_tracking, old.mpc_failures, old.mpc_solve_ms_median) == (1.0, 0.0, 1.5)
    assert math.isnan(old.replans_clearance) and math.isnan(old.planner_margin_m)
    assert math.isnan(old.planner_attempts) and math.isnan(old.clearance_over_margin_min)
    # through metrics.csv and back, exactly
    path = write_metrics_csv([m, ppo], tmp_path / "metrics.csv")
    back = read_metrics_csv(path)
    assert same(back[0], ppo) and same(back[1], m)


def test_a_metrics_csv_without_the_tracker_columns_still_reads(tmp_path):
    lines = write_metrics_csv([row("rrt_mpc")], tmp_path / "new.csv").read_text().splitlines()
    # the columns older files lack are last, in the order they came (`planner_wall_caps` after the sensing ones)
    tracker = tuple(m for m in M.TRACKER_METRICS if m != "planner_wall_caps")
    later = (*tracker, "vehicle_fingerprint", "sensing", "map_error", *M.SENSING_METRICS, *M.MAPPING_METRICS,
             "planner_wall_caps")
    n = len(COLUMNS) - len(later)
    assert COLUMNS[n:] == later
    old = tmp_path / "old.csv"
    old.write_text("\n".join(",".join(line.split(",")[:n]) for line in lines) + "\n")
    (r,) = read_metrics_csv(old)
    assert r.planner_margin_m != r.planner_margin_m and r.plan_time_s == 0.5
    assert (r.sensing, r.map_error) == ("perfect", "exact") and math.isnan(r.gnss_availability)


def test_tracker_metrics_are_summarised_but_not_paired():
    rows = [row("rrt_mpc", episode=e, planner_margin_m=1.0 + e, replans_clearance=float(e)) for e in range(2)]
    rows += [row("ppo", episode=e) for e in range(2)]
    s = summarize(rows, resamples=50)
    assert s.pilots["rrt_mpc"].stats["planner_margin_m"].mean == 1.5
    assert s.pilots["rrt_mpc"].stats["replans_clearance"].n == 2
    assert s.pilots["ppo"].stats["planner_margin_m"].n == 0 and s.pilots["ppo"].stats["planner_margin_m"].mean is None
    (pair,) = s.paired
    assert pair.name == "ppo - rrt_mpc" and not set(M.TRACKER_METRICS) & set(pair.stats)


def test_threshold_fields_follow_the_constant():
    assert CLEARANCE_THRESHOLDS_M == (2.0, 5.0)
    assert [M.below_field(th) for th in CLEARANCE_THRESHOLDS_M] == ["time_below_2m_s", "time_below_5m_s"]
    assert all(M.below_field(th) in COLUMNS for th in CLEARANCE_THRESHOLDS_M)


def test_time_below_uses_the_physics_step_of_each_sample():
    clear = np.array([0.0, 1.0, 1.0, 3.0, 6.0, 1.9, 2.0])   # 2.0 is not below 2 m
    m = episode_metrics(make_episode(positions=[(0.0, 0.0, 10.0)] * 7, clearance=clear))
    assert m.time_below_2m_s == pytest.approx(3 * DT)
    assert m.time_below_5m_s == pytest.approx(5 * DT)


def test_spl_cases():
    # Reached the goal radius 0.8 m short of the goal: path 12.2 m < straight 13 m, SPL capped at 1.
    short = [(0.0, 0.0, 10.0), (0.0, 0.0, 16.0), (0.0, 0.0, 22.2)]
    m = episode_metrics(make_episode(positions=short, clearance=(5, 5, 5), goal=(0.0, 0.0, 23.0)))
    assert m.path_length_m == pytest.approx(12.2) and m.straight_line_m == pytest.approx(13.0)
    assert m.spl == 1.0
    # Straight flight: 1; a failure on the same path: 0.
    straight = [(0.0, 0.0, 10.0), (0.0, 0.0, 16.5), (0.0, 0.0, 23.0)]
    ok = episode_metrics(make_episode(positions=straight, clearance=(5, 5, 5), goal=(0.0, 0.0, 23.0)))
    assert ok.spl == pytest.approx(1.0)
    failed = episode_metrics(make_episode(positions=straight, clearance=(5, 5, 5), goal=(0.0, 0.0, 23.0),
                                          outcome="timeout"))
    assert failed.spl == 0.0 and not failed.success and failed.failure_reason == "timeout"


def test_collision_and_failure_reasons():
    m = episode_metrics(make_episode(clearance=(5.0, 3.0, 1.0, -0.1), outcome="collision"))
    assert m.collision and not m.success and m.failure_reason == "collision" and m.spl == 0.0
    assert m.min_clearance_m == -0.1
    for outcome in ("out_of_bounds", "nonfinite", "timeout", "planner_failure", "solver_failure"):
        m = episode_metrics(make_episode(outcome=outcome))
        assert m.outcome == m.failure_reason == outcome and not m.collision and not m.success
    with pytest.raises(ValueError, match=r"town__ep000__rrt_mpc__s0: unknown outcome 'crashed'"):
        episode_metrics(make_episode(outcome="crashed"))


def test_nonfinite_flight_ignores_nan_samples():
    pos = [(0.0, 0.0, 10.0), (1.0, 0.0, 10.0), (2.0, 0.0, 10.0), (np.nan, np.nan, np.nan)]
    m = episode_metrics(make_episode(positions=pos, clearance=(4.0, 3.0, 1.0, np.nan), outcome="nonfinite"))
    assert m.path_length_m == pytest.approx(2.0)           # the flight up to the blow-up
    assert m.min_clearance_m == 1.0
    assert m.time_below_2m_s == pytest.approx(DT)
    assert m.time_below_5m_s == pytest.approx(2 * DT)
    all_nan = episode_metrics(make_episode(positions=pos, clearance=(np.nan,) * 4, outcome="nonfinite"))
    assert math.isnan(all_nan.min_clearance_m) and all_nan.time_below_5m_s == 0.0


def test_no_decisions_and_plan_time_by_pilot():
    pf = episode_metrics(make_episode(positions=[(0.0, 0.0, 10.0)], clearance=(8.0,), compute_s=(),
                                      outcome="planner_failure", plan_time_s=2.5))
    assert math.isnan(pf.compute_ms_mean) and math.isnan(pf.compute_ms_max)
    assert pf.time_s == 0.0 and pf.path_length_m == 0.0 and pf.time_below_5m_s == 0.0
    assert pf.plan_time_s == 2.5
    assert math.isnan(episode_metrics(make_episode(pilot="ppo", plan_time_s=0.0)).plan_time_s)
    assert episode_metrics(make_episode(pilot="ppo", plan_time_s=0.1)).plan_time_s == 0.1
    assert episode_metrics(make_episode(pilot="rrt_mpc", plan_time_s=0.0)).plan_time_s == 0.0


def test_inconsistent_arrays_are_an_error():
    with pytest.raises(ValueError, match="town__ep000__rrt_mpc__s0"):
        episode_metrics(make_episode(clearance=(1.0, 2.0, 3.0)))


def test_saved_episode_round_trip_scores_the_same(tmp_path):
    saved = make_episode(pilot="ppo", plan_time_s=0.0, clearance=(0.5, 1.5, np.nan, 1.0))
    path = save_episode(tmp_path / "episodes" / f"{saved.meta.key.stem}.npz", saved.meta, saved.trajectory)
    loaded = load_episode(path)
    assert same(episode_metrics(loaded), episode_metrics(saved))
    m = episode_metrics(loaded)
    assert m.path_length_m == pytest.approx(19.0) and m.time_below_2m_s == pytest.approx(2 * DT)


def test_saved_shaft_power_round_trip_and_older_files(tmp_path):
    """The per-step shaft power is saved and read back exactly; a file without it (saved before it was recorded)
    reads as None, and a column of the wrong length is an error naming the file."""
    saved = make_episode()
    power = np.array([100.0, 101.5, 99.25, 120.0])
    with_power = SavedEpisode(saved.meta, Trajectory(**{**saved.trajectory.__dict__, "shaft_power_W": power}))
    path = save_episode(tmp_path / "new.npz", with_power.meta, with_power.trajectory)
    np.testing.assert_array_equal(load_episode(path).trajectory.shaft_power_W, power)
    old = save_episode(tmp_path / "old.npz", saved.meta, saved.trajectory)
    assert load_episode(old).trajectory.shaft_power_W is None
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    np.savez(tmp_path / "short.npz", **{**arrays, "shaft_power_W": power[:2]})
    with pytest.raises(ValueError, match=r"short\.npz: shaft_power_W has shape \(2,\)"):
        load_episode(tmp_path / "short.npz")


def test_episode_key_stem_parses_back():
    for key in (EpisodeKey("suburb-quad", 3, "ppo", 0), EpisodeKey("a__b", 120, "rrt_mpc", 4294967295)):
        assert EpisodeKey.from_stem(key.stem) == key
    for stem in ("notes", "town__ep7__ppo__s0", "town__ep007__ppo__sx", "town__ep007__s0"):
        assert EpisodeKey.from_stem(stem) is None, stem


# --------------------------------------------------------------------------------------------------
# metrics.csv
# --------------------------------------------------------------------------------------------------

def test_csv_columns_are_the_contract_order():
    assert COLUMNS == (
        "scenario", "episode", "method", "seed", "map", "vehicle", "outcome", "success", "collision",
        "failure_reason", "min_clearance_m", "time_below_2m_s", "time_below_5m_s", "time_s",
        "path_length_m", "straight_line_m", "spl", "energy_kj", "compute_ms_mean", "compute_ms_max",
        "plan_time_s", "mpc_solve_ms_median", "mpc_solve_ms_p95", "mpc_failures", "replans_tracking",
        "replans_clearance", "tracking_rms_m", "tracking_max_m", "planner_margin_m", "mpc_margin_m",
        "planner_margin_floor_m", "planner_attempts", "clearance_over_margin_min",
        "vehicle_fingerprint", "sensing", "map_error", "est_error_h_rms_m", "est_error_h_max_m", "est_error_v_rms_m",
        "est_error_v_max_m", "gnss_availability", "min_clearance_unmapped_m",
        "est_nees_in_bounds", "unmapped_sensed", "unmapped_first_sensed_m_min", "unmapped_first_sensed_m_median",
        "replans_blocked", "replans_uncertainty", "hover_holds", "replan_ms_median", "replan_ms_p95",
        "map_update_ms_median", "uncertainty_margin_max_m", "sensed_obstacles", "cleared_prior_parts",
        "improvements_tried", "improvements_taken", "planner_wall_caps")


def test_csv_round_trip_is_exact_and_sorted(tmp_path):
    rows = [row("rrt_mpc", 1, 0, time_s=0.1 + 0.2, path_length_m=1 / 3),
            row("ppo", 1, 0, success=False, outcome="collision", min_clearance_m=-0.05),
            row("ppo", 0, 1, compute_ms_mean=math.nan, energy_kj=1e-17),
            row("ppo", 0, 0, scenario="a, quoted \"city\""),
            row("rrt_mpc", 0, 0, outcome="solver_failure", success=False)]
    path = write_metrics_csv(rows, tmp_path / "metrics.csv")
    text = path.read_text()
    lines = text.splitlines()
    assert lines[0] == ",".join(COLUMNS)
    back = read_metrics_csv(path)
    expected = sorted(rows, key=lambda r: (r.scenario, r.episode, r.method, r.seed))
    assert len(back) == len(rows) and all(same(a, b) for a, b in zip(back, expected))
    assert back[0].scenario == "a, quoted \"city\""
    assert back[1].time_s == 20.0 and isinstance(back[1].success, bool)
    assert next(r for r in back if r.method == "rrt_mpc" and r.episode == 1).time_s == 0.1 + 0.2
    # bools as 0/1, NaN as nan, floats at repr precision
    ppo_fail = next(line for line in lines[1:] if ",collision," in line)
    assert ",0,1,collision," in ppo_fail
    assert ",nan," in text and "0.30000000000000004" in text and "1e-17" in text
    # writing what was read gives the same bytes
    assert write_metrics_csv(back, tmp_path / "again.csv").read_text() == text


def test_atomic_writes_leave_no_temporary_file(tmp_path, monkeypatch):
    write_metrics_csv([row()], tmp_path / "metrics.csv")
    write_summary_json(summarize([row()], resamples=50), tmp_path / "summary.json")
    assert sorted(os.listdir(tmp_path)) == ["metrics.csv", "summary.json"]
    # outputs get the mode plain `open` would give (not mkstemp's private 0600): a run folder can be shared
    mask = os.umask(0o022)
    os.umask(mask)
    assert (tmp_path / "metrics.csv").stat().st_mode & 0o777 == 0o666 & ~mask
    before = (tmp_path / "metrics.csv").read_text()

    def broken_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(atomic.os, "replace", broken_replace)  # the one atomic writer (uam_fdm.files.atomic)
    with pytest.raises(OSError, match="disk full"):
        write_metrics_csv([row(), row("rrt_mpc")], tmp_path / "metrics.csv")
    assert sorted(os.listdir(tmp_path)) == ["metrics.csv", "summary.json"]
    assert (tmp_path / "metrics.csv").read_text() == before


def test_bad_csv_is_a_value_error_naming_the_file(tmp_path):
    good = write_metrics_csv([row()], tmp_path / "metrics.csv").read_text().splitlines()
    header, cells = good[0].split(","), good[1].split(",")
    k = COLUMNS.index("spl")

    def write(name, lines):
        p = tmp_path / name
        p.write_text("\n".join(lines) + "\n")
        return p

    no_spl = write("no_spl.csv", [",".join(header[:k] + header[k + 1:]), ",".join(cells[:k] + cells[k + 1:])])
    with pytest.raises(ValueError, match=r"no_spl\.csv: missing column\(s\) spl"):
        read_metrics_csv(no_spl)
    bad_bool = write("bad_bool.csv", [good[0], good[1].replace(",1,0,,", ",yes,0,,")])
    with pytest.raises(ValueError, match=r"bad_bool\.csv: line 2, column success: cannot read 'yes'"):
        read_metrics_csv(bad_bool)
    extra = write("extra.csv", [good[0] + ",colour", good[1] + ",red"])
    with pytest.raises(ValueError, match=r"extra\.csv: unknown column\(s\) colour"):
        read_metrics_csv(extra)
    short = write("short.csv", [good[0], ",".join(cells[:-1])])
    with pytest.raises(ValueError, match=r"short\.csv: line 2"):
        read_metrics_csv(short)
    empty = write("empty.csv", [])
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(ValueError, match=r"empty\.csv: empty file"):
        read_metrics_csv(empty)


# --------------------------------------------------------------------------------------------------
# summary.json
# --------------------------------------------------------------------------------------------------

def comparison_rows() -> list[EpisodeMetrics]:
    """PPO flies episodes 0-9, RRT*+MPC episodes 2-9 (8 matched); known failures and NaNs."""
    rows = []
    for ep in range(10):
        ppo_ok = ep != 3
        rows.append(row("ppo", ep, success=ppo_ok, time_s=10.0 + ep, path_length_m=100.0 + ep,
                        energy_kj=20.0 + ep, min_clearance_m=1.0 + 0.5 * ep,
                        compute_ms_mean=math.nan if ep == 0 else 0.5, compute_ms_max=1.0))
    for ep in range(2, 10):
        mpc_ok = ep not in (5, 6)
        outcome = "success" if mpc_ok else ("collision" if ep == 5 else "timeout")
        rows.append(row("rrt_mpc", ep, success=mpc_ok, outcome=outcome, time_s=12.0 + 2 * ep,
                        path_length_m=90.0 + ep, energy_kj=25.0, min_clearance_m=2.0 + 0.25 * ep,
                        compute_ms_mean=20.0, compute_ms_max=40.0 + ep, plan_time_s=1.0 + 0.1 * ep))
    return rows


def test_summary_per_method_on_known_data():
    rows = comparison_rows()
    s = summarize(rows, resamples=500, seed=3)
    assert s.bootstrap == BootstrapConfig(resamples=500, confidence=0.95, seed=3, method="percentile",
                                          min_n=MIN_INTERVAL_N)
    assert s.metrics == S.SUMMARY_METRICS and s.by_scenario is None
    assert list(s.pilots) == ["ppo", "rrt_mpc"]
    ppo, mpc = s.pilots["ppo"], s.pilots["rrt_mpc"]
    assert ppo.episodes == 10 and ppo.failure_reasons == {"timeout": 1}
    assert mpc.episodes == 8 and mpc.failure_reasons == {"collision": 1, "timeout": 1}
    assert ppo.stats["success"].mean == pytest.approx(0.9) and ppo.stats["success"].n == 10
    assert mpc.stats["collision"].mean == pytest.approx(1 / 8)
    # success-only metrics: PPO's failed episode 3 is left out
    succ = [ep for ep in range(10) if ep != 3]
    assert ppo.stats["time_s"].mean == pytest.approx(np.mean([10.0 + ep for ep in succ]))
    assert ppo.stats["time_s"].n == 9 and ppo.stats["time_s"].over == "successes"
    assert ppo.stats["path_length_m"].over == "successes" and ppo.stats["energy_kj"].over == "successes"
    assert ppo.stats["min_clearance_m"].over == "all" and ppo.stats["min_clearance_m"].n == 10
    # NaNs dropped per metric; PPO does not plan → n = 0 and nulls
    assert ppo.stats["compute_ms_mean"].n == 9 and ppo.stats["compute_ms_mean"].mean == pytest.approx(0.5)
    assert ppo.stats["plan_time_s"] == Stat(mean=None, ci_low=None, ci_high=None, n=0, over="all")
    assert mpc.stats["plan_time_s"].mean == pytest.approx(1.0 + 0.1 * 5.5)
    for stats in (ppo, mpc):
        for metric in S.SUMMARY_METRICS:
            st = stats.stats[metric]
            if st.n >= MIN_INTERVAL_N or (st.n and metric in S.RATE_METRICS):
                assert st.ci_low <= st.mean <= st.ci_high, (metric, st)
            elif st.n:  # too few episodes for the bootstrap: the mean alone
                assert st.ci_low is None and st.ci_high is None, (metric, st)
    assert mpc.stats["success"].n == 8 and mpc.stats["min_clearance_m"].ci_low is None  # 8 < 10: no bootstrap
    # the CI of a spread sample has width and stays inside the data's range
    clear = ppo.stats["min_clearance_m"]
    assert 1.0 <= clear.ci_low < clear.mean < clear.ci_high <= 5.5


def test_ci_edge_cases_and_confidence():
    s = summarize([row("ppo", 0, compute_ms_max=7.0), row("ppo", 1, success=False)], resamples=200)
    ppo = s.pilots["ppo"]
    assert ppo.stats["time_s"] == Stat(mean=20.0, ci_low=None, ci_high=None, n=1, over="successes")
    rows = [row("ppo", ep, min_clearance_m=float(ep % 7)) for ep in range(40)]
    wide = summarize(rows, resamples=1000, confidence=0.99).pilots["ppo"].stats["min_clearance_m"]
    narrow = summarize(rows, resamples=1000, confidence=0.5).pilots["ppo"].stats["min_clearance_m"]
    assert wide.ci_high - wide.ci_low > narrow.ci_high - narrow.ci_low > 0
    with pytest.raises(ValueError, match="confidence"):
        summarize(rows, confidence=1.0)
    with pytest.raises(ValueError, match="resamples"):
        summarize(rows, resamples=0)
    with pytest.raises(ValueError, match="two rows"):
        summarize([row("ppo", 0), row("ppo", 0)])


def test_paired_differences_only_over_matched_episodes():
    rows = comparison_rows() + [row("rrt_mpc", 3, seed=1)]     # seed 1: PPO never flew it
    s = summarize(rows, resamples=500)
    (p,) = s.paired
    assert (p.first, p.second, p.name) == ("ppo", "rrt_mpc", "ppo - rrt_mpc")
    assert p.episodes == 8
    eps = range(2, 10)
    ppo_ok = {ep: ep != 3 for ep in eps}
    mpc_ok = {ep: ep not in (5, 6) for ep in eps}
    assert p.stats["success"].n == 8
    assert p.stats["success"].mean == pytest.approx(np.mean([ppo_ok[e] - mpc_ok[e] for e in eps]))
    clear = np.mean([(1.0 + 0.5 * e) - (2.0 + 0.25 * e) for e in eps])
    assert p.stats["min_clearance_m"].mean == pytest.approx(clear)
    assert p.stats["min_clearance_m"].ci_low is None  # 8 pairs: too few for the bootstrap
    assert p.stats["success"].ci_low is not None      # a rate keeps its (Newcombe) interval
    both = [e for e in eps if ppo_ok[e] and mpc_ok[e]]                    # 2, 4, 7, 8, 9
    assert p.stats["time_s"].n == len(both) == 5 and p.stats["time_s"].over == "successes"
    assert p.stats["time_s"].mean == pytest.approx(np.mean([(10.0 + e) - (12.0 + 2 * e) for e in both]))
    assert p.stats["compute_ms_mean"].n == 8                 # PPO's NaN is on episode 0, not matched
    assert p.stats["plan_time_s"].n == 0 and p.stats["plan_time_s"].mean is None


def test_summary_json_is_deterministic_and_nan_free(tmp_path):
    rows = comparison_rows() + [row("a_star", ep) for ep in range(4)]
    shuffled = rows[:]
    random.Random(7).shuffle(shuffled)
    a = write_summary_json(summarize(rows), tmp_path / "a.json").read_bytes()
    b = write_summary_json(summarize(shuffled), tmp_path / "b.json").read_bytes()
    assert a == b
    text = a.decode()
    assert "NaN" not in text and "Infinity" not in text and text.startswith('{\n  "bootstrap"')
    loaded = json.loads(text)
    assert list(loaded["paired"]) == ["ppo - rrt_mpc", "ppo - a_star", "rrt_mpc - a_star"]  # table order
    assert loaded["methods"]["ppo"]["plan_time_s"]["mean"] is None
    assert loaded["paired"]["ppo - rrt_mpc"]["success"]["mean_diff"] is not None  # the file's name for it
    spread = [row("ppo", ep, min_clearance_m=2.0 + math.sin(1.7 * ep)) for ep in range(20)]
    assert summarize(spread, seed=1).pilots != summarize(spread, seed=0).pilots   # the seed drives the CIs


def test_summary_json_round_trip(tmp_path):
    """write → read gives the same Summary (per scenario too), and writing it again the same bytes."""
    rows = comparison_rows() + [row("ppo", ep, scenario="city", success=ep != 1) for ep in range(3)]
    s = summarize_run(rows)
    assert list(s.by_scenario) == ["city", "town"]
    assert s.by_scenario["city"] == summarize([r for r in rows if r.scenario == "city"])
    path = write_summary_json(s, tmp_path / "summary.json")
    back = read_summary_json(path)
    assert back == s
    assert write_summary_json(back, tmp_path / "again.json").read_bytes() == path.read_bytes()
    assert summary_to_json(back) == json.loads(path.read_text())
    # a summary without intervals or per-scenario parts (hand-written, or older) still reads
    (tmp_path / "old.json").write_text(json.dumps({
        "bootstrap": {"resamples": 10}, "metrics": ["success"],
        "methods": {"ppo": {"episodes": 2, "success": {"mean": 0.5, "ci_low": None, "ci_high": None, "n": 2}}}}))
    old = read_summary_json(tmp_path / "old.json")
    assert old.by_scenario is None and old.paired == () and old.bootstrap == BootstrapConfig(resamples=10)
    assert old.pilots["ppo"].stats["success"] == Stat(0.5, None, None, 2) and old.pilots["ppo"].failure_reasons == {}
    assert isinstance(old, Summary) and pilots_table(old)[1] == ["ppo", "2", "50% (n=2, no CI)"]


def test_bad_summary_json_names_the_file_and_key(tmp_path):
    bad = tmp_path / "summary.json"
    bad.write_text('{"methods": {"ppo": {"episodes": 2, "success": {"mean": "high"}}}}')
    with pytest.raises(ValueError, match=r"summary\.json: methods\.ppo\.success\.mean: expected a number"):
        read_summary_json(bad)
    bad.write_text("{not json")
    with pytest.raises(ValueError, match=r"summary\.json: not readable JSON"):
        read_summary_json(bad)


def test_pilots_table():
    table = pilots_table(summarize(comparison_rows(), resamples=300))
    header = table[0]
    assert header[:4] == ["pilot", "episodes", "success", "collision"]
    assert len(header) == 2 + len(S.SUMMARY_METRICS)
    assert [r[0] for r in table[1:]] == ["ppo", "rrt_mpc"] and all(len(r) == len(header) for r in table)
    ppo = dict(zip(header, table[1]))
    assert ppo["episodes"] == "10"
    assert ppo["success"].startswith("90% [") and ppo["success"].endswith("%]")
    assert ppo["min clearance [m]"].startswith("3.25 [")
    assert ppo["plan time [s]"] == "n/a"
    # 9 successes: below MIN_INTERVAL_N, the mean and its n, no bootstrap interval
    assert ppo["time [s] (successes)"] == f"{np.mean([10.0 + e for e in range(10) if e != 3]):.1f} (n=9, no CI)"


def test_a_run_whose_plans_hit_the_wall_cap_says_so(tmp_path):
    """The run's printout names each pilot with episodes whose plans the wall-time cap cut (they may not repeat);
    nothing when none had, or for a run without the column (NaN)."""
    from compare.cli.printout import wall_cap_note

    assert wall_cap_note(tmp_path) == ""  # no metrics.csv
    clean = [row("rrt_mpc", 0, planner_wall_caps=0.0), row("ppo", 0), row("rrt_mpc", 1)]
    write_metrics_csv(clean, tmp_path / "metrics.csv")
    assert wall_cap_note(tmp_path) == ""
    write_metrics_csv([*clean, row("rrt_mpc", 2, planner_wall_caps=3.0)], tmp_path / "metrics.csv")
    note = wall_cap_note(tmp_path)
    assert "rrt_mpc 1 of 3" in note and "ppo" not in note and "planner_wall_caps" in note
