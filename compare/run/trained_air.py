"""Which scenarios a learned pilot flies outside the air, sensing and map error its policy was trained in.

A policy's config.json says the air it trained in (`rl.task.air.AirDistribution`: field elevation and ISA
offset ranges, turbulence levels, top steady wind); `air_envelope` turns it into what a run compares and
records (`compare.results.run_info.AirEnvelope`: a density-altitude range, the top wind, the levels). Its sensing
and map-error levels become a `compare.results.sensing_facts.SensingEnvelope` (`sensing_envelope`), compared
with each scenario's `SensedFacts` (`sensed_facts`). Such a scenario is still flown (researchers want to see
where a policy breaks): the run warns before flying, notes it in run.json, and the report marks it
(`compare.report.sweep_pages`).
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from compare.flying import pilots
from compare.results.run_info import AirEnvelope
from compare.results.sensing_facts import SensedFacts, SensingEnvelope
from compare.run.cells import Cell
from compare.scenarios.scenario import Scenario
from rl.task.air import AirDistribution
from rl.task.config import NavConfig
from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions, density_altitude_m
from uam_fdm.city.map_error import MAP_ERROR_PRESETS
from uam_fdm.sensing.specs import GnssSpec, SensingConfig, sensing_preset
from uam_fdm.vehicle.params import load_vehicle

NAMED_PER_NOTE = 6
"""Scenarios named one by one in a note (the report marks every one)."""


def field_density_altitude_m(elevation_m: float, isa_offset_k: float) -> float:
    """The density altitude [m] of a field at `elevation_m` [m MSL] on a day `isa_offset_k` [K] from ISA, in
    JSBSim's atmosphere (the one flown)."""
    air = Atmosphere.from_jsbsim(AtmosphereConditions(elevation_m, isa_offset_k), z_max_m=10.0, z_min_m=0.0)
    return density_altitude_m(float(air.density_kg_m3(0.0)))


def air_envelope(air: AirDistribution) -> AirEnvelope:
    """The envelope of a policy's training air: density altitude from its densest corner (lowest, coldest
    field) to its thinnest (highest, hottest) [m], its top steady wind [m/s] and its turbulence levels."""
    (e0, e1), (t0, t1) = air.elevation_m, air.isa_offset_k
    return AirEnvelope((round(field_density_altitude_m(e0, t0), 1), round(field_density_altitude_m(e1, t1), 1)),
                       air.steady_wind_max_m_s, tuple(air.turbulence))


def _outage_s(gnss: GnssSpec) -> float:
    """The longest GNSS outage [s] a receiver meets (0 when it never loses lock)."""
    return float(gnss.max_outage_s) if gnss.outage_rate_per_min > 0.0 else 0.0


def sensed_facts(sensing: SensingConfig) -> SensedFacts | None:
    """What a run records of a scenario's sensing (None at `perfect`: nothing is simulated)."""
    if sensing.perfect:
        return None
    return SensedFacts(bool(sensing.gnss.urban_canyon), _outage_s(sensing.gnss), float(sensing.lidar.max_range_m))


def sensing_envelope(nav: NavConfig) -> SensingEnvelope:
    """The sensing and map error of a policy's training task: its sensing levels' presets for its vehicle (the
    sky, outages and lidar of each) and its map-error levels' missing shares."""
    mass = load_vehicle(nav.vehicle).mass_kg
    sensed = [sensing_preset(level, mass) for level in nav.sensing if level != "perfect"]
    return SensingEnvelope(
        sensed=bool(sensed), gnss_urban_canyon=any(c.gnss.urban_canyon for c in sensed),
        gnss_max_outage_s=max((_outage_s(c.gnss) for c in sensed), default=0.0),
        lidar_range_m=min((float(c.lidar.max_range_m) for c in sensed), default=None),
        missing_fraction_max=max(MAP_ERROR_PRESETS[level].missing_fraction for level in nav.map_error))


def scenario_outside(sc: Scenario, envelope: AirEnvelope, sensing: SensingEnvelope | None = None
                     ) -> tuple[str, ...]:
    """Why scenario `sc`'s air (at its field; its steady wind at the reference height; its turbulence level) lies
    outside `envelope`, then why its sensing and map lie outside `sensing` (None: not compared); empty when
    inside."""
    da = density_altitude_m(float(sc.air.density_kg_m3(0.0)))
    why = envelope.outside(da, math.hypot(*sc.wind.steady_enu_m_s), sc.wind.turbulence.value)
    if sensing is not None:
        why += sensing.outside(sc.sensing.label, sensed_facts(sc.sensing), sc.map_error.missing_fraction)
    return why


def outside_trained_air(scenarios: Sequence[Scenario], cells: Sequence[Cell],
                        envelopes: Mapping[str, AirEnvelope],
                        sensing: Mapping[str, SensingEnvelope] | None = None) -> list[str]:
    """One note per (pilot that flies a policy, vehicle) that flies scenarios outside its policy's trained air,
    sensing or map error: how many, the envelope, and the first `NAMED_PER_NOTE` with their reasons.

    Args:
        scenarios: the run's scenarios (`cells` index them).
        cells: the cells to fly.
        envelopes: the trained air of each policy flown, by vehicle fingerprint (`VehicleParams.fingerprint`).
        sensing: the trained sensing and map error of each, by the same keys (None or absent: not compared).
    """
    flown: dict[tuple[str, str], list[int]] = {}  # (pilot, vehicle fingerprint) -> its scenarios, in run order
    for c in cells:
        if pilots.pilot(c.pilot).needs_policy:
            mine = flown.setdefault((c.pilot, scenarios[c.scenario].vehicle.fingerprint()), [])
            if c.scenario not in mine:
                mine.append(c.scenario)
    notes = []
    for (pilot, fp), indices in flown.items():
        env = envelopes.get(fp)
        if env is None:
            continue
        trained = (sensing or {}).get(fp)
        out = [(scenarios[i].name, why) for i in indices if (why := scenario_outside(scenarios[i], env, trained))]
        if not out:
            continue
        what = env.describe() + ("" if trained is None else f"; {trained.describe()}")
        named = "; ".join(f"{name} ({', '.join(why)})" for name, why in out[:NAMED_PER_NOTE])
        more = f"; and {len(out) - NAMED_PER_NOTE} more" if len(out) > NAMED_PER_NOTE else ""
        notes.append(f"{pilot} flies {len(out)} of {len(indices)} {scenarios[indices[0]].vehicle_name} scenarios "
                     f"outside the conditions its policy was trained in ({what}); they are flown all the same "
                     f"and marked in the report: {named}{more}")
    return notes
