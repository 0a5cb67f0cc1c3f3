"""Which scenarios a learned pilot flies outside the air its policy was trained in.

A policy's config.json says the air it trained in (`rl.task.air.AirDistribution`: field elevation and ISA
offset ranges, turbulence levels, top steady wind); `air_envelope` turns it into what a run compares and
records (`compare.results.run_info.AirEnvelope`: a density-altitude range, the top wind, the levels). Such a
scenario is still flown (researchers want to see where a policy breaks): the run warns before flying, notes
it in run.json, and the report marks it (`compare.report.sweep_pages`).
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from compare.flying import pilots
from compare.results.run_info import AirEnvelope
from compare.run.cells import Cell
from compare.scenarios.scenario import Scenario
from rl.task.air import AirDistribution
from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions, density_altitude_m

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


def scenario_outside(sc: Scenario, envelope: AirEnvelope) -> tuple[str, ...]:
    """Why scenario `sc`'s air (at its field; its steady wind at the reference height; its turbulence level)
    lies outside `envelope`; empty when inside."""
    da = density_altitude_m(float(sc.air.density_kg_m3(0.0)))
    return envelope.outside(da, math.hypot(*sc.wind.steady_enu_m_s), sc.wind.turbulence.value)


def outside_trained_air(scenarios: Sequence[Scenario], cells: Sequence[Cell],
                        envelopes: Mapping[str, AirEnvelope]) -> list[str]:
    """One note per (pilot that flies a policy, vehicle) that flies scenarios outside its policy's trained air:
    how many, the envelope, and the first `NAMED_PER_NOTE` with their reasons.

    Args:
        scenarios: the run's scenarios (`cells` index them).
        cells: the cells to fly.
        envelopes: the trained air of each policy flown, by vehicle fingerprint (`VehicleParams.fingerprint`).
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
        out = [(scenarios[i].name, why) for i in indices if (why := scenario_outside(scenarios[i], env))]
        if not out:
            continue
        named = "; ".join(f"{name} ({', '.join(why)})" for name, why in out[:NAMED_PER_NOTE])
        more = f"; and {len(out) - NAMED_PER_NOTE} more" if len(out) > NAMED_PER_NOTE else ""
        notes.append(f"{pilot} flies {len(out)} of {len(indices)} {scenarios[indices[0]].vehicle_name} scenarios "
                     f"outside the air its policy was trained in ({env.describe()}); they are flown all the same "
                     f"and marked in the report: {named}{more}")
    return notes
