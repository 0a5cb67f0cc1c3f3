"""The robustness sweep: the same tasks at every step, the density altitudes, winds, missing shares, GNSS skies and
lidar ranges it claims, held-out cities, a version that is repeatable and moves with the output; a learned pilot
warned (and still flown) where the air, sensing or map leaves its training."""
from __future__ import annotations

import logging
import math
from collections import defaultdict
from pathlib import Path

import pytest

from compare.results.episodes import open_episodes
from compare.results.run_info import AirEnvelope
from compare.results.sensing_facts import SensedFacts, SensingEnvelope
from compare.run.campaign import RunConfig, plan_cells, policy_facts
from compare.run.trained_air import outside_trained_air, scenario_outside, sensed_facts
from compare.scenarios import sweep
from compare.scenarios.benchmark import FAMILIES, LEARNED_PILOT_POOLS, city_seed_ranges, validation_design
from compare.scenarios.sets import builtin_sets, resolve_scenarios
from compare.scenarios.sweep import (
    DA_TOLERANCE_M,
    DENSITY_ALTITUDES_M,
    DESIGN,
    GNSS_STEPS,
    LIDAR_RANGE_FRACTIONS,
    MISSING_FRACTIONS,
    build_sweep,
    sensed_points,
    sweep_seed_ranges,
)
from rl.policies.folder import shipped_policy_dir
from uam_fdm.air.atmosphere import density_altitude_m


@pytest.fixture(scope="module")
def quick():
    return build_sweep("sweep-quick")


def _city(sc) -> int:
    return sc.raw["map"]["generator"]["seed"]


def test_the_same_tasks_at_every_step(quick) -> None:
    by_city = defaultdict(list)
    for sc in quick.scenarios:
        by_city[_city(sc)].append(sc)
    assert len(by_city) == 2 * DESIGN.quick_cities  # one city per vehicle
    for scenarios in by_city.values():
        legs = {tuple((tuple(e.task.start_m), tuple(e.task.goal_m)) for e in sc.episodes) for sc in scenarios}
        assert len(legs) == 1 and len(next(iter(legs))) == DESIGN.quick_legs
        assert len({sc.city.buildings for sc in scenarios}) == 1
        assert {tuple(sc.pilots) for sc in scenarios} == {("ppo", "rrt_mpc", "apf")}
        # one axis at a time: raised fields fly one wind; winds vary at sea level only; the sensed steps fly the
        # raised fields' wind at sea level
        raised = [sc for sc in scenarios if sc.atmosphere.elevation_m > 0.0]
        sensed = [sc for sc in scenarios if not sc.sensing.perfect]
        assert len({round(math.hypot(*sc.wind.steady_enu_m_s), 1) for sc in raised + sensed}) == 1
        assert {sc.atmosphere.elevation_m for sc in sensed} == {0.0}
        headings = {round(math.atan2(sc.wind.steady_enu_m_s[1], sc.wind.steady_enu_m_s[0]), 2)
                    for sc in scenarios if math.hypot(*sc.wind.steady_enu_m_s) > 0}
        assert len(headings) == 1
        assert {sc.wind.turbulence.value for sc in scenarios} == {"light"}


def test_the_steps_hit_their_density_altitudes_and_winds(quick) -> None:
    for sv in DESIGN.vehicles:
        mine = [sc for sc in quick.scenarios if sc.vehicle_name == sv.tasks.vehicle and sc.sensing.perfect]
        assert all(sc.map_error.exact for sc in mine)
        assert len(mine) == len(DENSITY_ALTITUDES_M) + len(sv.wind_steps_m_s) - 1  # the sea-level point shared
        das = sorted({density_altitude_m(float(sc.air.density_kg_m3(0.0))) for sc in mine})
        assert len(das) == len(DENSITY_ALTITUDES_M) >= 7 and max(DENSITY_ALTITUDES_M) >= 4500.0
        for want, got in zip(DENSITY_ALTITUDES_M, das):
            assert abs(got - want) <= DA_TOLERANCE_M
        sea = [sc for sc in mine if sc.atmosphere.elevation_m == 0.0]
        winds = sorted(round(math.hypot(*sc.wind.steady_enu_m_s), 1) for sc in sea)
        assert winds == pytest.approx(sorted(sv.wind_steps_m_s), abs=0.06) and len(winds) >= 7
    quad = next(sv for sv in DESIGN.vehicles if sv.tasks.vehicle == "small_quad")
    uam = next(sv for sv in DESIGN.vehicles if sv.tasks.vehicle == "uam_multicopter")
    assert max(quad.wind_steps_m_s) == 12.0 and max(uam.wind_steps_m_s) == 16.0


def test_the_sensed_steps_move_one_thing_each(quick) -> None:
    """Nominal sensing at every sensed step; each axis moves its own figure from the shared point, and the prior map
    lacks the step's share of the buildings."""
    points = sensed_points()
    assert len(points) == 1 + (len(MISSING_FRACTIONS) - 1) + (len(GNSS_STEPS) - 1) + (len(LIDAR_RANGE_FRACTIONS) - 1)
    for sv in DESIGN.vehicles:
        mine = [sc for sc in quick.scenarios if sc.vehicle_name == sv.tasks.vehicle and not sc.sensing.perfect]
        assert len(mine) == len(points) == 11
        assert {sc.sensing.level for sc in mine} == {"nominal"}
        part = max(sc.sensing.lidar.max_range_m for sc in mine)
        assert part == (100.0 if sv.tasks.vehicle == "small_quad" else 200.0)
        facts = {sc.name: (sensed_facts(sc.sensing), sc.map_error.missing_fraction) for sc in mine}
        missing = sorted(m for f, m in facts.values() if f == SensedFacts(False, 0.0, part))
        assert missing == [0.0, 0.1, 0.25, 0.5]
        skies = sorted((f.gnss_urban_canyon, f.gnss_max_outage_s) for f, m in facts.values()
                       if m == 0.0 and f.lidar_range_m == part)
        assert skies == [(False, 0.0), (True, 0.0), (True, 10.0), (True, 30.0), (True, 60.0)]
        ranges = sorted(f.lidar_range_m for f, m in facts.values() if m == 0.0 and not f.gnss_urban_canyon)
        assert ranges == pytest.approx([0.2 * part, 0.4 * part, 0.6 * part, part])
        outages = [sc.sensing.gnss for sc in mine if sc.sensing.gnss.max_outage_s]
        assert {g.outage_rate_per_min for g in outages} == {sweep.GNSS_OUTAGE_RATE_PER_MIN}
        for sc in mine:
            n = len(sc.city.buildings)
            lacking = n - len(sc.prior_map.buildings)
            assert lacking == math.floor(sc.map_error.missing_fraction * n + 0.5), sc.name
        half = next(sc for sc in mine if sc.map_error.missing_fraction == 0.5)
        assert half.name.endswith("-sensed-m50-g0-l100") and half.map_error.seed == half.raw["map"]["generator"]["seed"]


def test_city_seeds_are_held_out() -> None:
    taken = {**LEARNED_PILOT_POOLS, **{f"{v} {name}": r for family in FAMILIES
                                       for twin, name in ((family, family.sets[0]),
                                                          (validation_design(family), family.sets[2]))
                                       for v, r in city_seed_ranges(twin).items()}}
    ranges = sweep_seed_ranges()
    for vehicle, seeds in ranges.items():
        for other in [*taken.values(), *(r for v, r in ranges.items() if v != vehicle)]:
            assert not set(seeds) & set(other), vehicle
    with pytest.raises(ValueError, match="overlap the small_quad benchmark-perfect"):
        tasks = DESIGN.vehicles[0].tasks
        clash = sweep.SweepVehicle(sweep.VehicleBenchmark(tasks.vehicle, tasks.tag, 3_000_010, tasks.leg_bins_m,
                                                          tasks.altitude_m, 0.0), (0.0, 2.0), 2.0)
        build_sweep("sweep-quick", sweep.SweepDesign(vehicles=(clash,)))
    with pytest.raises(ValueError, match="overlap the small_quad benchmark-perfect-validation"):  # the twins too
        tasks = DESIGN.vehicles[0].tasks
        clash = sweep.SweepVehicle(sweep.VehicleBenchmark(tasks.vehicle, tasks.tag, 3_200_005, tasks.leg_bins_m,
                                                          tasks.altitude_m, 0.0), (0.0, 2.0), 2.0)
        build_sweep("sweep-quick", sweep.SweepDesign(vehicles=(clash,)))


def test_version_is_repeatable_and_quick_is_a_subset(quick) -> None:
    again = build_sweep("sweep-quick")
    assert again.info.version == quick.info.version and [s.raw for s in again.scenarios] == [s.raw for s in
                                                                                              quick.scenarios]
    assert quick.info.version.startswith(f"{sweep.GENERATOR_VERSION}+")
    assert quick.info.version == "2+c50b13dab8"  # docs/benchmark.md
    bigger = build_sweep("sweep-quick", sweep.SweepDesign(quick_legs=3))
    assert bigger.info.version != quick.info.version
    for small, big in zip(quick.scenarios, bigger.scenarios):
        assert small.name == big.name and small.raw["episodes"] == big.raw["episodes"][:2]
    only = build_sweep("sweep-quick", vehicles=("small_quad",))
    assert [s.name for s in only.scenarios] == [s.name for s in quick.scenarios if s.vehicle_name == "small_quad"]
    with pytest.raises(ValueError, match="--vehicle .*: no sweep for this vehicle"):
        build_sweep("sweep-quick", vehicles=("zeppelin",))


def test_the_sets_resolve_by_name(quick) -> None:
    assert {"sweep", "sweep-quick"} <= set(builtin_sets())
    assert [s.name for s in resolve_scenarios("sweep-quick")] == [s.name for s in quick.scenarios]


# ---- the trained envelope --------------------------------------------------------------------------------
def test_a_shipped_policy_is_warned_in_thin_air_not_at_sea_level(quick) -> None:
    facts = policy_facts(shipped_policy_dir("small_quad"))
    env = facts.envelope
    # the shipped quad policy is trained across the envelope: density altitude -0.6 to 4.0 km, wind to 8 m/s
    assert env is not None and env.steady_wind_max_m_s == 8.0 and env.turbulence == ("none", "light", "moderate")
    assert -600.0 < env.density_altitude_m[0] < -500.0 and 4000.0 < env.density_altitude_m[1] < 4100.0
    quad = [sc for sc in quick.scenarios if sc.vehicle_name == "small_quad"]
    sea = next(sc for sc in quad if sc.name.endswith("-da0000-w020"))
    inside = next(sc for sc in quad if sc.name.endswith("-da3000-w020"))
    thin = next(sc for sc in quad if sc.name.endswith("-da4500-w020"))
    windy = next(sc for sc in quad if sc.name.endswith("-da0000-w100"))
    assert scenario_outside(sea, env) == () and scenario_outside(inside, env) == ()
    assert scenario_outside(thin, env) == ("density altitude 4497 m",)
    assert scenario_outside(windy, env) == ("steady wind 10.0 m/s",)
    air = [sc for sc in quad if sc.sensing.perfect]
    cells, _ = plan_cells(air, RunConfig(Path("unused")), None)
    notes = outside_trained_air(air, cells, {facts.vehicle_fingerprint: env})
    # past the envelope: 4.5 km, and wind 10 and 12 m/s
    assert len(notes) == 1 and notes[0].startswith("ppo flies 3 of 13 small_quad scenarios outside")
    assert thin.name in notes[0] and windy.name in notes[0] and sea.name not in notes[0]
    assert inside.name not in notes[0]
    assert outside_trained_air([sea], plan_cells([sea], RunConfig(Path("unused")), None)[0],
                               {facts.vehicle_fingerprint: env}) == []
    # it trained on the truth and exact maps: every sensed step is outside, said once for the sensing
    assert facts.sensing == SensingEnvelope(False, False, 0.0, None, 0.0)
    sensed = [sc for sc in quad if not sc.sensing.perfect]
    base = next(sc for sc in sensed if sc.name.endswith("-sensed-m00-g0-l100"))
    half = next(sc for sc in sensed if sc.name.endswith("-sensed-m50-g0-l100"))
    canyon = next(sc for sc in sensed if sc.name.endswith("-sensed-m00-g4-l100"))
    assert scenario_outside(base, env, facts.sensing) == ("nominal sensing",)
    assert scenario_outside(half, env, facts.sensing) == ("nominal sensing", "50 % of the buildings unmapped")
    assert scenario_outside(canyon, env, facts.sensing) == ("nominal+ sensing",)
    assert scenario_outside(canyon, env) == ()  # no sensing envelope: not compared
    cells, _ = plan_cells(quad, RunConfig(Path("unused")), None)
    notes = outside_trained_air(quad, cells, {facts.vehicle_fingerprint: env}, {facts.vehicle_fingerprint:
                                                                                facts.sensing})
    assert len(notes) == 1 and notes[0].startswith("ppo flies 14 of 24 small_quad scenarios outside")
    assert "sensing perfect only, maps missing up to 0 % of the buildings" in notes[0]


def test_a_policy_trained_across_sensing_is_warned_past_its_levels(quick) -> None:
    """Trained at every sensing and map-error level: the open sky, the canyon, outages to 30 s, the part's range
    and a quarter of the map missing are inside; 60 s outages, a shorter range and half the map missing are not."""
    from dataclasses import replace

    from compare.run.trained_air import sensing_envelope
    from rl.task.vehicles import task_for

    nav = replace(task_for("small_quad"), sensing=("perfect", "nominal", "degraded"),
                  map_error=("exact", "outdated", "wrong"))
    trained = sensing_envelope(nav)
    assert trained == SensingEnvelope(True, True, 30.0, 100.0, 0.25)
    assert "GNSS up to urban canyon, outages to 30 s, lidar range from 100 m" in trained.describe()
    env = AirEnvelope((-600.0, 4100.0), 8.0, ("none", "light", "moderate"))
    why = {sc.name.split("-sensed-")[1]: scenario_outside(sc, env, trained) for sc in quick.scenarios
           if sc.vehicle_name == "small_quad" and not sc.sensing.perfect}
    assert why == {"m00-g0-l100": (), "m10-g0-l100": (), "m25-g0-l100": (),
                   "m50-g0-l100": ("50 % of the buildings unmapped",),
                   "m00-g1-l100": (), "m00-g2-l100": (), "m00-g3-l100": (), "m00-g4-l100": ("GNSS outages to 60 s",),
                   "m00-g0-l020": ("lidar range 20 m",), "m00-g0-l040": ("lidar range 40 m",),
                   "m00-g0-l060": ("lidar range 60 m",)}
    only_nominal = sensing_envelope(replace(nav, sensing=("nominal",), map_error=("exact",)))
    assert only_nominal == SensingEnvelope(True, False, 0.0, 100.0, 0.0)
    assert only_nominal.outside("degraded", SensedFacts(True, 30.0, 100.0), 0.1) == (
        "GNSS urban canyon", "GNSS outages to 30 s", "10 % of the buildings unmapped")
    assert only_nominal.outside("perfect", None, 0.0) == ()


def test_envelope_reasons() -> None:
    env = AirEnvelope((-600.0, 4100.0), 8.0, ("none", "light"))
    assert env.outside(4000.0, 8.0, "light") == ()
    assert env.outside(4200.0, 8.5, "moderate") == ("density altitude 4200 m", "steady wind 8.5 m/s",
                                                    "moderate turbulence")
    assert env.outside(None, None, None) == ()


def test_a_run_warns_and_still_flies_outside_the_envelope(quick, tmp_path: Path,
                                                          caplog: pytest.LogCaptureFixture) -> None:
    """The warning comes before flying, through logging; run.json keeps the note and the policy's trained air."""
    from compare.results.run_info import read_run_info
    from compare.run.campaign import run_comparison

    thin = next(sc for sc in quick.scenarios if sc.name == "sweep-quad-00-da4500-w020")
    thin = sweep.dataclasses.replace(thin, episodes=thin.episodes[:1])
    opts = RunConfig(tmp_path / "run", pilots=("ppo",), progress=False, report=False, videos="none")
    with caplog.at_level(logging.WARNING, logger="compare.run.campaign"):
        run_comparison([thin], opts)
    assert any("ppo flies 1 of 1 small_quad scenarios outside" in r.getMessage() for r in caplog.records)
    info = read_run_info(tmp_path / "run")
    assert any("density altitude 4497 m" in n for n in info.notes)
    (pol,) = info.policies("ppo")
    assert pol.envelope is not None and pol.envelope.steady_wind_max_m_s == 8.0
    assert len(open_episodes(tmp_path / "run").entries) == 1  # flown all the same
