"""The report's metrics pages for one vehicle: tables and figures from its summary and metrics rows.

A run may fly several vehicles; nothing here pools them. For each vehicle `vehicle_pages` gives, in
order: the per-pilot table (mean [95 % CI]), the forest plot of the main metrics, the paired
differences (forest plot and table, each metric's minimum detectable difference beside it), success
along task difficulty, the scenarios' conditions and the per-scenario table. `episode_table_pages`
lists its episodes (bounded: every row is in metrics.csv).

Builders take loaded data (`Summary`, `EpisodeMetrics`, `ScenarioConditions`) and a `PilotStyle`;
they return figures and never read files.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from matplotlib.figure import Figure

from compare.report.layout import Block, Paragraph, TableBlock, flow_pages, table_pages
from compare.report.summary_figures import ForestPanel, ForestRow, difficulty_figure, forest_figure
from compare.results.difficulty import ScenarioConditions, success_by_difficulty
from compare.results.metrics import EpisodeMetrics
from compare.results.stats import MIN_INTERVAL_N
from compare.results.summary import (
    NO_INTERVAL_NOTE,
    RATE_METRICS,
    BootstrapConfig,
    PairedStat,
    PairedSummary,
    Stat,
    Summary,
    format_stat,
    mdd_gap,
)

# (summary key, row label with unit, scale, decimals)
SUMMARY_ROWS: tuple[tuple[str, str, float, int], ...] = (
    ("success", "success [%]", 100.0, 0),
    ("collision", "collision [%]", 100.0, 0),
    ("min_clearance_m", "min clearance [m]", 1.0, 2),
    ("time_below_2m_s", "time below 2 m clearance [s]", 1.0, 2),
    ("time_below_5m_s", "time below 5 m clearance [s]", 1.0, 2),
    ("time_s", "flight time [s]", 1.0, 1),
    ("path_length_m", "path length [m]", 1.0, 1),
    ("spl", "SPL (success weighted by path length) [-]", 1.0, 3),
    ("energy_kj", "rotor energy [kJ]", 1.0, 2),
    ("compute_ms_mean", "compute per decision, mean [ms]", 1.0, 2),
    ("compute_ms_max", "compute per decision, max [ms]", 1.0, 2),
    ("plan_time_s", "plan time [s]", 1.0, 3),
    ("mpc_solve_ms_median", "MPC solve, median per episode [ms]", 1.0, 2),
    ("mpc_solve_ms_p95", "MPC solve, p95 per episode [ms]", 1.0, 2),
    ("mpc_failures", "MPC failed solves per episode", 1.0, 2),
    ("replans_tracking", "replans per episode: tracking error", 1.0, 2),
    ("replans_clearance", "replans per episode: predicted clearance", 1.0, 2),
    ("tracking_rms_m", "tracking RMS (distance to the reference) [m]", 1.0, 3),
    ("tracking_max_m", "tracking max (distance to the reference) [m]", 1.0, 3),
    ("planner_margin_m", "planner clearance margin [m]", 1.0, 2),
    ("mpc_margin_m", "MPC clearance margin [m]", 1.0, 2),
    ("planner_margin_floor_m", "planner clearance margin at rest [m]", 1.0, 2),
    ("planner_attempts", "planning attempts at reset", 1.0, 2),
    ("planner_wall_caps", "plans cut by the planner's wall-time cap", 1.0, 2),
    ("clearance_over_margin_min", "min clearance / margin in force", 1.0, 2),
)

# the summary figure's metrics: (summary key, panel title, scale, decimals)
FOREST_METRICS: tuple[tuple[str, str, float, int], ...] = (
    ("success", "success [%]", 100.0, 0),
    ("collision", "collision [%]", 100.0, 0),
    ("min_clearance_m", "min clearance [m]", 1.0, 2),
    ("time_s", "flight time, successes [s]", 1.0, 1),
    ("energy_kj", "rotor energy, successes [kJ]", 1.0, 2),
    ("compute_ms_mean", "compute per decision, mean [ms]", 1.0, 2),
)

# the per-scenario table's metrics: (summary key, column header, scale, decimals)
SCENARIO_COLUMNS: tuple[tuple[str, str, float, int], ...] = (
    ("success", "success [%]", 100.0, 0),
    ("collision", "collision [%]", 100.0, 0),
    ("min_clearance_m", "min clearance [m]", 1.0, 2),
    ("time_s", "time [s] (successes)", 1.0, 1),
    ("energy_kj", "energy [kJ] (successes)", 1.0, 2),
    ("compute_ms_mean", "compute mean [ms]", 1.0, 2),
)
EPISODE_ROWS_PER_VEHICLE = 104
"""Per-episode table rows shown per vehicle (4 pages); the rest are in metrics.csv."""


@dataclass(frozen=True)
class PilotStyle:
    """How pilots show: table order, display labels and colours (by pilot name)."""

    order: tuple[str, ...]
    labels: Mapping[str, str]
    colors: Mapping[str, str]

    def label(self, pilot: str) -> str:
        return self.labels.get(pilot, pilot)

    def color(self, pilot: str) -> str:
        return self.colors.get(pilot, "0.3")

    def rank(self, pilot: str) -> int:
        """The pilot's place in table order (after every known one when unknown)."""
        return self.order.index(pilot) if pilot in self.order else len(self.order)

    def sorted(self, pilots: Sequence[str]) -> list[str]:
        """`pilots` in table order (those the style does not know last, in the order given)."""
        known = [m for m in self.order if m in pilots]
        return known + [m for m in pilots if m not in known]

    def pair_label(self, pair: PairedSummary) -> str:
        return f"{self.label(pair.first)} − {self.label(pair.second)}"


def format_ci(stat: Stat | None, scale: float = 1.0, digits: int = 2) -> str:
    """"mean [low, high]" of a summary's `Stat` (a paired one: the mean difference), scaled; "mean (n=3, no CI)"
    below `MIN_INTERVAL_N` values without an interval; "n/a" if missing (`compare.results.summary.format_stat`,
    as the command line prints it)."""
    return format_stat(stat, lambda v: f"{v * scale:.{digits}f}")


def no_interval_notes(table: Sequence[Sequence[str]]) -> list[str]:
    """`NO_INTERVAL_NOTE` when a cell of `table` says "no CI", else nothing."""
    return [NO_INTERVAL_NOTE + "."] if any("no CI)" in c for row in table for c in row) else []


def _number(v: float | None, scale: float, digits: int) -> str:
    return "n/a" if v is None or not math.isfinite(v) else f"{v * scale:.{digits}f}"


def interval_words(summary: Summary) -> str:
    """How the summary's intervals were made, in words (an older summary.json: all by the bootstrap)."""
    b: BootstrapConfig = summary.bootstrap
    fields = (("resamples", b.resamples), ("confidence", b.confidence), ("seed", b.seed), ("method", b.method))
    boot = ", ".join(f"{k}={v}" for k, v in fields if v is not None)
    rates = summary.intervals.rates
    named = {"wilson": "Wilson score"}.get(rates or "", rates)
    head = f"Rates ({', '.join(summary.intervals.rate_metrics)}): {named} interval; the rest: " if rates else ""
    few = (f" Below {b.min_n} episodes (or pairs) a mean has no interval: too few to resample."
           if b.min_n is not None else "")
    return head + "percentile bootstrap over episodes" + (f" ({boot})." if boot else ".") + few


# ---- one vehicle ---------------------------------------------------------------------------------------
def vehicle_pages(vehicle: str, summary: Summary, scenarios: Mapping[str, Summary], rows: Sequence[EpisodeMetrics],
                  conditions: Mapping[str, ScenarioConditions], style: PilotStyle,
                  source: str) -> list[tuple[str, list[Figure]]]:
    """The metrics pages of one vehicle, as (page name, figures) in report order.

    Args:
        vehicle: its name.
        summary: its summary (`Summary.per_vehicle()[vehicle]`).
        scenarios: the summaries of its scenarios, by name, in run order.
        rows: its metrics rows.
        conditions: its scenarios' conditions, by name.
        style: the pilots' order, labels and colours.
        source: where the numbers come from (a sentence for the notes).
    """
    pilots = style.sorted(list(summary.pilots))
    where = f"{len(scenarios)} scenario{'s' if len(scenarios) != 1 else ''} of vehicle {vehicle}"
    slug = f"vehicle_{vehicle}"
    # the first page keeps its first file name, figures/vehicle_<vehicle>_methods.png
    out = [(f"{slug}_methods", _pilots_pages(vehicle, summary, pilots, style, where, source)),
           (f"{slug}_forest", [_forest_page(vehicle, summary, pilots, style, where)])]
    if summary.paired:
        out.append((f"{slug}_paired", _paired_pages(vehicle, summary, style)))
    axes = success_by_difficulty(rows, conditions, pilots)
    subtitle = ("Success rate per bin with its 95 % Wilson interval (wide where a bin holds few episodes); bins "
                "shared by the pilots, easier conditions on the left. Leg: straight-line start-goal distance; "
                "coverage: share of the map under building footprints (maps/*.yaml); turbulence and air density "
                "at the field from run.json.")
    out.append((f"{slug}_difficulty", [difficulty_figure(f"{vehicle}: where does each pilot break?", axes,
                                                         {m: style.label(m) for m in pilots}, style.colors,
                                                         subtitle=subtitle)]))
    out.append((f"{slug}_scenarios", scenario_pages(vehicle, scenarios, rows, conditions, style)))
    return out


def vehicle_summary_pages(vehicle: str, summary: Summary, scenarios: Mapping[str, Summary], style: PilotStyle,
                          source: str) -> list[tuple[str, list[Figure]]]:
    """The summary report's pages of one vehicle: the per-pilot table and the paired differences' forest plot.

    Args: as `vehicle_pages`'s.
    """
    pilots = style.sorted(list(summary.pilots))
    where = f"{len(scenarios)} scenario{'s' if len(scenarios) != 1 else ''} of vehicle {vehicle}"
    slug = f"vehicle_{vehicle}"
    out = [(f"{slug}_methods", _pilots_pages(vehicle, summary, pilots, style, where, source))]
    if summary.paired:
        out.append((f"{slug}_paired", _paired_pages(vehicle, summary, style)[:1]))
    return out


def _pilots_pages(vehicle: str, summary: Summary, pilots: list[str], style: PilotStyle, where: str,
                   source: str) -> list[Figure]:
    stats = summary.pilots
    keys = [k for k, *_ in SUMMARY_ROWS]
    spec = list(SUMMARY_ROWS) + [(k, k, 1.0, 3) for k in summary.metrics if k not in keys]
    table = [["episodes"] + [str(stats[m].episodes) for m in pilots]]
    for key, label, scale, digits in spec:
        if any(key in stats[m].stats and stats[m].stats[key].n for m in pilots):  # no row nobody has a value in
            table.append([label] + [format_ci(stats[m].stats.get(key), scale, digits) for m in pilots])
    reasons = [", ".join(f"{k}: {v}" for k, v in stats[m].failure_reasons.items()) or "none" for m in pilots]
    table.append(["failure reasons"] + reasons)
    notes = [f"Over the {where}, never pooled with another vehicle; {source}",
             "Cells: mean [95 % confidence interval] over episodes (flight time, path length and energy: successful "
             "ones only). " + interval_words(summary), *no_interval_notes(table)]
    return table_pages(f"{vehicle}: per pilot, mean [95 % CI]", ["metric"] + [style.label(m) for m in pilots],
                       table, notes=notes, font_size=8.5)


def _forest_page(vehicle: str, summary: Summary, pilots: list[str], style: PilotStyle, where: str) -> Figure:
    panels = []
    for key, title, scale, _ in FOREST_METRICS:
        rows = []
        for m in pilots:
            st = summary.pilots[m].stats.get(key)
            ok = st is not None and st.mean is not None
            rows.append(ForestRow(style.label(m), style.color(m), _scaled(st, "mean", scale),
                                  _scaled(st, "ci_low", scale), _scaled(st, "ci_high", scale),
                                  note=_n_note(st) if ok and st is not None else "n/a"))
        panels.append(ForestPanel(title, tuple(rows), limits=(-4.0, 104.0) if key in RATE_METRICS else None))
    subtitle = (f"Per pilot over the {where}: mean and 95 % interval (rates: Wilson; the rest: bootstrap, none below "
                f"{MIN_INTERVAL_N} episodes); n = episodes used (time and energy: successful ones).")
    return forest_figure(f"{vehicle}: summary per pilot", panels, subtitle=subtitle)


def _n_note(st: Stat) -> str:
    """A forest row's note: its n, and "no CI" where it has no interval."""
    return f"n {st.n}" + (" (no CI)" if st.ci_low is None or st.ci_high is None else "")


def _scaled(st: Stat | None, name: str, scale: float) -> float | None:
    v = None if st is None else getattr(st, name)
    return None if v is None or not math.isfinite(v) else v * scale


def mdd_words(summary: Summary) -> str:
    """What the MDD columns mean, with the summary's alpha and power."""
    p = summary.power
    if p.alpha is None or p.power is None:
        return "MDD: not recorded in this summary.json (written before it was computed)."
    return (f"MDD (minimum detectable difference): the true mean difference that n paired episodes detect with "
            f"probability {p.power:g} at two-sided alpha {p.alpha:g}: (z_{1 - p.alpha / 2:g} + z_{p.power:g}) x "
            f"sd / sqrt(n), sd the observed standard deviation of the paired differences; n/a where every pair "
            f"agreed (sd 0 says nothing) or below {MIN_INTERVAL_N} pairs. For rates also the design value before "
            f"any run: both pilots at {p.design_rate or 0.5:g}, outcomes independent. A smaller true difference is "
            f"likely to go unseen.")


def _paired_pages(vehicle: str, summary: Summary, style: PilotStyle) -> list[Figure]:
    """The paired differences of one vehicle: a forest plot (MDD beside each) and the full table."""
    pairs = summary.paired
    panels = []
    for key, title, scale, digits in FOREST_METRICS:
        rows = []
        for p in pairs:
            st = p.stats.get(key)
            excl = st.excludes_zero if st is not None else None
            mdd = "n/a" if st is None or mdd_gap(st) else mdd_cell(st, key, scale, digits)
            note = "n/a" if st is None else f"n {st.n}, " + (
                "no CI" if st.mean is not None and (st.ci_low is None or st.ci_high is None) else f"MDD {mdd}")
            rows.append(ForestRow(style.pair_label(p), "0.15", _scaled(st, "mean", scale),
                                  _scaled(st, "ci_low", scale), _scaled(st, "ci_high", scale),
                                  note=note + (" *" if excl else ""), hollow=not excl))
        unit = title.replace("success [%]", "success [% points]").replace("collision [%]", "collision [% points]")
        panels.append(ForestPanel(unit, tuple(rows), zero_line=True))
    subtitle = ("Mean paired difference (first − second; same scenario, episode and seed; time and energy where both "
                f"succeeded) with its 95 % interval (rates: Newcombe; the rest: bootstrap, none below {MIN_INTERVAL_N} "
                f"pairs). Filled and *: the interval excludes 0 (never called below {MIN_INTERVAL_N} pairs). MDD: the "
                "smallest difference these pairs detect (alpha 0.05, power 0.8); n/a where every pair agreed or "
                "pairs are too few (see the table).")
    figs = [forest_figure(f"{vehicle}: paired differences", panels, subtitle=subtitle, columns=2)]
    table = []
    for p in pairs:
        for key, label, scale, digits in SUMMARY_ROWS:
            st = p.stats.get(key)
            if st is None:
                continue
            label = label.replace("[%]", "[% points]") if key in RATE_METRICS else label
            table.append(_paired_row(style.pair_label(p), label, st, key, scale, digits))
    header = ["pair (first − second)", "metric", "pairs", "mean difference [95 % CI]", "excludes 0",
              "MDD", "MDD before any run"]
    notes = ["Rates in percentage points. " + mdd_words(summary),
             "Intervals: " + ("Newcombe's hybrid score interval for rates, the percentile bootstrap for the rest"
                              if summary.intervals.paired_rates else "the percentile bootstrap")
             + f"; below {MIN_INTERVAL_N} pairs no bootstrap interval, and no difference is said to exclude 0.",
             *no_interval_notes(table)]
    figs += table_pages(f"{vehicle}: paired differences and minimum detectable differences", header, table,
                        notes=notes, font_size=7.5, keep_columns=2)
    return figs


def _paired_row(pair: str, label: str, st: PairedStat, key: str, scale: float, digits: int) -> list[str]:
    excl = st.excludes_zero
    design = mdd_cell(st, key, scale, digits, design=True) if key in RATE_METRICS else ""
    called = ("yes" if excl else "no") if excl is not None else (
        f"n/a (n < {MIN_INTERVAL_N})" if 0 < st.n < MIN_INTERVAL_N else "n/a")
    return [pair, label, str(st.n), format_ci(st, scale, digits), called, mdd_cell(st, key, scale, digits), design]


def mdd_cell(st: PairedStat, key: str, scale: float, digits: int, design: bool = False) -> str:
    """A paired difference's MDD (or its design value) as a cell: "n/a (every pair agreed)" or "n/a (fewer than 10
    pairs)" where the observed spread says nothing (`compare.results.summary.mdd_gap`, as the command line says
    it), "> 100" for a rate no difference can reach."""
    gap = "" if design else mdd_gap(st)
    if gap:
        return f"n/a ({gap})"
    value = st.mdd_design if design else st.mdd
    if value is None:
        return "n/a"
    if key in RATE_METRICS and value > 1.0:
        return f"> {scale:.0f}"
    return _number(value, scale, digits)


def scenario_pages(vehicle: str, scenarios: Mapping[str, Summary], rows: Sequence[EpisodeMetrics],
                   conditions: Mapping[str, ScenarioConditions], style: PilotStyle) -> list[Figure]:
    """One vehicle's scenarios: their conditions, then each pilot per scenario (mean [95 % CI]), one flow of pages."""
    table = []
    for name in scenarios:
        c = conditions.get(name)
        mine = [r for r in rows if r.scenario == name]
        cells = {(r.episode, r.seed) for r in mine}
        legs = np.array([r.straight_line_m for r in mine], dtype=float)
        legs = legs[np.isfinite(legs)]
        da = None if c is None else c.density_altitude_m
        table.append([name, "n/a" if c is None else _number(c.building_coverage, 100.0, 0),
                      (c.turbulence if c is not None else None) or "n/a",
                      "n/a" if c is None else _number(c.density_kg_m3, 1.0, 3), _number(da, 1.0, 0),
                      str(len(cells)), _number(float(np.median(legs)) if legs.size else None, 1.0, 0)])
    header = ["scenario", "building coverage [%]", "turbulence", "air density [kg/m³]", "density altitude [m]",
              "episodes x seeds", "leg length, median [m]"]
    per_pilot = []
    for name, part in scenarios.items():
        for m in style.sorted(list(part.pilots)):
            ms = part.pilots[m]
            reasons = ", ".join(f"{k} {v}" for k, v in ms.failure_reasons.items()) or "none"
            per_pilot.append([name, style.label(m), str(ms.episodes)]
                             + [format_ci(ms.stats.get(k), scale, digits) for k, _, scale, digits in SCENARIO_COLUMNS]
                             + [reasons])
    pilot_header = ["scenario", "pilot", "episodes"] + [h for _, h, *_ in SCENARIO_COLUMNS] + ["failures"]
    blocks: list[Block] = [TableBlock(tuple(header), tuple(map(tuple, table)), 8.0,
                                      caption="The scenarios and their conditions")]
    blocks.append(TableBlock(tuple(pilot_header), tuple(map(tuple, per_pilot)), 7.5, keep_columns=2,
                             caption="Each pilot per scenario, mean [95 % CI]") if per_pilot
                  else Paragraph("No scenario summaries."))
    notes = ["Building coverage: share of the map's area under building footprints (maps/<scenario>.yaml). "
             "Density altitude: the ISA altitude with the field's air density.",
             "Per pilot: mean [95 % CI] within the scenario (rates: Wilson; the rest: bootstrap).",
             *no_interval_notes(per_pilot)]
    return flow_pages(f"{vehicle}: per scenario", blocks, notes=notes)


def episode_table_pages(vehicle: str, rows: Sequence[EpisodeMetrics], style: PilotStyle,
                        scenario_order: Sequence[str], max_rows: int = EPISODE_ROWS_PER_VEHICLE) -> list[Figure]:
    """One vehicle's episodes, one row per metrics.csv row in run order, at most `max_rows` (a note says so)."""
    def order(r: EpisodeMetrics) -> tuple:
        k = scenario_order.index(r.scenario) if r.scenario in scenario_order else len(scenario_order)
        return (k, r.scenario, r.episode, r.seed, style.rank(r.method), r.method)

    ordered = sorted(rows, key=order)
    shown = ordered[:max_rows]
    table = [[r.scenario, str(r.episode), str(r.seed), style.label(r.method), r.outcome,
              _number(r.min_clearance_m, 1.0, 2), _number(r.time_s, 1.0, 1), _number(r.energy_kj, 1.0, 2)]
             for r in shown]
    header = ["scenario", "episode", "seed", "pilot", "outcome", "min clearance [m]", "time [s]", "energy [kJ]"]
    note = (f"{len(rows)} rows of metrics.csv." if len(shown) == len(rows) else
            f"The first {len(shown)} of {len(rows)} rows of metrics.csv (run order); every row is in metrics.csv.")
    return table_pages(f"{vehicle}: per episode", header, table, notes=[note], keep_columns=4)
