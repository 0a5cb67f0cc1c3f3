"""The PDF report of a comparison run, built from the run folder's saved files only (never simulating).

A run folder holds `run.json` (provenance), `maps/<scenario>.yaml`, the episodes (`store/`, or
`episodes/*.npz` in a folder saved before the store: `compare.results.episodes`), `metrics.csv` and
`summary.json`.  `build_report` writes, in order (`compare.report.title_page` for 1):

1. "uam-compare report": the headline, per vehicle and pilot success and collisions with Wilson intervals and
   the pilots' paired differences; "About this run": task set and version (a benchmark run), scenarios, pilots,
   notes, fairness, software versions, with no path of the machine that made the run;
2. per vehicle, never pooled across vehicles (`compare.report.metrics_pages`): per-pilot mean [95 % CI]
   table, summary forest plot, paired differences with their minimum detectable differences, success
   along task difficulty, the scenarios' conditions, per-scenario and per-episode tables (bounded);
   then the classical pilot's tracker per scenario; a robustness-sweep run's rates against density altitude
   and wind, then against the map's missing share, the GNSS sky and the lidar range, per vehicle
   (`compare.report.sweep_pages`); a run flown at several sensing or map-error levels, its
   rates against them per vehicle (`compare.report.degradation_pages`);
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
present are used; a missing `metrics.csv` is noted instead of failing). Every page carries its number, every
table fits its page (`compare.report.layout`), and the PDF's outline has an entry per section (pypdf writes it:
matplotlib's PdfPages has no outline). The PDF is written under a temporary name and renamed; every page is also
saved as a PNG under `RUN_DIR/figures/`. `build_report(..., summary=True)` writes the summary report instead,
RUN_DIR/report-summary.pdf: the first pages, per vehicle the pilots' table and their paired differences, and
the failures listed.
"""
from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from matplotlib import rc_context
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure

from compare.flying import pilots
from compare.report import figures as F
from compare.report.degradation_pages import degradation_pages
from compare.report.flight_figures import (
    episode_paths_figure,
    episode_snapshots_figure,
    episode_timeseries_figure,
    failure_paths_figure,
)
from compare.report.layout import table_pages, text_pages
from compare.report.learning_pages import learning_figures
from compare.report.metrics_pages import (
    SUMMARY_ROWS,
    PilotStyle,
    episode_table_pages,
    format_ci,
    vehicle_pages,
    vehicle_summary_pages,
)
from compare.report.pdf_pages import PNG_DPI, PageWriter, add_outline
from compare.report.sweep_pages import sweep_pages
from compare.report.title_page import TitleFacts, about_pages, headline_pages, shown_path
from compare.report.tracker_pages import mapping_pages, tracker_pages
from compare.report.training_pages import ppo_policies, read_reward_curve, training_figure
from compare.results.difficulty import scenario_conditions
from compare.results.episodes import EpisodeEntry, RunEpisodes, open_episodes
from compare.results.failures import FAILED_DIR, describe_failures, read_failures
from compare.results.metrics import EpisodeMetrics, cell_order, read_metrics_csv
from compare.results.run_info import RunInfo, read_run_info
from compare.results.summary import Summary, read_summary_json, summarize_run
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.city.mapfile import load_map_file
from uam_fdm.episode import Outcome
from uam_fdm.files.atomic import atomic_path

logger = logging.getLogger(__name__)

MAX_FAILURE_PLOTS = 6
MAX_FAILURE_ROWS = 130
"""Failures listed one by one (5 pages); every one is in metrics.csv."""
SUMMARY_FAILURE_ROWS = 25
"""Failures listed in the summary report (one page); the full report lists `MAX_FAILURE_ROWS`."""
DRAWN_SCENARIOS_PER_VEHICLE = 3
DRAWN_FLIGHTS_PER_SCENARIO = 3
"""Flight pages (three per task) are drawn for this many scenarios per vehicle and tasks per scenario."""


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


REPORT_NAME = "report.pdf"
SUMMARY_NAME = "report-summary.pdf"
"""The full report and the summary report (`build_report(..., summary=True)`), in the run folder."""


@F.plain_text
def build_report(run_dir: Path, out: Path | None = None, *, warn_unreadable: bool = True,
                 summary: bool = False) -> Path:
    """Write the run's PDF report (and, the full one, its pages as PNGs under RUN_DIR/figures/).

    Every page carries its number; the PDF's outline (bookmarks) has an entry per section and page group. An
    unreadable (corrupt, truncated) episode file is left out, logged and listed on the failures page.

    Args:
        run_dir: the run folder.
        out: the PDF path (default RUN_DIR/report.pdf, or RUN_DIR/report-summary.pdf); written atomically.
        warn_unreadable: log skipped episode files as warnings (False: at INFO, the caller has warned).
        summary: a report of a few pages: the headline, the run, per vehicle the pilots' table and their paired
            differences, and the failures listed (no PNGs are written).

    Returns:
        The PDF path.

    Raises:
        ValueError: `run_dir` has no readable run.json.
    """
    run_dir = Path(run_dir)
    run = _make_run(run_dir, read_run_info(run_dir))
    run.skip_log_level = logging.WARNING if warn_unreadable else logging.INFO
    root = run_dir if out is None else None  # the run's own report: no link in the run folder followed
    out = Path(out) if out is not None else run_dir / (SUMMARY_NAME if summary else REPORT_NAME)
    out.parent.mkdir(parents=True, exist_ok=True)
    groups = _episode_groups(run)
    rows, why = _read_metrics(run_dir / "metrics.csv")
    parts, source, why = _parts_or_why(run, rows, why)
    with atomic_path(out, suffix=".pdf.tmp", root=root) as tmp:
        # TrueType (Type 42) fonts: text stays searchable and journals accept the pages
        metadata = {"Title": "uam-compare report" + (" (summary)" if summary else ""), "Creator": "uam-compare",
                    "Subject": run.info.command, "CreationDate": None}
        with rc_context({"pdf.fonttype": 42}), PdfPages(tmp, metadata=metadata) as pdf:
            pages = _PageWriter(pdf, None if summary else run_dir / "figures", run_dir)
            facts = TitleFacts(run_dir, run.info, run.label, sum(len(p) for p in groups.values()),
                               _planned_episodes(run), None if parts is None else
                               {v: part.summary for v, part in parts.items()}, run.style(), source, why)
            pages.add_all(headline_pages(facts, summary), "title")
            pages.add_all(about_pages(facts, compact=summary), "about", "About this run")
            if summary:
                _summary_pages(run, rows, parts, source, why, pages)
            else:
                _full_pages(run, groups, rows, parts, source, why, pages)
        add_outline(tmp, pages.outline)
    pages.remove_stale_pngs()
    logger.info("report %s: %d pages", out, pages.count)
    return out


def _full_pages(run: _Run, groups: dict[tuple[str, int, int], list[EpisodeEntry]], rows: list[EpisodeMetrics] | None,
                parts: dict[str, _VehiclePart] | None, source: str, why: str, pages: _PageWriter) -> None:
    """The full report after its first pages: metrics per vehicle, tracker, sweep, flights, training, failures."""
    for section, name, figs in _metrics_pages(run, rows, parts, source, why):
        pages.add_all(figs, name, section)
    for name, fig in sweep_pages(run.info, rows or [], run.style()):  # a sweep run's rates per step
        pages.add(fig, name, "Robustness sweep")
    for name, fig in degradation_pages(run.info, rows or [], run.style()):  # rates per sensing and map level
        pages.add(fig, name, "Degradation")
    drawn, left_out = _drawn_groups(run, groups, rows)
    if left_out:
        pages.add_all(text_pages("Flights", left_out), "flights_drawn", "Flights")
    failures = _episode_pages(run, drawn, pages)
    policies = ppo_policies(run.info)
    for k, pol in enumerate(policies or [None]):  # one convergence page per policy flown
        suffix = "" if k == 0 or pol is None else f"_{pol.vehicle or k}"
        pages.add(training_figure(pol, len(policies) > 1, lambda p: _shown(run, p)), f"training_reward_curve{suffix}",
                  "Training")
        if pol is not None and pol.policy_dir:  # beside it, its recorded flights (none: no page)
            title = "Learning in pictures" + (f" ({pol.vehicle})" if len(policies) > 1 and pol.vehicle else "")
            pages.add_all(learning_figures(Path(pol.policy_dir), title), f"learning_in_pictures{suffix}", "Training")
    _failure_pages(run, failures, rows, pages)


def _summary_pages(run: _Run, rows: list[EpisodeMetrics] | None, parts: dict[str, _VehiclePart] | None,
                   source: str, why: str, pages: _PageWriter) -> None:
    """The summary report after its first pages: per vehicle the pilots' table and their paired differences, then
    the failures listed."""
    if parts is None:
        pages.add_all(text_pages("Metrics", [("p", why)]), "metrics", "Metrics")
        return
    style = run.style()
    for vehicle, part in parts.items():
        for name, figs in vehicle_summary_pages(vehicle, part.summary, part.scenarios, style, source):
            pages.add_all(figs, name, vehicle)
    _failure_pages(run, [], rows, pages, draw=False)


_PageWriter = PageWriter  # its name here before it had a module of its own


# ---- assembly helpers -----------------------------------------------------------------------------------
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


def _float(v: object) -> float:
    try:
        return float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return math.nan


def _fmt(v: object, digits: int, scale: float = 1.0) -> str:
    f = _float(v)
    return f"{f * scale:.{digits}f}" if math.isfinite(f) else "n/a"


# ---- 1. title -------------------------------------------------------------------------------------------
def _planned_episodes(run: _Run) -> int:
    return sum((s.episodes or 0) * len(s.seeds or [0]) * len(s.pilots or run.pilots) for s in run.info.scenarios)


# ---- 2. metrics -----------------------------------------------------------------------------------------
def _read_metrics(path: Path) -> tuple[list[EpisodeMetrics] | None, str]:
    """The rows of metrics.csv, or None and why (the file is missing or unreadable: logged)."""
    if not path.is_file():
        return None, "metrics.csv was not found in the run folder"
    try:
        return read_metrics_csv(path), ""
    except (OSError, ValueError) as exc:
        logger.warning("%s unreadable (%s): the metrics tables are skipped", path, exc)
        return None, f"metrics.csv could not be read ({str(exc).replace(str(path.parent) + os.sep, '')})"


def _read_summary(path: Path) -> Summary | None:
    if not path.is_file():
        return None
    try:
        return read_summary_json(path)
    except ValueError as exc:  # the message names the file
        logger.warning("summary unreadable (%s): means without confidence intervals", exc)
        return None


def _parts_or_why(run: _Run, rows: list[EpisodeMetrics] | None, why: str
                  ) -> tuple[dict[str, _VehiclePart] | None, str, str]:
    """Each vehicle's part (`_vehicle_parts`) and where its numbers come from; or None and why there are none."""
    if rows is None:
        return None, "", (f"{why}: the metrics tables are skipped. The uam-compare CLI recomputes metrics from the "
                          "saved episodes before building the report.")
    for m in dict.fromkeys(r.method for r in rows):  # a pilot only metrics.csv names still gets a label and colour
        if m not in run.pilots:
            run.add_pilot(m)
    try:
        parts, source = _vehicle_parts(run, rows)
    except ValueError as exc:  # e.g. a hand-edited metrics.csv with a cell twice
        logger.warning("metrics not summarised (%s)", exc)
        return None, "", f"The metrics could not be summarised: {exc}"
    return parts, source, ""


def _metrics_pages(run: _Run, rows: list[EpisodeMetrics] | None, parts: dict[str, _VehiclePart] | None,
                   source: str, why: str) -> list[tuple[str, str, list[Figure]]]:
    """(section, page name, figures): per vehicle its metrics pages (`compare.report.metrics_pages`), then the
    tracker pages; a page saying why when there are no metrics."""
    if rows is None or parts is None:
        return [("", "metrics", text_pages("Metrics", [("p", why)]))]
    style = run.style()
    conditions = {s.name: scenario_conditions(s, run.map_of(s.name)) for s in run.info.scenarios}
    out: list[tuple[str, str, list[Figure]]] = []
    for vehicle, part in parts.items():
        out += [(vehicle, name, figs) for name, figs in
                vehicle_pages(vehicle, part.summary, part.scenarios, part.rows, conditions, style, source)]
        out.append((vehicle, f"vehicle_{vehicle}_episodes",
                    episode_table_pages(vehicle, part.rows, style, run.scenarios)))
    tracker = [fig for m in run.pilots for fig in (*tracker_pages(run.label(m), rows, m),
                                                    *mapping_pages(run.label(m), rows, m))]
    if tracker:
        out.append(("", "metrics_tracker", tracker))
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
        pages.add(episode_paths_figure(f"{title}: paths", traces, bmap), f"{name}_paths", "Flights")
        pages.add(episode_timeseries_figure(f"{title}: clearance, speed and rotors over time", traces),
                  f"{name}_timeseries", "Flights", bookmark=False)
        pages.add(episode_snapshots_figure(f"{title}: snapshots over time", traces, bmap),
                  f"{name}_snapshots", "Flights", bookmark=False)
    return failures


def _shown(run: _Run, path: Path) -> str:
    """A path as the report shows it (`compare.report.title_page.shown_path`)."""
    return shown_path(str(path), run.run_dir, run.info.command)


# ---- 5. failures ----------------------------------------------------------------------------------------
def _failure_pages(run: _Run, failures: list[F.FlightTrace], rows: list[EpisodeMetrics] | None,
                   pages: _PageWriter, draw: bool = True) -> None:
    """The failures table (the first `MAX_FAILURE_ROWS`, run order) and top-down views of up to six; `failures`: the
    failed flights drawn (their detail is known), the others come from metrics.csv. `draw` False (the summary
    report): the first `SUMMARY_FAILURE_ROWS` listed, no views."""
    most = MAX_FAILURE_ROWS if draw else SUMMARY_FAILURE_ROWS
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
        pages.add_all(text_pages("Failures", [("p", "No failures: every episode in this report succeeded.")]
                                 + [("p", n) for n in notes]), "failures", "Failures")
        return
    if len(entries) > most:
        notes.insert(0, f"The first {most} of {len(entries)} failures (run order); every one is in "
                        f"metrics.csv.")
    header = ["scenario", "episode", "seed", "pilot", "failure reason", "detail", "time [s]"]
    pages.add_all(table_pages("Failures", header, [e for _, e in entries[:most]], notes=notes,
                              keep_columns=4), "failures_table", "Failures")
    if not draw:
        return
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
        pages.add(failure_paths_figure(f"Failures: where the flights ended ({count})",
                                       [(t, run.map_of(t.episode.key.scenario)) for t in shown]), "failures_paths",
                  "Failures")


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
    pages.add_all(table_pages("Failed cells: no episode", header, table, notes=notes, keep_columns=4), "failed_cells",
                  "Failures")


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


__all__ = ["PNG_DPI", "REPORT_NAME", "SUMMARY_NAME", "SUMMARY_ROWS", "build_report", "format_ci", "ppo_policies",
           "read_reward_curve"]
