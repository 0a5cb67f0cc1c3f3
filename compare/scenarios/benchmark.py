"""The benchmark sets: held-out task distributions per vehicle, generated, seeded and versioned, in two families.

**The tiered benchmark** (`DESIGN`: "benchmark", "benchmark-quick", "benchmark-validation",
"benchmark-validation-quick"; `GENERATOR_VERSION` 2): every scenario also flies a sensing level (perfect, nominal,
degraded) and a map-error level (exact, outdated, wrong; drawn from the city's seed, clear of every leg of the full
set), steady winds across the envelopes (8 m/s small quad, 12 m/s UAM), each vehicle's envelope task (the UAM's
cities alternating between its districts and the shipped maps' scale, with their own leg bins); city seeds
3,400,000.. (small quad) and 3,500,000.. (UAM). **benchmark-perfect** (`PERFECT_DESIGN`: the same names with
"-perfect"; `PERFECT_GENERATOR_VERSION` 1): the headline set before the tiers, task for task and version for version
(its scenarios keep their names, "benchmark-quad-007"): perfect sensing over exact maps, winds to 3 and 5 m/s, the
UAM in its own districts; city seeds 3,000,000.. and 3,100,000...

`build_task_set(name)` generates the scenarios of a set: per vehicle, cities drawn from the learned pilot's city
distribution (`rl.task.vehicles.task_for(vehicle, envelope=...).cities`) at seeds no pool of its training or
evaluation uses (`rl.task.cities`: training 0.., test 1,000,000.., validation 1,050,000..) nor the other family,
each flown in one air and turbulence condition on several start/goal legs at that vehicle's task scale (goal radius,
clearances, margins and time limits of its task; `rl.task.vehicles`). Every scenario is a plain scenario mapping
checked by the same strict loader as a file (`compare.scenarios.scenario.scenario_from_dict`), so `uam-compare
validate benchmark` checks every one.

The difficulty axes vary on purpose, so that success can be plotted against them:

* building density: three levels of the generator's lot occupancy and footprint fill (the lowest, middle
  and highest the learned pilot trained on); measured as the built cover (`building_coverage`);
* turbulence: none, light, moderate;
* air: sea level on a standard day, warm and raised, hot and high (`AIR_LEVELS`; `density_altitude_m`);
* leg length: three bins per vehicle (leg j of a scenario is in bin j mod 3);
* (tiered) sensing and map error: three levels each.

The scenario index i sets them through an orthogonal array (i in base 3: a, b, c; turbulence a, density a + b, air
a + 2b + c, sensing a + b + c, map error 2b + c, mod 3): every 27 consecutive scenarios hold each pair of levels of
any two axes equally often; every run of 9 holds each pair of turbulence, density and air levels once, and each
tier level against each air and each turbulence level once (sensing moves with density there). Legs prefer a
straight line blocked by buildings (the first blocked candidate; the first free one when none of `MAX_LEG_DRAWS`
is blocked).

Determinism and subsets: scenario i's city, air and wind come from its own seed, and leg j from its own
stream, so a scenario's first legs do not depend on how many it has (and its map error keeps clear of all the full
set's legs). A quick set is the first `quick_scenarios` scenarios of each vehicle with their first `quick_legs`
legs: the same names, tasks, maps and cell seeds as in its full set, so its cells are cells of the full set; a
validation twin's quick set is likewise the first of the twin.

Validation: each family's validation set is its full set's twin on other cities (`VALIDATION_SEED_OFFSET` added to
every city seed; the same design, levels, leg bins and time limits; scenarios named "<prefix>-validation-<tag>-007").
A pilot's choices (margins, budgets, gains, checkpoints) are tuned there; the full set is the test pool, flown only
to report.

Version: the family's generator version + "+" + a hash of everything generated (the scenario mappings and the
buildings of every city), so any change to the output, including the city generator's, changes it.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from compare.results.difficulty import building_coverage
from compare.results.run_info import TaskSetInfo
from compare.scenarios.fingerprint import scenario_fingerprint
from compare.scenarios.random_legs import LegRanges
from compare.scenarios.random_legs import draw_leg as random_leg
from compare.scenarios.scenario import Scenario, scenario_from_dict
from rl.task.air import AIR_LEVELS as LEVELS_OF_AIR
from rl.task.cities import EVAL_SEEDS, TRAIN_SEEDS, CityDistribution, CityMixture, TaskDistribution
from rl.task.vehicles import task_for
from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions, density_altitude_m
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.city.generator import CityGenConfig, generate_city
from uam_fdm.city.map_error import MAP_ERROR_LEVELS
from uam_fdm.sensing.specs import LEVELS as SENSING_LEVELS
from uam_fdm.vehicle.params import VehicleParams, load_vehicle

GENERATOR_VERSION = "2"
"""The tiered benchmark's; bumped by hand when the design changes on purpose (the hash in the version catches every
change anyway)."""
PERFECT_GENERATOR_VERSION = "1"
"""benchmark-perfect's: the headline set before the tiers, kept task for task (its versions are unchanged)."""
# the generated sets (`compare.scenarios.sets`): the tiered benchmark's family, then benchmark-perfect's
TIERED_SETS = ("benchmark", "benchmark-quick", "benchmark-validation", "benchmark-validation-quick")
PERFECT_SETS = ("benchmark-perfect", "benchmark-perfect-quick", "benchmark-perfect-validation",
                "benchmark-perfect-validation-quick")
BENCHMARK_SETS = TIERED_SETS + PERFECT_SETS
FULL, QUICK, VALIDATION, VALIDATION_QUICK = TIERED_SETS
VALIDATION_SEED_OFFSET = 200_000
"""The validation twin's city seeds: the full set's plus this (benchmark: 3,600,000.. for the small quad, 3,700,000..
for the UAM; benchmark-perfect: 3,200,000.. and 3,300,000..: clear of every full set's and of every learned pilot's
pool, `_check_design`)."""
PILOT_NAMES = ("ppo", "rrt_mpc", "apf")
TURBULENCE_LEVELS = ("none", "light", "moderate")
DENSITY_LEVELS = ("sparse", "medium", "dense")
MAX_LEG_DRAWS = 256  # candidate legs per leg before a free straight line is accepted
_STREAM_AIR, _STREAM_LEG = 0xA1B, 0x1E6  # PCG64 stream tags: a scenario's air and wind, its legs
LEARNED_PILOT_POOLS: dict[str, range] = {"training": TRAIN_SEEDS, "test and validation": EVAL_SEEDS}
"""The learned pilot's city seed pools (`rl.task.cities`, `rl.training.evaluation`), which the benchmark's seeds
avoid."""


AIR_LEVELS = tuple(LEVELS_OF_AIR.values())
"""The air axis's levels (`rl.task.air.AIR_LEVELS`: sea level on a standard day, warm and raised, hot and high)."""


@dataclass(frozen=True)
class VehicleBenchmark:
    """The task distribution of one vehicle (the rest is its learned pilot's task, `rl.task.vehicles.task_for`).

    Attributes:
        vehicle: the vehicle preset.
        tag: short name in the scenario names ("benchmark-<tag>-007").
        first_seed: the first city seed (scenario i flies city first_seed + i).
        leg_bins_m: straight start-goal distance ranges [m]; leg j is drawn in bin j mod len.
        altitude_m: start and goal height range above the ground [m].
        steady_wind_max_m_s: each scenario's steady wind speed is uniform in [0, this] [m/s] (the learned
            pilot's training air when the set was made; fixed here so the set does not move with training).
        envelope: the cities, the legs' clearances and margins and the time-limit rule of the vehicle's envelope
            task (`task_for(vehicle, envelope=True)`: the UAM's cities half its districts, half the shipped maps'
            scale); False: of its own task.
        component_leg_bins_m: when the cities are a mixture, the leg bins in each component's cities (scenario i
            flies component i mod their count); empty: `leg_bins_m` in all.
    """

    vehicle: str
    tag: str
    first_seed: int
    leg_bins_m: tuple[tuple[float, float], ...]
    altitude_m: tuple[float, float]
    steady_wind_max_m_s: float
    envelope: bool = False
    component_leg_bins_m: tuple[tuple[tuple[float, float], ...], ...] = ()


@dataclass(frozen=True)
class BenchmarkDesign:
    """What the benchmark sets hold.

    Attributes:
        vehicles: one task distribution per vehicle (never pooled: each vehicle has its own scenarios).
        scenarios_per_vehicle, legs_per_scenario: the full set's size per vehicle.
        quick_scenarios, quick_legs: the quick subset's (the first scenarios, their first legs).
        seeds: the seeds every episode is flown with.
        pilots: the pilots flown.
        sets: the names of its full set, quick subset, validation twin and the twin's quick subset.
        generator_version: the version's first part.
        prefix: the scenarios' names' ("<prefix>-<tag>-007"; the twin's "<prefix>-validation-<tag>-007").
        tiers: each scenario also has a sensing level and a map-error level (`levels`); False: perfect sensing over
            an exact map everywhere (no such keys in the scenarios).
    """

    vehicles: tuple[VehicleBenchmark, ...] = (
        # the learned quad's legs are 40-250 m at 5-30 m; the shipped scenarios 120-250 m at 8-20 m; wind to 8 m/s
        # (its envelope's)
        VehicleBenchmark("small_quad", "quad", 3_400_000, ((60.0, 120.0), (120.0, 180.0), (180.0, 240.0)),
                         (8.0, 25.0), 8.0, envelope=True),
        # the UAM in its envelope's cities, every other scenario at the shipped maps' scale (600-1,100 m across:
        # legs to 700 m there, to 1.2 km in its own districts); wind to 12 m/s (its envelope's)
        VehicleBenchmark("uam_multicopter", "uam", 3_500_000, ((300.0, 600.0), (600.0, 900.0), (900.0, 1200.0)),
                         (30.0, 90.0), 12.0, envelope=True,
                         component_leg_bins_m=(((300.0, 600.0), (600.0, 900.0), (900.0, 1200.0)),
                                               ((250.0, 400.0), (400.0, 550.0), (550.0, 700.0)))),
    )
    # 36 = 4 blocks of the orthogonal array: every pair of levels 4 times, each level 12 times (144 tasks)
    scenarios_per_vehicle: int = 36
    legs_per_scenario: int = 12
    # the first 6 scenarios hold every level of each axis twice (the tiers' too), 3 legs every length bin; sized
    # to run in minutes with --jobs 2 (measured: docs/benchmark.md)
    quick_scenarios: int = 6
    quick_legs: int = 3
    seeds: tuple[int, ...] = (0,)
    pilots: tuple[str, ...] = PILOT_NAMES
    sets: tuple[str, str, str, str] = TIERED_SETS
    generator_version: str = GENERATOR_VERSION
    prefix: str = "benchmark-v2"
    tiers: bool = True


DESIGN = BenchmarkDesign()
"""The headline benchmark: sensing and map-error tiers, the envelopes' winds, the UAM also at the shipped maps'
scale."""
PERFECT_DESIGN = BenchmarkDesign(
    vehicles=(
        VehicleBenchmark("small_quad", "quad", 3_000_000, ((60.0, 120.0), (120.0, 180.0), (180.0, 240.0)),
                         (8.0, 25.0), 3.0),
        # a 1.2 km leg still fits the smallest district's flyable square (1000 m less 2 x 80 m margins: 1188 m
        # across the diagonal)
        VehicleBenchmark("uam_multicopter", "uam", 3_100_000, ((300.0, 600.0), (600.0, 900.0), (900.0, 1200.0)),
                         (30.0, 90.0), 5.0),
    ),
    sets=PERFECT_SETS, generator_version=PERFECT_GENERATOR_VERSION, prefix="benchmark", tiers=False)
"""benchmark-perfect: the headline set before the tiers (every pilot on the exact state and an exact map, winds to
3 and 5 m/s, the UAM in its own districts), kept task for task under its own name and its versions."""
FAMILIES = (DESIGN, PERFECT_DESIGN)


@dataclass(frozen=True)
class TaskSet:
    """A generated set: what run.json records of it, and its checked scenarios (vehicle by vehicle)."""

    info: TaskSetInfo
    scenarios: tuple[Scenario, ...]


@dataclass(frozen=True)
class Levels:
    """Scenario i's levels on the designed axes (indices into TURBULENCE_LEVELS, DENSITY_LEVELS, AIR_LEVELS,
    SENSING_LEVELS and MAP_ERROR_LEVELS; the last two flown by a design with tiers only)."""

    turbulence: int
    density: int
    air: int
    sensing: int
    map_error: int


def levels(index: int) -> Levels:
    """The orthogonal-array levels of scenario `index` (see the module docstring)."""
    a, b, c = index % 3, (index // 3) % 3, (index // 9) % 3
    return Levels(turbulence=a, density=(a + b) % 3, air=(a + 2 * b + c) % 3, sensing=(a + b + c) % 3,
                  map_error=(2 * b + c) % 3)


# ---- the sets ---------------------------------------------------------------------------------------
def design_of(name: str) -> BenchmarkDesign:
    """The design whose sets include `name` (`FAMILIES`).

    Raises:
        ValueError: an unknown set name (naming the known ones).
    """
    for design in FAMILIES:
        if name in design.sets:
            return design
    raise ValueError(f"unknown benchmark set {name!r} (known: {', '.join(BENCHMARK_SETS)})")


def build_task_set(name: str, design: BenchmarkDesign | None = None) -> TaskSet:
    """Generate and check the benchmark set `name` (one of `BENCHMARK_SETS`) of `design` (None: its family's,
    `design_of`).

    Raises:
        ValueError: an unknown set name or one `design` does not hold, or a design whose quick set is not a subset
            of the full one or whose city seeds are not held out (`LEARNED_PILOT_POOLS`, another vehicle's, another
            family's).
    """
    design = design_of(name) if design is None else design
    if name not in design.sets:
        raise ValueError(f"benchmark set {name!r} is not one of the design's ({', '.join(design.sets)})")
    _check_design(design)
    full, quick, validation, validation_quick = design.sets
    n_scenarios, n_legs = ((design.quick_scenarios, design.quick_legs) if name in (quick, validation_quick)
                           else (design.scenarios_per_vehicle, design.legs_per_scenario))
    flown, prefix = design, design.prefix
    if name in (validation, validation_quick):
        flown, prefix = validation_design(design), f"{design.prefix}-validation"
        _check_design(flown, others={f"{v} {full}": seeds for v, seeds in city_seed_ranges(design).items()})
    checked = []
    for vb in flown.vehicles:
        vehicle = load_vehicle(vb.vehicle)
        for i in range(n_scenarios):
            data = scenario_mapping(vb, vehicle, i, n_legs, flown, prefix)
            checked.append(scenario_from_dict(data, f"{name}:{data['name']}", Path(".")))
    info = TaskSetInfo(name, task_set_version(checked, design.generator_version),
                       _describe(name, n_scenarios, n_legs, flown))
    return TaskSet(info, tuple(dataclasses.replace(sc, task_set=info) for sc in checked))


def city_seed_ranges(design: BenchmarkDesign = DESIGN) -> dict[str, range]:
    """The city seeds of the full set, per vehicle."""
    return {vb.vehicle: range(vb.first_seed, vb.first_seed + design.scenarios_per_vehicle) for vb in design.vehicles}


def validation_design(design: BenchmarkDesign = DESIGN) -> BenchmarkDesign:
    """The design of the validation twin: every vehicle's city seeds moved by `VALIDATION_SEED_OFFSET`."""
    return dataclasses.replace(design, vehicles=tuple(
        dataclasses.replace(vb, first_seed=vb.first_seed + VALIDATION_SEED_OFFSET) for vb in design.vehicles))


def _check_design(design: BenchmarkDesign, others: dict[str, range] | None = None) -> None:
    """Raise ValueError when the quick set is not a subset, or a city seed is in a learned pilot's pool, in
    `others` (named seed ranges: the test set's, for its validation twin), in another family's sets or twice."""
    if not (1 <= design.quick_scenarios <= design.scenarios_per_vehicle
            and 1 <= design.quick_legs <= design.legs_per_scenario):
        raise ValueError(f"the quick set ({design.quick_scenarios} x {design.quick_legs}) must be a non-empty subset "
                         f"of the full set ({design.scenarios_per_vehicle} x {design.legs_per_scenario})")
    taken: dict[str, range] = {**LEARNED_PILOT_POOLS, **(others or {})}
    for other in FAMILIES:  # the other family's sets and twins hold other cities
        if other.sets != design.sets:
            for twin, name in ((other, other.sets[0]), (validation_design(other), other.sets[2])):
                taken.update({f"{v} {name}": seeds for v, seeds in city_seed_ranges(twin).items()})
    for vehicle, seeds in city_seed_ranges(design).items():
        for pool, other_seeds in taken.items():
            if seeds.start < other_seeds.stop and other_seeds.start < seeds.stop:
                raise ValueError(f"{vehicle}: city seeds {seeds.start}-{seeds.stop - 1} overlap the {pool} cities "
                                 f"({other_seeds.start}-{other_seeds.stop - 1})")
        taken[f"{vehicle} {design.sets[0]}"] = seeds


def task_set_version(scenarios: Sequence[Scenario], generator_version: str = GENERATOR_VERSION) -> str:
    """`generator_version` (this module's `GENERATOR_VERSION`) + "+" + 10 hex digits of SHA-256 over the
    scenarios' mappings and their cities' buildings and bounds (the mapping names the city by generator
    parameters and seed; the hash of what was generated catches a change of the city generator too).

    The mappings are hashed with their pilots under the key's first name, `methods` (renamed `pilots` since):
    the rename changes no task, so it keeps every published version (docs/benchmark.md)."""
    content = [[{("methods" if k == "pilots" else k): v for k, v in sc.raw.items()}, scenario_fingerprint(sc)["map"]]
               for sc in scenarios]
    digest = hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()
    return f"{generator_version}+{digest[:10]}"


def _describe(name: str, n_scenarios: int, n_legs: int, design: BenchmarkDesign) -> str:
    full, quick, validation, validation_quick = design.sets
    sizes = ", ".join(f"{vb.vehicle} {n_scenarios} cities x {n_legs} legs = {n_scenarios * n_legs} tasks"
                      for vb in design.vehicles)
    subset = {quick: f" (the first of {full}'s)",
              validation: f" for tuning: the validation twin of {full} (city seeds +{VALIDATION_SEED_OFFSET:,})",
              validation_quick: f" for tuning: the first of {validation}'s"}.get(name, "")
    tiers = (f", sensing {'/'.join(SENSING_LEVELS)}, maps {'/'.join(MAP_ERROR_LEVELS)}" if design.tiers
             else ", perfect sensing over exact maps")
    winds = "/".join(f"{vb.steady_wind_max_m_s:g}" for vb in design.vehicles)
    return (f"Held-out generated tasks per vehicle{subset}: {sizes}; cities of each learned pilot's distribution at "
            f"unseen seeds; buildings {'/'.join(DENSITY_LEVELS)}, turbulence {'/'.join(TURBULENCE_LEVELS)}, air "
            f"{'/'.join(a.name for a in AIR_LEVELS)}{tiers}, steady wind to {winds} m/s, "
            f"{len(design.vehicles[0].leg_bins_m)} leg-length bins, straight lines blocked by buildings where possible")


# ---- one scenario -----------------------------------------------------------------------------------
def scenario_mapping(vb: VehicleBenchmark, vehicle: VehicleParams, index: int, n_legs: int,
                     design: BenchmarkDesign = DESIGN, prefix: str = "benchmark") -> dict:
    """The scenario mapping (the scenario-file schema, `compare.scenarios.scenario`) of scenario `index` of a vehicle.

    Args:
        vb: the vehicle's distribution.
        vehicle: its parameters (`load_vehicle(vb.vehicle)`).
        index: the scenario's index (its city seed is vb.first_seed + index).
        n_legs: how many legs (the first n of this scenario's sequence).
        design: the sets' design (seeds, pilots).
        prefix: the scenario's name before "-<tag>-<index>".

    Raises:
        RuntimeError: a leg with no free start and goal after MAX_LEG_DRAWS candidates.
    """
    nav = task_for(vb.vehicle, envelope=vb.envelope)
    seed = vb.first_seed + index
    lv = levels(index)
    cities, bins = nav.cities, vb.leg_bins_m
    if isinstance(cities, CityMixture):  # each component in turn (not by the seed's draw): exactly its share
        k = index % len(cities.components)
        cities = cities.components[k]
        bins = vb.component_leg_bins_m[k] if vb.component_leg_bins_m else bins
    params = city_params(cities, seed, lv.density)
    city = generate_city(params, seed, name=f"gen-{seed}")
    rng = np.random.Generator(np.random.PCG64([seed, _STREAM_AIR]))
    air = AIR_LEVELS[lv.air]
    elevation = round(float(rng.uniform(*air.elevation_m)), -1)
    offset = round(float(rng.uniform(*air.isa_offset_k)), 1)
    speed, heading = float(rng.uniform(0.0, vb.steady_wind_max_m_s)), float(rng.uniform(-math.pi, math.pi))
    wind = [round(speed * math.cos(heading), 1), round(speed * math.sin(heading), 1), 0.0]
    turbulence = TURBULENCE_LEVELS[lv.turbulence]
    # every leg of the full set (each from its own stream): a subset's map error keeps clear of them all
    every = [draw_leg(city, nav.tasks, vb, vehicle.collision_radius_m, seed, j, bins)
             for j in range(max(n_legs, design.legs_per_scenario if design.tiers else n_legs))]
    legs = every[:n_legs]
    episodes = [{"start": a, "goal": b,
                 "timeout_s": round(nav.tasks.timeout_s(math.dist(a, b), b[2] - a[2], vehicle.controller.max_speed_m_s,
                                                        vehicle.controller.max_vertical_speed_m_s), 1)}
                for a, b in legs]
    density_altitude = density_altitude_m(field_density_kg_m3(elevation, offset))
    name = f"{prefix}-{vb.tag}-{index:03d}"
    fields = {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(params).items()}
    tiers: dict = {}
    sensed = ""
    if design.tiers:  # the map error drawn from the city's seed, clear of every leg of the full set
        sensing, map_error = SENSING_LEVELS[lv.sensing], MAP_ERROR_LEVELS[lv.map_error]
        keep = [p for leg in every for p in leg]
        tiers = {"sensing": sensing, "map_error": map_error if map_error == "exact" else
                 {"preset": map_error, "seed": seed, "keep_clear": keep}}
        sensed = f", {sensing} sensing, {map_error} map"
    data = {
        "name": name,
        "description": (f"{vb.vehicle} in held-out city {seed}: {DENSITY_LEVELS[lv.density]} buildings (built cover "
                        f"{building_coverage(city):.2f}), turbulence {turbulence}, {air.name} (field {elevation:g} m, "
                        f"ISA{offset:+g} K, density altitude {round(density_altitude):d} m), wind {speed:.1f} m/s"
                        f"{sensed}"),
        "map": {"generator": {"seed": seed, "name": city.name, **fields}},
        "vehicle": vb.vehicle,
        "atmosphere": {"elevation_m": elevation, "isa_offset_k": offset, "wind_mps": wind, "turbulence": turbulence},
        "goal_radius_m": nav.tasks.goal_radius_m,
        "episodes": episodes,
        "seeds": list(design.seeds),
        "pilots": list(design.pilots),
    }
    return {**data, **tiers}


def city_params(cities: CityDistribution | CityMixture, seed: int, density_level: int) -> CityGenConfig:
    """City `seed` of the learned pilot's distribution with its lot occupancy and footprint fill set to the
    density level's (0: the lowest of the distribution's ranges, 1: the middle, 2: the highest); the fill's
    spread is the city's own (from a mixture: the ranges of the component the city comes from)."""
    cities = cities.distribution(seed)
    p = cities.params(seed)
    t = density_level / (len(DENSITY_LEVELS) - 1)
    density = cities.density[0] + t * (cities.density[1] - cities.density[0])
    fill_low = cities.fill_low[0] + t * (cities.fill_low[1] - cities.fill_low[0])
    spread = p.fill_range[1] - p.fill_range[0]
    return dataclasses.replace(p, density=round(density, 3),
                               fill_range=(round(fill_low, 3), round(min(0.9, fill_low + spread), 3)))


def draw_leg(city: BuildingMap, tasks: TaskDistribution, vb: VehicleBenchmark, radius_m: float, seed: int,
             j: int, bins: tuple[tuple[float, float], ...] | None = None) -> tuple[list[float], list[float]]:
    """Leg j of city `seed`: start and goal (ENU, rounded to 0.1 m) from the leg's own stream
    (`compare.scenarios.random_legs.draw_leg`: a length in the leg's bin, heights in the vehicle's range, both ends
    the task's clearance beyond the collision radius from buildings and the ground, inside the bounds less the
    task's margin; the first candidate whose straight line is blocked wins, else the first free one).

    Raises:
        RuntimeError: no free start and goal in `MAX_LEG_DRAWS` candidates.
    """
    rng = np.random.Generator(np.random.PCG64([seed, _STREAM_LEG, j]))
    bins = vb.leg_bins_m if bins is None else bins
    bin_m = bins[j % len(bins)]
    ranges = LegRanges(bin_m, vb.altitude_m, tasks.min_clearance_m, tasks.bounds_margin_m)
    leg = random_leg(city, rng, ranges, radius_m, MAX_LEG_DRAWS)
    if leg is None:
        raise RuntimeError(f"city {seed}: no free start and goal for leg {j} ({bin_m[0]:g}-{bin_m[1]:g} m) in "
                           f"{MAX_LEG_DRAWS} candidates")
    return leg


# ---- difficulty measures ------------------------------------------------------------------------------
def field_density_kg_m3(elevation_m: float, isa_offset_k: float) -> float:
    """Air density at the field [kg/m³] in JSBSim's atmosphere (the one flown)."""
    air = Atmosphere.from_jsbsim(AtmosphereConditions(elevation_m, isa_offset_k), z_max_m=10.0, z_min_m=0.0)
    return float(air.density_kg_m3(0.0))


