"""A benchmark run's rates per vehicle, per level of its air, turbulence, sensing and map-error axes (and of each
sensing x map-error pair), and per pilot, with Wilson intervals, and per level the paired differences of every two
pilots' rates (Newcombe intervals), read from the run's results (run.json and metrics.csv), never re-simulated.

The levels are read from what each scenario flew (run.json), not from its name: a scenario's air level is
the one of `rl.task.air.AIR_LEVELS` whose field-elevation and ISA-offset ranges hold the scenario's field
("other" when none does, e.g. a scenario file of its own); its turbulence, sensing and map-error levels are
run.json's. Each (vehicle, axis, level, pilot) pools its scenarios' episodes of every seed; "all" is the vehicle's
whole run. The outcomes are counted as the episodes ended: success, collision, time-out, and the rest (out of
bounds, a planner failure, a non-finite state), which `other` holds by name. Two pilots are paired on the cells
(scenario, episode, seed) both flew at the level; below `MIN_INTERVAL_N` pairs no difference is said to exclude
zero. Each paired difference also has its minimum detectable difference (`compare.results.stats.paired_mdd`, at
`MDD_ALPHA` and `MDD_POWER`, from the discordance observed there; none below `MIN_INTERVAL_N` pairs), and each
vehicle's pairs of pilots a summary of their success MDDs: overall and the largest at any level of one axis
(`LevelMdd`).
"""
from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from compare.results.metrics import EpisodeMetrics
from compare.results.run_info import RunInfo, ScenarioInfo
from compare.results.stats import MIN_INTERVAL_N, OutcomeRates, PairedCounts, newcombe_paired_interval, paired_mdd
from rl.task.air import AIR_LEVELS
from uam_fdm.city.map_error import MAP_ERROR_LEVELS
from uam_fdm.episode import Outcome
from uam_fdm.sensing.specs import LEVELS as SENSING_LEVELS
from uam_fdm.stats import wilson_interval

AXES = ("all", "air", "turbulence", "sensing", "map_error", "sensing_map")
"""The axes of the table: the vehicle's whole run, its air, turbulence, sensing and map-error levels, and each
sensing and map-error pair flown ("nominal/wrong")."""
LEVEL_AXES = ("air", "turbulence", "sensing", "map_error")
"""The axes whose levels `LevelMdd` takes the largest MDD over: not the sensing x map-error pairs, each a fraction
of a level's cells (a ninth when both axes have three levels), whose MDD no run sized for the levels keeps small."""
OTHER = "other"
"""The air level of a scenario whose field lies in none of `AIR_LEVELS`."""
TURBULENCE_ORDER = ("none", "light", "moderate", "severe")
MDD_ALPHA = 0.05
"""Two-sided significance level of the paired MDDs."""
MDD_POWER = 0.8
"""Power of the paired MDDs: the probability of detecting a true difference of that size."""
_TOLERANCE = 1e-6  # a field on a level's edge belongs to it (the generator rounds nothing here, but files may)


@dataclass(frozen=True)
class LevelRate(OutcomeRates):
    """One pilot's outcomes at one level of one axis of a vehicle's run.

    Attributes:
        vehicle: the vehicle preset. axis: one of `AXES`. level: the level's name ("all" on the "all" axis).
        pilot: the pilot's name. episodes: episodes flown (all seeds).
        successes, collisions, timeouts: their counts; other: the remaining outcomes, (name, count), by count.
        success_ci95, collision_ci95, timeout_ci95: 95 % Wilson intervals of the rates.
    """

    vehicle: str
    axis: str
    level: str
    pilot: str
    episodes: int
    successes: int
    collisions: int
    timeouts: int
    other: tuple[tuple[str, int], ...]
    success_ci95: tuple[float, float]
    collision_ci95: tuple[float, float]
    timeout_ci95: tuple[float, float]

    @property
    def timeout(self) -> float:
        """Time-out rate (NaN without episodes)."""
        return self.timeouts / self.episodes if self.episodes else math.nan


def air_level(s: ScenarioInfo) -> str:
    """The name of the `AIR_LEVELS` level whose ranges hold the scenario's field, else `OTHER` (also when the
    field was not recorded)."""
    elevation, offset = s.atmosphere.elevation_m, s.atmosphere.isa_offset_k
    if elevation is None or offset is None:
        return OTHER
    for name, level in AIR_LEVELS.items():
        (e0, e1), (t0, t1) = level.elevation_m, level.isa_offset_k
        if e0 - _TOLERANCE <= elevation <= e1 + _TOLERANCE and t0 - _TOLERANCE <= offset <= t1 + _TOLERANCE:
            return name
    return OTHER


def _levels(axis: str, scenarios: Sequence[ScenarioInfo]) -> list[tuple[str, list[str]]]:
    """One axis's levels (in the axis's order, only those flown) with their scenarios' names."""
    if axis == "all":
        return [("all", [s.name for s in scenarios])]
    groups: dict[str, list[str]] = {}
    for s in scenarios:
        groups.setdefault(_level_of(axis, s), []).append(s.name)
    order = {"air": [*AIR_LEVELS, OTHER], "turbulence": [*TURBULENCE_ORDER, OTHER], "sensing": list(SENSING_LEVELS),
             "map_error": list(MAP_ERROR_LEVELS),
             "sensing_map": [f"{a}/{b}" for a in SENSING_LEVELS for b in MAP_ERROR_LEVELS]}[axis]
    return sorted(groups.items(), key=lambda kv: (order.index(kv[0]) if kv[0] in order else len(order), kv[0]))


def _level_of(axis: str, s: ScenarioInfo) -> str:
    """Scenario `s`'s level on `axis` (not "all")."""
    if axis == "air":
        return air_level(s)
    if axis == "turbulence":
        return s.wind.turbulence or OTHER
    if axis == "sensing":
        return s.sensing
    if axis == "map_error":
        return s.map_error
    return f"{s.sensing}/{s.map_error}"


@dataclass(frozen=True)
class LevelPair:
    """Two pilots on the same cells of one level of one axis of a vehicle's run: the paired differences of their
    rates, first - second, with Newcombe's 95 % intervals and their minimum detectable differences.

    Attributes:
        vehicle, axis, level: as `LevelRate`'s. first, second: the pilots. pairs: cells both flew.
        success_diff, collision_diff: the differences of the rates; *_ci95: their intervals.
        success_excludes_zero, collision_excludes_zero: whether the interval excludes 0 (None below
            `MIN_INTERVAL_N` pairs: too few to call).
        success_mdd, collision_mdd: the smallest true difference (either sign) detected at `MDD_ALPHA` with
            `MDD_POWER`, from the observed discordance (`paired_mdd`), a fraction like the rates; NaN below
            `MIN_INTERVAL_N` pairs, as no MDD is derived from so few.
    """

    vehicle: str
    axis: str
    level: str
    first: str
    second: str
    pairs: int
    success_diff: float
    success_ci95: tuple[float, float]
    success_excludes_zero: bool | None
    collision_diff: float
    collision_ci95: tuple[float, float]
    collision_excludes_zero: bool | None
    success_mdd: float
    collision_mdd: float


def _groups(info: RunInfo, rows: Sequence[EpisodeMetrics]) -> Iterator[tuple[str, str, str, set[str], list[str]]]:
    """Each (vehicle, axis, level) flown, with its scenarios' names and the run's pilots (in run order)."""
    vehicles, flown = info.run_order(r.method for r in rows)
    for vehicle in vehicles:
        mine = [s for s in info.scenarios if s.vehicle == vehicle]
        for axis in AXES:
            for level, names in _levels(axis, mine):
                yield vehicle, axis, level, set(names), list(flown)


def level_pairs(info: RunInfo, rows: Sequence[EpisodeMetrics]) -> list[LevelPair]:
    """Every vehicle's paired differences per axis, level and pair of pilots (in run order), on the cells
    (scenario, episode, seed) both pilots flew at the level."""
    out = []
    for vehicle, axis, level, wanted, flown in _groups(info, rows):
        cells = {p: {(r.scenario, r.episode, r.seed): r for r in rows if r.method == p and r.scenario in wanted}
                 for p in flown}
        for i, a in enumerate(flown):
            for b in flown[i + 1:]:
                both = sorted(cells[a].keys() & cells[b].keys())
                if both:
                    out.append(_pair(vehicle, axis, level, a, b, [cells[a][c] for c in both],
                                     [cells[b][c] for c in both]))
    return out


def _pair(vehicle: str, axis: str, level: str, a: str, b: str, first: Sequence[EpisodeMetrics],
          second: Sequence[EpisodeMetrics]) -> LevelPair:
    n = len(first)
    diffs = []
    for outcome in ("success", "collision"):
        x = np.array([bool(getattr(r, outcome)) for r in first])
        y = np.array([bool(getattr(r, outcome)) for r in second])
        counts = PairedCounts.of(x, y)
        lo, hi = newcombe_paired_interval(counts)
        few = n < MIN_INTERVAL_N
        diffs.append((float(x.mean() - y.mean()), (lo, hi), None if few else bool(lo > 0.0 or hi < 0.0),
                      math.nan if few else paired_mdd(counts, MDD_ALPHA, MDD_POWER)))
    (ds, s_ci, s_ex, s_mdd), (dc, c_ci, c_ex, c_mdd) = diffs
    return LevelPair(vehicle, axis, level, a, b, n, ds, s_ci, s_ex, dc, c_ci, c_ex, s_mdd, c_mdd)


@dataclass(frozen=True)
class LevelMdd:
    """One pair of pilots' minimum detectable success differences over one vehicle's run (`LevelPair.success_mdd`,
    fractions like the rates).

    Attributes:
        vehicle, first, second: as `LevelPair`'s.
        overall: the MDD on the whole run (axis "all"; NaN when it has too few pairs).
        max_per_level: the largest MDD at any level of the `LEVEL_AXES` (NaN when none has one).
        max_axis, max_level: where it is ("" when none).
        too_few: those levels without an MDD (fewer than `MIN_INTERVAL_N` pairs), left out of the largest.
    """

    vehicle: str
    first: str
    second: str
    overall: float
    max_per_level: float
    max_axis: str
    max_level: str
    too_few: int


def level_mdds(pairs: Sequence[LevelPair]) -> list[LevelMdd]:
    """Per vehicle and pair of pilots (in the order of `pairs`), the success MDD overall and the largest at any level
    of the `LEVEL_AXES` (the first in table order when several are as large)."""
    groups: dict[tuple[str, str, str], list[LevelPair]] = {}
    for p in pairs:
        groups.setdefault((p.vehicle, p.first, p.second), []).append(p)
    out = []
    for (vehicle, first, second), mine in groups.items():
        overall = next((p.success_mdd for p in mine if p.axis == "all"), math.nan)
        levels = [p for p in mine if p.axis in LEVEL_AXES]
        known = [p for p in levels if math.isfinite(p.success_mdd)]
        worst = max(known, key=lambda p: p.success_mdd, default=None)
        out.append(LevelMdd(vehicle, first, second, overall, math.nan if worst is None else worst.success_mdd,
                            "" if worst is None else worst.axis, "" if worst is None else worst.level,
                            len(levels) - len(known)))
    return out


def level_rates(info: RunInfo, rows: Sequence[EpisodeMetrics]) -> list[LevelRate]:
    """Every vehicle's rates per axis, level and pilot (vehicles and pilots in run order, levels in axis order).

    Args:
        info: the run's run.json (the scenarios' air and turbulence, the pilots).
        rows: its metrics rows.
    """
    out = []
    for vehicle, axis, level, wanted, flown in _groups(info, rows):
        for pilot in flown:
            cells = [r for r in rows if r.method == pilot and r.scenario in wanted]
            if cells:
                out.append(_rate(vehicle, axis, level, pilot, cells))
    return out


def _rate(vehicle: str, axis: str, level: str, pilot: str, cells: Sequence[EpisodeMetrics]) -> LevelRate:
    n = len(cells)
    ok = sum(bool(r.success) for r in cells)
    hit = sum(bool(r.collision) for r in cells)
    late = sum(1 for r in cells if not r.success and not r.collision and r.outcome == Outcome.TIMEOUT.value)
    rest = Counter(r.failure_reason or r.outcome for r in cells
                   if not r.success and not r.collision and r.outcome != Outcome.TIMEOUT.value)
    return LevelRate(vehicle, axis, level, pilot, n, ok, hit, late, tuple(rest.most_common()),
                     wilson_interval(ok, n), wilson_interval(hit, n), wilson_interval(late, n))


def _pct(rate: float, ci: tuple[float, float]) -> str:
    return f"{rate:6.1%} [{ci[0]:.1%}, {ci[1]:.1%}]"


def level_table_lines(rates: Sequence[LevelRate], pairs: Sequence[LevelPair] = ()) -> list[str]:
    """The rates as text: per vehicle one row per axis level and pilot (Wilson 95 % intervals), each level's paired
    differences below its pilots (Newcombe 95 % intervals, with their MDDs), and after the vehicle's rows a line of
    its success MDDs per pair of pilots (`level_mdds`)."""
    lines: list[str] = []
    vehicle = None
    by_level: dict[tuple[str, str, str], list[LevelPair]] = {}
    for p in pairs:
        by_level.setdefault((p.vehicle, p.axis, p.level), []).append(p)
    summaries = level_mdds(pairs)
    for k, r in enumerate(rates):
        if r.vehicle != vehicle:
            vehicle = r.vehicle
            lines.append(f"{vehicle}, per air, turbulence, sensing and map-error level (Wilson 95 % intervals; "
                         f"paired differences with Newcombe 95 % intervals):")
        level = "all" if r.axis == "all" else f"{r.axis} {r.level}"
        rest = ", ".join(f"{name} {count}" for name, count in r.other)
        lines.append(f"  {level:<26} {r.pilot:<10} n {r.episodes:>4}  success {_pct(r.success, r.success_ci95)}  "
                     f"collision {_pct(r.collision, r.collision_ci95)}  time-out {_pct(r.timeout, r.timeout_ci95)}"
                     + (f"  other: {rest}" if rest else ""))
        last = k + 1 == len(rates) or (rates[k + 1].vehicle, rates[k + 1].axis, rates[k + 1].level) != (
            r.vehicle, r.axis, r.level)
        for p in by_level.get((r.vehicle, r.axis, r.level), []) if last else []:
            few = "" if p.pairs >= MIN_INTERVAL_N else f" (fewer than {MIN_INTERVAL_N} pairs: too few to call)"
            lines.append(f"  {'':<26} {p.first} - {p.second}: {p.pairs} pairs, success "
                         f"{_diff(p.success_diff, p.success_ci95)} (MDD {_points(p.success_mdd)}), collision "
                         f"{_diff(p.collision_diff, p.collision_ci95)} (MDD {_points(p.collision_mdd)}){few}")
        mine = [m for m in summaries if m.vehicle == r.vehicle]
        if mine and (k + 1 == len(rates) or rates[k + 1].vehicle != r.vehicle):
            lines.append(_mdd_line(r.vehicle, mine))
    return lines


def _diff(d: float, ci: tuple[float, float]) -> str:
    return f"{d:+.1%} [{ci[0]:+.1%}, {ci[1]:+.1%}]"


def _points(fraction: float) -> str:
    """A difference as a fraction, in percentage points ("n/a" for NaN)."""
    return f"{100.0 * fraction:.1f} points" if math.isfinite(fraction) else "n/a"


def _mdd_line(vehicle: str, summaries: Sequence[LevelMdd]) -> str:
    """One vehicle's success MDDs per pair of pilots, overall and the largest per level, on one line."""
    parts = []
    for m in summaries:
        where = f" ({m.max_axis} {m.max_level})" if m.max_axis else ""
        left = (f", {m.too_few} level{'s' if m.too_few != 1 else ''} with fewer than {MIN_INTERVAL_N} pairs left out"
                if m.too_few else "")
        parts.append(f"{m.first} - {m.second} overall {_points(m.overall)}, per level at most "
                     f"{_points(m.max_per_level)}{where}{left}")
    return (f"{vehicle} MDD of paired success differences (alpha {MDD_ALPHA:g}, power {MDD_POWER:g}, from the "
            f"observed discordance): " + "; ".join(parts))


def level_json(rates: Sequence[LevelRate], pairs: Sequence[LevelPair] = ()
               ) -> dict[str, dict[str, dict[str, dict[str, dict]]]]:
    """The rates as plain data: vehicle -> axis -> level -> pilot -> episodes, rates with intervals, other; and
    under the level's key "paired", "first - second" -> pairs and the differences with intervals and MDDs (NaN
    below `MIN_INTERVAL_N` pairs). The per-vehicle MDD summary is `level_mdd_json`'s, kept apart so that a
    vehicle's keys stay its axes."""
    out: dict[str, dict[str, dict[str, dict[str, dict]]]] = {}
    for r in rates:
        out.setdefault(r.vehicle, {}).setdefault(r.axis, {}).setdefault(r.level, {})[r.pilot] = {
            "episodes": r.episodes,
            "success": {"rate": r.success, "ci95": list(r.success_ci95)},
            "collision": {"rate": r.collision, "ci95": list(r.collision_ci95)},
            "timeout": {"rate": r.timeout, "ci95": list(r.timeout_ci95)},
            "other": dict(r.other)}
    for p in pairs:
        level = out.setdefault(p.vehicle, {}).setdefault(p.axis, {}).setdefault(p.level, {})
        level.setdefault("paired", {})[f"{p.first} - {p.second}"] = {
            "pairs": p.pairs,
            "success": {"diff": p.success_diff, "ci95": list(p.success_ci95), "excludes_zero": p.success_excludes_zero,
                        "mdd": p.success_mdd},
            "collision": {"diff": p.collision_diff, "ci95": list(p.collision_ci95),
                          "excludes_zero": p.collision_excludes_zero, "mdd": p.collision_mdd}}
    return out


def level_mdd_json(summaries: Sequence[LevelMdd]) -> dict[str, dict[str, dict[str, object]]]:
    """The success MDD summaries as plain data: vehicle -> "first - second" -> overall, max_per_level (fractions;
    NaN when none), max_level ("axis level", "" when none), levels_too_few, alpha and power."""
    out: dict[str, dict[str, dict[str, object]]] = {}
    for m in summaries:
        out.setdefault(m.vehicle, {})[f"{m.first} - {m.second}"] = {
            "overall": m.overall, "max_per_level": m.max_per_level,
            "max_level": f"{m.max_axis} {m.max_level}" if m.max_axis else "", "levels_too_few": m.too_few,
            "alpha": MDD_ALPHA, "power": MDD_POWER}
    return out
