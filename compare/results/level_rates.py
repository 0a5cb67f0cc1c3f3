"""A benchmark run's rates per vehicle, per level of its air and turbulence axes, and per pilot, with Wilson
intervals, read from the run's results (run.json and metrics.csv), never re-simulated.

The levels are read from the air each scenario flew (run.json), not from its name: a scenario's air level is
the one of `rl.task.air.AIR_LEVELS` whose field-elevation and ISA-offset ranges hold the scenario's field
("other" when none does, e.g. a scenario file of its own); its turbulence level is run.json's. Each
(vehicle, axis, level, pilot) pools its scenarios' episodes of every seed; "all" is the vehicle's whole run.
The outcomes are counted as the episodes ended: success, collision, time-out, and the rest (out of bounds, a
planner failure, a non-finite state), which `other` holds by name.
"""
from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

from compare.results.metrics import EpisodeMetrics
from compare.results.run_info import RunInfo, ScenarioInfo
from compare.results.stats import OutcomeRates
from rl.task.air import AIR_LEVELS
from uam_fdm.episode import Outcome
from uam_fdm.stats import wilson_interval

AXES = ("all", "air", "turbulence")
"""The axes of the table: the vehicle's whole run, its air levels, its turbulence levels."""
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
        key = air_level(s) if axis == "air" else (s.wind.turbulence or OTHER)
        groups.setdefault(key, []).append(s.name)
    order = [*AIR_LEVELS, OTHER] if axis == "air" else [*TURBULENCE_ORDER, OTHER]
    return sorted(groups.items(), key=lambda kv: (order.index(kv[0]) if kv[0] in order else len(order), kv[0]))


def level_rates(info: RunInfo, rows: Sequence[EpisodeMetrics]) -> list[LevelRate]:
    """Every vehicle's rates per axis, level and pilot (vehicles and pilots in run order, levels in axis order).

    Args:
        info: the run's run.json (the scenarios' air and turbulence, the pilots).
        rows: its metrics rows.
    """
    vehicles, flown = info.run_order(r.method for r in rows)
    out = []
    for vehicle in vehicles:
        mine = [s for s in info.scenarios if s.vehicle == vehicle]
        for axis in AXES:
            for level, names in _levels(axis, mine):
                wanted = set(names)
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


def level_table_lines(rates: Sequence[LevelRate]) -> list[str]:
    """The rates as text: per vehicle one row per axis level and pilot (Wilson 95 % intervals)."""
    lines: list[str] = []
    vehicle = None
    for r in rates:
        if r.vehicle != vehicle:
            vehicle = r.vehicle
            lines.append(f"{vehicle}, per air and turbulence level (Wilson 95 % intervals):")
        level = "all" if r.axis == "all" else f"{r.axis} {r.level}"
        rest = ", ".join(f"{name} {count}" for name, count in r.other)
        lines.append(f"  {level:<26} {r.pilot:<10} n {r.episodes:>4}  success {_pct(r.success, r.success_ci95)}  "
                     f"collision {_pct(r.collision, r.collision_ci95)}  time-out {_pct(r.timeout, r.timeout_ci95)}"
                     + (f"  other: {rest}" if rest else ""))
    return lines


def level_json(rates: Sequence[LevelRate]) -> dict[str, dict[str, dict[str, dict[str, dict]]]]:
    """The rates as plain data: vehicle -> axis -> level -> pilot -> episodes, rates with intervals, other."""
    out: dict[str, dict[str, dict[str, dict[str, dict]]]] = {}
    for r in rates:
        out.setdefault(r.vehicle, {}).setdefault(r.axis, {}).setdefault(r.level, {})[r.pilot] = {
            "episodes": r.episodes,
            "success": {"rate": r.success, "ci95": list(r.success_ci95)},
            "collision": {"rate": r.collision, "ci95": list(r.collision_ci95)},
            "timeout": {"rate": r.timeout, "ci95": list(r.timeout_ci95)},
            "other": dict(r.other)}
    return out
