"""Per-episode metrics and `metrics.csv`.

One `EpisodeMetrics` row per saved episode (scenario, episode, pilot, seed) is computed from the
episode file alone, so metrics never need the world that produced the flight. `metrics.csv` is written
by `write_metrics_csv` and read by `read_metrics_csv`, nowhere else; it is written atomically (a
temporary file in the same folder, then `os.replace`), so a reader sees the old file or the new one,
never half of one. The summary over episodes is `compare.results.summary`'s.
"""
from __future__ import annotations

import csv
import io
import math
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import astuple, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from compare.flying import pilots
from compare.flying.episode_loop import Trajectory
from compare.results.trajectory import SavedEpisode
from planners.report import ClassicalReport
from uam_fdm.episode import Outcome
from uam_fdm.files.atomic import write_text_atomic
from uam_fdm.pilot import PilotReport

CLEARANCE_THRESHOLDS_M = (2.0, 5.0)
"""Clearances [m] below which the time spent is counted (`time_below_2m_s`, `time_below_5m_s`)."""

TRACKER_METRICS = ("mpc_solve_ms_median", "mpc_solve_ms_p95", "mpc_failures", "replans_tracking",
                   "replans_clearance", "tracking_rms_m", "tracking_max_m", "planner_margin_m", "mpc_margin_m",
                   "planner_margin_floor_m", "planner_attempts", "planner_wall_caps", "clearance_over_margin_min")
"""The classical pilot's tracker columns (NaN for a pilot without a tracker, e.g. ppo): summarised per
pilot like the rest, but not paired (there is nothing to pair them with). Older metrics.csv files
without them read as NaN."""
MAPPING_METRICS = ("replans_blocked", "replans_uncertainty", "hover_holds", "replan_ms_median", "replan_ms_p95",
                   "map_update_ms_median", "uncertainty_margin_max_m", "sensed_obstacles", "cleared_prior_parts",
                   "improvements_tried", "improvements_taken")
"""The classical pilot's columns of flying on its sensors: mapping and replanning in flight (NaN at perfect sensing
and for a pilot without them)."""


@dataclass(frozen=True)
class EpisodeMetrics:
    """The scores of one episode; the field order is the `metrics.csv` column order.

    Attributes:
        scenario, episode, method, seed: the comparison cell; `method` is the pilot's name (the column keeps its
            first name: scripts read metrics.csv and the store by it).
        map: the city's name. vehicle: the vehicle preset name.
        outcome: how the episode ended (an `uam_fdm.episode.Outcome`'s name).
        success: reached the goal radius before the timeout without collision.
        collision: the collision sphere touched a building or the ground.
        failure_reason: "" on success, else the outcome, or the episode's more specific failure reason
            (`EpisodeMeta.failure_reason`, e.g. "solver_failure": the classical pilot's MPC failed on many solves).
        min_clearance_m: least signed clearance of the collision sphere over the flight [m]
            (physics rate, NaN samples ignored; NaN when there is none).
        time_below_2m_s, time_below_5m_s: flight time with clearance below 2 m / 5 m [s].
        time_s: flight time, the last sample's time [s].
        path_length_m: length of the flown polyline [m].
        straight_line_m: distance from start to goal [m].
        spl: success weighted by path length, success × straight / max(path, straight) [-].
        energy_kj: rotor shaft energy [kJ].
        compute_ms_mean, compute_ms_max: wall time per decision [ms] (NaN without decisions).
        plan_time_s: planning time at reset, plus every replan of the classical pilot [s] (for the PPO
            pilot: computing its route field, the geodesic distance-to-go its observation uses; NaN for a
            pilot that reports none: zero from a pilot that does not always plan, `PilotEntry.plans`).
            A decision that replans also counts that time in compute_ms_max.
        mpc_solve_ms_median, mpc_solve_ms_p95: the MPC solver's wall time per decision [ms].
        mpc_failures: MPC solves that failed (a fallback command was flown) [count].
        replans_tracking, replans_clearance: replans because the tracking error exceeded its threshold,
            and because the MPC's prediction came closer to an obstacle than its margin [count].
        tracking_rms_m, tracking_max_m: RMS and largest distance from the vehicle to its reference
            curve over the decisions [m].
        planner_margin_m, mpc_margin_m: the clearance margins flown beyond the collision radius (the
            reference's, and the MPC's soft constraint) at cruise speed, the largest [m].
        planner_margin_floor_m: the reference's margin at rest (the margin follows the reference's
            speed, narrowing towards the start and goal) [m].
        planner_attempts: planning attempts at reset until a path was found (1: the first planner;
            more: the escalation ladder of `planners.ladder` climbed) [count].
        planner_wall_caps: plans cut short by the planner's wall-time cap, at reset and in flight [count]: 0 unless
            the machine was too slow or too loaded for the iteration budgets; above 0 the episode may not repeat on
            another machine or load.
        clearance_over_margin_min: least, over the physics steps, of the vehicle's true clearance over the margin
            in force at its reference point (the promise: >= 0.5; `compare.flying.promise`) [-].
        vehicle_fingerprint: the vehicle's fingerprint ("" where the episode file did not record it). Rows of
            two vehicles that share a name but not a fingerprint are labelled apart (`label_vehicles`).
        The tracker columns (`TRACKER_METRICS`) are NaN for a pilot without a tracker (ppo) and, where an
        older episode file did not record them, for the classical pilot too (counts as floats for that).
        sensing, map_error: the scenario's sensing level and map-error level (`perfect` and `exact` before either
            existed; a "+" marks a level with overrides).
        est_error_h_rms_m, est_error_h_max_m, est_error_v_rms_m, est_error_v_max_m: RMS and largest horizontal and
            vertical error of the navigation estimate's position, at the control periods' ends [m] (0 at perfect
            sensing: the estimate is the truth).
        gnss_availability: share of GNSS epochs with a fix [-] (NaN at perfect sensing: no receiver simulated).
        est_nees_in_bounds: share of the control periods whose position NEES (the estimate's error under its own
            covariance, 3 dof) lies inside the two-sided 95 % chi-square interval [-]: about 0.95 for a consistent
            filter, less for an over- or underconfident one (NaN at perfect sensing).
        min_clearance_unmapped_m: least signed clearance of the collision sphere to the obstacles the prior map
            lacks (unmapped buildings, missing ones, cranes and masts), physics rate [m] (NaN when it lacks none).
        unmapped_sensed: obstacles the prior map lacks that a returned lidar beam hit during the episode [count]
            (NaN at perfect sensing: no lidar simulated).
        unmapped_first_sensed_m_min, unmapped_first_sensed_m_median: over those obstacles, least and median true
            range from the vehicle's centre to the obstacle when the lidar first sensed it (the nearest returned
            beam on it in its first scan) [m]: how much room the pilot had left to react (NaN when none was
            sensed, and at perfect sensing).
        replans_blocked, replans_uncertainty: the classical pilot's replans in flight because a newly sensed obstacle
            came within its margin of the path still to fly, and because k σ of its estimate outgrew the margin it
            planned with [count] (`MAPPING_METRICS`: NaN at perfect sensing and for other pilots).
        hover_holds: times the classical pilot held (hovered) for want of a path in what it knew [count].
        replan_ms_median, replan_ms_p95: wall time of a replan in flight [ms] (the pilot flies `replan_budget_s`
            braking meanwhile, whatever this is).
        map_update_ms_median: wall time to map one lidar scan [ms].
        uncertainty_margin_max_m: the largest k σ the classical pilot added to its margins [m].
        sensed_obstacles, cleared_prior_parts: obstacles in its fused map at the end that the prior lacked, and
            prior parts it took out because beams passed through them [count].
        improvements_tried, improvements_taken: the classical pilot's searches for a faster path while flying one
            found at the floor margin, and those it took [count].
    """

    scenario: str
    episode: int
    method: str
    seed: int
    map: str
    vehicle: str
    outcome: str
    success: bool
    collision: bool
    failure_reason: str
    min_clearance_m: float
    time_below_2m_s: float
    time_below_5m_s: float
    time_s: float
    path_length_m: float
    straight_line_m: float
    spl: float
    energy_kj: float
    compute_ms_mean: float
    compute_ms_max: float
    plan_time_s: float
    mpc_solve_ms_median: float = math.nan
    mpc_solve_ms_p95: float = math.nan
    mpc_failures: float = math.nan
    replans_tracking: float = math.nan
    replans_clearance: float = math.nan
    tracking_rms_m: float = math.nan
    tracking_max_m: float = math.nan
    planner_margin_m: float = math.nan
    mpc_margin_m: float = math.nan
    planner_margin_floor_m: float = math.nan
    planner_attempts: float = math.nan
    clearance_over_margin_min: float = math.nan
    vehicle_fingerprint: str = ""
    sensing: str = "perfect"
    map_error: str = "exact"
    est_error_h_rms_m: float = math.nan
    est_error_h_max_m: float = math.nan
    est_error_v_rms_m: float = math.nan
    est_error_v_max_m: float = math.nan
    gnss_availability: float = math.nan
    min_clearance_unmapped_m: float = math.nan
    est_nees_in_bounds: float = math.nan
    unmapped_sensed: float = math.nan
    unmapped_first_sensed_m_min: float = math.nan
    unmapped_first_sensed_m_median: float = math.nan
    replans_blocked: float = math.nan
    replans_uncertainty: float = math.nan
    hover_holds: float = math.nan
    replan_ms_median: float = math.nan
    replan_ms_p95: float = math.nan
    map_update_ms_median: float = math.nan
    uncertainty_margin_max_m: float = math.nan
    sensed_obstacles: float = math.nan
    cleared_prior_parts: float = math.nan
    improvements_tried: float = math.nan
    improvements_taken: float = math.nan
    planner_wall_caps: float = math.nan  # last: the columns before keep their order


COLUMNS = tuple(f.name for f in fields(EpisodeMetrics))
"""`metrics.csv` columns, in order."""

# Field kinds as written in the annotations (strings under `from __future__ import annotations`).
_KINDS = {f.name: str(f.type) for f in fields(EpisodeMetrics)}


SENSING_METRICS = ("est_error_h_rms_m", "est_error_h_max_m", "est_error_v_rms_m", "est_error_v_max_m",
                   "gnss_availability", "min_clearance_unmapped_m", "est_nees_in_bounds", "unmapped_sensed",
                   "unmapped_first_sensed_m_min", "unmapped_first_sensed_m_median")
"""The columns of what the vehicle sensed and the map missed (older metrics.csv files: NaN)."""
_OPTIONAL = (*TRACKER_METRICS, "vehicle_fingerprint", "sensing", "map_error", *SENSING_METRICS, *MAPPING_METRICS)
# columns that older metrics.csv files lack
VEHICLE_TAG_CHARS = 8
"""Characters of the fingerprint that tell apart two vehicles sharing a name ("small_quad (1a2b3c4d)")."""


def label_vehicles(rows: Sequence[EpisodeMetrics]) -> list[EpisodeMetrics]:
    """`rows` with each vehicle named so that two vehicles never share a name: a vehicle whose name another
    vehicle (another fingerprint) also has is named "name (first 8 characters of its fingerprint)".

    A vehicle file that keeps a preset's name but changes its numbers is another vehicle; the summary and the
    report key vehicles by these names, so they never pool the two. Idempotent.
    """
    prints: dict[str, set[str]] = {}
    for r in rows:
        prints.setdefault(r.vehicle, set()).add(r.vehicle_fingerprint)
    shared = {name for name, fps in prints.items() if len(fps) > 1}
    return [replace(r, vehicle=f"{r.vehicle} ({r.vehicle_fingerprint[:VEHICLE_TAG_CHARS] or 'unrecorded'})")
            if r.vehicle in shared else r for r in rows]


def below_field(threshold_m: float) -> str:
    """Name of the time-below-clearance field for a threshold [m], e.g. 2.0 → `time_below_2m_s`."""
    return f"time_below_{threshold_m:g}m_s"


# ---------------------------------------------------------------------------------------------------
# One episode
# ---------------------------------------------------------------------------------------------------

def episode_metrics(saved: SavedEpisode) -> EpisodeMetrics:
    """Score one saved episode.

    The outcome, energy and planning time come from the episode's metadata; everything else from its
    trajectory arrays (physics rate, row 0 the initial state).

    Args:
        saved: an episode as returned by `compare.results.trajectory.load_episode` (or built in memory).

    Returns:
        The episode's `EpisodeMetrics`.

    Raises:
        ValueError: inconsistent array lengths, naming the episode.
    """
    meta, traj = saved.meta, saved.trajectory
    key = meta.key
    t = np.asarray(traj.t_s, dtype=float)
    states = np.asarray(traj.states, dtype=float)
    clearance = np.asarray(traj.clearance_m, dtype=float)
    if t.ndim != 1 or t.size == 0 or states.shape[0] != t.size or clearance.shape != t.shape:
        raise ValueError(f"episode {key.stem}: t_s {t.shape}, states {states.shape} and clearance_m "
                         f"{clearance.shape} do not have the same non-zero number of samples")
    compute_ms = 1e3 * np.asarray(traj.compute_s, dtype=float).ravel()
    success = meta.outcome == Outcome.SUCCESS
    path_m = _path_length_m(states[:, 0:3])
    straight_m = float(np.linalg.norm(np.subtract(meta.goal_m, meta.start_m, dtype=float)))
    below = {below_field(th): _time_below_s(t, clearance, th) for th in CLEARANCE_THRESHOLDS_M}
    finite_clearance = clearance[~np.isnan(clearance)]
    # a pilot the registry does not hold (a plug-in) is not imported to ask whether it plans: the file names it.
    entry = pilots.registered(key.method)
    does_not_plan = (entry is None or not entry.plans) and meta.plan_time_s == 0
    return EpisodeMetrics(
        scenario=key.scenario, episode=int(key.episode), method=key.method, seed=int(key.seed),
        map=meta.map_name, vehicle=meta.vehicle, vehicle_fingerprint=meta.vehicle_fingerprint,
        outcome=meta.outcome.value,
        success=success, collision=meta.outcome == Outcome.COLLISION,
        failure_reason="" if success else (meta.failure_reason or meta.outcome).value,
        min_clearance_m=float(finite_clearance.min()) if finite_clearance.size else math.nan,
        **below,
        time_s=float(t[-1]),
        path_length_m=path_m,
        straight_line_m=straight_m,
        spl=_spl(success, path_m, straight_m),
        energy_kj=float(meta.energy_J) / 1e3,
        compute_ms_mean=float(compute_ms.mean()) if compute_ms.size else math.nan,
        compute_ms_max=float(compute_ms.max()) if compute_ms.size else math.nan,
        plan_time_s=math.nan if does_not_plan else float(meta.plan_time_s),
        **_tracker_fields(meta.report),
        sensing=meta.sensing, map_error=meta.map_error,
        **_sensing_fields(traj, meta.sensing),
    )


def _sensing_fields(traj: Trajectory, sensing: str) -> dict[str, float]:
    """The estimation, unmapped-clearance and first-sensed columns from the flight's records (in the cell, before
    storing)."""
    out: dict[str, float] = {}
    near = traj.unmapped_clearance_m
    if near is not None:
        finite = np.asarray(near, float)[np.isfinite(near)]
        out["min_clearance_unmapped_m"] = float(finite.min()) if finite.size else math.nan
    nav = traj.nav
    if nav is None:
        if sensing == "perfect":
            out.update(est_error_h_rms_m=0.0, est_error_h_max_m=0.0, est_error_v_rms_m=0.0, est_error_v_max_m=0.0)
        return out
    err = np.asarray(nav.error_m, float)
    h, v = np.hypot(err[:, 0], err[:, 1]), np.abs(err[:, 2])
    out.update(est_error_h_rms_m=float(np.sqrt(np.mean(h ** 2))), est_error_h_max_m=float(h.max()),
               est_error_v_rms_m=float(np.sqrt(np.mean(v ** 2))), est_error_v_max_m=float(v.max()),
               gnss_availability=nav.gnss_availability, est_nees_in_bounds=nav.nees_in_bounds)
    first_m = np.array([r for _, _, r in nav.first_sensed], float)
    out["unmapped_sensed"] = float(len(first_m))
    if first_m.size:
        out.update(unmapped_first_sensed_m_min=float(first_m.min()),
                   unmapped_first_sensed_m_median=float(np.median(first_m)))
    return out


def _tracker_fields(report: PilotReport | None) -> dict[str, float]:
    """The tracker columns from the pilot's end-of-episode report: the classical pilot's
    (`planners.report.ClassicalReport`; NaN where an older episode file did not record a value), else
    NaN (a pilot without a tracker)."""
    if not isinstance(report, ClassicalReport):
        return {}  # the fields' NaN defaults
    r = report
    return {"mpc_solve_ms_median": float(r.mpc_solve_ms_median), "mpc_solve_ms_p95": float(r.mpc_solve_ms_p95),
            "mpc_failures": float(r.mpc_failures), "replans_tracking": float(r.replans_tracking),
            "replans_clearance": float(r.replans_clearance), "tracking_rms_m": float(r.tracking_rms_m),
            "tracking_max_m": float(r.tracking_max_m), "planner_margin_m": float(r.planner_margin_m),
            "mpc_margin_m": float(r.mpc_margin_m), "planner_margin_floor_m": float(r.planner_margin_floor_m),
            "planner_attempts": float(r.planner_attempts), "planner_wall_caps": float(r.planner_wall_caps),
            "clearance_over_margin_min": float(r.clearance_over_margin_min),
            **{name: float(getattr(r, name)) for name in MAPPING_METRICS}}


def _path_length_m(positions_m: np.ndarray) -> float:
    """Length of the polyline through (M, 3) positions [m].

    Segments touching a non-finite state are skipped, so a `nonfinite` episode's path is the flight up
    to the blow-up.
    """
    segments = np.linalg.norm(np.diff(positions_m, axis=0), axis=1)
    return float(np.sum(segments[np.isfinite(segments)]))


def _time_below_s(t_s: np.ndarray, clearance_m: np.ndarray, threshold_m: float) -> float:
    """Time [s] with clearance below `threshold_m`.

    Each sample after row 0 stands for the physics step ending at it (its dt from `diff(t_s)`), so on
    the runner's uniform grid this is (count of samples below) × dt. NaN clearances do not count.
    """
    dt = np.diff(t_s)
    below = clearance_m[1:] < threshold_m
    return float(np.sum(dt[below]))


def _spl(success: bool, path_m: float, straight_m: float) -> float:
    """Success weighted by path length: 1 for a straight-line success, 0 for any failure."""
    if not success:
        return 0.0
    longest = max(path_m, straight_m)
    return 1.0 if longest == 0.0 else straight_m / longest


# ---------------------------------------------------------------------------------------------------
# metrics.csv
# ---------------------------------------------------------------------------------------------------

def cell_order(row: EpisodeMetrics) -> tuple[str, int, str, int]:
    """The row's cell (scenario, episode, method, seed): the order of `metrics.csv` and a row's identity."""
    return (row.scenario, row.episode, row.method, row.seed)


def write_metrics_csv(rows: Iterable[EpisodeMetrics], path: Path) -> Path:
    """Write `metrics.csv` atomically, one row per episode sorted by (scenario, episode, method, seed).

    Booleans are written 0/1, floats with `repr` precision (so they read back exactly), NaN as `nan`.

    Returns:
        The path written.
    """
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(COLUMNS)
    for row in sorted(rows, key=cell_order):
        writer.writerow([_format_cell(_KINDS[name], value) for name, value in zip(COLUMNS, astuple(row))])
    return write_text_atomic(Path(path), buf.getvalue())


def read_metrics_csv(path: Path) -> list[EpisodeMetrics]:
    """Read a `metrics.csv` written by `write_metrics_csv`, rows in file order.

    Raises:
        ValueError: empty file, missing or unknown columns, a short row or an unreadable cell, naming
            the file (and the column and line where it applies).
    """
    path = Path(path)
    with path.open(newline="", encoding="utf-8") as f:
        reader = csv.reader(f)
        header = next(reader, None)
        if header is None:
            raise ValueError(f"{path}: empty file, expected a header with columns {', '.join(COLUMNS)}")
        missing = [c for c in COLUMNS if c not in header and c not in _OPTIONAL]  # older files: NaN, ""
        if missing:
            raise ValueError(f"{path}: missing column(s) {', '.join(missing)}")
        unknown = [c for c in header if c not in COLUMNS]
        if unknown:
            raise ValueError(f"{path}: unknown column(s) {', '.join(unknown)}")
        repeated = sorted(c for c, k in Counter(header).items() if k > 1)
        if repeated:
            raise ValueError(f"{path}: repeated column(s) {', '.join(repeated)}")
        rows = []
        for cells in reader:
            if len(cells) != len(header):
                raise ValueError(f"{path}: line {reader.line_num}: {len(cells)} cells, expected {len(header)}")
            values = {name: _parse_cell(_KINDS[name], text, f"{path}: line {reader.line_num}, column {name}")
                      for name, text in zip(header, cells)}  # absent tracker columns keep their NaN default
            rows.append(EpisodeMetrics(**values))
    return rows


def _format_cell(kind: str, value: Any) -> str:
    if kind == "bool":
        return "1" if value else "0"
    if kind == "float":
        return repr(float(value))   # shortest exact repr; NaN → 'nan'
    return str(value)


def _parse_cell(kind: str, text: str, where: str) -> Any:
    try:
        if kind == "bool":
            return {"0": False, "1": True}[text]
        if kind == "int":
            return int(text)
        if kind == "float":
            return float(text)
    except (KeyError, ValueError):
        raise ValueError(f"{where}: cannot read {text!r} as {kind}") from None
    return text
