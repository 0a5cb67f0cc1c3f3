"""A robustness sweep's rates: success and collision per vehicle, axis, step and pilot, with Wilson intervals,
read from a run's results (run.json and metrics.csv), never re-simulated.

The axes are read from what each scenario flew (run.json), not from names. The air's two are the scenarios at
`perfect` sensing on an exact map: the wind axis is those at sea level on a standard day (elevation 0, ISA +0 K),
stepped by steady wind speed; the density-altitude axis is those in the one wind that every raised or warmed field
flies (`compare.scenarios.sweep`: the vehicle's low wind), sea level in that wind included, stepped by field. The
sensed three are the scenarios flown below `perfect` (their `SensedFacts` recorded), each moving one thing from
the point where nothing is missing from the map, the GNSS sky is open and the lidar has its longest range: the
map axis steps by the share of buildings missing, the GNSS axis by the sky (open, an urban canyon, that canyon
with outages by their length; x counts the steps, `SweepRate.label` names them), the lidar axis by range. A step
pools its scenarios' episodes (one per city in `compare.scenarios.sweep`), so each step holds the same tasks. A
step lies outside a learned pilot's trained conditions when its air, sensing or map is outside the envelopes
run.json records for that pilot's policy of the vehicle.
"""
from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass

from compare.results.metrics import EpisodeMetrics
from compare.results.run_info import AirEnvelope, RunInfo, ScenarioInfo
from compare.results.sensing_facts import SensedFacts, SensingEnvelope
from compare.results.stats import OutcomeRates
from uam_fdm.air.atmosphere import density_altitude_m
from uam_fdm.stats import wilson_interval

AIR_AXES = ("density altitude", "wind")
"""The air's axes: x in metres of density altitude, in m/s of steady wind."""
SENSED_AXES = ("map missing", "GNSS", "lidar range")
"""The sensed axes: x the share of buildings missing from the map, the GNSS sky's step (0: open sky), the lidar's
range in metres."""
AXES = AIR_AXES + SENSED_AXES
UNITS = {"density altitude": "m", "wind": "m/s", "map missing": "fraction", "GNSS": "step", "lidar range": "m"}


@dataclass(frozen=True)
class SweepRate(OutcomeRates):
    """One pilot's rates at one step of one axis of a vehicle's sweep.

    Attributes:
        vehicle: the vehicle preset. axis: one of `AXES`. pilot: the pilot's name.
        x: the step, in the axis's unit (`UNITS`): density altitude [m] (the mean of its fields'), steady wind
            speed [m/s], missing share, GNSS step, lidar range [m].
        episodes: episodes flown (all seeds). successes, collisions: their counts.
        success_ci95, collision_ci95: 95 % Wilson intervals of the rates.
        outside: why the step lies outside the pilot's policy's trained air, sensing or map error (empty: inside,
            or a pilot without a policy, or no envelope recorded).
        label: the step as printed ("2.25 km", "6.0 m/s", "25 %", "urban canyon, outages to 30 s", "40 m").
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
    label: str = ""


@dataclass(frozen=True)
class SweepStep:
    """One step of an axis: its x (the axis's unit), its label and the scenarios flown at it."""

    x: float
    label: str
    scenarios: tuple[str, ...]


def _density_altitude(s: ScenarioInfo) -> float | None:
    rho = s.atmosphere.density_kg_m3
    return None if rho is None else density_altitude_m(rho)


def _wind(s: ScenarioInfo) -> float | None:
    w = s.wind.steady_enu_m_s
    return None if w is None else round(math.hypot(*w), 1)


def format_step(axis: str, x: float) -> str:
    """A step of a numeric axis as printed: "2.25 km" (density altitude), "6.0 m/s" (wind), "25 %" (map
    missing), "40 m" (lidar range)."""
    if axis == "density altitude":
        return f"{x / 1000.0:.2f} km"
    if axis == "map missing":
        return f"{100.0 * x:g} %"
    if axis == "lidar range":
        return f"{x:g} m"
    return f"{x:.1f} m/s"


def _steps(axis: str, scenarios: Sequence[ScenarioInfo], key: Callable[[ScenarioInfo], Hashable]
           ) -> list[SweepStep]:
    """`scenarios` grouped by `key` (sortable), as steps in key order (none for fewer than two)."""
    groups: dict = {}
    for s in scenarios:
        groups.setdefault(key(s), []).append(s.name)
    if len(groups) < 2:
        return []
    out = []
    for k, (value, names) in enumerate(sorted(groups.items())):
        if axis == "GNSS":
            canyon, outage = value
            x, label = float(k), SensedFacts(canyon, outage, 0.0).gnss_label()
        else:
            x, label = float(value), format_step(axis, float(value))
        out.append(SweepStep(x, label, tuple(names)))
    return out


def sweep_axes(scenarios: Sequence[ScenarioInfo]) -> dict[str, list[SweepStep]]:
    """One vehicle's axes (of `AXES`): per axis its steps, x ascending.

    Empty axes are left out (e.g. a run that is no sweep, or flew one axis only).
    """
    air = [s for s in scenarios if s.sensing == "perfect" and s.map_error == "exact"]
    sea = [s for s in air if s.atmosphere.elevation_m == 0.0 and s.atmosphere.isa_offset_k == 0.0]
    out: dict[str, list[SweepStep]] = {}
    if wind := _steps("wind", [s for s in sea if _wind(s) is not None], lambda s: _wind(s)):
        out["wind"] = wind
    winds = Counter(_wind(s) for s in air if s not in sea)
    if winds:
        da_wind = winds.most_common(1)[0][0]
        fields: dict[tuple[float | None, float | None], list[ScenarioInfo]] = {}
        for s in air:
            if _wind(s) == da_wind and _density_altitude(s) is not None:
                fields.setdefault((s.atmosphere.elevation_m, s.atmosphere.isa_offset_k), []).append(s)
        fielded = sorted((sum(_density_altitude(s) or 0.0 for s in group) / len(group), tuple(s.name for s in group))
                         for group in fields.values())
        if len(fielded) > 1:
            out["density altitude"] = [SweepStep(x, format_step("density altitude", x), names) for x, names in fielded]
    sensed = [(s, s.sensed) for s in scenarios if s.sensed is not None and s.missing_fraction is not None]
    if sensed:
        full = max(f.lidar_range_m for _, f in sensed)

        def open_sky(f: SensedFacts) -> bool:
            return not f.gnss_urban_canyon and not f.gnss_max_outage_s

        for axis, mine, key in (
                ("map missing", [s for s, f in sensed if open_sky(f) and f.lidar_range_m == full],
                 lambda s: s.missing_fraction),
                ("GNSS", [s for s, f in sensed if not s.missing_fraction and f.lidar_range_m == full],
                 lambda s: (s.sensed.gnss_urban_canyon, s.sensed.gnss_max_outage_s)),
                ("lidar range", [s for s, f in sensed if not s.missing_fraction and open_sky(f)],
                 lambda s: s.sensed.lidar_range_m)):
            if steps := _steps(axis, mine, key):
                out[axis] = steps
    return out


def sweep_rates(info: RunInfo, rows: Sequence[EpisodeMetrics]) -> list[SweepRate]:
    """Every vehicle's sweep rates (vehicles in run order, then axis, pilot in run order, step ascending).

    Args:
        info: the run's run.json (scenarios' air and sensing, pilots, policies' trained envelopes).
        rows: its metrics rows.
    """
    vehicles, flown = info.run_order(r.method for r in rows)
    out = []
    for vehicle in vehicles:
        mine = [s for s in info.scenarios if s.vehicle == vehicle]
        records = [(m, p) for m in flown for p in info.policies(m) if p.vehicle == vehicle]
        air = {m: p.envelope for m, p in records if p.envelope is not None}
        sensing = {m: p.sensing for m, p in records if p.sensing is not None}
        axes = sweep_axes(mine)
        for axis in (a for a in AXES if a in axes):
            for pilot in flown:
                for step in axes[axis]:
                    wanted = set(step.scenarios)
                    cells = [r for r in rows if r.method == pilot and r.scenario in wanted]
                    if cells:
                        out.append(_rate(vehicle, axis, step, pilot, cells, air.get(pilot), sensing.get(pilot),
                                         info.scenario(step.scenarios[0])))
    return out


def _rate(vehicle: str, axis: str, step: SweepStep, pilot: str, cells: Sequence[EpisodeMetrics],
          air: AirEnvelope | None, sensing: SensingEnvelope | None, scenario: ScenarioInfo | None) -> SweepRate:
    n = len(cells)
    ok, hit = sum(bool(r.success) for r in cells), sum(bool(r.collision) for r in cells)
    outside: tuple[str, ...] = ()
    if air is not None and scenario is not None:
        outside = air.outside(_density_altitude(scenario), _wind(scenario), scenario.wind.turbulence)
    if sensing is not None and scenario is not None:
        outside += sensing.outside(scenario.sensing, scenario.sensed, scenario.missing_fraction)
    return SweepRate(vehicle, axis, step.x, pilot, n, ok, hit, wilson_interval(ok, n), wilson_interval(hit, n),
                     outside, step.label)


def sweep_table_lines(rates: Sequence[SweepRate]) -> list[str]:
    """The rates as text, per vehicle and axis one row per step and pilot; "*" marks a step outside the pilot's
    trained conditions."""
    lines: list[str] = []
    head = None
    width = 9
    for r in rates:
        if (r.vehicle, r.axis) != head:
            head = (r.vehicle, r.axis)
            width = max(9, *(len(o.label) for o in rates if (o.vehicle, o.axis) == head))
            lines.append(f"{r.vehicle}, sweep over {r.axis} (Wilson 95 % intervals; * outside the pilot's trained "
                         f"conditions):")
        mark = "*" if r.outside else " "
        lines.append(f"  {r.label:>{width}} {mark} {r.pilot:<10} n {r.episodes:>4}  success "
                     f"{r.success:6.1%} [{r.success_ci95[0]:.0%}, {r.success_ci95[1]:.0%}]  collision "
                     f"{r.collision:6.1%} [{r.collision_ci95[0]:.0%}, {r.collision_ci95[1]:.0%}]")
    return lines


def sweep_json(rates: Sequence[SweepRate]) -> dict[str, dict[str, list[dict]]]:
    """The rates as plain data: vehicle -> axis -> one object per step and pilot (x in the axis's unit, `UNITS`,
    and the step's label)."""
    out: dict[str, dict[str, list[dict]]] = {}
    for r in rates:
        out.setdefault(r.vehicle, {}).setdefault(r.axis, []).append({
            "x": round(r.x, 3 if r.axis == "map missing" else 1), "unit": UNITS[r.axis], "label": r.label,
            "method": r.pilot, "episodes": r.episodes, "success": {"rate": r.success, "ci95": list(r.success_ci95)},
            "collision": {"rate": r.collision, "ci95": list(r.collision_ci95)},
            "outside_trained_air": list(r.outside)})
    return out
