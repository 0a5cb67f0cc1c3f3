"""A robustness sweep's rates: success and collision per vehicle, axis, step and pilot, with Wilson intervals,
read from a run's results (run.json and metrics.csv), never re-simulated.

The axes are read from the air each scenario flew (run.json), not from names: the wind axis is the scenarios
at sea level on a standard day (elevation 0, ISA +0 K), stepped by steady wind speed; the density-altitude
axis is the scenarios in the one wind that every raised or warmed field flies (`compare.scenarios.sweep`: the
vehicle's low wind), sea level in that wind included, stepped by field. A step pools its scenarios' episodes
(one per city in `compare.scenarios.sweep`), so each step holds the same tasks. A step lies outside a learned pilot's
trained air when its air is outside the envelope run.json records for that pilot's policy of the vehicle.
"""
from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

from compare.results.metrics import EpisodeMetrics
from compare.results.run_info import AirEnvelope, RunInfo, ScenarioInfo
from compare.results.stats import OutcomeRates
from uam_fdm.air.atmosphere import density_altitude_m
from uam_fdm.stats import wilson_interval

AXES = ("density altitude", "wind")
"""The sweep's axes: x in metres of density altitude, in m/s of steady wind."""


@dataclass(frozen=True)
class SweepRate(OutcomeRates):
    """One pilot's rates at one step of one axis of a vehicle's sweep.

    Attributes:
        vehicle: the vehicle preset. axis: one of `AXES`. pilot: the pilot's name.
        x: the step: density altitude [m] (the mean of its fields') or steady wind speed [m/s].
        episodes: episodes flown (all seeds). successes, collisions: their counts.
        success_ci95, collision_ci95: 95 % Wilson intervals of the rates.
        outside: why the step's air lies outside the pilot's policy's trained air (empty: inside, or a pilot
            without a policy, or no envelope recorded).
    """

    vehicle: str
    axis: str
    x: float
    pilot: str
    episodes: int
    successes: int
    collisions: int
    success_ci95: tuple[float, float]
    collision_ci95: tuple[float, float]
    outside: tuple[str, ...] = ()


def _density_altitude(s: ScenarioInfo) -> float | None:
    rho = s.atmosphere.density_kg_m3
    return None if rho is None else density_altitude_m(rho)


def _wind(s: ScenarioInfo) -> float | None:
    w = s.wind.steady_enu_m_s
    return None if w is None else round(math.hypot(*w), 1)


def sweep_axes(scenarios: Sequence[ScenarioInfo]) -> dict[str, list[tuple[float, list[str]]]]:
    """One vehicle's axes: per axis its steps (x, the scenarios at that step), x ascending.

    Empty axes are left out (e.g. a run that is no sweep, or flew one axis only).
    """
    sea = [s for s in scenarios if s.atmosphere.elevation_m == 0.0 and s.atmosphere.isa_offset_k == 0.0]
    raised = [s for s in scenarios if s not in sea]
    winds = Counter(_wind(s) for s in raised)
    out: dict[str, list[tuple[float, list[str]]]] = {}
    by_wind: dict[float, list[str]] = {}
    for s in sea:
        w = _wind(s)
        if w is not None:
            by_wind.setdefault(w, []).append(s.name)
    if len(by_wind) > 1:
        out["wind"] = sorted(by_wind.items())
    if winds:
        da_wind = winds.most_common(1)[0][0]
        fields: dict[tuple[float | None, float | None], list[ScenarioInfo]] = {}
        for s in scenarios:
            if _wind(s) == da_wind and _density_altitude(s) is not None:
                fields.setdefault((s.atmosphere.elevation_m, s.atmosphere.isa_offset_k), []).append(s)
        steps = [(sum(_density_altitude(s) or 0.0 for s in group) / len(group), [s.name for s in group])
                 for group in fields.values()]
        if len(steps) > 1:
            out["density altitude"] = sorted(steps)
    return out


def sweep_rates(info: RunInfo, rows: Sequence[EpisodeMetrics]) -> list[SweepRate]:
    """Every vehicle's sweep rates (vehicles in run order, then axis, pilot in run order, step ascending).

    Args:
        info: the run's run.json (scenarios' air, pilots, policies' trained air).
        rows: its metrics rows.
    """
    vehicles, flown = info.run_order(r.method for r in rows)
    out = []
    for vehicle in vehicles:
        mine = [s for s in info.scenarios if s.vehicle == vehicle]
        envelopes = {m: env for m in flown for p in info.policies(m)
                     if p.vehicle == vehicle and (env := p.envelope) is not None}
        axes = sweep_axes(mine)
        for axis, steps in ((a, axes[a]) for a in AXES if a in axes):
            for pilot in flown:
                for x, names in steps:
                    cells = [r for r in rows if r.method == pilot and r.scenario in names]
                    if not cells:
                        continue
                    out.append(_rate(vehicle, axis, x, pilot, cells, envelopes.get(pilot),
                                     info.scenario(names[0])))
    return out


def _rate(vehicle: str, axis: str, x: float, pilot: str, cells: Sequence[EpisodeMetrics],
          envelope: AirEnvelope | None, scenario: ScenarioInfo | None) -> SweepRate:
    n = len(cells)
    ok, hit = sum(bool(r.success) for r in cells), sum(bool(r.collision) for r in cells)
    outside: tuple[str, ...] = ()
    if envelope is not None and scenario is not None:
        outside = envelope.outside(_density_altitude(scenario), _wind(scenario), scenario.wind.turbulence)
    return SweepRate(vehicle, axis, x, pilot, n, ok, hit, wilson_interval(ok, n), wilson_interval(hit, n), outside)


def format_step(axis: str, x: float) -> str:
    """A step as printed: "2.25 km" (density altitude) or "6.0 m/s" (wind)."""
    return f"{x / 1000.0:.2f} km" if axis == "density altitude" else f"{x:.1f} m/s"


def sweep_table_lines(rates: Sequence[SweepRate]) -> list[str]:
    """The rates as text, per vehicle and axis one row per step and pilot; "*" marks a step outside the pilot's
    trained air."""
    lines: list[str] = []
    head = None
    for r in rates:
        if (r.vehicle, r.axis) != head:
            head = (r.vehicle, r.axis)
            lines.append(f"{r.vehicle}, sweep over {r.axis} (Wilson 95 % intervals; * outside the pilot's trained "
                         f"air):")
        mark = "*" if r.outside else " "
        lines.append(f"  {format_step(r.axis, r.x):>9} {mark} {r.pilot:<10} n {r.episodes:>4}  success "
                     f"{r.success:6.1%} [{r.success_ci95[0]:.0%}, {r.success_ci95[1]:.0%}]  collision "
                     f"{r.collision:6.1%} [{r.collision_ci95[0]:.0%}, {r.collision_ci95[1]:.0%}]")
    return lines


def sweep_json(rates: Sequence[SweepRate]) -> dict[str, dict[str, list[dict]]]:
    """The rates as plain data: vehicle -> axis -> one object per step and pilot."""
    out: dict[str, dict[str, list[dict]]] = {}
    for r in rates:
        out.setdefault(r.vehicle, {}).setdefault(r.axis, []).append({
            "x": round(r.x, 1), "unit": "m" if r.axis == "density altitude" else "m/s", "method": r.pilot,
            "episodes": r.episodes, "success": {"rate": r.success, "ci95": list(r.success_ci95)},
            "collision": {"rate": r.collision, "ci95": list(r.collision_ci95)},
            "outside_trained_air": list(r.outside)})
    return out
