"""The PDF report of a comparison run, built from the run folder's saved files only (never simulating).

A run folder holds `run.json` (provenance), `maps/<scenario>.yaml`, the episodes (`store/`, or
`episodes/*.npz` in a folder saved before the store: `compare.results.episodes`), `metrics.csv` and
`summary.json`.  `build_report` writes, in order:

1. title page(s) "uam-compare report": task set and version (a benchmark run), scenarios, pilots, software
   versions, command, date, fairness;
2. per vehicle, never pooled across vehicles (`compare.report.metrics_pages`): per-pilot mean [95 % CI]
   table, summary forest plot, paired differences with their minimum detectable differences, success
   along task difficulty, the scenarios' conditions, per-scenario and per-episode tables (bounded);
   then the classical pilot's tracker per scenario; a robustness-sweep run's rates against density altitude
   and wind per vehicle (`compare.report.sweep_pages`);
3. per (scenario, episode, seed): paths in 3D and top-down, clearance/speed/rotor time series,
   3D snapshots over time, for the first `DRAWN_SCENARIOS_PER_VEHICLE` scenarios of each vehicle and
   the first `DRAWN_FLIGHTS_PER_SCENARIO` tasks of each (a benchmark run has hundreds: a page says which);
4. "PPO training: reward convergence" from the policy folder's `reward_curve.csv`, and beside it "Learning in
   pictures" when the folder has recorded training flights (`compare.report.learning_pages`: fixed tasks by
   checkpoints, top-down);
5. "Failures": the cells that produced no episode (RUN_DIR/failed/: a pilot's exception, a crashed or hung
   worker), the unsuccessful episodes (the first `MAX_FAILURE_ROWS`), top-down views of up to six.

The per-vehicle numbers are summary.json's; a summary.json written before per-vehicle summaries (whose
run-wide numbers may pool vehicles), or none, is replaced by the same summary computed from metrics.csv,
and the pages say so. A pilot shows with run.json's label (a plug-in that cannot be imported where the
report is built too) and its own colour. It works on an interrupted run (the episodes and metric rows
present are used; a missing `metrics.csv` is noted instead of failing). The PDF is written under a
temporary name and renamed; every page is also saved as a PNG under `RUN_DIR/figures/`.
"""
from __future__ import annotations

import csv
import logging
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from matplotlib import rc_context
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure

from compare.flying import pilots
from compare.report import figures as F
from compare.report.learning_pages import learning_figures
from compare.report.metrics_pages import SUMMARY_ROWS, PilotStyle, episode_table_pages, format_ci, vehicle_pages
from compare.report.sweep_pages import sweep_pages
from compare.results.difficulty import scenario_conditions
from compare.results.episodes import EpisodeEntry, RunEpisodes, open_episodes
from compare.results.failures import FAILED_DIR, describe_failures, read_failures
from compare.results.metrics import EpisodeMetrics, cell_order, read_metrics_csv
from compare.results.run_info import PolicyRecord, RunInfo, ScenarioInfo, read_run_info
from compare.results.summary import Summary, read_summary_json, summarize_run
from rl.policies.folder import PolicyFolder, Provenance
from uam_fdm.air.shear import ShearLaw, WindShear
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.city.mapfile import load_map_file
from uam_fdm.city.plot import missing_glyphs_unsaid, save_figure
from uam_fdm.episode import Outcome
from uam_fdm.files.atomic import atomic_path

logger = logging.getLogger(__name__)

MAX_FAILURE_PLOTS = 6
MAX_FAILURE_ROWS = 130
"""Failures listed one by one (5 pages); every one is in metrics.csv."""
DRAWN_SCENARIOS_PER_VEHICLE = 3
DRAWN_FLIGHTS_PER_SCENARIO = 3
"""Flight pages (three per task) are drawn for this many scenarios per vehicle and tasks per scenario."""
PNG_DPI = 130


@dataclass
class _Run:
    """What every page needs: the folder, its provenance and the per-pilot labels and colours."""

    run_dir: Path
    info: RunInfo
    pilots: list[str]
    labels: dict[str, str]
    colors: dict[str, str]
    scenarios: list[str]
    maps: dict[str, BuildingMap | None] = field(default_factory=dict)
    unreadable: list[str] = field(default_factory=list)  # episode files skipped, for the failures page
    files: dict[tuple[str, int, str, int], EpisodeEntry] = field(default_factory=dict)  # episode by cell (`cell_order`)
    episodes: RunEpisodes | None = None  # the run's episodes, listed once
    skip_log_level: int = logging.WARNING  # INFO when the caller has already warned about them

    def skip(self, name: str, exc: Exception) -> None:
        """Leave out an unreadable episode (`name`: its file): log why (the message names it) and list it."""
        logger.log(self.skip_log_level, "skipping unreadable episode file %s", exc)
        if name not in self.unreadable:
            self.unreadable.append(name)

    def label(self, pilot: str) -> str:
        return self.labels.get(pilot, pilot)

    def add_pilot(self, pilot: str) -> None:
        """A pilot run.json does not list (found in the episode files or metrics.csv): its label and own colour."""
        self.pilots.append(pilot)
        self.labels.setdefault(pilot, _registry_label(pilot))
        self.colors = F.pilot_colors(self.pilots, self.info.colors())

    def style(self) -> PilotStyle:
        """The pilots' order, labels and colours, for the metrics pages."""
        return PilotStyle(tuple(self.pilots), dict(self.labels), dict(self.colors))

    def map_of(self, scenario: str) -> BuildingMap | None:
        if scenario not in self.maps:
            path = self.run_dir / "maps" / f"{scenario}.yaml"
            try:
                self.maps[scenario] = load_map_file(path)
            except ValueError as exc:  # ConfigError is a ValueError; a missing file is one too
                logger.warning("scenario %s: no city drawn (%s)", scenario, exc)
                self.maps[scenario] = None
        return self.maps[scenario]


def read_reward_curve(path: Path) -> F.RewardCurve | None:
    """A policy's `reward_curve.csv` as a `RewardCurve`, or None if the file is absent.

    Reads `rl.training.loop`'s format (one row per PPO update: timesteps, mean_episode_reward,
    train_success_rate, train_collision_rate, train_timeout_rate, train_episodes, difficulty,
    success_rate, collision_rate, eval_episodes, wall_s; the validation columns empty on rows without
    an evaluation) and older files with only some of these columns: an absent column or an empty or
    unreadable cell is NaN. Rows without a timestep (e.g. a half-written last line) are left out.

    Raises:
        ValueError: the file exists but lacks `timesteps` or `mean_episode_reward`, or has no rows,
            naming the file.
    """
    path = Path(path)
    if not path.is_file():
        return None
    with path.open(newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    need = ("timesteps", "mean_episode_reward")
    if not rows or any(k not in rows[0] for k in need):
        raise ValueError(f"{path}: needs columns {', '.join(need)} and at least one row")
    names = (*need, "success_rate", *F.CURVE_FIELDS)
    col = {k: np.array([_float(r.get(k)) for r in rows]) for k in names}
    keep = np.isfinite(col["timesteps"])
    if not np.any(keep):
        raise ValueError(f"{path}: no row has a timestep")
    return F.RewardCurve(**{k: v[keep] for k, v in col.items()})


@F.plain_text
def build_report(run_dir: Path, out: Path | None = None, *, warn_unreadable: bool = True) -> Path:
    """Write the run's PDF report (and its pages as PNGs under RUN_DIR/figures/).

    An unreadable (corrupt, truncated) episode file is left out, logged and listed on the failures page.

    Args:
        run_dir: the run folder.
        out: the PDF path (default RUN_DIR/report.pdf); written atomically.
        warn_unreadable: log skipped episode files as warnings (False: at INFO, the caller has warned).

    Returns:
        The PDF path.

    Raises:
        ValueError: `run_dir` has no readable run.json.
    """
    run_dir = Path(run_dir)
    run = _make_run(run_dir, read_run_info(run_dir))
    run.skip_log_level = logging.WARNING if warn_unreadable else logging.INFO
    root = run_dir if out is None else None  # the run's own report: no link in the run folder followed
    out = Path(out) if out is not None else run_dir / "report.pdf"
    out.parent.mkdir(parents=True, exist_ok=True)
    groups = _episode_groups(run)
    with atomic_path(out, suffix=".pdf.tmp", root=root) as tmp:
        # TrueType (Type 42) fonts: text stays searchable and journals accept the pages
        metadata = {"Title": "uam-compare report", "Creator": "uam-compare",
                    "Subject": run.info.command, "CreationDate": None}
        with rc_context({"pdf.fonttype": 42}), PdfPages(tmp, metadata=metadata) as pdf:
            pages = _PageWriter(pdf, run_dir / "figures", run_dir)
            n_present = sum(len(paths) for paths in groups.values())
            pages.add_all(F.text_pages("uam-compare report", _title_blocks(run, n_present)), "title")
            rows, why = _read_metrics(run_dir / "metrics.csv")
            for name, figs in _metrics_pages(run, rows, why):
                pages.add_all(figs, name)
            for name, fig in sweep_pages(run.info, rows or [], run.style()):  # a sweep run's rates per step
                pages.add(fig, name)
            drawn, left_out = _drawn_groups(run, groups, rows)
            if left_out:
                pages.add_all(F.text_pages("Flights", left_out), "flights_drawn")
            failures = _episode_pages(run, drawn, pages)
            policies = ppo_policies(run.info)
            for k, pol in enumerate(policies or [None]):  # one convergence page per policy flown
                suffix = "" if k == 0 or pol is None else f"_{pol.vehicle or k}"
                pages.add(_training_figure(pol, len(policies) > 1), f"training_reward_curve{suffix}")
                if pol is not None and pol.policy_dir:  # beside it, its recorded flights (none: no page)
                    title = "Learning in pictures" + (f" ({pol.vehicle})" if len(policies) > 1 and pol.vehicle else "")
                    pages.add_all(learning_figures(Path(pol.policy_dir), title), f"learning_in_pictures{suffix}")
            _failure_pages(run, failures, rows, pages)
    logger.info("report %s: %d pages", out, pages.count)
    return out


# ---- assembly helpers -----------------------------------------------------------------------------------
class _PageWriter:
    """Adds figures to the PDF and saves each as a PNG, then releases it."""

    def __init__(self, pdf: PdfPages, fig_dir: Path, run_dir: Path | None = None) -> None:
        self.pdf, self.fig_dir, self.run_dir, self.count = pdf, fig_dir, run_dir, 0  # run_dir: no link in it followed

    def add(self, fig: Figure, name: str) -> None:
        save_figure(fig, self.fig_dir / f"{_slug(name)}.png", dpi=PNG_DPI, root=self.run_dir)
        with missing_glyphs_unsaid():
            self.pdf.savefig(fig)
        fig.clear()  # Figure-API figures are not registered with pyplot: clearing frees their artists
        self.count += 1

    def add_all(self, figs: Sequence[Figure], name: str) -> None:
        for k, fig in enumerate(figs):
            self.add(fig, name if len(figs) == 1 else f"{name}_{k + 1}")


def _make_run(run_dir: Path, info: RunInfo) -> _Run:
    names = list(info.pilots)
    for s in info.scenarios:
        names += [m for m in s.pilots if m not in names]
    labels = {m: info.pilots[m].label if m in info.pilots else _registry_label(m) for m in names}
    return _Run(run_dir, info, names, labels, F.pilot_colors(names, info.colors()),
                [s.name for s in info.scenarios])


def _registry_label(pilot: str) -> str:
    """The label of a pilot run.json does not describe: the registry's, else its name (a plug-in is never
    imported to ask: the name comes from a data file)."""
    entry = pilots.registered(pilot)
    return entry.label if entry is not None else pilot


def _episode_groups(run: _Run) -> dict[tuple[str, int, int], list[EpisodeEntry]]:
    """Episodes grouped by (scenario, episode, seed), in run.json scenario order."""
    groups: dict[tuple[str, int, int], list[EpisodeEntry]] = {}
    run.episodes = open_episodes(run.run_dir)
    for bad in run.episodes.unreadable:
        run.skip(bad.path.name, ValueError(bad.reason))
    for entry in run.episodes.entries:
        k = entry.key
        if k.method not in run.pilots:  # a pilot run.json does not list still gets its own colour
            run.add_pilot(k.method)
        groups.setdefault((k.scenario, k.episode, k.seed), []).append(entry)
        run.files[(k.scenario, k.episode, k.method, k.seed)] = entry
    for s in sorted({k[0] for k in groups}):
        if s not in run.scenarios:
            run.scenarios.append(s)
    return dict(sorted(groups.items(), key=lambda kv: (run.scenarios.index(kv[0][0]), kv[0][1], kv[0][2])))


def _pilot_rank(run: _Run, pilot: str) -> int:
    return run.pilots.index(pilot) if pilot in run.pilots else len(run.pilots)


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


def _float(v: object) -> float:
    try:
        return float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return math.nan


def _fmt(v: object, digits: int, scale: float = 1.0) -> str:
    f = _float(v)
    return f"{f * scale:.{digits}f}" if math.isfinite(f) else "n/a"


def _num(v: float | None) -> str:
    """A recorded number as written short ("500" for 500.0), "n/a" when not recorded."""
    return "n/a" if v is None else f"{v:g}"


# ---- 1. title -------------------------------------------------------------------------------------------
def _planned_episodes(run: _Run) -> int:
    return sum((s.episodes or 0) * len(s.seeds or [0]) * len(s.pilots or run.pilots) for s in run.info.scenarios)


def _shear_words(shear: WindShear | None) -> str:
    """The steady wind's profile from run.json's wind.shear (absent in runs before it existed: uniform)."""
    if shear is None or shear.law is ShearLaw.UNIFORM:
        return "the same at every height"
    ref = _fmt(shear.reference_height_m, 0)
    if shear.law is ShearLaw.POWER:
        return f"given at {ref} m, power-law shear alpha {_fmt(shear.exponent, 2)}"
    return f"given at {ref} m, log-law shear z0 {_fmt(shear.roughness_m, 2)} m"


def _title_blocks(run: _Run, n_present: int) -> list[tuple[str, str]]:
    info = run.info
    planned = _planned_episodes(run)
    coverage = f"Episodes in this report: {n_present} of {planned} planned."
    if n_present < planned:
        coverage += " The run is incomplete (interrupted): the report covers the episodes saved so far."
    blocks = [("p", f"Created {info.created_utc or 'n/a'} by: {info.command or 'n/a'}"),
              ("p", f"Run folder: {run.run_dir}"), ("p", coverage), ("h", "Scenarios")]
    if info.task_set is not None:  # a benchmark set: its version names the exact tasks flown
        ts = info.task_set
        blocks.insert(1, ("p", f"Task set {ts.name}, version {ts.version}: {ts.description}"))
    for s in info.scenarios:
        blocks += _scenario_blocks(run, s)
    blocks.append(("h", "Pilots"))
    for m, cfg in info.pilots.items():
        blocks.append(("p", f"{run.label(m)} [{m}]: {cfg.description}"))
        for pol in ppo_policies(info, m):  # a pilot that flies policies: one per vehicle
            rate = f"; decides at {pol.decision_hz:g} Hz" if pol.decision_hz else ""
            who = f"for {pol.vehicle}: " if pol.vehicle else ""
            blocks.append(("p", f"    {who}policy {pol.policy_dir}{rate}"))
    if info.notes:  # e.g. cells left out, the pilots' decision rates
        blocks += [("h", "Notes"), *(("p", n) for n in info.notes)]
    blocks += [("h", "Software versions"),
               ("p", " · ".join(f"{k} {v}" for k, v in info.versions.items()) or "n/a"),
               ("h", "Fairness"), ("p", info.fairness or "n/a")]
    return blocks


def _scenario_blocks(run: _Run, s: ScenarioInfo) -> list[tuple[str, str]]:
    atm, wind = s.atmosphere, s.wind
    steady = "n/a" if wind.steady_enu_m_s is None else str(list(wind.steady_enu_m_s))
    return [
        ("p", f"{s.name}: {s.description}"),
        ("p", f"    map {s.map_name} · vehicle {s.vehicle} ({s.vehicle_summary or 'n/a'})"),
        ("p", (f"    atmosphere: field elevation {_fmt(atm.elevation_m, 0)} m, "
               f"ISA offset {_fmt(atm.isa_offset_k, 1)} K, "
               f"density {_fmt(atm.density_kg_m3, 3)} kg/m³")),
        ("p", (f"    wind: steady {steady} m/s (ENU), {_shear_words(wind.shear)}, "
               f"turbulence {wind.turbulence or 'n/a'}")),
        ("p", f"    sensing {s.sensing} · map error {s.map_error} (docs/sensing.md)"),
        ("p", (f"    {_num(s.episodes)} episodes × seeds {list(s.seeds)}; pilots "
               f"{', '.join(run.label(m) for m in s.pilots)}; "
               f"physics {_num(s.physics_hz)} Hz, control {_num(s.control_hz)} Hz; "
               f"source {s.source or 'n/a'}"))]


# ---- 2. metrics -----------------------------------------------------------------------------------------
def _read_metrics(path: Path) -> tuple[list[EpisodeMetrics] | None, str]:
    """The rows of metrics.csv, or None and why (the file is missing or unreadable: logged)."""
    if not path.is_file():
        return None, f"metrics.csv was not found in {path.parent}"
    try:
        return read_metrics_csv(path), ""
    except (OSError, ValueError) as exc:
        logger.warning("%s unreadable (%s): the metrics tables are skipped", path, exc)
        return None, f"metrics.csv could not be read ({exc})"


def _read_summary(path: Path) -> Summary | None:
    if not path.is_file():
        return None
    try:
        return read_summary_json(path)
    except ValueError as exc:  # the message names the file
        logger.warning("summary unreadable (%s): means without confidence intervals", exc)
        return None


def _metrics_pages(run: _Run, rows: list[EpisodeMetrics] | None, why: str) -> list[tuple[str, list[Figure]]]:
    """Per vehicle its metrics pages (`compare.report.metrics_pages`), then the tracker pages."""
    if rows is None:
        note = (f"{why}: the metrics tables are skipped. "
                "The uam-compare CLI recomputes metrics from the saved episodes before building the report.")
        return [("metrics", F.text_pages("Metrics", [("p", note)]))]
    for m in dict.fromkeys(r.method for r in rows):  # a pilot only metrics.csv names still gets a label and colour
        if m not in run.pilots:
            run.add_pilot(m)
    try:
        parts, source = _vehicle_parts(run, rows)
    except ValueError as exc:  # e.g. a hand-edited metrics.csv with a cell twice
        logger.warning("metrics not summarised (%s)", exc)
        return [("metrics", F.text_pages("Metrics", [("p", f"The metrics could not be summarised: {exc}")]))]
    style = run.style()
    conditions = {s.name: scenario_conditions(s, run.map_of(s.name)) for s in run.info.scenarios}
    out: list[tuple[str, list[Figure]]] = []
    for vehicle, part in parts.items():
        out += vehicle_pages(vehicle, part.summary, part.scenarios, part.rows, conditions, style, source)
        out.append((f"vehicle_{vehicle}_episodes", episode_table_pages(vehicle, part.rows, style, run.scenarios)))
    tracker = [fig for m in run.pilots for fig in _tracker_pages(run, rows, m)]
    if tracker:
        out.append(("metrics_tracker", tracker))
    return out


@dataclass(frozen=True)
class _VehiclePart:
    """One vehicle's summary, its scenarios' summaries (run order) and its metrics rows."""

    summary: Summary
    scenarios: dict[str, Summary]
    rows: list[EpisodeMetrics]


def _vehicle_parts(run: _Run, rows: list[EpisodeMetrics]) -> tuple[dict[str, _VehiclePart], str]:
    """Each vehicle's part, vehicles in run order, and where the numbers come from (a sentence).

    From summary.json when it holds per-vehicle summaries; else (missing, or written before them, when its
    run-wide numbers may pool vehicles) summarised here from metrics.csv the way a run saves them.

    Raises:
        ValueError: the rows cannot be summarised (two rows for one cell).
    """
    saved = _read_summary(run.run_dir / "summary.json")
    per_vehicle = saved.per_vehicle() if saved is not None else None
    if saved is not None and per_vehicle is not None:
        by_scenario, source = saved.by_scenario or {}, "numbers from summary.json."
    else:
        fresh = summarize_run(rows)
        per_vehicle, by_scenario = fresh.by_vehicle or {}, fresh.by_scenario or {}
        source = ("summary.json is missing" if saved is None else "summary.json predates per-vehicle summaries")
        source += ", so these numbers are computed here from metrics.csv."
    vehicle_of = {r.scenario: r.vehicle for r in rows}
    order = list(dict.fromkeys(vehicle_of[s] for s in run.scenarios if s in vehicle_of))
    order += sorted(v for v in per_vehicle if v not in order)
    return {v: _VehiclePart(per_vehicle[v],
                            {s: by_scenario[s] for s in run.scenarios if vehicle_of.get(s) == v and s in by_scenario},
                            [r for r in rows if r.vehicle == v])
            for v in order if v in per_vehicle}, source


def _column(rows: Sequence[EpisodeMetrics], name: str) -> np.ndarray:
    """One metrics.csv column of `rows` as floats (booleans as 0/1)."""
    return np.array([float(getattr(r, name)) for r in rows])


def _tracker_pages(run: _Run, rows: list[EpisodeMetrics], pilot: str) -> list[Figure]:
    """A pilot's tracker per scenario (margins flown vs clearance kept, solver, replans), from metrics.csv;
    nothing for a pilot without tracker columns (e.g. the learned pilot), one that did not fly, or a file
    that predates the tracker columns."""
    mine = [r for r in rows if r.method == pilot]
    if not mine or all(not math.isfinite(r.planner_margin_m) for r in mine):
        return []
    table = [_tracker_row(scenario, [r for r in mine if r.scenario == scenario])
             for scenario in dict.fromkeys(r.scenario for r in mine)]
    header = ["scenario", "episodes", "success [%]", "margin rest-cruise / MPC [m]", "min clearance [m]",
              "min clearance / margin", "tracking RMS [m]", "tracking max [m]", "solve median [ms]",
              "solve p95 max [ms]", "failures", "replans track / clear", "plan attempts max / >1"]
    notes = [("Margins: from the vehicle's measured tracking error at each reference speed in the scenario's "
              "forecast turbulence and air, narrowing from cruise towards start and goal (docs/planner.md). "
              "Min clearance / margin: over the margin in force where the vehicle was. Target: >= 0.5."),
             ("Plan attempts: planning attempts at reset (1: the first planner found the path; more: the "
              "escalation ladder of planners/ladder.py), largest / episodes with more than one."),
             ("Min clearance: least over the episodes. Tracking: distance to the reference curve (RMS: mean over "
              "episodes; max: over all)."),
             ("Solve: median of the episodes' medians, largest episode p95. Failures and replans: summed over the "
              "episodes.")]
    return F.table_pages(f"Metrics: the {run.label(pilot)} tracker per scenario", header, table,
                         rows_per_page=26, notes=notes, font_size=7)


def _tracker_row(scenario: str, rs: list[EpisodeMetrics]) -> list[str]:
    """One scenario's row of the tracker table."""
    def agg(f, x: np.ndarray, digits: int) -> str:
        x = x[np.isfinite(x)]
        return f"{f(x):.{digits}f}" if x.size else "n/a"

    col = {k: _column(rs, k) for k in
           ("success", "min_clearance_m", "planner_margin_m", "mpc_margin_m", "tracking_rms_m", "tracking_max_m",
            "mpc_solve_ms_median", "mpc_solve_ms_p95", "mpc_failures", "replans_tracking", "replans_clearance",
            "planner_margin_floor_m", "planner_attempts", "clearance_over_margin_min")}
    # the margin in force where the vehicle was when recorded (speed-dependent), else the one margin flown
    local = col["clearance_over_margin_min"]
    ratio = np.where(np.isfinite(local), local, col["min_clearance_m"] / col["planner_margin_m"])
    floor = col["planner_margin_floor_m"]
    margins = (agg(np.max, col["planner_margin_m"], 2) if not np.any(np.isfinite(floor)) else
               agg(np.min, floor, 2) + "-" + agg(np.max, col["planner_margin_m"], 2))
    attempts = col["planner_attempts"]

    return [scenario, str(len(rs)), agg(np.mean, 100.0 * col["success"], 0),
            margins + " / " + agg(np.max, col["mpc_margin_m"], 2),
            agg(np.min, col["min_clearance_m"], 2), agg(np.min, ratio, 2),
            agg(np.mean, col["tracking_rms_m"], 3), agg(np.max, col["tracking_max_m"], 2),
            agg(np.median, col["mpc_solve_ms_median"], 2), agg(np.max, col["mpc_solve_ms_p95"], 2),
            agg(np.sum, col["mpc_failures"], 0),
            agg(np.sum, col["replans_tracking"], 0) + " / " + agg(np.sum, col["replans_clearance"], 0),
            agg(np.max, attempts, 0) + " / " + agg(np.sum, attempts > 1, 0)]


# ---- 3. episodes ----------------------------------------------------------------------------------------
def _drawn_groups(run: _Run, groups: Mapping[tuple[str, int, int], list[EpisodeEntry]],
                  rows: list[EpisodeMetrics] | None) -> tuple[dict[tuple[str, int, int], list[EpisodeEntry]],
                                                             list[tuple[str, str]]]:
    """The tasks whose flights are drawn: of each vehicle the first `DRAWN_SCENARIOS_PER_VEHICLE` scenarios, of
    each the first `DRAWN_FLIGHTS_PER_SCENARIO` tasks (run order); and, when that leaves some out, the text of
    a page saying so (else empty)."""
    vehicle_of = {s.name: s.vehicle for s in run.info.scenarios if s.vehicle}
    vehicle_of.update({r.scenario: r.vehicle for r in rows or []})  # the scored rows tell same-named vehicles apart
    scenarios: dict[str, list[str]] = {}  # per vehicle, the scenarios drawn
    count: dict[str, int] = {}
    drawn = {}
    for key, paths in groups.items():
        scenario = key[0]
        mine = scenarios.setdefault(vehicle_of.get(scenario, ""), [])
        if scenario not in mine:
            if len(mine) >= DRAWN_SCENARIOS_PER_VEHICLE:
                continue
            mine.append(scenario)
        if count.get(scenario, 0) < DRAWN_FLIGHTS_PER_SCENARIO:
            count[scenario] = count.get(scenario, 0) + 1
            drawn[key] = paths
    if len(drawn) == len(groups):
        return drawn, []
    blocks = [("p", f"This run flew {len(groups)} tasks (scenario, episode, seed). Their flights (paths, time "
                    f"series, snapshots: three pages a task) are drawn for the first {DRAWN_SCENARIOS_PER_VEHICLE} "
                    f"scenarios of each vehicle and the first {DRAWN_FLIGHTS_PER_SCENARIO} tasks of each: "
                    f"{len(drawn)} tasks. Every flight plays in viewer.html; every number is in metrics.csv and "
                    f"the tables above; the failures are listed after the flights."), ("h", "Drawn")]
    for vehicle, names in scenarios.items():
        blocks.append(("p", f"{vehicle or 'vehicle not recorded'}: "
                            + ", ".join(f"{n} ({count[n]} of {sum(1 for k in groups if k[0] == n)})" for n in names)))
    rest = [n for n in dict.fromkeys(k[0] for k in groups) if n not in count]
    if rest:
        blocks += [("h", "Not drawn"), ("p", ", ".join(rest))]
    return drawn, blocks


def _episode_pages(run: _Run, groups: Mapping[tuple[str, int, int], list[EpisodeEntry]],
                   pages: _PageWriter) -> list[F.FlightTrace]:
    """Three pages per (scenario, episode, seed); returns the failed flights' traces (unreadable files: `run.skip`)."""
    failures: list[F.FlightTrace] = []
    for (scenario, ep, seed), paths in groups.items():
        traces = [t for path in paths if (t := _trace(run, path)) is not None]
        if not traces:
            continue
        traces.sort(key=lambda t: _pilot_rank(run, t.pilot))
        failures += [t for t in traces if t.episode.outcome != Outcome.SUCCESS]
        bmap = run.map_of(scenario)
        title = f"Episode {scenario} #{ep} seed {seed}" + ("" if bmap is not None else " (map file missing)")
        name = f"episode_{scenario}__ep{ep:03d}__s{seed}"
        pages.add(F.episode_paths_figure(f"{title}: paths", traces, bmap), f"{name}_paths")
        pages.add(F.episode_timeseries_figure(f"{title}: clearance, speed and rotors over time", traces),
                  f"{name}_timeseries")
        pages.add(F.episode_snapshots_figure(f"{title}: snapshots over time", traces, bmap),
                  f"{name}_snapshots")
    return failures


# ---- 4. training ----------------------------------------------------------------------------------------
def ppo_policies(info: RunInfo, pilot: str | None = None) -> list[PolicyRecord]:
    """The policies run.json records (vehicle, policy_dir, decision_hz), one per vehicle, of `pilot`
    (None: of every pilot that flies policies); a run written before policies per vehicle has one,
    without its vehicle."""
    return [pol for m in ([pilot] if pilot is not None else list(info.pilots)) for pol in info.policies(m)]


def _training_figure(policy: PolicyRecord | None, name_vehicle: bool) -> Figure:
    title = "PPO training: reward convergence"
    if name_vehicle and policy is not None and policy.vehicle:
        title += f" ({policy.vehicle})"
    policy_dir = policy.policy_dir if policy is not None else ""
    if not policy_dir:
        return F.reward_curve_figure(title, None,
                                     "No PPO policy folder is recorded in run.json: no reward curve.")
    folder = PolicyFolder(Path(policy_dir))
    path = folder.reward_curve
    try:
        curve = read_reward_curve(path)
    except (OSError, ValueError) as exc:
        return F.reward_curve_figure(title, None, f"The reward curve could not be read: {exc}")
    if curve is None:
        return F.reward_curve_figure(title, None, f"No reward curve: {path} does not exist.")
    try:
        prov = folder.provenance()  # None: an older policy folder without provenance, no marker
    except ValueError:
        prov = None  # unreadable: drawn as without
    kept = prov.kept_timesteps if prov is not None else None
    return F.reward_curve_figure(title, curve, _training_note(path, curve, prov),
                                 kept_timesteps=float(kept) if kept is not None else None,
                                 subtitle=_training_subtitle(prov, curve))


def _training_subtitle(prov: Provenance | None, curve: F.RewardCurve) -> str:
    method = (prov.method if prov is not None else None) or ""
    # a run still training has no provenance yet; its per-update columns say rl.training.loop wrote it (plain PPO)
    assert curve.difficulty is not None  # RewardCurve.__post_init__ fills an absent column with NaN
    per_update = prov is None and bool(np.any(np.isfinite(curve.difficulty)))
    if method.lower() == "ppo from scratch" or per_update:
        what = "Plain PPO from scratch (no demonstrations, no pre-trained weights)"
    elif method:
        what = f"Training method: {method}"
    elif prov is not None and prov.preset:
        what = f"Training preset {prov.preset!r} (an older policy folder: method not recorded)"
    else:
        what = "Training method not recorded (an older policy folder)"
    return (f"{what}.\nTraining episodes (training cities, at the curriculum's difficulty) vs. "
            "validation (held-out cities, full difficulty).")


def _training_note(path: Path, curve: F.RewardCurve, prov: Provenance | None) -> str:
    parts = [f"from {path}"]
    steps = _float(prov.timesteps if prov is not None else None)
    wall = _float(prov.wall_time_s if prov is not None else None)
    if not math.isfinite(steps):  # no provenance (a run still in progress): its last row
        steps = float(curve.timesteps[-1])
        assert curve.wall_s is not None  # RewardCurve.__post_init__ fills an absent column with NaN
        wall = float(curve.wall_s[-1])
        parts.append("no provenance.json (run in progress?)")
    if math.isfinite(steps):
        parts.append(f"{steps / 1e6:.1f} M timesteps"
                     + (f" in {wall / 60:.0f} min" if math.isfinite(wall) else ""))
    seed = prov.seed if prov is not None else None
    if seed is not None:
        parts.append(f"seed {seed}")
    return " · ".join(parts)


# ---- 5. failures ----------------------------------------------------------------------------------------
def _failure_pages(run: _Run, failures: list[F.FlightTrace], rows: list[EpisodeMetrics] | None,
                   pages: _PageWriter) -> None:
    """The failures table (the first `MAX_FAILURE_ROWS`, run order) and top-down views of up to six; `failures`:
    the failed flights drawn (their detail is known), the others come from metrics.csv."""
    by_key = {cell_order(r): r for r in rows or []}
    entries: list[tuple[tuple, list[str]]] = []
    traced: dict[tuple[str, int, str, int], F.FlightTrace] = {}
    for t in failures:
        k = t.episode.key
        key = (k.scenario, k.episode, k.method, k.seed)
        traced[key] = t
        row = by_key.get(key)
        reason = (row.failure_reason if row is not None else "") or t.episode.outcome
        entries.append((_cell_rank(run, key), [k.scenario, str(k.episode), str(k.seed), t.label, reason,
                                               _short(t.episode.detail), f"{t.end_t_s:.1f}"]))
    untraced = [key for key, r in by_key.items() if key not in traced and not r.success]
    for key in untraced:
        r = by_key[key]
        detail = "(flight not drawn)" if key in run.files else "(no trajectory file)"
        entries.append((_cell_rank(run, key), [r.scenario, str(r.episode), str(r.seed), run.label(r.method),
                                               r.failure_reason or r.outcome, detail, _fmt(r.time_s, 1)]))
    entries.sort(key=lambda e: e[0])
    notes = [f"Unreadable episode files skipped: {', '.join(run.unreadable)}"] if run.unreadable else []
    _failed_cell_pages(run, pages)
    if not entries:
        pages.add_all(F.text_pages("Failures", [("p", "No failures: every episode in this report succeeded.")]
                                   + [("p", n) for n in notes]), "failures")
        return
    if len(entries) > MAX_FAILURE_ROWS:
        notes.insert(0, f"The first {MAX_FAILURE_ROWS} of {len(entries)} failures (run order); every one is in "
                        f"metrics.csv.")
    header = ["scenario", "episode", "seed", "pilot", "failure reason", "detail", "time [s]"]
    pages.add_all(F.table_pages("Failures", header, [e for _, e in entries[:MAX_FAILURE_ROWS]], notes=notes),
                  "failures_table")
    shown = list(failures[:MAX_FAILURE_PLOTS])
    for key in sorted((k for k in untraced if k in run.files), key=lambda k: _cell_rank(run, k)):
        if len(shown) >= MAX_FAILURE_PLOTS:
            break
        trace = _trace(run, run.files[key])  # a failure whose flight was not drawn: read for its view
        if trace is not None:
            shown.append(trace)
    total = len(failures) + len(untraced)
    if shown:
        count = f"{len(shown)} of {total}" if total > len(shown) else f"{len(shown)}"
        pages.add(F.failure_paths_figure(f"Failures: where the flights ended ({count})",
                                         [(t, run.map_of(t.episode.key.scenario)) for t in shown]), "failures_paths")


def _failed_cell_pages(run: _Run, pages: _PageWriter) -> None:
    """The cells that produced no episode (RUN_DIR/failed/: a pilot's exception, a crashed or hung worker): not
    in any rate above, listed so that a reader sees them; `run --resume` flies them again."""
    failed = read_failures(run.run_dir)
    if not failed:
        return
    failed.sort(key=lambda f: _cell_rank(run, (f.key.scenario, f.key.episode, f.key.method, f.key.seed)))
    table = [[f.key.scenario, str(f.key.episode), str(f.key.seed), run.label(f.key.method), f.kind.value,
              _short(f.reason, 90), f"{f.elapsed_s:.1f}", f"{f.backend} {f.worker}".strip()]
             for f in failed[:MAX_FAILURE_ROWS]]
    notes = [f"{describe_failures(failed)}: these cells produced no episode, so they are in no rate, mean or paired "
             f"difference of this report (each pilot's counts above are of the episodes it flew). The records, "
             f"with full tracebacks, are in {FAILED_DIR}/; `uam-compare run ... --resume` flies them again."]
    if len(failed) > MAX_FAILURE_ROWS:
        notes.append(f"The first {MAX_FAILURE_ROWS} of {len(failed)} (run order).")
    header = ["scenario", "episode", "seed", "pilot", "kind", "reason", "after [s]", "where"]
    pages.add_all(F.table_pages("Failed cells: no episode", header, table, notes=notes), "failed_cells")


def _cell_rank(run: _Run, cell: tuple[str, int, str, int]) -> tuple:
    """A cell's place in run order: scenario, episode, seed, pilot."""
    scenario, episode, pilot, seed = cell
    k = run.scenarios.index(scenario) if scenario in run.scenarios else len(run.scenarios)
    return (k, scenario, episode, seed, _pilot_rank(run, pilot), pilot)


def _trace(run: _Run, entry: EpisodeEntry) -> F.FlightTrace | None:
    """The flight of one episode reduced for drawing (None: unreadable, `run.skip`)."""
    assert run.episodes is not None, "_episode_groups lists the episodes first"
    try:
        saved = run.episodes.load(entry)
    except ValueError as exc:
        run.skip(entry.name, exc)
        return None
    m = saved.meta.key.method
    return F.trace_from_episode(saved, run.label(m), run.colors.get(m, "0.3"))


def _short(text: str, n: int = 70) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= n else text[:n - 1] + "…"


__all__ = ["SUMMARY_ROWS", "build_report", "format_ci", "read_reward_curve"]
