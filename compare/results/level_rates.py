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
zero.
"""
from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from compare.results.metrics import EpisodeMetrics
from compare.results.run_info import RunInfo, ScenarioInfo
from compare.results.stats import MIN_INTERVAL_N, OutcomeRates, PairedCounts, newcombe_paired_interval
from rl.task.air import AIR_LEVELS
from uam_fdm.city.map_error import MAP_ERROR_LEVELS
from uam_fdm.episode import Outcome
from uam_fdm.sensing.specs import LEVELS as SENSING_LEVELS
from uam_fdm.stats import wilson_interval

AXES = ("all", "air", "turbulence", "sensing", "map_error", "sensing_map")
"""The axes of the table: the vehicle's whole run, its air, turbulence, sensing and map-error levels, and each
sensing and map-error pair flown ("nominal/wrong")."""
OTHER = "other"
"""The air level of a scenario whose field lies in none of `AIR_LEVELS`."""
TURBULENCE_ORDER = ("none", "light", "moderate", "severe")
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
    rates, first - second, with Newcombe's 95 % intervals.

    Attributes:
        vehicle, axis, level: as `LevelRate`'s. first, second: the pilots. pairs: cells both flew.
        success_diff, collision_diff: the differences of the rates; *_ci95: their intervals.
        success_excludes_zero, collision_excludes_zero: whether the interval excludes 0 (None below
            `MIN_INTERVAL_N` pairs: too few to call).
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
        lo, hi = newcombe_paired_interval(PairedCounts.of(x, y))
        diffs.append((float(x.mean() - y.mean()), (lo, hi), None if n < MIN_INTERVAL_N else bool(lo > 0.0 or hi < 0.0)))
    (ds, s_ci, s_ex), (dc, c_ci, c_ex) = diffs
    return LevelPair(vehicle, axis, level, a, b, n, ds, s_ci, s_ex, dc, c_ci, c_ex)


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
    differences below its pilots (Newcombe 95 % intervals)."""
    lines: list[str] = []
    vehicle = None
    by_level: dict[tuple[str, str, str], list[LevelPair]] = {}
    for p in pairs:
        by_level.setdefault((p.vehicle, p.axis, p.level), []).append(p)
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
                         f"{_diff(p.success_diff, p.success_ci95)}, collision "
                         f"{_diff(p.collision_diff, p.collision_ci95)}{few}")
    return lines


def _diff(d: float, ci: tuple[float, float]) -> str:
    return f"{d:+.1%} [{ci[0]:+.1%}, {ci[1]:+.1%}]"


def level_json(rates: Sequence[LevelRate], pairs: Sequence[LevelPair] = ()
               ) -> dict[str, dict[str, dict[str, dict[str, dict]]]]:
    """The rates as plain data: vehicle -> axis -> level -> pilot -> episodes, rates with intervals, other; and
    under the level's key "paired", "first - second" -> pairs and the differences with intervals."""
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
            "success": {"diff": p.success_diff, "ci95": list(p.success_ci95), "excludes_zero": p.success_excludes_zero},
            "collision": {"diff": p.collision_diff, "ci95": list(p.collision_ci95),
                          "excludes_zero": p.collision_excludes_zero}}
    return out
